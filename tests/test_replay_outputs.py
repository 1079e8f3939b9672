"""What `ltmap replay` writes into its output folder: every snapshot time has its three files."""

from __future__ import annotations

import json
from pathlib import Path

import open3d as o3d
from test_replay import run

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.state import read_state

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
