"""Depth images from cameras whose CameraInfo has lens distortion, made pinhole images.

A RealSense publishes its depth without distortion (D all zero), but an Azure Kinect or an
Orbbec Femto publishes ``depth/image_raw`` as the lens saw it (``rational_polynomial``, k1 near
0.5), a Kinect v2 its ``sd`` depth with ``plumb_bob`` k1 near 0.1: read as pinhole images, points
near the image's corners land tens of centimetres off at 5 m. ltmap's kernels project with the
pinhole model (``CameraIntrinsics``), so such an image is first resampled, as image_proc's
rectify does, to the pinhole image of the same K: each output pixel takes the depth of the
recorded pixel its ray hits through the lens (the nearest one: depth is not interpolated across
edges), and none where that falls outside the image. A pixel's depth is z along the optical
axis, which the lens does not change.

Models (REP 104 / image_geometry): ``plumb_bob`` and ``rational_polynomial`` (k1, k2, p1, p2,
k3[, k4, k5, k6]), ``equidistant`` (fisheye k1..k4). The maps are computed once per calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import LogReadError

MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
MAX_COEFFS = 14  # OpenCV's most (rational + thin prism + tilt): the coefficients read from a CameraInfo
MAP_ROWS_PIXELS = 1 << 20  # the map is computed this many pixels at a time (its float64 temporaries bounded)


@dataclass(frozen=True)
class Distortion:
    model: str
    d: tuple[float, ...]


def distortion(info) -> Distortion | None:
    """The CameraInfo's lens distortion, None when it has none (no coefficients, or all zero)."""
    d = getattr(info, "d", None)
    if d is None:
        d = getattr(info, "D", None)
    # (at most the first MAX_COEFFS: no model uses more, and a hostile message may hold millions)
    coeffs = tuple(float(x) for x in (np.asarray(d, dtype=np.float64).reshape(-1)[:MAX_COEFFS] if d is not None else ()))
    if not any(c != 0.0 for c in coeffs):
        return None
    return Distortion(str(getattr(info, "distortion_model", "") or "plumb_bob"), coeffs)


def distort(x: np.ndarray, y: np.ndarray, dist: Distortion, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Normalized pinhole coordinates -> where the lens puts them (image_geometry's models)."""
    d = list(dist.d) + [0.0] * 8
    if dist.model in ("plumb_bob", "rational_polynomial"):
        k1, k2, p1, p2, k3, k4, k5, k6 = d[:8]
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd
    if dist.model == "equidistant":
        k1, k2, k3, k4 = d[:4]
        r = np.sqrt(x * x + y * y)
        th = np.arctan(r)
        th2 = th * th
        thd = th * (1 + th2 * (k1 + th2 * (k2 + th2 * (k3 + th2 * k4))))
        scale = np.where(r > 1e-12, thd / np.maximum(r, 1e-12), 1.0)
        return x * scale, y * scale
    raise LogReadError(f"CameraInfo for depth {where} has distortion model {dist.model!r} with non-zero coefficients; "
                       f"ltmap rectifies {', '.join(MODELS)}: record the rectified depth topic (image_rect)")  # fmt: skip


_MAPS: dict[tuple, np.ndarray] = {}
_MAX_MAPS = 8


def source_index(w: int, h: int, fx: float, fy: float, cx: float, cy: float, dist: Distortion,
                 where: str) -> np.ndarray:
    """(h * w,) int64: for each pixel of the pinhole image, the flat index of the recorded pixel
    nearest to where the lens puts its ray; -1 where that lies outside the image."""
    key = (w, h, fx, fy, cx, cy, dist)
    idx = _MAPS.get(key)
    if idx is None:
        idx = np.full(h * w, -1, dtype=np.int64)
        step = max(1, MAP_ROWS_PIXELS // max(w, 1))
        for v0 in range(0, h, step):  # rows at a time: the float64 temporaries stay bounded
            u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(v0, min(v0 + step, h), dtype=np.float64))
            xd, yd = distort((u - cx) / fx, (v - cy) / fy, dist, where)
            us = np.floor(fx * xd + cx + 0.5)
            vs = np.floor(fy * yd + cy + 0.5)
            inside = (us >= 0) & (us < w) & (vs >= 0) & (vs < h) & np.isfinite(us) & np.isfinite(vs)
            part = np.full(u.shape, -1, dtype=np.int64)
            part[inside] = (vs * w + us)[inside].astype(np.int64)
            idx[v0 * w : v0 * w + part.size] = part.ravel()
        if len(_MAPS) >= _MAX_MAPS:
            _MAPS.pop(next(iter(_MAPS)))
        _MAPS[key] = idx
    return idx


def rectify(raw: np.ndarray, fx: float, fy: float, cx: float, cy: float, dist: Distortion, where: str) -> np.ndarray:
    """The pinhole image (same K, same dtype) of a depth image ``raw`` recorded through ``dist``;
    pixels whose ray leaves the recorded image are invalid (0, or NaN for float)."""
    h, w = raw.shape
    idx = source_index(w, h, fx, fy, cx, cy, dist, where)
    flat = np.ascontiguousarray(raw).reshape(-1)
    out = flat[np.maximum(idx, 0)]
    out[idx < 0] = 0 if raw.dtype.kind in "ui" else np.nan
    return out.reshape(h, w)
