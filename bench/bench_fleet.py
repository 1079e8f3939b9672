"""Benchmark of `ltmap batch` (issue 19): a fleet of 4 sites x 3 days of the sample logs, replayed
as a batch on the embedded Dask engine against the same 12 replays one after another.

- ``serial``: the 12 days replayed in this process with the replay library, site after site and
  day after day, each day resuming from the one before (what a person's script does); the numba
  kernels are loaded first by one untimed replay, so the serial run pays no compilation;
- ``batch``: ``ltmap batch`` as the command runs it (``fleet.runner.execute``): the engine started
  (worker processes that import ltmap and load the kernels), the 4 chains in parallel, the
  summary written. Timed from before the engine starts to the summary.

Printed per round (serial and batch interleaved, 3 rounds by default): both times, the ratio
batch / serial (target <= 0.65 on 2 cores), the engine's start-up (target <= 10 s), the serial
run's CPU time (the cores its own threads keep busy: the best ratio any batch on this machine's
cores could reach is that over the number of cores), and a check that the batch's maps equal the
serial ones (map.pgm and long_term.pgm of every day); then the median and best ratio, and the
machine's load average before and after.

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
from ltmap_cli.pipeline.replay import Replay, ReplayRequest  # noqa: E402

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
    """CPU time of this process, all its threads."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def serial(days: dict[str, list[Path]], out: Path, plots: bool) -> tuple[float, float]:
    """Wall and CPU seconds of the 12 replays one after another."""
    cfg = load_config()
    set_dotted(cfg, "replay.plots", plots)
    t0, c0 = time.perf_counter(), cpu_s()
    for site, logs in days.items():
        prev = None
        for i, log in enumerate(logs, start=1):
            folder = out / site / f"day{i}"
            Replay(cfg, ReplayRequest([log], folder, resume=prev)).run()
            prev = folder
    return time.perf_counter() - t0, cpu_s() - c0


def batch(manifest: Path, out: Path, plots: bool, workers: int | None) -> tuple[float, float, bool, str]:
    """Wall seconds of the batch as the command runs it, its engine's start-up, whether every task
    was done, and the engine's description."""
    t0 = time.perf_counter()
    plan = build_plan(load_manifest(manifest), out, sets=[("replay.plots", plots)])
    engine = Engine(workers=workers)
    result, _ = execute(plan, engine)
    ok = all(s.status == DONE for s in result.states)
    return time.perf_counter() - t0, engine.startup_s, ok, result.engine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=None, help="local engine workers [default: the cores]")
    ap.add_argument(
        "--plots", action="store_true", help="write each day's plots (as ltmap replay does by default)"
    )
    ap.add_argument("--rounds", type=int, default=3, help="serial and batch runs, interleaved [3]")
    args = ap.parse_args()
    if len(SAMPLES) < 5:
        sys.exit(f"bench_fleet: the samples 01..05 are missing under {ROOT / 'sample_logs'}")
    cores = os.cpu_count() or 1
    print(f"machine: {platform.node()}, {cores} cores, Python {platform.python_version()}")
    load0 = os.getloadavg()
    tmp = Path(tempfile.mkdtemp(prefix="bench_fleet_"))
    ratios = []
    try:
        manifest, days = fleet(tmp)
        cfg = load_config()
        set_dotted(cfg, "replay.plots", False)
        Replay(cfg, ReplayRequest([SAMPLES[0]], tmp / "warm")).run()  # numba kernels loaded, untimed
        for r in range(1, args.rounds + 1):
            t_serial, c_serial = serial(days, tmp / f"serial{r}", args.plots)
            t_batch, startup, ok, engine = batch(manifest, tmp / f"batch{r}", args.plots, args.workers)
            same = all(
                (tmp / f"batch{r}" / s / f"day{i}" / f).read_bytes()
                == (tmp / f"serial{r}" / s / f"day{i}" / f).read_bytes()
                for s in days
                for i in range(1, DAYS + 1)
                for f in ("map.pgm", "long_term.pgm")
            )
            ratios.append(t_batch / t_serial)
            print(
                f"round {r}: serial {t_serial:.1f} s ({c_serial:.1f} s of CPU: {c_serial / t_serial:.2f} "
                f"cores busy, so no batch on {cores} cores can beat {c_serial / t_serial / cores:.2f}); "
                f"batch on {engine}: "
                f"{t_batch:.1f} s (engine start-up {startup:.1f} s, target <= 10 s)"
                f"{'' if ok else ', SOME TASKS FAILED'}; maps equal: {same}; ratio {ratios[-1]:.2f}"
            )
        print(
            f"ratio batch / serial: median {statistics.median(ratios):.2f}, best {min(ratios):.2f} of "
            f"{len(ratios)} rounds (target <= 0.65 on 2 cores)"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    load1 = os.getloadavg()
    print(
        f"load average (1, 5, 15 min) before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}; "
        f"after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}"
    )


if __name__ == "__main__":
    main()
