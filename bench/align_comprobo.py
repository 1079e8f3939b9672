"""Find map -> odom for the comprobo22 log against its published map (docs/real_logs.md).

    python bench/align_comprobo.py [--real-logs ../shared/real_logs]

1. Replay the log without a static map and take the occupied columns of the sensor map O.
2. For every yaw in 1 degree steps, rotate them and find the best translation by FFT
   cross-correlation with the published map's occupied cells (dilated by one cell).
3. Refine locally (0.5, 0.2, 0.1 degrees; 0.04, 0.02, 0.01 m), maximizing the fraction of our
   columns within 2 cells of a published wall. Print the result and how the fraction falls off.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.io.state import read_state

GRID = 0.06  # m, correlation grid


def rotate(pts: np.ndarray, yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return pts @ np.array([[c, s], [-s, c]])


def dilate(mask: np.ndarray, n: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-n, n + 1):
        for dx in range(-n, n + 1):
            out |= np.roll(np.roll(mask, dy, 0), dx, 1)
    return out


def our_columns(log: Path) -> np.ndarray:
    with tempfile.TemporaryDirectory() as tmp:
        r = CliRunner().invoke(cli, ["replay", str(log), "-o", tmp, "-q"], catch_exceptions=False)
        assert r.exit_code == 0, r.output
        arrays, _ = read_state(Path(tmp) / "snapshots" / "state_final.npz")
    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    keys = m.occupied_keys("O")
    return np.unique((keys[:, :2] + 0.5) * 0.05, axis=0)


def coarse(pts: np.ndarray, wall_xy: np.ndarray) -> tuple[float, float, float]:
    lo = wall_xy.min(0) - 3.0
    hi = wall_xy.max(0) + 3.0
    W, H = int((hi[0] - lo[0]) / GRID) + 1, int((hi[1] - lo[1]) / GRID) + 1
    walls = np.zeros((H, W), dtype=bool)
    ij = ((wall_xy - lo) / GRID).astype(int)
    walls[ij[:, 1], ij[:, 0]] = True
    spectrum = np.fft.rfft2(dilate(walls, 1).astype(float))
    best = (-1.0, 0.0, 0.0, 0.0)
    for yaw in np.arange(0.0, 360.0, 1.0):
        q = rotate(pts, yaw)
        qmin = q.min(0)
        jj = ((q - qmin) / GRID).astype(int)
        if jj[:, 0].max() >= W or jj[:, 1].max() >= H:
            continue
        ours = np.zeros((H, W))
        ours[jj[:, 1], jj[:, 0]] = 1.0
        corr = np.fft.irfft2(spectrum * np.conj(np.fft.rfft2(ours)), s=walls.shape)
        dy, dx = np.unravel_index(np.argmax(corr), corr.shape)
        if corr[dy, dx] > best[0]:
            best = (float(corr[dy, dx]), float(yaw), lo[0] + dx * GRID - qmin[0], lo[1] + dy * GRID - qmin[1])
    return best[1], best[2], best[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-logs", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "real_logs")
    args = ap.parse_args()
    log = args.real_logs / "comprobo22_macfirst_floor_take_2"
    grid = read_map_yaml(args.real_logs / "comprobo22_maps" / "mac_1st_floor_final.yaml")
    pts = our_columns(log)
    occ = grid.data == 100
    rows, cols = np.nonzero(occ)
    wall_xy = np.stack([grid.origin[0] + (cols + 0.5) * grid.resolution,
                        grid.origin[1] + (rows + 0.5) * grid.resolution], axis=1)  # fmt: skip
    near = dilate(occ, 2)

    def on_walls(yaw: float, tx: float, ty: float) -> float:
        q = rotate(pts, yaw) + [tx, ty]
        j = np.floor((q - np.array(grid.origin[:2])) / grid.resolution).astype(int)
        ok = (j[:, 0] >= 0) & (j[:, 0] < occ.shape[1]) & (j[:, 1] >= 0) & (j[:, 1] < occ.shape[0])
        return float(near[j[ok, 1], j[ok, 0]].sum()) / len(pts)

    yaw, tx, ty = coarse(pts, wall_xy)
    best = (on_walls(yaw, tx, ty), yaw, tx, ty)
    for step_a, step_t in ((0.5, 0.04), (0.2, 0.02), (0.1, 0.01)):
        improved = True
        while improved:
            improved = False
            for da, dx, dy in itertools.product((-step_a, 0, step_a), (-step_t, 0, step_t), (-step_t, 0, step_t)):
                cand = (best[1] + da, best[2] + dx, best[3] + dy)
                score = on_walls(*cand)
                if score > best[0] + 1e-9:
                    best = (score, *cand)
                    improved = True
    score, yaw, tx, ty = best
    print(f"{len(pts)} occupied columns; map -> odom: x {tx:.3f} m, y {ty:.3f} m, yaw {yaw:.1f} deg "
          f"({np.radians(yaw):.5f} rad): {100 * score:.0f} % within 2 cells of a published wall")  # fmt: skip
    for dyaw in (2, 5, 10):
        print(f"  yaw off by {dyaw} deg: {100 * on_walls(yaw + dyaw, tx, ty):.0f} %")
    print(f"  shifted 0.3 m: {100 * on_walls(yaw, tx + 0.3, ty):.0f} %")


if __name__ == "__main__":
    main()
