"""Sensor models: where each sensor is, which rays it casts, and what it reports.

Frames (REP 103 / 105): ``map -> odom -> base_link`` from the robot's path; sensors are mounted on
``base_link`` with ``xyz`` and ``rpy`` (degrees). The depth camera is ``base_link -> camera_link``
(x forward, with ``pitch`` degrees of downward tilt added to the mount's pitch) ``->`` the optical
frame (z forward, x right, y down). Renders here are noise-free; ``simulate`` adds the noise.
"""

from __future__ import annotations

import math

import numpy as np

from .scenario import Depth, Laser, Mount, Points
from .scene import Primitives

# camera_link (x forward, y left, z up) -> optical (z forward, x right, y down): columns are the
# optical axes in camera_link coordinates
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), angles in radians (ROS's fixed-axis roll, pitch, yaw)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def quat_from_matrix(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix, w >= 0."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    if q[3] < 0:
        q = tuple(-v for v in q)
    n = math.sqrt(sum(v * v for v in q))
    return tuple(float(v / n) for v in q)  # type: ignore[return-value]


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def mount_matrix(m: Mount, extra_pitch_deg: float = 0.0) -> np.ndarray:
    """4x4 transform base_link -> sensor frame."""
    r, p, y = (math.radians(a) for a in m.rpy_deg)
    T = np.eye(4)
    T[:3, :3] = rpy_matrix(r, p + math.radians(extra_pitch_deg), y)
    T[:3, 3] = m.xyz
    return T


def base_matrix(x: float, y: float, yaw: float) -> np.ndarray:
    """4x4 transform map -> base_link for a planar pose (yaw in radians)."""
    T = np.eye(4)
    T[:3, :3] = rpy_matrix(0.0, 0.0, yaw)
    T[:2, 3] = (x, y)
    return T


# ----------------------------------------------------------------------------- laser


def laser_angles(L: Laser) -> tuple[float, float, np.ndarray]:
    """(angle_min, angle_increment, angles): a full circle splits 2 pi into ``beams`` steps;
    a partial field of view spans it end to end."""
    fov = math.radians(L.fov_deg)
    if L.fov_deg >= 360.0:
        inc = 2 * math.pi / L.beams
        amin = -math.pi
    else:
        inc = fov / max(L.beams - 1, 1)
        amin = -fov / 2
    return amin, inc, amin + inc * np.arange(L.beams, dtype=np.float64)


def render_scan(prims: Primitives, L: Laser, pose: tuple[float, float, float]) -> np.ndarray:
    """Exact ranges (float64, +inf where nothing is hit) of a laser at robot pose (x, y, yaw)."""
    T = base_matrix(*pose) @ mount_matrix(L.mount)
    _, _, a = laser_angles(L)
    local = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    return prims.cast(T[:3, 3], local @ T[:3, :3].T)


# ----------------------------------------------------------------------------- depth camera


def optical_matrix(D: Depth) -> np.ndarray:
    """4x4 transform base_link -> optical frame."""
    T = mount_matrix(D.mount, D.pitch_deg)
    O = np.eye(4)
    O[:3, :3] = R_LINK_OPTICAL
    return T @ O


def pixel_rays(D: Depth) -> np.ndarray:
    """(H*W, 3) rays in the optical frame with z = 1, row-major from the top-left pixel."""
    v, u = np.mgrid[0 : D.height, 0 : D.width].astype(np.float64)
    return np.column_stack([((u - D.cx) / D.fx).ravel(), ((v - D.cy) / D.fy).ravel(), np.ones(u.size)])


def render_depth(
    prims: Primitives, D: Depth, pose: tuple[float, float, float], rays: np.ndarray | None = None
) -> np.ndarray:
    """Exact z-depth (H, W) float64 in metres, +inf where nothing is hit."""
    T = base_matrix(*pose) @ optical_matrix(D)
    r = pixel_rays(D) if rays is None else rays
    return prims.cast(T[:3, 3], r @ T[:3, :3].T).reshape(D.height, D.width)


# a depth edge: neighbouring pixels whose depths differ by more than this share of the nearer
# (a stereo or structured-light camera loses the pixels there: occlusion shadows, mixed pixels)
EDGE_JUMP = 0.05


def _jumps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Neighbours ``a``, ``b`` across a depth edge: one with a return and one without, or depths
    differing by more than ``EDGE_JUMP`` of the nearer."""
    fa, fb = np.isfinite(a), np.isfinite(b)
    with np.errstate(invalid="ignore"):
        return (fa != fb) | (fa & fb & (np.abs(a - b) > EDGE_JUMP * np.minimum(a, b)))


def depth_edges(z: np.ndarray, width: int) -> np.ndarray:
    """(H, W) bool: the pixels of z-depth ``z`` (inf or NaN: no return) within ``width`` pixels
    of a depth edge along rows and columns; 1: the two pixels at each edge, 2: and one more on
    each side."""
    jx, jy = _jumps(z[:, 1:], z[:, :-1]), _jumps(z[1:, :], z[:-1, :])
    edge = np.zeros(z.shape, dtype=bool)
    edge[:, 1:] |= jx
    edge[:, :-1] |= jx
    edge[1:, :] |= jy
    edge[:-1, :] |= jy
    grown = edge.copy()
    for d in range(1, width):
        grown[:, d:] |= edge[:, :-d]
        grown[:, :-d] |= edge[:, d:]
        grown[d:, :] |= edge[:-d, :]
        grown[:-d, :] |= edge[d:, :]
    return grown


# ----------------------------------------------------------------------------- 3D lidar


def points_rays(P: Points) -> np.ndarray:
    """(channels * beams, 3) unit rays in the sensor frame."""
    el = np.radians(np.linspace(P.vfov_deg[0], P.vfov_deg[1], P.channels))
    az = -math.pi + 2 * math.pi / P.beams * np.arange(P.beams)
    E, A = np.meshgrid(el, az, indexing="ij")
    return np.column_stack(
        [(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()]
    )


def render_points(
    prims: Primitives, P: Points, pose: tuple[float, float, float], rays: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(ranges, unit rays in the sensor frame) of a multi-channel lidar."""
    T = base_matrix(*pose) @ mount_matrix(P.mount)
    r = points_rays(P) if rays is None else rays
    return prims.cast(T[:3, 3], r @ T[:3, :3].T), r
