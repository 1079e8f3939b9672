"""`ltmap build-static` through the CLI: bad input (one line, exit 2, nothing written), map input,
the sample plans."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.io.mapfile import GridMap, read_map_yaml, write_map
from ltmap_cli.io.static_layer import load_static_input, read_static_layer

NS = 'xmlns="http://www.w3.org/2000/svg"'
MM = 'width="4000mm" height="3000mm" viewBox="0 0 4000 3000"'
ROOM = '<rect x="500" y="500" width="3000" height="2000" fill="none" stroke="#000" stroke-width="100"/>'
PLANS = Path(__file__).resolve().parents[1] / "sample_logs" / "plans"


def run(*args):
    return CliRunner().invoke(cli, ["build-static", *map(str, args)])


@pytest.mark.parametrize(
    "content,needle",
    [
        ("this is not < xml", "not XML"),
        (f"<svg {NS} {MM}><text x='1' y='1'>only a label</text></svg>", "no wall shapes"),
        (f'<svg {NS} width="4furlong" height="3mm" viewBox="0 0 4000 3000">{ROOM}</svg>', "unknown unit 'furlong'"),
        (f'<svg {NS} {MM}><line id="w1" x1="0" y1="0" x2="3parsec" y2="0" stroke="#000"/></svg>',
         'unknown unit \'parsec\''),
        (f'<svg {NS} width="4000mm" height="3000mm" viewBox="0 0 0 3000">{ROOM}</svg>', "zero or negative size"),
        (f'<svg {NS} {MM}><path id="w7" d="M 0,0 L NaN,5" stroke="#000"/></svg>', 'id="w7"'),
        (f'<svg {NS} {MM}><path id="w8" d="M 0,0 L 1e400,5" stroke="#000"/></svg>', 'id="w8"'),
        (f'<svg {NS} viewBox="0 0 4000 3000">{ROOM}</svg>', "--scale METRES_PER_UNIT"),
        (f'<svg {NS} viewBox="0 0 4000 3000">{ROOM}<line id="scale" x1="0" y1="0" x2="10" y2="0"/></svg>',
         "data-length-m"),
        (f'<svg {NS} width="100000000mm" height="100000000mm" viewBox="0 0 1e8 1e8">{ROOM}</svg>', "--max-cells"),
        ("<html><body/></html>", "not <svg>"),
        (f'<svg {NS} {MM}><g transform="scale(0)">{ROOM}</g></svg>', "no wall shapes"),
        (f'<svg {NS} {MM}><g id="walls"><line x1="0" y1="500" x2="1000" y2="500" stroke="#000" '
         'stroke-width="100"/></g><g id="doors"><rect x="-100" y="0" width="1200" height="1000" fill="#000"/>'
         '</g></svg>', "cover no cell"),
        (f'<svg {NS} {MM}><circle cx="5" cy="5" r="-3" fill="#000"/></svg>', "negative r"),
        (f'<svg {NS} {MM}><rect x="0" y="0" width="-2000" height="100" fill="#000"/></svg>', "negative width"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, content, needle):
    p = tmp_path / "bad.svg"
    p.write_text(content)
    out = tmp_path / "out"
    res = run(p, "-o", out)
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ltmap: error: "), res.stderr
    assert needle in lines[0], lines[0]
    assert str(p) in lines[0]
    assert "Traceback" not in res.output
    assert not out.exists()


def test_scale_message_names_the_three_ways(tmp_path):
    p = tmp_path / "plan.svg"
    p.write_text(f'<svg {NS} viewBox="0 0 4000 3000">{ROOM}</svg>')
    msg = run(p, "-o", tmp_path / "o").stderr
    assert "--scale" in msg and "width/height" in msg and 'id="scale"' in msg


def test_too_large_names_the_memory(tmp_path):
    p = tmp_path / "plan.svg"
    p.write_text(f"<svg {NS} {MM}>{ROOM}</svg>")
    res = run(p, "-o", tmp_path / "o", "--max-cells", "1000")
    assert res.exit_code == 2 and "80 x 60 = 4.8e+03 cells" in res.stderr and "KB of memory" in res.stderr
    assert run(p, "-o", tmp_path / "o", "--max-cells", "4800").exit_code == 0


def test_missing_file_and_bad_origin(tmp_path):
    res = run(tmp_path / "nope.svg", "-o", tmp_path / "o")
    assert res.exit_code == 2 and "no such file" in res.stderr
    p = tmp_path / "plan.svg"
    p.write_text(f"<svg {NS} {MM}>{ROOM}</svg>")
    res = run(p, "--origin", "1,2")
    assert res.exit_code == 2 and "x,y,yaw" in res.output


def test_earlier_output_survives_a_failed_run(tmp_path):
    good = tmp_path / "plan.svg"
    good.write_text(f"<svg {NS} {MM}>{ROOM}</svg>")
    out = tmp_path / "out"
    assert run(good, "-o", out).exit_code == 0
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    bad = tmp_path / "bad.svg"
    bad.write_text(f"<svg {NS} {MM}><path id='x' d='M 0 0 L nan 1' stroke='#000'/></svg>")
    assert run(bad, "-o", out).exit_code == 2
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before


def test_map_yaml_as_input_is_normalized_and_resampled(tmp_path):
    data = np.full((40, 60), -1, dtype=np.int8)
    data[5:35, 5:55] = 0
    data[5, 5:55] = 100
    data[10:30, 20] = 100
    src = tmp_path / "slam.yaml"
    write_map(src, GridMap(data, 0.05, (-1.0, 2.0, 0.0)))
    out = tmp_path / "out"
    res = run(src, "-o", out, "--wall-height", "2")
    assert res.exit_code == 0, res.output
    g = read_map_yaml(out / "static.yaml")
    assert (g.data == data).all() and g.origin == (-1.0, 2.0, 0.0) and g.resolution == 0.05
    layer = read_static_layer(out)
    assert (layer.height[data == 100] == 2.0).all() and (layer.height[data != 100] == 0).all()
    # coarser: 0.1 m, origin kept; a wall one fine cell thick still gives a line of coarse cells
    res = run(src, "-o", tmp_path / "coarse", "--resolution", "0.1")
    assert res.exit_code == 0, res.output
    c = read_map_yaml(tmp_path / "coarse" / "static.yaml")
    assert c.data.shape == (20, 30) and c.resolution == 0.1 and c.origin == (-1.0, 2.0, 0.0)
    assert (c.data[2, 3:27] == 100).all()  # fine row 5 -> coarse row 2
    assert (c.data[5:15, 10] == 100).all()  # fine column 20 -> coarse column 10
    assert c.data[0, 0] == -1 and c.data[8, 5] == 0


def test_load_static_input_on_a_plain_map_server_yaml(tmp_path):
    data = np.zeros((10, 12), dtype=np.int8)
    data[0, :] = 100
    data[9, 3] = -1
    src = tmp_path / "map.yaml"
    write_map(src, GridMap(data, 0.1, (0.5, -0.5, 0.0)))
    layer = load_static_input(src, wall_height=1.8)
    assert (layer.grid.data == data).all() and layer.grid.origin == (0.5, -0.5, 0.0)
    assert (layer.height[0] == np.float32(1.8)).all() and layer.height[1:].max() == 0
    assert layer.lt_seed_height is None and layer.doors == 0 and layer.wall_height == 1.8


def test_load_static_input_on_build_outputs(tmp_path):
    p = tmp_path / "plan.svg"
    p.write_text(f'<svg {NS} xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" {MM}>'
                 f'<g inkscape:label="walls">{ROOM}</g><g inkscape:label="furniture">'
                 '<rect x="1010" y="1010" width="980" height="480" data-height-m="0.75"/></g></svg>')
    out = tmp_path / "out"
    assert run(p, "-o", out, "--furniture", "long-term", "--wall-height", "3").exit_code == 0
    for given in (out, out / "static.yaml", out / "static_layer.npz"):
        layer = load_static_input(given, wall_height=9.0)  # the stored wall height wins
        assert layer.wall_height == 3.0 and layer.height.max() == 3.0
        assert layer.lt_seed_height is not None and layer.lt_seed_height.max() == np.float32(0.75)
        assert int((layer.grid.data == 100).sum()) == 400
    # a person edits static.pgm (erases a wall cell, adds one): the YAML wins, heights follow
    g = read_map_yaml(out / "static.yaml")
    g.data[9, 30] = 0
    g.data[30, 30] = 100
    write_map(out / "static.yaml", g)
    layer = load_static_input(out)
    assert layer.height[9, 30] == 0 and layer.height[30, 30] == 3.0 and layer.grid.data[30, 30] == 100


def test_load_static_input_errors(tmp_path):
    from ltmap_cli.errors import MapFileError

    with pytest.raises(MapFileError, match="no such file"):
        load_static_input(tmp_path / "missing")
    with pytest.raises(MapFileError, match="neither static.yaml"):
        load_static_input(tmp_path)
    bad = tmp_path / "static_layer.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(MapFileError, match="unreadable static layer"):
        load_static_input(bad)
    with pytest.raises(MapFileError, match="not a map YAML"):
        load_static_input(Path(__file__))


@pytest.mark.parametrize("name,size,doors", [("house", (200, 160), 4), ("office", (420, 260), 11)])
def test_sample_plans_build(tmp_path, name, size, doors):
    out = tmp_path / name
    res = run(PLANS / f"{name}.svg", "-o", out, "--furniture", "static")
    assert res.exit_code == 0, res.output
    assert f"{doors} doors" in res.output and f"{size[0]} x {size[1]} cells" in res.output
    layer = load_static_input(out)
    g = layer.grid
    assert (g.width, g.height) == size
    # the entrance is open: a free cell in the doorway, and the corners outside are unknown
    assert g.data[0, 0] == -1 and g.data[-1, -1] == -1
    if name == "house":
        # front door: SVG x 3000..4000 at y 7500 -> map x 3.0..4.0, y 0.5: row 10, cols 61..78
        assert (g.data[9:12, 61:79] == 0).all()
        assert layer.height[g.data == 100].min() == pytest.approx(0.5)  # the bed is the lowest furniture
    else:
        # entrance: map x 0.5, y 6.0..7.0 (SVG 7000..6000 -> map 6.0..7.0): col 10, rows 121..138
        assert (g.data[121:139, 9:12] == 0).all()
