"""Tick rules (SPEC 2.2) under a tick-heavy load: ms per ``LayeredMap.end_tick``.

A sensor at the centre of a 8 x 6 m room, 2.5 m walls, sweeps +-60 deg; each frame casts 4000
rays (a 160 x 120 depth image's worth after deduplication) to the walls, a box that comes and
goes (present for 20 s of every 40 s), and noise points in front of the walls; 6 frames per
0.2 s tick (a 30 Hz camera), 600 ticks (2 minutes of log). Only ``end_tick`` is timed (the
frames' integration is not), median of --rounds rounds after one warm-up round.

``--before REF`` runs the same workload on git revision REF's code too (extracted to a
temporary folder, run in a child process), in the same run, and prints both and their ratio.

    python bench/bench_ticks.py [--rounds 3] [--ticks 600] [--before REF]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

WORKLOAD = r"""
import json, sys, time
import numpy as np
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap

ticks, rounds = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
ORIGIN = np.array([4.0, 3.0, 1.0])


def frame(t, rng):
    yaw = np.radians(60.0) * np.sin(2 * np.pi * t / 12.0)
    a = yaw + rng.uniform(-0.5, 0.5, 4000)
    el = rng.uniform(-0.6, 0.3, 4000)
    d = np.stack([np.cos(a) * np.cos(el), np.sin(a) * np.cos(el), np.sin(el)], axis=1)
    # distance to the walls of the box [0, 8] x [0, 6] x [0, 2.5]
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(d[:, 0] > 0, (8.0 - ORIGIN[0]) / d[:, 0], -ORIGIN[0] / d[:, 0])
        ty = np.where(d[:, 1] > 0, (6.0 - ORIGIN[1]) / d[:, 1], -ORIGIN[1] / d[:, 1])
        tz = np.where(d[:, 2] > 0, (2.5 - ORIGIN[2]) / d[:, 2], -ORIGIN[2] / d[:, 2])
    r = np.minimum(np.minimum(tx, ty), tz)
    if (t % 40.0) < 20.0:  # a box 1.5 m ahead of the sensor's mean view
        box = (np.abs(d[:, 1] / np.maximum(d[:, 0], 1e-9)) < 0.15) & (d[:, 0] > 0) & (d[:, 2] < 0)
        r = np.where(box, np.minimum(r, 1.5 / np.maximum(d[:, 0], 1e-9)), r)
    r = r + rng.normal(0.0, 0.01, len(r))
    return ORIGIN + d * r[:, None]


def one_round():
    m = LayeredMap(MapConfig())
    spent = 0.0
    for k in range(ticks):
        for f in range(6):
            m.integrate(ORIGIN, frame(k * 0.2 + f / 30.0, rng), max_range=8.0, dedupe=True)
        t0 = time.perf_counter()
        m.end_tick()
        spent += time.perf_counter() - t0
    return spent * 1e3 / ticks, int(m.D.n_blocks)


one_round_warm = one_round()  # compile / load the kernels
times = [one_round() for _ in range(rounds)]
print(json.dumps({"ms_per_tick": sorted(t for t, _ in times)[len(times) // 2], "all": [t for t, _ in times],
                  "d_blocks": times[0][1]}))
"""


def run(tree: Path, ticks: int, rounds: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    r = subprocess.run([sys.executable, "-c", WORKLOAD, str(ticks), str(rounds)], cwd=tree, env=env,
                       capture_output=True, text=True, check=True)  # fmt: skip
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ticks", type=int, default=600)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--before", help="a git revision to measure in the same run")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    results = {}
    t0 = time.perf_counter()
    if args.before:
        with tempfile.TemporaryDirectory() as tmp:
            archive = subprocess.run(["git", "archive", args.before], cwd=ROOT, capture_output=True, check=True)
            subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
            results[f"before ({args.before})"] = run(Path(tmp), args.ticks, args.rounds)
    results["now"] = run(ROOT, args.ticks, args.rounds)
    for name, r in results.items():
        print(f"{name:>24}: {r['ms_per_tick']:.3f} ms per tick (rounds: "
              f"{', '.join(f'{v:.3f}' for v in r['all'])}; D blocks {r['d_blocks']})")  # fmt: skip
    if args.before:
        a, b = (r["ms_per_tick"] for r in results.values())
        print(f"now / before: {b / a:.3f}")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
