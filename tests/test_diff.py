"""`ltmap diff`: alignment, counts and areas on hand-made maps, tolerance, exit statuses, PNG."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from mapfactory import write_trinary

from ltmap_cli.analysis import cell_to_world, load_grid, project_voxels, world_to_cell
from ltmap_cli.analysis.diff import align, diff_maps, diff_voxels
from ltmap_cli.cli import cli
from ltmap_cli.errors import InputError, MapFileError
from ltmap_cli.io.mapfile import GridMap
from ltmap_cli.outputs.folder import OutputFolder

A_ = 0.05 * 0.05  # m^2 of a 0.05 m cell


def base_map() -> np.ndarray:
    """10 rows x 20 cols, free, with a 1 x 8 wall on row 5 (cols 4..11)."""
    d = np.zeros((10, 20), dtype=np.int8)
    d[5, 4:12] = 100
    return d


def run(*args):
    return CliRunner().invoke(cli, ["diff", *map(str, args)])


# ---------------------------------------------------------------------------------------------
# counts, areas, exit statuses


def test_identical_maps_exit_0(tmp_path):
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", base_map())
    r = run(a, b)
    assert r.exit_code == 0, r.output
    assert "result: same" in r.output
    assert "IoU (occupied)        1.0000" in r.output


def test_known_differences_counts_and_area(tmp_path):
    a_data = base_map()
    a_data[0:2, 0:3] = -1  # 6 unknown cells in A
    b_data = base_map()
    b_data[5, 10:12] = 0  # 2 wall cells removed (occupied -> free)
    b_data[5, 4] = -1  # 1 wall cell becomes unknown: unknown-changed, not removed
    b_data[2, 15:18] = 100  # 3 cells added (free -> occupied)
    b_data[0, 0] = 100  # 1 cell added (unknown -> occupied): added, not unknown-changed
    b_data[8, 0:4] = -1  # 4 free cells become unknown
    a = write_trinary(tmp_path / "a.yaml", a_data)
    b = write_trinary(tmp_path / "b.yaml", b_data)
    r = run(a, b, "--json")
    assert r.exit_code == 1, r.output
    rep = json.loads(r.output)
    c = rep["cells"]
    assert c["added"] == 4
    assert c["removed"] == 2
    # 5 still-unknown-in-A cells now free in B, 1 wall cell -> unknown, 4 free -> unknown
    assert c["unknown_changed"] == 5 + 1 + 4
    assert c["unchanged_occupied"] == 5
    assert c["occupied_a"] == 8 and c["occupied_b"] == 5 + 4
    assert rep["m2"]["added"] == pytest.approx(4 * A_, abs=1e-12)
    assert rep["m2"]["removed"] == pytest.approx(2 * A_, abs=1e-12)
    assert rep["m2"]["unknown_changed"] == pytest.approx(10 * A_, abs=1e-12)
    assert rep["iou"] == pytest.approx(5 / 12)
    assert rep["same"] is False
    assert rep["size_cells"] == [20, 10]

    # the text table says the same
    r = run(a, b)
    assert r.exit_code == 1
    lines = {ln.split()[0]: ln.split() for ln in r.output.splitlines() if ln.strip()}
    assert lines["added"][1:] == ["4", "0.0100"]
    assert lines["removed"][1:] == ["2", "0.0050"]
    assert lines["unknown-changed"][1:] == ["10", "0.0250"]
    assert "result: maps differ (4 added, 2 removed)" in r.output


def test_only_unknown_changes_is_same(tmp_path):
    b_data = base_map()
    b_data[0:3, :] = -1
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", b_data)
    r = run(a, b, "--json")
    assert r.exit_code == 0
    assert json.loads(r.output)["cells"]["unknown_changed"] == 60


def test_shifted_origin_compensates(tmp_path):
    # B's content is A's moved 3 cells left, and B's origin 3 cells right: the same world map
    b_data = np.zeros((10, 20), dtype=np.int8)
    b_data[5, 1:9] = 100
    a = write_trinary(tmp_path / "a.yaml", base_map(), origin=(-1.0, 2.0, 0.0))
    b = write_trinary(tmp_path / "b.yaml", b_data, origin=(-1.0 + 3 * 0.05, 2.0, 0.0))
    r = run(a, b, "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["cells"]["added"] == 0 and rep["cells"]["removed"] == 0
    assert rep["cells"]["unchanged_occupied"] == 8
    assert rep["size_cells"] == [23, 10]  # union extent
    assert rep["origin"][:2] == pytest.approx([-1.0, 2.0])
    assert rep["cells"]["unknown_changed"] == 2 * 3 * 10  # the 3-column strips only one map covers
    assert rep["notes"] == []
    assert rep["iou"] == 1.0


def test_different_sizes(tmp_path):
    # B is 6 cells wider and 2 taller; its extra area holds a 2 x 2 box; the wall is unchanged
    b_data = np.zeros((12, 26), dtype=np.int8)
    b_data[5, 4:12] = 100
    b_data[10:12, 22:24] = 100
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", b_data)
    rep = json.loads(run(a, b, "--json").output)
    assert rep["size_cells"] == [26, 12]
    assert rep["cells"]["added"] == 4
    assert rep["cells"]["removed"] == 0
    assert rep["cells"]["unknown_changed"] == 26 * 12 - 20 * 10 - 4
    # swapped: the box is occupied in A and unknown in B: unknown-changed, not removed
    r = run(b, a, "--json")
    rep = json.loads(r.output)
    assert r.exit_code == 0
    assert rep["cells"]["removed"] == 0 and rep["cells"]["unknown_changed"] == 26 * 12 - 20 * 10


def test_resolution_mismatch_needs_resample(tmp_path):
    # B at 0.1 m: its cell (row 2, col 1..3) covers x 0.1..0.4, y 0.2..0.3 = A cells rows 4-5, cols 2..7
    coarse = np.zeros((5, 10), dtype=np.int8)
    coarse[2, 1:4] = 100
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", coarse, resolution=0.1)
    r = run(a, b)
    assert r.exit_code == 2
    assert "--resample" in r.output and "0.1 m" in r.output and r.output.startswith("ltmap: error:")
    assert len(r.output.strip().splitlines()) == 1

    r = run(a, b, "--resample", "--json")
    assert r.exit_code == 1
    rep = json.loads(r.output)
    assert rep["resolution"] == 0.05
    assert any("resampled from 0.1 m to 0.05 m" in n for n in rep["notes"])
    # B occupies rows 4,5 x cols 2..7 (12 cells); A's wall row 5 cols 4..11
    assert rep["cells"]["unchanged_occupied"] == 4  # row 5, cols 4..7
    assert rep["cells"]["added"] == 12 - 4
    assert rep["cells"]["removed"] == 4  # row 5, cols 8..11
    assert rep["m2"]["added"] == pytest.approx(8 * A_, abs=1e-12)


def test_coarse_first_map_is_resampled_to_the_finer_second(tmp_path):
    coarse = np.zeros((5, 10), dtype=np.int8)
    coarse[2, 1:4] = 100
    fine = np.zeros((10, 20), dtype=np.int8)
    fine[4:6, 2:8] = 100  # exactly the coarse cells
    a = write_trinary(tmp_path / "a.yaml", coarse, resolution=0.1)
    b = write_trinary(tmp_path / "b.yaml", fine)
    r = run(a, b, "--resample", "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["reference"] == "B" and rep["cells"]["unchanged_occupied"] == 12


def test_non_integer_origin_offset_is_resampled_and_said(tmp_path):
    # B's origin is 3.4 cells right of A's: B's cell c covers A-lattice x in [c+3.4, c+4.4);
    # the A-cell centre c'+0.5 falls in B's cell c = c' - 3 (the nearest B centre, c + 3.9).
    # B's wall at cols 1..8 -> A cols 4..11 = A's wall: no change.
    b_data = np.zeros((10, 20), dtype=np.int8)
    b_data[5, 1:9] = 100
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", b_data, origin=(3.4 * 0.05, 0.0, 0.0))
    r = run(a, b)
    assert r.exit_code == 0, r.output
    assert "not a whole number: resampled" in r.output


def test_tolerance_is_euclidean(tmp_path):
    shifted = np.zeros((10, 20), dtype=np.int8)
    shifted[6, 4:12] = 100  # the wall one row up
    diag = np.zeros((10, 20), dtype=np.int8)
    diag[6, 5:13] = 100  # one row up and one column right
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", shifted)
    c = write_trinary(tmp_path / "c.yaml", diag)
    rep = json.loads(run(a, b, "--json").output)
    assert rep["cells"]["added"] == 8 and rep["cells"]["removed"] == 8
    r = run(a, b, "--tolerance", "1", "--json")
    assert r.exit_code == 0
    rep = json.loads(r.output)
    assert rep["cells"]["added"] == 0 and rep["cells"]["added_within_tolerance"] == 8
    assert rep["cells"]["removed_within_tolerance"] == 8 and rep["tolerance_metric"] == "euclidean"
    # diagonal shift: the end cells are sqrt(2) away from the other wall, so tolerance 1 keeps
    # one added (row 6 col 12) and one removed (row 5 col 4); tolerance 2 ignores all
    rep = json.loads(run(a, c, "--tolerance", "1", "--json").output)
    assert rep["cells"]["added"] == 1 and rep["cells"]["removed"] == 1
    assert run(a, c, "--tolerance", "1").exit_code == 1
    assert run(a, c, "--tolerance", "2").exit_code == 0


def test_png_overlay(tmp_path):
    b_data = base_map()
    b_data[2, 15:18] = 100
    b_data[5, 10:12] = 0
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", b_data)
    png = tmp_path / "out" / "diff.png"
    r = run(a, b, "--png", png)
    assert r.exit_code == 1
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    with Image.open(png) as im:
        im.verify()
    with Image.open(png) as im:
        rgb = np.asarray(im.convert("RGB"))
    # red (added) and green (removed) pixels are there
    assert ((rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)).any()
    assert ((rgb[..., 1] > 140) & (rgb[..., 0] < 60) & (rgb[..., 2] < 60)).any()
    assert not list(png.parent.glob(".*tmp*"))  # no temporary file left behind


def completed_replay_folder(path, grid=None):
    """A folder as a completed replay leaves it (manifest written last), holding map.yaml."""
    with OutputFolder(path, command="replay") as out:
        if grid is not None:
            write_trinary(out.staging / "map.yaml", grid)
        out.commit()
    return path


def test_replay_folder_and_bad_inputs(tmp_path):
    completed_replay_folder(tmp_path / "run1", base_map())
    b = write_trinary(tmp_path / "b.yaml", base_map())
    assert run(tmp_path / "run1", b).exit_code == 0

    # a folder whose run did not complete (no manifest) is not read, even with a map.yaml in it
    write_trinary(tmp_path / "half" / "map.yaml", base_map())
    for folder in ("half", "empty"):
        (tmp_path / folder).mkdir(exist_ok=True)
        r = run(tmp_path / folder, b)
        assert r.exit_code == 2 and f"A {tmp_path / folder}: not a completed ltmap output" in r.output
        assert len(r.output.strip().splitlines()) == 1
    completed_replay_folder(tmp_path / "nomap")
    r = run(tmp_path / "nomap", b)
    assert r.exit_code == 2 and "no map.yaml" in r.output and "A " in r.output

    npz = tmp_path / "state.npz"
    np.savez(npz, x=np.zeros(1))
    r = run(b, npz)
    assert r.exit_code == 2 and "no ltmap state header" in r.output and "state.npz" in r.output

    r = run(b, tmp_path / "missing.yaml")
    assert r.exit_code == 2 and "missing.yaml" in r.output and "Traceback" not in r.output

    (tmp_path / "x.txt").write_text("hello")
    r = run(b, tmp_path / "x.txt")
    assert r.exit_code == 2 and "unknown kind of file" in r.output

    r = run(b, b, "--3d")
    assert r.exit_code == 2 and ".ot" in r.output


# ---------------------------------------------------------------------------------------------
# library level


def test_yaw_is_honoured():
    a = GridMap(base_map(), 0.05, (0.0, 0.0, 0.0))
    # the same world map stored with yaw pi/2: B[r', c'] = A[c', W_A - 1 - r']
    b = GridMap(np.ascontiguousarray(base_map().T[::-1]), 0.05, (20 * 0.05, 0.0, math.pi / 2))
    d = diff_maps(a, b)
    c = d.counts()
    assert c["added"] == 0 and c["removed"] == 0 and c["unknown_changed"] == 0
    assert c["unchanged_occupied"] == 8
    assert d.aligned.a.shape == (10, 20)
    assert any("yaw" in n for n in d.aligned.notes)


def test_world_cell_round_trip_with_yaw():
    g = GridMap(np.zeros((4, 6), np.int8), 0.1, (1.0, 2.0, math.pi / 2))
    # cell (row 1, col 2): local centre (0.25, 0.15) -> world (1 - 0.15, 2 + 0.25)
    x, y = cell_to_world(g, 1, 2)
    assert (x, y) == pytest.approx((0.85, 2.25))
    assert world_to_cell(g, x, y) == (1, 2)
    g0 = GridMap(np.zeros((4, 6), np.int8), 0.05, (-1.0, 2.0, 0.0))
    assert world_to_cell(g0, -0.999, 2.001) == (0, 0)
    assert world_to_cell(g0, -1.001, 2.001) == (0, -1)


def test_align_puts_each_map_where_it_belongs():
    a = GridMap(np.full((2, 2), 100, np.int8), 1.0, (0.0, 0.0, 0.0))
    b = GridMap(np.zeros((1, 1), np.int8), 1.0, (3.0, -1.0, 0.0))
    al = align(a, b)
    assert al.a.shape == (3, 4) and al.origin == pytest.approx((0.0, -1.0, 0.0))
    assert (al.a[1:3, 0:2] == 100).all() and (al.a[0] == -1).all() and (al.a[:, 2:] == -1).all()
    assert al.b[0, 3] == 0 and (al.b >= 0).sum() == 1


def test_resolution_error_is_input_error():
    a = GridMap(np.zeros((2, 2), np.int8), 0.05)
    b = GridMap(np.zeros((2, 2), np.int8), 0.1)
    with pytest.raises(InputError, match="--resample"):
        align(a, b)


def test_project_voxels_band_and_classes():
    res = 0.05
    keys = np.array(
        [
            [0, 0, 0],  # [0, 0.05): below the band (touches it with zero length) -> ignored
            [1, 0, 1],  # [0.05, 0.10): in the band, free
            [1, 0, 5],  # occupied in the same column -> occupied
            [2, 1, 29],  # [1.45, 1.50): in the band, occupied
            [3, 1, 30],  # [1.50, 1.55): above -> ignored
            [3, 2, 10],  # free only -> free
            [-1, 2, -3],  # below the floor -> ignored
        ]
    )
    lo = np.array([2.0, -1.0, 0.5, 0.1, 3.0, -0.2, 3.0], dtype=np.float32)
    g = project_voxels(keys, lo, res)
    assert g.origin == pytest.approx((0.05, 0.0, 0.0))  # columns i 1..3, j 0..2
    assert g.data.shape == (3, 3)
    expect = np.array([[100, -1, -1], [-1, 100, -1], [-1, -1, 0]], dtype=np.int8)
    np.testing.assert_array_equal(g.data, expect)


def test_ot_snapshots_projected_and_3d(tmp_path):
    from ltmap_cli.io.ot import write_ot

    res = 0.1
    # A: a 3-voxel wall at k = 4 ([0.4, 0.5) m, in the band) over free floor voxels at k = 1
    floor = [[i, j, 1] for i in range(4) for j in range(2)]
    wall = [[1, 0, 4], [2, 0, 4], [3, 0, 4]]
    ka = np.array(floor + wall)
    la = np.array([-1.0] * len(floor) + [2.0] * len(wall), np.float32)
    # B: the wall voxel (3,0,4) is gone (seen free), a voxel at k = 20 (2.0 m, above the band)
    # and a table top at (0,1,7) appear
    kb = np.array(floor + [[1, 0, 4], [2, 0, 4], [3, 0, 4], [2, 1, 20], [0, 1, 7]])
    lb = np.array([-1.0] * len(floor) + [2.0, 2.0, -1.0, 2.0, 2.0], np.float32)
    write_ot(tmp_path / "a.ot", ka, la, res)
    write_ot(tmp_path / "b.ot", kb, lb, res)

    r = run(tmp_path / "a.ot", tmp_path / "b.ot", "--json")
    assert r.exit_code == 1, r.output
    rep = json.loads(r.output)
    assert rep["resolution"] == pytest.approx(0.1)
    assert rep["cells"]["added"] == 1  # (0, 1): the table top; the k = 20 voxel is out of the band
    assert rep["cells"]["removed"] == 1  # column (3, 0)
    assert rep["cells"]["unchanged_occupied"] == 2
    assert rep["m2"]["added"] == pytest.approx(0.01)

    r = run(tmp_path / "a.ot", tmp_path / "b.ot", "--3d", "--json")
    assert r.exit_code == 1, r.output
    rep = json.loads(r.output)
    v = rep["voxels"]
    assert v["added"] == 2 and v["removed"] == 1 and v["unchanged_occupied"] == 2
    assert v["unknown_changed"] == 0  # the two new voxels are added, not unknown-changed
    assert rep["iou"] == pytest.approx(2 / 5)
    assert rep["m3"]["added"] == pytest.approx(0.002)
    # text output and a same-map comparison
    r = run(tmp_path / "a.ot", tmp_path / "a.ot", "--3d")
    assert r.exit_code == 0 and "result: same" in r.output
    # --z-band moves the projection band: with [1.9, 2.5] only the k = 20 voxel of B counts
    rep = json.loads(run(tmp_path / "a.ot", tmp_path / "b.ot", "--z-band", "1.9", "2.5", "--json").output)
    assert rep["cells"]["added"] == 1 and rep["cells"]["occupied_a"] == 0


def test_load_grid_npz_message(tmp_path):
    p = tmp_path / "s.npz"
    p.write_bytes(b"x")
    with pytest.raises(MapFileError, match="not a readable ltmap state file"):
        load_grid(p)


def test_state_snapshot_projects_to_the_replays_long_term_map(tmp_path):
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.state import write_state

    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([[3, 4, 10], [3, 5, 10], [8, 8, 0], [9, 9, 40]]), 1.0)  # k=0, 40: off band
    write_state(tmp_path / "state_final.npz", m.state_arrays(), {})
    g = load_grid(tmp_path / "state_final.npz")
    rows, cols = np.nonzero(g.data == 100)
    i0, j0 = round(g.origin[0] / g.resolution), round(g.origin[1] / g.resolution)
    assert {(int(c) + i0, int(r) + j0) for r, c in zip(rows, cols)} == {(3, 4), (3, 5)}
    assert g.resolution == pytest.approx(0.05)


def test_diff_voxels_counts_iou_and_tolerance():
    ka = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5], [9, 9, 9]])
    la = np.array([1, 1, 1, 1, -1], np.float32)  # 4 occupied, 1 free
    kb = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 6], [9, 9, 9], [7, 7, 7]])
    lb = np.array([1, 1, -1, 1, 1, -1], np.float32)
    d = diff_voxels(ka, la, kb, lb, 0.1)
    c = d.counts
    assert c["unchanged_occupied"] == 2
    assert c["removed"] == 1  # (2,0,0) occupied -> free; (5,5,5) occupied -> unknown is not removed
    assert c["added"] == 2  # (5,5,6) unknown -> occupied, (9,9,9) free -> occupied
    # known <-> unknown: (5,5,5) and (7,7,7); (5,5,6) is added, not counted here
    assert c["unknown_changed"] == 2
    assert d.iou == pytest.approx(2 / 6)
    assert not d.same
    d1 = diff_voxels(ka, la, kb, lb, 0.1, tolerance=1)
    # (5,5,6) is 1 voxel from A's (5,5,5); (9,9,9) is far; (2,0,0) is 1 from B's (1,0,0)
    assert d1.counts["added"] == 1 and d1.counts["added_within_tolerance"] == 1
    assert d1.counts["removed"] == 0 and d1.counts["removed_within_tolerance"] == 1


def test_3d_on_state_files_and_folders_equals_3d_on_their_ot(tmp_path):
    """--3d reads exact-state snapshots (and a replay folder's final state) as the .ot written
    beside them: the same counts, by hand: B loses one wall voxel and gains two."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.outputs.snapshots import write_snapshot

    wall = [[i, 0, 10] for i in range(6)]
    for name, keys in (("a", wall), ("b", wall[1:] + [[0, 3, 10], [0, 4, 12]])):
        m = LayeredMap(MapConfig())
        m.seed_long_term(np.array(keys), 1.0)
        with OutputFolder(tmp_path / name, command="replay") as out:
            write_snapshot(m, out.staging / "snapshots", None, {})
            out.commit()
    reps = []
    for a, b in (
        (tmp_path / "a/snapshots/long_term_final.ot", tmp_path / "b/snapshots/long_term_final.ot"),
        (tmp_path / "a/snapshots/state_final.npz", tmp_path / "b/snapshots/state_final.npz"),
        (tmp_path / "a", tmp_path / "b"),
    ):
        r = run(a, b, "--3d", "--json")
        assert r.exit_code == 1, r.output
        reps.append(json.loads(r.output)["voxels"])
    assert reps[0] == reps[1] == reps[2]
    # wall voxel (0,0,10) is absent from B's snapshot (unknown there): not "removed", not kept
    assert reps[0]["added"] == 2 and reps[0]["unchanged_occupied"] == 5 and reps[0]["occupied_a"] == 6


def test_maps_far_apart_are_refused_with_the_memory_they_would_need(tmp_path):
    a = write_trinary(tmp_path / "a.yaml", base_map())
    b = write_trinary(tmp_path / "b.yaml", base_map(), origin=(1e6, 0.0, 0.0))
    r = run(a, b)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "GB" in r.output and "same frame" in r.output and len(r.output.strip().splitlines()) == 1


def test_plan_and_2d_diff_read_state_snapshots_as_their_ot(tmp_path):
    """`plan` and 2D `diff` accept an exact-state .npz like the .ot written beside it: a wall of
    LT voxels across the way, 0.5 m wide with a gap at its end, makes the same detour on both."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.outputs.snapshots import write_snapshot

    m = LayeredMap(MapConfig())
    wall = [[20, j, 10] for j in range(0, 30)]  # x = 1.0 m, y 0 .. 1.5 m
    corners = [[0, 0, 10], [40, 0, 10], [0, 40, 10], [40, 40, 10]]  # the map's extent
    m.seed_long_term(np.array(wall + corners), 1.0)
    write_snapshot(m, tmp_path / "snapshots", None, {})
    npz, ot = tmp_path / "snapshots/state_final.npz", tmp_path / "snapshots/long_term_final.ot"
    plans = []
    for p in (npz, ot):
        r = CliRunner().invoke(cli, ["plan", str(p), "--start", "0.5,0.5", "--goal", "1.5,0.5",
                                     "--robot-radius", "0.1", "--allow-unknown", "--json"])  # fmt: skip
        assert r.exit_code == 0, r.output
        plans.append(json.loads(r.output))
    assert plans[0]["path"] == plans[1]["path"]
    assert plans[0]["length_m"] > 2 * 1.0  # around the wall's end at y = 1.5 m, not 1 m straight
    assert max(y for _, y in plans[0]["path"]) > 1.5
    r = run(npz, ot, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["cells"]["occupied_a"] == len(wall) + 4


@pytest.mark.parametrize("cmd", ["diff", "plan"])
def test_bad_map_arguments_name_every_accepted_kind(tmp_path, cmd):
    b = write_trinary(tmp_path / "b.yaml", base_map())
    (tmp_path / "empty").mkdir()
    (tmp_path / "r.json").write_text("{}")
    for bad, what in ((tmp_path / "empty", "not a completed ltmap output"), (tmp_path / "nope.npz", "no such file"),
                      (tmp_path / "r.json", "unknown kind of file")):  # fmt: skip
        args = [str(bad), str(b)] if cmd == "diff" else [str(bad), "--start", "0,0", "--goal", "1,1"]
        r = CliRunner().invoke(cli, [cmd, *args])
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        line = r.output.strip()
        assert "\n" not in line and what in line and str(bad) in line
        assert "a replay output folder" in line and ".ot snapshot" in line and "state .npz" in line


def test_3d_folder_without_final_state_and_a_yaml(tmp_path):
    b = write_trinary(tmp_path / "b.yaml", base_map())
    completed_replay_folder(tmp_path / "empty", base_map())
    r = run(tmp_path / "empty", tmp_path / "empty", "--3d")
    assert r.exit_code == 2 and "empty: folder has no snapshots/state_final.npz" in r.output
    r = run(b, b, "--3d")
    assert r.exit_code == 2 and "replay output folders" in r.output and "b.yaml is none of these" in r.output


@pytest.mark.parametrize("cmd", ["diff", "plan"])
def test_help_names_state_snapshots(cmd):
    out = " ".join(CliRunner().invoke(cli, [cmd, "--help"]).output.split())
    assert "exact-state .npz snapshot" in out and "replay output folder" in out


@pytest.mark.parametrize("cmd", ["diff", "plan"])
def test_png_that_is_a_folder_or_under_a_file_is_named_as_given(tmp_path, cmd):
    a = write_trinary(tmp_path / "a.yaml", base_map())
    (tmp_path / "pics").mkdir()
    (tmp_path / "afile").write_text("x")
    head = [str(a), str(a)] if cmd == "diff" else [str(a), "--start", "0.1,0.1", "--goal", "0.9,0.1"]
    example = "diff.png" if cmd == "diff" else "path.png"
    for png, want in (
        (tmp_path / "pics", f"--png {tmp_path / 'pics'}: is a folder; give a file name such as "
                            f"{tmp_path / 'pics' / example}"),
        (tmp_path / "afile" / "d.png", f"--png {tmp_path / 'afile' / 'd.png'}: {tmp_path / 'afile'} is a file"),
    ):  # fmt: skip
        r = CliRunner().invoke(cli, [cmd, *head, "--png", str(png)])
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        assert r.output.startswith(f"ltmap: error: {want}") and r.output.count("\n") == 1, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pgm", "a.yaml", "afile", "pics"]
    assert not any((tmp_path / "pics").iterdir())


def test_ot_snapshots_of_a_replay_diff_and_plan_like_their_state_files(tmp_path):
    """The reviewer's case: 01_static_object replayed with snapshots every 10 s. The box enters LT
    near 18 s and is seen gone at 23 s; the .ot pair now holds the free space the box leaves, so
    diff counts it removed exactly as the state .npz pair does, and plan starts in known space."""
    from pathlib import Path

    log = Path(__file__).resolve().parents[1] / "sample_logs/scenarios/01_static_object/log.mcap"
    out = tmp_path / "s1"
    args = ["replay", str(log), "-o", str(out), "--snapshot-every", "10", "-q", "--no-plots"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    s = out / "snapshots"
    box = (3.5 - 0.35, 3.5 + 0.35, 2.5 - 0.35, 2.5 + 0.35)  # 0.4 m box at 20 degrees, with a margin
    for t in ("t000010.0s", "t000020.0s"):
        ot = json.loads(run(s / f"long_term_{t}.ot", s / "long_term_final.ot", "--json").output)
        npz = json.loads(run(s / f"state_{t}.npz", s / "state_final.npz", "--json").output)
        assert ot["cells"] == npz["cells"], t
        if t == "t000020.0s":
            assert ot["cells"]["removed"] >= 12
            # the removed cells are the box's (and a few wall-edge cells whose LT is being forgotten)
            g = load_grid(s / f"long_term_{t}.ot")
            f = load_grid(s / "long_term_final.ot")
            box_cells = 0
            for row, col in zip(*np.nonzero(g.data == 100)):
                x, y = cell_to_world(g, row, col)
                fr, fc = world_to_cell(f, x, y)
                if box[0] < x < box[1] and box[2] < y < box[3]:
                    assert f.data[fr, fc] == 0, (x, y)  # occupied at 20 s, free at the end
                    box_cells += 1
            assert box_cells >= 10
    plans = []
    for f in ("long_term_final.ot", "state_final.npz"):
        r = CliRunner().invoke(cli, ["plan", str(s / f), "--start", "2.5,2.5", "--goal", "6,1.5", "--json"])
        assert r.exit_code == 0, r.output  # was: start is in an unknown cell, on the .ot
        plans.append(json.loads(r.output))
    assert plans[0]["path"] == plans[1]["path"]
    assert plans[0]["length_m"] == pytest.approx(plans[1]["length_m"])
