"""Cell-by-cell comparison of two occupancy maps (``ltmap diff``), and of two voxel sets (``--3d``).

Alignment (``align``): both maps are brought onto one *target* lattice, that of the reference
map: the finer of the two (A when they have the same resolution). The target grid covers the
union of both maps' footprints; a target cell outside a map's extent is unknown in that map.
The other map is sampled at the target cell centres, each taking the value of the cell of the
other map that contains it (its nearest cell centre). When the two lattices coincide (same
resolution and yaw, origins a whole number of cells apart) this is an exact shift; otherwise
the map is resampled and ``Aligned.notes`` says so. Different resolutions need
``resample=True`` (else InputError naming ``--resample``); a non-zero yaw is honoured (the
target frame is the reference's, rotated).

Classes (see ``ltmap_cli.analysis``): occupied >= 65, unknown -1, free otherwise.

- added: occupied in B, free or unknown in A;
- removed: occupied in A, free in B;
- unknown-changed: known in one, unknown in the other, and neither added nor removed
  (e.g. occupied -> unknown, free <-> unknown);
- unchanged occupied: occupied in both;
- IoU: |occ A & occ B| / |occ A | occ B| (1.0 when neither has an occupied cell).

``tolerance`` N (cells) ignores an added cell whose centre lies within N cells (Euclidean,
inclusive) of the centre of a cell occupied in A, and a removed cell within N cells of a cell
occupied in B. The maps are *the same* when nothing is added or removed after the tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io.mapfile import GridMap
from . import OCCUPIED_MIN

_SNAP = 1e-6  # a coordinate within this many cells of an integer is that integer


def _same(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b), 1.0)


def _snap(v: np.ndarray) -> np.ndarray:
    r = np.round(v)
    return np.where(np.abs(v - r) < _SNAP, r, v)


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


@dataclass
class Aligned:
    a: np.ndarray  # int8 (H, W): A's values on the target lattice (-1 outside A)
    b: np.ndarray  # int8 (H, W): B's values on the target lattice (-1 outside B)
    resolution: float
    origin: tuple[float, float, float]  # lower-left corner of target cell (0, 0) and yaw
    reference: str  # name of the map whose lattice is the target ("A" or "B")
    notes: list[str] = field(default_factory=list)

    def grid(self, which: str) -> GridMap:
        return GridMap(self.a if which == "A" else self.b, self.resolution, self.origin)


def _sample(src: GridMap, ref_origin, ref_yaw: float, res: float, row0: int, col0: int, h: int, w: int):
    """Values of ``src`` at the centres of target cells rows row0..row0+h, cols col0..col0+w of
    the lattice (ref_origin, ref_yaw, res); -1 outside ``src``."""
    out = np.full((h, w), -1, dtype=np.int8)
    ox, oy = ref_origin
    sx, sy, syaw = src.origin
    rs = src.resolution
    xs = (col0 + np.arange(w) + 0.5) * res  # target-local cell centres
    ys = (row0 + np.arange(h) + 0.5) * res
    if _same(syaw, ref_yaw):
        # same orientation: separable. src-local = target-local + R(-yaw) (o_ref - o_src)
        d = _rot(-syaw) @ np.array([ox - sx, oy - sy])
        cols = np.floor(_snap((xs + d[0]) / rs)).astype(np.int64)
        rows = np.floor(_snap((ys + d[1]) / rs)).astype(np.int64)
        ci = np.nonzero((cols >= 0) & (cols < src.width))[0]
        ri = np.nonzero((rows >= 0) & (rows < src.height))[0]
        if len(ci) and len(ri):
            out[np.ix_(ri, ci)] = np.asarray(src.data, dtype=np.int8)[np.ix_(rows[ri], cols[ci])]
        return out
    gx, gy = np.meshgrid(xs, ys)
    world = _rot(ref_yaw) @ np.vstack([gx.ravel(), gy.ravel()]) + np.array([[ox], [oy]])
    local = _rot(-syaw) @ (world - np.array([[sx], [sy]]))
    cols = np.floor(_snap(local[0] / rs)).astype(np.int64).reshape(h, w)
    rows = np.floor(_snap(local[1] / rs)).astype(np.int64).reshape(h, w)
    inside = (cols >= 0) & (cols < src.width) & (rows >= 0) & (rows < src.height)
    out[inside] = np.asarray(src.data, dtype=np.int8)[rows[inside], cols[inside]]
    return out


MAX_CELLS = 100_000_000  # the common grid of two maps: 10,000 x 10,000 cells
BYTES_PER_CELL = 12  # two int8 grids, their masks and the overlay while comparing


def align(a: GridMap, b: GridMap, resample: bool = False, names: tuple[str, str] = ("A", "B")) -> Aligned:
    """Bring ``a`` and ``b`` onto one lattice covering both (see the module docstring)."""
    notes: list[str] = []
    ra, rb = float(a.resolution), float(b.resolution)
    if not _same(ra, rb) and not resample:
        finer = min(ra, rb)
        raise InputError(
            f"{names[0]} has {ra:g} m cells and {names[1]} {rb:g} m cells; pass --resample to compare "
            f"them on the finer {finer:g} m cells (nearest cell centre)"
        )
    ref_is_a = ra <= rb or _same(ra, rb)
    ref, other = (a, b) if ref_is_a else (b, a)
    # notes name the maps "A" and "B"; ``names`` (which may hold file paths) are for errors
    ref_name, other_name = ("A", "B") if ref_is_a else ("B", "A")
    res = float(ref.resolution)
    for m, n in ((a, names[0]), (b, names[1])):
        if not all(np.isfinite(float(v)) for v in m.origin):
            raise InputError(f"{n}: origin {list(m.origin)} is not finite; fix the origin in its YAML")
    rx, ry, ryaw = (float(v) for v in ref.origin)
    if not _same(ra, rb):
        notes.append(
            f"{other_name} resampled from {other.resolution:g} m to {res:g} m cells (nearest cell centre)"
        )

    # the other map's footprint in target cell units
    oxw, oyw, oyaw = (float(v) for v in other.origin)
    corners = np.array(
        [[0, 0], [other.width, 0], [0, other.height], [other.width, other.height]], dtype=np.float64
    ).T * float(other.resolution)
    world = _rot(oyaw) @ corners + np.array([[oxw], [oyw]])
    tl = _rot(-ryaw) @ (world - np.array([[rx], [ry]])) / res
    tl = _snap(tl)
    col0 = min(0, int(np.floor(tl[0].min())))
    col1 = max(ref.width, int(np.ceil(tl[0].max())))
    row0 = min(0, int(np.floor(tl[1].min())))
    row1 = max(ref.height, int(np.ceil(tl[1].max())))
    h, w = row1 - row0, col1 - col0
    if h * w > MAX_CELLS:
        raise InputError(
            f"{names[0]} and {names[1]} lie {abs(oxw - rx):.6g} m / {abs(oyw - ry):.6g} m apart (origins): "
            f"comparing them needs a {w} x {h} cell grid (about {h * w * BYTES_PER_CELL / 2**30:.3g} GB); "
            f"check that both maps are in the same frame (the origin in each YAML)"
        )

    same_yaw = _same(oyaw, ryaw)
    if not same_yaw:
        notes.append(
            f"{other_name} origin yaw {oyaw:g} rad differs from {ref_name}'s {ryaw:g} rad: rotated and "
            f"resampled onto {ref_name}'s cells (nearest cell centre)"
        )
    elif _same(ra, rb):
        shift = _rot(-ryaw) @ np.array([oxw - rx, oyw - ry]) / res
        snapped = _snap(shift)
        if np.any(snapped != np.round(snapped)):
            notes.append(
                f"{other_name} origin is ({shift[0]:.3g}, {shift[1]:.3g}) cells from {ref_name}'s, not a whole "
                f"number: resampled onto {ref_name}'s cells (nearest cell centre)"
            )

    ref_data = np.full((h, w), -1, dtype=np.int8)
    ref_data[-row0 : -row0 + ref.height, -col0 : -col0 + ref.width] = np.asarray(ref.data, dtype=np.int8)
    other_data = _sample(other, (rx, ry), ryaw, res, row0, col0, h, w)
    c, s = math.cos(ryaw), math.sin(ryaw)
    origin = (rx + c * col0 * res - s * row0 * res, ry + s * col0 * res + c * row0 * res, ryaw)
    da, db = (ref_data, other_data) if ref_is_a else (other_data, ref_data)
    return Aligned(da, db, res, origin, "A" if ref_is_a else "B", notes)


@dataclass
class DiffResult:
    aligned: Aligned
    tolerance: int
    occupied_a: np.ndarray  # bool (H, W)
    occupied_b: np.ndarray
    added: np.ndarray  # bool (H, W), after tolerance
    removed: np.ndarray
    added_ignored: np.ndarray  # within tolerance
    removed_ignored: np.ndarray
    unknown_changed: np.ndarray
    unchanged: np.ndarray  # occupied in both

    @property
    def resolution(self) -> float:
        return self.aligned.resolution

    @property
    def cell_area(self) -> float:
        return self.aligned.resolution**2

    def counts(self) -> dict[str, int]:
        return {
            "added": int(self.added.sum()),
            "removed": int(self.removed.sum()),
            "unknown_changed": int(self.unknown_changed.sum()),
            "unchanged_occupied": int(self.unchanged.sum()),
            "added_within_tolerance": int(self.added_ignored.sum()),
            "removed_within_tolerance": int(self.removed_ignored.sum()),
            "occupied_a": int(self.occupied_a.sum()),
            "occupied_b": int(self.occupied_b.sum()),
        }

    @property
    def iou(self) -> float:
        union = int((self.occupied_a | self.occupied_b).sum())
        return 1.0 if union == 0 else int(self.unchanged.sum()) / union

    @property
    def same(self) -> bool:
        return not self.added.any() and not self.removed.any()


def diff_aligned(al: Aligned, tolerance: int = 0) -> DiffResult:
    """Classify every cell of two aligned maps (see the module docstring)."""
    if tolerance < 0:
        raise InputError(f"--tolerance {tolerance} is negative; give a number of cells >= 0")
    a, b = al.a, al.b
    occ_a, occ_b = a >= OCCUPIED_MIN, b >= OCCUPIED_MIN
    unk_a, unk_b = a < 0, b < 0
    free_b = ~occ_b & ~unk_b
    added = occ_b & ~occ_a
    removed = occ_a & free_b
    unknown_changed = (unk_a != unk_b) & ~added & ~removed
    unchanged = occ_a & occ_b
    added_ignored = np.zeros_like(added)
    removed_ignored = np.zeros_like(removed)
    if tolerance > 0:
        from .planner import inflate

        if added.any():
            added_ignored = added & inflate(occ_a, tolerance)
        if removed.any():
            removed_ignored = removed & inflate(occ_b, tolerance)
    return DiffResult(
        aligned=al,
        tolerance=int(tolerance),
        occupied_a=occ_a,
        occupied_b=occ_b,
        added=added & ~added_ignored,
        removed=removed & ~removed_ignored,
        added_ignored=added_ignored,
        removed_ignored=removed_ignored,
        unknown_changed=unknown_changed,
        unchanged=unchanged,
    )


def diff_maps(
    a: GridMap, b: GridMap, tolerance: int = 0, resample: bool = False, names: tuple[str, str] = ("A", "B")
) -> DiffResult:
    """Align two maps and compare them cell by cell."""
    return diff_aligned(align(a, b, resample=resample, names=names), tolerance)


def diff_report(d: DiffResult) -> dict:
    """The JSON-ready summary of a 2D diff."""
    al = d.aligned
    counts = d.counts()
    area = d.cell_area
    return {
        "mode": "2d",
        "resolution": al.resolution,
        "origin": list(al.origin),
        "size_cells": [int(al.a.shape[1]), int(al.a.shape[0])],  # width, height
        "reference": al.reference,
        "notes": list(al.notes),
        "tolerance_cells": d.tolerance,
        "tolerance_metric": "euclidean",
        "cells": counts,
        "m2": {k: round(v * area, 9) for k, v in counts.items()},
        "iou": d.iou,
        "same": d.same,
    }


# ---------------------------------------------------------------------------------------------
# 3D: voxel sets (.ot snapshots)

_BITS = 21
_OFF = 1 << (_BITS - 1)


def _encode(keys: np.ndarray) -> np.ndarray:
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3) + _OFF
    if len(k) and (k.min() < 0 or k.max() >= (1 << _BITS)):
        raise InputError(f"voxel keys exceed +-{_OFF} cells; cannot compare these snapshots")
    return (k[:, 0] << (2 * _BITS)) | (k[:, 1] << _BITS) | k[:, 2]


def _within(query: np.ndarray, target_sorted: np.ndarray, radius: int) -> np.ndarray:
    """For each key of ``query`` (N,3): is a key of the sorted encoded set within ``radius``
    voxels (Euclidean, inclusive, centre to centre)?"""
    hit = np.zeros(len(query), dtype=bool)
    if len(query) == 0 or len(target_sorted) == 0:
        return hit
    rng = range(-radius, radius + 1)
    for dx in rng:
        for dy in rng:
            for dz in rng:
                if dx * dx + dy * dy + dz * dz > radius * radius:
                    continue
                enc = _encode(query + np.array([dx, dy, dz]))
                pos = np.searchsorted(target_sorted, enc)
                pos = np.minimum(pos, len(target_sorted) - 1)
                hit |= target_sorted[pos] == enc
    return hit


@dataclass
class VoxelDiffResult:
    resolution: float
    tolerance: int
    counts: dict[str, int]
    iou: float

    @property
    def same(self) -> bool:
        return self.counts["added"] == 0 and self.counts["removed"] == 0


def diff_voxels(
    keys_a: np.ndarray,
    logodds_a: np.ndarray,
    keys_b: np.ndarray,
    logodds_b: np.ndarray,
    resolution: float,
    tolerance: int = 0,
) -> VoxelDiffResult:
    """Compare two voxel sets on one lattice: occupied = log-odds > 0, free = known and not
    occupied, unknown = absent. Same categories as the 2D diff; the tolerance is Euclidean in
    voxels."""
    if tolerance < 0:
        raise InputError(f"--tolerance {tolerance} is negative; give a number of voxels >= 0")
    ka = np.asarray(keys_a, dtype=np.int64).reshape(-1, 3)
    kb = np.asarray(keys_b, dtype=np.int64).reshape(-1, 3)
    ea, eb = _encode(ka), _encode(kb)
    la = np.asarray(logodds_a).reshape(-1)
    lb = np.asarray(logodds_b).reshape(-1)
    occ_a = np.unique(ea[la > 0])
    occ_b = np.unique(eb[lb > 0])
    known_a = np.unique(ea)
    known_b = np.unique(eb)
    free_b = np.setdiff1d(known_b, occ_b, assume_unique=True)
    added = np.setdiff1d(occ_b, occ_a, assume_unique=True)
    removed = np.intersect1d(occ_a, free_b, assume_unique=True)
    both = np.intersect1d(occ_a, occ_b, assume_unique=True)
    unknown_changed = np.setxor1d(known_a, known_b, assume_unique=True)
    unknown_changed = np.setdiff1d(unknown_changed, np.union1d(added, removed), assume_unique=True)
    added_ign = removed_ign = 0
    if tolerance > 0:

        def decode(e):
            return np.column_stack(
                [
                    (e >> (2 * _BITS)) - _OFF,
                    ((e >> _BITS) & ((1 << _BITS) - 1)) - _OFF,
                    (e & ((1 << _BITS) - 1)) - _OFF,
                ]
            )

        ia = _within(decode(added), occ_a, tolerance)
        ir = _within(decode(removed), occ_b, tolerance)
        added_ign, removed_ign = int(ia.sum()), int(ir.sum())
        added, removed = added[~ia], removed[~ir]
    union = len(np.union1d(occ_a, occ_b))
    counts = {
        "added": int(len(added)),
        "removed": int(len(removed)),
        "unknown_changed": int(len(unknown_changed)),
        "unchanged_occupied": int(len(both)),
        "added_within_tolerance": added_ign,
        "removed_within_tolerance": removed_ign,
        "occupied_a": int(len(occ_a)),
        "occupied_b": int(len(occ_b)),
    }
    return VoxelDiffResult(
        float(resolution), int(tolerance), counts, 1.0 if union == 0 else len(both) / union
    )


def voxel_report(d: VoxelDiffResult) -> dict:
    vol = d.resolution**3
    return {
        "mode": "3d",
        "resolution": d.resolution,
        "tolerance_cells": d.tolerance,
        "tolerance_metric": "euclidean",
        "voxels": dict(d.counts),
        "m3": {k: round(v * vol, 12) for k, v in d.counts.items()},
        "iou": d.iou,
        "same": d.same,
    }
