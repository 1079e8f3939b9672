"""Read an SVG floor plan into shapely geometry in metres, in the map frame.

svgelements resolves transforms, nested groups, ``<use>``, units and arcs into viewport pixels;
this module undoes the root viewport transform to get SVG user units, applies the plan's scale
(metres per user unit), flips y (SVG y points down, the map's y up) so that the plan's lower-left
corner is map (0, 0), then applies ``--origin x,y,yaw``.

Conventions (see docs/plans.md):

- Scale, first that applies: ``--scale`` metres per user unit; the root ``width``/``height`` in
  mm, cm, m, in, pt or pc against the ``viewBox``; an element ``id="scale"`` with
  ``data-length-m`` (its drawn length is that many metres).
- Layers: a ``<g>`` whose ``id`` or ``inkscape:label`` is walls, doors, windows or furniture
  (any case). Without a named layer every shape is a wall; with one, shapes outside the named
  layers are ignored (annotations, dimensions).
- A stroke becomes the polygon it paints (caps, joins and mitre limit from the SVG, whose defaults
  are flat caps and mitre joins), its width the stroke width after transforms. Hairlines (width 0,
  no stroke-width set anywhere, Inkscape's hairline or ``vector-effect: non-scaling-stroke``) get
  ``--wall-thickness``. A filled closed (sub)path is solid (fill-rule honoured). A shape with
  neither a visible stroke nor a fill counts as a hairline.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import PlanError

LAYERS = ("walls", "doors", "windows", "furniture")
INKSCAPE_LABEL = "{http://www.inkscape.org/namespaces/inkscape}label"
# metres per unit of the root width/height ("m" is not CSS, but people write it)
PHYSICAL_UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "pt": 0.0254 / 72, "pc": 0.0254 / 6}
ELEMENT_UNITS = {"", "px", "mm", "cm", "in", "pt", "pc", "%", "em", "ex"}
LENGTH_ATTRS = ("x", "y", "x1", "y1", "x2", "y2", "width", "height", "r", "rx", "ry", "cx", "cy",
                "stroke-width")
SIZE_ATTRS = ("width", "height", "r", "rx", "ry", "stroke-width")  # negative: invalid SVG
NUMBER_ATTRS = ("d", "points", "transform") + LENGTH_ATTRS
_LENGTH_RE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z%]*)\s*$")
_NONFINITE_RE = re.compile(r"(?i)nan|inf")
CURVE_STEP_M = 0.02  # chord length when flattening arcs and Beziers


@dataclass
class Stroke:
    line: np.ndarray  # (N, 2) centre line, metres, map frame
    width: float  # metres
    closed: bool


@dataclass
class PlanShape:
    """One SVG shape, in metres in the map frame."""

    element: str  # for messages: 'id="w3"' or '<line> #4'
    layer: str  # walls | doors | windows | furniture
    region: object  # shapely (Multi)Polygon painted by fill and stroke (may be empty)
    fill: object  # shapely geometry of the filled part, or None
    strokes: list[Stroke] = field(default_factory=list)
    height_m: float | None = None  # data-height-m (furniture)


@dataclass
class Plan:
    source: str
    shapes: list[PlanShape]
    canvas: tuple[float, float, float, float] | None  # bounds of the SVG canvas in the map frame
    metres_per_unit: float
    scale_source: str  # "--scale" | "width/height" | "scale element"
    named_layers: bool
    ignored: int  # shapes outside any named layer (only when named layers exist)

    def of(self, *layers: str) -> list[PlanShape]:
        return [s for s in self.shapes if s.layer in layers]


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _describe_xml(el, counters: dict[str, int]) -> str:
    tag = _local(el.tag)
    if el.get("id"):
        return f'<{tag} id="{el.get("id")}">'
    return f"<{tag}> #{counters.get(tag, 0)} (no id)"


def _parse_length(text: str | None, where: str, source: str, units: set[str] | dict) -> tuple[float, str] | None:
    if text is None or text.strip().lower() in ("auto", "inherit", "initial", ""):
        return None
    m = _LENGTH_RE.match(text)
    if not m:
        raise PlanError(f"{source}: {where} has the value {text!r}, which is not a length; "
                        "write a number with a unit such as 12.5mm")
    value, unit = float(m.group(1)), m.group(2).lower()
    if unit not in units:
        known = ", ".join(sorted(u for u in units if u)) if isinstance(units, dict) else "px, mm, cm, in, pt, pc, %"
        raise PlanError(f"{source}: {where} has the unknown unit {m.group(2)!r} in {text!r}; "
                        f"use one of {known}")
    if not math.isfinite(value):
        raise PlanError(f"{source}: {where} is not a finite number ({text!r}); fix the value")
    return value, unit


def _prescan(root, source: str) -> None:
    """Check what svgelements would silently accept: unknown units and NaN / inf numbers."""
    counters: dict[str, int] = {}
    for el in root.iter():
        tag = _local(el.tag)
        counters[tag] = counters.get(tag, 0) + 1
        if el is root:
            continue
        style = {}
        for item in (el.get("style") or "").split(";"):
            if ":" in item:
                k, v = item.split(":", 1)
                style[k.strip()] = v.strip()
        for name in NUMBER_ATTRS:
            value = el.get(name)
            if value is None and name == "stroke-width":
                value = style.get("stroke-width")
            if value is None:
                continue
            if _NONFINITE_RE.search(value):
                raise PlanError(f"{source}: {_describe_xml(el, counters)} has a NaN or infinite number in "
                                f"its {name} ({value[:60]!r}); fix the coordinates in the drawing")
            if name in LENGTH_ATTRS and tag not in ("svg", "image", "pattern", "mask", "filter",
                                                    "marker", "symbol", "clipPath"):
                parsed = _parse_length(value, f"{_describe_xml(el, counters)} attribute {name}", source,
                                       ELEMENT_UNITS)  # fmt: skip
                if parsed is not None and parsed[0] < 0 and name in SIZE_ATTRS:
                    raise PlanError(f"{source}: {_describe_xml(el, counters)} has a negative {name} ({value!r}), "
                                    "which SVG does not allow; fix the shape in the drawing")


def _root_dims(root, source: str):
    """(width (value, unit) or None, height likewise, viewBox (x, y, w, h) or None)."""
    width = _parse_length(root.get("width"), "the root <svg> width", source, {**PHYSICAL_UNITS, "": 0, "px": 0, "%": 0})
    height = _parse_length(root.get("height"), "the root <svg> height", source,
                           {**PHYSICAL_UNITS, "": 0, "px": 0, "%": 0})
    vb = root.get("viewBox")
    viewbox = None
    if vb is not None:
        if _NONFINITE_RE.search(vb):
            raise PlanError(f"{source}: the root <svg> viewBox {vb!r} has a NaN or infinite number; fix it")
        try:
            parts = [float(v) for v in vb.replace(",", " ").split()]
        except ValueError:
            parts = []
        if len(parts) != 4:
            raise PlanError(f"{source}: the root <svg> viewBox {vb!r} is not four numbers (min-x min-y width "
                            "height); fix it")
        if parts[2] <= 0 or parts[3] <= 0:
            raise PlanError(f"{source}: the root <svg> viewBox {vb!r} has zero or negative size; give it the "
                            "drawing's width and height")
        viewbox = tuple(parts)
    for dim, name in ((width, "width"), (height, "height")):
        if dim is not None and dim[0] <= 0:
            raise PlanError(f"{source}: the root <svg> {name} is {dim[0]:g}{dim[1]}; give it a positive size")
    return width, height, viewbox


def _physical_scale(width, height, viewbox, source: str) -> float | None:
    """Metres per user unit from a physical root width/height, or None."""
    scales = []
    for dim, vb_len, name in ((width, 2, "width"), (height, 3, "height")):
        if dim is None or dim[1] not in PHYSICAL_UNITS:
            continue
        metres = dim[0] * PHYSICAL_UNITS[dim[1]]
        units = viewbox[vb_len] if viewbox is not None else metres / (0.0254 / 96)  # no viewBox: 1 unit = 1 px
        scales.append((name, metres / units))
    if not scales:
        return None
    if len(scales) == 2 and abs(scales[0][1] - scales[1][1]) > 1e-6 * max(scales[0][1], scales[1][1]):
        raise PlanError(f"{source}: the root width and height give different scales in x and y "
                        f"({scales[0][1]:.6g} vs {scales[1][1]:.6g} m per unit) against the viewBox; make "
                        "them proportional to the viewBox or pass --scale")
    return scales[0][1]


def _element_name(e, counters: dict[str, int]) -> str:
    tag = e.values.get("tag", type(e).__name__.lower())
    counters[tag] = counters.get(tag, 0) + 1
    if e.id:
        return f'id="{e.id}"'
    return f"<{tag}> #{counters[tag]} (no id)"


def _group_layer(e) -> str | None:
    for name in (e.id, e.values.get(INKSCAPE_LABEL)):
        if isinstance(name, str) and name.strip().lower() in LAYERS:
            return name.strip().lower()
    return None


@dataclass
class _Raw:
    element: str
    layer: str | None
    shape: object  # svgelements Shape


def _walk(container, layer: str | None, out: list[_Raw], counters: dict[str, int], named: list[bool]) -> None:
    from svgelements import Group, Shape, Use

    for e in container:
        if isinstance(e, (Group, Use)):
            sub = _group_layer(e) if isinstance(e, Group) else None
            if sub is not None:
                named[0] = True
            _walk(e, sub or layer, out, counters, named)
        elif isinstance(e, Shape):
            out.append(_Raw(_element_name(e, counters), layer, e))


def _subpaths(shape, px_to_uu) -> list[tuple[np.ndarray, bool]]:
    """(points in user units (N, 2), closed) for each subpath; curves flattened (in px)."""
    from svgelements import Close, Line, Move, Path

    path = abs(Path(shape))  # segments in viewport pixels, every transform applied
    out = []
    for sub in path.as_subpaths():
        pts: list[np.ndarray] = []
        closed = False
        for seg in sub:
            if isinstance(seg, Move):
                pts.append(np.array([[seg.end.x, seg.end.y]], dtype=np.float64))
            elif isinstance(seg, Close):
                closed = True
            elif isinstance(seg, Line):
                pts.append(np.array([[seg.end.x, seg.end.y]], dtype=np.float64))
            elif seg.start is not None and seg.end is not None:
                coarse = np.asarray(seg.npoint(np.linspace(0, 1, 17)), dtype=np.float64)
                uu = px_to_uu(coarse)
                length = float(np.hypot(*np.diff(uu, axis=0).T).sum())
                pts.append(("curve", length, seg))  # resolved by the caller once the scale is known
        out.append((pts, closed))
    return out


class _Builder:
    """Turns svgelements shapes into shapely geometry in the map frame."""

    def __init__(self, source: str, px_to_uu, wall_thickness: float):
        self.source = source
        self.px_to_uu = px_to_uu
        self.wall_thickness = wall_thickness

    def points(self, parts, uu_to_map, scale: float, element: str) -> np.ndarray:
        arrays = []
        for p in parts:
            if isinstance(p, tuple):
                _, length_uu, seg = p
                n = int(min(max(math.ceil(length_uu * scale / CURVE_STEP_M), 16), 4096))
                arrays.append(np.asarray(seg.npoint(np.linspace(0, 1, n + 1)[1:]), dtype=np.float64))
            else:
                arrays.append(p)
        px = np.concatenate(arrays) if arrays else np.zeros((0, 2))
        if not np.isfinite(px).all():
            raise PlanError(f"{self.source}: {element} has a coordinate that is not a finite number; fix "
                            "the coordinates in the drawing")
        return uu_to_map(self.px_to_uu(px))


def _winding(px: np.ndarray, py: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Winding number of points around a closed ring (N, 2) (first point not repeated)."""
    x0, y0 = ring[:, 0], ring[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    w = np.zeros(len(px), dtype=np.int64)
    for k in range(len(x0)):
        cross = (x1[k] - x0[k]) * (py - y0[k]) - (px - x0[k]) * (y1[k] - y0[k])
        up = (y0[k] <= py) & (y1[k] > py) & (cross > 0)
        down = (y0[k] > py) & (y1[k] <= py) & (cross < 0)
        w += up.astype(np.int64) - down.astype(np.int64)
    return w


def _fill_region(rings: list[np.ndarray], evenodd: bool):
    """The area an SVG fill paints for closed rings, with the fill rule: polygonize the rings'
    linework into faces and keep each face whose winding number says filled."""
    import shapely
    from shapely.geometry import LinearRing, Polygon

    rings = [r for r in rings if len(r) >= 3]
    if not rings:
        return None
    if len(rings) == 1:
        poly = Polygon(rings[0])
        return poly if poly.is_valid else shapely.make_valid(poly)
    lines = shapely.union_all([LinearRing(r) for r in rings])
    faces = list(shapely.get_parts(shapely.polygonize(shapely.get_parts(lines))))
    if not faces:
        return None
    pts = np.array([f.representative_point().coords[0] for f in faces])
    wind = sum(_winding(pts[:, 0], pts[:, 1], r) if not evenodd else np.abs(_winding(pts[:, 0], pts[:, 1], r)) % 2
               for r in rings)
    keep = [f for f, w in zip(faces, wind) if (w % 2 == 1 if evenodd else w != 0)]
    return shapely.union_all(keep) if keep else None


def _stroke_polygon(line: np.ndarray, closed: bool, width: float, cap: str, join: str, mitre: float):
    from shapely.geometry import LinearRing, LineString, Point

    if len(line) == 1 or (len(line) == 2 and np.allclose(line[0], line[1])):
        return Point(line[0]).buffer(width / 2, cap_style="square") if cap == "square" else (
            Point(line[0]).buffer(width / 2) if cap == "round" else None)
    if closed and len(line) >= 3:
        geom = LinearRing(line)
        return geom.buffer(width / 2, join_style=join, mitre_limit=mitre)
    geom = LineString(line)
    return geom.buffer(width / 2, cap_style=cap, join_style=join, mitre_limit=mitre)


def parse_plan(
    path: str | Path,
    scale: float | None = None,
    wall_thickness: float = 0.10,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Plan:
    """Read an SVG plan. Raises PlanError (one line: what, where, what to do) for bad input."""
    import xml.etree.ElementTree as ET

    import shapely

    source = str(path)
    p = Path(path)
    if not p.is_file():
        raise PlanError(f"{source}: no such file; give the path of an SVG plan or a map YAML")
    raw_bytes = p.read_bytes()
    try:
        root = ET.fromstring(raw_bytes)
    except ET.ParseError as exc:
        raise PlanError(f"{source}: not XML ({exc}); give an SVG file (Inkscape: Save As plain SVG)") from exc
    if _local(root.tag) != "svg":
        raise PlanError(f"{source}: the root element is <{_local(root.tag)}>, not <svg>; give an SVG file")
    _prescan(root, source)
    width, height, viewbox = _root_dims(root, source)
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise PlanError(f"--scale must be a positive number of metres per SVG unit, got {scale}")

    from svgelements import SVG, Matrix

    try:
        svg = SVG.parse(str(p), reify=True, ppi=96.0)
    except Exception as exc:  # svgelements raises many kinds on malformed content
        raise PlanError(f"{source}: svgelements cannot read it ({type(exc).__name__}: {exc}); "
                        "re-save it as plain SVG") from exc
    vt = Matrix(svg.viewbox_transform) if getattr(svg, "viewbox_transform", None) else Matrix()
    det_v = abs(vt.a * vt.d - vt.b * vt.c)
    if not det_v > 0:
        raise PlanError(f"{source}: the root viewport transform is degenerate; check the viewBox and width/height")
    inv = ~vt
    ia, ib, ic, id_, ie, if_ = inv.a, inv.b, inv.c, inv.d, inv.e, inv.f

    def px_to_uu(pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([ia * pts[:, 0] + ic * pts[:, 1] + ie, ib * pts[:, 0] + id_ * pts[:, 1] + if_])

    px_per_uu = math.sqrt(det_v)

    raws: list[_Raw] = []
    named = [False]
    _walk(svg, None, raws, {}, named)
    scale_raws = [r for r in raws if r.shape.id == "scale"]
    raws = [r for r in raws if r.shape.id != "scale"]

    # --- scale: first that applies
    scale_source = "--scale"
    if scale is None:
        scale = _physical_scale(width, height, viewbox, source)
        scale_source = "width/height"
    if scale is None and scale_raws:
        el = scale_raws[0]
        text = el.shape.values.get("data-length-m")
        try:
            length_m = float(text)
        except (TypeError, ValueError):
            length_m = float("nan")
        if not (math.isfinite(length_m) and length_m > 0):
            raise PlanError(f"{source}: the scale element {el.element} needs data-length-m, a positive length in "
                            f"metres (got {text!r}); add e.g. data-length-m=\"5\"")
        length_uu = 0.0
        for parts, closed in _subpaths(el.shape, px_to_uu):
            uu = px_to_uu(_flatten_px(parts))
            if closed and len(uu) > 1:
                uu = np.vstack([uu, uu[:1]])
            length_uu += float(np.hypot(*np.diff(uu, axis=0).T).sum()) if len(uu) > 1 else 0.0
        if not (math.isfinite(length_uu) and length_uu > 0):
            raise PlanError(f"{source}: the scale element {el.element} has zero length; draw it as a line of "
                            "known length")
        scale = length_m / length_uu
        scale_source = "scale element"
    if scale is None:
        raise PlanError(f"{source}: the plan has no scale; pass --scale METRES_PER_UNIT, give the root <svg> a "
                        "width/height in mm, cm, m, in, pt or pc with a viewBox, or add a line with id=\"scale\" "
                        "and data-length-m")

    # --- the canvas in user units: the viewBox, else the root width/height, else the drawing
    canvas_uu = None
    if viewbox is not None:
        canvas_uu = viewbox
    elif width is not None and height is not None and width[1] != "%" and height[1] != "%":
        canvas_uu = (0.0, 0.0, _to_px(width), _to_px(height))
    if canvas_uu is None:
        all_pts = [px_to_uu(_flatten_px(parts)) for r in raws for parts, _ in _subpaths(r.shape, px_to_uu)]
        all_pts = [a for a in all_pts if len(a) and np.isfinite(a).all()]
        if all_pts:
            stack = np.concatenate(all_pts)
            lo, hi = stack.min(axis=0), stack.max(axis=0)
            canvas_uu = (lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1])
    cx, cy, cw, ch = canvas_uu if canvas_uu is not None else (0.0, 0.0, 0.0, 0.0)
    ox, oy, yaw = (float(v) for v in origin)
    cos_y, sin_y = math.cos(yaw), math.sin(yaw)

    def uu_to_map(uu: np.ndarray) -> np.ndarray:
        xm = (uu[:, 0] - cx) * scale
        ym = (cy + ch - uu[:, 1]) * scale
        out = np.column_stack([ox + cos_y * xm - sin_y * ym, oy + sin_y * xm + cos_y * ym])
        return np.round(out, 9)  # drop float noise, so that a wall on a grid line is exactly on it

    canvas = None
    if canvas_uu is not None and cw > 0 and ch > 0:
        corners = uu_to_map(np.array([[cx, cy], [cx + cw, cy], [cx, cy + ch], [cx + cw, cy + ch]]))
        canvas = (*corners.min(axis=0), *corners.max(axis=0))

    builder = _Builder(source, px_to_uu, wall_thickness)
    shapes: list[PlanShape] = []
    ignored = 0
    for r in raws:
        layer = r.layer if named[0] else "walls"
        if layer is None:
            ignored += 1
            continue
        shape = r.shape
        values = shape.values
        subs = []
        for parts, closed in _subpaths(shape, px_to_uu):
            pts = builder.points(parts, uu_to_map, scale, r.element)
            if len(pts) == 0 or np.ptp(pts, axis=0).max() < 1e-9:  # nothing, or collapsed to a point
                continue
            if len(pts) > 2 and np.allclose(pts[0], pts[-1], atol=1e-9):
                closed, pts = True, pts[:-1]
            subs.append((pts, closed))
        if not subs:
            continue
        tag = values.get("tag", "")
        stroke_visible = shape.stroke is not None and shape.stroke.value is not None and values.get("stroke") != "none"
        fill_visible = shape.fill is not None and shape.fill.value is not None and values.get("fill") != "none"
        fillable = fill_visible and tag not in ("line", "polyline") and any(c for _, c in subs)
        fill = None
        if fillable:
            evenodd = str(values.get("fill-rule", "nonzero")).strip().lower() == "evenodd"
            fill = _fill_region([pts for pts, c in subs if c and len(pts) >= 3], evenodd)
        strokes: list[Stroke] = []
        if stroke_visible or fill is None:
            width_m = _stroke_width_m(shape, values, px_per_uu, scale, wall_thickness, stroke_visible)
            cap = {"butt": "flat", "square": "square", "round": "round"}.get(
                str(values.get("stroke-linecap", "butt")).strip().lower(), "flat")
            join = {"miter": "mitre", "round": "round", "bevel": "bevel"}.get(
                str(values.get("stroke-linejoin", "miter")).strip().lower(), "mitre")
            try:
                mitre = float(values.get("stroke-miterlimit", 4.0))
            except (TypeError, ValueError):
                mitre = 4.0
            polys = []
            for pts, closed in subs:
                strokes.append(Stroke(pts, width_m, closed))
                poly = _stroke_polygon(pts, closed, width_m, cap, join, max(mitre, 1.0))
                if poly is not None and not poly.is_empty:
                    polys.append(poly)
            stroke_region = shapely.union_all(polys) if polys else None
        else:
            stroke_region = None
        parts_ = [g for g in (fill, stroke_region) if g is not None and not g.is_empty]
        if not parts_ and not strokes:
            continue
        region = shapely.union_all(parts_) if parts_ else shapely.Polygon()
        height_m = None
        if layer == "furniture" and values.get("data-height-m") is not None:
            try:
                height_m = float(values["data-height-m"])
            except (TypeError, ValueError):
                height_m = float("nan")
            if not (math.isfinite(height_m) and height_m > 0):
                raise PlanError(f"{source}: {r.element} has data-height-m={values['data-height-m']!r}; give a "
                                "positive height in metres")
        shapes.append(PlanShape(r.element, layer, region, fill, strokes, height_m))

    if not any(s.layer in ("walls", "windows") for s in shapes):
        where = "in the walls or windows layer" if named[0] else "in it"
        raise PlanError(f"{source}: no wall shapes {where} (lines, polylines, paths, rects, circles...); "
                        "draw the walls, or name the layer holding them 'walls'")
    return Plan(source, shapes, canvas, float(scale), scale_source, named[0], ignored)


def _to_px(dim: tuple[float, str]) -> float:
    value, unit = dim
    if unit in PHYSICAL_UNITS:
        return value * PHYSICAL_UNITS[unit] / (0.0254 / 96)
    return value


def _flatten_px(parts) -> np.ndarray:
    arrays = []
    for p in parts:
        if isinstance(p, tuple):
            arrays.append(np.asarray(p[2].npoint(np.linspace(0, 1, 65)[1:]), dtype=np.float64))
        else:
            arrays.append(p)
    return np.concatenate(arrays) if arrays else np.zeros((0, 2))


def _stroke_width_m(shape, values, px_per_uu: float, scale: float, wall_thickness: float, visible: bool) -> float:
    """The stroke width in metres, or ``wall_thickness`` for hairlines."""
    if not visible or values.get("stroke-width") is None:
        return wall_thickness
    if str(values.get("-inkscape-stroke", "")).strip().lower() == "hairline":
        return wall_thickness
    if str(values.get("vector-effect", "")).strip().lower() == "non-scaling-stroke":
        return wall_thickness
    try:
        w_px = float(shape.implicit_stroke_width)
    except (TypeError, ValueError):
        return wall_thickness
    if not math.isfinite(w_px) or w_px <= 0:
        return wall_thickness
    return w_px / px_per_uu * scale
