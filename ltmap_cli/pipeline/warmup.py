"""The kernels' first calls, before the first frame: numba compiles them after an install (a
minute of CPU in one process), then loads them from its disk cache (well under a second).

Compiling is split into groups that share almost no kernel: ``rays`` (the rays of points and
scans, the voxels they pass as block masks, the rays' tails of depth frames too, their updates
of O), ``lists`` (the voxels rays pass listed, and their updates: frames whose box is too big for
block masks; only for sensors whose rays reach that far, ``lists_needed``), ``maps`` (the tick
rules, the projection, the snapshots' tree walk, the events' grouping), ``fused_scan`` (the
virtual scan of ``--mcap``), ``planner`` (``--plan-goal``) and two per depth image encoding, the
depth kernel's and the projective integration's (``depth16``, ``projective16``: 16UC1/mono16;
``depth32``, ``projective32``: 32FC1); a run warms only the groups it calls
(``replay_groups``). On a cold cache ``BackgroundCompile`` compiles the groups a run will need
in child processes, a child per core, the groups shared by their compiling time
(``children_of``), in parallel with each other and with reading and checking the log (started
at its first message, or, when it has raw depth images, at the first of them, whose pixels say
which encoding's groups: the replay's ``_start_compile``), so that the first run on two cores
waits for about half the compiling instead of all of it, and a log that fails its checks (a
missing transform) fails before any compiling is waited for. The children write numba's cache;
the replay then loads the kernels from it. A kernel that two groups call is compiled in both
children, so each group makes its map without the others' kernels (``maps`` seeds D instead of
casting rays); only the grid's block lookups and O's updates are in two. The depth groups leave
the voxels rays pass to ``rays``, which every replay warms.
"""

from __future__ import annotations

import contextlib
import fcntl
import importlib
import math
import os
import pkgutil
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
from numba.core.registry import CPUDispatcher

from .. import core
from ..core import raycast
from ..core.config import MapConfig
from ..core.grid import BLOCK
from ..core.layers import MAX_PLAIN_RANGE, LayeredMap, _QuietBlocks
from ..core.projection import project, virtual_scan
from ..core.projective import LISTED_VOXELS_MAX_BLOCKS, depth_projection_blocks
from ..core.sensors import depth_to_points, transform_points
from ..errors import KernelCacheError
from .executor import usable_cores

CORE = Path(__file__).resolve().parent.parent / "core"


def _pose() -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = 1.0
    return T


def warm_rays(cfg: MapConfig) -> None:
    """The frame path: a scan's points to the fixed frame, rays with and without a footprint,
    the voxels they pass as block masks (``LayeredMap.ray_voxels``; the rays' tails of a depth
    frame too) and their updates of O, and O's block pool grown (its hash table rebuilt)."""
    m = LayeredMap(cfg)
    T = _pose()
    scan = transform_points(T, np.array([[1.0, 0.1, -0.5], [1.0, -0.1, -0.98]]))  # to the fixed frame
    m.integrate(T[:3, 3], scan, [True, False], max_range=4.0, robot_pose=T)
    m.integrate([0.0, 0.0, 1.0], [[1.0, 0.1, 0.5]], None, max_range=4.0, robot_pose=None, dedupe=False)
    m.O.grow()


def warm_lists(cfg: MapConfig) -> None:
    """The voxels rays pass, listed, and their updates of O: a frame whose box holds too many
    blocks for block masks (``LayeredMap.ray_voxels``, ``depth_voxels``; a long-range 3D lidar's
    cloud), a group of its own, compiled beside the others (about 7 s)."""
    m = LayeredMap(cfg)
    origin = np.array([0.0, 0.0, 1.0])
    ends = np.array([[1.0, 0.1, 0.5], [-1.0, 0.0, 1.0]])
    kind = np.array([raycast.RAY_HIT, raycast.RAY_CLEAR], dtype=np.int8)
    m.apply_voxels(*m.frame_voxels(origin, ends, kind), 1)


def warm_maps(cfg: MapConfig) -> None:
    """What works on the map between and after frames: the tick rules, P, the .ot snapshot's
    tree walk and the events' grouping (D seeded, so the map has blocks, without the ``rays``
    group's kernels)."""
    from ..analysis.events import _group
    from ..outputs.snapshots import snapshot_ot_bytes

    m = LayeredMap(cfg)
    m.seed_long_term(np.array([[1, 1, 1], [2, 1, 1]], dtype=np.int64), 1.0)
    m.end_tick()
    # the quiet blocks' check after a tick (the rays group's apply_voxels makes their record)
    o, d, q = m.O, m.D, _QuietBlocks
    raycast.quiet_after_tick(o.n_blocks, np.zeros((o.max_blocks, 8), dtype=q.NFREE), np.zeros(o.max_blocks, dtype=q.FLAG),
                             o.block_coords, d.table_keys, d.table_vals, d.data["st"], d.data["lt"])  # fmt: skip
    # and the still voxels cleared where LT was seeded (the rays group's apply_voxels after a seed)
    raycast.still_clear(0, d.n_blocks, d.block_coords, d.data["st"], d.data["lt"], o.table_keys, o.table_vals,
                        np.zeros((o.max_blocks, 8), dtype=np.uint64))  # fmt: skip
    project(m)
    snapshot_ot_bytes(m)
    _group(np.zeros((2, 3), dtype=np.int64), np.zeros(2, dtype=np.int64), 1, 1)


def warm_fused_scan(cfg: MapConfig) -> None:
    """The virtual scan of /scan_fused (``--mcap``), over an empty map's P (made without
    kernels)."""
    m = LayeredMap(cfg)
    virtual_scan(m, project(m), (0.0, 0.0, 0.0), np.zeros(1), 0.05, 4.0, o_since_frame=1)


def warm_planner(cfg: MapConfig) -> None:
    """The planner (``--plan-goal``): the robot radius's inflation and the search."""
    from ..analysis.planner import inflate, plan_path

    plan_path(inflate(np.zeros((4, 4), dtype=bool), 1.5), (0, 0), (3, 3))


def warm_depth(cfg: MapConfig, dtype, contiguous: bool = True, parts=("rays", "projection")) -> None:
    """The depth kernels for raw pixels of ``dtype``, C-contiguous or a strided view (numba
    compiles one specialization per dtype and layout): ``rays``, the fused depth kernel (the
    frame's rays), and ``projection``, with projective depth integration the projection's
    kernels and the map thread's use of them. Not the voxels rays pass (``frame_voxels``, 10 s
    of compiling): the ``rays`` group compiles them, in every replay, with the same types. The
    two parts are two groups (``depth16``, ``projective16``): together they were the one group a
    first run waited for (17.7 s of 25.7 s on a 2-core AMD EPYC VM; the other groups 8.6 s and
    7.3 s), apart they compile in parallel."""
    m = LayeredMap(cfg)
    depth = np.full((2, 4), 1000 if np.dtype(dtype).kind == "u" else 1.0, dtype=dtype)
    depth = depth[:, :2] if contiguous else depth[:, ::2]
    if contiguous:
        depth = np.ascontiguousarray(depth)
    T = _pose()
    if "rays" in parts:
        m.depth_rays(depth, 1.0, 1.0, 0.5, 0.5, T, 4.0, T, dedupe=m.cfg.sensor.dedupe_dense)
    if "projection" not in parts or m.cfg.sensor.depth_integration != "projective":
        return
    ends = np.array([[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [-0.5, 0.5, 2.0], [0.5, 0.5, 2.0]])  # (depth_rays' for them)
    none = np.empty(0, dtype=np.int64)
    m.apply_voxels(none, none, 0, m.depth_projection(depth, 1.0, 1.0, 0.5, 0.5, T, 4.0, ends))
    # the map thread's fill of blocks a worker skipped as still that are still no more: every
    # voxel read as still, none is
    q = m._quiet_sync()
    q.still[:] = ~np.uint64(0)
    projection = m.depth_projection(depth, 1.0, 1.0, 0.5, 0.5, T, 4.0, ends)
    q.still[:] = 0
    m.apply_voxels(none, none, 0, projection)


def warm_depth_points(cfg: MapConfig) -> None:
    """The depth kernels of the plain path (``Replay.fast`` False, the tests' reference): a
    depth image in float32 metres as points, their rays (``classify_rays``, the end points'
    dedupe) and, with projective integration, the projection of float32 metres. Without it the
    first depth frame of a plain replay compiled them after a core module changed (4.7 to 6.9 s)."""
    m = LayeredMap(cfg)
    T = _pose()
    depth = np.ones((2, 2), dtype=np.float32)
    pts = transform_points(T, depth_to_points(depth, 1.0, 1.0, 0.5, 0.5))
    m.rays(T[:3, 3], pts, None, max_range=4.0, robot_pose=T, dedupe=m.cfg.sensor.dedupe_dense)
    warm_depth(cfg, np.float32, parts=("projection",))


GROUPS = {"rays": warm_rays, "lists": warm_lists, "maps": warm_maps, "fused_scan": warm_fused_scan, "planner": warm_planner,
          "depth16": lambda c: warm_depth(c, np.uint16, parts=("rays",)),
          "projective16": lambda c: warm_depth(c, np.uint16, parts=("projection",)),
          "depth32": lambda c: warm_depth(c, np.float32, parts=("rays",)),
          "projective32": lambda c: warm_depth(c, np.float32, parts=("projection",))}  # fmt: skip


def replay_groups(replay, raw_depth: bool = False, projective: bool = True, bits: str = "16",
                  lists: bool = False) -> list[str]:
    """The groups a replay with settings ``replay`` (``config.ReplayConfig``) calls: ``rays`` and
    ``maps`` always, ``lists`` with ``lists`` (a sensor whose frames' boxes may be too big for
    block masks: ``lists_needed``), ``fused_scan`` with ``--mcap``, ``planner`` with
    ``--plan-goal``, and with ``raw_depth`` (raw depth images) ``depth16`` (``bits`` "32":
    ``depth32``), and with ``projective`` (``map.sensor.depth_integration``) ``projective16``
    (``projective32``) too."""
    groups = ["rays", "lists", "maps"] if lists else ["rays", "maps"]
    if replay.mcap_out:
        groups.append("fused_scan")
    if replay.plan_goal:
        groups.append("planner")
    if raw_depth:
        groups += depth_groups(bits, projective)
    return groups


def box_blocks(reach: float, resolution: float, height: float | None = None) -> int:
    """The most blocks the box of a frame can hold (the voxels of its sensor and of its rays'
    ends, ``core.projective.ends_box``) when its rays reach at most ``reach`` m: a cube, or, given
    the ``height`` its ends can span (a scan's plane: ``scan_box_blocks``), a square that high."""
    b = resolution * BLOCK
    side = math.ceil(2.0 * reach / b) + 2  # (+ 2: the box's ends on blocks)
    return side * side * (side if height is None else math.ceil(height / b) + 2)


def scan_box_blocks(frame, T: np.ndarray, resolution: float) -> int:
    """``box_blocks`` of a LaserScan (``io.frames.ScanFrame``) placed at ``T`` (4x4, its frame in
    the fixed frame): its rays reach its ``range_max`` (no return clears up to it), or, without
    a finite one below ``MAX_PLAIN_RANGE`` (inf, as pointcloud_to_laserscan publishes), its
    farthest finite range; they lie in the laser's x-y plane, which spans 2 reach sin(tilt) in
    height (a laser pitched by 1 degree at 65 m: 2.3 m)."""
    rmax = float(frame.range_max)
    if math.isfinite(rmax) and 0.0 < rmax <= MAX_PLAIN_RANGE:
        reach = rmax
    else:
        r = np.asarray(frame.ranges, dtype=np.float64)
        fin = r[np.isfinite(r)]
        reach = float(np.abs(fin).max()) if len(fin) else 0.0
    return box_blocks(reach, resolution, 2.0 * reach * math.hypot(float(T[2, 0]), float(T[2, 1])))


def lists_needed(blocks: int) -> bool:
    """Whether a frame whose box may hold ``blocks`` blocks (``box_blocks``) may have its voxels
    listed (more than ``LISTED_VOXELS_MAX_BLOCKS``: the ``lists`` group's kernels, 6.6 s of a
    first run's compiling). At 0.05 m: not a depth camera or cloud cut at 8 m (42^3 blocks), nor
    a level laser of up to 70 m (352^2 x 2); a cloud cut at 30 m, a level laser of 80 m or one
    of 40 m pitched by 5 degrees, yes."""
    return blocks > LISTED_VOXELS_MAX_BLOCKS


def warm_up(cfg: MapConfig, groups=tuple(GROUPS)) -> None:
    """Call the kernels of ``groups`` once on throw-away maps (every group by default)."""
    for g in groups:
        GROUPS[g](cfg)


def depth_key(raw: np.ndarray) -> tuple:
    """What numba compiles a depth kernel for: a raw image's (native-order dtype, C-contiguous)."""
    return raw.dtype.newbyteorder("="), bool(raw.flags.c_contiguous)


class BackgroundWarmUp:
    """A warm run's kernels loaded from numba's cache in a thread of their own, started with the
    run (``Replay``): the loading (about 0.25 s of one core, under the GIL but for LLVM's part)
    then overlaps the static map, the log's opening and its first reads, when the other core
    has little to do, instead of holding up the first frame. ``depth(key)`` adds a depth image
    encoding's kernels (``warm_depth``; ``depth_key``) as soon as the log's first image of it is
    read. A job's future re-raises its failure (a damaged cache file) in the thread that asks
    for its ``result()``."""

    def __init__(self, cfg: MapConfig, groups):
        self.cfg = cfg
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="ltmap-warmup")
        self.common: Future | None = None
        self.depths: dict[tuple, Future] = {}
        self.add(groups)

    def add(self, groups) -> Future:
        """Load ``groups`` too, after those before, a job each (so ``close`` drops those not
        begun); ``common`` is the last, which re-raises the failure of any before it."""
        for g in groups:
            self.common = self.pool.submit(_after, self.common, warm_up, self.cfg, [g])
        return self.common

    def depth(self, key: tuple) -> Future:
        if key not in self.depths:
            self.depths[key] = self.pool.submit(warm_depth, self.cfg, *key)
        return self.depths[key]

    def close(self) -> None:
        """No more jobs; the one being run ends by itself (a kernel's loading cannot be stopped)."""
        self.pool.shutdown(wait=False, cancel_futures=True)


def _after(before: Future | None, fn, *args) -> None:
    """``fn(*args)`` once ``before`` has ended well (its failure is raised instead)."""
    if before is not None:
        before.result()
    fn(*args)


def cache_folder() -> Path:
    """Where numba caches the map's kernels, as numba itself chose when it loaded them: a folder
    of its own under ``NUMBA_CACHE_DIR``, else the modules' ``__pycache__``, else (an install the
    user cannot write) a user-wide folder. (Read from a kernel's cache; the first two when that
    is not there.)"""
    path = getattr(getattr(raycast.frame_voxels, "_cache", None), "_cache_path", None)
    if path:
        return Path(path)
    root = os.environ.get("NUMBA_CACHE_DIR")
    return Path(root) if root else CORE / "__pycache__"


def _core_kernels():
    """The numba functions of ``ltmap_cli.core`` (each with a disk cache: ``cache=True``)."""
    for info in pkgutil.iter_modules(core.__path__):
        mod = importlib.import_module(f"{core.__name__}.{info.name}")
        for obj in vars(mod).values():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == mod.__name__:
                yield obj


def kernels_cached() -> bool:
    """Whether numba's disk cache holds the map's kernels for the code as it is (else the first
    run compiles them), as numba itself decides: a kernel's index (``*.nbi``, in
    ``cache_folder()``) counts when it was written by the same numba for the same source text
    (numba keeps a hash of the module's source in it, not the file's time). So a reinstall, a
    checkout or a touch that leaves the source as it was keeps the cache (comparing times, every
    replay after one started compiling children that had nothing to compile, and waited for
    them), and an edited module's kernels are compiled again. Per core module, one index written
    for its text is enough: a kernel called only from other kernels (or from Python only on a
    rare path, a buffer's growth) keeps an index of an older text for as long as its callers'
    are good, and a kernel never compiled has none; an index counts only with code for this
    process's target (numba's key: CPU and features). An index that cannot be read (a cache
    copied in part, a damaged disk: numba writes them whole) is removed, so numba compiles that
    kernel again instead of failing on it in every run. (The groups a run calls only for some
    logs: ``groups_cached``.)"""
    try:
        target = _target()
        fresh: dict[str, bool] = {}
        for k in _core_kernels():
            if os.path.exists(k._cache._cache_file._index_path) and not fresh.get(k.__module__):
                fresh[k.__module__] = _index_good(k, target)
        return bool(fresh) and all(fresh.values())
    except (AttributeError, ImportError):  # numba's internals moved: compare times, as numba did once
        folder = cache_folder()
        newest = max((f.stat().st_mtime for f in folder.glob("*.nbi")), default=None) if folder.is_dir() else None
        return newest is not None and newest >= max(f.stat().st_mtime for f in CORE.glob("*.py"))


def groups_cached(groups, layout: str = "C") -> bool:
    """Whether the cache holds code for this target of each of ``groups`` that a run calls only
    for some logs (``GROUP_PROBES``: a kernel that only it compiles, for the encoding of its
    images, with ``layout`` "C" or "A": a strided image): the module's other kernels say nothing
    of them (the lists group after runs that never needed it; the 32FC1 depth kernels after
    16UC1 logs only)."""
    try:
        target = _target()
        return all(_index_good(k, target, dtype, layout) for g in groups for k, dtype in GROUP_PROBES.get(g, ()))
    except (AttributeError, ImportError):  # (numba's internals moved: kernels_cached's times only)
        return True


def _target() -> tuple:
    """numba's key for this process's target (triple, CPU, features: ``ltmap_cli.jit``'s choice):
    code cached for another CPU sharing the folder, or for other ``NUMBA_CPU_FEATURES``, is not
    this process's."""
    from numba.core.registry import cpu_target

    return cpu_target.target_context.codegen().magic_tuple()


def _index_good(kernel, target, dtype=None, layout: str = "C") -> bool:
    """Whether ``kernel``'s index (numba's, in the cache) was written for this source text and
    holds code for ``target`` (with ``dtype``, for a first argument of that dtype and ``layout``);
    one that cannot be read is removed (numba compiles it again)."""
    f = kernel._cache._cache_file
    if not os.path.exists(f._index_path):
        return False
    try:  # ({}: another numba, or another source text)
        keys = list(f._load_index())
    except Exception:  # (unpickling a damaged file: any of several errors)
        with contextlib.suppress(OSError):
            os.remove(f._index_path)
        return False  # (to compile, in the first run's children)
    want = None if dtype is None else np.dtype(dtype).name
    return any(key[1] == target and (want is None or (str(getattr(key[0][0], "dtype", "")) == want
                                                      and getattr(key[0][0], "layout", "") == layout))
               for key in keys)  # fmt: skip


# the groups a run calls only for some logs (``replay_groups``), and a kernel that only each
# compiles, with the dtype of its first argument (a depth image's): what ``groups_cached`` reads
GROUP_PROBES = {
    "lists": ((raycast.frame_voxels, None),),
    "depth16": ((raycast.depth_image_rays, np.uint16),),
    "projective16": ((depth_projection_blocks, np.uint16),),
    "depth32": ((raycast.depth_image_rays, np.float32),),
    "projective32": ((depth_projection_blocks, np.float32),),
}


def depth_groups(bits: str, projective: bool) -> list[str]:
    """The groups of a depth image encoding (``bits`` "16" or "32": ``depth_bits``): its depth
    kernel's, and with projective integration its projection's."""
    return [f"depth{bits}", f"projective{bits}"] if projective else [f"depth{bits}"]


def depth_bits(dtype) -> str:
    """A raw depth image's encoding: "32" for float32 metres (32FC1), else "16"."""
    return "32" if np.dtype(dtype).kind == "f" else "16"


_NUMBA_LOADS = ("_load_index", "_load_data")  # numba.core.caching.IndexDataCacheFile's readers


def kernel_cache_error(exc: BaseException) -> KernelCacheError | None:
    """When numba failed reading a file of its disk cache (``exc`` raised, in this thread or a
    worker's, from ``IndexDataCacheFile._load_index`` or ``_load_data``: a data file or an index
    cut short or damaged, which numba does not catch), that file and its kernel's index removed
    and an error saying so; else None. numba compiles the kernel again at its next call, so the
    next run works (before, every run failed there with numba's traceback until the cache was
    deleted by hand). ``kernels_cached`` removes damaged indexes before a replay; this catches
    the rest: data files, other commands' kernels."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        tb = exc.__traceback__
        while tb is not None:
            code = tb.tb_frame.f_code
            if code.co_name in _NUMBA_LOADS and Path(code.co_filename).parts[-3:] == ("numba", "core", "caching.py"):
                local = tb.tb_frame.f_locals
                cache = local.get("self")
                path = local.get("path") if code.co_name == "_load_data" else getattr(cache, "_index_path", None)
                if path:
                    return _removed_cache_file(Path(path), getattr(cache, "_index_path", None), exc)
            tb = tb.tb_next
        exc = exc.__cause__ or exc.__context__
    return None


def _removed_cache_file(path: Path, index: str | None, exc: BaseException) -> KernelCacheError:
    removed = []
    for p in dict.fromkeys([path, Path(index) if index else path]):
        with contextlib.suppress(OSError):
            p.unlink()
            removed.append(p.name)
    what = f"{type(exc).__name__}: {exc}".rstrip(": ")
    done = f"removed {' and '.join(removed)}, so it compiles again (once, a few seconds)" if removed else \
        f"remove it (or the whole folder {path.parent})"
    return KernelCacheError(f"numba's cache of the compiled kernels holds a file it cannot read: {path} ({what}); "
                            f"{done}; run the command again")  # fmt: skip


# seconds each group took to compile alone in a child, its 0.35 s of start-up left out (a 2-core
# Intel Xeon VM, 2026-12-04, session 30): how the children share the groups (``children_of``)
COMPILE_S = {"rays": 7.2, "lists": 6.6, "maps": 6.0, "fused_scan": 1.0, "planner": 2.4, "depth16": 3.1,
             "projective16": 10.6, "depth32": 3.3, "projective32": 10.7}  # fmt: skip


def children_of(groups, cores: int) -> list[list[str]]:
    """``groups`` shared among at most ``cores`` child processes, the costliest group first, each
    to the child with the least compiling so far (``COMPILE_S``). The children share the cores, so
    the run waits for all of them: what counts is the compiling they do in all, and each child
    adds its start-up and compiles again the kernels its groups share with another child's (the
    grid's lookups, O's updates, the quiet blocks' counts). On 2 cores the house sample's five
    groups took 19.4 to 19.7 s in two children, 21.5 to 21.7 s in three (session 30; with four
    groups in session 21, three children had been faster than four)."""
    children: list[list[str]] = []
    load: list[float] = []
    for g in sorted(groups, key=lambda g: -COMPILE_S.get(g, 1.0)):
        if len(children) < max(cores, 1):
            children.append([g])
            load.append(COMPILE_S.get(g, 1.0))
            continue
        i = load.index(min(load))
        children[i].append(g)
        load[i] += COMPILE_S.get(g, 1.0)
    return children


COMPILE_LOCK = ".ltmap-compile.lock"  # in the cache folder: one first run's compiling at a time


class CompileLock:
    """An exclusive ``flock`` on ``COMPILE_LOCK`` in the kernels' cache folder, held while a first
    run's children compile into it (released by the OS if that run is killed)."""

    def __init__(self, folder: Path | None = None):
        self.path = (folder if folder is not None else cache_folder()) / COMPILE_LOCK
        self.fd: int | None = None

    def try_acquire(self) -> bool | None:
        """True: ours now; False: another process holds it; None: no lock here (a read-only
        install: nothing to coordinate)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        except OSError:
            os.close(fd)
            return None
        self.fd = fd
        return True

    def wait_released(self) -> None:
        """Until the process that holds it releases it."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            pass
        finally:
            os.close(fd)  # (closing releases it)

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


class BackgroundCompile:
    """Child processes that compile kernel groups into numba's cache, started at once
    (``children_of`` this machine's cores); ``wait()`` before calling the kernels, ``stop()``
    when the run ends early. When another ltmap is compiling into the same cache (two first runs
    at once: a fleet batch's workers on one machine), none are started (``waiting``): ``wait()``
    waits for that one instead of compiling the same kernels again beside it, and the run loads
    what it compiled (and compiles what it did not, in its own process)."""

    def __init__(self, groups, folder: Path | None = None):
        self.procs = []
        self.lock = CompileLock(folder)
        self.waiting = self.lock.try_acquire() is False
        if self.waiting:
            return
        for child in children_of(groups, usable_cores()):  # (a container's CPU quota counts)
            self.procs.append(subprocess.Popen([sys.executable, "-m", __name__, *child], stdin=subprocess.DEVNULL,
                                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))  # fmt: skip

    def wait(self, on_done=None, poll_s: float = 0.2) -> None:
        """Until every child has ended; ``on_done(ended, total)`` each time one more has (a first
        run's half minute of compiling says that it moves). ``waiting``: until the other run's
        compiling has ended."""
        if self.waiting:
            self.lock.wait_released()
            self.waiting = False
            return
        total, ended = len(self.procs), 0
        while ended < total:
            now = sum(p.poll() is not None for p in self.procs)
            if now == ended:
                time.sleep(poll_s)
                continue
            ended = now
            if on_done is not None:
                on_done(ended, total)
        self.procs = []
        self.lock.release()

    def stop(self) -> None:
        for p in self.procs:
            p.kill()
            p.wait()
        self.procs = []
        self.lock.release()


if __name__ == "__main__":  # a BackgroundCompile child: python -m ltmap_cli.pipeline.warmup GROUP [GROUP ...]
    warm_up(MapConfig(), sys.argv[1:])
