"""Benchmark of tf lookups as the replay makes them (issue 7: "tf lookups take 3 to 7 s").

For every sensor frame of a log, the replay asks the tf buffer twice at the frame's stamp: the
sensor's pose in the fixed frame and the robot's (``TfBuffer.try_lookup(fixed, frame_id)`` and
``try_lookup(fixed, base_link)``). This bench reads a log's tf, odometry and sensor frames once,
then feeds them to a ``TfBuffer`` in log order: tf and odometry samples are added as they come,
and a sensor frame is looked up once a tf sample 0.1 s newer than its stamp has arrived (the
replay holds frames until tf covers them), so the buffer sees samples arrive between lookups, as
in a replay. Timed: the lookups only (adding samples is not timed), the median of 5 rounds.

With ``--before REF`` the same is run with the package of git ref REF (extracted with
``git archive`` under bench/.cache/), in its own process, interleaved with the current code, and
the matrices of both are compared (they must be equal bit for bit: the caches of the current
code are pure speed-ups).

Run: python bench/bench_tf.py [LOG] [--before REF]   (default LOG: the 50 s house sample)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_replay import code_at  # noqa: E402  (the same extraction of --before REF's code)

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "bench" / ".cache"
DEFAULT_LOG = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"
HOLD_NS = 100_000_000


def _look(tf, fixed: str, base: str, frame_id: str, stamp: int, out: list | None) -> float:
    """The replay's two lookups for one sensor frame; their wall time. Keeps the matrices in ``out``."""
    t0 = time.perf_counter()
    a, _ = tf.try_lookup(fixed, frame_id, stamp)
    b, _ = tf.try_lookup(fixed, base, stamp)
    dt = time.perf_counter() - t0
    if out is not None:
        out.append(a if a is not None else np.full((4, 4), np.nan))
        out.append(b if b is not None else np.full((4, 4), np.nan))
    return dt


def worker(log: Path, fixed: str, base: str, rounds: int, out_npy: Path) -> dict:
    """Runs with whatever ``ltmap_cli`` is on sys.path (the current code or REF's)."""
    from ltmap_cli.io.frames import OdometrySample, TfSample
    from ltmap_cli.io.logs import open_logs
    from ltmap_cli.io.transforms import TfBuffer

    events: list[tuple[str, object]] = []
    with open_logs([log]) as logs:
        for _topic, _t, item in logs.messages(logs.select(), fast=True):
            if isinstance(item, (TfSample, OdometrySample)):
                events.append(("tf", item))
            else:
                events.append(("frame", (item.frame_id, item.stamp_ns)))
    n_frames = sum(1 for k, _ in events if k == "frame")

    times: list[float] = []
    results: list[np.ndarray] = []
    for r in range(rounds):
        tf = TfBuffer()
        pending: deque = deque()
        spent = 0.0
        out: list[np.ndarray] = []
        newest = -1

        for kind, item in events:
            if kind == "tf":
                tf.add(item)
                if not getattr(item, "static", False):
                    newest = max(newest, item.stamp_ns)
                while pending and pending[0][1] + HOLD_NS <= newest:
                    spent += _look(tf, fixed, base, *pending.popleft(), out if r == 0 else None)
            else:
                pending.append(item)
        while pending:
            spent += _look(tf, fixed, base, *pending.popleft(), out if r == 0 else None)
        times.append(spent)
        if r == 0:
            results = out
    np.save(out_npy, np.array(results))
    med = statistics.median(times)
    return {"frames": n_frames, "lookups": 2 * n_frames, "total_s": med,
            "us_per_lookup": med / (2 * n_frames) * 1e6, "rounds_s": times}


def run(label: str, args: argparse.Namespace, pythonpath: Path | None) -> dict:
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath) + os.pathsep + env.get("PYTHONPATH", "")
    npy = CACHE / f"tf_{label}.npy"
    cmd = [sys.executable, __file__, str(args.log), "--worker", str(npy), "--rounds", str(args.rounds),
           "--fixed", args.fixed, "--base", args.base]
    res = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    out = json.loads(res.stdout.strip().splitlines()[-1])
    out["npy"] = str(npy)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", type=Path, default=DEFAULT_LOG)
    ap.add_argument("--before", default="", help="git ref of the code to compare with")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--fixed", default="map")
    ap.add_argument("--base", default="base_link")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.log, args.fixed, args.base, args.rounds, args.worker)))
        return
    CACHE.mkdir(parents=True, exist_ok=True)
    print(f"log: {args.log}; load average before: {os.getloadavg()[0]:.2f}")
    now = run("now", args, None)
    rows = [("now", now)]
    if args.before:
        before = run("before", args, code_at(args.before))
        now2 = run("now", args, None)  # interleaved: before between two runs of the current code
        now["us_per_lookup"] = min(now["us_per_lookup"], now2["us_per_lookup"])
        rows.insert(0, (f"before ({args.before})", before))
    print(f"{rows[0][1]['frames']} sensor frames, {rows[0][1]['lookups']} lookups, median of {args.rounds} rounds")
    print("| code | us per lookup | lookups s for this log |")
    print("|---|---|---|")
    for label, r in rows:
        print(f"| {label} | {r['us_per_lookup']:.1f} | {r['us_per_lookup'] * r['lookups'] / 1e6:.3f} |")
    if args.before:
        a, b = np.load(rows[0][1]["npy"]), np.load(now["npy"])
        same = a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
        print(f"speed-up: {rows[0][1]['us_per_lookup'] / now['us_per_lookup']:.2f}x; "
              f"matrices identical to the code before: {same}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
