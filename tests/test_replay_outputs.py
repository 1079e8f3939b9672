"""What `ltmap replay` writes into its output folder: every snapshot time has its three files; a
folder ltmap did not write is refused before the run (replaced with --force); the manifest and the
summary line name every file written."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import open3d as o3d
import pytest
from test_replay import assert_one_line_error, run

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.state import read_state
from ltmap_cli.outputs.folder import MANIFEST
from ltmap_cli.outputs.names import PLOT_FILES
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


def test_periodic_snapshots_stop_while_the_disk_is_nearly_full_and_the_run_completes(tmp_path, monkeypatch):
    """Hours of log write hundreds of snapshots. While the output's disk has less free than
    3 snapshots and SNAPSHOT_FREE_MARGIN, a periodic snapshot is left out: one warning, counted
    in report.json; they start again when room comes back; the final snapshot and the maps are
    written. (Before, a full disk failed the whole run at its end.) The disk here: nearly full
    for the 2nd and 3rd periodic snapshots, then free again."""
    import shutil
    from collections import namedtuple

    from ltmap_cli.pipeline.sinks import SNAPSHOT_FREE_MARGIN

    real = shutil.disk_usage
    usage = namedtuple("usage", "total used free")
    calls = []

    def disk_usage(path):
        u = real(path)
        calls.append(path)
        if len(calls) in (2, 3):
            return usage(u.total, u.total - SNAPSHOT_FREE_MARGIN // 2, SNAPSHOT_FREE_MARGIN // 2)
        return u

    monkeypatch.setattr(shutil, "disk_usage", disk_usage)
    out = tmp_path / "out"
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--no-plots", "--snapshot-every", "5"])
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    times = [s["log_time_s"] for s in report["snapshots"]]
    assert times == [5.0, 20.0, 25.0, None] and report["snapshots_skipped_low_disk"] == 2
    assert len(calls) == 5  # one check per periodic snapshot: at 5, 10, 15, 20 and 25 s
    warned = [x for x in r.output.splitlines() if "snapshots every 5 s stop at 10 s of log" in x]
    assert len(warned) == 1 and "free some space, or give --snapshot-every a longer period" in warned[0]
    assert (out / "snapshots" / "state_final.npz").is_file() and (out / "map.pgm").is_file()


@pytest.fixture
def no_replay(monkeypatch):
    """Fail the test if the replay itself starts (the refusal must come before it)."""

    def started(self, *a, **kw):
        raise AssertionError("the replay started")

    monkeypatch.setattr(Replay, "_run", started)


@pytest.mark.parametrize("name, make", [("replay.mcap", "dir"), ("map.pgm", "dir"), ("plots", "file"),
                                        ("notes.txt", "file")])  # fmt: skip
def test_a_folder_ltmap_did_not_write_is_refused_before_the_run(tmp_path, no_replay, name, make):
    out = tmp_path / "out"
    out.mkdir()
    (out / name).mkdir() if make == "dir" else (out / name).write_text("mine")
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--mcap-out"], plots=True)
    assert_one_line_error(r, f"-o {out}: holds files ltmap did not write ({name})", "--force")
    assert [p.name for p in out.iterdir()] == [name]  # nothing written, nothing removed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder, no lock file


def test_force_replaces_a_foreign_folder_as_a_whole(tmp_path):
    out = tmp_path / "out"
    (out / "replay.mcap").mkdir(parents=True)
    (out / "plots").write_text("not ours")
    (out / "empty_dir").mkdir()
    assert run(["replay", str(LOG), "-o", str(out), "-q", "--force"]).exit_code == 0
    manifest = json.loads((out / MANIFEST).read_text())
    on_disk = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert on_disk == set(manifest["files"]) | {MANIFEST}
    assert not (out / "replay.mcap").exists() and not (out / "plots").exists() and not (out / "empty_dir").exists()


def test_the_manifest_and_the_summary_name_everything_written(tmp_path):
    # with every optional output: the static map (any map_server YAML), replay.mcap and plots
    first = tmp_path / "first"
    assert run(["replay", str(LOG), "-o", str(first), "-q"]).exit_code == 0
    out = tmp_path / "out"
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--static", str(first / "map.yaml"), "--mcap-out"], plots=True)
    assert r.exit_code == 0, r.output
    files = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    manifest = json.loads((out / MANIFEST).read_text())
    assert files == set(manifest["files"]) | {MANIFEST}
    maps = {f"{stem}.{ext}" for stem in ("map", "long_term", "static") for ext in ("pgm", "yaml", "png")}
    snaps = {f"snapshots/{k}_final.{e}" for k, e in (("long_term", "ot"), ("long_term", "ply"), ("state", "npz"))}
    plots = {f"plots/{f}" for f in PLOT_FILES.values()}
    assert files == maps | snaps | plots | {"events.csv", "report.json", "config.yaml", "replay.mcap", MANIFEST}
    for name, info in manifest["files"].items():
        data = (out / name).read_bytes()
        assert info == {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    assert manifest["command"] == "replay" and manifest["logs"] == [str(LOG)]
    summary = [ln for ln in r.output.splitlines() if ln.startswith("wrote ")]
    assert summary == [f"wrote {out}/: config.yaml, events.csv, long_term.pgm, long_term.png, long_term.yaml, "
                       "map.pgm, map.png, map.yaml, replay.mcap, report.json, static.pgm, static.png, static.yaml, "
                       "plots/ (5 files), snapshots/ (3 files)"]  # fmt: skip
    # the report and config.yaml name the folder the user gave, not the staging folder
    report = json.loads((out / "report.json").read_text())
    assert report["outputs"]["events"] == str(out / "events.csv")
    assert report["snapshots"][-1]["state"] == str(out / "snapshots" / "state_final.npz")
    assert f"-o {out} --config {out / 'config.yaml'}" in (out / "config.yaml").read_text().splitlines()[1]
    assert "ltmap-staging" not in (out / "report.json").read_text()
