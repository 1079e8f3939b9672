"""Measure ``ltmap replay --localize`` on the real logs (docs/localization.md).

    python bench/bench_localize.py [--real-logs ../shared/real_logs] [--only comprobo,pioneer,scan-only,speed]

- comprobo22 with its published map: the start alignment against the documented hand alignment
  (docs/real_logs.md); the fraction of O's occupied columns within 2 cells (6 cm) of a published
  wall, and the long-term voxels and their distance to the published walls, for the hand-aligned
  run and the --localize run.
- Pioneer without a static map: the thickness of its corridor walls with raw odometry and with
  --localize (see ``wall_thickness``).
- A scan-only copy of the Pioneer log (only /scan, no tf, no odometry; written with rosbags):
  IoU of occupied cells of its map and the full-odometry --localize map after ``ltmap diff
  --tolerance 1``-style alignment.
- Speed: wall time of the replay with and without --localize (best of ``--repeat`` runs).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ltmap_cli.analysis.map_quality import dilate, fraction_on_walls, raster, wall_distance, wall_thickness
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.io.state import read_state

HAND = (-0.345, -0.017, 0.08552)  # docs/real_logs.md
PIONEER_MOUNT = "base_link:laser=0.1,0,0.3,0,0,0"
# as tests/test_real_logs.py: its walls are seen for less than the default st_rise_s
PIONEER = ["--tf", PIONEER_MOUNT, "--set", "map.layers.st_rise_s=5"]


def ltmap(*args: str, out: list | None = None, cpu: list | None = None) -> float:
    """Run ltmap; the wall time of the whole command (``out`` gets its stdout, ``cpu`` its CPU
    time: user + system, less disturbed than wall time on a shared machine)."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "ltmap_cli", *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode not in (0, 1):
        raise SystemExit(f"ltmap {' '.join(args)} failed:\n{r.stderr}")
    if out is not None:
        out.append(r.stdout)
    if cpu is not None:
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall


def diff_iou(a: Path, b: Path, tolerance: int = 1) -> float:
    """The IoU that ``ltmap diff A B --tolerance N --json`` reports."""
    text: list = []
    ltmap("diff", str(a), str(b), "--tolerance", str(tolerance), "--json", out=text)
    return float(json.loads(text[0])["iou"])


def o_columns(out: Path) -> np.ndarray:
    """xy centres of the columns of O's occupied voxels (fixed frame) in a replay output."""
    arrays, _ = read_state(out / "snapshots" / "state_final.npz")
    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    keys = m.occupied_keys("O")
    return np.unique((keys[:, :2] + 0.5) * m.resolution, axis=0)


def lt_columns(out: Path) -> np.ndarray:
    arrays, _ = read_state(out / "snapshots" / "state_final.npz")
    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    keys = m.occupied_keys("LT")
    return (keys[:, :2] + 0.5) * m.resolution


def first_pose(log: Path, mount: str) -> list[float]:
    """base_link's pose in odom at the log's first scan (to put a scan-only map in odom)."""
    from ltmap_cli.io.frames import ScanFrame
    from ltmap_cli.io.logs import open_logs
    from ltmap_cli.io.transforms import TfBuffer

    tf = TfBuffer()
    tf.add_mount(mount)
    first = None
    with open_logs(log) as logs:
        for _, _, it in logs.messages(logs.select()):
            if isinstance(it, ScanFrame):
                first = first or it.stamp_ns
            else:
                tf.add(it)
                if first is not None and tf.try_lookup("odom", "base_link", first)[0] is not None:
                    break
    T = tf.lookup("odom", "base_link", first)
    return [float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0])]


def occupied_iou(a: Path, b: Path, tolerance: int = 1) -> float:
    """IoU of occupied cells of two map.yaml on one lattice, a cell counting as shared when the
    other map has an occupied cell within ``tolerance`` cells (as ``ltmap diff --tolerance``)."""
    ga, gb = read_map_yaml(a / "map.yaml"), read_map_yaml(b / "map.yaml")
    res = ga.resolution
    pa = np.argwhere(ga.data == 100)[:, ::-1] * res + np.array(ga.origin[:2])
    pb = np.argwhere(gb.data == 100)[:, ::-1] * res + np.array(gb.origin[:2])
    lo = np.minimum(pa.min(0), pb.min(0)) - 1.0
    hi = np.maximum(pa.max(0), pb.max(0)) + 1.0
    shape = tuple((np.ceil((hi - lo) / res)).astype(int)[::-1] + 1)
    A = np.zeros(shape, bool)
    B = np.zeros(shape, bool)
    ia = np.round((pa - lo) / res).astype(int)
    ib = np.round((pb - lo) / res).astype(int)
    A[ia[:, 1], ia[:, 0]] = True
    B[ib[:, 1], ib[:, 0]] = True
    a_hit = A & dilate(B, tolerance)
    b_hit = B & dilate(A, tolerance)
    inter = (a_hit.sum() + b_hit.sum()) / 2
    return float(inter / (A.sum() + B.sum() - inter))


def scan_only_copy(src: Path, dst: Path) -> Path:
    """The log's LaserScan messages alone, written as a ROS 1 bag with rosbags."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with AnyReader([src]) as reader, Writer(dst) as writer:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/LaserScan"]
        out = writer.add_connection(conns[0].topic, "sensor_msgs/msg/LaserScan", typestore=ts)
        for conn, t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            writer.write(out, t, ts.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-logs", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "real_logs")
    ap.add_argument("--only", default="comprobo,pioneer,scan-only,speed")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    only = set(args.only.split(","))
    rl = args.real_logs
    comp = rl / "comprobo22_macfirst_floor_take_2"
    pub = rl / "comprobo22_maps" / "mac_1st_floor_final.yaml"
    pio = rl / "ist_pioneer3dx_test1.bag"
    grid = read_map_yaml(pub)
    hand_args = [str(comp), "--static", str(pub), "--fixed-frame", "map", "--tf", "map:odom=" + ",".join(
        map(str, (HAND[0], HAND[1], 0, 0, 0, HAND[2])))]
    loc_args = [str(comp), "--static", str(pub), "--localize"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if "comprobo" in only:
            ltmap("replay", *hand_args, "-o", str(tmp / "hand"), "-q", "--no-plots")
            ltmap("replay", *loc_args, "-o", str(tmp / "loc"), "-q", "--no-plots")
            loc = json.loads((tmp / "loc" / "report.json").read_text())["localization"]
            a = loc["alignment"]
            print(f"comprobo22 start alignment: x {a['x']:.3f} y {a['y']:.3f} yaw {a['yaw_deg']:.2f} deg "
                  f"(score {a['score']:.2f}, runner-up {a['runner_up_score']:.2f}, {a['seconds']:.2f} s); hand: "
                  f"x {HAND[0]} y {HAND[1]} yaw {math.degrees(HAND[2]):.2f}: off by "
                  f"{math.hypot(a['x'] - HAND[0], a['y'] - HAND[1]):.3f} m, "
                  f"{abs(a['yaw_deg'] - math.degrees(HAND[2])):.2f} deg")
            print(f"  tracking: {loc['accepted']} accepted, {loc['rejected']} rejected, median score "
                  f"{loc['score_median']}, p10 {loc['score_p10']}; pre-pass {loc['wall_s']} s")
            for name in ("hand", "loc"):
                cols = o_columns(tmp / name)
                lt = lt_columns(tmp / name)
                d = wall_distance(lt, grid) if len(lt) else np.array([])
                print(f"  {name}: {len(cols)} O columns, {100 * fraction_on_walls(cols, grid):.1f} % within 2 cells of a "
                      f"published wall; {len(lt)} long-term voxels, {int((d <= 0.1).sum())} within 0.1 m of a wall"
                      f" (distances {np.round(np.sort(d), 2).tolist()})")
        if "pioneer" in only or "scan-only" in only:
            ltmap("replay", str(pio), *PIONEER, "-o", str(tmp / "pio_raw"), "-q", "--no-plots")
            ltmap("replay", str(pio), *PIONEER, "--localize", "-o", str(tmp / "pio_loc"), "-q", "--no-plots")
            for name in ("pio_raw", "pio_loc"):
                g = read_map_yaml(tmp / name / "map.yaml")
                print(f"pioneer {name}: walls of O {wall_thickness(raster(o_columns(tmp / name), 0.05), 0.05)}; "
                      f"of map.pgm {wall_thickness(g.data == 100, g.resolution)}")
        if "scan-only" in only:
            bag = scan_only_copy(pio, tmp / "scan_only.bag")
            start = first_pose(pio, PIONEER_MOUNT)
            ltmap("replay", str(bag), *PIONEER, "--localize", "--set",
                  f"replay.localization.initial_pose=[{start[0]},{start[1]},{start[2]}]", "-o",
                  str(tmp / "scan_only"), "-q", "--no-plots")
            rep = json.loads((tmp / "scan_only" / "report.json").read_text())
            print(f"scan-only: {sum(rep['frames_used'].values())} scans used, localization "
                  f"{rep['localization']['message']}")
            for ref in ("pio_loc", "pio_raw"):
                print(f"  against {ref}: IoU of occupied cells {occupied_iou(tmp / 'scan_only', tmp / ref):.3f} "
                      f"(a cell shared when the other has one within 1 cell); ltmap diff --tolerance 1 "
                      f"iou {diff_iou(tmp / ref, tmp / 'scan_only'):.3f}")
        if "speed" in only:
            for label, a in (("comprobo22", hand_args), ("comprobo22 --localize", loc_args),
                             ("pioneer", [str(pio), *PIONEER]), ("pioneer --localize", [str(pio), *PIONEER, "--localize"])):
                cpu: list = []
                best = min(ltmap("replay", *a, "-o", str(tmp / "speed"), "-q", cpu=cpu) for _ in range(args.repeat))
                stage = json.loads((tmp / "speed" / "report.json").read_text())["stage_s"]
                print(f"speed: {label}: wall {best:.2f} s, CPU {min(cpu):.2f} s (whole command, best of "
                      f"{args.repeat}); localize pre-pass {stage.get('localize', 0.0):.2f} s")


if __name__ == "__main__":
    main()
