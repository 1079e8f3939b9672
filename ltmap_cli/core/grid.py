"""Sparse voxel storage: a hash of fixed-size dense blocks (as VDB and Bonxai do).

Voxel (i, j, k) spans ``[i*r, (i+1)*r) x [j*r, (j+1)*r) x [k*r, (k+1)*r)`` for resolution
``r``; integer keys may be negative. Voxels live in blocks of 8 x 8 x 8; a block is allocated
the first time one of its voxels is touched, so memory grows with the space observed, not with
the bounding box. Blocks are found through an open-addressing hash table (linear probing) kept
at most half full. Every array is a plain numpy array so that numba kernels can work on them
directly; a kernel that runs out of blocks returns and the Python side grows the pool.
"""

from __future__ import annotations

import numpy as np

from ..jit import helper, njit

BLOCK_BITS = 3
BLOCK = 1 << BLOCK_BITS  # voxels per block edge
BLOCK_MASK = BLOCK - 1
BLOCK_VOXELS = BLOCK * BLOCK * BLOCK
_PACK_OFFSET = 1 << 20  # block coordinates (and the voxel keys of core.raycast) lie in [-2^20, 2^20)
_PACK_BITS = 21
EMPTY_KEY = -1

# meta array layout shared by the kernels: [n_blocks, max_blocks]
META_N = 0
META_MAX = 1


def pos_to_coord(points: np.ndarray, resolution: float) -> np.ndarray:
    """World positions (..., 3) to integer voxel keys (..., 3): floor(p * (1 / r)), computed as
    the ray-casting kernel and OctoMap compute it, so boundaries fall the same way."""
    return np.floor(np.asarray(points, dtype=np.float64) * (1.0 / resolution)).astype(np.int64)


def coord_to_pos(coords: np.ndarray, resolution: float) -> np.ndarray:
    """Integer voxel keys (..., 3) to the world positions of the voxel centres."""
    return (np.asarray(coords, dtype=np.float64) + 0.5) * resolution


def pack_blocks(coords: np.ndarray) -> np.ndarray:
    """``pack_block`` of each row of (n, 3) block coordinates, with numpy (same order: sorting
    the packed keys sorts the blocks by x, then y, then z)."""
    c = np.asarray(coords, dtype=np.int64) + _PACK_OFFSET
    return (c[:, 0] << (2 * _PACK_BITS)) | (c[:, 1] << _PACK_BITS) | c[:, 2]


@njit(cache=True, inline="always")
def pack_block(bx, by, bz):
    return (
        ((np.int64(bx) + _PACK_OFFSET) << (2 * _PACK_BITS))
        | ((np.int64(by) + _PACK_OFFSET) << _PACK_BITS)
        | (np.int64(bz) + _PACK_OFFSET)
    )


@njit(cache=True, inline="always")
def unpack_block(packed):
    """(bx, by, bz) of ``pack_block``'s int64 (voxel keys are packed the same way)."""
    m = (np.int64(1) << _PACK_BITS) - 1
    return ((packed >> (2 * _PACK_BITS)) - _PACK_OFFSET, ((packed >> _PACK_BITS) & m) - _PACK_OFFSET,
            (packed & m) - _PACK_OFFSET)  # fmt: skip


@njit(cache=True, inline="always")
def _slot(packed, mask):
    h = np.uint64(packed) * np.uint64(0x9E3779B97F4A7C15)
    h ^= h >> np.uint64(31)
    return np.int64(h & np.uint64(mask))


@njit(cache=True, inline="always")
def voxel_offset(i, j, k):
    """Index of voxel key (i, j, k) inside its block (z fastest)."""
    return ((i & BLOCK_MASK) << (2 * BLOCK_BITS)) | ((j & BLOCK_MASK) << BLOCK_BITS) | (k & BLOCK_MASK)


@helper()
def find_block(table_keys, table_vals, bx, by, bz):
    """Index of block (bx, by, bz) or -1 when it was never allocated."""
    mask = table_keys.shape[0] - 1
    packed = pack_block(bx, by, bz)
    s = _slot(packed, mask)
    while True:
        k = table_keys[s]
        if k == packed:
            return table_vals[s]
        if k == EMPTY_KEY:
            return -1
        s = (s + 1) & mask


@helper()
def get_or_add_block(table_keys, table_vals, block_coords, meta, bx, by, bz):
    """Index of block (bx, by, bz), allocating it if needed; -1 when the pool is full."""
    mask = table_keys.shape[0] - 1
    packed = pack_block(bx, by, bz)
    s = _slot(packed, mask)
    while True:
        k = table_keys[s]
        if k == packed:
            return table_vals[s]
        if k == EMPTY_KEY:
            n = meta[META_N]
            if n >= meta[META_MAX]:
                return -1
            table_keys[s] = packed
            table_vals[s] = n
            block_coords[n, 0] = bx
            block_coords[n, 1] = by
            block_coords[n, 2] = bz
            meta[META_N] = n + 1
            return n
        s = (s + 1) & mask


@njit(cache=True, nogil=True)
def _rehash(block_coords, n_blocks, capacity):
    keys = np.full(capacity, EMPTY_KEY, dtype=np.int64)
    vals = np.full(capacity, -1, dtype=np.int32)
    mask = capacity - 1
    for b in range(n_blocks):
        packed = pack_block(block_coords[b, 0], block_coords[b, 1], block_coords[b, 2])
        s = _slot(packed, mask)
        while keys[s] != EMPTY_KEY:
            s = (s + 1) & mask
        keys[s] = packed
        vals[s] = b
    return keys, vals


@njit(cache=True, nogil=True)
def _lookup_many(table_keys, table_vals, keys):
    n = keys.shape[0]
    blocks = np.empty(n, dtype=np.int64)
    offs = np.empty(n, dtype=np.int64)
    for t in range(n):
        i, j, k = keys[t, 0], keys[t, 1], keys[t, 2]
        blocks[t] = find_block(table_keys, table_vals, i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS)
        offs[t] = voxel_offset(i, j, k)
    return blocks, offs


@njit(cache=True, nogil=True)
def _add_many(table_keys, table_vals, block_coords, meta, keys, blocks, offs, start):
    """Allocate the blocks of ``keys[start:]``; returns the first index not done (== len when done)."""
    for t in range(start, keys.shape[0]):
        i, j, k = keys[t, 0], keys[t, 1], keys[t, 2]
        b = get_or_add_block(
            table_keys, table_vals, block_coords, meta, i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS
        )
        if b < 0:
            return t
        blocks[t] = b
        offs[t] = voxel_offset(i, j, k)
    return keys.shape[0]


def _grown(arr: np.ndarray, rows: int, fill) -> np.ndarray:
    """``arr`` with ``rows`` rows, the new ones set to ``fill``: resized in place when nothing else
    references it, else copied."""
    old = arr.shape[0]
    try:
        arr.resize((rows, *arr.shape[1:]), refcheck=True)
    except (ValueError, SystemError):  # referenced elsewhere (a view, a kernel argument): copy
        extra = np.full((rows - old, *arr.shape[1:]), fill, dtype=arr.dtype)
        return np.concatenate([arr, extra])
    if fill != 0:
        arr[old:] = fill
    return arr


def _local_offsets() -> np.ndarray:
    """(512, 3) local (di, dj, dk) of each voxel offset inside a block."""
    o = np.arange(BLOCK_VOXELS)
    return np.stack([o >> (2 * BLOCK_BITS), (o >> BLOCK_BITS) & BLOCK_MASK, o & BLOCK_MASK], axis=1)


class VoxelGrid:
    """Sparse voxel grid with named per-voxel channels, stored in 8^3 blocks.

    ``channels`` maps a name to ``(dtype, fill value)``; every channel is a (max_blocks, 512)
    array. Kernels receive ``table_keys, table_vals, block_coords, meta`` and the channels.
    """

    def __init__(self, resolution: float, channels: dict[str, tuple[type, float]], initial_blocks: int = 256):
        if resolution <= 0:
            raise ValueError("resolution must be positive")
        self.resolution = float(resolution)
        self.channel_spec = dict(channels)
        cap_blocks = max(16, int(initial_blocks))
        self.meta = np.array([0, cap_blocks], dtype=np.int64)
        self.block_coords = np.zeros((cap_blocks, 3), dtype=np.int32)
        self.data = {
            name: np.full((cap_blocks, BLOCK_VOXELS), fill, dtype=dtype)
            for name, (dtype, fill) in self.channel_spec.items()
        }
        capacity = 1 << int(np.ceil(np.log2(cap_blocks * 2)))
        self.table_keys = np.full(capacity, EMPTY_KEY, dtype=np.int64)
        self.table_vals = np.full(capacity, -1, dtype=np.int32)

    # -- size -------------------------------------------------------------------------------
    @property
    def n_blocks(self) -> int:
        return int(self.meta[META_N])

    @property
    def max_blocks(self) -> int:
        return int(self.meta[META_MAX])

    def nbytes(self) -> int:
        """Bytes held by the grid's arrays (allocated capacity, not just used blocks)."""
        total = self.block_coords.nbytes + self.table_keys.nbytes + self.table_vals.nbytes
        return total + sum(a.nbytes for a in self.data.values())

    def grow(self, min_free_blocks: int = 1) -> None:
        """Grow the block pool by half (at least ``min_free_blocks``), and the hash table with it.

        Arrays are resized in place where numpy can (``ndarray.resize``: a realloc, which for
        large arrays remaps pages instead of copying), so growing does not hold the old and the
        new pool at once; when something else still references an array (a view handed out by
        ``channel``), it is copied instead. Growth by 1.5x keeps the unused tail of the pool
        below a third of it."""
        n, old = self.n_blocks, self.max_blocks
        new = max(old + old // 2, n + min_free_blocks, 16)
        self.block_coords = _grown(self.block_coords, new, 0)
        for name, (_dtype, fill) in self.channel_spec.items():
            self.data[name] = _grown(self.data.pop(name), new, fill)
        self.meta[META_MAX] = new
        if self.table_keys.shape[0] < 2 * new:
            capacity = 1 << int(np.ceil(np.log2(2 * new)))
            self.table_keys, self.table_vals = _rehash(self.block_coords, n, capacity)

    # -- access by key ------------------------------------------------------------------------
    def lookup(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(block index or -1, offset) for integer voxel keys (N, 3)."""
        keys = np.ascontiguousarray(np.asarray(keys, dtype=np.int64).reshape(-1, 3))
        return _lookup_many(self.table_keys, self.table_vals, keys)

    def allocate(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(block index, offset) for keys (N, 3), allocating missing blocks."""
        keys = np.ascontiguousarray(np.asarray(keys, dtype=np.int64).reshape(-1, 3))
        blocks = np.empty(len(keys), dtype=np.int64)
        offs = np.empty(len(keys), dtype=np.int64)
        start = 0
        while True:
            start = _add_many(self.table_keys, self.table_vals, self.block_coords, self.meta, keys, blocks, offs, start)
            if start == len(keys):
                return blocks, offs
            self.grow()

    def get(self, name: str, keys: np.ndarray) -> np.ndarray:
        """Channel values at keys (N, 3); the channel's fill value where never allocated."""
        blocks, offs = self.lookup(keys)
        dtype, fill = self.channel_spec[name]
        out = np.full(len(blocks), fill, dtype=dtype)
        ok = blocks >= 0
        out[ok] = self.data[name][blocks[ok], offs[ok]]
        return out

    def set(self, name: str, keys: np.ndarray, values) -> None:
        blocks, offs = self.allocate(keys)
        self.data[name][blocks, offs] = values

    def block_keys(self) -> np.ndarray:
        """(n_blocks, 3) coordinates of the allocated blocks."""
        return self.block_coords[: self.n_blocks].astype(np.int64)

    def voxels_where(self, mask: np.ndarray) -> np.ndarray:
        """Keys (M, 3) of voxels where ``mask`` (n_blocks, 512) is true."""
        b, o = np.nonzero(mask[: self.n_blocks])
        return self.block_coords[b].astype(np.int64) * BLOCK + _LOCAL[o]

    def channel(self, name: str) -> np.ndarray:
        """The used part (n_blocks, 512) of a channel (a view)."""
        return self.data[name][: self.n_blocks]

    # -- state ------------------------------------------------------------------------------
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The used part of every array, as views (no copy: a snapshot of a big map would
        otherwise double its memory): write or copy them before the map changes."""
        n = self.n_blocks
        out = {f"{prefix}block_coords": self.block_coords[:n]}
        for name in self.channel_spec:
            out[f"{prefix}{name}"] = self.data[name][:n]
        return out

    @classmethod
    def from_arrays(
        cls, resolution: float, channels: dict[str, tuple[type, float]], arrays: dict[str, np.ndarray], prefix: str
    ) -> VoxelGrid:
        coords = np.asarray(arrays[f"{prefix}block_coords"], dtype=np.int32)
        n = len(coords)
        grid = cls(resolution, channels, initial_blocks=max(256, n))
        grid.block_coords[:n] = coords
        for name, (dtype, _fill) in channels.items():
            grid.data[name][:n] = np.asarray(arrays[f"{prefix}{name}"], dtype=dtype)
        grid.meta[META_N] = n
        grid.table_keys, grid.table_vals = _rehash(grid.block_coords, n, grid.table_keys.shape[0])
        return grid


_LOCAL = _local_offsets()


def band_k_range(z_min: float, z_max: float, resolution: float) -> tuple[int, int]:
    """Voxel indices k (inclusive) whose interval [k r, (k+1) r) overlaps [z_min, z_max]
    with positive length."""
    k_lo = int(np.floor(z_min / resolution + 1e-9))
    k_hi = int(np.ceil(z_max / resolution - 1e-9)) - 1
    return k_lo, k_hi
