"""A depth frame's worker part, kernel by kernel, on frames captured from a replay (issue 17).

Whole-run figures (``bench_long_rays.py``) vary by 15 % between runs on a shared VM. This times
each kernel of a depth frame's worker part alone, on the same captured inputs, so a change to
one kernel can be measured to a few per cent. It replays a scene's log once on the serial path
(``bench_long_rays.py``'s scenes, simulated and cached there), captures every ``--every``-th
depth frame's inputs as the replay hands them to ``LayeredMap.depth_voxels`` (the raw image, the
pose, the rays, and what the projection read of the map then: O's table, its quiet quarters and
still voxels, ``LayeredMap._map_seen``), then times on them, best of
``--rounds`` passes over all frames:

- ``rays``: ``LayeredMap.depth_rays`` (``core.raycast.depth_image_rays``: raw pixels to one ray
  per end voxel), and within it pass 1 alone (``pass1``: every pixel's end point and key, no
  dedupe set) and pass 1 with 1b (``pass1b``: the neighbours' comparisons), from copies of
  ``_depth_rays_pass`` with the later passes cut out;
- ``range_image``: ``core.projective.depth_range_image`` (a part of ``projection``);
- ``projection``: ``LayeredMap.depth_projection`` (the range image, the frame's box, the blocks'
  miss masks, quiet quarters and still voxels left out);
- ``tails``: ``LayeredMap.ray_voxels`` with the projective tail (the hits and the band's misses
  into the projection's masks).

It also prints per frame: the rays, one per end voxel (hit, and clear: floor returns and rays cut
at max_range), the box's blocks by class (``core.projective._classify``: culled, front, mixed),
the blocks listed with misses and those whose quiet quarters or still voxels the projection left out.

Run: python bench/bench_depth_parts.py [--scenes room,hall,office] [--every 10] [--rounds 3]
"""

from __future__ import annotations

import argparse
import functools
import inspect
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_long_rays  # noqa: E402  (the scenes and their cached logs)
import bench_replay  # noqa: E402  (machine)


def capture(scene: str, every: int) -> list[dict]:
    """Every ``every``-th depth frame's inputs to ``depth_voxels`` in a serial replay."""
    from ltmap_cli.config import Config
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    frames: list[dict] = []
    seen = [0]
    real = LayeredMap.depth_voxels

    def spy(self, depth, fx, fy, cx, cy, T, max_range, ends, kind):
        seen[0] += 1
        if seen[0] % every == 0:
            frames.append({"depth": np.array(depth), "k": (float(fx), float(fy), float(cx), float(cy)),
                           "T": np.array(T, dtype=np.float64), "max_range": float(max_range),
                           "ends": ends.copy(), "kind": kind.copy(),
                           "seen": tuple(a.copy() for a in self._map_seen())})  # fmt: skip
        return real(self, depth, fx, fy, cx, cy, T, max_range, ends, kind)

    cfg = Config()
    cfg.replay.plots = False
    log = bench_long_rays.ensure_log(scene)
    LayeredMap.depth_voxels = spy
    try:
        out = Path(f"/tmp/bench_depth_parts_{scene}")
        run = Replay(cfg, ReplayRequest([log], out))
        run.fast, run.threads = True, False
        run.run()
    finally:
        LayeredMap.depth_voxels = real
    return frames


def pass_variants():
    """``_depth_rays_pass`` cut after pass 1 and after pass 1b (compiled here, not cached)."""
    from numba import njit

    import ltmap_cli.core.raycast as rc

    src = inspect.getsource(rc._depth_rays_pass.py_func)
    src = src[src.index("def _depth_rays_pass"):]  # (its decorator: the copies are compiled below)
    cuts = {
        "pass1b": [("        for q in range(n_look):", "        for q in range(0):")],
        "pass1": [("        for q in range(n_look):", "        for q in range(0):"),
                  ("        if dedupe:  # pass 1b", "        if False:  # pass 1b")],
    }  # fmt: skip
    out = {}
    for name, edits in cuts.items():
        s = src
        for old, new in edits:
            if old not in s:
                raise SystemExit(f"bench_depth_parts: _depth_rays_pass changed: {old.strip()!r} not found; update the cuts")
            s = s.replace(old, new)
        space = dict(vars(rc))
        exec(compile(s, f"<{name}>", "exec"), space)
        out[name] = njit(nogil=True, error_model="numpy")(space["_depth_rays_pass"])
    return out


@functools.cache
def _classes_kernel():
    """A kernel counting the box's blocks by ``core.projective._classify``'s class (compiled once)."""
    from numba import njit

    from ltmap_cli.core import projective as pj
    from ltmap_cli.core.grid import BLOCK_BITS

    @njit(nogil=True)
    def classes(reach, tmin, tmax, fx, fy, cx, cy, Tinv, box, res, band):
        h, w = reach.shape
        far, planes, e = pj._frame_setup(tmax, fx, fy, cx, cy, w, h, Tinv, res, band)
        n = np.zeros(3, np.int64)
        for bi in range(box[0] >> BLOCK_BITS, (box[3] >> BLOCK_BITS) + 1):
            for bj in range(box[1] >> BLOCK_BITS, (box[4] >> BLOCK_BITS) + 1):
                for bk in range(box[2] >> BLOCK_BITS, (box[5] >> BLOCK_BITS) + 1):
                    c, _, _, _ = pj._block_class(bi, bj, bk, tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far,
                                                 planes, e)  # fmt: skip
                    n[c] += 1
        return n

    return classes


def counts(lmap, f, ends, kind) -> dict:
    """The frame's end voxels by kind, the box's blocks by class."""
    from ltmap_cli.core import projective as pj
    from ltmap_cli.core.layers import _depth_view
    from ltmap_cli.core.raycast import RAY_CLEAR, RAY_HIT

    fx, fy, cx, cy = f["k"]
    d, unit_mm = _depth_view(f["depth"])
    band = float(lmap.cfg.sensor.projective_band)
    reach, tmin, tmax, _ = pj.depth_range_image(d, unit_mm, pj.pixel_range_factors(*d.shape, fx, fy, cx, cy),
                                                f["max_range"], band)  # fmt: skip
    T = f["T"]
    R, t = T[:3, :3], T[:3, 3]
    Tinv = np.ascontiguousarray(np.hstack([R.T, (-R.T @ t)[:, None]]))
    box = pj.ends_box(np.ascontiguousarray(t), ends, 1.0 / lmap.resolution)
    cls = _classes_kernel()(reach, tmin, tmax, fx, fy, cx, cy, Tinv, box, lmap.resolution, band)
    return {"hit": int((kind == RAY_HIT).sum()), "clear": int((kind == RAY_CLEAR).sum()),
            "culled": int(cls[pj.CULLED]), "front": int(cls[pj.FRONT]), "mixed": int(cls[pj.MIXED])}  # fmt: skip


def time_parts(frames: list[dict], rounds: int) -> tuple[dict, dict]:
    """Milliseconds per frame of each part (best of ``rounds``), and the counts per frame."""
    from ltmap_cli.config import Config
    from ltmap_cli.core.layers import LayeredMap, _depth_view
    from ltmap_cli.core.projective import depth_range_image
    from ltmap_cli.core.raycast import depth_rays_cap

    lmap = LayeredMap(Config().map)
    sc = lmap.cfg.sensor
    variants = pass_variants()
    fp = lmap._footprint(None)  # (the replay passes the robot's pose: its box is tested only on rows nearer than its far corner)

    def one(f, spent, tally):
        fx, fy, cx, cy = f["k"]
        c = time.perf_counter()
        ends, kind = lmap.depth_rays(f["depth"], fx, fy, cx, cy, f["T"], f["max_range"], None, dedupe=sc.dedupe_dense)
        spent["rays"] += time.perf_counter() - c
        d, unit_mm = _depth_view(f["depth"])
        args = (d, unit_mm, fx, fy, cx, cy, f["T"], f["max_range"], float(sc.ground_tolerance), *fp, True,
                1.0 / lmap.resolution, np.int64(depth_rays_cap(len(kind), d.size)), True)  # fmt: skip
        for name, fn in variants.items():
            c = time.perf_counter()
            fn(*args)
            spent[name] += time.perf_counter() - c
        c = time.perf_counter()
        depth_range_image(d, unit_mm, lmap._range_factors(d.shape, fx, fy, cx, cy), f["max_range"], float(sc.projective_band))
        spent["range_image"] += time.perf_counter() - c
        lmap._map_seen = lambda seen=f["seen"]: seen
        c = time.perf_counter()
        proj = lmap.depth_projection(f["depth"], fx, fy, cx, cy, f["T"], f["max_range"], ends)
        spent["projection"] += time.perf_counter() - c
        c = time.perf_counter()
        lmap.ray_voxels(f["T"][:3, 3], ends, kind, lmap.projective_tail(), proj)
        spent["tails"] += time.perf_counter() - c
        if tally is not None:
            for k, v in counts(lmap, f, ends, kind).items():
                tally[k] = tally.get(k, 0) + v
            tally["blocks with misses"] = tally.get("blocks with misses", 0) + len(proj.keys)
            tally["quiet skips"] = tally.get("quiet skips", 0) + (0 if proj.skipped is None else len(proj.skipped))

    for f in frames[:2]:  # (compiles the copies)
        one(f, dict.fromkeys(PARTS, 0.0), None)
    best: dict[str, float] = {}
    tally: dict[str, int] = {}
    for r in range(rounds):
        spent = dict.fromkeys(PARTS, 0.0)
        for f in frames:
            one(f, spent, tally if r == 0 else None)
        best = spent if not best else {k: min(best[k], spent[k]) for k in spent}
    n = len(frames)
    return {k: 1000.0 * v / n for k, v in best.items()}, {k: v / n for k, v in tally.items()}


PARTS = ("rays", "pass1", "pass1b", "range_image", "projection", "tails")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="room,hall,office", help=f"of {','.join(bench_long_rays.SCENES)}")
    ap.add_argument("--every", type=int, default=10, help="capture every N-th depth frame")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"bench_depth_parts: {bench_replay.machine()}")
    rows = []
    for scene in args.scenes.split(","):
        frames = capture(scene, args.every)
        ms, per = time_parts(frames, args.rounds)
        rows.append((scene, len(frames), ms, per))
        print(f"  {scene}: {len(frames)} frames captured", flush=True)
    print("\nms per depth frame (best of the rounds; pass1 and pass1b are parts of rays, range_image of projection)\n")
    print("| scene | frames | " + " | ".join(PARTS) + " | rays + projection + tails |")
    print("|---|---|" + "---|" * (len(PARTS) + 1))
    for scene, n, ms, _ in rows:
        total = ms["rays"] + ms["projection"] + ms["tails"]
        print(f"| {scene} | {n} | " + " | ".join(f"{ms[k]:.3f}" for k in PARTS) + f" | {total:.3f} |")
    print("\nper frame\n")
    keys = ["hit", "clear", "culled", "front", "mixed", "blocks with misses", "quiet skips"]
    print("| scene | hit rays | clear rays | blocks culled | front | mixed | blocks with misses | quiet skips |")
    print("|---|" + "---|" * len(keys))
    for scene, _, _, per in rows:
        print(f"| {scene} | " + " | ".join(f"{per.get(k, 0):,.0f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
