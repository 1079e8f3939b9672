"""Benchmark of memory and per-frame cost at scale (SPEC 8): a 100 m x 100 m office floor at 0.05 m.

"Memory grows with the space observed, not with the bounding box: a 100 m x 100 m floor at
0.05 m fits in 1.5 GB", and the replay cost per frame must not grow with the size of the map
already built.

The floor: outer walls 100 x 100 m; 100 office blocks of 8 x 8 m (walls 0.1 m, a 1 m door in
the north and south sides) on a 10 m grid, so corridors 2 m wide run between them in both directions; boxes
here and there in the corridors. The robot drives a serpentine along the nine east-west
corridors (y = 10, 20, .., 90 m, joined at x = 10 and x = 90), 800 m at 1.6 m/s, with a 720-beam
laser at 15 Hz (10 m range) and a 320x240 depth camera at 2 Hz (8 m range, pitched 25 degrees
down; the simulator casts every pixel against every wall face, so a 640x480 camera at a higher
rate would take an hour to simulate: memory follows the space observed, which the smaller image
covers the same at 0.05 m). The log is simulated once with ``ltmap simulate`` and cached under ``bench/.cache/``
(git-ignored); the static layer is not given (every wall goes through O, the worst case for
memory).

Printed: peak memory (ru_maxrss of the replay process) and the map's own bytes against the
1.5 GB budget (ratio), what a dense grid over the bounding box would take (the peer of "grows
with the space observed"), the allocated blocks, and the mean cost per frame (laser, depth) and
per tick in each fifth of the run: with the map growing from nothing to the whole floor, the
last fifth costs what the first does when the cost does not grow with the map.

With ``--snapshots`` the replay writes a snapshot every 60 s of log time (the default), each
timed: their cost grows with the map.

Run: python bench/bench_scale.py [--rate-depth HZ] [--before REF] [--snapshots]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_replay  # noqa: E402  (simulated_log, code_at)

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "bench" / ".cache"
SIZE = 100.0
SPEED = 1.6  # m/s


def _walls() -> list[str]:
    rows = [f"  - {{points: [[0, 0], [{SIZE:g}, 0], [{SIZE:g}, {SIZE:g}], [0, {SIZE:g}], [0, 0]], thickness: 0.2}}"]
    for i in range(10):
        for j in range(10):
            x0, y0 = 10 * i + 1, 10 * j + 1
            x1, y1 = x0 + 8, y0 + 8
            # east and west sides solid; north and south (on the corridors the robot drives) with a
            # 1 m door in the middle
            rows.append(f"  - {{points: [[{x1}, {y0}], [{x1}, {y1}]], thickness: 0.1}}")
            rows.append(f"  - {{points: [[{x0}, {y1}], [{x0}, {y0}]], thickness: 0.1}}")
            for (ax, ay), (bx, by) in (((x0, y0), (x1, y0)), ((x1, y1), (x0, y1))):
                mx, my = (ax + bx) / 2, (ay + by) / 2
                dx, dy = (bx - ax) / 8, (by - ay) / 8
                rows.append(f"  - {{points: [[{ax}, {ay}], [{mx - 0.5 * dx:g}, {my - 0.5 * dy:g}]], thickness: 0.1}}")
                rows.append(f"  - {{points: [[{mx + 0.5 * dx:g}, {my + 0.5 * dy:g}], [{bx}, {by}]], thickness: 0.1}}")
    return rows


def _path() -> tuple[list[str], float]:
    pts = []
    for k, y in enumerate(range(10, 100, 10)):
        xs = (10, 90) if k % 2 == 0 else (90, 10)
        pts += [(xs[0], y), (xs[1], y)]
    rows, t = [], 0.0
    prev = None
    for x, y in pts:
        if prev is not None:
            d = abs(x - prev[0]) + abs(y - prev[1])
            yaw_prev = rows[-1][3]
            yaw = {(1, 0): 0, (-1, 0): 180, (0, 1): 90}[(int((x > prev[0]) - (x < prev[0])),
                                                           int((y > prev[1]) - (y < prev[1])))]
            # turn on the spot (2 s), then drive
            if yaw != yaw_prev:
                t += 2.0
                rows.append((t, prev[0], prev[1], yaw))
            t += d / SPEED
            rows.append((t, x, y, yaw))
        else:
            rows.append((0.0, x, y, 0))
        prev = (x, y)
    # keep yaw continuous (no 360 degree spins): unwrap
    out, last = [], None
    for t, x, y, yaw in rows:
        if last is not None:
            while yaw - last > 180:
                yaw -= 360
            while yaw - last < -180:
                yaw += 360
        last = yaw
        out.append(f"      - {{t: {t:.2f}, x: {x}, y: {y}, yaw: {yaw}}}")
    return out, t


def scenario_yaml(rate_depth: float) -> tuple[str, float]:
    path, duration = _path()
    boxes = []
    for k in range(40):
        x = 12 + (k * 37) % 76
        y = 10 * (1 + k % 9) + (0.6 if k % 2 else -0.6)
        boxes.append(f"  - {{id: box{k}, kind: box, pose: {{x: {x}, y: {y}}}, size: [0.5, 0.4, 0.7]}}")
    text = "\n".join([
        "# bench/bench_scale.py: a 100 x 100 m office floor. Written by the bench; do not edit by hand.",
        "name: bench-office",
        "wall_height: 2.5",
        f"duration: {duration:.2f}",
        "seed: 9",
        "walls:",
        *_walls(),
        "robot:",
        "  radius: 0.25",
        "  path:",
        "    waypoints:",
        *path,
        "sensors:",
        "  laser: {beams: 720, fov: 360, range_max: 10, rate: 15, noise: 0.01, mount: {xyz: [0.15, 0, 0.25]}}",
        f"  depth: {{mount: {{xyz: [0.1, 0, 1.1]}}, pitch: 25, width: 320, height: 240, rate: {rate_depth:g},",
        "          noise: 0.002, quantization: 0.0025}",
        "objects:",
        *boxes,
        "",
    ])
    return text, duration


def ensure_log(rate_depth: float) -> Path:
    text, duration = scenario_yaml(rate_depth)
    return bench_replay.simulated_log("scale_office", text, f"the office floor ({duration:.0f} s of log)")


def child(log: Path, out: Path, snapshots: bool = False) -> None:
    import resource

    import numpy as np

    import ltmap_cli.pipeline.sinks as sinks
    from ltmap_cli.config import Config
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    cfg = Config()
    cfg.replay.plots = False
    snapshot_s: list[float] = []  # each snapshot's wall time
    if snapshots:  # the default: a snapshot every 60 s of log time, each timed
        write = sinks.write_snapshot

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return write(*a, **k)
            finally:
                snapshot_s.append(time.perf_counter() - t0)

        sinks.write_snapshot = timed
    else:
        cfg.replay.snapshot_every = 1e9  # one snapshot at the end: memory of the map, not of snapshots
    run = Replay(cfg, ReplayRequest([log], out))
    t0 = time.perf_counter()
    rep = run.run()
    wall = time.perf_counter() - t0
    lmap = run.lmap
    rep.setdefault("stage_s", None)
    fifths = {}
    for topic, ms in list(run.metrics.frame_ms.items()) + [("tick", run.metrics.tick_ms)]:
        a = np.asarray(ms, dtype=np.float64)
        fifths[topic] = [float(x.mean()) if len(x) else 0.0 for x in np.array_split(a, 5)]
    o_keys = lmap.O.block_coords[: lmap.O.n_blocks].astype(np.int64)
    print(json.dumps({
        "wall_s": wall, "log_s": rep["log_duration_s"], "speed": rep["log_duration_s"] / wall,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, "map_mb": lmap.nbytes() / 2**20,
        "o_blocks": lmap.O.n_blocks, "o_capacity": lmap.O.max_blocks, "d_blocks": lmap.D.n_blocks,
        "d_capacity": lmap.D.max_blocks, "bbox_blocks": [int(v) for v in (o_keys.max(0) - o_keys.min(0) + 1)],
        "frames_used": rep["frames_used"], "fifths_ms": fifths, "stage_s": rep["stage_s"], "snapshot_s": snapshot_s,
    }), flush=True)


def run_child(log: Path, code: Path | None = None, snapshots: bool = False) -> dict:
    out = Path(tempfile.mkdtemp(prefix="bench_scale_"))
    env = dict(os.environ)
    if code is not None:
        env["PYTHONPATH"] = str(code) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, __file__, "--child", str(log), str(out)] + (["--snapshots"] if snapshots else []),
                          check=True, capture_output=True, text=True, env=env)  # fmt: skip
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    r["out"] = str(out)
    return r


def report(r: dict, label: str) -> None:
    res = 0.05
    bx, by, bz = r["bbox_blocks"]
    dense_bbox_mb = bx * by * bz * 512 * 8 / 2**20  # O alone (log-odds + stamp), dense over the bounding box
    dense_floor_mb = (SIZE / res) ** 2 * (2.5 / res) * 8 / 2**20
    print(f"[{label}] log {r['log_s']:.0f} s replayed in {r['wall_s']:.1f} s ({r['speed']:.1f}x real time); frames "
          f"{r['frames_used']}")
    print(f"[{label}] peak memory (ru_maxrss): {r['peak_mb']:.0f} MB = {r['peak_mb'] / 1536:.2f} of the 1.5 GB "
          f"budget ({'meets' if r['peak_mb'] < 1536 else 'misses'} it); map arrays {r['map_mb']:.0f} MB")
    print(f"[{label}] O blocks used / allocated {r['o_blocks']} / {r['o_capacity']} (8^3 voxels each), D "
          f"{r['d_blocks']} / {r['d_capacity']}; bounding box {bx} x {by} x {bz} blocks")
    print(f"[{label}] peer, a dense O over the observed bounding box: {dense_bbox_mb:.0f} MB "
          f"({dense_bbox_mb / max(r['map_mb'], 1e-9):.1f}x the sparse map); dense over the floor x 2.5 m: "
          f"{dense_floor_mb:.0f} MB")
    print(f"[{label}] mean cost per frame / tick (ms) in each fifth of the run (the map grows from empty to the "
          f"floor):")
    for topic, f in r["fifths_ms"].items():
        print(f"  {topic:28s} " + "  ".join(f"{v:7.2f}" for v in f) + f"   last/first {f[-1] / max(f[0], 1e-9):.2f}")
    print(f"[{label}] stages (s): {r.get('stage_s')}")
    if r.get("snapshot_s"):
        print(f"[{label}] {len(r['snapshot_s'])} snapshots (every 60 s of log and the final one): "
              f"{sum(r['snapshot_s']):.1f} s in all, each " + ", ".join(f"{x:.2f}" for x in r["snapshot_s"]))
    print(f"[{label}] outputs kept in {r['out']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate-depth", type=float, default=2.0, help="depth camera rate in the log, Hz (default 2)")
    ap.add_argument("--before", default="", help="git ref of the code before this work: also run that code "
                    "(extracted under bench/.cache) on the same log, first")
    ap.add_argument("--snapshots", action="store_true", help="snapshots at the default period (60 s of log), each "
                    "timed, instead of one at the end")
    args = ap.parse_args()
    log = ensure_log(args.rate_depth)
    import platform

    print(f"bench_scale: {datetime.date.today()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
          f"Python {platform.python_version()}")
    print(f"log: {log} ({log.stat().st_size / 2**20:.0f} MiB); load average before {os.getloadavg()[0]:.2f}")
    if args.before:
        before = run_child(log, bench_replay.code_at(args.before), args.snapshots)
        report(before, f"before {args.before}")
    r = run_child(log, snapshots=args.snapshots)
    print(f"load average after {os.getloadavg()[0]:.2f}")
    report(r, "now")
    if args.before:
        print(f"now vs before: peak memory {r['peak_mb'] / before['peak_mb']:.2f}x, speed "
              f"{r['speed'] / before['speed']:.2f}x")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(Path(sys.argv[2]), Path(sys.argv[3]), "--snapshots" in sys.argv[4:])
    else:
        main()
