"""OctoMap ``.ot`` files (``OcTree``, log-odds per node), readable by OctoMap's own tools.

Voxel (i, j, k) spans [i*r, (i+1)*r) x [j*r, (j+1)*r) x [k*r, (k+1)*r); OctoMap's key of that
voxel is (i, j, k) + 32768 (``tree_max_val``), in a tree of depth 16. The child of a node at
level b (bit b of the key, 15 at the root's children down to 0 at the leaves) is
``pos = bit_b(kx) + 2 * bit_b(ky) + 4 * bit_b(kz)`` (OctoMap's ``computeChildIdx``).

File layout (``AbstractOcTree::write`` + ``OcTreeBaseImpl::writeNodesRecurs``)::

    # Octomap OcTree file
    # (comment lines)
    id OcTree
    size <number of nodes>
    res <resolution>
    data
    <nodes in pre-order: float32 log-odds (little endian), uint8 child bitmask, then children>

An inner node holds the max of its children's log-odds (``updateOccupancyChildren``). The writer
prunes as OctoMap's ``prune()`` does: eight sibling leaves whose float32 log-odds are bitwise equal
become one leaf at their parent, recursively up to depth 1 (a snapshot's free space, all at one
log-odds, shrinks 5x on the house sample). OctoMap reads pruned trees natively; the reader
expands a pruned leaf into its voxels, so a written file reads back voxel for voxel.

Pruning and the tree walk are numba kernels over the voxels sorted in Morton order (a stack, no
Python recursion): 5.9 million voxels write in about 0.35 s. ``blocks_ot_bytes`` builds the same
file from blocks of 8^3 voxels (blocks in Morton order, voxels in Morton order within each),
pruning as the leaves come, so a snapshot of a 100 m floor (23 million free voxels) needs memory
for its pruned leaves only, not a key per voxel: 0.6 s instead of 5.2 s, and no 0.8 GB peak.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import numpy as np

from ltmap_cli.errors import MapFileError
from ltmap_cli.io.atomic import atomic_path

TREE_DEPTH = 16
TREE_MAX_VAL = 32768
FILE_HEADER = b"# Octomap OcTree file"
BINARY_HEADER = b"# Octomap OcTree binary file"
MAX_VOXELS = 50_000_000

NODE_DTYPE = np.dtype([("value", "<f4"), ("children", "u1")])  # packed: 5 bytes, as OctoMap writes

_OK, _TRUNCATED, _CORRUPT = 0, 1, 2


# --------------------------------------------------------------------------------------------
# kernels (plain Python here, compiled with numba on first use)


def morton_codes(octo_keys: np.ndarray) -> np.ndarray:
    """48-bit Morton codes (int64) of OctoMap keys (N, 3) in 0..65535: bits 3b, 3b+1, 3b+2 are
    bit b of kx, ky, kz, so ``(code >> 3b) & 7`` is OctoMap's child index at level b."""
    keys = np.ascontiguousarray(np.asarray(octo_keys, dtype=np.int64).reshape(-1, 3))
    out = np.empty(len(keys), dtype=np.int64)
    _kernels()[0](keys, 0, out)
    return out


def _morton(keys, offset, out):
    """``out[n]`` = Morton code of ``keys[n] + offset``: bit b of each axis spread to bit 3b."""
    for n in range(keys.shape[0]):
        code = np.int64(0)
        for a in range(3):
            v = (keys[n, a] + offset) & 0xFFFF
            v = (v | (v << 32)) & 0x001F_0000_0000_FFFF
            v = (v | (v << 16)) & 0x001F_0000_FF00_00FF
            v = (v | (v << 8)) & 0x100F_00F0_0F00_F00F
            v = (v | (v << 4)) & 0x10C3_0C30_C30C_30C3
            v = (v | (v << 2)) & 0x1249_2492_4924_9249
            code |= v << a
        out[n] = code


def _prune(codes, bits, out_codes, out_levels, out_bits):
    """OctoMap's ``prune()`` over sorted unique voxel codes (depth 16) whose float32 values are
    given as their bits: eight sibling leaves with bitwise equal values become one leaf at their
    parent, recursively. Writes the leaves (Morton code of their first voxel, level = 16 - depth,
    value bits) in Morton order and returns their number. A stack: a leaf is pushed, then the top
    eight entries are merged while they are the eight children of one node with one value (in
    Morton order siblings are adjacent, the last one is child 7). Leaves stop at depth 1."""
    top = 0
    for i in range(codes.shape[0]):
        top = _push_leaf(out_codes, out_levels, out_bits, top, codes[i], bits[i])
    return top


def _push_leaf(out_codes, out_levels, out_bits, top, code, bits, level=0):
    """Push a leaf (a voxel, or at ``level`` > 0 a node all of whose voxels hold ``bits``, as
    pruning them would leave it) on the prune stack of ``_prune``, merge eight equal siblings into
    their parent while it can; the new stack size."""
    out_codes[top] = code
    out_levels[top] = level
    out_bits[top] = bits
    top += 1
    while top >= 8:
        lv = out_levels[top - 1]
        if lv >= TREE_DEPTH - 1 or ((out_codes[top - 1] >> (3 * lv)) & 7) != 7:
            break
        shift = 3 * (lv + 1)
        parent = out_codes[top - 1] >> shift
        b = out_bits[top - 1]
        same = True
        for j in range(top - 8, top - 1):
            if out_levels[j] != lv or (out_codes[j] >> shift) != parent or out_bits[j] != b:
                same = False
                break
        if not same:
            break
        top -= 8
        out_codes[top] = parent << shift
        out_levels[top] = lv + 1
        out_bits[top] = b
        top += 1
    return top


def _count_nodes(codes, levels):
    """Number of tree nodes above sorted leaves (code of the first voxel, level = 16 - depth), or
    -1 if two leaves overlap (a voxel given twice)."""
    n = codes.shape[0]
    if n == 0:
        return 0
    total = TREE_DEPTH - levels[0] + 1
    for i in range(1, n):
        diff = codes[i] ^ codes[i - 1]
        if diff == 0:
            return -1
        level = TREE_DEPTH - 1
        while (diff >> (3 * level)) == 0:
            level -= 1
        first_new = TREE_DEPTH - level  # depth of the first node not shared with the previous leaf
        depth = TREE_DEPTH - levels[i]
        if first_new > depth or first_new > TREE_DEPTH - levels[i - 1]:
            return -1  # one leaf inside the other
        total += depth - first_new + 1  # new nodes at depths first_new .. depth
    return total


def _emit_preorder(codes, levels, values, out_values, out_masks):
    """Pre-order nodes of the tree whose leaves are ``codes`` at depths 16 - ``levels`` (sorted,
    disjoint): value (leaf: its own; inner: max of its children) and child bitmask."""
    slot = np.zeros(TREE_DEPTH + 1, dtype=np.int64)  # output index of the open node per depth
    maxv = np.zeros(TREE_DEPTH + 1, dtype=np.float32)
    idx = 0
    n = codes.shape[0]
    prev_depth = 0
    for i in range(n):
        code = codes[i]
        v = values[i]
        depth = TREE_DEPTH - np.int64(levels[i])
        first_new = 0
        if i > 0:
            diff = code ^ codes[i - 1]
            level = TREE_DEPTH - 1
            while (diff >> (3 * level)) == 0:
                level -= 1
            first_new = TREE_DEPTH - level
            for d in range(first_new, prev_depth):  # close the previous leaf's own branch
                out_values[slot[d]] = maxv[d]
        for d in range(first_new, depth + 1):
            slot[d] = idx
            out_masks[idx] = 0
            maxv[d] = v
            idx += 1
        out_values[slot[depth]] = v
        for d in range(max(first_new - 1, 0), depth):
            child = (code >> (3 * (TREE_DEPTH - 1 - d))) & 7
            out_masks[slot[d]] = out_masks[slot[d]] | (1 << child)
        for d in range(first_new):
            if v > maxv[d]:
                maxv[d] = v
        prev_depth = depth
    if n > 0:
        for d in range(prev_depth):
            out_values[slot[d]] = maxv[d]
    return idx


def _walk(masks, values, min_value, fill, out_keys, out_values):
    """Walk pre-order nodes. Returns (status, nodes consumed, voxels). With ``fill``, writes the
    voxels' indices (key - 32768) and values; a leaf above depth 16 gives all its voxels. Leaves
    whose value is not above ``min_value`` are skipped (not expanded: -inf keeps every leaf)."""
    n = masks.shape[0]
    if n == 0:
        return _TRUNCATED, 0, 0
    mk = np.zeros(TREE_DEPTH + 1, dtype=np.int64)
    nxt = np.zeros(TREE_DEPTH + 1, dtype=np.int64)
    kx = np.zeros(TREE_DEPTH + 1, dtype=np.int64)
    ky = np.zeros(TREE_DEPTH + 1, dtype=np.int64)
    kz = np.zeros(TREE_DEPTH + 1, dtype=np.int64)
    d = 0
    cur = 0
    pos = 1
    count = 0
    while True:
        m = np.int64(masks[cur])
        if m == 0:
            v = values[cur]
            if v > min_value:
                s = TREE_DEPTH - d
                side = np.int64(1) << s
                if fill:
                    bx = (kx[d] << s) - TREE_MAX_VAL
                    by = (ky[d] << s) - TREE_MAX_VAL
                    bz = (kz[d] << s) - TREE_MAX_VAL
                    for c in range(side):
                        for b in range(side):
                            for a in range(side):
                                out_keys[count, 0] = bx + a
                                out_keys[count, 1] = by + b
                                out_keys[count, 2] = bz + c
                                out_values[count] = v
                                count += 1
                else:
                    count += side * side * side
            found = False
            while d > 0:
                d -= 1
                i = nxt[d]
                while i < 8 and ((mk[d] >> i) & 1) == 0:
                    i += 1
                if i < 8:
                    nxt[d] = i + 1
                    kx[d + 1] = (kx[d] << 1) | (i & 1)
                    ky[d + 1] = (ky[d] << 1) | ((i >> 1) & 1)
                    kz[d + 1] = (kz[d] << 1) | ((i >> 2) & 1)
                    d += 1
                    found = True
                    break
            if not found:
                return _OK, pos, count
        else:
            if d == TREE_DEPTH:
                return _CORRUPT, pos, count
            mk[d] = m
            i = 0
            while ((m >> i) & 1) == 0:
                i += 1
            nxt[d] = i + 1
            kx[d + 1] = (kx[d] << 1) | (i & 1)
            ky[d + 1] = (ky[d] << 1) | ((i >> 1) & 1)
            kz[d + 1] = (kz[d] << 1) | ((i >> 2) & 1)
            d += 1
        if pos >= n:
            return _TRUNCATED, pos, count
        cur = pos
        pos += 1


def _block_leaves(block_codes, lt_start, lt_offs, lt_bits, o_block, o_free, free_bits, local_off, local_code,
                  out_codes, out_levels, out_bits):
    """Pruned leaves of blocks of 8^3 voxels given in Morton order (``block_codes``: the code of
    each block's first voxel), without a list of voxels: voxel ``local_off[li]`` of a block (its
    storage offset) has Morton code ``block_code | local_code[li]``, li in Morton order. A voxel's
    value: its long-term log-odds bits if listed (``lt_offs`` / ``lt_bits`` of block n at
    ``lt_start[n]:lt_start[n + 1]``), else ``free_bits`` if ``o_free[o_block[n], off]`` (o_block -1:
    no sensor block), else none. Leaves go through ``_prune``'s stack as they come; a run of 512,
    64 or 8 voxels in Morton order (a node at level 3, 2 or 1) that all hold one value goes as one
    leaf at that level: what pruning its voxels one by one would leave, without the pushes (a
    floor's free space). Returns the number of leaves, or -1 if ``out_*`` are too small."""
    cap = out_codes.shape[0]
    scratch = np.zeros(512, dtype=np.uint32)
    has = np.zeros(512, dtype=np.bool_)
    vals = np.zeros(512, dtype=np.uint32)  # the block's values in Morton order ...
    present = np.zeros(512, dtype=np.bool_)  # ... where it has one
    top = 0
    for n in range(block_codes.shape[0]):
        for j in range(lt_start[n], lt_start[n + 1]):
            scratch[lt_offs[j]] = lt_bits[j]
            has[lt_offs[j]] = True
        ob = o_block[n]
        for li in range(512):
            off = local_off[li]
            if has[off]:
                vals[li] = scratch[off]
                present[li] = True
            elif ob >= 0 and o_free[ob, off]:
                vals[li] = free_bits
                present[li] = True
            else:
                present[li] = False
        for j in range(lt_start[n], lt_start[n + 1]):
            has[lt_offs[j]] = False
        code0 = block_codes[n]
        li = 0
        while li < 512:
            level = 0
            for lv in (3, 2, 1):  # the largest aligned run from li that is whole and of one value
                size = 1 << (3 * lv)
                if li & (size - 1) != 0:
                    continue
                whole = True
                for t in range(li, li + size):
                    if not present[t] or vals[t] != vals[li]:
                        whole = False
                        break
                if whole:
                    level = lv
                    break
            if level == 0 and not present[li]:
                li += 1
                continue
            if top >= cap:
                return -1
            top = _push_leaf(out_codes, out_levels, out_bits, top, code0 | local_code[li], vals[li], level)
            li += 1 << (3 * level)
    return top


@functools.lru_cache(maxsize=1)
def _kernels():
    from numba.core.registry import CPUDispatcher

    from ..jit import njit

    global _push_leaf  # the kernels below call it: compiled first, as the global they resolve
    if not isinstance(_push_leaf, CPUDispatcher):
        _push_leaf = njit(cache=True, inline="always")(_push_leaf)
    return tuple(njit(cache=True, nogil=True)(f) for f in (_morton, _prune, _count_nodes, _emit_preorder,
                                                           _walk, _block_leaves))  # fmt: skip


# --------------------------------------------------------------------------------------------
# writing


def _header(num_nodes: int, resolution: float) -> bytes:
    return (
        FILE_HEADER + b"\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
        b"id OcTree\n" + f"size {num_nodes}\nres {resolution!r}\ndata\n".encode()
    )


def ot_bytes(keys: np.ndarray, logodds: np.ndarray, resolution: float, prune: bool = True) -> bytes:
    """The ``.ot`` file content for voxels ``keys`` (N, 3) with log-odds ``logodds`` (N,).

    With ``prune`` (the default) eight sibling leaves with bitwise equal log-odds are stored as
    one leaf at their parent, recursively, as OctoMap's ``prune()`` does; ``prune=False`` keeps
    one leaf per voxel. Both describe the same voxels."""
    keys = np.asarray(keys)
    logodds = np.asarray(logodds, dtype=np.float32)
    if keys.ndim != 2 or keys.shape[1] != 3 or not np.issubdtype(keys.dtype, np.integer):
        raise ValueError(f"write_ot: keys must be an integer (N, 3) array, got {keys.dtype} {keys.shape}")
    if logodds.shape != (keys.shape[0],):
        raise ValueError(f"write_ot: logodds must have shape ({keys.shape[0]},), got {logodds.shape}")
    resolution = float(resolution)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise ValueError(f"write_ot: resolution must be > 0, got {resolution}")
    if not np.all(np.isfinite(logodds)):
        raise ValueError("write_ot: logodds must be finite")
    n = keys.shape[0]
    if n == 0:
        return _header(0, resolution)
    kmin, kmax = int(keys.min()), int(keys.max())
    if kmin < -TREE_MAX_VAL or kmax >= TREE_MAX_VAL:
        raise ValueError(
            f"write_ot: voxel indices must be in [-32768, 32767] (OctoMap's 16-bit keys), got {kmin}..{kmax}"
        )
    morton, prune_leaves, count_nodes, emit_preorder, _, _ = _kernels()
    codes = np.empty(n, dtype=np.int64)
    morton(np.ascontiguousarray(keys, dtype=np.int64), TREE_MAX_VAL, codes)  # OctoMap keys' codes, < 2**48
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    values = logodds[order]
    if prune:
        leaf_codes = np.empty(n, dtype=np.int64)
        levels = np.empty(n, dtype=np.int8)
        bits = np.empty(n, dtype=np.uint32)
        m = prune_leaves(codes, values.view(np.uint32), leaf_codes, levels, bits)
        codes, levels, values = leaf_codes[:m], levels[:m], bits[:m].view(np.float32)
    else:
        levels = np.zeros(n, dtype=np.int8)
    return _tree_bytes(codes, levels, values, resolution)


def _tree_bytes(codes: np.ndarray, levels: np.ndarray, values: np.ndarray, resolution: float) -> bytes:
    """The file for sorted, disjoint leaves (Morton code of their first voxel, level, value)."""
    _, _, count_nodes, emit_preorder, _, _ = _kernels()
    num_nodes = count_nodes(codes, levels)
    if num_nodes < 0:
        raise ValueError("write_ot: keys contain the same voxel twice")
    nodes = np.empty(num_nodes, dtype=NODE_DTYPE)
    out_values = np.empty(num_nodes, dtype=np.float32)
    out_masks = np.empty(num_nodes, dtype=np.uint8)
    written = emit_preorder(codes, levels, values, out_values, out_masks)
    assert written == num_nodes
    nodes["value"] = out_values
    nodes["children"] = out_masks
    return _header(num_nodes, resolution) + nodes.tobytes()


def _local_tables() -> tuple[np.ndarray, np.ndarray]:
    """(storage offset, Morton code) of the 512 voxels of a block, in Morton order. Storage
    offset: ``(x << 6) | (y << 3) | z`` (core.grid.voxel_offset); Morton: bit b of x, y, z at
    3b, 3b + 1, 3b + 2."""
    li = np.arange(512, dtype=np.int64)
    x = (li & 1) | ((li >> 2) & 2) | ((li >> 4) & 4)
    y = ((li >> 1) & 1) | ((li >> 3) & 2) | ((li >> 5) & 4)
    z = ((li >> 2) & 1) | ((li >> 4) & 2) | ((li >> 6) & 4)
    return (x << 6) | (y << 3) | z, li


def blocks_ot_bytes(
    block_coords: np.ndarray,
    o_block: np.ndarray,
    o_free: np.ndarray,
    free_logodds: float,
    lt_keys: np.ndarray,
    lt_logodds: np.ndarray,
    resolution: float,
) -> bytes:
    """The pruned ``.ot`` of voxels given by blocks of 8^3, without a list of every voxel (a
    100 m floor has tens of millions of free voxels): blocks ``block_coords`` (B, 3) in any
    order; ``o_free`` (M, 512) bool, row ``o_block[n]`` for block n (-1: none), the voxels at
    ``free_logodds``; ``lt_keys`` (K, 3) voxel keys with ``lt_logodds`` (K,), which win over
    free. Every block of ``lt_keys`` must be among the blocks. The same bytes as ``ot_bytes`` on
    the listed voxels."""
    block_coords = np.asarray(block_coords, dtype=np.int64).reshape(-1, 3)
    lt_keys = np.asarray(lt_keys, dtype=np.int64).reshape(-1, 3)
    lt_logodds = np.asarray(lt_logodds, dtype=np.float32).reshape(-1)
    if len(block_coords) == 0:
        return _header(0, float(resolution))
    lo, hi = int(block_coords.min()) * 8, int(block_coords.max()) * 8 + 7
    if lo < -TREE_MAX_VAL or hi >= TREE_MAX_VAL:
        raise ValueError(
            f"write_ot: voxel indices must be in [-32768, 32767] (OctoMap's 16-bit keys), got {lo}..{hi}"
        )
    morton, _, _, _, _, block_leaves = _kernels()
    bcodes = np.empty(len(block_coords), dtype=np.int64)
    morton(np.ascontiguousarray(block_coords * 8), TREE_MAX_VAL, bcodes)
    order = np.argsort(bcodes, kind="stable")
    bcodes = bcodes[order]
    o_block = np.asarray(o_block, dtype=np.int64)[order]
    # long-term voxels grouped by block, in the blocks' order
    lt_codes = np.empty(len(lt_keys), dtype=np.int64)
    morton(np.ascontiguousarray((lt_keys >> 3) * 8), TREE_MAX_VAL, lt_codes)
    pos = np.searchsorted(bcodes, lt_codes)
    if len(lt_keys) and (pos.max() >= len(bcodes) or not np.array_equal(bcodes[pos], lt_codes)):
        raise ValueError("blocks_ot_bytes: a long-term voxel lies outside the blocks given")
    lt_offs = ((lt_keys[:, 0] & 7) << 6) | ((lt_keys[:, 1] & 7) << 3) | (lt_keys[:, 2] & 7)
    by = np.argsort(pos, kind="stable")
    lt_start = np.searchsorted(pos[by], np.arange(len(bcodes) + 1))
    local_off, local_code = _local_tables()
    free_bits = np.array([free_logodds], dtype=np.float32).view(np.uint32)[0]
    cap = max(1024, len(lt_keys) + 64 * len(bcodes))
    while True:
        out_codes = np.empty(cap, dtype=np.int64)
        out_levels = np.empty(cap, dtype=np.int8)
        out_bits = np.empty(cap, dtype=np.uint32)
        m = block_leaves(bcodes, lt_start.astype(np.int64), lt_offs[by].astype(np.int64),
                         lt_logodds[by].view(np.uint32), o_block, np.ascontiguousarray(o_free, dtype=np.bool_),
                         free_bits, local_off, local_code, out_codes, out_levels, out_bits)  # fmt: skip
        if m >= 0:
            break
        cap *= 2
    return _tree_bytes(out_codes[:m], out_levels[:m], out_bits[:m].view(np.float32), float(resolution))


def write_ot(
    path: str | os.PathLike, keys: np.ndarray, logodds: np.ndarray, resolution: float, prune: bool = True
) -> None:
    """Write voxels ``keys`` (N, 3) int voxel indices (each in [-32768, 32767]) with
    ``logodds`` (N,) float32 as an OctoMap ``OcTree`` ``.ot`` file, atomically, pruned (see
    ``ot_bytes``). Raises ValueError for bad arrays (wrong shape, duplicates, out of OctoMap's
    key range)."""
    data = ot_bytes(keys, logodds, resolution, prune=prune)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


# --------------------------------------------------------------------------------------------
# reading


def _parse_header(raw: bytes, path: Path) -> tuple[str, int, float, int]:
    """Return (id, size, resolution, offset of the node data)."""
    if raw.startswith(BINARY_HEADER):
        raise MapFileError(
            f"{path}: is an OctoMap binary tree (.bt, occupied/free bits only); ltmap reads "
            "full-probability .ot files: save the map with OctoMap's write(), not writeBinary()"
        )
    if not raw.startswith(FILE_HEADER):
        raise MapFileError(
            f"{path}: not an OctoMap .ot file (first line must be '# Octomap OcTree file'); give an .ot file"
        )
    tree_id, size, resolution = "", None, None
    pos = raw.index(b"\n") + 1 if b"\n" in raw else len(raw)
    while pos < len(raw):
        end = raw.find(b"\n", pos)
        if end < 0:
            end = len(raw)
        line = raw[pos:end]
        tokens = line.split()
        pos = end + 1
        if not tokens or tokens[0].startswith(b"#"):
            continue
        word = tokens[0]
        if word == b"data":
            break
        if len(tokens) < 2:
            continue
        try:
            if word == b"id":
                tree_id = tokens[1].decode("ascii", "replace")
            elif word == b"size":
                size = int(tokens[1])
            elif word == b"res":
                resolution = float(tokens[1])
        except ValueError:
            raise MapFileError(
                f"{path}: bad OctoMap header line {line.decode('ascii', 'replace')!r}; the file is corrupt"
            ) from None
    else:
        raise MapFileError(f"{path}: OctoMap header has no 'data' line; the file is truncated or corrupt")
    if tree_id == "1":  # OctoMap's deprecated id for OcTree
        tree_id = "OcTree"
    if tree_id != "OcTree":
        shown = tree_id or "(none)"
        raise MapFileError(
            f"{path}: OctoMap tree id is {shown}, ltmap reads only 'OcTree' files; convert it to an OcTree"
        )
    if resolution is None or not math.isfinite(resolution) or resolution <= 0.0:
        raise MapFileError(f"{path}: OctoMap header has no valid 'res' (resolution > 0); the file is corrupt")
    return tree_id, -1 if size is None else size, resolution, min(pos, len(raw))


def read_ot(
    path: str | os.PathLike, occupied_only: bool = False, max_voxels: int = MAX_VOXELS,
    min_logodds: float | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Read an OctoMap ``OcTree`` ``.ot`` file (ours or OctoMap's).

    Returns (keys int64 (N, 3) voxel indices, logodds float32 (N,), resolution), the leaves in
    pre-order; a pruned leaf is expanded into all its voxels. With ``occupied_only`` only voxels
    with log-odds > 0 are returned (OctoMap's files hold large pruned free-space leaves); with
    ``min_logodds`` only those above it (leaves below are not expanded, so a snapshot's free space
    costs no memory when only its long-term voxels are wanted). Raises
    MapFileError for a missing, truncated or corrupt file, a ``.bt`` file, another tree id, or more
    than ``max_voxels`` voxels.
    """
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"{path}: OctoMap file not found; give the path of an existing .ot file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MapFileError(f"{path}: cannot read the OctoMap file ({exc}); check the file") from None
    _, size, resolution, offset = _parse_header(raw, path)
    body = memoryview(raw)[offset:]
    num_records = len(body) // NODE_DTYPE.itemsize
    if size == 0 or (num_records == 0 and size < 0):
        return np.zeros((0, 3), np.int64), np.zeros(0, np.float32), resolution
    nodes = np.frombuffer(body, dtype=NODE_DTYPE, count=num_records)
    masks = np.ascontiguousarray(nodes["children"])
    values = np.ascontiguousarray(nodes["value"])
    walk = _kernels()[4]
    dummy_keys = np.zeros((0, 3), np.int64)
    dummy_values = np.zeros(0, np.float32)
    floor = 0.0 if occupied_only else (-math.inf if min_logodds is None else float(min_logodds))
    status, consumed, voxels = walk(masks, values, floor, False, dummy_keys, dummy_values)
    if status == _TRUNCATED:
        raise MapFileError(
            f"{path}: OctoMap data truncated ({num_records} nodes present, header says {size}); "
            "the file is incomplete, write it again"
        )
    if status == _CORRUPT:
        raise MapFileError(f"{path}: OctoMap data corrupt (a voxel at depth 16 has children near node {consumed})")
    if voxels > max_voxels:
        raise MapFileError(
            f"{path}: OctoMap tree expands to {voxels} voxels, more than the {max_voxels} ltmap loads; "
            "read occupied voxels only or use a coarser map"
        )
    keys = np.empty((voxels, 3), np.int64)
    logodds = np.empty(voxels, np.float32)
    walk(masks, values, floor, True, keys, logodds)
    return keys, logodds, resolution
