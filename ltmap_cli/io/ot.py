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
does not prune (eight equal leaves stay eight leaves): OctoMap reads it all the same. The reader
expands pruned leaves of files written by OctoMap into their voxels.

The tree walk is a numba kernel over the leaves sorted in Morton order (no Python recursion), so
10^6 voxels write in well under a second.
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


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Put bit b of each 16-bit value at bit 3b of an int64."""
    v = v.astype(np.int64) & 0xFFFF
    v = (v | (v << 32)) & 0x001F_0000_0000_FFFF
    v = (v | (v << 16)) & 0x001F_0000_FF00_00FF
    v = (v | (v << 8)) & 0x100F_00F0_0F00_F00F
    v = (v | (v << 4)) & 0x10C3_0C30_C30C_30C3
    v = (v | (v << 2)) & 0x1249_2492_4924_9249
    return v


def morton_codes(octo_keys: np.ndarray) -> np.ndarray:
    """48-bit Morton codes (int64) of OctoMap keys (N, 3) in 0..65535: bits 3b, 3b+1, 3b+2 are
    bit b of kx, ky, kz, so ``(code >> 3b) & 7`` is OctoMap's child index at level b."""
    return _spread_bits(octo_keys[:, 0]) | (_spread_bits(octo_keys[:, 1]) << 1) | (_spread_bits(octo_keys[:, 2]) << 2)


def _count_nodes(codes):
    """Number of tree nodes above sorted leaf codes, or -1 if a code repeats."""
    n = codes.shape[0]
    if n == 0:
        return 0
    total = TREE_DEPTH + 1
    for i in range(1, n):
        diff = codes[i] ^ codes[i - 1]
        if diff == 0:
            return -1
        level = TREE_DEPTH - 1
        while (diff >> (3 * level)) == 0:
            level -= 1
        total += level + 1  # new nodes at depths 16 - level .. 16
    return total


def _emit_preorder(codes, values, out_values, out_masks):
    """Pre-order nodes of the tree whose leaves (depth 16) are ``codes`` (sorted, unique):
    value (leaf: its own; inner: max of its children) and child bitmask."""
    slot = np.zeros(TREE_DEPTH + 1, dtype=np.int64)  # output index of the open node per depth
    maxv = np.zeros(TREE_DEPTH + 1, dtype=np.float32)
    idx = 0
    n = codes.shape[0]
    for i in range(n):
        code = codes[i]
        v = values[i]
        first_new = 0
        if i > 0:
            diff = code ^ codes[i - 1]
            level = TREE_DEPTH - 1
            while (diff >> (3 * level)) == 0:
                level -= 1
            first_new = TREE_DEPTH - level
            for d in range(first_new, TREE_DEPTH):  # close the previous leaf's own branch
                out_values[slot[d]] = maxv[d]
        for d in range(first_new, TREE_DEPTH + 1):
            slot[d] = idx
            out_masks[idx] = 0
            maxv[d] = v
            idx += 1
        out_values[slot[TREE_DEPTH]] = v
        for d in range(max(first_new - 1, 0), TREE_DEPTH):
            child = (code >> (3 * (TREE_DEPTH - 1 - d))) & 7
            out_masks[slot[d]] = out_masks[slot[d]] | (1 << child)
        for d in range(first_new):
            if v > maxv[d]:
                maxv[d] = v
    if n > 0:
        for d in range(TREE_DEPTH):
            out_values[slot[d]] = maxv[d]
    return idx


def _walk(masks, values, occupied_only, fill, out_keys, out_values):
    """Walk pre-order nodes. Returns (status, nodes consumed, voxels). With ``fill``, writes the
    voxels' indices (key - 32768) and values; a leaf above depth 16 gives all its voxels."""
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
            if (not occupied_only) or v > 0.0:
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


@functools.lru_cache(maxsize=1)
def _kernels():
    import numba

    return (
        numba.njit(cache=True)(_count_nodes),
        numba.njit(cache=True)(_emit_preorder),
        numba.njit(cache=True)(_walk),
    )


# --------------------------------------------------------------------------------------------
# writing


def _header(num_nodes: int, resolution: float) -> bytes:
    return (
        FILE_HEADER + b"\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
        b"id OcTree\n" + f"size {num_nodes}\nres {resolution!r}\ndata\n".encode()
    )


def ot_bytes(keys: np.ndarray, logodds: np.ndarray, resolution: float) -> bytes:
    """The ``.ot`` file content for voxels ``keys`` (N, 3) with log-odds ``logodds`` (N,)."""
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
    count_nodes, emit_preorder, _ = _kernels()
    codes = morton_codes(keys.astype(np.int64) + TREE_MAX_VAL)  # int64, < 2**48
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    values = logodds[order]
    num_nodes = count_nodes(codes)
    if num_nodes < 0:
        raise ValueError("write_ot: keys contain the same voxel twice")
    nodes = np.empty(num_nodes, dtype=NODE_DTYPE)
    out_values = np.empty(num_nodes, dtype=np.float32)
    out_masks = np.empty(num_nodes, dtype=np.uint8)
    written = emit_preorder(codes, values, out_values, out_masks)
    assert written == num_nodes
    nodes["value"] = out_values
    nodes["children"] = out_masks
    return _header(num_nodes, resolution) + nodes.tobytes()


def write_ot(path: str | os.PathLike, keys: np.ndarray, logodds: np.ndarray, resolution: float) -> None:
    """Write voxels ``keys`` (N, 3) int voxel indices (each in [-32768, 32767]) with
    ``logodds`` (N,) float32 as an OctoMap ``OcTree`` ``.ot`` file, atomically. Raises
    ValueError for bad arrays (wrong shape, duplicates, out of OctoMap's key range)."""
    data = ot_bytes(keys, logodds, resolution)
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
    path: str | os.PathLike, occupied_only: bool = False, max_voxels: int = MAX_VOXELS
) -> tuple[np.ndarray, np.ndarray, float]:
    """Read an OctoMap ``OcTree`` ``.ot`` file (ours or OctoMap's).

    Returns (keys int64 (N, 3) voxel indices, logodds float32 (N,), resolution), the leaves in
    pre-order; a pruned leaf is expanded into all its voxels. With ``occupied_only`` only voxels
    with log-odds > 0 are returned (OctoMap's files hold large pruned free-space leaves). Raises
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
    _, _, walk = _kernels()
    dummy_keys = np.zeros((0, 3), np.int64)
    dummy_values = np.zeros(0, np.float32)
    status, consumed, voxels = walk(masks, values, occupied_only, False, dummy_keys, dummy_values)
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
    walk(masks, values, occupied_only, True, keys, logodds)
    return keys, logodds, resolution
