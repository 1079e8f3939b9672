"""Draw docs/img/foxglove_replay_mcap.png: what replay.mcap of the house sample holds, read back
with mcap + mcap_ros2 and drawn with matplotlib (an illustration, not a Foxglove screenshot).

    python sample_logs/make_foxglove_figure.py     # replays with `ltmap` (LTMAP=... to choose it)

It shows the moment whose /ltmap/occupied_voxels message holds the most voxels with long_term < 1
(voxels being forgotten): /map, /scan_fused placed with /tf and /tf_static, the occupied voxels
coloured by their `long_term` field, and /ltmap/static_voxels.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE.parent / "docs" / "img" / "foxglove_replay_mcap.png"
VMIN = 0.65  # map.projection.occupied_thresh: the lowest value /ltmap/occupied_voxels holds


def read_messages(path: Path) -> dict[str, list[tuple[int, object]]]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list[tuple[int, object]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, msg in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return out


def cloud(msg):
    import numpy as np

    names = [fl.name for fl in msg.fields]
    rec = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.width * msg.height, len(names))
    return {n: rec[:, i] for i, n in enumerate(names)}


def matrix(tr):
    import numpy as np

    q, t = tr.transform.rotation, tr.transform.translation
    x, y, z, w = q.x, q.y, q.z, q.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]  # fmt: skip
    m[:3, 3] = (t.x, t.y, t.z)
    return m


def lookup(msgs, fixed: str, frame: str, t_ns: int):
    """fixed <- frame at t_ns: the latest /tf sample at or before t_ns per edge, /tf_static mounts."""
    import numpy as np

    edges = {}
    for _t, m in msgs["/tf_static"]:
        for tr in m.transforms:
            edges[tr.child_frame_id] = (tr.header.frame_id, matrix(tr))
    for t, m in msgs["/tf"]:
        if t > t_ns:
            break
        for tr in m.transforms:
            edges[tr.child_frame_id] = (tr.header.frame_id, matrix(tr))
    T = np.eye(4)
    while frame != fixed:
        parent, m = edges[frame]
        T = m @ T
        frame = parent
    return T


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    ltmap = os.environ.get("LTMAP", "ltmap")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([ltmap, "build-static", str(HERE / "plans" / "house.svg"), "-o", str(tmp / "static")],
                       check=True, stdout=subprocess.DEVNULL)  # fmt: skip
        subprocess.run([ltmap, "replay", str(HERE / "scenarios" / "06_house" / "log.mcap"), "--static",
                        str(tmp / "static"), "-o", str(tmp / "out"), "-q", "--no-plots", "--mcap-out"],
                       check=True, stdout=subprocess.DEVNULL)  # fmt: skip
        msgs = read_messages(tmp / "out" / "replay.mcap")

    t0 = min(t for v in msgs.values() for t, _ in v)
    voxels = msgs["/ltmap/occupied_voxels"]
    t_ns, vox = max(voxels, key=lambda tm: (int((cloud(tm[1])["long_term"] < 1.0).sum()), -tm[0]))
    grid = next(m for t, m in msgs["/map"] if t == t_ns)
    scan_t, scan = max((tm for tm in msgs["/scan_fused"] if tm[0] <= t_ns), key=lambda tm: tm[0])
    fixed = grid.header.frame_id
    v = cloud(vox)
    static = cloud(msgs["/ltmap/static_voxels"][0][1])
    order = np.argsort(-v["long_term"])  # voxels below 1 drawn last, on top
    falling = int((v["long_term"] < 1.0).sum())

    fig = plt.figure(figsize=(12, 5.2), layout="constrained")
    gs = fig.add_gridspec(1, 2, width_ratios=(1.0, 1.35))
    fig.suptitle(f"replay.mcap of the house sample at t = {(t_ns - t0) / 1e9:.1f} s, read back with mcap + "
                 "mcap_ros2 and drawn with matplotlib (not a Foxglove screenshot)", fontsize=10)  # fmt: skip
    ax = fig.add_subplot(gs[0])
    g = np.asarray(grid.data, np.int8).reshape(grid.info.height, grid.info.width)  # row 0 = lowest y
    img = np.full(g.shape, 0.55)
    img[g == 0] = 0.95
    img[g == 100] = 0.0
    r = grid.info.resolution
    ox, oy = grid.info.origin.position.x, grid.info.origin.position.y
    ax.imshow(img, cmap="gray", vmin=0, vmax=1, origin="lower", interpolation="nearest",
              extent=(ox, ox + g.shape[1] * r, oy, oy + g.shape[0] * r))  # fmt: skip
    sc = ax.scatter(v["x"][order], v["y"][order], c=v["long_term"][order], cmap="turbo", vmin=VMIN, vmax=1.0,
                    s=4, marker="s", label="/ltmap/occupied_voxels (top view)")  # fmt: skip
    T = lookup(msgs, fixed, scan.header.frame_id, scan_t)
    ranges = np.asarray(scan.ranges, np.float64)
    ang = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
    ok = np.isfinite(ranges)
    pts = np.stack([ranges * np.cos(ang), ranges * np.sin(ang), np.zeros_like(ang), np.ones_like(ang)])[:, ok]
    pts = T @ pts
    ax.scatter(pts[0], pts[1], s=3, color="magenta", label="/scan_fused")
    ax.annotate("", xy=T[:2, 3] + 0.6 * T[:2, 0], xytext=T[:2, 3],
                arrowprops={"arrowstyle": "->", "color": "tab:blue", "lw": 2})  # fmt: skip
    lo, hi = np.array([static["x"].min(), static["y"].min()]), np.array([static["x"].max(), static["y"].max()])
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_title(f"top view: /map, /scan_fused, voxels (frame {fixed})", fontsize=10)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8, markerscale=3)

    ax3 = fig.add_subplot(gs[1], projection="3d")
    top = static["z"] >= static["z"].max() - 1e-3
    ax3.scatter(static["x"][top], static["y"][top], static["z"][top], s=1, color="0.75", depthshade=False)
    ax3.scatter(v["x"][order], v["y"][order], v["z"][order], c=v["long_term"][order], cmap="turbo", vmin=VMIN,
                vmax=1.0, s=3, marker="s", depthshade=False)  # fmt: skip
    ax3.set_title(f"3D: /ltmap/occupied_voxels by field 'long_term' ({falling} below 1),\n"
                  "tops of /ltmap/static_voxels in grey", fontsize=10)  # fmt: skip
    ax3.set_xlabel("x")
    ax3.set_ylabel("y")
    ax3.set_zlabel("z")
    ax3.set_zticks([0, 1, 2])
    ax3.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], 2.5), zoom=1.25)
    ax3.view_init(elev=35, azim=-60)
    fig.colorbar(sc, ax=ax3, shrink=0.6, label="long_term")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=100)
    print(f"wrote {OUT} (t = {(t_ns - t0) / 1e9:.1f} s, {len(v['x'])} voxels, {falling} below 1)", file=sys.stderr)


if __name__ == "__main__":
    main()
