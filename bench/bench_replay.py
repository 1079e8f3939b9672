"""Benchmark of replay speed (SPEC 8): a 5-minute log, 640x480 depth at 30 Hz and a 720-beam laser
at 15 Hz, through the furnished house, replayed at 0.05 m. Target: at least 10x faster than real
time on 2 cores.

The log is simulated once (``ltmap simulate``, about 9 minutes on 2 cores) and cached under
``bench/.cache/replay_house/`` (git-ignored) with the static layer of the house plan; the scenario
is written by this script, so the cache is rebuilt when the scenario changes.

Per run the script replays the log with ``ltmap_cli.pipeline.replay.Replay`` (no plots, no MCAP output)
and prints: log seconds per wall second, the time per stage (read and decode, tf, ray casting,
ticks, projection, output) from the replay's own stage clock, frames integrated, and peak memory
(ru_maxrss of a fresh child process per configuration, so configurations do not share a peak).
Configurations, all measured in this run:

- ``serial``: the reference path: frames decoded by the generic deserializers in the main
  thread, depth images turned into (N, 3) float64 points, transformed, classified and deduped
  (``replay.fast_path: false``, ``replay.reader_thread: false``);
- ``exact``: CDR read directly with numpy, fused depth kernel, reader thread beside integration,
  every depth ray walked whole (``map.sensor.depth_integration: exact``); the same O bit for bit as
  ``serial`` (checked here: the O log-odds arrays of the two runs are compared);
- ``projective``: the default: ``exact`` with projective depth integration (``core.projective``),
  an approximation whose effect on the map is printed as IoU of LT and of P against ``exact``;
- ``rate5``: ``exact`` with ``map.sensor.depth_max_rate: 5`` (at most 5 depth frames per second
  per camera integrated; the others are not even decoded), an approximation whose effect on the
  map is printed as IoU of LT and of P against ``exact``.

- ``before`` (with ``--before REF``): the code of git ref REF (e.g. the commit before this
  work), extracted with ``git archive`` under ``bench/.cache``, on the serial path (the code
  before the pipeline rewrite had no other); ``before-exact``: REF's code in the exact
  configuration, ``before-default``: in its default one (for a REF that has the fast reader and
  the threads: compare it with ``projective``).

Every configuration runs in a fresh process, first replaying the 50 s house sample once so that
numba kernels are compiled or loaded from their cache before the timed run.

Run: python bench/bench_replay.py [--duration S] [--only serial,exact,projective,rate5] [--before REF]
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "bench" / ".cache"
PLAN = ROOT / "sample_logs" / "plans" / "house.svg"

# one 150 s loop through the house (map frame: x right, y up; metres, degrees): the living room
# (table, chair, ball), the kitchen, back, the bedroom, back; driven twice
LOOP = [
    (0, 4.6, 2.3, 180), (10, 4.6, 2.3, 180), (16, 4.6, 2.3, 90), (22, 5.9, 3.3, 90), (28, 5.9, 4.8, 90),
    (36, 7.5, 5.5, 30), (44, 8.0, 6.5, 90), (50, 8.0, 6.5, 200), (60, 6.5, 5.5, 230), (66, 5.9, 4.8, 270),
    (72, 5.9, 3.3, 270), (80, 4.5, 3.3, 180), (90, 2.0, 3.4, 180), (95, 1.95, 3.4, 90), (101, 1.95, 4.6, 90),
    (110, 3.5, 5.5, 45), (118, 3.8, 6.5, 90), (124, 3.8, 6.5, 270), (132, 1.95, 4.6, 250),
    (138, 1.95, 3.4, 270), (142, 3.5, 3.4, 360), (150, 4.6, 2.3, 540),
]


def scenario_yaml(duration: float) -> str:
    wps = []
    t_off, yaw_off = 0.0, 0.0
    while t_off < duration:
        for t, x, y, yaw in LOOP:
            if wps and t == 0:
                continue
            if t_off + t > duration + 150:
                break
            wps.append(f"      - {{t: {t_off + t:g}, x: {x}, y: {y}, yaw: {yaw + yaw_off:g}}}")
        t_off += 150
        yaw_off += 360
    return "\n".join([
        "# bench/bench_replay.py: 5 minutes in the furnished house, laser 720 beams at 15 Hz, depth",
        "# 640x480 at 30 Hz (SPEC 8). Written by the bench; do not edit by hand.",
        "name: bench-house",
        f"plan: {PLAN}",
        "wall_height: 2.5",
        f"duration: {duration:g}",
        "seed: 8",
        "robot:",
        "  radius: 0.25",
        "  odometry_drift: [0.002, 0.001, 0.05]",
        "  path:",
        "    waypoints:",
        *wps,
        "sensors:",
        "  laser: {beams: 720, fov: 360, range_max: 10, rate: 15, noise: 0.01, mount: {xyz: [0.15, 0, 0.25]}}",
        "  depth: {mount: {xyz: [0.1, 0, 1.1]}, pitch: 25, width: 640, height: 480, rate: 30, noise: 0.002,",
        "          quantization: 0.0025}",
        "objects:",
        "  - {id: table, kind: table, pose: {x: 2.3, y: 2.35}, size: [1.6, 0.9, 0.75]}",
        "  - {id: chair, kind: chair, pose: {x: 2.3, y: 1.45, yaw: 90}, size: [0.45, 0.45, 0.45]}",
        "  - {id: ball, kind: sphere, label: ball, pose: {x: 3.5, y: 3.0}, radius: 0.1}",
        "  - {id: box, kind: box, pose: {x: 3.2, y: 1.0}, size: [0.4, 0.4, 0.6], present: [[0, 120]]}",
        "  - {id: bin, kind: cylinder, pose: {x: 7.2, y: 6.8}, radius: 0.2, height: 0.6, present: [[100, null]]}",
        "doors:",
        "  - {id: bath-door, from: [6.5, 1.7], to: [6.5, 2.5], thickness: 0.04, height: 2.0, closed: [[0, null]]}",
        "people:",
        "  - id: person",
        "    path:",
        "      - {t: 4, x: 3.8, y: 0.8}",
        "      - {t: 9, x: 3.8, y: 3.6}",
        "      - {t: 14, x: 1.0, y: 3.7}",
        "  - id: cook",
        "    path:",
        "      - {t: 170, x: 8.2, y: 4.5}",
        "      - {t: 180, x: 7.0, y: 7.0}",
        "      - {t: 190, x: 6.0, y: 6.0}",
        "",
    ])


def ltmap_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "ltmap_cli", *args]


def simulated_log(prefix: str, text: str, what: str, minutes: float | None = None) -> Path:
    """``log.mcap`` of the scenario ``text``, simulated once into ``bench/.cache/<prefix>_<hash of
    the text>/`` (so a changed scenario is simulated again); the benches share it."""
    tag = hashlib.sha1(text.encode()).hexdigest()[:10]
    folder = CACHE / f"{prefix}_{tag}"
    log = folder / "log.mcap"
    if log.is_file():
        return log
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scenario.yaml").write_text(text)
    t0 = time.perf_counter()
    about = f"; about {minutes:.0f} min" if minutes is not None else ""
    print(f"simulating {what} into {folder} (once{about}) ...", flush=True)
    subprocess.run(ltmap_cmd("simulate", str(folder / "scenario.yaml"), "-o", str(log)), check=True, env=code_env(),
                   stdout=subprocess.DEVNULL)  # fmt: skip
    print(f"  done in {time.perf_counter() - t0:.0f} s", flush=True)
    return log


def warm_kernels(Replay, ReplayRequest, Config, out: Path, fast: bool, threads: bool, log: Path | None = None) -> None:
    """A replay of the house sample, so that every numba kernel is compiled or loaded from its
    cache before a timed run (``Replay`` & co. of the code under test, which may be older), and
    of the first second of ``log``, the timed log: its depth encoding's kernels too (the house is
    16UC1; a 32FC1 log compiled its own for 5 to 8 s inside the first timed replay of each
    code)."""
    warm = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"
    for path, end_s, name in ((warm, 0.0, "warmup"), (log, 1.0, "warmup_log")):
        if path is None or not path.exists():
            continue
        cfg = Config()
        cfg.replay.plots = False
        cfg.replay.end_s = end_s
        run = Replay(cfg, ReplayRequest([path], out / name))
        run.fast, run.threads = fast, threads
        run.run()


def ensure_log(duration: float) -> tuple[Path, Path]:
    """(log.mcap, static folder) of the bench scenario, simulated once and cached."""
    log = simulated_log(f"replay_house_{int(duration)}s", scenario_yaml(duration), f"{duration:g} s of log",
                        minutes=duration * 1.8 / 60)  # fmt: skip
    static = log.parent / "static"
    if not (static / "static.yaml").is_file():
        subprocess.run(ltmap_cmd("build-static", str(PLAN), "-o", str(static), "--force"), check=True, env=code_env(),
                       stdout=subprocess.DEVNULL)  # fmt: skip
    return log, static


if __name__ == "__main__" and "--generate-only" in sys.argv:
    ensure_log(float(sys.argv[sys.argv.index("--generate-only") + 1]))
    sys.exit(0)


CONFIGS = {
    # name: (fast, threads, depth_max_rate, map.sensor.depth_integration)
    "before": (False, False, 0.0, None),  # the code of --before REF (git archive), as it was
    "before-exact": (True, True, 0.0, "exact"),  # REF's code in the exact configuration (REF has fast/threads)
    "before-default": (True, True, 0.0, None),  # REF's code in its default configuration (threads, its integration)
    "serial": (False, False, 0.0, "exact"),
    "exact": (True, True, 0.0, "exact"),
    "exact-1thread": (True, False, 0.0, "exact"),
    "projective": (True, True, 0.0, "projective"),  # the default (core.projective)
    "rate10": (True, True, 10.0, "exact"),
    "rate5": (True, True, 5.0, "exact"),
}


def child(name: str, log: Path, static: Path, out: Path) -> None:
    """One configuration in this (fresh) process; prints one JSON line."""
    import resource

    import numpy as np

    t_proc = time.perf_counter()
    import ltmap_cli
    from ltmap_cli.config import Config
    from ltmap_cli.core.projection import project
    try:
        from ltmap_cli.pipeline.replay import Replay, ReplayRequest
    except ImportError:  # --before a commit older than the pipeline package
        from ltmap_cli.replay import Replay, ReplayRequest

    fast, threads, rate, integration = CONFIGS[name]
    warm_kernels(Replay, ReplayRequest, Config, out, fast, threads)
    cfg = Config()
    cfg.replay.plots = False
    cfg.map.sensor.depth_max_rate = rate
    if integration is not None:  # (code before the setting ignores it: it was exact)
        cfg.map.sensor.depth_integration = integration
    run = Replay(cfg, ReplayRequest([log], out, static=static))
    run.fast, run.threads = fast, threads
    t0 = time.perf_counter()
    rep = run.run()
    wall = time.perf_counter() - t0
    lmap = run.lmap
    p = project(lmap)
    np.savez(out / "bench_state.npz", P=p.data, P_origin=np.asarray(p.origin, dtype=np.float64),
             **lmap.state_arrays())  # fmt: skip
    print(json.dumps({
        "name": name, "wall_s": wall, "process_s": time.perf_counter() - t_proc, "code": ltmap_cli.__file__,
        "log_s": rep["log_duration_s"], "speed": rep["log_duration_s"] / wall, "stage_s": rep.get("stage_s", {}),
        "frames_used": rep["frames_used"], "frames_over_depth_max_rate": rep.get("frames_over_depth_max_rate", {}),
        "rays": rep["rays"], "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "map_mb": rep["map_memory_mb"], "blocks": rep["voxels"]["observed_blocks"],
        "lt_occupied": rep["voxels"]["long_term_occupied"], "events": rep["events"]["count"],
    }), flush=True)


def code_env(ref: str | None = None) -> dict:
    """The environment of a child process that runs the code of git ``ref`` (``code_at``), or
    with None this checkout's: the tree this file is in, not whichever ltmap the venv has
    installed (a bench run from a second worktree measured the first one's code as "now").
    Without ``PYTHONDONTWRITEBYTECODE``: a user's Python writes ltmap's ``.pyc`` files at its
    first run and reads them after; with it set (as on some CI and sandbox machines) every
    process compiled ltmap's modules from source again, 0.2 to 0.4 s of each whole-process
    figure that no user pays."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = str(code_at(ref) if ref else ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def code_at(ref: str) -> Path:
    """The package as it was at git ref ``ref``, extracted under bench/.cache (once), for "before"."""
    sha = subprocess.run(["git", "rev-parse", ref], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout.strip()
    path = CACHE / f"code_{sha[:10]}"
    if not (path / "ltmap_cli").is_dir():
        path.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "archive", sha, "ltmap_cli"], cwd=ROOT, check=True, capture_output=True)
        subprocess.run(["tar", "-x", "-C", str(path)], input=archive.stdout, check=True)
    return path


def run_config(name: str, log: Path, static: Path, work: Path, before: str | None = None) -> dict:
    out = work / name
    out.mkdir(parents=True, exist_ok=True)
    env = code_env(before or "HEAD") if name.startswith("before") else code_env()
    proc = subprocess.run([sys.executable, __file__, "--child", name, str(log), str(static), str(out)],
                          check=True, capture_output=True, text=True, env=env)
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    res["out"] = str(out)
    return res


def _keys(arrays, prefix: str, channel: str, pred) -> set:
    import numpy as np

    coords = arrays[f"{prefix}block_coords"].astype(np.int64)
    vals = arrays[f"{prefix}{channel}"]
    b, o = np.nonzero(pred(vals))
    k = coords[b] * 8 + np.stack([o >> 6, (o >> 3) & 7, o & 7], axis=1)
    return set(map(tuple, k.tolist()))


def iou(a, b) -> float:
    """Intersection over union of two collections of keys (1.0 when both are empty): sets,
    1-D arrays of packed keys, or (n, 3) arrays of voxel keys. The one IoU of the benches."""
    import numpy as np

    def as_set(k):
        if isinstance(k, (set, frozenset)):
            return k
        k = np.asarray(k, dtype=np.int64)
        if k.ndim == 2:
            k = k.reshape(-1, 3) + (1 << 20)
            k = (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]
        return set(k.tolist())

    sa, sb = as_set(a), as_set(b)
    return len(sa & sb) / len(sa | sb) if (sa or sb) else 1.0


def compare(ref: dict, other: dict) -> dict:
    """Bit-for-bit check of O and D, and IoU of O / LT / P occupied against ``ref``."""
    import numpy as np

    a = np.load(Path(ref["out"]) / "bench_state.npz")
    b = np.load(Path(other["out"]) / "bench_state.npz")
    same = all(a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes()
               for k in a.files if k.startswith(("O_", "D_")))  # fmt: skip
    res = {"identical": bool(same)}
    # the code before the quiet blocks (issue 17) stamps every miss: the map is the same when O's
    # log-odds, D and the known voxels (stamp > 0) are, whatever the stamps of clamped-free voxels
    res["map_identical"] = bool(
        all(a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes()
            for k in a.files if k.startswith(("O_", "D_")) and k != "O_stamp")
        and a["O_stamp"].shape == b["O_stamp"].shape and np.array_equal(a["O_stamp"] > 0, b["O_stamp"] > 0)
    )  # fmt: skip
    res["iou_O"] = iou(_keys(a, "O_", "logodds", lambda v: v > 0), _keys(b, "O_", "logodds", lambda v: v > 0))
    res["iou_LT"] = iou(_keys(a, "D_", "lt", lambda v: v >= 0.65), _keys(b, "D_", "lt", lambda v: v >= 0.65))
    pa, pb = a["P"], b["P"]
    if pa.shape == pb.shape and np.array_equal(a["P_origin"], b["P_origin"]):
        occ_a, occ_b = pa >= 65, pb >= 65
        res["iou_P"] = float((occ_a & occ_b).sum() / max((occ_a | occ_b).sum(), 1))
        res["P_cells_differ"] = int((pa != pb).sum())
    else:
        res["iou_P"] = None
    return res


def machine() -> str:
    cpu = "?"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import numba
    import numpy

    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}; Python "
            f"{platform.python_version()}, numpy {numpy.__version__}, numba {numba.__version__}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=300.0, help="log length, s (default 300: the SPEC's)")
    ap.add_argument("--only", default="serial,exact,projective,rate5", help="configurations, comma separated: "
                    + ", ".join(CONFIGS))
    ap.add_argument("--before", default="", help="git ref of the code before this work: adds the configuration "
                    "'before' (that code, as it was, extracted under bench/.cache)")
    args = ap.parse_args()
    names = [n for n in args.only.split(",") if n]
    if args.before and not any(n.startswith("before") for n in names):
        names.insert(0, "before")
    for n in names:
        if n not in CONFIGS:
            ap.error(f"unknown configuration {n}; use {', '.join(CONFIGS)}")
    log, static = ensure_log(args.duration)
    print(f"bench_replay: {datetime.date.today()}, {machine()}")
    print(f"log: {log} ({log.stat().st_size / 2**20:.0f} MiB), static: {static}")
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    work = Path(tempfile.mkdtemp(prefix="bench_replay_"))
    results = {}
    for n in names:
        print(f"  running {n} ...", flush=True)
        results[n] = run_config(n, log, static, work, args.before)
        print(f"    {results[n]['speed']:.2f}x real time ({results[n]['code']})", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print()
    stages = ["read", "read_thread", "tf", "rays", "cast", "rays_wait", "integrate", "ticks", "projection", "output"]
    print("| config | log s | wall s | x real time | " + " | ".join(stages)
          + " | depth frames used | rays | peak MB | map MB |")
    print("|---" * (8 + len(stages)) + "|")
    for n, r in results.items():
        st = r["stage_s"]
        depth = sum(v for k, v in r["frames_used"].items() if "depth" in k)
        print(f"| {n} | {r['log_s']:.1f} | {r['wall_s']:.2f} | {r['speed']:.2f} | "
              + " | ".join(f"{st.get(s, 0.0):.2f}" for s in stages)
              + f" | {depth} | {r['rays']} | {r['peak_mb']:.0f} | {r['map_mb']:.0f} |")
    print()
    ref = "exact" if "exact" in results else names[0]
    if "serial" in results:
        for n in results:
            if n != "serial":
                c = compare(results["serial"], results[n])
                if n == "before":
                    print(f"serial vs before: speed ratio {results['serial']['speed'] / results[n]['speed']:.2f}x, "
                          f"IoU O {c['iou_O']:.4f}, LT {c['iou_LT']:.4f}, P {c['iou_P']} (before: BLAS "
                          f"transform, so not bit for bit)")
                    continue
                print(f"{n} vs serial: speed ratio {results[n]['speed'] / results['serial']['speed']:.2f}x, "
                      f"O and D bit for bit identical: {c['identical']}, IoU O {c['iou_O']:.4f}, "
                      f"LT {c['iou_LT']:.4f}, P {c['iou_P']}")
    if "before-exact" in results and "exact" in results:
        c = compare(results["before-exact"], results["exact"])
        print(f"exact vs before-exact ({args.before}): speed ratio "
              f"{results['exact']['speed'] / results['before-exact']['speed']:.2f}x, O and D bit for bit identical: "
              f"{c['identical']} (log-odds, D and known voxels: {c['map_identical']}), IoU O {c['iou_O']:.4f}, "
              f"LT {c['iou_LT']:.4f}, P {c['iou_P']}")  # fmt: skip
    for n in results:
        if (n.startswith("rate") or n == "projective") and ref in results:
            c = compare(results[ref], results[n])
            print(f"{n} vs {ref}: speed ratio {results[n]['speed'] / results[ref]['speed']:.2f}x, "
                  f"IoU of occupied voxels O {c['iou_O']:.4f}, LT {c['iou_LT']:.4f}, P cells {c['iou_P']:.4f} "
                  f"({c.get('P_cells_differ')} P cells differ); LT occupied {results[n]['lt_occupied']} vs "
                  f"{results[ref]['lt_occupied']}; events {results[n]['events']} vs {results[ref]['events']}")
    for n, r in results.items():
        print(f"{n}: {r['speed']:.2f}x real time ({'meets' if r['speed'] >= 10 else 'misses'} the 10x target); "
              f"process wall (imports, numba cache, replay) {r['process_s']:.1f} s")
    print(f"outputs kept in {work}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]), Path(sys.argv[5]))
    else:
        main()
