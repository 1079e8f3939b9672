"""OctoMap .ot files: checked against the real OctoMap library (pyoctomap)."""

from __future__ import annotations

import struct

import numpy as np
import pyoctomap
import pytest

from ltmap_cli.errors import MapFileError
from ltmap_cli.io.ot import morton_codes, ot_bytes, read_ot, write_ot


def _octomap_leaves(tree, resolution):
    """Every voxel of every leaf of a pyoctomap tree: {(i, j, k): log-odds}."""
    out = {}
    for it in tree.begin_leafs():
        size = it.getSize()
        n = int(round(size / resolution))
        cx, cy, cz = it.getCoordinate()
        base = [int(np.floor((c - size / 2) / resolution + 0.5)) for c in (cx, cy, cz)]
        value = it.current_node.getLogOdds()
        for a in range(n):
            for b in range(n):
                for c in range(n):
                    out[(base[0] + a, base[1] + b, base[2] + c)] = value
    return out


def _as_dict(keys, values):
    return {tuple(int(v) for v in k): float(x) for k, x in zip(keys, values)}


def _voxel_set(seed=1):
    rng = np.random.default_rng(seed)
    scattered = rng.integers(-300, 300, size=(400, 3))
    cube = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(4), indexing="ij"), -1).reshape(-1, 3)
    cube = cube + [-2, 5, -9]  # straddles 0 in x: negative and positive keys in one cube
    keys = np.unique(np.concatenate([scattered, cube, [[-32768, 0, 32767], [0, 0, 0], [-1, -1, -1]]]), axis=0)
    logodds = rng.uniform(-2.0, 3.5, size=len(keys)).astype(np.float32)
    return keys, logodds


def test_file_bytes_for_two_voxels_by_hand():
    # voxel (0,0,0) -> key 32768 (bit 15 set in x, y, z: root child 7);
    # voxel (-1,2,3) -> keys 32767, 32770, 32771 (bit 15: 0, 1, 1 -> root child 2 + 4 = 6).
    # The paths split at the root: 1 root + 2 * 16 nodes = 33. Pre-order: child 6 first.
    data = ot_bytes(np.array([[0, 0, 0], [-1, 2, 3]]), np.array([0.85, -0.4], np.float32), 0.1)
    header = b"# Octomap OcTree file\n"
    assert data.startswith(header)
    head, body = data.split(b"\ndata\n", 1)
    assert b"\nid OcTree\nsize 33\nres 0.1" in head + b"\n"
    assert len(body) == 33 * 5
    value, mask = struct.unpack("<fB", body[:5])
    assert value == pytest.approx(0.85) and mask == 0b1100_0000  # root: max of children
    value, mask = struct.unpack("<fB", body[5:10])
    assert value == pytest.approx(-0.4)  # first child of the root is child 6, the (-1,2,3) branch
    # level 14 of (32767, 32770, 32771): bits 1, 0, 0 -> child 1
    assert mask == 0b0000_0010
    # the 16th node of the first branch is the leaf: mask 0
    value, mask = struct.unpack("<fB", body[16 * 5 : 17 * 5])
    assert (value, mask) == (pytest.approx(-0.4), 0)


def test_morton_code_matches_octomap_child_index():
    keys = np.array([[32768, 32767, 32771], [1, 0, 0], [0, 1, 0], [0, 0, 1], [65535, 0, 65535]])
    codes = morton_codes(keys)
    assert list(codes[1:4]) == [1, 2, 4]
    for key, code in zip(keys, codes):
        for level in range(16):
            pos = ((key[0] >> level) & 1) + 2 * ((key[1] >> level) & 1) + 4 * ((key[2] >> level) & 1)
            assert (int(code) >> (3 * level)) & 7 == pos


def test_octomap_reads_what_we_write(tmp_path):
    keys, logodds = _voxel_set()
    path = tmp_path / "map.ot"
    write_ot(path, keys, logodds, 0.05)
    tree = pyoctomap.OcTree(0.1).read(str(path))
    assert tree is not None
    assert tree.getResolution() == pytest.approx(0.05)
    header_size = int(path.read_bytes().split(b"\nsize ")[1].split(b"\n")[0])
    assert tree.size() == header_size
    assert tree.getNumLeafNodes() == len(keys)
    leaves = _octomap_leaves(tree, 0.05)
    ours = _as_dict(keys, logodds)
    assert leaves.keys() == ours.keys()
    for key, value in ours.items():
        assert np.float32(leaves[key]) == np.float32(value), key
    # occupancy as OctoMap judges it: occupied iff log-odds > 0 (p > 0.5)
    occupied_octomap = {
        tuple(int(np.floor(c / 0.05)) for c in it.getCoordinate())
        for it in tree.begin_leafs()
        if tree.isNodeOccupied(it)
    }
    assert occupied_octomap == {tuple(k) for k, v in zip(keys.tolist(), logodds) if v > 0}
    # inner nodes hold the max of their children: the root holds the global max
    assert np.float32(tree.getRoot().getLogOdds()) == logodds.max()


def test_read_what_octomap_writes_with_pruned_leaves(tmp_path):
    res = 0.1
    tree = pyoctomap.OcTree(res)
    # a solid 8 x 8 x 8 voxel block aligned to a depth-13 node, seen 3 times -> pruned to one leaf
    g = (np.arange(8) + 0.5) * res
    block = np.stack(np.meshgrid(g + 1.6, g + 0.8, g + 0.8, indexing="ij"), -1).reshape(-1, 3)
    others = np.array([[-0.35, 0.25, 0.15], [0.45, -0.65, 0.05]])
    for _ in range(3):
        tree.insertPointCloud(np.concatenate([block, others]), np.array([0.0, 0.0, 0.05]))
    depths = [it.getDepth() for it in tree.begin_leafs()]
    assert min(depths) < 16  # the file really has pruned leaves to expand
    path = tmp_path / "octomap.ot"
    assert tree.write(str(path))
    expected = _octomap_leaves(tree, res)
    keys, logodds, resolution = read_ot(path)
    assert resolution == res
    assert _as_dict(keys, logodds) == pytest.approx(expected)
    occupied = {k for k, v in expected.items() if v > 0}
    assert len(occupied) >= 512 + 2
    okeys, ologodds, _ = read_ot(path, occupied_only=True)
    assert {tuple(k) for k in okeys.tolist()} == occupied
    assert np.all(ologodds > 0)


def test_round_trip(tmp_path):
    keys, logodds = _voxel_set(seed=7)
    path = tmp_path / "rt.ot"
    write_ot(path, keys, logodds, 0.025)
    back_keys, back_logodds, res = read_ot(path)
    assert res == 0.025 and back_keys.dtype == np.int64 and back_logodds.dtype == np.float32
    assert _as_dict(back_keys, back_logodds) == _as_dict(keys, logodds)
    assert len(back_keys) == len(keys)


def test_empty_tree(tmp_path):
    path = tmp_path / "empty.ot"
    write_ot(path, np.zeros((0, 3), np.int32), np.zeros(0, np.float32), 0.05)
    tree = pyoctomap.OcTree(0.1).read(str(path))
    assert tree.size() == 0
    keys, logodds, res = read_ot(path)
    assert keys.shape == (0, 3) and logodds.shape == (0,) and res == 0.05


def test_write_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="same voxel twice"):
        write_ot(tmp_path / "a.ot", np.array([[1, 2, 3], [1, 2, 3]]), np.zeros(2, np.float32), 0.1)
    with pytest.raises(ValueError, match=r"\[-32768, 32767\]"):
        write_ot(tmp_path / "a.ot", np.array([[32768, 0, 0]]), np.zeros(1, np.float32), 0.1)
    with pytest.raises(ValueError, match="shape"):
        write_ot(tmp_path / "a.ot", np.array([[1, 2, 3]]), np.zeros(2, np.float32), 0.1)
    assert list(tmp_path.iterdir()) == []


def test_read_rejects_bt(tmp_path):
    tree = pyoctomap.OcTree(0.1)
    tree.updateNode(np.array([0.05, 0.05, 0.05]), True)
    path = tmp_path / "map.bt"
    assert tree.writeBinary(str(path))
    with pytest.raises(MapFileError, match=r"map\.bt: is an OctoMap binary tree \(\.bt"):
        read_ot(path)


def test_read_rejects_other_tree_id(tmp_path):
    path = tmp_path / "color.ot"
    data = ot_bytes(np.array([[0, 0, 0]]), np.array([1.0], np.float32), 0.1)
    path.write_bytes(data.replace(b"id OcTree", b"id ColorOcTree"))
    with pytest.raises(MapFileError, match=r"color\.ot: OctoMap tree id is ColorOcTree, ltmap reads only 'OcTree'"):
        read_ot(path)


def test_read_errors(tmp_path):
    with pytest.raises(MapFileError, match=r"nope\.ot: OctoMap file not found"):
        read_ot(tmp_path / "nope.ot")
    junk = tmp_path / "junk.ot"
    junk.write_bytes(b"P5\n1 1\n255\n\x00")
    with pytest.raises(MapFileError, match=r"junk\.ot: not an OctoMap \.ot file"):
        read_ot(junk)
    cut = tmp_path / "cut.ot"
    data = ot_bytes(np.array([[0, 0, 0], [5, 5, 5]]), np.array([1.0, 2.0], np.float32), 0.1)
    cut.write_bytes(data[:-7])
    with pytest.raises(MapFileError, match=r"cut\.ot: OctoMap data truncated"):
        read_ot(cut)
    # a lone root leaf covers the whole 65536^3 key space
    huge = tmp_path / "huge.ot"
    huge.write_bytes(b"# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n" + struct.pack("<fB", 1.0, 0))
    with pytest.raises(MapFileError, match=r"huge\.ot: OctoMap tree expands to 281474976710656 voxels"):
        read_ot(huge)
    write_ot(cut, np.array([[0, 0, 0], [5, 5, 5]]), np.array([1.0, 2.0], np.float32), 0.1)
    with pytest.raises(MapFileError, match="expands to 2 voxels, more than the 1"):
        read_ot(cut, max_voxels=1)


# --------------------------------------------------------------------------------------------
# pruning: eight sibling leaves with bitwise equal log-odds are one leaf at their parent


def _reference_prune(keys, logodds):
    """OctoMap's prune() done the slow way: {(depth, i, j, k of the leaf's first voxel): bits}."""
    leaves = {(0, *map(int, k)): int(b) for k, b in zip(keys, logodds.astype(np.float32).view(np.uint32))}
    for level in range(15):  # the root (depth 0) is never a leaf
        groups = {}
        for (lv, i, j, k), b in leaves.items():
            if lv == level:
                groups.setdefault((i >> (level + 1), j >> (level + 1), k >> (level + 1)), []).append(b)
        for (pi, pj, pk), bits in groups.items():
            if len(bits) == 8 and len(set(bits)) == 1:
                s = level + 1
                for c in range(8):
                    ci, cj, ck = ((pi << 1) | (c & 1)) << level, ((pj << 1) | ((c >> 1) & 1)) << level, (
                        (pk << 1) | (c >> 2)) << level  # fmt: skip
                    del leaves[(level, ci, cj, ck)]
                leaves[(s, pi << s, pj << s, pk << s)] = bits[0]
    return {(16 - lv, i, j, k): b for (lv, i, j, k), b in leaves.items()}


def _pruned_voxel_set():
    """Free space with obstacles in it, as a long-term snapshot holds: big equal-valued regions
    (aligned and not, across 0), one occupied voxel inside an aligned block, a block whose
    values differ by one ulp or by the sign of zero, and random scattered voxels."""
    free = np.float32(-7.5261)
    rng = np.random.default_rng(3)

    def box(lo, n):
        g = np.stack(np.meshgrid(*(np.arange(a, a + m) for a, m in zip(lo, n)), indexing="ij"), -1)
        return g.reshape(-1, 3)

    parts = [
        (box((-32, -32, 0), (48, 32, 32)), free),  # aligned: one leaf at depth 11, four at 12
        (box((5, 3, 20), (13, 9, 6)), free),  # not aligned: some 2^3 nodes at most
        (box((40, 40, 40), (8, 8, 8)), np.float32(3.5)),  # one occupied depth-13 leaf
    ]
    keys = np.concatenate([p for p, _ in parts])
    vals = np.concatenate([np.full(len(p), v, np.float32) for p, v in parts])
    odd = box((-64, 0, 0), (8, 8, 8))  # free but voxel (-64, 0, 0) is occupied: 7 siblings stay
    odd_v = np.full(len(odd), free, np.float32)
    odd_v[0] = 2.0
    ulp = box((64, 0, 0), (2, 2, 2))  # one ulp apart: not equal
    ulp_v = np.full(8, free, np.float32)
    ulp_v[3] = np.nextafter(free, np.float32(0))
    zeros = box((66, 0, 0), (2, 2, 2))  # +0.0 and -0.0: equal as numbers, not bitwise
    zeros_v = np.zeros(8, np.float32)
    zeros_v[5] = -0.0
    scattered = rng.integers(-500, 500, size=(300, 3)) + [0, 0, 200]
    keys = np.concatenate([keys, odd, ulp, zeros, scattered])
    vals = np.concatenate([vals, odd_v, ulp_v, zeros_v, rng.uniform(-3, 3, 300).astype(np.float32)])
    keys, first = np.unique(keys, axis=0, return_index=True)
    return keys, vals[first]


def test_pruned_file_is_the_same_voxels_for_octomap_and_for_us(tmp_path):
    keys, logodds = _pruned_voxel_set()
    expected = _reference_prune(keys, logodds)
    assert min(d for d, *_ in expected) == 11 and len(expected) < len(keys) / 20
    pruned, plain = tmp_path / "pruned.ot", tmp_path / "plain.ot"
    write_ot(pruned, keys, logodds, 0.05)
    write_ot(plain, keys, logodds, 0.05, prune=False)
    assert pruned.stat().st_size < plain.stat().st_size / 10
    ours = _as_dict(keys, logodds)
    occupied = {k for k, v in ours.items() if v >= 0}  # OctoMap's test (p >= 0.5): its own free / occupied
    for path, n_leaves in ((pruned, len(expected)), (plain, len(keys))):
        tree = pyoctomap.OcTree(0.1).read(str(path))
        assert tree.size() == int(path.read_bytes().split(b"\nsize ")[1].split(b"\n")[0])
        assert tree.getNumLeafNodes() == n_leaves
        leaves = _octomap_leaves(tree, 0.05)  # pruned leaves expanded into their voxels
        assert leaves.keys() == ours.keys()
        assert all(np.float32(leaves[k]).tobytes() == np.float32(v).tobytes() for k, v in ours.items())
        theirs_occ = set()
        for it in tree.begin_leafs():
            if tree.isNodeOccupied(it):
                n = int(round(it.getSize() / 0.05))
                base = [int(np.floor((c - it.getSize() / 2) / 0.05 + 0.5)) for c in it.getCoordinate()]
                theirs_occ |= {(base[0] + a, base[1] + b, base[2] + c) for a in range(n) for b in range(n)
                               for c in range(n)}  # fmt: skip
        assert theirs_occ == occupied
        assert ours.keys() - theirs_occ == {k for k, v in ours.items() if v < 0}  # the free voxels
    # the leaves OctoMap sees are OctoMap's prune() of the voxels
    tree = pyoctomap.OcTree(0.1).read(str(pruned))
    seen = {}
    for it in tree.begin_leafs():
        base = tuple(int(np.floor((c - it.getSize() / 2) / 0.05 + 0.5)) for c in it.getCoordinate())
        seen[(it.getDepth(), *base)] = int(np.float32(it.current_node.getLogOdds()).view(np.uint32))
    assert seen == expected
    # and read_ot expands them back exactly
    back_keys, back_logodds, res = read_ot(pruned)
    assert res == 0.05 and len(back_keys) == len(keys)
    order, back = np.lexsort(keys.T[::-1]), np.lexsort(back_keys.T[::-1])
    np.testing.assert_array_equal(back_keys[back], keys[order])
    assert back_logodds[back].tobytes() == logodds[order].tobytes()


def test_prune_merges_only_bitwise_equal_siblings():
    cube = np.stack(np.meshgrid(np.arange(2), np.arange(2), np.arange(2), indexing="ij"), -1).reshape(-1, 3)

    def size(values):
        return int(ot_bytes(cube, np.asarray(values, np.float32), 0.1).split(b"\nsize ")[1].split(b"\n")[0])

    assert size([-2.0] * 8) == 16  # root .. one leaf at depth 15
    assert size([-2.0] * 7 + [np.nextafter(np.float32(-2.0), np.float32(0))]) == 16 + 8  # root .. 8 leaves
    assert size([0.0] * 7 + [-0.0]) == 16 + 8
    unpruned = ot_bytes(cube, np.full(8, -2.0, np.float32), 0.1, prune=False)
    assert b"\nsize 24\n" in unpruned


def test_snapshot_built_block_by_block_is_the_voxel_list_file():
    """write_snapshot builds the .ot from the sensor map's blocks (no key per free voxel): the
    same bytes as ot_bytes on the voxel list, with long-term voxels that win over free space,
    seeds in blocks the sensor map never allocated, and negative coordinates."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.ot import ot_bytes
    from ltmap_cli.outputs.snapshots import snapshot_ot_bytes, snapshot_voxels

    m = LayeredMap(MapConfig())
    rng = np.random.default_rng(3)
    for _ in range(20):  # rays from near the origin into all octants: free space and hits
        origin = rng.uniform(-0.3, 0.3, 3) + [0, 0, 1.0]
        m.integrate(origin, rng.uniform(-3, 3, (200, 3)) + [0, 0, 1.0], max_range=4.0)
    free_keys = m.O.voxels_where(m.O.channel("logodds") < 0)
    m.seed_long_term(free_keys[:50], 0.9)  # long-term where O says free: LT wins
    m.seed_long_term(np.array([[400, -400, 3], [401, -400, 3], [-900, 5, 0]]), 1.0)  # no O block there
    keys, logodds = snapshot_voxels(m)
    assert len(keys) > 10_000
    assert snapshot_ot_bytes(m) == ot_bytes(keys, logodds, m.resolution)


def test_snapshot_leaves_out_what_octomap_keys_cannot_hold(tmp_path):
    """A map reaching beyond +-32768 voxels (1.6 km at 0.05 m) still snapshots: the .ot holds what
    OctoMap's 16-bit keys can address, with one warning; the state .npz holds everything."""
    import warnings

    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.errors import LtmapWarning
    from ltmap_cli.io.ot import read_ot
    from ltmap_cli.outputs.snapshots import _WARNED, write_snapshot

    m = LayeredMap(MapConfig())
    m.integrate([0.01, 0.01, 1.01], [[1.0, 0.01, 1.01]])
    m.integrate([2000.01, 0.01, 1.01], [[2001.0, 0.01, 1.01]])  # 2 km east: keys ~40000
    m.seed_long_term(np.array([[10, 0, 20], [40_000, 0, 20]]), 1.0)
    _WARNED.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        paths = write_snapshot(m, tmp_path, None, {})
    assert [str(w.message) for w in caught if issubclass(w.category, LtmapWarning)] == [
        "the .ot snapshots leave out what lies beyond +-1.6 km of the fixed frame's origin (OctoMap's 16-bit keys "
        "at 0.05 m); the state .npz snapshots hold it all"]
    keys, logodds, _ = read_ot(paths["ot"])
    assert keys.max() < 32768 and keys[logodds > 0].tolist() == [[10, 0, 20]]  # the near seed wins over free


def test_resume_reads_only_the_long_term_voxels_of_a_snapshot(tmp_path):
    """A snapshot's free leaves are not expanded when only long-term voxels are wanted (resume):
    read_ot with min_logodds returns the LT > 0 voxels and nothing of the free space."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.ot import read_ot
    from ltmap_cli.outputs.snapshots import (
        LT_CLIP,
        load_resume,
        long_term_voxels,
        lt_to_ot_logodds,
        write_snapshot,
    )

    m = LayeredMap(MapConfig())
    for y in np.arange(-1.0, 1.0, 0.05):
        m.integrate([0.01, 0.01, 1.01], [[3.0, y, 1.01]])
    m.seed_long_term(np.array([[60, 0, 20], [61, 0, 20], [5, 5, 5]]), np.array([1.0, 0.3, 0.01]))
    path = write_snapshot(m, tmp_path, None, {})["ot"]
    everything, _, _ = read_ot(path)
    floor = float(lt_to_ot_logodds(LT_CLIP * 1.5, 0.65))
    keys, logodds, _ = read_ot(path, min_logodds=floor)
    lt_keys, _ = long_term_voxels(m)
    assert len(everything) > 1000 > len(keys) == len(lt_keys) == 3
    assert sorted(map(tuple, keys.tolist())) == sorted(map(tuple, lt_keys.tolist()))
    day2 = LayeredMap(MapConfig())
    assert load_resume(day2, path)["long_term_voxels"] == 3


def test_blocks_of_one_value_go_as_one_leaf_and_give_the_voxel_list_file(tmp_path):
    """blocks_ot_bytes pushes a whole block, 64-run or 8-run of one value as one leaf: the bytes
    stay those of ot_bytes on every voxel listed, for whole blocks, blocks missing one voxel,
    long-term voxels breaking a run (or equal to free: still one run), runs of 64 and 8, and
    scattered voxels; and OctoMap's pruning reads them back as the same voxels."""
    from ltmap_cli.io.ot import _local_tables, blocks_ot_bytes, ot_bytes, read_ot

    free = np.float32(-2.0)
    rng = np.random.default_rng(7)
    blocks = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, -1, 0], [2, 2, 1], [3, -2, 0], [5, 5, 5]])
    local_off, _ = _local_tables()
    o_free = np.zeros((len(blocks), 512), dtype=bool)
    o_free[0] = True  # a whole block
    o_free[1] = True
    o_free[1, 77] = False  # all but one voxel
    o_free[2] = True  # whole, with long-term voxels below
    o_free[3, local_off[:64]] = True  # the first 64-run in Morton order
    o_free[3, local_off[128:136]] = True  # and one 8-run
    o_free[4] = rng.random(512) < 0.5  # scattered
    o_free[5, local_off[8:15]] = True  # an 8-run less one voxel
    o_block = np.arange(len(blocks))
    o_block[6] = -1  # long-term only, no sensor block
    lt_keys = np.array([[0, 8, 0], [3, 12, 5], [4, 9, 1], [40, 40, 40], [41, 40, 40]])
    lt = np.array([1.5, free, 0.7, 2.0, 2.0], dtype=np.float32)  # (0, 8, 0)'s... one equal to free
    got = blocks_ot_bytes(blocks, o_block, o_free, float(free), lt_keys, lt, 0.05)
    keys, vals = [], []
    for n, b in enumerate(blocks):
        if o_block[n] < 0:
            continue
        for off in np.flatnonzero(o_free[n]):
            keys.append(b * 8 + [off >> 6, (off >> 3) & 7, off & 7])
            vals.append(free)
    listed = {tuple(k): v for k, v in zip(keys, vals)}
    for k, v in zip(lt_keys.tolist(), lt):
        listed[tuple(k)] = v  # long-term wins over free
    k = np.array(list(listed), dtype=np.int64)
    v = np.array(list(listed.values()), dtype=np.float32)
    assert got == ot_bytes(k, v, 0.05)
    (tmp_path / "m.ot").write_bytes(got)
    rk, rv, _ = read_ot(tmp_path / "m.ot")
    assert len(rk) == len(k) and dict(zip(map(tuple, rk.tolist()), rv.tolist())) == {a: float(b) for a, b in listed.items()}
    assert len(got) < len(ot_bytes(k, v, 0.05, prune=False)) / 3  # the whole runs are single leaves
