"""What `ltmap replay` writes into its output folder: every snapshot time has its three files, and
the fixed output names are checked before the run (a folder where a file goes, or the reverse)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from test_replay import assert_one_line_error, run

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.state import read_state
from ltmap_cli.outputs.names import replay_output_files, replay_output_folders
from ltmap_cli.pipeline.replay import Replay

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"


def long_term_occupied(state_path: Path) -> int:
    arrays, _ = read_state(state_path)
    lmap = LayeredMap(MapConfig(resolution=float(arrays["resolution"])))
    lmap.load_state_arrays(arrays)
    return len(lmap.occupied_keys("LT"))


def test_every_snapshot_time_has_ot_ply_and_npz_even_with_an_empty_long_term_map(tmp_path):
    # the box appears at 3 s and needs st_rise_s (15 s) to enter LT: LT is empty at 10 s
    out = tmp_path / "out"
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--snapshot-every", "10"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in (out / "snapshots").iterdir())
    assert names == sorted(f"{kind}_{t}.{ext}" for t in ("t000010.0s", "t000020.0s", "final")
                           for kind, ext in (("long_term", "ot"), ("long_term", "ply"), ("state", "npz")))  # fmt: skip
    report = json.loads((out / "report.json").read_text())
    assert [Path(s["ply"]).name for s in report["snapshots"]] == [
        "long_term_t000010.0s.ply", "long_term_t000020.0s.ply", "long_term_final.ply"]
    counts = {}
    for t in ("t000010.0s", "t000020.0s", "final"):
        cloud = o3d.io.read_point_cloud(str(out / "snapshots" / f"long_term_{t}.ply"))
        counts[t] = len(cloud.points)
        assert counts[t] == long_term_occupied(out / "snapshots" / f"state_{t}.npz")
    assert counts["t000010.0s"] == 0 and counts["t000020.0s"] > 0
    assert counts["final"] == report["voxels"]["long_term_occupied"]
    empty = (out / "snapshots" / "long_term_t000010.0s.ply").read_bytes()
    assert empty.endswith(b"element vertex 0\nproperty double x\nproperty double y\nproperty double z\n"
                          b"property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")


@pytest.fixture
def no_replay(monkeypatch):
    """Fail the test if the replay itself starts (the refusal must come before it)."""

    def started(self, *a, **kw):
        raise AssertionError("the replay started")

    monkeypatch.setattr(Replay, "_run", started)


@pytest.mark.parametrize("name, extra", [
    ("replay.mcap", ["--mcap-out"]), ("map.pgm", []), ("long_term.yaml", []), ("report.json", []),
    ("config.yaml", []), ("events.csv", []), ("plots/map_3d.png", ["--plots"])])  # fmt: skip
def test_a_folder_at_a_fixed_output_name_is_refused_before_the_run(tmp_path, no_replay, name, extra):
    out = tmp_path / "out"
    (out / name).mkdir(parents=True)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    plots = extra == ["--plots"]
    r = run(["replay", str(LOG), "-o", str(out), "-q", *[e for e in extra if e != "--plots"]], plots=plots)
    assert_one_line_error(r, f"{out / name} is a folder", f"writes the file {name}", "choose another output folder")
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # nothing written, nothing removed


@pytest.mark.parametrize("name", ["snapshots", "plots"])
def test_a_file_where_a_folder_goes_is_refused_before_the_run(tmp_path, no_replay, name):
    out = tmp_path / "out"
    out.mkdir()
    (out / name).write_text("mine")
    r = run(["replay", str(LOG), "-o", str(out), "-q"], plots=True)
    assert_one_line_error(r, f"{out / name} is a file", f"its folder {name}/", "choose another output folder")
    assert [p.name for p in out.iterdir()] == [name] and (out / name).read_text() == "mine"


def test_names_that_need_their_option_are_free_without_it(tmp_path):
    out = tmp_path / "out"
    (out / "replay.mcap").mkdir(parents=True)  # without --mcap-out nothing is written there
    (out / "static.pgm").mkdir()  # without --static neither
    (out / "plots").write_text("not ours")  # nor here with --no-plots
    assert run(["replay", str(LOG), "-o", str(out), "-q"]).exit_code == 0
    assert (out / "replay.mcap").is_dir() and (out / "plots").read_text() == "not ours"
    assert (out / "map.pgm").is_file()


def test_the_checked_names_are_what_a_run_writes(tmp_path):
    # with every optional output: the static map (any map_server YAML), replay.mcap and plots
    first = tmp_path / "first"
    assert run(["replay", str(LOG), "-o", str(first), "-q"]).exit_code == 0
    out = tmp_path / "out"
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--static", str(first / "map.yaml"), "--mcap-out"], plots=True)
    assert r.exit_code == 0, r.output
    files = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.parent.name != "snapshots"}
    folders = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_dir()}
    assert files == set(replay_output_files(static=True, mcap=True, plots=True))
    assert folders == set(replay_output_folders(plots=True))
    assert set(replay_output_files(static=False, mcap=False, plots=False)) == {
        n for n in files if not n.startswith(("static.", "plots/")) and n != "replay.mcap"}
    assert np.all([(out / n).stat().st_size > 0 for n in files])
