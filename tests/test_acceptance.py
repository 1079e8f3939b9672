"""The paper's acceptance criteria (SPEC 7), on the committed sample logs and their ground truth.

Method. Each sample log is replayed through the real CLI (``ltmap replay``); where timing matters
the replay writes a snapshot at every tick (``--snapshot-every 0.2``). A snapshot named ``t``
holds the state after every tick that ends at or before ``t`` seconds after the first sensor frame;
the simulator starts every sensor at the log's start (scenario time 0), so snapshot times are
scenario times (checked against report.json's log start). For an object we take the voxels whose
centre lies within one voxel of its ground-truth geometry, inside the projection band
[0.05, 1.5] m and more than 0.1 m from a wall, and read LT (and O) there in every snapshot:

- *enters LT*: the first snapshot where one of them has LT >= 0.65; latency from the moment the
  object appears (the robot looks at it from then on, so sight is continuous from t_on);
- *leaves LT*: the first snapshot after its removal where none has LT >= 0.65; latency measured
  from the removal itself, which is stricter than the spec's "from the first tick seen free"
  (O needs about 9 misses, ~1 s at 10 Hz, before the voxels read free).

Maps (``map.pgm``, P) are read with ``read_map_yaml``; A* is ``ltmap plan``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.core.config import LayerConfig, MapConfig

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1] / "sample_logs"
SC = ROOT / "scenarios"
R = 0.05
LAY = LayerConfig()
TICK = LAY.tick
ENTER_MAX = LAY.st_rise_s + 2 * TICK  # 15.4 s
LEAVE_MAX = LAY.lt_fall_s + 2 * TICK  # 3.4 s
OCC = 0.65


def ltmap(*args: str | Path) -> str:
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res.output


def ground_truth(name: str) -> dict:
    return json.loads((SC / name / "ground_truth.json").read_text())


def gt_object(gt: dict, oid: str) -> dict:
    return next(o for o in gt["objects"] if o["id"] == oid)


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    """Replay outputs, computed once: out(name, *replay options) -> folder."""
    cache: dict[tuple, Path] = {}
    base = tmp_path_factory.mktemp("acceptance")

    def run(log: str, *opts: str) -> Path:
        key = (log, *opts)
        if key not in cache:
            folder = base / f"run{len(cache)}"
            ltmap("replay", SC / log, "-o", folder, "-q", *opts)
            cache[key] = folder
        return cache[key]

    return run


# ----------------------------------------------------------------------------- geometry


def part_keys(p: dict, margin: float = R, z_band=(0.05, 1.5)) -> np.ndarray:
    """Voxel keys whose centre is within ``margin`` of a ground-truth part, inside the z band."""
    if p["type"] == "box":
        c, h = np.array(p["center"]), np.array(p["size"]) / 2
        ext = math.hypot(h[0], h[1]) + margin
        lo, hi = c - [ext, ext, h[2] + margin], c + [ext, ext, h[2] + margin]
    elif p["type"] == "cylinder":
        (cx, cy), rr = p["center"], p["radius"] + margin
        lo, hi = (
            np.array([cx - rr, cy - rr, p["z"][0] - margin]),
            np.array([cx + rr, cy + rr, p["z"][1] + margin]),
        )
    else:
        c = np.array(p["center"])
        lo, hi = c - p["radius"] - margin, c + p["radius"] + margin
    k0, k1 = np.floor(lo / R).astype(int), np.floor(hi / R).astype(int)
    g = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(k0, k1)], indexing="ij"), -1).reshape(
        -1, 3
    )
    ctr = (g + 0.5) * R
    if p["type"] == "box":
        a = math.radians(p["yaw_deg"])
        d = ctr - c
        lx = math.cos(a) * d[:, 0] + math.sin(a) * d[:, 1]
        ly = -math.sin(a) * d[:, 0] + math.cos(a) * d[:, 1]
        ok = (abs(lx) <= h[0] + margin) & (abs(ly) <= h[1] + margin) & (abs(d[:, 2]) <= h[2] + margin)
    elif p["type"] == "cylinder":
        ok = np.hypot(ctr[:, 0] - cx, ctr[:, 1] - cy) <= p["radius"] + margin
        ok &= (ctr[:, 2] >= p["z"][0] - margin) & (ctr[:, 2] <= p["z"][1] + margin)
    else:
        ok = np.linalg.norm(ctr - c, axis=1) <= p["radius"] + margin
    ok &= (ctr[:, 2] >= z_band[0]) & (ctr[:, 2] <= z_band[1])
    return g[ok]


def walls(gt: dict):
    import shapely

    return shapely.from_wkt(gt["walls_wkt"]) if gt["walls_wkt"] else shapely.GeometryCollection()


def object_keys(gt: dict, oid: str) -> np.ndarray:
    import shapely

    keys = np.unique(np.concatenate([part_keys(p) for p in gt_object(gt, oid)["parts"]]), axis=0)
    ctr = (keys + 0.5) * R
    far = shapely.distance(walls(gt), shapely.points(ctr[:, :2])) > 0.1
    assert far.sum() > 10
    return keys[far]


def footprint(part: dict):
    import shapely
    from shapely import affinity

    if part["type"] == "box":
        sx, sy = part["size"][:2]
        b = shapely.box(-sx / 2, -sy / 2, sx / 2, sy / 2)
        return affinity.translate(affinity.rotate(b, part["yaw_deg"]), *part["center"][:2])
    return shapely.Point(part["center"][:2]).buffer(part["radius"])


def series(folder: Path, keys: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(t, LT, O log-odds) at ``keys`` for every per-tick snapshot, in time order."""
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.state import read_state

    rows = []
    for f in (folder / "snapshots").glob("state_t*.npz"):
        arrays, meta = read_state(f)
        lm = LayeredMap(MapConfig())
        lm.load_state_arrays(arrays)
        rows.append((float(meta["log_time_s"]), lm.values("LT", keys), lm.values("O", keys)))
    rows.sort(key=lambda r: r[0])
    assert len(rows) > 100 and rows[1][0] - rows[0][0] == pytest.approx(TICK)
    return rows


def enter_leave(rows, t_on: float, t_off: float | None) -> tuple[float, float | None]:
    """(first time any voxel is in LT, first time after the removal that every voxel seen gone
    is out of LT). "Seen gone" = O says free at some time after the removal: a voxel that is not
    observed again keeps its LT (SPEC 2.2), so the removal criterion applies to what was seen;
    at least 90 % of the object's long-term voxels must have been seen gone."""
    t_enter = next(t for t, lt, _ in rows if (lt >= OCC).any())
    assert t_enter > t_on, "in LT before the object appeared"
    t_leave = None
    if t_off is not None:
        assert all((lt >= OCC).any() for t, lt, _ in rows if t_enter <= t <= t_off)
        in_lt = next(lt for t, lt, _ in rows if t >= t_off) >= OCC
        seen_gone = np.zeros_like(in_lt)
        for t, _, lo in rows:
            if t > t_off:
                seen_gone |= lo < 0
        assert (seen_gone & in_lt).sum() >= 0.9 * in_lt.sum(), (int((seen_gone & in_lt).sum()), int(in_lt.sum()))
        t_leave = next(t for t, lt, _ in rows if t > t_off and not ((lt >= OCC) & seen_gone).any())
    return t_enter, t_leave


def leave_after_seen_gone(rows, t_off: float) -> float:
    """The longest time, over the voxels in LT at the removal and seen gone after it, from the
    first tick O says the voxel is free to the first tick its LT is below the threshold: the
    spec's "leaves within lt_fall_s + 2 ticks of being seen gone"."""
    start = next(i for i, r in enumerate(rows) if r[0] >= t_off)
    in_lt = rows[start][1] >= OCC
    worst = 0.0
    for v in np.nonzero(in_lt)[0]:
        t_gone = next((t for t, _, lo in rows[start:] if lo[v] < 0), None)
        if t_gone is None:
            continue  # never observed free again: LT keeps it (checked in enter_leave)
        t_out = next(t for t, lt, _ in rows[start:] if t >= t_gone and lt[v] < OCC)
        worst = max(worst, t_out - t_gone)
    return worst


def check_start(folder: Path, gt: dict) -> None:
    report = json.loads((folder / "report.json").read_text())
    assert report["log_start_ns"] == gt["start_time_ns"]
    assert report["frames_skipped"] == {}


# ----------------------------------------------------------------------------- map helpers


def map_cells(folder: Path, geom) -> np.ndarray:
    """Values (-1/0/100) of map.pgm's cells whose centre lies in a shapely geometry."""
    import shapely

    from ltmap_cli.io.mapfile import read_map_yaml

    g = read_map_yaml(folder / "map.yaml")
    ox, oy, yaw = g.origin
    assert yaw == 0
    rows, cols = np.mgrid[0 : g.data.shape[0], 0 : g.data.shape[1]]
    x = ox + (cols + 0.5) * g.resolution
    y = oy + (rows + 0.5) * g.resolution
    inside = shapely.contains_xy(geom, x, y)
    return g.data[inside]


def table_geometry(gt: dict, oid: str = "table"):
    parts = gt_object(gt, oid)["parts"]
    top = footprint(parts[0])
    legs = [footprint(p) for p in parts[1:5]]
    return top, legs


# ----------------------------------------------------------------------------- 1: static object


def test_static_object_enters_and_leaves_long_term(out):
    gt = ground_truth("01_static_object")
    folder = out("01_static_object/log.mcap", "--snapshot-every", "0.2")
    check_start(folder, gt)
    (t_on, t_off) = gt_object(gt, "box")["present"][0]
    rows = series(folder, object_keys(gt, "box"))
    t_enter, t_leave = enter_leave(rows, t_on, t_off)
    assert leave_after_seen_gone(rows, t_off) <= LEAVE_MAX
    # measured: appears at 3.0 s, in LT at 18.2 s (15.2 s), removed at 23.0 s, out of LT at 25.8 s (2.8 s)
    assert LAY.st_rise_s - TICK <= t_enter - t_on <= ENTER_MAX
    assert t_leave - t_off <= LEAVE_MAX


@pytest.mark.parametrize("log", ["log.bag", "log_ros2"])
def test_ros1_and_ros2_bags_give_the_same_map_as_mcap(out, log):
    a = out("01_static_object/log.mcap")
    b = out(f"01_static_object/{log}")
    assert (a / "map.pgm").read_bytes() == (b / "map.pgm").read_bytes()
    assert (a / "long_term.pgm").read_bytes() == (b / "long_term.pgm").read_bytes()
    ra, rb = (json.loads((f / "report.json").read_text()) for f in (a, b))
    assert ra["frames_used"] == rb["frames_used"] == {"/scan": 300}


# ----------------------------------------------------------------------------- 2: table


def test_table_top_occupied_with_depth_absent_with_laser_alone(out):
    gt = ground_truth("02_table")
    depth = out("02_table/log.mcap")
    laser = out("02_table/log.mcap", "--scan-topic", "/scan")
    top, legs = table_geometry(gt)
    inner = top.buffer(-0.15)  # the top away from its edges and legs
    with_depth = map_cells(depth, inner)
    with_laser = map_cells(laser, inner)
    assert len(with_depth) > 300
    assert (with_depth == 100).mean() >= 0.95  # measured: every cell
    assert (with_laser == 100).sum() == 0  # measured: all free
    for leg in legs:  # the laser sees the legs
        assert (map_cells(laser, leg.buffer(0.05)) == 100).any()
        assert (map_cells(depth, leg.buffer(0.05)) == 100).any()


def _plan(folder: Path) -> dict:
    text = ltmap("plan", folder / "map.yaml", "--start", "1.6,2.5", "--goal", "5.5,2.5", "--robot-radius", "0.25",
                 "--allow-unknown", "--json")  # fmt: skip
    return json.loads(text)


def test_astar_routes_around_the_table_with_depth_and_under_it_with_laser(out):
    import shapely

    gt = ground_truth("02_table")
    top, _ = table_geometry(gt)
    p_depth = _plan(out("02_table/log.mcap"))
    p_laser = _plan(out("02_table/log.mcap", "--scan-topic", "/scan"))
    line_d = shapely.LineString(p_depth["path"])
    line_l = shapely.LineString(p_laser["path"])
    # laser alone: straight between the legs (3.9 m); with depth: around the table (measured 4.93 m)
    assert p_laser["length_m"] == pytest.approx(3.9, abs=0.06)
    assert line_l.intersects(top)
    assert not line_d.intersects(top)
    assert p_depth["length_m"] > p_laser["length_m"] + 0.5


# ----------------------------------------------------------------------------- 3: ball


def test_ball_below_the_laser_plane_occupied_with_depth_only(out):
    import shapely

    gt = ground_truth("03_ball")
    ball = gt_object(gt, "ball")["parts"][0]
    area = shapely.Point(ball["center"][:2]).buffer(ball["radius"] + 0.05)
    with_depth = map_cells(out("03_ball/log.mcap"), area)
    with_laser = map_cells(out("03_ball/log.mcap", "--scan-topic", "/scan"), area)
    assert (with_depth == 100).sum() >= 5  # measured: 14 cells of 0.05 m
    assert (with_laser == 100).sum() == 0


# ----------------------------------------------------------------------------- 2, 3: depth only


def _band_keys(gt: dict, part: dict) -> np.ndarray:
    """``part_keys`` of one part, more than 0.1 m from a wall (as ``object_keys``)."""
    import shapely

    keys = part_keys(part)
    far = shapely.distance(walls(gt), shapely.points((keys[:, :2] + 0.5) * R)) > 0.1
    assert far.sum() > 10
    return keys[far]


@pytest.mark.parametrize(("name", "oid"), [("02_table", "table"), ("03_ball", "ball")])
def test_seen_by_depth_only_enters_long_term_within_st_rise(out, name, oid):
    """The table top (0.73 m) and the ball (below the laser plane) are seen by the 2.5 Hz depth
    camera only, every other 0.2 s tick: with map.layers.max_gap_s the gap between two frames
    counts as observed time, so they enter LT in st_rise_s like what the 10 Hz laser sees."""
    gt = ground_truth(name)
    folder = out(f"{name}/log.mcap", "--snapshot-every", "0.2")
    check_start(folder, gt)
    obj = gt_object(gt, oid)
    (t_on, _) = obj["present"][0]
    keys = _band_keys(gt, obj["parts"][0])  # the table's top, the ball's sphere
    t_enter, _ = enter_leave(series(folder, keys), t_on, None)
    # measured: in view from 0.0 s, in LT at 15.0 s (both)
    assert LAY.st_rise_s - TICK <= t_enter - t_on <= ENTER_MAX


def test_depth_only_without_gap_credit_takes_twice_st_rise(out):
    """The control: with max_gap_s = 1 tick, ST rises once per depth frame (every other tick), so
    the ball needs twice st_rise_s (measured: 30.0 s)."""
    gt = ground_truth("03_ball")
    folder = out("03_ball/log.mcap", "--snapshot-every", "0.2", "--set", f"map.layers.max_gap_s={TICK}")
    obj = gt_object(gt, "ball")
    (t_on, _) = obj["present"][0]
    t_enter, _ = enter_leave(series(folder, _band_keys(gt, obj["parts"][0])), t_on, None)
    assert 2 * LAY.st_rise_s - TICK <= t_enter - t_on <= 2 * LAY.st_rise_s + 2 * TICK


# ----------------------------------------------------------------------------- 4: door


def test_closed_door_enters_is_kept_while_unobserved_and_leaves(out):
    gt = ground_truth("04_door")
    folder = out("04_door/log.mcap", "--snapshot-every", "0.2")
    check_start(folder, gt)
    (t_close, t_open) = gt_object(gt, "door")["present"][0]
    rows = series(folder, object_keys(gt, "door"))
    t_enter, t_leave = enter_leave(rows, t_close, t_open)
    assert leave_after_seen_gone(rows, t_open) <= LEAVE_MAX
    # measured: closes at 4.0 s while the robot drives toward it, in LT at 19.2 s (15.2 s);
    # opens at 31.0 s, out of LT at 33.8 s (2.8 s)
    assert LAY.st_rise_s - TICK <= t_enter - t_close <= ENTER_MAX
    assert t_leave - t_open <= LEAVE_MAX
    # the robot faces away (yaw 180 deg, 270 deg laser) from 23 to 27 s: the door is not observed
    # (O does not change there) and LT keeps it
    away = [(t, lt, lo) for t, lt, lo in rows if 23.2 <= t <= 27.0]
    assert len(away) >= 19
    assert all(np.array_equal(lo, away[0][2]) for _, _, lo in away)
    assert all((lt >= OCC).sum() == (away[0][1] >= OCC).sum() > 0 for _, lt, _ in away)


# ----------------------------------------------------------------------------- 5: person


def _person_area(gt: dict, pid: str = "person"):
    import shapely

    p = gt_object(gt, pid)
    line = shapely.LineString([(q["x"], q["y"]) for q in p["path"]])
    area = line.buffer(p["radius"] + 0.1).difference(walls(gt).buffer(0.15))
    others = [footprint(part) for o in gt["objects"] if o["category"] != "person" for part in o["parts"]]
    if others:
        area = area.difference(shapely.union_all(others).buffer(0.15))
    return area


def _lt_near(folder: Path, area) -> list[tuple[float, int, float]]:
    """(t, LT-occupied voxels in the area's columns within the band, max ST there) per snapshot."""
    import shapely

    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.state import read_state

    rows = []
    for f in (folder / "snapshots").glob("state_*.npz"):
        arrays, meta = read_state(f)
        lm = LayeredMap(MapConfig())
        lm.load_state_arrays(arrays)
        D = lm.D
        keys = D.voxels_where(D.channel("st") > 0)
        lt_keys = lm.occupied_keys("LT")
        ctr = (lt_keys + 0.5) * R
        n = int(
            (shapely.contains_xy(area, ctr[:, 0], ctr[:, 1]) & (ctr[:, 2] >= 0.05) & (ctr[:, 2] <= 1.5)).sum()
        )
        c2 = (keys + 0.5) * R
        inside = shapely.contains_xy(area, c2[:, 0], c2[:, 1])
        st = float(D.get("st", keys[inside]).max()) if inside.any() else 0.0
        rows.append((meta["log_time_s"] or 1e9, n, st))
    return sorted(rows)


def test_person_never_enters_long_term(out):
    gt = ground_truth("05_person")
    folder = out("05_person/log.mcap", "--snapshot-every", "0.2")
    rows = _lt_near(folder, _person_area(gt))
    assert len(rows) > 100
    assert all(n == 0 for _, n, _ in rows)
    # the person stood 10 s in front of the robot: ST rose to about 10 / 15 but never reached 1
    top = max(st for _, _, st in rows)
    assert 0.5 < top < 1.0  # measured: 0.72


# ----------------------------------------------------------------------------- 6: house


@pytest.fixture(scope="module")
def house(out, tmp_path_factory):
    static = tmp_path_factory.mktemp("house_static")
    ltmap("build-static", ROOT / "plans" / "house.svg", "-o", static)
    depth = out("06_house/log.mcap", "--static", str(static), "--snapshot-every", "0.2")
    laser = out("06_house/log.mcap", "--static", str(static), "--scan-topic", "/scan")
    return ground_truth("06_house"), depth, laser


def test_house_table_top_and_ball_with_depth_only(house):
    import shapely

    gt, depth, laser = house
    top, _ = table_geometry(gt)
    inner = top.buffer(-0.15)
    assert (map_cells(depth, inner) == 100).mean() >= 0.9
    assert (map_cells(laser, inner) == 100).sum() == 0
    ball = gt_object(gt, "ball")["parts"][0]
    area = shapely.Point(ball["center"][:2]).buffer(ball["radius"] + 0.05)
    assert (map_cells(depth, area) == 100).sum() >= 3
    assert (map_cells(laser, area) == 100).sum() == 0


def test_house_removed_box_leaves_and_person_never_enters(house):
    gt, depth, _ = house
    check_start(depth, gt)
    (t_on, t_off) = gt_object(gt, "box")["present"][0]
    rows = series(depth, object_keys(gt, "box"))
    t_enter, t_leave = enter_leave(rows, t_on, t_off)
    # the person walks between the robot and the box (4..14 s): sight is not continuous, so entry
    # is only bounded here (measured 15.8 s)
    assert LAY.st_rise_s - TICK <= t_enter - t_on <= 25.0
    # the box's upper part is seen by the 2.5 Hz camera only: O needs 9 misses (3.6 s) to call it
    # free, then LT leaves within lt_fall_s + 2 ticks of that (measured 2.0 s; 5.2 s from removal)
    assert leave_after_seen_gone(rows, t_off) <= LEAVE_MAX
    assert t_leave - t_off <= 9 / 2.5 + LEAVE_MAX
    assert all(n == 0 for _, n, _ in _lt_near(depth, _person_area(gt)))
