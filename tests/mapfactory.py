"""Hand-written map_server maps for tests: bytes we control, independent of ltmap's writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_trinary(path: Path, data: np.ndarray, resolution: float = 0.05, origin=(0.0, 0.0, 0.0)) -> Path:
    """Write a map_server trinary map by hand (row 0 of ``data`` = bottom): occupied 0, free 254,
    unknown 205 in a P5 PGM, top row first."""
    data = np.asarray(data)
    pix = np.full(data.shape, 205, dtype=np.uint8)
    pix[data == 0] = 254
    pix[data == 100] = 0
    pix = pix[::-1]
    h, w = pix.shape
    path.parent.mkdir(parents=True, exist_ok=True)
    pgm = path.with_suffix(".pgm")
    pgm.write_bytes(b"P5\n%d %d\n255\n" % (w, h) + pix.tobytes())
    path.write_text(
        f"image: {pgm.name}\nmode: trinary\nresolution: {resolution}\n"
        f"origin: [{origin[0]!r}, {origin[1]!r}, {origin[2]!r}]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return path
