"""The map's steps, the current code against REF's, in serial replays alternating (issue 17).

On a noisy machine (a shared VM: the same code's replay varies by 30 % within an hour) whole-run
figures cannot resolve a change of a few per cent. This runs each scene's log ``--rounds`` times
per code (after one run of each that is not counted: a code's first run may compile its kernels),
alternating which goes first, each run a fresh process on the serial path (one thread:
no worker contention), and sums the thread CPU of each ``LayeredMap`` step: the projection
(``depth_projection``), the rays' voxels (``frame_voxels``: the tails, up to session 19), the
whole worker part of a depth frame (``depth_voxels``: both, and the tails' masks), the map thread's updates
(``apply_voxels``, and within it the lists and the masks), the tick rules (``end_tick``), and the
whole process. Ratios are now / before; a step whose code did not change shows the machine's
noise between processes (a few per cent). Then every array of the final state is compared: O's
stamps may differ where quiet blocks skip misses; O's log-odds and D by their blocks'
coordinates (content), and D's block order.

Run: python bench/bench_stages_ab.py --before REF [--scenes room,office] [--rounds 3]
(the scenes are bench_long_rays.py's, simulated and cached there).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_long_rays  # noqa: E402  (the scenes and their cached logs)
import bench_replay  # noqa: E402  (code_at, machine)

STEPS = {  # name: LayeredMap method timed
    "cast": "depth_voxels",  # a depth frame's worker part: the projection, the tails, their masks
    "projection": "depth_projection",
    "tails": "frame_voxels",
    "apply": "apply_voxels",
    "apply_lists": "_apply",
    "apply_masks": "_apply_masks",
    "ticks": "end_tick",
}


def child(log: str, out: str) -> None:
    """One serial replay; the steps' thread CPU and the process's as JSON on stdout, the final
    state in ``out``."""
    import numpy as np

    from ltmap_cli.config import Config
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    spent: dict[str, float] = defaultdict(float)

    def timed(name, f):
        def wrapper(*a, **k):
            c = time.thread_time()
            try:
                return f(*a, **k)
            finally:
                spent[name] += time.thread_time() - c

        return wrapper

    for name, method in STEPS.items():
        setattr(LayeredMap, method, timed(name, getattr(LayeredMap, method)))
    cfg = Config()
    cfg.replay.plots = False
    run = Replay(cfg, ReplayRequest([Path(log)], Path(out) / "replay"))
    run.fast, run.threads = True, False
    c0 = time.process_time()
    run.run()
    spent["process"] = time.process_time() - c0
    np.savez(Path(out) / "state.npz", **run.lmap.state_arrays())
    print(json.dumps(spent))


def compare(a_path: Path, b_path: Path) -> str:
    import numpy as np

    a, b = np.load(a_path), np.load(b_path)
    same = [k for k in a.files if a[k].shape == b[k].shape and np.array_equal(a[k], b[k])]
    differ = sorted(set(a.files) - set(same))

    def by_coords(z, grid):
        coords = z[f"{grid}_block_coords"]
        order = np.lexsort(coords.T[::-1])
        return coords[order], {k: z[k][order] for k in z.files if k.startswith(grid + "_") and z[k].shape[:1] == coords.shape[:1]}

    content = True
    for grid in ("O", "D"):
        ca, va = by_coords(a, grid)
        cb, vb = by_coords(b, grid)
        keys = [k for k in va if not k.endswith(("block_coords", "_stamp"))]
        content &= np.array_equal(ca, cb) and all(np.array_equal(va[k], vb[k]) for k in keys)
    return f"arrays that differ: {', '.join(differ) or 'none'}; O (but stamps) and D by block coordinates the same: {content}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="git ref of the code to compare with")
    ap.add_argument("--scenes", default="room,office", help=f"of {','.join(bench_long_rays.SCENES)}")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"bench_stages_ab: {bench_replay.machine()}")
    bench_replay.code_at(args.before)  # (extracted once, before the rounds)
    work = Path(tempfile.mkdtemp(prefix="bench_stages_ab_"))
    for scene in args.scenes.split(","):
        log = bench_long_rays.ensure_log(scene)
        spent = {"now": [], "before": []}
        for r in range(-1, args.rounds):  # round -1: each code once, not counted (a code's first run
            for which in ("now", "before") if r % 2 == 0 else ("before", "now"):  # compiles its kernels)
                env = bench_replay.code_env(args.before if which == "before" else None)
                out = work / scene / which
                out.mkdir(parents=True, exist_ok=True)
                proc = subprocess.run([sys.executable, __file__, "--child", str(log), str(out)], env=env,
                                      capture_output=True, text=True, check=True)  # fmt: skip
                if r >= 0:
                    spent[which].append(json.loads(proc.stdout.strip().splitlines()[-1]))
        line = [f"{scene} ({args.rounds} rounds, CPU s a run now / before, ratio):"]
        for name in ("process", *STEPS):
            a = sum(x.get(name, 0.0) for x in spent["now"]) / args.rounds
            b = sum(x.get(name, 0.0) for x in spent["before"]) / args.rounds
            line.append(f"{name} {a:.2f} / {b:.2f} ({a / b:.3f})" if b else f"{name} {a:.2f} / -")
        print("  " + line[0] + " " + "; ".join(line[1:]), flush=True)
        print(f"  {scene}: {compare(work / scene / 'now' / 'state.npz', work / scene / 'before' / 'state.npz')}")
    print(f"outputs kept in {work}")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--child":
        child(sys.argv[2], sys.argv[3])
    else:
        main()
