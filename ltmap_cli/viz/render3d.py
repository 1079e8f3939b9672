"""A 3D picture of a voxel map (``map_3d.png``, SPEC 6).

``render_map_3d`` draws the voxels as cubes coloured by height (the static layer in grey). It
tries open3d's offscreen renderer first; that needs a working EGL / OSMesa / Vulkan stack and,
on a headless machine without one, raises or even kills the process. So whether it works is
probed once per process in a child process (``open3d_offscreen_available``, cached), and when it
does not the picture is drawn with matplotlib's 3D axes instead (Agg canvas, no pyplot).

Only the faces between an occupied voxel and a free one are drawn (a solid block of voxels costs
its surface, not its volume). Above ``max_faces`` faces the matplotlib view draws square markers
instead of cubes, and above ``max_points`` voxels the map is first merged onto a coarser grid
(a multiple of the resolution) so that the picture keeps the map's shape.

So that the walls do not hide the objects, the static layer (the building's walls) is drawn only
up to ``wall_cut_z`` (0.3 m: the rooms' outline), and without a static layer the long-term voxels
above that height in a band along the two sides of the map nearest the viewer (where the front
walls are) are left out; the title says what is cut. The z axis starts at the floor; a map of
one height (a 2D laser alone) gets a legend entry for its height instead of a colour bar.

The environment variable ``LTMAP_RENDER3D`` (``open3d`` | ``matplotlib``) forces a renderer;
``renderer=`` does the same per call.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

STATIC_RGB = (0.62, 0.62, 0.62)
HEIGHT_CMAP = "viridis"  # perceptually uniform, colour-blind safe
MAX_POINTS = 50_000
MAX_FACES = 40_000
PROBE_TIMEOUT_S = 60.0
WALL_CUT_Z = 0.3  # m: walls are drawn up to this height
FRONT_BAND = 0.4  # m: without a static layer, voxels this close to the near sides are cut like walls
VIEW_ELEV, VIEW_AZIM = 42, -60  # the matplotlib view: the viewer stands at low y and high x

# face directions and the brightness each one gets (a fixed light from above, front-left)
_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
_SHADE = np.array([0.78, 0.62, 0.70, 0.88, 1.0, 0.45])
# the four corners of each face of the unit cube centred at 0, counter-clockwise seen from outside
_FACE_CORNERS = (
    np.array(
        [
            [[1, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1]],
            [[-1, 1, -1], [-1, -1, -1], [-1, -1, 1], [-1, 1, 1]],
            [[1, 1, -1], [-1, 1, -1], [-1, 1, 1], [1, 1, 1]],
            [[-1, -1, -1], [1, -1, -1], [1, -1, 1], [-1, -1, 1]],
            [[-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]],
            [[-1, 1, -1], [1, 1, -1], [1, -1, -1], [-1, -1, -1]],
        ],
        dtype=float,
    )
    * 0.5
)

_PROBE_CODE = """
import numpy as np
import open3d as o3d
r = o3d.visualization.rendering.OffscreenRenderer(64, 48)
m = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
m.compute_vertex_normals()
mat = o3d.visualization.rendering.MaterialRecord()
mat.shader = "defaultLit"
r.scene.add_geometry("box", m, mat)
r.setup_camera(60.0, [0.5, 0.5, 0.5], [3.0, 3.0, 3.0], [0.0, 0.0, 1.0])
img = np.asarray(r.render_to_image())
assert img.shape[:2] == (48, 64), img.shape
assert img.std() > 0, "blank image"
print("LTMAP_O3D_OK")
"""

_probe_cache: bool | None = None
_probe_proc: subprocess.Popen | None = None


def _launch_probe() -> subprocess.Popen | None:
    try:
        return subprocess.Popen([sys.executable, "-c", _PROBE_CODE], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})  # fmt: skip
    except OSError:
        return None


def start_probe() -> None:
    """Start the probe of ``open3d_offscreen_available`` in the background (a replay does so at
    its start, so that the 1 to 2 s the child takes overlap the mapping instead of the plots);
    not when ``LTMAP_RENDER3D=matplotlib`` says its answer will not be asked."""
    global _probe_proc
    if _probe_cache is not None or _probe_proc is not None or os.environ.get("LTMAP_RENDER3D") == "matplotlib":
        return
    _probe_proc = _launch_probe()


def open3d_offscreen_available(refresh: bool = False) -> bool:
    """Whether open3d's OffscreenRenderer can render here. Probed once per process in a child
    Python (a missing EGL may segfault it), then cached; the answer of a probe started with
    ``start_probe`` is used when there is one."""
    global _probe_cache, _probe_proc
    if _probe_cache is not None and not refresh:
        return _probe_cache
    proc, _probe_proc = _probe_proc, None
    if proc is not None and refresh:  # a probe started before: asked afresh
        proc.kill()
        proc.communicate()
        proc = None
    proc = proc or _launch_probe()
    if proc is None:
        _probe_cache = False
        return _probe_cache
    try:
        out, _ = proc.communicate(timeout=PROBE_TIMEOUT_S)
        _probe_cache = proc.returncode == 0 and "LTMAP_O3D_OK" in out
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        _probe_cache = False
    return _probe_cache


def _keys(ijk: np.ndarray) -> np.ndarray:
    """int64 keys of integer voxel indices (21 bits per axis, offset so negatives work)."""
    v = ijk.astype(np.int64) + (1 << 20)
    return (v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2]


def _index(centers: np.ndarray, resolution: float) -> np.ndarray:
    return np.floor(centers / resolution).astype(np.int64)


def merge(centers: np.ndarray, size: float, values: np.ndarray | None = None):
    """The distinct voxels of edge ``size`` that hold ``centers`` (their centres), and the mean
    of ``values`` in each (None without values)."""
    c = np.asarray(centers, dtype=float).reshape(-1, 3)
    if not len(c):
        return c, (None if values is None else np.zeros(0))
    ijk, inverse = np.unique(_index(c, size), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    v = None
    if values is not None:
        v = np.bincount(inverse, weights=values, minlength=len(ijk)) / np.bincount(
            inverse, minlength=len(ijk)
        )
    return (ijk + 0.5) * size, v


def coarsen(centers, static_centers, resolution: float, max_points: int = MAX_POINTS, values=None):
    """Merge both voxel sets onto the grid ``k * resolution`` with the smallest k (1, 2, 3, ...)
    that leaves at most ``max_points`` voxels in all; a voxel in both sets stays only in the
    static one. Returns (centers, values, static centers, k)."""
    k = 1
    while True:
        size = k * resolution
        c, v = merge(centers, size, values)
        s, _ = merge(static_centers, size)
        if len(c) and len(s):
            dyn = ~np.isin(_keys(_index(c, size)), _keys(_index(s, size)))
            c, v = c[dyn], (None if v is None else v[dyn])
        if len(c) + len(s) <= max_points:
            return c, v, s, k
        k = max(k + 1, int(k * (((len(c) + len(s)) / max_points) ** (1 / 3))))


def visible_faces(centers: np.ndarray, resolution: float):
    """Faces of the voxels at ``centers`` that do not touch another of these voxels.

    Returns (voxel index (F,), face direction 0..5 (F,))."""
    ijk = _index(centers, resolution)
    keys = _keys(ijk)
    vox, dirs = [], []
    for d, step in enumerate(_DIRS):
        free = ~np.isin(_keys(ijk + step), keys)
        idx = np.nonzero(free)[0]
        vox.append(idx)
        dirs.append(np.full(len(idx), d))
    return np.concatenate(vox), np.concatenate(dirs)


def cutaway(centers, values, static_centers, resolution: float, cut_z: float = WALL_CUT_Z,
            band: float = FRONT_BAND):  # fmt: skip
    """(centers, values, static centers, what was cut: a phrase for the title or ""): static voxels
    above ``cut_z`` left out; without static voxels, the voxels above ``cut_z`` within ``band`` of
    the two sides of the map nearest the viewer (low y, high x; the front walls) left out."""
    c = np.asarray(centers, dtype=float).reshape(-1, 3)
    v = None if values is None else np.asarray(values, dtype=float).ravel()
    s = None if static_centers is None else np.asarray(static_centers, dtype=float).reshape(-1, 3)
    cut = c[:, 2] - resolution / 2 >= cut_z - 1e-9  # a voxel whose bottom is at or above the cut
    if s is not None and len(s):
        s = s[s[:, 2] - resolution / 2 < cut_z - 1e-9]
        return c, v, s, f"static walls (grey) cut at {cut_z:g} m"
    if not len(c) or np.ptp(c[:, 0]) < 4 * band or np.ptp(c[:, 1]) < 4 * band:
        return c, v, s, ""
    front = (c[:, 1] <= c[:, 1].min() + band) | (c[:, 0] >= c[:, 0].max() - band)
    drop = cut & front
    if not drop.any():
        return c, v, s, ""
    return c[~drop], (None if v is None else v[~drop]), s, f"front walls cut at {cut_z:g} m"


def _prepare(centers, values, static_centers, resolution, color_by, max_points):
    """Voxel centres, RGB colours (N, 3) and the colour scale of the picture."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    c = np.asarray(centers, dtype=float).reshape(-1, 3)
    v = None if values is None else np.asarray(values, dtype=float).ravel()
    if v is not None and len(v) != len(c):
        raise ValueError(f"{len(v)} values for {len(c)} voxels")
    keep = np.all(np.isfinite(c), axis=1)
    c, v = c[keep], (None if v is None else v[keep])
    s = np.zeros((0, 3)) if static_centers is None else np.asarray(static_centers, dtype=float).reshape(-1, 3)
    s = s[np.all(np.isfinite(s), axis=1)]
    c, v, s, k = coarsen(c, s, resolution, max_points, v)
    if color_by == "value" and v is not None:
        scalar, label = v, "value"
    else:
        scalar, label = c[:, 2], "height z [m]"
    lo, hi = (float(scalar.min()), float(scalar.max())) if len(scalar) else (0.0, 1.0)
    if hi <= lo:  # one value: the colour bar gives way to a legend entry (see _render_matplotlib)
        hi = lo + 1e-9
    norm = Normalize(lo, hi)
    cmap = colormaps[HEIGHT_CMAP]
    rgb = (
        np.vstack([cmap(norm(scalar))[:, :3], np.tile(STATIC_RGB, (len(s), 1))])
        if len(c) + len(s)
        else np.zeros((0, 3))
    )
    allc = np.vstack([c, s]) if len(s) else c
    return allc, rgb, len(s), (cmap, norm, label), k


def _quads(centers, rgb, size):
    """Quads (F, 4, 3) of the visible faces of cubes of edge ``size`` and their shaded colours."""
    vox, dirs = visible_faces(centers, size)
    quads = centers[vox][:, None, :] + _FACE_CORNERS[dirs] * size
    colours = np.clip(rgb[vox] * _SHADE[dirs][:, None], 0, 1)
    return quads, colours, dirs


def _render_matplotlib(path, centers, rgb, n_static, scale, size, title, width, height) -> None:
    from ..io.atomic import atomic_path

    fig = _matplotlib_figure(centers, rgb, n_static, scale, size, title, width, height)
    with atomic_path(path) as tmp:  # no tight bbox: the picture keeps the asked width x height
        fig.savefig(tmp, format="png", dpi=fig.dpi)


def _matplotlib_figure(centers, rgb, n_static, scale, size, title, width, height):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.02, 0.86, 0.92), projection="3d")
    ax.view_init(elev=VIEW_ELEV, azim=VIEW_AZIM)
    if len(centers):
        lo = centers.min(axis=0) - size / 2
        hi = centers.max(axis=0) + size / 2
        quads, colours, _dirs = _quads(centers, rgb, size)
        pc = Poly3DCollection(quads, facecolors=colours, edgecolors=colours * 0.8, linewidths=0.15)
        ax.add_collection3d(pc)
    else:
        lo, hi = np.zeros(3), np.ones(3)
        ax.text2D(0.5, 0.5, "empty map", transform=ax.transAxes, ha="center", color="0.4", style="italic")
    lo[2] = min(lo[2], 0.0)  # z from the floor: a laser-only map is a layer at the laser's height
    hi[2] = max(hi[2], lo[2] + 0.5)
    span = np.maximum(hi - lo, size)
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(tuple(span / span.max()), zoom=0.95)
    ax.zaxis.set_major_locator(MaxNLocator(nbins=max(2, min(6, round(8 * span[2] / span.max()) + 1)),
                                           steps=[1, 2, 2.5, 5, 10]))  # fmt: skip
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.xaxis.pane.set_facecolor((0.96, 0.96, 0.96, 1.0))
    ax.yaxis.pane.set_facecolor((0.96, 0.96, 0.96, 1.0))
    ax.zaxis.pane.set_facecolor((0.93, 0.93, 0.93, 1.0))
    ax.set_title(title or "3D map")
    cmap, norm, label = scale
    n_dyn = len(centers) - n_static
    handles = []
    if n_dyn and norm.vmax - norm.vmin > 1e-6:
        sm = ScalarMappable(norm=norm, cmap=cmap)
        cax = fig.add_axes((0.88, 0.25, 0.018, 0.5))
        fig.colorbar(sm, cax=cax, label=label)
    elif n_dyn:  # one height (or value): a colour bar would span nothing
        what = "height" if label.startswith("height") else "value"
        at = f"z = {norm.vmin:.2f} m" if what == "height" else f"value {norm.vmin:.2f}"
        handles.append(Patch(facecolor=rgb[0], edgecolor="0.4", label=f"long-term voxels ({at})"))
    if n_static:
        handles.append(Patch(facecolor=STATIC_RGB, edgecolor="0.4", label="static layer"))
    if handles:
        ax.legend(handles=handles, loc="upper left", fontsize="small", frameon=False)
    return fig


def _render_open3d(path, centers, rgb, size, width, height) -> None:
    """The voxels' visible faces as one unlit, vertex-coloured mesh (open3d draws no text)."""
    import open3d as o3d
    import open3d.visualization.rendering as rendering

    from ..io.atomic import atomic_path

    quads, colours, _dirs = _quads(centers, rgb, size)
    f = len(quads)
    verts = quads.reshape(-1, 3)
    base = np.arange(f)[:, None] * 4
    tris = np.vstack([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.int32)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(tris))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.repeat(colours, 4, axis=0))
    r = rendering.OffscreenRenderer(int(width), int(height))
    mat = rendering.MaterialRecord()
    mat.shader = "defaultUnlit"  # the faces carry their own shading
    r.scene.set_background([1.0, 1.0, 1.0, 1.0])
    r.scene.add_geometry("map", mesh, mat)
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    mid = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2 + size
    eye = mid + radius * np.array([-1.1, -1.6, 1.3])
    r.setup_camera(50.0, mid.tolist(), eye.tolist(), [0.0, 0.0, 1.0])
    img = r.render_to_image()
    if np.asarray(img).std() == 0:
        raise RuntimeError("open3d rendered a blank image")
    with atomic_path(path) as tmp:
        if not o3d.io.write_image(str(tmp), img):
            raise RuntimeError("open3d could not write the image")


def _cut_and_title(centers, values, static_centers, resolution, title, color_by):
    """``cutaway``'s voxels, and the title: the caller's, or one that says what is shown; either
    way it says what was cut."""
    centers, values, static_centers, cut = cutaway(centers, values, static_centers, resolution)
    if not title:
        coloured = "by value" if color_by == "value" and values is not None else "by height"
        title = f"final map: long-term voxels coloured {coloured}" if len(centers) else "final map: no long-term voxels"
        if cut:
            title += f"; {cut}"
    elif cut:
        title += f" ({cut})"
    return centers, values, static_centers, title


def figure_3d(centers, values, resolution: float, *, static_centers=None, title: str | None = None,
              width: int = 1280, height: int = 960, color_by: str = "height", max_points: int = MAX_POINTS):  # fmt: skip
    """The matplotlib figure ``render_map_3d`` draws (without merging for ``max_faces``)."""
    centers, values, static_centers, title = _cut_and_title(centers, values, static_centers, resolution, title,
                                                           color_by)  # fmt: skip
    allc, rgb, n_static, scale, k = _prepare(centers, values, static_centers, resolution, color_by, max_points)
    return _matplotlib_figure(allc, rgb, n_static, scale, k * resolution, title, width, height)


def render_map_3d(
    path_png: Path,
    centers: np.ndarray,
    values: np.ndarray | None,
    resolution: float,
    *,
    static_centers: np.ndarray | None = None,
    title: str | None = None,
    width: int = 1280,
    height: int = 960,
    renderer: str = "auto",
    color_by: str = "height",
    max_points: int = MAX_POINTS,
    max_faces: int = MAX_FACES,
) -> str:
    """Write a 3D picture of a voxel map to ``path_png`` (atomically) and return the renderer
    used, ``"open3d"`` or ``"matplotlib"``.

    ``centers`` (N, 3) voxel centres in metres, coloured by height (viridis) or, with
    ``color_by="value"``, by ``values`` (N,); ``static_centers`` (M, 3) are drawn grey (a voxel in
    both is drawn once, grey). ``renderer``: ``auto`` (open3d when the probe says its offscreen
    renderer works, else matplotlib; ``LTMAP_RENDER3D`` overrides) or ``matplotlib``; ``open3d``
    is the same as ``auto``: open3d is never used in-process unless the probe passed, and if it
    fails after all, matplotlib draws the picture. Above ``max_points`` voxels both sets are
    merged onto a coarser grid (the title says so). Walls are cut (``cutaway``). Without a
    ``title`` the picture's says what it shows."""
    if resolution <= 0 or not math.isfinite(resolution):
        raise ValueError(f"resolution must be > 0, got {resolution}")
    centers, values, static_centers, title = _cut_and_title(centers, values, static_centers, resolution, title,
                                                           color_by)  # fmt: skip
    choice = renderer if renderer != "auto" else os.environ.get("LTMAP_RENDER3D", "auto")
    if choice not in ("auto", "open3d", "matplotlib"):
        raise ValueError(f"unknown renderer {choice!r}")
    args = (centers, values, static_centers, resolution, color_by)
    # even when open3d is asked for, the probe guards the process against a crashing EGL
    if choice != "matplotlib" and open3d_offscreen_available():
        allc, rgb, _n_static, _scale, k = _prepare(*args, max_points)
        if len(allc):
            try:
                _render_open3d(path_png, allc, rgb, k * resolution, width, height)
                return "open3d"
            except Exception:  # noqa: BLE001 - any failure of the GPU path falls back to matplotlib
                pass
    # matplotlib sorts and draws every face: merge until the faces are few enough
    allc, rgb, n_static, scale, k = _prepare(*args, max_points)
    while len(allc) and len(visible_faces(allc, k * resolution)[0]) > max_faces:
        allc, rgb, n_static, scale, k = _prepare(*args, max(int(len(allc) * 0.6), 1))
    size = k * resolution
    if k > 1:
        title = f"{title} (merged to {size:g} m voxels)" if title else f"merged to {size:g} m voxels"
    _render_matplotlib(path_png, allc, rgb, n_static, scale, size, title, width, height)
    return "matplotlib"
