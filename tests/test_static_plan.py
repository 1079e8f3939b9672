"""build-static geometry against hand-computed cells.

The reference room: a 4 x 3 m canvas; walls on the rectangle x 0.5..3.5 m, y 0.5..2.5 m (map frame,
y up), 0.10 m thick. At 0.05 m the cell centres are (j + 0.5) * 0.05, so the west wall (x 0.45..0.55)
holds the centres 0.475 and 0.525: columns 9 and 10; the east wall (3.45..3.55) columns 69, 70; the
south wall rows 9, 10; the north wall rows 49, 50. The ring spans rows 9..50, columns 9..70, with the
hole rows 11..48, columns 11..68: 42 * 62 - 38 * 58 = 400 cells. The outline (the ring, holes
filled) is free inside, the rest of the 80 x 60 grid unknown.
"""

import math

import numpy as np
import pytest

from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.static.build import build_from_plan
from ltmap_cli.static.svgplan import parse_plan

NS = 'xmlns="http://www.w3.org/2000/svg" xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape"'
MM = 'width="4000mm" height="3000mm" viewBox="0 0 4000 3000"'


def write_svg(tmp_path, body, root=MM, name="plan.svg"):
    p = tmp_path / name
    p.write_text(f"<svg {NS} {root}>{body}</svg>")
    return p


def build(path, resolution=0.05, **kw):
    parse_kw = {k: kw.pop(k) for k in ("scale", "wall_thickness", "origin") if k in kw}
    plan = parse_plan(path, **parse_kw)
    return build_from_plan(plan, resolution, **kw)


def ring(rows, cols, hole_rows, hole_cols, shape=(60, 80)):
    m = np.zeros(shape, bool)
    m[rows[0]:rows[1] + 1, cols[0]:cols[1] + 1] = True
    m[hole_rows[0]:hole_rows[1] + 1, hole_cols[0]:hole_cols[1] + 1] = False
    return m


ROOM = ring((9, 50), (9, 70), (11, 48), (11, 68))
ROOM_RECT = '<rect x="500" y="500" width="3000" height="2000" fill="none" stroke="#000" stroke-width="100"/>'


def walls_of(layer):
    return layer.grid.data == 100


def test_reference_room_cells_free_and_unknown(tmp_path):
    layer, stats = build(write_svg(tmp_path, ROOM_RECT))
    g = layer.grid
    assert g.data.shape == (60, 80) and g.origin == (0.0, 0.0, 0.0) and g.resolution == 0.05
    assert (walls_of(layer) == ROOM).all()
    inside = np.zeros((60, 80), bool)
    inside[11:49, 11:69] = True
    assert (g.data[inside] == 0).all()
    assert (g.data[~(inside | ROOM)] == -1).all()
    assert stats.wall_cells == 400
    assert stats.wall_area_m2 == pytest.approx(2 * (3.1 + 2.1) * 0.1 - 4 * 0.01 + 0.0, abs=1e-6)  # 1.0 m^2
    assert stats.wall_length_m == pytest.approx((2 * (3.1 + 2.1) + 2 * (2.9 + 1.9)) / 2)  # 10.0 m
    # 3D: walls extruded to the wall height, nothing elsewhere
    assert (layer.height[ROOM] == 2.5).all() and (layer.height[~ROOM] == 0).all()
    assert layer.lt_seed_height is None and layer.doors == 0


@pytest.mark.parametrize(
    "root,body,kw",
    [
        # centimetres
        ('width="400cm" height="300cm" viewBox="0 0 400 300"',
         '<rect x="50" y="50" width="300" height="200" fill="none" stroke="#000" stroke-width="10"/>', {}),
        # metres (not CSS, accepted at the root)
        ('width="4m" height="3m" viewBox="0 0 4000 3000"', ROOM_RECT, {}),
        # inches (4000 mm = 157.48... in) and points against a mm viewBox
        ('width="157.480314961in" height="118.110236220in" viewBox="0 0 4000 3000"', ROOM_RECT, {}),
        ('width="11338.582677pt" height="8503.937008pt" viewBox="0 0 4000 3000"', ROOM_RECT, {}),
        # px (no physical size) with --scale
        ('viewBox="0 0 4000 3000"', ROOM_RECT, {"scale": 0.001}),
        ('width="4000" height="3000"', ROOM_RECT, {"scale": 0.001}),
        # px drawing, 1 unit = 1 cm, given by --scale
        ('width="400px" height="300px" viewBox="0 0 400 300"',
         '<rect x="50" y="50" width="300" height="200" fill="none" stroke="#000" stroke-width="10"/>',
         {"scale": 0.01}),
        # a scale element: a 2 m line drawn 2000 units long (not a wall itself)
        ('viewBox="0 0 4000 3000"',
         ROOM_RECT + '<line id="scale" x1="1000" y1="2900" x2="3000" y2="2900" stroke="red" data-length-m="2"/>', {}),
        # --scale wins over width/height
        ('width="40mm" height="30mm" viewBox="0 0 4000 3000"', ROOM_RECT, {"scale": 0.001}),
    ],
)
def test_units_and_scales_give_the_reference_room(tmp_path, root, body, kw):
    layer, _ = build(write_svg(tmp_path, body, root), **kw)
    assert layer.grid.data.shape == (60, 80)
    assert (walls_of(layer) == ROOM).all()


def test_scale_sources_are_reported(tmp_path):
    assert parse_plan(write_svg(tmp_path, ROOM_RECT)).scale_source == "width/height"
    p = write_svg(tmp_path, ROOM_RECT + '<line id="scale" x1="0" y1="0" x2="500" y2="0" data-length-m="0.5"/>',
                  'viewBox="0 0 4000 3000"')
    plan = parse_plan(p)
    assert plan.scale_source == "scale element" and plan.metres_per_unit == pytest.approx(0.001)
    plan = parse_plan(p, scale=0.002)
    assert plan.scale_source == "--scale" and plan.metres_per_unit == 0.002
    pt = write_svg(tmp_path, ROOM_RECT, 'width="72pt" height="72pt" viewBox="0 0 100 100"')
    assert parse_plan(pt).metres_per_unit == pytest.approx(0.0254 / 100)


@pytest.mark.parametrize(
    "body",
    [
        '<g transform="translate(500,500)"><rect width="3000" height="2000" fill="none" stroke="#000" '
        'stroke-width="100"/></g>',
        # rotate(90) maps (x, y) to (-y, x): the 2000 x 3000 rect lands on x -3000..0, y 0..2000
        '<g transform="translate(3500,500)"><g transform="rotate(90)"><rect width="2000" height="3000" '
        'fill="none" stroke="#000" stroke-width="100"/></g></g>',
        # scale(2) doubles coordinates and the stroke width
        '<g transform="scale(2)"><rect x="250" y="250" width="1500" height="1000" fill="none" stroke="#000" '
        'stroke-width="50"/></g>',
        # nested: scale then translate, the stroke set on the outer group
        '<g style="stroke:#000;stroke-width:25;fill:none" transform="scale(4)"><g transform="translate(125,125)">'
        '<rect width="750" height="500"/></g></g>',
        # a mirrored copy through <use>
        '<defs><rect id="r" width="3000" height="2000" fill="none" stroke="#000" stroke-width="100"/></defs>'
        '<use href="#r" transform="translate(500,2500) scale(1,-1)"/>',
    ],
)
def test_group_transforms(tmp_path, body):
    layer, _ = build(write_svg(tmp_path, body))
    assert (walls_of(layer) == ROOM).all()


@pytest.mark.parametrize(
    "body",
    [
        # four stroked lines; square caps close the outer corners
        '<g stroke="#000" stroke-width="100" stroke-linecap="square">'
        '<line x1="500" y1="500" x2="3500" y2="500"/><line x1="3500" y1="500" x2="3500" y2="2500"/>'
        '<line x1="3500" y1="2500" x2="500" y2="2500"/><line x1="500" y1="2500" x2="500" y2="500"/></g>',
        # one stroked rect
        ROOM_RECT,
        # one stroked closed polyline (mitre joins)
        '<polygon points="500,500 3500,500 3500,2500 500,2500" fill="none" stroke="#000" stroke-width="100"/>',
        # a filled ring, even-odd
        '<path fill-rule="evenodd" fill="#000" d="M 450,450 H 3550 V 2550 H 450 Z M 550,550 H 3450 V 2450 H 550 Z"/>',
        # a filled ring, nonzero with the inner ring wound the other way
        '<path fill="#000" d="M 450,450 H 3550 V 2550 H 450 Z M 550,550 V 2450 H 3450 V 550 Z"/>',
    ],
)
def test_same_room_drawn_several_ways(tmp_path, body):
    layer, stats = build(write_svg(tmp_path, body))
    assert (walls_of(layer) == ROOM).all()
    assert stats.wall_length_m == pytest.approx(10.0)


def test_nonzero_ring_wound_the_same_way_is_solid(tmp_path):
    body = '<path fill="#000" d="M 450,450 H 3550 V 2550 H 450 Z M 550,550 H 3450 V 2450 H 550 Z"/>'
    layer, _ = build(write_svg(tmp_path, body))
    solid = np.zeros((60, 80), bool)
    solid[9:51, 9:71] = True
    assert (walls_of(layer) == solid).all()


def test_arc_wall(tmp_path):
    # an arc of radius 1500 mm about (2500, 2500) mm, from (1000, 2500) to (2500, 1000): in the map frame
    # a quarter ring about (2.5, 0.5), radius 1.45..1.55 m, in the quadrant x <= 2.5, y >= 0.5
    body = '<path d="M 1000,2500 A 1500,1500 0 0 1 2500,1000" fill="none" stroke="#000" stroke-width="100"/>'
    layer, _ = build(write_svg(tmp_path, body))
    xs = (np.arange(80) + 0.5) * 0.05
    ys = (np.arange(60) + 0.5) * 0.05
    X, Y = np.meshgrid(xs, ys)
    d = np.hypot(X - 2.5, Y - 0.5)
    expect = (d >= 1.45) & (d <= 1.55) & (X <= 2.5) & (Y >= 0.5)
    unsure = (np.abs(d - 1.45) < 1e-3) | (np.abs(d - 1.55) < 1e-3)
    assert expect.sum() > 80
    assert (walls_of(layer) == expect)[~unsure].all()


DOOR_WALLS = '<g id="walls"><path d="M 500,1500 H 1500 M 2400,1500 H 3500" stroke="#000" stroke-width="100" ' \
             'fill="none"/></g>'
# a wall line y = 1.5 m (rows 29, 30), x 0.5..1.5 and 2.4..3.5 m: columns 10..29 and 48..69


def expected_gap_walls():
    m = np.zeros((60, 80), bool)
    m[29:31, 10:30] = True
    m[29:31, 48:70] = True
    return m


def test_door_across_the_gap_overlapping_the_walls_keeps_it_free(tmp_path):
    # the door rect overlaps both wall ends by 20 mm and sticks out of the wall on both sides
    door = '<g inkscape:label="Doors"><rect x="1480" y="1440" width="940" height="120" fill="#fff"/></g>'
    layer, stats = build(write_svg(tmp_path, DOOR_WALLS + door))
    assert (walls_of(layer) == expected_gap_walls()).all()
    assert (layer.grid.data[29:31, 30:48] == 0).all()  # the opening: free (inside the outline), not unknown
    assert stats.doors == 1 and layer.doors == 1
    # the same rect without layers is a wall: the gap closes
    layer, _ = build(write_svg(tmp_path, DOOR_WALLS.replace('id="walls"', "") + door.replace(
        ' inkscape:label="Doors"', "")))
    assert walls_of(layer)[29:31, 10:70].all()


def test_door_symbol_over_a_continuous_wall_carves_the_opening(tmp_path):
    walls = '<g id="Walls"><line x1="500" y1="1500" x2="3500" y2="1500" stroke="#000" stroke-width="100"/></g>'
    # a CAD-style door: a white rect covering the wall line, with a leaf and a swing in thin lines
    door = ('<g id="DOORS"><rect x="1500" y="1400" width="900" height="200" fill="#fff"/>'
            '<path d="M 1500,1500 V 600 A 900,900 0 0 1 2400,1500" fill="none" stroke="#c00" stroke-width="10"/></g>')
    layer, stats = build(write_svg(tmp_path, walls + door))
    assert (walls_of(layer) == expected_gap_walls()).all()
    assert stats.doors == 1


def test_doors_layer_is_free_and_counted(tmp_path):
    doors = ('<g inkscape:label="doors">'
             '<path d="M 1500,1500 V 600" stroke="#c00" stroke-width="20" fill="none"/>'
             '<path d="M 1500,600 A 900,900 0 0 1 2400,1500" stroke="#c00" stroke-width="20" fill="none"/>'
             '<rect x="100" y="100" width="200" height="200" fill="#c00"/></g>')
    layer, stats = build(write_svg(tmp_path, DOOR_WALLS + doors))
    assert (walls_of(layer) == expected_gap_walls()).all()
    assert stats.doors == 2  # the leaf and its swing touch: one door; the square is another
    assert layer.height[~expected_gap_walls()].max() == 0


def test_hairline_thinner_than_a_cell_is_an_unbroken_line(tmp_path):
    # a 10 mm wall at y = 1.01 m (inside row 20, whose centre is 1.025): no centre inside, the spine rule
    # marks row 20, columns 10 (x 0.51) .. 69 (x 3.49)
    body = '<line x1="510" y1="1990" x2="3490" y2="1990" stroke="#000" stroke-width="10"/>'
    layer, _ = build(write_svg(tmp_path, body))
    expect = np.zeros((60, 80), bool)
    expect[20, 10:70] = True
    assert (walls_of(layer) == expect).all()
    # the same as a thin filled rect
    body = '<rect x="510" y="1985" width="2980" height="10" fill="#000"/>'
    layer, _ = build(write_svg(tmp_path, body))
    assert (walls_of(layer) == expect).all()


def test_zero_width_and_unset_strokes_get_the_wall_thickness(tmp_path):
    # band y 0.96..1.06 holds the centres 0.975, 1.025: rows 19, 20
    for stroke in ('stroke="#000" stroke-width="0"', 'stroke="#000"', "",
                   'style="stroke:#000;stroke-width:1;vector-effect:non-scaling-stroke"',
                   'style="stroke:#000;stroke-width:30;-inkscape-stroke:hairline"'):
        body = f'<line x1="510" y1="1990" x2="3490" y2="1990" {stroke}/>'
        layer, _ = build(write_svg(tmp_path, body))
        rows = np.nonzero(walls_of(layer).any(axis=1))[0]
        assert list(rows) == [19, 20], stroke
    # --wall-thickness 0.2: band 0.91..1.11 -> centres 0.925 .. 1.075: rows 18..21
    layer, _ = build(write_svg(tmp_path, '<line x1="510" y1="1990" x2="3490" y2="1990"/>'), wall_thickness=0.2)
    assert list(np.nonzero(walls_of(layer).any(axis=1))[0]) == [18, 19, 20, 21]


def _connected(mask, start, end):
    seen = np.zeros_like(mask)
    seen[start] = True
    while True:
        grown = seen.copy()
        grown[1:] |= seen[:-1]
        grown[:-1] |= seen[1:]
        grown[:, 1:] |= seen[:, :-1]
        grown[:, :-1] |= seen[:, 1:]
        grown &= mask
        if grown[end]:
            return True
        if (grown == seen).all():
            return False
        seen = grown


def test_diagonal_hairline_is_4_connected(tmp_path):
    body = '<line x1="510" y1="2490" x2="3470" y2="530" stroke="#000" stroke-width="5"/>'
    layer, _ = build(write_svg(tmp_path, body))
    m = walls_of(layer)
    # ends: map (0.51, 0.51) -> cell (10, 10); (3.47, 2.47) -> cell (49, 69)
    assert m[10, 10] and m[49, 69]
    assert _connected(m, (10, 10), (49, 69))


def test_named_layers_ignore_other_shapes_and_windows_are_walls(tmp_path):
    body = ('<g inkscape:label="Walls">' + ROOM_RECT + "</g>"
            '<g inkscape:label="Windows"><rect x="1000" y="450" width="1000" height="100" fill="#9cf"/></g>'
            '<g inkscape:label="Notes"><line x1="0" y1="1500" x2="4000" y2="1500" stroke="#000"/>'
            "<text x='10' y='10'>kitchen</text></g>")
    plan = parse_plan(write_svg(tmp_path, body))
    assert plan.named_layers and plan.ignored == 1
    layer, stats = build_from_plan(plan, 0.05)
    assert (walls_of(layer) == ROOM).all()  # the window lies inside the wall band
    assert stats.ignored_shapes == 1


FURNITURE = ('<g inkscape:label="walls">' + ROOM_RECT + "</g>"
             '<g inkscape:label="furniture"><rect id="table" x="1010" y="1010" width="980" height="480" '
             'data-height-m="0.75" fill="#a70"/>'
             '<rect id="shelf" x="2510" y="1010" width="480" height="480" fill="#a70"/></g>')
# table: map x 1.01..1.99, y 1.51..1.99 -> cols 20..39, rows 30..39; shelf x 2.51..2.99, y 1.51..1.99 -> cols 50..59


@pytest.mark.parametrize("mode", ["none", "static", "long-term"])
def test_furniture_modes(tmp_path, mode):
    layer, stats = build(write_svg(tmp_path, FURNITURE), furniture=mode, wall_height=2.0)
    table = (slice(30, 40), slice(20, 40))
    shelf = (slice(30, 40), slice(50, 60))
    assert stats.furniture == 2 and stats.wall_cells == 400
    if mode == "static":
        assert (layer.height[table] == 0.75).all() and (layer.height[shelf] == 2.0).all()
        assert (layer.grid.data[table] == 100).all()
        assert layer.lt_seed_height is None
        assert layer.grid.data[29, 20] == 0 and layer.grid.data[30, 19] == 0
    else:
        assert (layer.grid.data[table] == 0).all() and (layer.height[table] == 0).all()
        if mode == "long-term":
            seed = layer.lt_seed_height
            assert (seed[table] == np.float32(0.75)).all() and (seed[shelf] == 2.0).all()
            assert int((seed > 0).sum()) == 200 + 100
        else:
            assert layer.lt_seed_height is None


def test_origin_translates_and_rotates(tmp_path):
    p = write_svg(tmp_path, ROOM_RECT)
    layer, _ = build(p, origin=(1.0, -2.0, 0.0))
    assert layer.grid.origin == (1.0, -2.0, 0.0) and (walls_of(layer) == ROOM).all()
    # yaw 90 deg: map = (-y, x): the canvas lands on x -3..0, y 0..4; the lattice stays axis-aligned
    layer, _ = build(p, origin=(0.0, 0.0, math.pi / 2))
    g = layer.grid
    assert g.origin == (-3.0, 0.0, 0.0) and g.data.shape == (80, 60)
    # new (row, col) is reference (row', col') with x = -y' (col = 59 - row') and y = x' (row = col')
    assert (walls_of(layer) == ROOM.T[:, ::-1]).all()


def test_written_map_reads_back_with_nav2_semantics(tmp_path):
    from click.testing import CliRunner

    from ltmap_cli.cli import cli

    p = write_svg(tmp_path, DOOR_WALLS.replace("</g>", ROOM_RECT + "</g>")
                  + '<g id="doors"><rect x="1480" y="1440" width="940" height="120" fill="#fff"/></g>')
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["build-static", str(p), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "1 doors" in res.output and "80 x 60 cells = 4.00 x 3.00 m" in res.output
    g = read_map_yaml(out / "static.yaml")
    assert g.resolution == 0.05 and g.origin == (0.0, 0.0, 0.0)
    expect = ROOM | expected_gap_walls()
    assert ((g.data == 100) == expect).all()
    assert (g.data[11:49, 11:69][~expect[11:49, 11:69]] == 0).all()
    assert (g.data[:9] == -1).all() and (g.data[:, 71:] == -1).all()
    pgm = (out / "static.pgm").read_bytes()
    assert pgm.startswith(b"P5") and (out / "static.png").is_file() and (out / "static_layer.npz").is_file()
