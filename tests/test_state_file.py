"""The state file (``io.state``): an .npz that np.load and read_state read back exactly, its
arrays deflated by zlib-ng (half zlib's time at every snapshot) in zipfile's own format."""

from __future__ import annotations

import io
import zipfile
import zlib

import numpy as np

from ltmap_cli.io.state import ZIP_LEVEL, _deflate_with_zlib_ng, read_state, write_state


def _arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(31)
    lo = np.zeros((300, 512), dtype=np.float32)  # a map's log-odds: runs of values and zeros
    lo[rng.random(300) < 0.4] = rng.choice([-2.0, 3.5, 0.4], size=(1, 512)).astype(np.float32)
    lo[:, rng.random(512) < 0.1] = 0
    stamp = np.cumsum(rng.integers(0, 3, (300, 512)), axis=1).astype(np.int32)
    return {"O_logodds": lo, "O_stamp": stamp, "O_block_coords": rng.integers(-50, 50, (300, 3)).astype(np.int32)}


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, allow_pickle=False)
    return buf.getvalue()


def test_state_arrays_come_back_exactly_deflated_by_zlib_ng(tmp_path):
    from zlib_ng import zlib_ng

    arrays = _arrays()
    path = tmp_path / "state.npz"
    write_state(path, arrays, {"log_time_s": 2.5})
    back, meta = read_state(path)
    assert meta["log_time_s"] == 2.5 and set(back) == set(arrays)
    assert all(np.array_equal(back[k], arrays[k]) and back[k].dtype == arrays[k].dtype for k in arrays)
    with np.load(path) as z:  # numpy reads it as its own
        assert np.array_equal(z["O_stamp"], arrays["O_stamp"])
    with zipfile.ZipFile(path) as zf:
        for name, a in arrays.items():
            info = zf.getinfo(name + ".npy")
            assert info.compress_type == zipfile.ZIP_DEFLATED
            raw = _npy(a)
            ng = zlib_ng.compressobj(ZIP_LEVEL, zlib_ng.DEFLATED, -15)
            by_ng = len(ng.compress(raw) + ng.flush())
            zl = zlib.compressobj(ZIP_LEVEL, zlib.DEFLATED, -15)
            by_zlib = len(zl.compress(raw) + zl.flush())
            assert info.compress_size == by_ng != by_zlib, name


def test_without_the_writers_compressor_attribute_zlib_is_kept():
    class Member:  # (a zipfile whose writer keeps its compressor under another name)
        pass

    assert _deflate_with_zlib_ng(Member()) is False
