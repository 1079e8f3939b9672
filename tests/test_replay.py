"""`ltmap replay` end to end on tiny real logs in every format, with geometry known exactly.

The scene: a square room with walls on x = +-2.025 and y = +-2.025 m (cell centres at 0.05 m),
an optional 0.2 m square pillar, a robot standing at (1.0, 0.5) with yaw 30 degrees and a laser
mounted 0.1 m ahead and 0.3 m up. Ranges are ray cast here in float64 and stored as float32; the
expected occupied cells are computed from that geometry, independently of the pipeline.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from logfactory import FORMATS, Msg, camera_info, image, scan, string, tf, truncate, write_log, yaw_quat

from ltmap_cli.cli import cli
from ltmap_cli.io.mapfile import read_map_yaml

R = 0.05
WALL = 2.025
ROBOT = (1.0, 0.5, math.radians(30))
MOUNT = (0.1, 0.0, 0.3)
N_BEAMS = 180
T0 = 1_000_000_000
PILLAR = (-1.1, -1.1, -0.9, -0.9)  # x0, y0, x1, y1


def laser_pose():
    x, y, yaw = ROBOT
    return x + math.cos(yaw) * MOUNT[0], y + math.sin(yaw) * MOUNT[0], yaw


def beam_angles():
    amin = np.float32(-math.pi)
    inc = np.float32(2 * math.pi / N_BEAMS)
    return float(amin), float(inc), float(amin) + float(inc) * np.arange(N_BEAMS)


def cast(pillar: bool) -> tuple[np.ndarray, np.ndarray]:
    """(ranges float32, hit points float64 (N, 2)) of the laser in the room."""
    lx, ly, yaw = laser_pose()
    _, _, ang = beam_angles()
    th = yaw + ang
    dx, dy = np.cos(th), np.sin(th)
    with np.errstate(divide="ignore"):
        tx = np.where(dx > 0, (WALL - lx) / dx, (-WALL - lx) / dx)
        ty = np.where(dy > 0, (WALL - ly) / dy, (-WALL - ly) / dy)
    t = np.minimum(np.abs(tx), np.abs(ty))
    if pillar:
        x0, y0, x1, y1 = PILLAR
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (x0 - lx) / dx, (x1 - lx) / dx
            c, d = (y0 - ly) / dy, (y1 - ly) / dy
            tn = np.maximum(np.minimum(a, b), np.minimum(c, d))
            tf_ = np.minimum(np.maximum(a, b), np.maximum(c, d))
        t = np.where((tn <= tf_) & (tn > 0), np.minimum(t, tn), t)
    r = t.astype(np.float32)
    pts = np.stack([lx + r.astype(np.float64) * dx, ly + r.astype(np.float64) * dy], axis=1)
    return r, pts


def room_messages(t_start_s: float, duration_s: float, pillar: bool, rate_hz: float = 5.0, static_mount=True):
    msgs: list[Msg] = []
    if static_mount:
        msgs.append(tf(T0, [("base_link", "laser", MOUNT, (0, 0, 0, 1))], static=True))
    x, y, yaw = ROBOT
    r, _ = cast(pillar)
    amin, inc, _ = beam_angles()
    t_tf = t_start_s - 0.1
    n_scans = int(round(duration_s * rate_hz))
    scans = [T0 + int(round((t_start_s + i / rate_hz) * 1e9)) for i in range(n_scans)]
    events = []
    while t_tf <= t_start_s + duration_s + 0.2:
        ns = T0 + int(round(t_tf * 1e9))
        events.append((ns, 0, tf(ns, [("odom", "base_link", (x, y, 0.0), yaw_quat(yaw))])))
        t_tf += 0.1
    for ns in scans:
        events.append((ns, 1, scan("/scan", ns, r, frame_id="laser", angle_min=amin, angle_increment=inc,
                                   range_min=0.05, range_max=10.0)))  # fmt: skip
    events.sort(key=lambda e: (e[0], e[1]))
    return msgs + [e[2] for e in events]


def expected_cells(pillar: bool) -> tuple[set, set]:
    """(cells that must be occupied, cells that may be: neighbours of hits within 1e-4 m of a
    cell boundary, where float32 ranges and a different order of operations may round either way)."""
    _, pts = cast(pillar)
    must, may = set(), set()
    for px, py in pts:
        c = (math.floor(px / R), math.floor(py / R))
        fx, fy = px / R - math.floor(px / R), py / R - math.floor(py / R)
        near = [d for d, f in ((0, fx), (1, fy)) if min(f, 1 - f) < 1e-4 / R]
        if not near:
            must.add(c)
        else:
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    may.add((c[0] + di, c[1] + dj))
    return must, may


def occupied_cells(yaml_path: Path) -> set:
    g = read_map_yaml(yaml_path)
    rows, cols = np.nonzero(g.data == 100)
    i0 = round(g.origin[0] / g.resolution)
    j0 = round(g.origin[1] / g.resolution)
    return {(int(c) + i0, int(r) + j0) for r, c in zip(rows, cols)}


def run(args, plots: bool = False, **kw):
    """Invoke the CLI; replays skip plots (seconds each) unless a test asks for them."""
    args = list(args)
    if args and args[0] == "replay" and not plots and "--dump-config" not in args:
        args.append("--no-plots")
    return CliRunner().invoke(cli, args, catch_exceptions=False, **kw)


def assert_one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    err = [ln for ln in lines if ln.startswith("ltmap: error:")]
    assert len(err) == 1, result.output
    assert "Traceback" not in result.output
    for n in needles:
        assert n in err[0], err[0]


def no_temp_files(folder: Path) -> bool:
    return not [p for p in folder.rglob("*") if ".tmp" in p.name]


@pytest.mark.parametrize("fmt", FORMATS)
def test_walls_seen_17_s_are_in_the_map_to_the_cell(tmp_path, fmt):
    log = write_log(tmp_path / f"room{'.bag' if fmt == 'ros1' else '.mcap' if fmt.startswith('mcap') else ''}",
                    fmt, room_messages(0.0, 17.0, pillar=True))  # fmt: skip
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    assert report["frames_used"] == {"/scan": 85}
    assert report["frames_skipped"] == {}
    assert report["fixed_frame"] == "odom"
    must, may = expected_cells(pillar=True)
    occ = occupied_cells(out / "map.yaml")
    assert len(must) > 150
    assert must <= occ, sorted(must - occ)[:10]
    assert occ <= must | may, sorted(occ - must - may)[:10]
    # free between the robot and the walls, unknown outside the room
    g = read_map_yaml(out / "map.yaml")
    i0, j0 = round(g.origin[0] / R), round(g.origin[1] / R)
    assert g.data[math.floor(0.5 / R) - j0, math.floor(0.0 / R) - i0] == 0
    assert (g.data[:, : -41 - i0] == -1).all()  # x < -2.05: behind the wall, never seen
    for name in ("map.pgm", "map.yaml", "map.png", "long_term.yaml", "config.yaml", "snapshots/state_final.npz",
                 "snapshots/long_term_final.ot", "snapshots/long_term_final.ply"):  # fmt: skip
        assert (out / name).is_file(), name
    assert no_temp_files(out)


def test_walls_seen_less_than_st_rise_s_stay_out_of_the_map(tmp_path):
    log = write_log(tmp_path / "short.mcap", "mcap-ros2", room_messages(0.0, 10.0, pillar=False))
    out = tmp_path / "out"
    assert run(["replay", str(log), "-o", str(out), "-q"]).exit_code == 0
    assert occupied_cells(out / "map.yaml") == set()
    # ... but the same log with st_rise_s = 5 s puts them there
    out2 = tmp_path / "out2"
    r = run(["replay", str(log), "-o", str(out2), "-q", "--set", "map.layers.st_rise_s=5"])
    assert r.exit_code == 0
    must, _ = expected_cells(pillar=False)
    assert must <= occupied_cells(out2 / "map.yaml")
    assert "st_rise_s: 5.0" in (out2 / "config.yaml").read_text()


def test_missing_mount_fails_naming_the_transform_and_the_fix_then_tf_flag_fixes_it(tmp_path):
    log = write_log(tmp_path / "nomount.mcap", "mcap-ros2", room_messages(0.0, 17.0, True, static_mount=False))
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q"])
    assert_one_line_error(r, "every sensor frame was skipped", "base_link -> laser", "--tf base_link:laser=")
    assert not (out / "map.yaml").exists()
    r = run(["replay", str(log), "-o", str(out), "-q", "--tf", "base_link:laser=0.1,0,0.3,0,0,0"])
    assert r.exit_code == 0, r.output
    must, may = expected_cells(pillar=True)
    occ = occupied_cells(out / "map.yaml")
    assert must <= occ and occ <= must | may


def lt_occupied(out: Path) -> set:
    from ltmap_cli.io.state import read_state

    arrays, _ = read_state(out / "snapshots" / "state_final.npz")
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap

    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    return {tuple(k) for k in m.occupied_keys("LT").tolist()}


def test_resume_gives_the_same_long_term_map_as_one_run(tmp_path):
    # day 1: the pillar stands 17 s; day 2: it is gone for 13 s. LT must forget it either way.
    a = write_log(tmp_path / "a.mcap", "mcap-ros2", room_messages(0.0, 17.0, pillar=True))
    b = write_log(tmp_path / "b.mcap", "mcap-ros2", room_messages(17.0, 13.0, pillar=False, static_mount=True))
    one, day1, day2 = tmp_path / "one", tmp_path / "day1", tmp_path / "day2"
    assert run(["replay", str(a), str(b), "-o", str(one), "-q"]).exit_code == 0
    assert run(["replay", str(a), "-o", str(day1), "-q"]).exit_code == 0
    r = run(["replay", str(b), "-o", str(day2), "-q", "--resume", str(day1)])
    assert r.exit_code == 0, r.output
    day1_lt, day2_lt, one_lt = lt_occupied(day1), lt_occupied(day2), lt_occupied(one)
    pillar = {k for k in day1_lt if PILLAR[0] - R <= (k[0] + 0.5) * R <= PILLAR[2] + R
              and PILLAR[1] - R <= (k[1] + 0.5) * R <= PILLAR[3] + R}  # fmt: skip
    assert len(pillar) >= 3  # day 1 learned the pillar
    assert not (pillar & day2_lt) and not (pillar & one_lt)  # and both forgot it
    assert day2_lt == one_lt
    from ltmap_cli.io.state import read_state

    day1_arrays, _ = read_state(day1 / "snapshots" / "state_final.npz")
    n_lt = int((day1_arrays["D_lt"] > 0).sum())
    assert json.loads((day2 / "report.json").read_text())["resume"]["long_term_voxels"] == n_lt


def test_ot_snapshot_read_by_octomap_has_our_long_term_voxels(tmp_path):
    pyoctomap = pytest.importorskip("pyoctomap")
    log = write_log(tmp_path / "room.mcap", "mcap-ros2", room_messages(0.0, 17.0, pillar=True))
    out = tmp_path / "out"
    assert run(["replay", str(log), "-o", str(out), "-q"]).exit_code == 0
    ours = lt_occupied(out)
    assert len(ours) > 150
    tree = pyoctomap.OcTree(0.1).read(str(out / "snapshots" / "long_term_final.ot"))
    assert tree.getResolution() == pytest.approx(R)
    theirs = set()
    for it in tree.begin_leafs():
        if tree.isNodeOccupied(it):
            c = np.asarray(it.getCoordinate(), dtype=float)
            theirs.add(tuple(int(v) for v in np.floor(c / R)))
    assert theirs == ours


def test_resume_from_an_ot_snapshot_restores_the_long_term_map(tmp_path):
    log = write_log(tmp_path / "room.mcap", "mcap-ros2", room_messages(0.0, 17.0, pillar=True))
    out, out2 = tmp_path / "out", tmp_path / "out2"
    assert run(["replay", str(log), "-o", str(out), "-q"]).exit_code == 0
    short = write_log(tmp_path / "short.mcap", "mcap-ros2", room_messages(17.0, 2.0, pillar=True))
    r = run(["replay", str(short), "-o", str(out2), "-q", "--resume", str(out / "snapshots/long_term_final.ot")])
    assert r.exit_code == 0, r.output
    assert occupied_cells(out2 / "map.yaml") == occupied_cells(out / "map.yaml")


def pillar_removed_run(tmp_path: Path) -> Path:
    """The pillar stands 17 s (enters LT near 15 s), then is gone 13 s (seen free, LT falls from
    about 20 s to 23 s); snapshots every 3 s: t18 holds it in LT, t21 mid-fall, final without it."""
    a = write_log(tmp_path / "a.mcap", "mcap-ros2", room_messages(0.0, 17.0, pillar=True))
    b = write_log(tmp_path / "b.mcap", "mcap-ros2", room_messages(17.0, 13.0, pillar=False, static_mount=True))
    out = tmp_path / "out"
    assert run(["replay", str(a), str(b), "-o", str(out), "-q", "--snapshot-every", "3"]).exit_code == 0
    return out / "snapshots"


def _sorted_voxels(keys, logodds):
    order = np.lexsort(np.asarray(keys).T[::-1])
    return np.asarray(keys)[order], np.asarray(logodds, np.float32)[order]


def test_ot_snapshot_holds_free_space_so_diff_sees_the_removal_the_state_files_see(tmp_path):
    from ltmap_cli.io.state import read_state

    snaps = pillar_removed_run(tmp_path)

    def lt_columns(name):
        from ltmap_cli.core.config import MapConfig
        from ltmap_cli.core.layers import LayeredMap

        m = LayeredMap(MapConfig())
        m.load_state_arrays(read_state(snaps / f"state_{name}.npz")[0])
        return {(int(k[0]), int(k[1])) for k in m.occupied_keys("LT") if 1 <= k[2] <= 29}  # band [0.05, 1.5)

    with_pillar, without = lt_columns("t000018.0s"), lt_columns("final")
    gone = with_pillar - without
    assert without < with_pillar and len(gone) >= 3  # the pillar's seen face
    reps = {}
    for kind, a, b in (("ot", "long_term_t000018.0s.ot", "long_term_final.ot"),
                       ("npz", "state_t000018.0s.npz", "state_final.npz")):  # fmt: skip
        for extra in ((), ("--3d",)):
            r = CliRunner().invoke(cli, ["diff", str(snaps / a), str(snaps / b), "--json", *extra])
            assert r.exit_code == 1, r.output
            rep = json.loads(r.output)
            reps[kind, extra] = rep["voxels" if extra else "cells"]
    assert reps["ot", ()] == reps["npz", ()]
    assert reps["ot", ()]["removed"] == len(gone) and reps["ot", ()]["added"] == 0  # not "unknown-changed"
    assert reps["ot", ()]["unknown_changed"] == 0
    assert reps["ot", ("--3d",)] == reps["npz", ("--3d",)]
    assert reps["ot", ("--3d",)]["removed"] == len(gone)


def test_plan_on_an_ot_snapshot_takes_the_path_of_the_state_file(tmp_path):
    snaps = pillar_removed_run(tmp_path)
    outs = []
    for f in ("long_term_final.ot", "state_final.npz"):
        # to where the pillar stood: free once it was seen gone
        r = CliRunner().invoke(cli, ["plan", str(snaps / f), "--start", "1.2,0.5", "--goal", "-1.0,-1.0", "--json"])
        assert r.exit_code == 0, r.output
        outs.append(json.loads(r.output))
    assert outs[0]["path"] == outs[1]["path"] and outs[0]["length_m"] == outs[1]["length_m"] > 2.5
    for f in ("long_term_t000018.0s.ot", "state_t000018.0s.npz"):  # while it stood, neither plans into it
        r = CliRunner().invoke(cli, ["plan", str(snaps / f), "--start", "1.2,0.5", "--goal", "-1.0,-1.0"])
        assert r.exit_code == 2 and "goal (-1, -1) is within the robot radius of an obstacle" in r.output


def test_ot_snapshot_is_long_term_plus_free_space_and_octomap_reads_it(tmp_path):
    pyoctomap = pytest.importorskip("pyoctomap")
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.ot import read_ot
    from ltmap_cli.io.state import read_state
    from ltmap_cli.outputs.snapshots import lt_to_ot_logodds, read_snapshot_voxels

    snaps = pillar_removed_run(tmp_path)
    for name in ("t000018.0s", "t000021.0s", "final"):
        m = LayeredMap(MapConfig())
        m.load_state_arrays(read_state(snaps / f"state_{name}.npz")[0])
        lt_keys = m.D.voxels_where(m.D.channel("lt") > 0)
        lt = m.D.get("lt", lt_keys)
        o_free = m.O.voxels_where(m.O.channel("logodds") < 0)
        lt_set = {tuple(k) for k in lt_keys.tolist()}
        free_only = {tuple(k) for k in o_free.tolist()} - lt_set
        assert len(free_only) > 10 * len(lt_set)
        ot = snaps / f"long_term_{name}.ot"
        keys, logodds, res = read_ot(ot)
        assert res == R and len(keys) == len(lt_set) + len(free_only)
        got = dict(zip(map(tuple, keys.tolist()), logodds.tolist()))
        want = dict(zip(map(tuple, lt_keys.tolist()), lt_to_ot_logodds(lt, 0.65).tolist()))
        want.update(dict.fromkeys(free_only, float(lt_to_ot_logodds(0.0, 0.65))))
        assert got == want
        # a state .npz reads as the .ot written beside it, array for array
        nk, nl, nres = read_snapshot_voxels(snaps / f"state_{name}.npz")
        ok_, ol = _sorted_voxels(keys, logodds)
        nk_, nl = _sorted_voxels(nk, nl)
        assert nres == res
        np.testing.assert_array_equal(nk_, ok_)
        assert nl.tobytes() == ol.tobytes()
        # OctoMap: the same occupied and free voxels (one laser plane: nothing here to prune)
        tree = pyoctomap.OcTree(0.1).read(str(ot))
        occ, free = set(), set()
        for it in tree.begin_leafs():
            n = int(round(it.getSize() / R))
            base = [int(np.floor((c - it.getSize() / 2) / R + 0.5)) for c in it.getCoordinate()]
            cube = {(base[0] + a, base[1] + b, base[2] + c) for a in range(n) for b in range(n) for c in range(n)}
            (occ if tree.isNodeOccupied(it) else free).update(cube)
        assert occ == {k for k, v in want.items() if v > 0}
        assert free == {k for k, v in want.items() if v < 0}
        if name == "t000021.0s":  # the pillar mid-fall: LT between 0 and 0.65 is free for OctoMap too
            assert any(0 < v < 0.65 for v in lt.tolist())


def test_resume_from_an_ot_snapshot_equals_resume_from_its_state_file(tmp_path):
    """The free leaves seed nothing: LT after --resume is the same voxels and values from the .ot
    as from the .npz (t21: the pillar's LT mid-fall, 0 < LT < 1)."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.ot import read_ot
    from ltmap_cli.outputs.snapshots import load_resume

    snaps = pillar_removed_run(tmp_path)
    for name in ("t000021.0s", "final"):
        seeded = []
        for f in (f"long_term_{name}.ot", f"state_{name}.npz"):
            m = LayeredMap(MapConfig())
            info = load_resume(m, snaps / f)
            keys = m.D.voxels_where(m.D.channel("lt") > 0)
            seeded.append((info["long_term_voxels"], *_sorted_voxels(keys, m.D.get("lt", keys))))
        (n_ot, k_ot, v_ot), (n_npz, k_npz, v_npz) = seeded
        assert n_ot == n_npz == len(k_ot) > 150
        np.testing.assert_array_equal(k_ot, k_npz)
        assert v_ot.tobytes() == v_npz.tobytes()
        assert len(read_ot(snaps / f"long_term_{name}.ot")[0]) > 10 * n_ot  # the free leaves it skipped
        if name == "t000021.0s":
            assert ((v_ot > 0) & (v_ot < 1)).sum() >= 3


# ------------------------------------------------------------------------------ bad input


def test_missing_path(tmp_path):
    r = run(["replay", str(tmp_path / "nope.mcap"), "-o", str(tmp_path / "o")])
    assert_one_line_error(r, "nope.mcap")


def test_empty_file(tmp_path):
    p = tmp_path / "empty.bag"
    p.write_bytes(b"")
    assert_one_line_error(run(["replay", str(p), "-o", str(tmp_path / "o")]), "empty.bag")


def test_not_a_log(tmp_path):
    p = tmp_path / "notes.mcap"
    p.write_text("these are my notes, not a log\n" * 20)
    assert_one_line_error(run(["replay", str(p), "-o", str(tmp_path / "o")]), "notes.mcap")


def test_truncated_log_fails_unless_allowed(tmp_path):
    log = write_log(tmp_path / "cut.mcap", "mcap-ros2", room_messages(0.0, 17.0, True), chunk_size=20_000)
    truncate(log, 0.6)
    out = tmp_path / "o"
    assert_one_line_error(run(["replay", str(log), "-o", str(out), "-q"]), "cut.mcap", "--allow-truncated")
    assert not (out / "map.yaml").exists() and no_temp_files(tmp_path)
    r = run(["replay", str(log), "-o", str(out), "-q", "--allow-truncated"])
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    assert report["stopped_at"] and "cut.mcap" in report["stopped_at"]
    assert 0 < report["frames_used"]["/scan"] < 85


def test_a_failed_run_leaves_the_folder_as_it_was(tmp_path):
    """A run that fails after writing periodic snapshots (the log is cut at 60 %) leaves the
    earlier run's snapshots/ byte for byte; a failed run into a new folder leaves no folder."""
    good = write_log(tmp_path / "good.mcap", "mcap-ros2", room_messages(0.0, 17.0, True), chunk_size=20_000)
    cut = write_log(tmp_path / "cut.mcap", "mcap-ros2", room_messages(0.0, 17.0, True), chunk_size=20_000)
    truncate(cut, 0.6)
    out = tmp_path / "o"
    assert run(["replay", str(good), "-o", str(out), "-q", "--snapshot-every", "5"]).exit_code == 0

    def snapshot_files():
        return {p.name: p.read_bytes() for p in sorted((out / "snapshots").iterdir())}

    before = snapshot_files()
    assert "state_t000005.0s.npz" in before and "state_final.npz" in before
    assert_one_line_error(run(["replay", str(cut), "-o", str(out), "-q", "--snapshot-every", "2"]), "cut.mcap")
    assert snapshot_files() == before
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []
    # a successful rerun replaces the snapshots: only this run's remain
    assert run(["replay", str(good), "-o", str(out), "-q", "--snapshot-every", "8"]).exit_code == 0
    assert sorted(n for n in snapshot_files() if n.startswith("state")) == [
        "state_final.npz", "state_t000008.0s.npz", "state_t000016.0s.npz"]
    new = tmp_path / "new"
    assert_one_line_error(run(["replay", str(cut), "-o", str(new), "-q"]), "cut.mcap")
    assert not new.exists()


def test_output_path_that_cannot_be_a_folder(tmp_path):
    log = write_log(tmp_path / "good.mcap", "mcap-ros2", room_messages(0.0, 2.0, False))
    (tmp_path / "afile").write_text("x")
    for o in (tmp_path / "afile", tmp_path / "afile" / "sub"):
        assert_one_line_error(run(["replay", str(log), "-o", str(o), "-q"]), f"-o {o}: ",
                              f"{tmp_path / 'afile'} is a file, not a folder" if o.name == "sub" else "is a file",
                              "choose another output folder")


def test_a_sensor_topic_left_out_is_said_on_the_console(tmp_path):
    msgs = room_messages(0.0, 2.0, False) + [
        image("/cam/depth/image_raw", T0 + 10**8, np.ones((3, 4), np.uint16) * 1000)]
    msgs.sort(key=lambda m: m.log_time_ns)
    log = write_log(tmp_path / "l.mcap", "mcap-ros2", msgs)
    r = run(["replay", str(log), "-o", str(tmp_path / "o"), "-q"])
    assert r.exit_code == 0, r.output
    # (a 2 s log also gets the hint that its long-term map is nearly empty: analysis.hints)
    warn = [ln for ln in r.output.splitlines() if ln.startswith("ltmap: warning:") and "st_rise_s" not in ln]
    assert len(warn) == 1 and "/cam/depth/image_raw not used: depth Image without CameraInfo" in warn[0]
    r = run(["replay", str(log), "-o", str(tmp_path / "o2"), "-q", "--scan-topic", "/scan"])
    assert r.exit_code == 0
    assert [ln for ln in r.output.splitlines() if "warning" in ln and "st_rise_s" not in ln] == []  # on purpose


def test_raw_and_negated_maps_read_back_as_the_trinary_one(tmp_path):
    log = write_log(tmp_path / "l.mcap", "mcap-ros2", room_messages(0.0, 17.0, True))  # 15 s to enter LT
    cells = {}
    for name, extra in (("trinary", []), ("raw", ["--mode", "raw"]), ("neg", ["--set", "replay.negate=true"]),
                        ("rawneg", ["--mode", "raw", "--set", "replay.negate=true"])):
        assert run(["replay", str(log), "-o", str(tmp_path / name), "-q", *extra]).exit_code == 0
        cells[name] = occupied_cells(tmp_path / name / "map.yaml")
    must, _ = expected_cells(True)
    assert must <= cells["trinary"] and cells["raw"] == cells["neg"] == cells["rawneg"] == cells["trinary"]
    assert "mode: raw" in (tmp_path / "raw" / "map.yaml").read_text()
    r = run(["replay", str(log), "-o", str(tmp_path / "x"), "--set", "map.projection.occupied_thresh=1.0"])
    assert_one_line_error(r, "occupied_thresh 1.0")
    assert not (tmp_path / "x").exists()


def test_no_usable_topic_lists_what_is_there(tmp_path):
    log = write_log(tmp_path / "chat.mcap", "mcap-ros2",
                    [string("/chatter", T0, "hello"), tf(T0, [("odom", "base_link")])])  # fmt: skip
    assert_one_line_error(run(["replay", str(log), "-o", str(tmp_path / "o")]), "/chatter")


def test_unsupported_depth_encoding(tmp_path):
    msgs = [camera_info("/camera/depth/camera_info", T0, width=4, height=3, fx=2, fy=2, cx=2, cy=1.5),
            image("/camera/depth/image_raw", T0 + 1, np.zeros((3, 4, 3), np.uint8), encoding="rgb8"),
            tf(T0, [("odom", "base_link")])]  # fmt: skip
    log = write_log(tmp_path / "rgb.mcap", "mcap-ros2", msgs)
    assert_one_line_error(run(["replay", str(log), "-o", str(tmp_path / "o")]), "rgb8", "/camera/depth/image_raw")


def test_depth_without_camera_info(tmp_path):
    msgs = [image("/camera/depth/image_raw", T0 + 1, np.ones((3, 4), np.uint16) * 1000, encoding="16UC1"),
            tf(T0, [("odom", "base_link")])]  # fmt: skip
    log = write_log(tmp_path / "noinfo.mcap", "mcap-ros2", msgs)
    assert_one_line_error(run(["replay", str(log), "-o", str(tmp_path / "o")]), "CameraInfo")


def test_debug_shows_the_traceback_with_the_same_status(tmp_path):
    r = CliRunner().invoke(cli, ["--debug", "replay", str(tmp_path / "nope.mcap")])
    assert r.exit_code == 2
    assert "Traceback (most recent call last)" in r.stderr
    assert r.stderr.rstrip().splitlines()[-1].startswith("ltmap: error: log not found:")


def test_dump_config_and_config_file_round_trip(tmp_path):
    r = run(["replay", "--dump-config", "--tick", "0.1", "--set", "map.layers.lt_fall_s=5"])
    assert r.exit_code == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_text(r.output)
    r2 = run(["replay", "--dump-config", "--config", str(cfg)])
    assert r2.output == r.output
    assert "tick: 0.1" in r.output and "lt_fall_s: 5.0" in r.output
    r3 = run(["replay", "--dump-config", "--set", "map.layers.nope=1"])
    assert_one_line_error(r3, "map.layers.nope")


def test_replay_of_a_time_window(tmp_path):
    """``--start`` / ``--end`` (s of log time from the log's first message): the sensor frames
    logged in the window are mapped, with the poses and calibration from before it; the report's
    duration and speed are the window's; a window outside the log is one line, status 2."""
    from ltmap_cli.io.logs import open_logs

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    s = 1_000_000_000
    with open_logs(log) as logs:
        t0 = logs.start_ns
        scans = [t for _, t, _, _ in logs.raw(["/scan"]) if t0 + 10 * s <= t <= t0 + 20 * s]
    out = tmp_path / "w"
    r = run(["replay", str(log), "-o", str(out), "-q", "--start", "10", "--end", "20"])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["window"] == {"start_s": 10.0, "end_s": 20.0}
    assert rep["log_duration_s"] == 10.0 and rep["frames_used"] == {"/scan": len(scans)} and not rep["frames_skipped"]
    assert "replayed 10.0 s of log" in r.stdout
    assert "the window mapped (--start / --end) lasts 10.0 s, shorter than" in r.stderr  # LT's rise needs 15 s
    for args, words in ((["--start", "99"], ["--start 99 s is past the end", "it lasts"]),
                        (["--start", "5", "--end", "5"], ["replay.end_s (5 s) must be after replay.start_s"]),
                        (["--end", "-1"], ["must be >= 0"])):
        bad = CliRunner().invoke(cli, ["replay", str(log), "-o", str(tmp_path / "bad"), "-q", "--no-plots", *args])
        assert bad.exit_code == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.output
        assert all(w in bad.stderr for w in words), bad.stderr
        assert not (tmp_path / "bad" / "report.json").exists()


def test_an_interrupted_replay_writes_the_map_of_the_log_read_so_far(tmp_path):
    """``Replay.interrupt`` (the CLI's first Ctrl-C): reading stops, the frames taken are mapped
    (those waiting for their pose get the tf logged up to ``tf_wait`` later, nothing skipped),
    the last tick ends and the outputs are written as for the log ending there: the same frames
    and the same arrays as ``--end`` at that time; report.json says where it stopped."""
    from ltmap_cli.config import Config
    from ltmap_cli.io.state import read_state
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    s = 1_000_000_000

    class StopAt12(Replay):  # interrupted once 12 s of log were read, as a signal handler would
        def _report_progress(self, log_ns, force=False, phase=None):
            if log_ns is not None and log_ns - self.state.log_start_ns >= 12 * s:
                self.interrupt()
            super()._report_progress(log_ns, force, phase)

    cfg = Config()
    cfg.replay.plots = False
    (tmp_path / "a").mkdir()
    stopped_run = StopAt12(cfg, ReplayRequest([log], tmp_path / "a"))
    rep = stopped_run.run()
    assert not stopped_run.whole_log_read  # (the CLI's Ctrl-C handler says what it stopped by this)
    stop = rep["interrupted_at_s"]
    assert 12.0 <= stop < 12.1 and rep["log_duration_s"] == stop and not rep["frames_skipped"], rep
    cfg2 = Config()
    cfg2.replay.plots = False
    cfg2.replay.end_s = stop + 0.0005  # (the report rounds to the ms)
    (tmp_path / "b").mkdir()
    ref_run = Replay(cfg2, ReplayRequest([log], tmp_path / "b"))
    ref = ref_run.run()
    assert ref_run.whole_log_read  # (all of its window)
    assert rep["frames_used"] == ref["frames_used"] and rep["ticks"] == ref["ticks"]
    assert ref["interrupted_at_s"] is None
    a, _ = read_state(tmp_path / "a" / "snapshots" / "state_final.npz")
    b, _ = read_state(tmp_path / "b" / "snapshots" / "state_final.npz")
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), [k for k in a if not np.array_equal(a[k], b[k])]
    assert (tmp_path / "a" / "map.pgm").read_bytes() == (tmp_path / "b" / "map.pgm").read_bytes()


def test_an_interrupt_before_any_frame_writes_nothing_and_ends_the_localization_pass(tmp_path):
    """Ctrl-C during --localize's pre-pass (a pass over the whole log before mapping) ends the
    pass too; with no frame mapped the run is RunInterrupted (exit status 130), nothing written."""
    from ltmap_cli.config import Config
    from ltmap_cli.errors import RunInterrupted
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    cfg = Config()
    cfg.replay.plots = False
    cfg.replay.localize = True
    (tmp_path / "o").mkdir()
    run = Replay(cfg, ReplayRequest([log], tmp_path / "o"))
    run.interrupt()  # (as the first Ctrl-C would, before the pass began)
    with pytest.raises(RunInterrupted, match="interrupted before any sensor frame"):
        run.run()
    assert run.localization is not None and run.localization.summary["scans"] == 0
    assert RunInterrupted.exit_code == 130 and not (tmp_path / "o" / "report.json").exists()
