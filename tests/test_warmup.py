"""The warm-up compiles what a replay calls, in the specializations it calls them with (issue 21):
on a cold cache anything else is compiled in the middle of the run, in the main process (a
read-only depth image once cost a cold run 10 s of compiling while mapping)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.config import Config
from ltmap_cli.pipeline.warmup import COMPILE_S, GROUPS, children_of, replay_groups

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"
PLAN = ROOT / "sample_logs" / "plans" / "house.svg"

# a fresh process: warm the groups the replay will call, note every kernel's specializations,
# replay, and print the kernels that gained one
_SCRIPT = """
import gc, json, sys
from numba.core.registry import CPUDispatcher
from ltmap_cli.cli import cli
from ltmap_cli.config import Config
from ltmap_cli.pipeline.warmup import groups_cached, replay_groups, warm_up

def kernels():
    return {f"{d.py_func.__module__}.{d.py_func.__qualname__}": len(d.signatures)
            for d in gc.get_objects() if isinstance(d, CPUDispatcher)}

cfg = Config()
cfg.replay.mcap_out, cfg.replay.plan_goal = True, [5.0, 4.0]
warm_up(cfg.map, replay_groups(cfg.replay, raw_depth=True, lists=groups_cached(["lists"])))  # (cached: loaded)
before = kernels()
try:
    cli(sys.argv[1:], prog_name="ltmap")
except SystemExit as e:
    assert not e.code, e.code
print(json.dumps({k: [before.get(k, 0), n] for k, n in kernels().items() if n != before.get(k, 0)}))
"""


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_replay_compiles_nothing_the_warm_up_did_not(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "ltmap_cli", "build-static", str(PLAN), "-o", str(tmp_path / "static")],
                   check=True, capture_output=True, env=env)  # fmt: skip
    out = subprocess.run([sys.executable, "-c", _SCRIPT, "replay", str(HOUSE), "--static", str(tmp_path / "static"),
                          "-o", str(tmp_path / "out"), "--mcap", "--plan-goal", "5,4", "--no-plots"],
                         check=True, capture_output=True, text=True, env=env)  # fmt: skip
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {}


# the same for the plain path (``Replay.fast`` False: depth images as float32 metres, rays from
# points), the tests' reference: the groups and ``warm_depth_points`` before the replay
_PLAIN_SCRIPT = _SCRIPT.split("cfg = Config()")[0] + """
from pathlib import Path
from ltmap_cli.pipeline.replay import Replay, ReplayRequest
from ltmap_cli.pipeline.warmup import warm_depth_points
cfg = Config()
cfg.replay.plots = False
warm_up(cfg.map, replay_groups(cfg.replay, lists=groups_cached(["lists"])))  # (cached: loaded)
warm_depth_points(cfg.map)
before = kernels()
run = Replay(cfg, ReplayRequest([Path(sys.argv[1])], Path(sys.argv[2])))
run.fast, run.threads = False, False
run.run()
print(json.dumps({k: [before.get(k, 0), n] for k, n in kernels().items() if n != before.get(k, 0)}))
"""


@pytest.mark.slow
@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_a_plain_replay_compiles_nothing_its_warm_up_did_not(tmp_path):
    """After a core module changed, the plain path's first depth frame compiled its kernels
    (float32 metres: 6.9 s); the replay now warms them (``warm_depth_points``) before it."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", _PLAIN_SCRIPT, str(HOUSE), str(tmp_path / "out")],
                         check=True, capture_output=True, text=True, env=env)  # fmt: skip
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {}


def test_a_plain_replay_warms_its_depth_kernels_before_its_first_depth_frame(tmp_path, monkeypatch):
    """``Replay._dispatch`` calls ``warm_depth_points`` once, before the first depth frame is
    cast, on the plain path only."""
    import ltmap_cli.pipeline.replay as replay_mod
    from ltmap_cli.io.decode import RawDepthFrame
    from ltmap_cli.io.frames import DepthFrame
    from ltmap_cli.pipeline.rays import FrameCaster
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    seen: list[str] = []
    real_cast = FrameCaster.cast

    def cast(self, frame, T, robot):
        if isinstance(frame, (DepthFrame, RawDepthFrame)):
            seen.append("depth")
        return real_cast(self, frame, T, robot)

    monkeypatch.setattr(replay_mod, "warm_depth_points", lambda cfg: seen.append("warm"))
    monkeypatch.setattr(FrameCaster, "cast", cast)
    for fast in (False, True):
        seen.clear()
        cfg = Config()
        cfg.replay.plots = False
        run = Replay(cfg, ReplayRequest([HOUSE], tmp_path / f"out{fast}"))
        run.fast, run.threads = fast, False
        run.run()
        assert "depth" in seen
        assert seen.count("warm") == (0 if fast else 1) and seen.index("depth") > (-1 if fast else seen.index("warm"))


def _record_warm_up(monkeypatch, seen: list):
    """Patch the warm-up's loaders and the frames' cast to note, in order, which ran in which thread."""
    import threading

    import ltmap_cli.pipeline.replay as replay_mod
    import ltmap_cli.pipeline.warmup as warmup_mod
    from ltmap_cli.io.decode import RawDepthFrame
    from ltmap_cli.pipeline.rays import FrameCaster

    real_up, real_depth, real_cast = warmup_mod.warm_up, warmup_mod.warm_depth, FrameCaster.cast

    def up(cfg, groups):
        real_up(cfg, groups)
        seen.append(("groups", tuple(groups), threading.current_thread().name))

    def depth(cfg, dtype, contiguous=True):
        real_depth(cfg, dtype, contiguous)
        seen.append(("depth", (dtype, contiguous), threading.current_thread().name))

    def cast(self, frame, T, robot):
        seen.append(("cast", "depth" if isinstance(frame, RawDepthFrame) else "other", ""))
        return real_cast(self, frame, T, robot)

    monkeypatch.setattr(replay_mod, "kernels_cached", lambda groups=(): True)  # (a warm run, whatever the cache holds)
    monkeypatch.setattr(replay_mod, "groups_cached", lambda groups, layout="C": True)  # (lists too: loaded)
    for mod in (replay_mod, warmup_mod):
        monkeypatch.setattr(mod, "warm_up", up)
        monkeypatch.setattr(mod, "warm_depth", depth)
    monkeypatch.setattr(FrameCaster, "cast", cast)


@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
@pytest.mark.parametrize("threads", [True, False])
def test_a_warm_run_loads_its_kernels_in_a_thread_of_its_own_before_its_first_frame(tmp_path, monkeypatch, threads):
    """A warm replay loads the kernel groups it calls in the ``ltmap-warmup`` thread from its
    start, and its depth images' kernels as soon as the first image is read; each before the
    first frame that needs them is cast. The serial path loads them itself, at the first frame."""
    import numpy as np

    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    seen: list = []
    _record_warm_up(monkeypatch, seen)
    cfg = Config()
    cfg.replay.plots = False
    run = Replay(cfg, ReplayRequest([HOUSE], tmp_path / "out"))
    run.threads = threads
    run.run()
    loads = [s for s in seen if s[0] != "cast"]
    groups = [g for s in loads if s[0] == "groups" for g in s[1]]  # (threads: a job per group)
    assert sorted(groups) == sorted(replay_groups(cfg.replay, lists=True))  # (lists: cached, so loaded)
    assert loads[-1][:2] == ("depth", (np.dtype(np.uint16), True)) and len(loads) == (4 if threads else 2)
    assert {s[2] for s in loads} == ({"ltmap-warmup_0"} if threads else {"MainThread"})
    first_cast = seen.index(next(s for s in seen if s[0] == "cast"))
    first_depth = seen.index(next(s for s in seen if s[1] == "depth" and s[0] == "cast"))
    assert max(seen.index(s) for s in loads[:-1]) < first_cast and seen.index(loads[-1]) < first_depth


@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_a_failure_of_the_background_warm_up_is_the_runs(tmp_path, monkeypatch):
    """A kernel that cannot be loaded in the warm-up thread (a damaged cache file) fails the run
    with the same error, in the caller's thread, and nothing is cast before it."""
    import ltmap_cli.pipeline.replay as replay_mod
    import ltmap_cli.pipeline.warmup as warmup_mod
    from ltmap_cli.errors import KernelCacheError
    from ltmap_cli.pipeline.rays import FrameCaster
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    def broken(cfg, groups):
        raise KernelCacheError("the kernel cache file x is damaged")

    cast: list = []
    monkeypatch.setattr(replay_mod, "kernels_cached", lambda groups=(): True)
    monkeypatch.setattr(warmup_mod, "warm_up", broken)
    monkeypatch.setattr(FrameCaster, "cast", lambda self, *a: cast.append(1))
    cfg = Config()
    cfg.replay.plots = False
    run = Replay(cfg, ReplayRequest([HOUSE], tmp_path / "out"))
    with pytest.raises(KernelCacheError, match="file x is damaged"):
        run.run()
    assert cast == []


def test_replay_groups():
    cfg = Config()
    assert replay_groups(cfg.replay) == ["rays", "maps"]
    assert replay_groups(cfg.replay, lists=True) == ["rays", "lists", "maps"]
    assert replay_groups(cfg.replay, raw_depth=True) == ["rays", "maps", "depth16", "projective16"]
    assert replay_groups(cfg.replay, raw_depth=True, projective=False) == ["rays", "maps", "depth16"]
    cfg.replay.mcap_out, cfg.replay.plan_goal = True, [1.0, 2.0]
    assert replay_groups(cfg.replay) == ["rays", "maps", "fused_scan", "planner"]
    assert set(replay_groups(cfg.replay, raw_depth=True, lists=True)) <= set(GROUPS) == set(COMPILE_S)


def test_lists_are_needed_only_by_sensors_whose_boxes_can_exceed_the_masks_limit():
    """By hand, at 0.05 m (blocks of 0.4 m; the limit LISTED_VOXELS_MAX_BLOCKS = 262,144): a depth
    camera cut at 8 m spans at most ceil(16 / 0.4) + 2 = 42 blocks a side, 74,088 blocks; at 30 m,
    152^3; a level laser of 70 m, 352^2 x 2 = 247,808; of 80 m, 402^2 x 2 = 323,208; one of 40 m
    pitched by 5 degrees spans 80 sin 5 = 6.97 m in height, ceil(6.97 / 0.4) + 2 = 20 blocks:
    202^2 x 20 = 816,080; at 0.02 m (blocks of 0.16 m) an 8 m camera, 102^3. A scan without a
    finite range_max (inf, as pointcloud_to_laserscan publishes) reaches its farthest finite range."""
    import math

    from ltmap_cli.core.projective import LISTED_VOXELS_MAX_BLOCKS
    from ltmap_cli.io.frames import ScanFrame
    from ltmap_cli.pipeline.warmup import box_blocks, lists_needed, scan_box_blocks

    assert LISTED_VOXELS_MAX_BLOCKS == 262_144
    assert box_blocks(8.0, 0.05) == 42**3 and not lists_needed(box_blocks(8.0, 0.05))
    assert box_blocks(30.0, 0.05) == 152**3 and lists_needed(box_blocks(30.0, 0.05))
    assert box_blocks(8.0, 0.02) == 102**3 and lists_needed(box_blocks(8.0, 0.02))

    def scan(range_max, ranges=(1.0,)):
        return ScanFrame(0, "laser", 0.0, 0.01, 0.1, range_max, np.asarray(ranges, dtype=np.float32))

    level, pitched = np.eye(4), np.eye(4)
    a = math.radians(5.0)
    pitched[:3, :3] = [[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]]
    assert scan_box_blocks(scan(70.0), level, 0.05) == 352**2 * 2 and not lists_needed(352**2 * 2)
    assert scan_box_blocks(scan(80.0), level, 0.05) == 402**2 * 2 and lists_needed(402**2 * 2)
    assert scan_box_blocks(scan(40.0), pitched, 0.05) == 202**2 * 20
    inf_scan = scan(float("inf"), [np.inf, np.nan, 3.0, -np.inf, 9.9])
    assert scan_box_blocks(inf_scan, level, 0.05) == box_blocks(9.9, 0.05, 0.0) == 52**2 * 2
    assert scan_box_blocks(scan(float("nan"), [np.nan]), level, 0.05) == 2 * 2 * 2  # (reach 0: its own blocks)


def test_box_blocks_bound_the_boxes_of_frames_as_cast():
    """The bound holds for frames as the map casts them (``LayeredMap.rays``, ``ends_box``): 200
    seeded scans, tilted up to 10 degrees, with returns, no returns (inf, beyond range_max) and
    NaN, and clouds cut at 8 m, anywhere in the map; the bound is tight within 3 blocks a side."""
    import math

    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.core.projective import ends_box
    from ltmap_cli.core.sensors import scan_to_points, transform_points
    from ltmap_cli.io.frames import ScanFrame
    from ltmap_cli.pipeline.warmup import box_blocks, scan_box_blocks

    cfg = Config()
    m = LayeredMap(cfg.map)
    res = cfg.map.resolution
    rng = np.random.default_rng(30)

    def blocks(origin, ends):
        box = ends_box(origin, ends, 1.0 / res)
        return int(np.prod((box[3:] >> 3) - (box[:3] >> 3) + 1))

    tight = []
    for _ in range(200):
        roll, pitch, yaw = rng.uniform(-math.radians(10), math.radians(10), 2).tolist() + [rng.uniform(-3, 3)]
        cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
        T = np.eye(4)
        T[:3, :3] = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) \
            @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])  # fmt: skip
        T[:3, 3] = rng.uniform(-50, 50, 3)
        rmax = float(rng.choice([5.0, 30.0, 60.0]))
        ranges = rng.uniform(0.05, rmax * 1.2, 360).astype(np.float32)
        ranges[rng.random(360) < 0.1] = np.inf
        ranges[rng.random(360) < 0.05] = np.nan
        frame = ScanFrame(0, "laser", -math.pi, 2 * math.pi / 360, 0.1, rmax, ranges)
        pts, rets = scan_to_points(frame.ranges, frame.angle_min, frame.angle_increment, frame.range_min, rmax)
        ends, kind = m.rays(T[:3, 3], transform_points(T, pts), rets, max_range=rmax)
        got, bound = blocks(T[:3, 3], ends), scan_box_blocks(frame, T, res)
        assert got <= bound
        tight.append(bound / got)
        cloud = rng.normal(size=(2000, 3)) * rng.uniform(1.0, 6.0)
        ends, kind = m.rays(T[:3, 3], transform_points(T, cloud), None, max_range=8.0)
        assert blocks(T[:3, 3], ends) <= box_blocks(8.0, res)
    assert min(tight) < (1 + 3 / 20) ** 2 * 2  # (some scan's box within 3 blocks a side of the bound)


def test_children_share_the_groups_by_their_compiling():
    """At most a child per core, the costliest group first, each to the child with the least so
    far: on 2 cores the depth replay's five groups in two children (by hand from COMPILE_S:
    projective16 10.6 and rays 7.2 open the two; lists 6.6 to rays (13.8), maps 6.0 to
    projective16 (16.6), depth16 3.1 to rays (16.9)), one each with cores to spare, all in one
    on one core."""
    five = ["rays", "lists", "maps", "depth16", "projective16"]
    assert children_of(five, 2) == [["projective16", "maps"], ["rays", "lists", "depth16"]]
    assert children_of(five, 8) == [["projective16"], ["rays"], ["lists"], ["maps"], ["depth16"]]
    assert children_of(five, 1) == children_of(five, 0) == [["projective16", "rays", "lists", "maps", "depth16"]]
    # then planner 2.4 to projective16 (16.6 -> 19.0), fused_scan 1.0 to rays (16.9 -> 17.9)
    seven = five + ["fused_scan", "planner"]
    assert children_of(seven, 2) == [["projective16", "maps", "planner"], ["rays", "lists", "depth16", "fused_scan"]]
    assert sorted(g for c in children_of(seven, 2) for g in c) == sorted(seven) and children_of([], 2) == []


def test_background_compile_says_each_group_ended():
    """A first run waits for its compiling children; ``wait`` reports each one that ends (the
    progress line then says "1 of 3 kernel groups compiled", so half a minute is not silence)."""
    from ltmap_cli.pipeline.warmup import BackgroundCompile

    bc = BackgroundCompile([])  # no groups: children of our own, ending one after another
    bc.procs = [subprocess.Popen([sys.executable, "-c", f"import time; time.sleep({d})"]) for d in (0.6, 0.0, 0.3)]
    seen = []
    bc.wait(lambda ended, total: seen.append((ended, total)), poll_s=0.05)
    assert seen[-1] == (3, 3) and [e for e, _ in seen] == sorted({e for e, _ in seen})  # rising, each once
    assert len(seen) >= 2 and bc.procs == []  # (two ending within one poll are said together)


def _literal(node, constants):
    """The value of a literal bool / int argument, or of a module's int constant (``BLOCK``):
    numba types either as a literal when the call is made from a kernel. Else None."""
    import ast

    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        v = _literal(node.operand, constants)
        return None if v is None else -v
    if isinstance(node, ast.Constant) and isinstance(node.value, (bool, int)):
        return node.value
    if isinstance(node, ast.Name):
        return constants.get(node.id)
    return None


def _module_constants(trees) -> dict:
    """Module-level ``NAME = <int expression of literals and such names>`` of every module."""
    import ast

    constants: dict = {}
    for _ in range(3):  # (constants made of other modules' constants: a few rounds)
        for tree in trees:
            for st in tree.body:
                if isinstance(st, ast.Assign) and len(st.targets) == 1 and isinstance(st.targets[0], ast.Name):
                    try:
                        v = eval(compile(ast.Expression(st.value), "<const>", "eval"), {"__builtins__": {}},
                                 dict(constants))  # fmt: skip
                    except Exception:  # noqa: BLE001 - anything but a constant expression
                        continue
                    if isinstance(v, (bool, int)):
                        constants[st.targets[0].id] = v
    return constants


def test_kernels_are_not_compiled_once_per_literal():
    """A kernel called from kernels with a literal argument (``f(x, True)``) is compiled for that
    literal: called elsewhere with another literal, or with a variable, it is compiled twice (each
    one a second or more of a first run's compiling: ``_pyramid``, ``_tiles_query``,
    ``projective_blocks`` and ``_classify``, with ``BLOCK``, were). Every call site inside the package's kernels is
    read: an argument position gets one literal value, or none (a kernel inlined into its callers
    is not compiled on its own)."""
    import ast

    calls: dict[str, dict] = {}  # kernel -> argument position -> {literal values, or "variable"}
    kernels = set()
    trees = {f: ast.parse(f.read_text()) for f in sorted((ROOT / "ltmap_cli").rglob("*.py"))}

    def is_kernel(fn):
        return any("njit" in ast.unparse(d) or ast.unparse(d).startswith("helper(") for d in fn.decorator_list)

    constants = _module_constants(trees.values())
    for tree in trees.values():  # (one inlined into its callers, ``inline="always"``, is no compiled function)
        kernels |= {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and is_kernel(n)
                    and not any("inline=" in ast.unparse(d) for d in n.decorator_list)}  # fmt: skip
    for tree in trees.values():
        for fn in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and is_kernel(n)):
            for call in (n for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)):
                if call.func.id not in kernels:
                    continue
                seen = calls.setdefault(call.func.id, {})
                for pos, arg in [*enumerate(call.args), *((k.arg, k.value) for k in call.keywords)]:
                    v = _literal(arg, constants)
                    seen.setdefault(pos, set()).add("variable" if v is None else repr(v))
    assert calls.get("_tiles_query") and calls.get("_pyramid")  # (the scan sees the call sites)
    twice = {f"{name}, argument {pos}: {sorted(kinds)}" for name, seen in calls.items() for pos, kinds in seen.items()
             if len(kinds) > 1 and kinds != {"variable"}}  # fmt: skip
    assert not twice


# a fresh process and cache: compile the groups (their 16-bit depth ones) and print the kernels
# with more than one specialization
_SPECIALIZATIONS_SCRIPT = """
import gc, json
from numba.core.registry import CPUDispatcher
from ltmap_cli.core.config import MapConfig
from ltmap_cli.pipeline.warmup import GROUPS, warm_up
warm_up(MapConfig(), [g for g in GROUPS if not g.endswith("32")])
print(json.dumps({f"{d.py_func.__module__}.{d.py_func.__qualname__}": [str(s) for s in d.signatures]
                  for d in gc.get_objects() if isinstance(d, CPUDispatcher) and len(d.signatures) > 1}))
"""


@pytest.mark.slow  # (about 35 s of one core's compiling)
def test_a_first_run_compiles_each_kernel_once(tmp_path):
    """Every group compiled in a fresh cache gives each kernel one specialization, but
    ``_frame_voxels`` (its loop compiled with the dense bitmap and with None, on purpose). The
    call-site check above sees literal arguments only: a variable set to a literal and changed
    in a loop (``by_block = True``, then False) made numba compile ``_depth_rays_pass`` for the
    literal too (2 s of a first run), and block coordinates read from int32 arrays beside int64
    ones made two ``find_block``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", _SPECIALIZATIONS_SCRIPT], check=True, capture_output=True, text=True,
                         env=env)  # fmt: skip
    twice = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(twice) == {"ltmap_cli.core.raycast._frame_voxels"}, twice
    dense, sparse = twice["ltmap_cli.core.raycast._frame_voxels"]
    assert dense.replace("Array(uint64, 1, 'C', False, aligned=True), Array(int64", "none, Array(int64", 1) == sparse


def _first_run_groups(tmp_path, monkeypatch, name, msgs, settings=None, cached=lambda groups=(): False,
                      phases=None, have=lambda groups, layout="C": True):
    """The groups a first run (``kernels_cached`` False; or as ``cached`` says) hands its compiling
    children, each time it starts some (recorded, not started: this process's kernels are
    compiled already), with the ``settings`` (dotted: value) given; the progress's phases into
    ``phases``."""
    from logfactory import write_log

    import ltmap_cli.pipeline.replay as replay_mod
    from ltmap_cli.config import set_dotted
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    started = []

    class Recorded:
        waiting = False  # (no other run compiling)

        def __init__(self, groups):
            started.append(list(groups))

        def wait(self, on_done=None, poll_s=0.2):
            pass

        def stop(self):
            pass

    monkeypatch.setattr(replay_mod, "kernels_cached", cached)
    monkeypatch.setattr(replay_mod, "groups_cached", have)  # (a warm run's groups that a run may lack)
    monkeypatch.setattr(replay_mod, "BackgroundCompile", Recorded)
    cfg = Config()
    cfg.replay.plots = False
    for key, value in (settings or {}).items():
        set_dotted(cfg, key, value)
    log = write_log(tmp_path / f"{name}.mcap", "mcap-ros2", msgs)
    run = Replay(cfg, ReplayRequest([log], tmp_path / name),
                 progress=None if phases is None else (lambda p: phases.append(p.phase)))  # fmt: skip
    run.run()
    return started


def test_a_first_run_compiles_the_depth_kernels_of_its_images_encoding(tmp_path, monkeypatch):
    """The children start at the first depth image, whose pixels say 16UC1 or 32FC1 (started
    before it, with the 16-bit kernels, a 32FC1 log compiled those for nothing and then its own
    in the middle of mapping); without depth images, at the first frame placed, without them."""
    import numpy as np
    from logfactory import camera_info, image, scan, tf

    S = 10**9
    place = [tf(S // 2, [("map", "cam", (0.0, 0.0, 1.0), (0.5, -0.5, 0.5, -0.5)),
                         ("map", "laser", (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0))], static=True)]  # fmt: skip

    def depth_msgs(encoding):
        px = np.full((12, 16), 2000, dtype=np.uint16) if encoding == "16UC1" else np.full((12, 16), 2.0, np.float32)
        out = []
        for i in range(4):
            t = S + i * S // 10
            out.append(scan("/scan", t, [2.0] * 90))  # (a scan first: the depth image comes after it)
            out.append(camera_info("/cam/depth/camera_info", t, width=16, height=12, fx=14, fy=14, cx=7.5, cy=5.5))
            out.append(image("/cam/depth/image_raw", t + 1, px, encoding=encoding, frame_id="cam"))
        return out

    base = ["rays", "maps"]
    got = _first_run_groups(tmp_path, monkeypatch, "d32", place + depth_msgs("32FC1"))
    assert got == [base + ["depth32", "projective32"]]
    got = _first_run_groups(tmp_path, monkeypatch, "d16", place + depth_msgs("16UC1"))
    assert got == [base + ["depth16", "projective16"]]
    scans = [m for m in depth_msgs("16UC1") if m.topic == "/scan"]
    got = _first_run_groups(tmp_path, monkeypatch, "scans", place + scans)
    assert got == [base]
    # a depth camera cut at 30 m: its frames' boxes may be too big for masks (lists_needed)
    got = _first_run_groups(tmp_path, monkeypatch, "d16far", place + depth_msgs("16UC1"),
                            {"map.sensor.depth_max_range": 30.0})  # fmt: skip
    assert got == [["rays", "lists", "maps", "depth16", "projective16"]]
    # a warm run of it whose cache lacks the lists group (the runs before never needed it):
    # its children compile that group alone
    no_lists = lambda groups, layout="C": "lists" not in groups  # noqa: E731
    got = _first_run_groups(tmp_path, monkeypatch, "warm_far", place + depth_msgs("16UC1"),
                            {"map.sensor.depth_max_range": 30.0}, cached=lambda groups=(): True, have=no_lists)  # fmt: skip
    assert got == [["lists"]]
    got = _first_run_groups(tmp_path, monkeypatch, "warm_near", place + depth_msgs("16UC1"),
                            cached=lambda groups=(): True, have=no_lists)  # fmt: skip
    assert got == []
    # a warm run of a 32FC1 log whose cache holds the 16UC1 depth kernels only (the logs before
    # were 16UC1): children for that encoding's groups at its first image, the progress saying so
    no32 = lambda groups, layout="C": not any(g.endswith("32") for g in groups)  # noqa: E731
    for encoding, groups in (("32FC1", [["depth32", "projective32"]]), ("16UC1", [])):
        phases: list = []
        got = _first_run_groups(tmp_path, monkeypatch, f"warm{encoding}", place + depth_msgs(encoding),
                                cached=lambda groups=(): True, phases=phases, have=no32)  # fmt: skip
        assert got == groups
        assert any(p and p.startswith("compiling kernels") for p in phases) == bool(groups)


@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_a_scan_reaching_far_warms_the_lists_group_before_its_frame_is_cast(tmp_path, monkeypatch):
    """A laser whose box may be too big for masks (80 m level, 40 m pitched by 5 degrees, at
    0.05 m) has its voxels listed: the lists group is warmed at its first frame, before it is
    cast; one of 10 m, or with an infinite range_max and returns within 2 m, is not (an infinite
    range_max crashed the check)."""
    import math

    from logfactory import scan, tf, write_log

    import ltmap_cli.pipeline.replay as replay_mod
    from ltmap_cli.io.frames import ScanFrame
    from ltmap_cli.pipeline.rays import FrameCaster
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    seen: list = []
    real_cast, real_up = FrameCaster.cast, replay_mod.warm_up

    def cast(self, frame, T, robot):
        seen.append(("cast", isinstance(frame, ScanFrame)))
        return real_cast(self, frame, T, robot)

    def up(cfg, groups):
        seen.append(("warm", tuple(groups)))
        real_up(cfg, groups)

    monkeypatch.setattr(FrameCaster, "cast", cast)
    monkeypatch.setattr(replay_mod, "warm_up", up)
    monkeypatch.setattr(replay_mod, "kernels_cached", lambda groups=(): True)
    monkeypatch.setattr(replay_mod, "groups_cached", lambda groups, layout="C": "lists" not in groups)
    S = 10**9
    level, pitched = (0.0, 0.0, 0.0, 1.0), (0.0, math.sin(math.radians(2.5)), 0.0, math.cos(math.radians(2.5)))
    for range_max, q, lists in ((80.0, level, True), (10.0, level, False), (40.0, pitched, True),
                                (float("inf"), level, False)):  # fmt: skip
        seen.clear()
        msgs = [tf(S // 2, [("map", "laser", (0.0, 0.0, 0.3), q)], static=True)]
        msgs += [scan("/scan", S + i * S // 10, [2.0] * 90 + [float("inf")] * 10, range_max=range_max) for i in range(3)]
        name = f"scan{range_max:g}_{q[1]:.2f}"
        log = write_log(tmp_path / f"{name}.mcap", "mcap-ros2", msgs)
        cfg = Config()
        cfg.replay.plots = False
        run = Replay(cfg, ReplayRequest([log], tmp_path / name))
        run.threads = False
        run.run()
        warmed = [s for s in seen if s == ("warm", ("lists",))]
        assert len(warmed) == (1 if lists else 0)
        if lists:
            assert seen.index(warmed[0]) < seen.index(("cast", True))


def test_a_first_run_waits_for_another_ones_compiling_instead_of_compiling_beside_it(tmp_path, monkeypatch):
    """Two first runs on one machine (a fleet batch's workers): while one's children compile into
    the cache (it holds the cache's compile lock), the other starts none and waits for it; the
    lock is released when the children end or are stopped, and by the OS if the run dies."""
    import threading
    import time

    from ltmap_cli.pipeline import warmup
    from ltmap_cli.pipeline.warmup import BackgroundCompile, CompileLock

    spawned = []

    class Child:  # a child that has ended
        def __init__(self, args, **kw):
            spawned.append(args[3:])

        def poll(self):
            return 0

        def kill(self):
            pass

        def wait(self):
            return 0

    monkeypatch.setattr(warmup.subprocess, "Popen", Child)
    monkeypatch.setattr(warmup, "usable_cores", lambda: 2)  # (a child per core)
    first = BackgroundCompile(["rays", "maps"], folder=tmp_path)  # a first run: compiles, holds the lock
    assert not first.waiting and spawned == [["rays"], ["maps"]]  # (the costlier first: COMPILE_S)
    second = BackgroundCompile(["rays", "maps"], folder=tmp_path)  # another, meanwhile: waits
    assert second.waiting and len(spawned) == 2
    threading.Timer(0.4, first.wait).start()  # the first's children end 0.4 s from now
    t0 = time.monotonic()
    second.wait()
    assert time.monotonic() - t0 >= 0.35 and not second.waiting
    assert CompileLock(tmp_path).try_acquire() is True  # released (and taken here: a third would wait)
    third = BackgroundCompile(["rays"], folder=tmp_path)
    assert third.waiting
    monkeypatch.undo()  # (subprocess.Popen is the module's: the real one again)
    # a run that dies holding it: the OS releases it
    code = f"from ltmap_cli.pipeline.warmup import CompileLock; import os; CompileLock(__import__('pathlib').Path({str(tmp_path / 'd')!r})).try_acquire(); os._exit(0)"
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert CompileLock(tmp_path / "d").try_acquire() is True


def test_kernels_cached_looks_where_numba_caches_them(tmp_path):
    """With a NUMBA_CACHE_DIR that other projects share, only ltmap's own folder in it counts:
    another project's newer kernels there do not make a first run skip its compiling children
    (which then compiled in the main process, in the middle of mapping)."""
    (tmp_path / "other_project").mkdir()
    (tmp_path / "other_project" / "kernel-1.py311.nbi").write_bytes(b"")
    code = ("from ltmap_cli.pipeline.warmup import cache_folder, kernels_cached; "
            "print(kernels_cached(), cache_folder())")  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    cached, folder = out.stdout.split()
    assert cached == "False" and Path(folder).parent == tmp_path and Path(folder).name.startswith("core_")


def test_kernels_cached_follows_the_source_text_not_its_time(tmp_path):
    """numba keeps a hash of a module's source in its kernels' cache: a reinstall, a checkout or
    a touch that leaves the text as it was keeps the cache good, and ``kernels_cached()`` says so
    (it compared times before: every replay after a touch started compiling children with
    nothing to compile, and waited for them); an edited module's cache is stale, and it says so;
    a damaged index is removed (numba failed on it in every run), and compiled again."""
    import shutil

    pkg = tmp_path / "code" / "ltmap_cli"
    shutil.copytree(ROOT / "ltmap_cli", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "code"), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    def cached(compile_one: bool = False, compile_two: bool = False, features: str | None = None) -> bool:
        code = ("import numpy as np\n"
                "from ltmap_cli.pipeline.warmup import kernels_cached\n"
                "from ltmap_cli.core import projective\n"
                "print(kernels_cached(), projective.__file__)\n"
                + ("projective.ends_box(np.zeros(3), np.ones((2, 3)), 20.0)\n" if compile_one or compile_two else "")
                + ("projective.depth_range_image(np.ones((16, 16), np.uint16), True, np.ones((16, 16)), 8.0, 0.2)\n"
                   if compile_two else ""))  # fmt: skip
        run_env = env if features is None else {**env, "NUMBA_CPU_FEATURES": features}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=run_env, check=True,
                             cwd=tmp_path)  # (not the checkout's folder: -c imports from the working folder first)
        assert out.stdout.split()[1] == str(pkg / "core" / "projective.py")
        return out.stdout.split()[0] == "True"

    assert not cached(compile_two=True)  # nothing cached yet; then three kernels compile and are cached
    assert cached()
    later = os.stat(pkg / "core" / "raycast.py").st_mtime + 3600
    for f in (pkg / "core").glob("*.py"):
        os.utime(f, (later, later))  # a reinstall of the same code: newer files, the same text
    assert cached()
    src = pkg / "core" / "projective.py"
    src.write_text(src.read_text() + "\n# an edit\n")
    assert not cached(compile_one=True)  # projective's kernels are stale: the first run compiles them again
    # one of the module's kernels compiled for its new text is enough: the others (depth_range_image
    # and its callee) keep their stale index until called, and are compiled then
    assert cached()
    # a damaged index (a cache copied in part) is removed: not cached, and the kernel compiles
    # again instead of failing in numba's unpickling in every run
    index = next((tmp_path / "numba").glob("*/projective.ends_box-*.nbi"))
    index.write_bytes(index.read_bytes()[:20])
    assert not cached(compile_one=True)
    assert index.exists() and cached()  # written again, whole
    # code compiled for other target features (another CPU sharing the folder, or the user's
    # NUMBA_CPU_FEATURES) is not this target's: not cached for them until they compile theirs;
    # then both are
    other = "+64bit,+cmov,+cx8,+fxsr,+mmx,+sse,+sse2"
    assert not cached(compile_two=True, features=other)
    assert cached(features=other) and cached()


_KERNEL = """
from ltmap_cli.jit import njit  # (the features this process compiles for, as every kernel of ltmap)


@njit(cache=True)
def plus_one(x):
    return x + 1
"""


@pytest.mark.parametrize("damaged", ["nbc", "nbi"])
def test_a_damaged_cache_file_is_one_error_that_removes_it(tmp_path, damaged):
    """numba reads its cache files whole and does not catch a pickle cut short (a cache copied
    in part): every run then failed in numba with its traceback, until the cache was deleted by
    hand. ``kernel_cache_error`` names the file, removes it and its kernel's index, and the next
    call compiles again. A data file (numba's own failure) and an index (met outside a replay's
    ``kernels_cached``) alike; any other error is not it."""
    import importlib
    import sys

    from ltmap_cli.errors import KernelCacheError
    from ltmap_cli.pipeline.warmup import kernel_cache_error

    name = f"ltmap_test_kernel_{damaged}"
    (tmp_path / f"{name}.py").write_text(_KERNEL)
    run = [sys.executable, "-c", f"import {name}; print({name}.plus_one(1))"]
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    assert subprocess.run(run, capture_output=True, text=True, env=env, check=True).stdout.strip() == "2"
    (cut,) = (tmp_path / "__pycache__").glob(f"{name}.*.{damaged}")
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    sys.path.insert(0, str(tmp_path))
    try:
        module = importlib.import_module(name)
        with pytest.raises(Exception) as info:
            module.plus_one(1)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop(name, None)
    err = kernel_cache_error(info.value)
    assert isinstance(err, KernelCacheError) and str(cut) in str(err) and "run the command again" in str(err)
    assert not list((tmp_path / "__pycache__").glob(f"{name}.*.nbi")) and not cut.exists()
    assert kernel_cache_error(ValueError("another error")) is None
    # the next run compiles it again, and the one after loads it
    for _ in range(2):
        assert subprocess.run(run, capture_output=True, text=True, env=env, check=True).stdout.strip() == "2"


def test_the_cli_says_a_damaged_kernel_cache_in_one_line_and_heals(tmp_path):
    """``ltmap plan`` on a cache whose planner data file is cut short: one line naming the file,
    exit status 2 (was numba's traceback and status 1 in every run); the run after plans as the
    first did."""
    import sys

    from test_plan import door_map, write_trinary, xy

    grid = write_trinary(tmp_path / "m.yaml", door_map(True))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "ltmap_cli", "plan", str(grid), "--start", xy(10, 30), "--goal", xy(50, 30)]
    first = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert first.returncode == 0, first.stderr
    (data,) = (tmp_path / "cache").rglob("planner._astar-*.nbc")
    data.write_bytes(data.read_bytes()[:100])
    bad = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert bad.returncode == 2 and bad.stderr.startswith("ltmap: error: numba's cache of the compiled kernels")
    assert len(bad.stderr.strip().splitlines()) == 1 and data.name in bad.stderr and not data.exists()
    again = subprocess.run(cmd, capture_output=True, text=True, env=env)
    plan = [line for line in first.stdout.splitlines() if not line.startswith("expanded:")]  # (its time)
    assert again.returncode == 0 and [line for line in again.stdout.splitlines() if line in plan] == plan


def test_a_read_only_install_with_no_user_cache_caches_the_kernels_in_the_temp_folder(tmp_path, monkeypatch):
    """numba caches kernels beside the modules or in the user's cache folder, and refuses at
    import when it can write neither (an install owned by root with a read-only home; a
    container's read-only root file system): "cannot cache function 'pack_block': no locator
    available", in every command, ``--help`` included. ``ltmap_cli`` then points
    ``NUMBA_CACHE_DIR`` at a folder of its own in the temp folder. Made here without
    permissions (the tests may run as root): a file where the package's ``__pycache__`` would
    be, and ``XDG_CACHE_HOME`` under a file."""
    import shutil
    import sys

    from ltmap_cli import _kernel_cache_fallback

    copy = tmp_path / "site"
    shutil.copytree(ROOT / "ltmap_cli", copy / "ltmap_cli", ignore=shutil.ignore_patterns("__pycache__"))
    for package in ("core", "analysis", "io", "sim", "pipeline"):
        (copy / "ltmap_cli" / package / "__pycache__").write_text("not a folder")
    (tmp_path / "tmp").mkdir()
    env = {**os.environ, "PYTHONPATH": str(copy), "XDG_CACHE_HOME": "/dev/null/cache", "TMPDIR": str(tmp_path / "tmp")}
    env.pop("NUMBA_CACHE_DIR", None)
    call = "import ltmap_cli.core.grid as g, numpy as np; print(g.unpack_block(np.int64(g.pack_block(1, 2, 3))))"
    out = subprocess.run([sys.executable, "-c", call], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-500:]
    assert out.stdout.split() == ["(1,", "2,", "3)"]
    cached = list((tmp_path / "tmp").glob(f"ltmap-numba-cache-{os.getuid()}/core_*/grid.*.nbi"))
    assert cached  # compiled into the fallback folder, found there by the next process
    help_ = subprocess.run([sys.executable, "-m", "ltmap_cli", "plan", "--help"], capture_output=True, text=True,
                           env=env, cwd=tmp_path)  # fmt: skip
    assert help_.returncode == 0 and "Usage:" in help_.stdout
    # the decision itself: a cache dir given wins; a writable package or user folder is left to numba
    import tempfile

    (tmp_path / "tmp2").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp2"))
    environ = {"XDG_CACHE_HOME": "/dev/null/cache"}
    assert _kernel_cache_fallback(environ, package=copy / "ltmap_cli") == environ["NUMBA_CACHE_DIR"]
    assert _kernel_cache_fallback({"NUMBA_CACHE_DIR": "/x", "XDG_CACHE_HOME": "/dev/null/c"}, package=copy / "ltmap_cli") is None
    assert _kernel_cache_fallback({"XDG_CACHE_HOME": str(tmp_path / "user")}, package=copy / "ltmap_cli") is None
    assert _kernel_cache_fallback({"XDG_CACHE_HOME": "/dev/null/cache"}, package=ROOT / "ltmap_cli") is None
    # a folder of that name that others may write into is not taken (their pickles would be loaded as kernels)
    (tmp_path / "tmp" / f"ltmap-numba-cache-{os.getuid()}").chmod(0o777)
    out = subprocess.run([sys.executable, "-c", call], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode != 0 and "no locator available" in out.stderr
