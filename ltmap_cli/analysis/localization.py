"""2D localization of laser scans: a start alignment against a static map, then scan-to-map
registration along the log (against the static map plus the map built so far), or scan-matching
odometry when there is no static map. Pure numpy; no ROS, no files.

Poses are ``(x, y, yaw)`` tuples. A *correction* ``C`` maps the points of one scan, given in a
*child* frame (``odom`` when odometry places the laser, else the robot's or the laser's own frame),
into the fixed frame ``map``: ``p_map = C * p_child``. With odometry ``C`` is ``map -> odom``
and changes slowly; without, ``C`` is the pose of the child frame in ``map``.

The matcher (``register``) is a Gauss-Newton fit of the points to a *distance field*: the
distance (m) from each cell of a 2D grid to the nearest surface cell, clipped at
``surface_distance`` (points farther than that are outliers), bilinear with its gradient, as
likelihood-field / Hector-style scan matchers do. The field is built once from the static map
(an exact Euclidean distance transform) and updated in place when a cell of the map built so far
becomes a surface (``map_min_hits`` scans hit it), so a match costs a few vectorized passes over
the scan's points and no tree is rebuilt. The match score is the fraction of the scan's points
within ``inlier_distance`` of a surface.

The start alignment (``global_align``) is the search ``bench/align_comprobo.py`` did by hand:
for every yaw in ``align_yaw_step_deg`` steps the best translation of the first scans' points
(in odom) by FFT cross-correlation with the static map's walls on a coarse grid; the best few
candidates are refined with ``register`` and scored; below ``align_min_score``, or less than
``align_min_margin`` above a clearly different candidate (an ambiguous fit), the log cannot be
aligned.

``Tracker`` runs along the log: each scan is matched from a prediction (the previous correction
with odometry, a constant-velocity guess without), a match is rejected when its score is below
``min_score`` or it lands farther than ``max_jump_m`` / ``max_jump_deg`` from the prediction (the
prediction holds, the scan is counted), and with odometry the correction moves at most
``max_step_m`` / ``max_step_deg`` per scan, so that it never jumps and tears the map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np

Pose = tuple[float, float, float]

COARSE = 0.2  # m: cell of the start alignment's correlation grid (coarser for large maps) ...
COARSE_CELLS = 600  # ... at most this many cells across the static map
CANDIDATES = 6  # start alignment: correlation peaks refined


# ---------------------------------------------------------------------------------------------
# 2D poses


def compose(a: Pose, b: Pose) -> Pose:
    """``a * b``: the pose ``b`` (given in frame ``a``) in ``a``'s parent."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def invert(a: Pose) -> Pose:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap(-a[2]))


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def apply(pose: Pose, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) in the child frame -> in the parent frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty_like(pts, dtype=np.float64)
    out[:, 0] = pose[0] + c * pts[:, 0] - s * pts[:, 1]
    out[:, 1] = pose[1] + s * pts[:, 0] + c * pts[:, 1]
    return out


def pose_change(a: Pose, b: Pose, at: np.ndarray) -> tuple[float, float]:
    """How far (m) and how much (rad) the point ``at`` (child frame) moves from correction ``a``
    to correction ``b``."""
    pa = apply(a, at.reshape(1, 2))[0]
    pb = apply(b, at.reshape(1, 2))[0]
    return float(np.hypot(*(pb - pa))), abs(wrap(b[2] - a[2]))


def toward(a: Pose, b: Pose, at: np.ndarray, max_m: float, max_rad: float) -> Pose:
    """The correction between ``a`` and ``b`` that moves the point ``at`` at most ``max_m`` and
    turns at most ``max_rad`` from ``a`` (``b`` itself when it is within both)."""
    d, r = pose_change(a, b, at)
    f = min(1.0, max_m / d if d > 0 else 1.0, max_rad / r if r > 0 else 1.0)
    if f >= 1.0:
        return b
    # interpolate the pose of ``at`` and the heading, then back to a correction
    pa = apply(a, at.reshape(1, 2))[0]
    pb = apply(b, at.reshape(1, 2))[0]
    p = pa + f * (pb - pa)
    yaw = wrap(a[2] + f * wrap(b[2] - a[2]))
    c, s = math.cos(yaw), math.sin(yaw)
    return (float(p[0] - (c * at[0] - s * at[1])), float(p[1] - (s * at[0] + c * at[1])), yaw)


# ---------------------------------------------------------------------------------------------
# points


def downsample(pts: np.ndarray, cell: float) -> np.ndarray:
    """One point (the first) per ``cell``-sized square: dense near returns do not outweigh walls."""
    if len(pts) == 0:
        return pts.reshape(0, 2)
    keys = np.floor(pts / cell).astype(np.int64)
    _, idx = np.unique(keys[:, 0] * 2_000_003 + keys[:, 1], return_index=True)
    return pts[np.sort(idx)]


# ---------------------------------------------------------------------------------------------
# the distance field


def distance_field(surface: np.ndarray, res: float, dmax: float) -> np.ndarray:
    """float32 distance (m) from each cell centre to the nearest ``surface`` cell centre, clipped
    at ``dmax``: the exact Euclidean distance transform, separable (a row pass for the nearest
    surface column, then a column pass adding the row offsets), over offsets up to ``dmax``."""
    k = int(math.ceil(dmax / res))
    h, w = surface.shape
    big = np.float32((k + 1) ** 2 * 4)
    pad = np.zeros((h, w + 2 * k), dtype=bool)
    pad[:, k:k + w] = surface
    row = np.full((h, w), big, dtype=np.float32)  # squared column offset to the nearest surface in the row
    for dj in range(-k, k + 1):
        np.minimum(row, np.where(pad[:, k + dj:k + dj + w], np.float32(dj * dj), big), out=row)
    padr = np.full((h + 2 * k, w), big, dtype=np.float32)
    padr[k:k + h] = row
    d2 = np.full((h, w), big, dtype=np.float32)
    for di in range(-k, k + 1):
        np.minimum(d2, padr[k + di:k + di + h] + np.float32(di * di), out=d2)
    return np.minimum(np.sqrt(d2) * np.float32(res), np.float32(dmax))


class SurfaceField:
    """Distance (m) from every cell to the nearest surface cell, clipped at ``dmax``, on a 2D
    lattice that grows as points arrive (row 0 = lowest y). ``hits`` counts the scans that hit
    each cell; a cell becomes a surface when it reaches ``min_hits`` (or is static)."""

    GROW = 10.0  # m added on a side when the lattice grows

    def __init__(self, resolution: float, dmax: float, origin=(0.0, 0.0), shape=(1, 1), min_hits: int = 1):
        self.res = float(resolution)
        self.dmax = float(dmax)
        self.min_hits = int(min_hits)
        self.origin = np.array(origin, dtype=np.float64)
        self.dist = np.full(shape, self.dmax, dtype=np.float32)
        self.surface = np.zeros(shape, dtype=bool)
        self.hits = np.zeros(shape, dtype=np.int16)  # saturates: only min_hits matters
        self.locked = np.zeros(shape, dtype=bool)  # cells where hits make no surface (near a static wall)
        k = int(math.ceil(self.dmax / self.res))
        di, dj = np.mgrid[-k:k + 1, -k:k + 1]
        d = self.res * np.hypot(di, dj)
        keep = d < self.dmax
        self._kernel = (di[keep].astype(np.int64), dj[keep].astype(np.int64), d[keep].astype(np.float32))

    @classmethod
    def from_points(cls, surface_xy: np.ndarray, resolution: float, dmax: float, margin: float = 2.0,
                    min_hits: int = 1) -> SurfaceField:
        """A field whose surfaces are the cells holding ``surface_xy`` (N, 2), with exact
        Euclidean distances (``distance_field``)."""
        lo = surface_xy.min(0) - margin - resolution / 2  # the first point at a cell centre
        hi = surface_xy.max(0) + margin
        shape = (int(math.ceil((hi[1] - lo[1]) / resolution)), int(math.ceil((hi[0] - lo[0]) / resolution)))
        f = cls(resolution, dmax, lo, shape, min_hits)
        ij = f.cells(surface_xy)
        f.surface[ij[:, 0], ij[:, 1]] = True
        f.dist = distance_field(f.surface, f.res, f.dmax)
        return f

    def cells(self, xy: np.ndarray) -> np.ndarray:
        """(row, col) of the cells holding points (N, 2), which must lie inside the lattice."""
        ij = np.floor((xy - self.origin) / self.res).astype(np.int64)
        return ij[:, ::-1]

    def ensure(self, xy: np.ndarray) -> None:
        """Grow the lattice (by ``GROW`` m on a side) so that it holds the points (N, 2)."""
        if len(xy) == 0:
            return
        h, w = self.dist.shape
        lo = xy.min(0) - self.dmax - self.res
        hi = xy.max(0) + self.dmax + self.res
        top = self.origin + self.res * np.array([w, h])
        if np.all(lo >= self.origin) and np.all(hi <= top):
            return
        add_lo = np.where(lo < self.origin, np.ceil((self.origin - lo + self.GROW) / self.res), 0).astype(int)
        add_hi = np.where(hi > top, np.ceil((hi - top + self.GROW) / self.res), 0).astype(int)
        pad = ((add_lo[1], add_hi[1]), (add_lo[0], add_hi[0]))
        self.dist = np.pad(self.dist, pad, constant_values=self.dmax)
        self.surface = np.pad(self.surface, pad, constant_values=False)
        self.hits = np.pad(self.hits, pad, constant_values=0)
        self.locked = np.pad(self.locked, pad, constant_values=False)
        self.origin = self.origin - self.res * add_lo

    def add_hits(self, xy: np.ndarray, weight: int = 1) -> int:
        """Count a scan's points (N, 2; one per cell: see ``downsample``) as hits; cells that
        reach ``min_hits`` become surfaces and the field is updated around them. Returns how
        many cells became surfaces."""
        if len(xy) == 0:
            return 0
        self.ensure(xy)
        ij = np.unique(self.cells(xy), axis=0)
        r, c = ij[:, 0], ij[:, 1]
        self.hits[r, c] = np.minimum(self.hits[r, c].astype(np.int32) + weight, 30000)
        new = (self.hits[r, c] >= self.min_hits) & ~self.surface[r, c] & ~self.locked[r, c]
        r, c = r[new], c[new]
        if len(r) == 0:
            return 0
        self.surface[r, c] = True
        di, dj, d = self._kernel
        rr = (r[:, None] + di[None, :]).ravel()
        cc = (c[:, None] + dj[None, :]).ravel()
        np.minimum.at(self.dist, (rr, cc), np.broadcast_to(d, (len(r), len(d))).ravel())
        return len(r)

    def sample(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distance (N,) and its gradient (N, 2) at points (N, 2), bilinear between cell centres;
        ``dmax`` and a zero gradient outside the lattice."""
        u = (q[:, 0] - self.origin[0]) / self.res - 0.5
        v = (q[:, 1] - self.origin[1]) / self.res - 0.5
        j0 = np.floor(u).astype(np.int64)
        i0 = np.floor(v).astype(np.int64)
        h, w = self.dist.shape
        ok = (j0 >= 0) & (j0 < w - 1) & (i0 >= 0) & (i0 < h - 1)
        d = np.full(len(q), self.dmax, dtype=np.float64)
        g = np.zeros((len(q), 2), dtype=np.float64)
        if not ok.any():
            return d, g, ok
        j0, i0, fu, fv = j0[ok], i0[ok], (u[ok] - j0[ok]), (v[ok] - i0[ok])
        D = self.dist
        d00, d01, d10, d11 = D[i0, j0], D[i0, j0 + 1], D[i0 + 1, j0], D[i0 + 1, j0 + 1]
        d[ok] = (1 - fv) * ((1 - fu) * d00 + fu * d01) + fv * ((1 - fu) * d10 + fu * d11)
        g[ok, 0] = ((1 - fv) * (d01 - d00) + fv * (d11 - d10)) / self.res
        g[ok, 1] = ((1 - fu) * (d10 - d00) + fu * (d11 - d01)) / self.res
        return d, g, ok

    def score(self, q: np.ndarray, inlier: float) -> float:
        """Fraction of the points (N, 2) within ``inlier`` m of a surface."""
        if len(q) == 0:
            return 0.0
        d, _, _ = self.sample(q)
        return float(np.mean(d < inlier))


# ---------------------------------------------------------------------------------------------
# registration


@dataclass
class Match:
    pose: Pose
    score: float  # fraction of the points within inlier_distance of a surface
    used: int  # points inside the surface distance at the end
    iterations: int


def register(field: SurfaceField, pts: np.ndarray, init: Pose, inlier: float, iterations: int = 10,
             max_step: tuple[float, float] = (0.1, math.radians(3.0)), trim: float | None = None) -> Match:
    """Fit points (N, 2, child frame) to the field's surfaces from ``init`` (child -> map) by
    Gauss-Newton on their distances (points at or beyond ``dmax`` left out), each step limited to
    ``max_step`` (m, rad) and damped in directions the points do not constrain (a corridor's
    length), which then keep ``init``; it stops at a step below 2 mm and 0.01 degree. ``trim``:
    only points nearer than this to a surface pull (default: the field's ``dmax``)."""
    pose = init
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007 - reported
        q = apply(pose, pts)
        d, g, ok = field.sample(q)
        w = ok & (d < (field.dmax if trim is None else min(trim, field.dmax)) * 0.999)
        n = int(w.sum())
        if n < 6:
            break
        qw, gw, r = q[w], g[w], d[w]
        m = qw.mean(0)
        J = np.empty((n, 3))
        J[:, :2] = gw
        J[:, 2] = -gw[:, 0] * (qw[:, 1] - m[1]) + gw[:, 1] * (qw[:, 0] - m[0])
        H = J.T @ J
        spread = float(np.mean(np.sum((qw - m) ** 2, axis=1))) + 1e-6
        H += np.diag([1e-2 * n, 1e-2 * n, 1e-2 * n * spread])
        delta = -np.linalg.solve(H, J.T @ r)
        t = math.hypot(delta[0], delta[1])
        if t > max_step[0]:
            delta[:2] *= max_step[0] / t
        delta[2] = float(np.clip(delta[2], -max_step[1], max_step[1]))
        # rotate by delta[2] about m, then translate: T = (m + dt) R (-m), composed on the left
        c, s = math.cos(delta[2]), math.sin(delta[2])
        step = (m[0] + delta[0] - (c * m[0] - s * m[1]), m[1] + delta[1] - (s * m[0] + c * m[1]), float(delta[2]))
        pose = compose(step, pose)
        if t < 2e-3 and abs(delta[2]) < 2e-4:
            break
    q = apply(pose, pts)
    d, _, _ = field.sample(q)
    return Match(pose, float(np.mean(d < inlier)) if len(q) else 0.0, int(np.sum(d < field.dmax * 0.999)), it)


# ---------------------------------------------------------------------------------------------
# start alignment


@dataclass
class Alignment:
    found: bool
    pose: Pose | None  # map <- child correction at the start
    score: float  # fraction of the first scans' points within inlier_distance of a static wall
    runner_up: float  # the best score of a clearly different candidate (how ambiguous the map is)
    points: int
    seconds: float = 0.0
    message: str = ""


def _fast_len(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n (FFT sizes that pocketfft transforms fastest)."""
    best = 1 << max(n - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def _dilate(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out2 = out.copy()
    out2[:, 1:] |= out[:, :-1]
    out2[:, :-1] |= out[:, 1:]
    return out2


def global_align(pts: np.ndarray, walls_xy: np.ndarray, cfg, field: SurfaceField | None = None) -> Alignment:
    """The correction (child -> map) that best lays points (N, 2, child frame: the first scans in
    odom) on the static walls (M, 2: centres of occupied cells). ``cfg``: a LocalizationConfig.
    ``field``: the walls' SurfaceField at ``cfg.surface_distance`` (built if not given)."""
    import time

    t0 = time.perf_counter()
    pts = downsample(np.asarray(pts, dtype=np.float64).reshape(-1, 2), cfg.resolution)
    if len(pts) < 20 or len(walls_xy) == 0:
        return Alignment(False, None, 0.0, 0.0, len(pts), time.perf_counter() - t0,
                         f"too few points to align ({len(pts)} in the first {cfg.align_window_s:g} s)"
                         if len(walls_xy) else "the static map has no occupied cell")
    if field is None:
        field = SurfaceField.from_points(walls_xy, cfg.resolution, cfg.surface_distance)
    # a wide field for refining the coarse candidates: they are off by up to a coarse cell
    coarse = max(COARSE, float(np.max(walls_xy.max(0) - walls_xy.min(0))) / COARSE_CELLS)
    wide = SurfaceField.from_points(walls_xy, max(cfg.resolution, coarse / 4), max(3 * coarse, cfg.surface_distance))
    centre = pts.mean(0)
    local = pts - centre
    radius = float(np.max(np.hypot(local[:, 0], local[:, 1]))) + coarse
    lo = walls_xy.min(0) - radius - coarse
    hi = walls_xy.max(0) + radius + coarse
    shape = (int(math.ceil((hi[1] - lo[1]) / coarse)) + 1, int(math.ceil((hi[0] - lo[0]) / coarse)) + 1)
    target = np.zeros(shape, dtype=np.float32)
    ij = np.floor((walls_xy - lo) / coarse).astype(np.int64)
    target[ij[:, 1], ij[:, 0]] = 1.0
    target = _dilate(target > 0).astype(np.float32)
    shape = (_fast_len(shape[0]), _fast_len(shape[1]))
    target = np.pad(target, ((0, shape[0] - target.shape[0]), (0, shape[1] - target.shape[1])))
    spec = np.fft.rfft2(target)
    n_r = int(math.ceil(2 * radius / coarse)) + 1
    found: list[tuple[float, float, float, float]] = []  # (corr score, yaw, x, y)
    for yaw in np.radians(np.arange(0.0, 360.0, cfg.align_yaw_step_deg)):
        c, s = math.cos(yaw), math.sin(yaw)
        rot = np.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]], axis=1)
        jj = np.floor((rot + radius) / coarse).astype(np.int64)
        img = np.zeros((n_r, n_r), dtype=np.float32)
        img[jj[:, 1], jj[:, 0]] = 1.0
        npts = float(img.sum())
        corr = np.fft.irfft2(spec * np.conj(np.fft.rfft2(img, s=shape)), s=shape)
        # a peak at (dy, dx): img shifted by it lies on the walls; keep the best few per yaw
        flat = np.argpartition(corr.ravel(), -3)[-3:]
        for k in flat:
            dy, dx = divmod(int(k), shape[1])
            x = lo[0] + dx * coarse + radius - centre[0] * c + centre[1] * s
            y = lo[1] + dy * coarse + radius - centre[0] * s - centre[1] * c
            # the rotation about the origin that the coarse image used: map = R(yaw) p + (x, y)
            found.append((float(corr.ravel()[k]) / npts, float(yaw), float(x), float(y)))
    found.sort(key=lambda f: -f[0])
    picked: list[tuple[float, float, float, float]] = []
    for f in found:
        if all(abs(wrap(f[1] - p[1])) > math.radians(5) or math.hypot(f[2] - p[2], f[3] - p[3]) > 0.5
               for p in picked):
            picked.append(f)
        if len(picked) >= CANDIDATES:
            break
    results = []
    for _, yaw, x, y in picked:
        m = register(wide, pts, (x, y, yaw), cfg.inlier_distance, iterations=30)
        m = register(field, pts, m.pose, cfg.inlier_distance, iterations=30)
        # then only the points on walls pull: clutter near the walls does not drag the fit
        m = register(field, pts, m.pose, cfg.inlier_distance, iterations=30, trim=cfg.inlier_distance)
        results.append(m)
    results.sort(key=lambda m: -m.score)
    best = results[0]
    others = [m.score for m in results[1:]
              if pose_change(best.pose, m.pose, centre)[0] > 0.5 or pose_change(best.pose, m.pose, centre)[1]
              > math.radians(5)]  # fmt: skip
    runner = max(others) if others else 0.0
    x, y, yaw = best.pose
    msg = (f"aligned to the static map: map -> odom x {x:.3f} m, y {y:.3f} m, yaw {math.degrees(yaw):.2f} deg, "
           f"{100 * best.score:.0f} % of the first scans' points on its walls (next best alignment "
           f"{100 * runner:.0f} %)")
    ok = False
    if best.score < cfg.align_min_score:
        msg = (f"cannot align the log to the static map: at best {100 * best.score:.0f} % of the first "
               f"{cfg.align_window_s:g} s of scans lie on its walls (needs {100 * cfg.align_min_score:.0f} %); "
               f"a map of another place? Using the recorded poses")
    elif best.score - runner < cfg.align_min_margin:
        msg = (f"cannot align the log to the static map: two different alignments fit about as well "
               f"({100 * best.score:.0f} % and {100 * runner:.0f} % of the first {cfg.align_window_s:g} s of "
               f"scans on its walls); a map of another place, or a symmetric one? Using the recorded poses")
    else:
        ok = True
    return Alignment(ok, best.pose, best.score, runner, len(pts), time.perf_counter() - t0, msg)


# ---------------------------------------------------------------------------------------------
# tracking along the log


@dataclass
class Step:
    correction: Pose  # the correction applied to this scan
    score: float  # match score of the scan (before the step limit); nan when not matched
    accepted: bool
    reason: str = ""  # why it was rejected


@dataclass
class Tracker:
    """Scan-to-map registration along a log. ``field``: the static map's SurfaceField (its
    surfaces), or None to build the map from the scans alone. ``odometry``: whether the scans'
    child frame is odom (the correction changes slowly, step-limited) or the robot's own frame
    (the correction is its pose; predicted at constant velocity)."""

    cfg: object
    odometry: bool
    field: SurfaceField | None = None
    correction: Pose = (0.0, 0.0, 0.0)
    rejected: int = 0
    accepted: int = 0
    scores: list = dc_field(default_factory=list)
    _prev: tuple | None = None  # (stamp ns, correction) of the scan before the last
    _last: tuple | None = None  # (stamp ns, correction) of the last scan
    _started: bool = False  # the field has a surface to match against

    def __post_init__(self):
        c = self.cfg
        if self.field is None:
            self.field = SurfaceField(c.resolution, c.surface_distance, min_hits=c.map_min_hits)
        else:
            # the static walls anchor the match: what the scans see near them adds no surface (a
            # wall seen a little off would otherwise pull the following scans with it)
            self.field.min_hits = c.map_min_hits
            self.field.locked |= self.field.dist < self.field.dmax

    def _predict(self, stamp_ns: int) -> Pose:
        if self.odometry or self._last is None:
            return self.correction
        if self._prev is None:
            return self._last[1]
        (t0, a), (t1, b) = self._prev, self._last
        if t1 <= t0:
            return b
        f = min((stamp_ns - t1) / (t1 - t0), 3.0)
        d = compose(invert(a), b)
        return compose(b, (d[0] * f, d[1] * f, d[2] * f))

    def step(self, stamp_ns: int, pts: np.ndarray, sensor_xy: np.ndarray) -> Step:
        """One scan: points (N, 2) and the laser's position (2,) in the child frame."""
        c = self.cfg
        pred = self._predict(stamp_ns)
        if not self._started:
            self._started = bool(self.field.surface.any())
        if not self._started:  # nothing to match against yet: this scan starts the map
            out = Step(pred, float("nan"), True, "")
            self.field.add_hits(apply(pred, pts), weight=c.map_min_hits)
        else:
            m = register(self.field, pts, pred, c.inlier_distance)
            dm, dr = pose_change(pred, m.pose, sensor_xy)
            reason = ""
            if m.score < c.min_score:
                reason = "score"
            elif dm > c.max_jump_m or dr > math.radians(c.max_jump_deg):
                reason = "jump"
            if reason:
                out = Step(pred, m.score, False, reason)
            else:
                new = m.pose
                if self.odometry:
                    new = toward(pred, m.pose, sensor_xy, c.max_step_m, math.radians(c.max_step_deg))
                out = Step(new, m.score, True, "")
                self.field.add_hits(apply(new, pts))
        if out.accepted:
            self.accepted += 1
        else:
            self.rejected += 1
        self.scores.append(out.score)
        self.correction = out.correction
        self._prev, self._last = self._last, (stamp_ns, out.correction)
        return out
