"""docs/foxglove.md against a real replay.mcap: every topic the file holds is in the doc's table,
and what the doc says of the voxel clouds and the map messages holds in the file."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from test_replay import run

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
DOC = ROOT / "docs" / "foxglove.md"


def read_back(path: Path):
    msgs: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        qos = {ch.topic: ch.metadata["offered_qos_profiles"] for ch in summary.channels.values()}
        for _s, channel, message, msg in reader.iter_decoded_messages():
            msgs.setdefault(channel.topic, []).append((message.log_time, msg))
    return msgs, qos


def cloud(msg) -> tuple[list[str], np.ndarray]:
    names = [f.name for f in msg.fields]
    return names, np.frombuffer(bytes(msg.data), "<f4").reshape(msg.width, len(names))


def test_replay_mcap_is_what_docs_foxglove_md_says(tmp_path):
    first = tmp_path / "first"  # its map.yaml serves as the static map (any map_server YAML does)
    assert run(["replay", str(LOG), "-o", str(first), "-q"]).exit_code == 0
    out = tmp_path / "out"
    r = run(["replay", str(LOG), "-o", str(out), "-q", "--static", str(first / "map.yaml"), "--mcap-out"])
    assert r.exit_code == 0, r.output
    msgs, qos = read_back(out / "replay.mcap")
    doc = DOC.read_text()
    table = set(re.findall(r"^\| `(/[\w/]+)` \|", doc, flags=re.M))
    assert set(msgs) == table  # no topic undocumented, none documented that is not there

    # occupied voxels: x y z long_term, only LT >= occupied_thresh (0.65)
    assert "float32 `long_term`" in doc
    values = []
    for _t, m in msgs["/ltmap/occupied_voxels"]:
        names, rec = cloud(m)
        assert names == ["x", "y", "z", "long_term"]
        values.append(rec[:, 3])
    values = np.concatenate(values)
    assert len(values) and values.min() >= 0.65 and values.max() == 1.0

    # static voxels: one message, x y z only, volatile (a late subscriber misses it)
    (t_static, m), = msgs["/ltmap/static_voxels"]
    names, rec = cloud(m)
    assert names == ["x", "y", "z"] and len(rec) > 0
    assert "durability: 2" in qos["/ltmap/static_voxels"]  # volatile
    assert all("durability: 1" in qos[t] for t in ("/map", "/long_term_map", "/tf_static"))  # transient local
    assert t_static == msgs["/map"][0][0]  # written with the first maps, at the first tick

    # the maps and the occupied voxels are written together, at most every --map-period (1 s),
    # the last one at the last sensor stamp
    stamps = [t for t, _ in msgs["/map"]]
    assert stamps == [t for t, _ in msgs["/long_term_map"]] == [t for t, _ in msgs["/ltmap/occupied_voxels"]]
    assert min(np.diff(stamps)[:-1]) >= 1e9 and len(stamps) <= 50 + 2  # 50 s of log
    assert stamps[-1] == max(t for t, _ in msgs["/scan_fused"])
