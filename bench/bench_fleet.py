"""Benchmark of `ltmap batch` (issue 19): a fleet of 4 sites x 3 days of the sample logs, replayed
as a batch on the embedded Dask engine against the same 12 replays one after another, in two ways.

- ``by hand``: the 12 days as the commands a person types, one after another, each a fresh
  process: ``ltmap replay LOG -o OUT/siteN/day1 -q --no-plots``, then ``ltmap replay LOG -o
  OUT/siteN/day2 --resume OUT/siteN/day1 -q --no-plots`` and so on (docs/fleet.md: day N of a batch
  is that command). Each command pays Python's and ltmap's imports and the kernels' load from
  numba's cache, as the user's own serial run does. This is the baseline issue 19 speaks of;
- ``warm``: the same 12 days replayed in this process with the replay library, site after site and
  day after day, each day resuming from the one before (what a person's Python script does); the
  numba kernels are loaded first by one untimed replay, so this run pays no start-up at all: the
  harder baseline;
- ``batch``: ``ltmap batch`` as the command runs it (``fleet.runner.execute``): the engine started
  (worker processes that import ltmap and load the kernels), the 4 chains in parallel, the
  summary written. Timed from before the engine starts to the summary.

Printed per round (the three interleaved, 3 rounds by default): each one's wall and CPU time
(user + system of every thread and process it ran: this process, the commands, the engine's
workers), the two ratios batch / by hand and batch / warm (target <= 0.65 on 2 cores), the engine's
start-up (target <= 10 s), the cores the warm run keeps busy on its own (CPU / wall: the best ratio
any batch could reach against it is that over the number of cores), and a check that the batch's
maps equal both serial runs' (map.pgm and long_term.pgm of every day); then the median and best
of each ratio, and the machine's load average before and after every round.

The logs are the 30 s samples 01..05 (02 and 03 have a depth camera); site i replays samples
i, i+1, i+2 (mod 5) on its three days. Day plots are off (``replay.plots: false``) unless --plots.

Run: python bench/bench_fleet.py [--workers 2] [--plots] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ltmap_cli.config import load_config, set_dotted  # noqa: E402
from ltmap_cli.fleet.graph import build_plan  # noqa: E402
from ltmap_cli.fleet.manifest import load_manifest  # noqa: E402
from ltmap_cli.fleet.runner import DONE, Engine, execute  # noqa: E402
from ltmap_cli.outputs.folder import OutputFolder  # noqa: E402
from ltmap_cli.pipeline.replay import Replay, ReplayRequest  # noqa: E402

# the environment as the user's shell gave it: Dask's nanny writes OMP_NUM_THREADS and the like
# into this process's environment when it starts a worker, and the later commands must not inherit them
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
SAMPLES = sorted((ROOT / "sample_logs" / "scenarios").glob("0[1-5]*/log.mcap"))
SITES, DAYS = 4, 3


def fleet(tmp: Path) -> tuple[Path, dict[str, list[Path]]]:
    days = {f"site{i + 1}": [SAMPLES[(i + k) % len(SAMPLES)] for k in range(DAYS)] for i in range(SITES)}
    text = "sites:\n" + "".join(
        f"  {s}:\n    days:\n" + "".join(f"      - [{p}]\n" for p in logs) for s, logs in days.items()
    )
    (tmp / "fleet.yaml").write_text(text)
    return tmp / "fleet.yaml", days


def cpu_s() -> float:
    """CPU time of this process (all its threads) and of its children that ended (the commands,
    the engine's worker processes once the engine is closed)."""
    t = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        t += r.ru_utime + r.ru_stime
    return t


def by_hand(days: dict[str, list[Path]], out: Path, plots: bool) -> tuple[float, float]:
    """Wall and CPU seconds of the 12 ``ltmap replay`` commands one after another."""
    t0, c0 = time.perf_counter(), cpu_s()
    for site, logs in days.items():
        prev = None
        for i, log in enumerate(logs, start=1):
            folder = out / site / f"day{i}"
            cmd = [sys.executable, "-m", "ltmap_cli", "replay", str(log), "-o", str(folder), "-q"]
            cmd += ["--resume", str(prev)] if prev else []
            cmd += [] if plots else ["--no-plots"]
            subprocess.run(cmd, check=True, env=ENV, stdout=subprocess.DEVNULL)
            prev = folder
    return time.perf_counter() - t0, cpu_s() - c0


def serial(days: dict[str, list[Path]], out: Path, plots: bool) -> tuple[float, float]:
    """Wall and CPU seconds of the 12 replays one after another in this (warm) process."""
    cfg = load_config()
    set_dotted(cfg, "replay.plots", plots)
    t0, c0 = time.perf_counter(), cpu_s()
    for site, logs in days.items():
        prev = None
        for i, log in enumerate(logs, start=1):
            folder = out / site / f"day{i}"
            with OutputFolder(folder, command="replay") as o:  # as ltmap replay writes it
                Replay(cfg, ReplayRequest([log], o.staging, resume=prev, final_dir=o.final)).run()
                o.commit({"logs": [str(log)]})
            prev = folder
    return time.perf_counter() - t0, cpu_s() - c0


def batch(
    manifest: Path, out: Path, plots: bool, workers: int | None
) -> tuple[float, float, float, bool, str]:
    """Wall and CPU seconds of the batch as the command runs it (the engine closed: its workers'
    CPU counted), its engine's start-up, whether every task was done, and the engine's
    description."""
    t0, c0 = time.perf_counter(), cpu_s()
    plan = build_plan(load_manifest(manifest), out, sets=[("replay.plots", plots)])
    engine = Engine(workers=workers)
    result, _ = execute(plan, engine)
    ok = all(s.status == DONE for s in result.states)
    return time.perf_counter() - t0, cpu_s() - c0, engine.startup_s, ok, result.engine


def same_maps(a: Path, b: Path, days: dict[str, list[Path]]) -> bool:
    """map.pgm and long_term.pgm of every day equal, byte for byte."""
    return all(
        (a / s / f"day{i}" / f).read_bytes() == (b / s / f"day{i}" / f).read_bytes()
        for s in days
        for i in range(1, DAYS + 1)
        for f in ("map.pgm", "long_term.pgm")
    )


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=None, help="local engine workers [default: the cores]")
    ap.add_argument(
        "--plots", action="store_true", help="write each day's plots (as ltmap replay does by default)"
    )
    ap.add_argument("--rounds", type=int, default=3, help="by hand, warm and batch runs, interleaved [3]")
    args = ap.parse_args()
    if len(SAMPLES) < 5:
        sys.exit(f"bench_fleet: the samples 01..05 are missing under {ROOT / 'sample_logs'}")
    cores = os.cpu_count() or 1
    print(f"machine: {platform.node()}, {cores} cores, Python {platform.python_version()}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="bench_fleet_"))
    hand_ratios, warm_ratios = [], []
    try:
        manifest, days = fleet(tmp)
        cfg = load_config()
        set_dotted(cfg, "replay.plots", False)
        Replay(cfg, ReplayRequest([SAMPLES[0]], tmp / "warm")).run()  # numba kernels loaded, untimed
        for r in range(1, args.rounds + 1):
            load0 = load()
            t_hand, c_hand = by_hand(days, tmp / f"hand{r}", args.plots)
            t_warm, c_warm = serial(days, tmp / f"warm{r}", args.plots)
            t_batch, c_batch, startup, ok, engine = batch(
                manifest, tmp / f"batch{r}", args.plots, args.workers
            )
            same = same_maps(tmp / f"batch{r}", tmp / f"hand{r}", days) and same_maps(
                tmp / f"batch{r}", tmp / f"warm{r}", days
            )
            hand_ratios.append(t_batch / t_hand)
            warm_ratios.append(t_batch / t_warm)
            print(
                f"round {r} (load average 1/5/15 min before: {load0}, after: {load()}):\n"
                f"  by hand (12 ltmap replay commands): {t_hand:5.1f} s, {c_hand:5.1f} s of CPU\n"
                f"  warm (12 replays in one process):   {t_warm:5.1f} s, {c_warm:5.1f} s of CPU "
                f"({c_warm / t_warm:.2f} cores busy: no batch on {cores} cores beats "
                f"{c_warm / t_warm / cores:.2f} of it)\n"
                f"  batch on {engine}: {t_batch:5.1f} s, {c_batch:5.1f} s of CPU (engine start-up "
                f"{startup:.1f} s, target <= 10 s){'' if ok else ', SOME TASKS FAILED'}; maps equal: {same}\n"
                f"  ratio batch / by hand {hand_ratios[-1]:.2f}, batch / warm {warm_ratios[-1]:.2f} "
                f"(target <= 0.65)"
            )
        for name, ratios in (("by hand", hand_ratios), ("warm", warm_ratios)):
            print(
                f"ratio batch / {name}: median {statistics.median(ratios):.2f}, best {min(ratios):.2f} of "
                f"{len(ratios)} rounds: target <= 0.65 on 2 cores "
                f"{'met' if statistics.median(ratios) <= 0.65 else 'NOT met'} (median)"
            )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
