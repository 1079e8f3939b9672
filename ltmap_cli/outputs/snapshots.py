"""Long-term snapshots: OctoMap ``.ot``, ``.ply`` for viewers, and the exact state for --resume.

``.ot``: every voxel with LT > 0, as an OctoMap OcTree whose log-odds are shifted so that
OctoMap's own occupancy test (p >= 0.5) agrees with ltmap's (LT >= occupied_thresh, 0.65):
``logodds = logit(clip(LT, 0.001, 0.999)) - logit(occupied_thresh)``. ``LT`` is recovered as
``sigmoid(logodds + logit(occupied_thresh))`` (to within the clip) when an ``.ot`` is resumed.
Besides them it holds the free space: every voxel the sensor map O has seen free (log-odds < 0)
that LT does not hold, at the log-odds of LT = 0 (``lt_to_ot_logodds(0)`` = logit(0.001) -
logit(0.65), about -7.53). So OctoMap, ``ltmap diff`` and ``ltmap plan`` tell free (seen, nothing
there, e.g. where an object was seen gone) from unknown (absent from the tree). Free space is most
of a snapshot (the house sample ends with 233,418 free voxels beside 1,162 with LT > 0); the writer
prunes it as OctoMap does (see ``io.ot``). A voxel whose LT is being forgotten (0 < LT < 0.65)
has log-odds < 0: free for OctoMap too. ``--resume`` keeps only LT > 1.5e-3, so the free leaves
seed nothing: resuming from an ``.ot`` gives the LT a state file gives.

``state_*.npz``: the map core's exact arrays (O, ST, LT and clocks). ``--resume`` carries LT only
(day 2 starts with a fresh sensor map and short-term layer), from a state file, an ``.ot``, or an
output folder (its ``snapshots/state_final.npz``). ``diff`` and ``plan`` read a state file as the
``.ot`` written beside it (``read_snapshot_voxels``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..core.config import MapConfig, logodds
from ..core.grid import BLOCK_VOXELS, coord_to_pos
from ..core.layers import D_CHANNELS, O_STATE_CHANNELS, LayeredMap
from ..errors import LtmapWarning, MapFileError, shown
from ..io.ply import write_voxels_ply
from ..io.state import read_state, write_state
from .folder import OutputFolder

LT_CLIP = 1e-3
SNAPSHOTS = "snapshots"  # the snapshots' folder in a replay's output folder


def lt_to_ot_logodds(lt: np.ndarray, occupied_thresh: float) -> np.ndarray:
    p = np.clip(np.asarray(lt, dtype=np.float64), LT_CLIP, 1.0 - LT_CLIP)
    return (logodds(p) - logodds(occupied_thresh)).astype(np.float32)


def ot_logodds_to_lt(values: np.ndarray, occupied_thresh: float) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64) + logodds(occupied_thresh)
    lt = 1.0 / (1.0 + np.exp(-x))
    lt = np.where(lt >= 1.0 - 1.5 * LT_CLIP, 1.0, lt)
    return lt.astype(np.float32)


def snapshot_name(t_s: float | None) -> str:
    return "final" if t_s is None else f"t{t_s:08.1f}s"


KILLED_RUN_STATE = ".killed_run_state.npz"  # beside OUT: the last snapshot of a replay into OUT that was killed


def keep_killed_run_state(staging: Path, target: Path) -> None:
    """``staging`` is what a replay into ``target`` left when it was killed (the next run into it
    removes it): keep its last snapshot's state as ``<target>.killed_run_state.npz`` (a newer
    one replaces it), and say how to map the rest of the log from there, so hours of replay are
    not lost with the run."""
    import warnings

    from ..io.state import read_state_meta

    folder = staging / SNAPSHOTS
    if not folder.is_dir():
        return
    states = sorted(folder.glob("state_t*.npz"))  # t%08.1f: in time order
    final = folder / f"state_{snapshot_name(None)}.npz"
    best = final if final.is_file() else (states[-1] if states else None)
    if best is None:
        return
    meta = read_state_meta(best)
    if not meta:
        return
    kept = target.parent / (target.name + KILLED_RUN_STATE)
    os.replace(best, kept)
    mapped = meta.get("mapped_to_s")
    rest = (f"`ltmap replay LOG --start {mapped:g} --resume {kept} -o <a folder>` maps the rest of its log onto its "
            f"long-term layer" if isinstance(mapped, (int, float)) else f"--resume {kept} starts from it")
    where = f" (the sensor frames up to {mapped:g} s of log time)" if isinstance(mapped, (int, float)) else ""
    warnings.warn(LtmapWarning(f"a replay into {target} was killed before it finished; its last snapshot{where} is "
                               f"kept as {kept}: {rest}"), stacklevel=2)  # fmt: skip


def final_state() -> str:
    """The exact state at the end of a run, relative to its output folder (what --resume loads)."""
    return f"{SNAPSHOTS}/state_{snapshot_name(None)}.npz"


def long_term_voxels(lmap: LayeredMap) -> tuple[np.ndarray, np.ndarray]:
    """(keys (N, 3), LT (N,)) of every voxel with LT > 0: what a ``.ot`` snapshot holds."""
    D = lmap.D
    keys = D.voxels_where(D.channel("lt") > 0)
    return keys, D.get("lt", keys)


def _seen_free(lmap: LayeredMap) -> np.ndarray:
    """Per O voxel (blocks x 512): the sensor saw it free (log-odds < 0, updated at least once)."""
    O = lmap.O
    return (O.channel("logodds") < 0) & (O.channel("stamp") > 0)


def snapshot_voxels(lmap: LayeredMap) -> tuple[np.ndarray, np.ndarray]:
    """(keys (N, 3), OctoMap log-odds (N,) float32) of what a ``.ot`` snapshot holds: every voxel
    with LT > 0 (log-odds from its LT), then every voxel the sensor map O has seen free (log-odds
    < 0) and LT does not hold, at the log-odds of LT = 0 (``lt_to_ot_logodds(0)``)."""
    thr = lmap.cfg.projection.occupied_thresh
    keys, lt = long_term_voxels(lmap)
    free = lmap.O.voxels_where(_seen_free(lmap))
    if len(free):
        free = free[lmap.D.get("lt", free) <= 0]
    logodds = np.empty(len(keys) + len(free), dtype=np.float32)
    logodds[: len(keys)] = lt_to_ot_logodds(lt, thr)
    logodds[len(keys) :] = lt_to_ot_logodds(0.0, thr)
    return np.concatenate([keys, free]), logodds


def snapshot_ot_bytes(lmap: LayeredMap, long_term: tuple[np.ndarray, np.ndarray] | None = None) -> bytes:
    """The ``.ot`` of ``snapshot_voxels`` (the same bytes as ``ot_bytes(*snapshot_voxels(lmap))``),
    built block by block from the sensor map's arrays: memory for the pruned leaves only, not a
    key per free voxel (tens of millions on a 100 m floor). ``long_term``: ``long_term_voxels``
    when the caller has it already."""
    from ..io.ot import blocks_ot_bytes

    thr = lmap.cfg.projection.occupied_thresh
    lt_keys, lt = long_term if long_term is not None else long_term_voxels(lmap)
    O = lmap.O
    o_free = _seen_free(lmap)
    o_block = np.flatnonzero(o_free.any(axis=1))  # the sensor's blocks that hold free space
    blocks = O.block_keys()[o_block]
    if len(lt_keys):  # long-term voxels in blocks without free space (or never allocated: seeds, resume)
        lt_blocks = np.unique(lt_keys >> 3, axis=0)
        have = {tuple(k) for k in blocks.tolist()}
        extra = np.array([k for k in lt_blocks.tolist() if tuple(k) not in have], dtype=np.int64).reshape(-1, 3)
        if len(extra):
            blocks = np.concatenate([blocks, extra])
            o_block = np.concatenate([o_block, np.full(len(extra), -1, dtype=np.int64)])
    # OctoMap's keys are 16 bits: voxel indices -32768..32767 (+-1.6 km at 0.05 m); what lies
    # beyond is left out of the .ot (the state .npz keeps it), once said
    b_in = ((blocks >= -4096) & (blocks <= 4095)).all(axis=1)
    v_in = ((lt_keys >= -32768) & (lt_keys <= 32767)).all(axis=1)
    if not (b_in.all() and v_in.all()):
        blocks, o_block, lt_keys, lt = blocks[b_in], o_block[b_in], lt_keys[v_in], lt[v_in]
        _warn_once(f"the .ot snapshots leave out what lies beyond +-{32768 * lmap.resolution / 1000:.1f} km of "
                   f"the fixed frame's origin (OctoMap's 16-bit keys at {lmap.resolution:g} m); the state .npz "
                   f"snapshots hold it all")  # fmt: skip
    return blocks_ot_bytes(blocks, o_block, o_free, float(lt_to_ot_logodds(0.0, thr)), lt_keys,
                           lt_to_ot_logodds(lt, thr), lmap.resolution)  # fmt: skip


_WARNED: set[str] = set()


def _warn_once(text: str) -> None:
    import warnings

    from ..errors import LtmapWarning

    if text not in _WARNED:
        _WARNED.add(text)
        warnings.warn(LtmapWarning(text), stacklevel=3)


def static_digest(lmap: LayeredMap) -> str | None:
    """A short hash of the static map S on the map lattice (None without S): stored in each
    state file, so that ``--resume`` can tell when day 2 brings another S."""
    import hashlib

    S = lmap.static
    if S is None:
        return None
    h = hashlib.sha256()
    h.update(f"{S.i0},{S.j0},{S.resolution!r},{S.occ.shape}".encode())
    h.update(np.ascontiguousarray(S.occ).tobytes())
    h.update(np.ascontiguousarray(S.top_k).tobytes())
    return h.hexdigest()[:16]


def check_state(arrays: dict[str, np.ndarray], p: Path) -> float:
    """Check a state file's arrays against the layout ``LayeredMap.state_arrays`` writes (keys,
    dtypes, shapes, finite values in range) before anything is built from them; returns the
    resolution. One ``MapFileError`` line names the file and the fault."""

    def bad(what: str) -> MapFileError:
        return MapFileError(f"state file {p}: {what}; the file is damaged or not from this ltmap: write it "
                            f"again with ltmap replay (or give another snapshot)")

    voxels = BLOCK_VOXELS
    need = ["resolution", "frame_id", "tick_index"]
    for prefix, channels in (("O_", O_STATE_CHANNELS), ("D_", D_CHANNELS)):
        need += [f"{prefix}block_coords"] + [f"{prefix}{c}" for c in channels]
    missing = [k for k in need if k not in arrays]
    if missing:
        raise bad(f"missing array{'s' if len(missing) > 1 else ''} {', '.join(missing[:5])}"
                  + (f", ... {len(missing) - 5} more" if len(missing) > 5 else ""))
    for key in ("resolution", "frame_id", "tick_index"):
        a = arrays[key]
        if a.shape != () or a.dtype.kind not in ("f" if key == "resolution" else "iu") + "iu":
            raise bad(f"{key} must be one number, got an array of {a.dtype} with shape {a.shape}")
    res = float(arrays["resolution"])
    if not (math.isfinite(res) and 0.001 <= res <= 10.0):
        raise bad(f"resolution {shown(res)} is not a voxel size in metres")
    if int(arrays["frame_id"]) < 0 or int(arrays["tick_index"]) < 0:
        raise bad("frame_id and tick_index must be >= 0")
    for prefix, channels in (("O_", O_STATE_CHANNELS), ("D_", D_CHANNELS)):
        coords = arrays[f"{prefix}block_coords"]
        if coords.ndim != 2 or coords.shape[1] != 3 or coords.dtype.kind not in "iu":
            raise bad(f"{prefix}block_coords must be integers of shape (N, 3), got {coords.dtype} {coords.shape}")
        n = coords.shape[0]
        if n and (coords.min() < -(2**28) or coords.max() >= 2**28):
            raise bad(f"{prefix}block_coords hold block indices beyond any map")
        if n and len(np.unique(coords, axis=0)) != n:
            raise bad(f"{prefix}block_coords name a block twice")
        for name, (dtype, _fill) in channels.items():
            a = arrays[f"{prefix}{name}"]
            if a.shape != (n, voxels):
                raise bad(f"{prefix}{name} has shape {a.shape}, not ({n}, {voxels}) as {prefix}block_coords says")
            if a.dtype.kind not in ("f" if np.dtype(dtype).kind == "f" else "iu"):
                raise bad(f"{prefix}{name} holds {a.dtype}, not {np.dtype(dtype)}")
            if a.dtype.kind == "f" and not np.isfinite(a).all():
                raise bad(f"{prefix}{name} holds NaN or infinite values")
            if name in ("st", "lt") and n and (a.min() < 0 or a.max() > 1):
                raise bad(f"{prefix}{name} holds values outside [0, 1]")
    return res


def read_snapshot_voxels(path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(keys, OctoMap log-odds, resolution) of a ``.ot`` or of a state ``.npz`` (the voxels and
    log-odds of the ``.ot`` written beside it, see ``snapshot_voxels``: occupied iff log-odds > 0,
    free where LT < occupied_thresh or O saw free space, unknown where absent)."""
    if Path(path).suffix.lower() == ".ot":
        from ..io.ot import read_ot

        return read_ot(path)

    arrays, _meta = read_state(path)
    lmap = LayeredMap(MapConfig(resolution=check_state(arrays, Path(path))))
    lmap.load_state_arrays(arrays)
    keys, logodds = snapshot_voxels(lmap)
    return keys, logodds, lmap.resolution


def write_snapshot(lmap: LayeredMap, folder: Path, t_s: float | None, meta: dict) -> dict[str, str]:
    """Write long_term_<name>.ot / .ply and state_<name>.npz into ``folder``; return their paths.
    The state is deflated in a second thread while the .ot and .ply are built (the map waits
    for both: a 100 m floor's snapshot, 650 MB of arrays, takes 1.7 s instead of 4.5 s)."""
    from concurrent.futures import ThreadPoolExecutor

    folder.mkdir(parents=True, exist_ok=True)
    name = snapshot_name(t_s)
    thr = lmap.cfg.projection.occupied_thresh
    out = {}
    state_path = folder / f"state_{name}.npz"
    with ThreadPoolExecutor(1, thread_name_prefix="ltmap-state") as pool:
        state = pool.submit(write_state, state_path, lmap.state_arrays(),
                            {"log_time_s": t_s, "static_digest": static_digest(lmap), **meta})  # fmt: skip
        ot_path = folder / f"long_term_{name}.ot"
        keys, lt = long_term_voxels(lmap)
        data = snapshot_ot_bytes(lmap, (keys, lt))
        ot_path.write_bytes(data)  # the folder is a staging folder (outputs.folder): no temporary name needed
        del data
        out["ot"] = str(ot_path)
        occ = lt >= thr
        ply_path = folder / f"long_term_{name}.ply"
        # no occupied voxel (the first snapshots of a run) is a valid PLY with 0 vertices: every
        # snapshot time has its .ot, .ply and .npz
        write_voxels_ply(ply_path, coord_to_pos(keys[occ], lmap.resolution), lt[occ], lmap.resolution)
        out["ply"] = str(ply_path)
        state.result()
    out["state"] = str(state_path)
    return out


def resolve_resume(path: str | Path) -> Path:
    """The snapshot file a --resume argument names: a state .npz, an .ot, or a completed replay
    output folder (its manifest names snapshots/state_final.npz, or else its latest state)."""
    p = Path(path)
    if p.is_dir():
        fix = "give a completed ltmap replay output folder, or a snapshot file (.npz or .ot)"
        manifest = OutputFolder.completed(p, "--resume", command="replay", fix=fix)
        states = sorted(n for n in manifest["files"] if n.startswith("snapshots/state_") and n.endswith(".npz"))
        if final_state() in states:
            return p / final_state()
        if states:
            return p / states[-1]
        raise MapFileError(f"--resume {p}: no {final_state()} in this folder; {fix}")
    if not p.is_file():
        raise MapFileError(f"--resume {p}: no such file or folder; give a replay output folder or a snapshot")
    if p.suffix not in (".npz", ".ot"):
        raise MapFileError(f"--resume {p}: expected a state .npz, an OctoMap .ot or an output folder")
    return p


def load_resume(lmap: LayeredMap, path: str | Path) -> dict:
    """Seed LT of ``lmap`` from a snapshot; returns what was loaded (for the report)."""
    p = resolve_resume(path)
    if p.suffix == ".ot":
        from ..io.ot import read_ot

        floor = float(lt_to_ot_logodds(LT_CLIP * 1.5, lmap.cfg.projection.occupied_thresh))
        keys, logodds, res = read_ot(p, min_logodds=floor)  # the free leaves (LT = 0) are not expanded
        if not math.isclose(res, lmap.resolution, rel_tol=1e-6):
            raise MapFileError(
                f"--resume {p}: resolution {res} m differs from this run's {lmap.resolution} m; "
                f"replay with --resolution {res}"
            )
        lt = ot_logodds_to_lt(logodds, lmap.cfg.projection.occupied_thresh)
        keep = lt > LT_CLIP * 1.5
        lmap.seed_long_term(keys[keep], lt[keep])
        n = int(keep.sum())
    else:
        arrays, meta = read_state(p)
        res = check_state(arrays, p)
        if not math.isclose(res, lmap.resolution, rel_tol=1e-6):
            raise MapFileError(
                f"--resume {p}: resolution {res} m differs from this run's {lmap.resolution} m; "
                f"replay with --resolution {res}"
            )
        lmap.load_state_arrays(arrays, long_term_only=True)
        n = int((lmap.D.channel("lt") > 0).sum())
        if "static_digest" in meta and meta["static_digest"] != static_digest(lmap):
            import warnings

            had, has = meta["static_digest"] is not None, lmap.static is not None
            why = ("another static map (--static) than the run that wrote it" if had and has else
                   "a static map (--static), and the run that wrote it had none" if has else
                   "no static map, and the run that wrote it had one (--static)")
            warnings.warn(LtmapWarning(
                f"--resume {p}: this run has {why}; the long-term map was learnt against the old one, so objects "
                f"may be counted twice or go missing: resume with the same --static"), stacklevel=2)
    return {"path": str(p), "long_term_voxels": n}
