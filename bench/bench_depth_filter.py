"""Cost and effect of the depth outlier filter (``ltmap replay --depth-outlier-filter``, ``replay.depth_outlier_filter``).

    python bench/bench_depth_filter.py [--log sample_logs/scenarios/06_house/log.mcap]

Takes the depth frames of a simulated log (clean: the simulator renders no mixed pixels), adds
flying pixels the way real depth cameras make them, and integrates the frames three times into
fresh sensor maps O, at the frames' true poses:

- clean: the frames as recorded (the reference);
- noisy: with flying pixels (at each depth edge over 0.2 m, the pixels on either side get a depth
  drawn uniformly between foreground and background, with probability 0.5);
- filtered: noisy, then ``flying_pixel_mask`` (open3d's radius outlier removal on the pixels
  near depth jumps; radius 0.02 m, at least 3 other points).

Prints, per run: occupied voxels of O in the robot's z band, spurious voxels (occupied but not in
the clean map, and more than one voxel away from any clean occupied voxel), clean voxels lost,
and the filter's cost per frame.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.grid import band_k_range
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.core.sensors import depth_to_points, transform_points
from ltmap_cli.io.frames import DepthFrame, OdometrySample, TfSample
from ltmap_cli.io.logs import open_logs
from ltmap_cli.io.transforms import TfBuffer
from ltmap_cli.pipeline.filters import flying_pixel_mask

ROOT = Path(__file__).resolve().parents[1]


def add_flying_pixels(depth: np.ndarray, rng: np.random.Generator, jump: float = 0.2, p: float = 0.5):
    d = depth.copy()
    for axis in (0, 1):
        a = np.take(depth, range(depth.shape[axis] - 1), axis=axis)
        b = np.take(depth, range(1, depth.shape[axis]), axis=axis)
        edge = np.isfinite(a) & np.isfinite(b) & (np.abs(a - b) > jump) & (rng.random(a.shape) < p)
        mix = np.where(edge, np.minimum(a, b) + rng.random(a.shape) * np.abs(a - b), np.nan)
        target = np.take(d, range(depth.shape[axis] - 1), axis=axis)
        target = np.where(edge, mix, target)
        if axis == 0:
            d[:-1] = target
        else:
            d[:, :-1] = target
    return d


def band_occupied(m: LayeredMap) -> set:
    k_lo, k_hi = band_k_range(0.05, 1.5, m.resolution)
    keys = m.occupied_keys("O")
    keys = keys[(keys[:, 2] >= k_lo) & (keys[:, 2] <= k_hi)]
    return {tuple(k) for k in keys.tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, default=ROOT / "sample_logs/scenarios/06_house/log.mcap")
    ap.add_argument("--radius", type=float, default=0.02)
    ap.add_argument("--min-neighbors", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)

    tf = TfBuffer()
    frames: list[DepthFrame] = []
    with open_logs([args.log]) as logs:
        sel = logs.select()
        for _, _, item in logs.messages(sel):
            if isinstance(item, (TfSample, OdometrySample)):
                tf.add(item)
            elif isinstance(item, DepthFrame):
                frames.append(item)
    fixed = tf.fixed_frame()
    maps = {name: LayeredMap(MapConfig()) for name in ("clean", "noisy", "filtered")}
    cost, removed, n_pts = [], [], []
    for f in frames:
        T, _ = tf.try_lookup(fixed, f.frame_id, f.stamp_ns)
        if T is None:
            continue
        k = f.intrinsics
        noisy = add_flying_pixels(f.depth_m, rng)
        t0 = time.perf_counter()
        drop = flying_pixel_mask(noisy, k.fx, k.fy, k.cx, k.cy, radius=args.radius, min_neighbors=args.min_neighbors)
        cost.append(time.perf_counter() - t0)
        flying = np.isfinite(noisy) & (noisy != f.depth_m)
        removed.append((int((drop & flying).sum()), int(flying.sum()), int((drop & ~flying).sum())))
        n_pts.append(int(np.isfinite(noisy).sum()))
        filtered = np.where(drop, np.nan, noisy)
        for name, depth in (("clean", f.depth_m), ("noisy", noisy), ("filtered", filtered)):
            pts = transform_points(T, depth_to_points(depth, k.fx, k.fy, k.cx, k.cy))
            maps[name].integrate(T[:3, 3], pts, max_range=8.0, dedupe=True)
    clean = band_occupied(maps["clean"])
    near_clean = {(x + a, y + b, z + c) for x, y, z in clean for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)}
    print(f"# Depth outlier filter on {args.log.relative_to(ROOT) if args.log.is_relative_to(ROOT) else args.log}")
    print(f"{len(frames)} depth frames {frames[0].depth_m.shape[1]}x{frames[0].depth_m.shape[0]}; "
          f"radius {args.radius} m, at least {args.min_neighbors} other points; 0.05 m voxels\n")  # fmt: skip
    print("| run | occupied voxels in band | spurious (not within 1 voxel of clean) | clean voxels lost |")
    print("|---|---|---|---|")
    for name in ("clean", "noisy", "filtered"):
        occ = band_occupied(maps[name])
        spurious = len(occ - near_clean)
        lost = len(clean - occ)
        print(f"| {name} | {len(occ)} | {spurious} | {lost} |")
    rem = np.array(removed)
    print(f"\nfilter cost per frame: median {1e3 * np.median(cost):.1f} ms, max {1e3 * np.max(cost):.1f} ms. "
          f"Flying pixels dropped: {rem[:, 0].sum()} of {rem[:, 1].sum()} ({100 * rem[:, 0].sum() / max(rem[:, 1].sum(), 1):.0f} %); "
          f"good pixels dropped: {rem[:, 2].sum()} of {sum(n_pts) - rem[:, 1].sum()}")  # fmt: skip


if __name__ == "__main__":
    main()
