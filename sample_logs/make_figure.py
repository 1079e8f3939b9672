"""Draw docs/img/house_laser_vs_depth.png: the house run's map P with the laser alone beside
laser + depth, with the ground-truth table, chair and ball outlined.

    python sample_logs/make_figure.py            # replays with `ltmap` (LTMAP=... to choose it)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE.parent / "docs" / "img" / "house_laser_vs_depth.png"


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.patches import Circle, Polygon

    from ltmap_cli.io.mapfile import read_map_yaml

    ltmap = os.environ.get("LTMAP", "ltmap")
    log = HERE / "scenarios" / "06_house" / "log.mcap"
    gt = json.loads((HERE / "scenarios" / "06_house" / "ground_truth.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([ltmap, "build-static", str(HERE / "plans" / "house.svg"), "-o", str(tmp / "static")],
                       check=True, stdout=subprocess.DEVNULL)
        runs = {"laser only (--scan-topic /scan)": ["--scan-topic", "/scan"], "laser + depth 640x480": []}
        maps = {}
        for title, opts in runs.items():
            out = tmp / str(len(maps))
            subprocess.run([ltmap, "replay", str(log), "--static", str(tmp / "static"), "-o", str(out), "-q", *opts],
                           check=True, stdout=subprocess.DEVNULL)
            maps[title] = read_map_yaml(out / "map.yaml")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    for ax, (title, g) in zip(axes, maps.items()):
        img = np.full(g.data.shape, 0.8)
        img[g.data == 0] = 1.0
        img[g.data == 100] = 0.0
        ox, oy, _ = g.origin
        h, w = g.data.shape
        ax.imshow(img, cmap="gray", vmin=0, vmax=1, origin="lower", interpolation="nearest",
                  extent=(ox, ox + w * g.resolution, oy, oy + h * g.resolution))
        for o in gt["objects"]:
            if o["category"] != "object":
                continue
            for p in o["parts"][:1]:
                if p["type"] == "box":
                    c, (sx, sy, _), a = p["center"], p["size"], np.radians(p["yaw_deg"])
                    corners = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) / 2
                    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
                    ax.add_patch(Polygon(corners @ rot.T + c[:2], fill=False, ec="tab:red", lw=1.2))
                else:
                    ax.add_patch(Circle(p["center"][:2], p["radius"], fill=False, ec="tab:red", lw=1.2))
            ax.annotate(o["id"], o["parts"][0]["center"][:2], color="tab:red", fontsize=8,
                        xytext=(4, 6), textcoords="offset points")
        path = np.array([[q["x"], q["y"]] for q in gt["robot"]["path"]])
        ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=1.5, label="robot path")
        ax.set_xlim(0, 10)
        ax.set_ylim(0, 8)
        ax.set_title(f"house: {title}")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.legend(loc="upper right", fontsize=8)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
