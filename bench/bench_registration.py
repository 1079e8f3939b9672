"""Scan-to-map registration for ``--localize``: the distance-field matcher of
``analysis/localization.py`` against open3d's ``registration_icp`` (point-to-point, and
point-to-plane with the walls' 2D normals), on scans cast against a synthetic room.

    python bench/bench_registration.py [--trials 200]

Each trial: a 360-beam scan (1 cm range noise) from a random pose in the room, started from the
true pose plus an error (up to 0.15 m and 3 degrees, as odometry between two scans would leave
at most), matched to the room's walls rasterized at 5 cm. Prints per method: median and 95th
percentile of the remaining position and heading error, and the time per match.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from ltmap_cli.analysis.localization import SurfaceField, register, wrap

ROOM = [(0, 0, 8, 0), (8, 0, 8, 6), (8, 6, 0, 6), (0, 6, 0, 0), (3, 0, 3, 2.5), (5.5, 6, 5.5, 4.0),
        (6, 1.5, 6.4, 1.5), (6.4, 1.5, 6.4, 1.9), (6.4, 1.9, 6, 1.9), (6, 1.9, 6, 1.5)]  # fmt: skip
ANGLES = np.radians(np.arange(-180.0, 180.0, 1.0))


def cast(pose, rng) -> np.ndarray:
    seg = np.asarray(ROOM, dtype=float)
    a = pose[2] + ANGLES
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    p0, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
    w = p0 - np.array(pose[:2])
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den
    t = np.where((np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1), t, np.inf)
    r = t.min(axis=1) + rng.normal(0, 0.01, len(ANGLES))
    ok = np.isfinite(r) & (r > 0.2)
    return np.stack([r[ok] * np.cos(ANGLES[ok]), r[ok] * np.sin(ANGLES[ok])], axis=1)


def wall_cells(res: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the wall cells and each one's normal (from the segment it samples)."""
    pts, normals = [], []
    for x0, y0, x1, y1 in ROOM:
        n = int(math.hypot(x1 - x0, y1 - y0) / 0.01) + 2
        xy = np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], axis=1)
        c = np.round(xy / res) * res  # cells centred on whole multiples of res: the walls on centres
        pts.append(c)
        nx, ny = -(y1 - y0), x1 - x0
        normals.append(np.tile(np.array([nx, ny]) / math.hypot(nx, ny), (n, 1)))
    pts, normals = np.concatenate(pts), np.concatenate(normals)
    _, idx = np.unique(np.round(pts / res).astype(int), axis=0, return_index=True)
    return pts[idx], normals[idx]


def pose_matrix(p) -> np.ndarray:
    c, s = math.cos(p[2]), math.sin(p[2])
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = p[:2]
    return m


def main() -> None:
    import open3d as o3d

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--building", type=float, default=0.0, help="add copies of the room's walls over a "
                    "building this many metres across (a static map as large as a real floor: registration_icp "
                    "builds its k-d tree of the whole target in every call; the distance field is built once)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    walls, normals = wall_cells()
    if args.building > 0:
        copies = [(dx, dy) for dx in np.arange(0, args.building, 10.0) for dy in np.arange(0, args.building, 8.0)
                  if (dx, dy) != (0, 0)]  # fmt: skip
        walls = np.concatenate([walls] + [walls[: len(normals)] + (dx, dy) for dx, dy in copies])
        normals = np.concatenate([normals] * (len(copies) + 1))
    field = SurfaceField.from_points(walls, 0.05, 0.3)
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[walls, np.zeros(len(walls))]))
    target.normals = o3d.utility.Vector3dVector(np.c_[normals, np.zeros(len(normals))])
    p2p = o3d.pipelines.registration.TransformationEstimationPointToPoint()
    p2l = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30)
    results: dict[str, list] = {"distance field (ltmap)": [], "open3d ICP point-to-point": [],
                                "open3d ICP point-to-plane": []}  # fmt: skip
    times: dict[str, float] = dict.fromkeys(results, 0.0)
    for _ in range(args.trials):
        true = (rng.uniform(0.6, 7.4), rng.uniform(0.6, 5.4), rng.uniform(-math.pi, math.pi))
        if np.any(np.hypot(*(walls - true[:2]).T) < 0.4):
            continue
        pts = cast(true, rng)
        err_r = rng.uniform(0, 0.15)
        err_a = rng.uniform(-math.pi, math.pi)
        init = (true[0] + err_r * math.cos(err_a), true[1] + err_r * math.sin(err_a),
                true[2] + math.radians(rng.uniform(-3, 3)))  # fmt: skip
        t0 = time.perf_counter()
        got = register(field, pts, init, 0.1).pose
        times["distance field (ltmap)"] += time.perf_counter() - t0
        results["distance field (ltmap)"].append(got)
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[pts, np.zeros(len(pts))]))
        for name, est in (("open3d ICP point-to-point", p2p), ("open3d ICP point-to-plane", p2l)):
            t0 = time.perf_counter()
            reg = o3d.pipelines.registration.registration_icp(source, target, 0.3, pose_matrix(init), est, crit)
            times[name] += time.perf_counter() - t0
            T = np.asarray(reg.transformation)
            results[name].append((T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])))
        for name in results:
            got = results[name][-1]
            results[name][-1] = (math.hypot(got[0] - true[0], got[1] - true[1]),
                                 abs(math.degrees(wrap(got[2] - true[2]))))  # fmt: skip
    n = len(results["distance field (ltmap)"])
    print(f"{n} scans, start error up to 0.15 m and 3 degrees, walls at 5 cm ({len(walls)} wall cells)")
    for name, errs in results.items():
        e = np.array(errs)
        print(f"{name:28s}: position error median {1000 * np.median(e[:, 0]):5.1f} mm, p95 "
              f"{1000 * np.percentile(e[:, 0], 95):5.1f} mm; heading median {np.median(e[:, 1]):.3f} deg, p95 "
              f"{np.percentile(e[:, 1], 95):.3f} deg; {1000 * times[name] / n:.2f} ms per scan")


if __name__ == "__main__":
    main()
