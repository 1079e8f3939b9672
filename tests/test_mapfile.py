"""map_server YAML + PGM/PNG: nav2 map_io reading rules, map_saver writing rules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from ltmap_cli.cli import cli
from ltmap_cli.errors import ConfigError, MapFileError
from ltmap_cli.io.mapfile import GridMap, read_map_yaml, write_map

YAML_TEMPLATE = """image: {image}
resolution: {resolution}
origin: {origin}
negate: {negate}
occupied_thresh: {occ}
free_thresh: {free}
"""


def _yaml(tmp_path: Path, image: str = "map.pgm", *, mode: str | None = None, negate: int = 0,
          occ: float = 0.65, free: float = 0.196, resolution: float = 0.05,
          origin: str = "[1.0, -2.0, 0.0]", name: str = "map.yaml") -> Path:
    text = YAML_TEMPLATE.format(image=image, resolution=resolution, origin=origin, negate=negate,
                                occ=occ, free=free)
    if mode is not None:
        text += f"mode: {mode}\n"
    path = tmp_path / name
    path.write_text(text)
    return path


def _pgm(path: Path, pixels: np.ndarray) -> None:
    h, w = pixels.shape
    path.write_bytes(b"P5\n# comment\n%d %d\n255\n" % (w, h) + pixels.astype(np.uint8).tobytes())


def _parse_p5(raw: bytes) -> np.ndarray:
    """Minimal independent P5 parser (no comments, as write_map writes it)."""
    parts = raw.split(b"\n", 3)
    assert parts[0] == b"P5" and parts[2] == b"255"
    w, h = (int(v) for v in parts[1].split())
    return np.frombuffer(parts[3], dtype=np.uint8).reshape(h, w)


def _grid() -> GridMap:
    # 3 rows x 4 cols, row 0 = bottom
    data = np.array([[100, 0, -1, 0],
                     [0, 0, 100, -1],
                     [-1, 100, 0, 0]], dtype=np.int8)
    return GridMap(data=data, resolution=0.05, origin=(-1.25, 2.5, 0.3))


def test_trinary_round_trip(tmp_path):
    grid = _grid()
    write_map(tmp_path / "m.yaml", grid)
    back = read_map_yaml(tmp_path / "m.yaml")
    assert back.data.dtype == np.int8
    np.testing.assert_array_equal(back.data, grid.data)
    assert back.resolution == 0.05
    assert back.origin == (-1.25, 2.5, 0.3)
    assert (tmp_path / "m.pgm").exists() and (tmp_path / "m.png").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left


def test_written_files_match_nav2_formula_by_hand(tmp_path):
    # cells between free (20) and occupied (65) thresholds, and out-of-range values, are unknown
    data = np.array([[0, 20, 21, 64, 65, 100, -1, 101]], dtype=np.int16)
    write_map(tmp_path / "m.yaml", GridMap(data=data, resolution=0.1))
    pixels = _parse_p5((tmp_path / "m.pgm").read_bytes())
    np.testing.assert_array_equal(pixels[0], [254, 254, 205, 205, 0, 0, 205, 205])
    # nav2 trinary by hand: occ = 1 - p/255; occ > 0.65 -> 100; occ < 0.196 -> 0; else -1
    expect = []
    for p in pixels[0]:
        occ = 1.0 - p / 255.0
        expect.append(100 if occ > 0.65 else 0 if occ < 0.196 else -1)
    assert expect == [0, 0, -1, -1, 100, 100, -1, -1]
    np.testing.assert_array_equal(read_map_yaml(tmp_path / "m.yaml").data[0], expect)
    yaml_text = (tmp_path / "m.yaml").read_text()
    assert "image: m.pgm\n" in yaml_text and "free_thresh: 0.196\n" in yaml_text
    assert "mode: trinary\n" in yaml_text and "negate: 0\n" in yaml_text
    # the preview PNG holds the same pixels
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "m.png")), pixels)


def test_row_flip_single_cell(tmp_path):
    # a 5 x 4 (H x W) map at 0.5 m, origin (10, 20): occupied cell at x = 11.25, y = 20.75
    # -> col (11.25 - 10) / 0.5 = 2, row from bottom (20.75 - 20) / 0.5 = 1 -> image row 5-1-1 = 3
    data = np.zeros((5, 4), dtype=np.int8)
    col, row = int((11.25 - 10) / 0.5), int((20.75 - 20) / 0.5)
    data[row, col] = 100
    write_map(tmp_path / "m.yaml", GridMap(data=data, resolution=0.5, origin=(10.0, 20.0, 0.0)))
    pixels = _parse_p5((tmp_path / "m.pgm").read_bytes())
    assert list(zip(*np.nonzero(pixels == 0))) == [(3, 2)]
    back = read_map_yaml(tmp_path / "m.yaml")
    assert list(zip(*np.nonzero(back.data == 100))) == [(1, 2)]


def test_read_row_flip_from_image(tmp_path):
    pixels = np.full((3, 2), 254, dtype=np.uint8)
    pixels[0, 1] = 0  # top-right pixel
    _pgm(tmp_path / "map.pgm", pixels)
    grid = read_map_yaml(_yaml(tmp_path))
    np.testing.assert_array_equal(grid.data, [[0, 0], [0, 0], [0, 100]])
    assert (grid.width, grid.height) == (2, 3)


def test_negate(tmp_path):
    _pgm(tmp_path / "map.pgm", np.array([[0, 254, 205, 255]], dtype=np.uint8))
    # negate: occ = p / 255 -> 0: 0 free; 254: 0.996 occupied; 205: 0.804 occupied; 255: occupied
    grid = read_map_yaml(_yaml(tmp_path, negate=1))
    np.testing.assert_array_equal(grid.data[0], [0, 100, 100, 100])
    grid = read_map_yaml(_yaml(tmp_path, negate=0))
    np.testing.assert_array_equal(grid.data[0], [100, 0, -1, 0])


def test_scale_mode_read(tmp_path):
    # occ = 1 - p/255; between thresholds: rint((occ - 0.2) / (0.7 - 0.2) * 100)
    pixels = np.array([[255, 0, 153, 102, 200]], dtype=np.uint8)
    _pgm(tmp_path / "map.pgm", pixels)
    grid = read_map_yaml(_yaml(tmp_path, mode="scale", occ=0.7, free=0.2))
    # 153: occ 0.4 -> 40; 102: occ 0.6 -> 80; 200: occ 0.21569 -> rint(3.14) = 3
    np.testing.assert_array_equal(grid.data[0], [0, 100, 40, 80, 3])


def test_scale_mode_png_alpha_is_unknown(tmp_path):
    rgba = np.zeros((1, 3, 4), dtype=np.uint8)
    rgba[0, :, :3] = [[255, 255, 255], [0, 0, 0], [153, 153, 153]]
    rgba[0, :, 3] = [255, 254, 255]  # middle pixel not fully opaque
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "map.png")
    grid = read_map_yaml(_yaml(tmp_path, "map.png", mode="scale", occ=0.7, free=0.2))
    np.testing.assert_array_equal(grid.data[0], [0, -1, 40])


def test_scale_mode_write_and_read_back(tmp_path):
    data = np.array([[0, 50, 100, -1]], dtype=np.int8)
    write_map(tmp_path / "s.yaml", GridMap(data=data, resolution=0.1), mode="scale", png=False)
    text = (tmp_path / "s.yaml").read_text()
    assert "image: s.png\n" in text and "mode: scale\n" in text
    png = np.asarray(Image.open(tmp_path / "s.png"))
    # grey round(255 * (100 - v) / 100): 255, 128 (127.5 rounds up), 0; unknown 205 transparent
    np.testing.assert_array_equal(png[0, :, 0], [255, 128, 0, 205])
    np.testing.assert_array_equal(png[0, :, 1], [255, 255, 255, 0])
    np.testing.assert_array_equal(_parse_p5((tmp_path / "s.pgm").read_bytes())[0], [255, 128, 0, 205])
    back = read_map_yaml(tmp_path / "s.yaml")
    # 128: occ = 1 - 128/255 = 0.49804 -> rint((0.49804 - 0.196) / 0.454 * 100) = rint(66.53) = 67
    np.testing.assert_array_equal(back.data[0], [0, 67, 100, -1])


def test_raw_mode(tmp_path):
    _pgm(tmp_path / "map.pgm", np.array([[0, 37, 100, 101, 255]], dtype=np.uint8))
    grid = read_map_yaml(_yaml(tmp_path, mode="raw", negate=1))  # raw ignores negate
    np.testing.assert_array_equal(grid.data[0], [0, 37, 100, -1, -1])


def test_rgb_png_input_mean_of_channels(tmp_path):
    rgb = np.array([[[255, 0, 0], [30, 30, 30], [250, 250, 255]]], dtype=np.uint8)
    Image.fromarray(rgb, mode="RGB").save(tmp_path / "map.png")
    grid = read_map_yaml(_yaml(tmp_path, "map.png"))
    # (255+0+0)/3 = 85 -> occ 0.667 > 0.65 -> 100; 30 -> occ 0.88 -> 100; 251.67 -> occ 0.013 -> 0
    np.testing.assert_array_equal(grid.data[0], [100, 100, 0])


def test_trinary_alpha_is_averaged_in(tmp_path):
    la = np.array([[[254, 255], [254, 0], [0, 0]]], dtype=np.uint8)
    Image.fromarray(la, mode="LA").save(tmp_path / "map.png")
    grid = read_map_yaml(_yaml(tmp_path, "map.png"))
    # shade = (3 * L + A) / 4 / 255: (762+255)/1020 = 0.997 -> free; 762/1020 = 0.747 -> occ
    # 0.253 -> unknown; 0 -> occ 1 -> occupied
    np.testing.assert_array_equal(grid.data[0], [0, -1, 100])


def test_ascii_pgm_and_absolute_image_path(tmp_path):
    img = tmp_path / "sub" / "a.pgm"
    img.parent.mkdir()
    img.write_bytes(b"P2\n# c\n3 1\n15\n0 15 # trailing comment\n 12\n")
    grid = read_map_yaml(_yaml(tmp_path, str(img)))
    # maxval 15: 12 -> shade 0.8 -> occ 0.2 -> unknown
    np.testing.assert_array_equal(grid.data[0], [100, 0, -1])


def test_relative_image_is_relative_to_yaml_folder(tmp_path, monkeypatch):
    (tmp_path / "maps").mkdir()
    _pgm(tmp_path / "maps" / "map.pgm", np.array([[0]], dtype=np.uint8))
    yaml_path = _yaml(tmp_path / "maps")
    monkeypatch.chdir(tmp_path)
    assert read_map_yaml(Path("maps") / yaml_path.name).data[0, 0] == 100


def test_mode_defaults_to_trinary_and_negate_bool(tmp_path):
    _pgm(tmp_path / "map.pgm", np.array([[100]], dtype=np.uint8))
    path = tmp_path / "map.yaml"
    path.write_text(_yaml(tmp_path).read_text().replace("negate: 0", "negate: false"))
    # occ = 1 - 100/255 = 0.608: unknown in trinary (it would be 90 in scale)
    assert read_map_yaml(path).data[0, 0] == -1


# ---- errors -------------------------------------------------------------------------------


def test_missing_yaml(tmp_path):
    with pytest.raises(MapFileError, match=r"nope\.yaml: map YAML not found"):
        read_map_yaml(tmp_path / "nope.yaml")


@pytest.mark.parametrize("key", ["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"])
def test_missing_key(tmp_path, key):
    _pgm(tmp_path / "map.pgm", np.zeros((1, 1), np.uint8))
    path = _yaml(tmp_path)
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith(f"{key}:")]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(MapFileError, match=rf"map\.yaml: missing key '{key}'") as info:
        read_map_yaml(path)
    assert "\n" not in str(info.value)


def test_image_missing(tmp_path):
    with pytest.raises(MapFileError, match=r"gone\.pgm: map image not found; check the 'image' key"):
        read_map_yaml(_yaml(tmp_path, "gone.pgm"))


def test_image_unreadable(tmp_path):
    (tmp_path / "map.png").write_bytes(b"this is not an image")
    with pytest.raises(MapFileError, match=r"map\.png: not a readable PGM or PNG image") as info:
        read_map_yaml(_yaml(tmp_path, "map.png"))
    assert "BytesIO" not in str(info.value) and "\n" not in str(info.value)


def test_corrupt_pgm_named_by_a_map_yaml(tmp_path):
    """A .pgm whose bytes are no image at all: the message names the PGM, not PIL's BytesIO."""
    (tmp_path / "map.pgm").write_bytes(b"garbage, not P5\n")
    with pytest.raises(MapFileError) as info:
        read_map_yaml(_yaml(tmp_path, "map.pgm"))
    assert str(info.value) == (
        f"{tmp_path / 'map.pgm'}: not a readable PGM or PNG image (format not recognised); re-export the "
        "map image as PGM or PNG (grayscale or RGB)"
    )
    r = CliRunner().invoke(cli, ["plan", str(tmp_path / "map.yaml"), "--start", "1,1", "--goal", "2,2"])
    assert r.exit_code == 2 and r.output == f"ltmap: error: {info.value}\n"


def test_truncated_pgm(tmp_path):
    (tmp_path / "map.pgm").write_bytes(b"P5\n4 4\n255\n\x00\x00")
    with pytest.raises(MapFileError, match=r"map\.pgm: PGM raster truncated \(2 of 16 bytes\)"):
        read_map_yaml(_yaml(tmp_path))


@pytest.mark.parametrize("res", [0, -0.05])
def test_non_positive_resolution(tmp_path, res):
    _pgm(tmp_path / "map.pgm", np.zeros((1, 1), np.uint8))
    with pytest.raises(MapFileError, match=r"map\.yaml: key 'resolution' must be > 0"):
        read_map_yaml(_yaml(tmp_path, resolution=res))


@pytest.mark.parametrize("origin", ["[1.0, 2.0]", "[1, 2, 3, 4]", "5.0", "[a, 1, 2]"])
def test_bad_origin(tmp_path, origin):
    _pgm(tmp_path / "map.pgm", np.zeros((1, 1), np.uint8))
    with pytest.raises(MapFileError, match=r"map\.yaml: key 'origin' must be .*3"):
        read_map_yaml(_yaml(tmp_path, origin=origin))


def test_bad_mode_and_bad_yaml(tmp_path):
    _pgm(tmp_path / "map.pgm", np.zeros((1, 1), np.uint8))
    with pytest.raises(MapFileError, match=r"key 'mode' must be one of trinary, scale, raw"):
        read_map_yaml(_yaml(tmp_path, mode="fancy"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("image: [unclosed\n")
    with pytest.raises(MapFileError, match=r"bad\.yaml: not valid YAML at line"):
        read_map_yaml(bad)
    bad.write_text("- just\n- a list\n")
    with pytest.raises(MapFileError, match=r"bad\.yaml: not a map_server YAML"):
        read_map_yaml(bad)


def test_write_rejects_bad_parameters(tmp_path):
    with pytest.raises(ConfigError, match="free_thresh 0.25 would make map_server read unknown"):
        write_map(tmp_path / "m.yaml", _grid(), free_thresh=0.25)
    with pytest.raises(ConfigError, match="map mode must be 'trinary', 'scale' or 'raw'"):
        write_map(tmp_path / "m.yaml", _grid(), mode="ternary")
    with pytest.raises(ConfigError, match="negate must be true or false"):
        write_map(tmp_path / "m.yaml", _grid(), negate=2)
    # grey 0 has occ exactly 1.0, which is not > 1.0: map_server would read it unknown
    with pytest.raises(ConfigError, match="occupied_thresh 1.0 would make map_server read occupied"):
        write_map(tmp_path / "m.yaml", _grid(), occupied_thresh=1.0)
    # grey 205 has occ 0.19608 > 0.195: map_server would read unknown as occupied
    with pytest.raises(ConfigError, match="occupied_thresh 0.195 would"):
        write_map(tmp_path / "m.yaml", _grid(), occupied_thresh=0.195, free_thresh=0.19, negate=True)
    with pytest.raises(ValueError, match="non-empty 2D grid"):
        write_map(tmp_path / "m.yaml", GridMap(np.zeros((0, 3), np.int8), 0.05))
    assert list(tmp_path.iterdir()) == []


def test_write_name_without_yaml_suffix(tmp_path):
    write_map(tmp_path / "out" / "long_term", _grid(), png=False)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["long_term.pgm", "long_term.yaml"]
    np.testing.assert_array_equal(read_map_yaml(tmp_path / "out" / "long_term.yaml").data, _grid().data)


def test_pixels_exactly_at_thresholds_are_unknown(tmp_path):
    # negate: occ = p / 255 exactly (51 / 255 == 0.2, 204 / 255 == 0.8); nav2 needs occ < free
    # for free and occ > occupied for occupied, so both boundary pixels are unknown
    _pgm(tmp_path / "map.pgm", np.array([[50, 51, 52, 204, 205]], dtype=np.uint8))
    grid = read_map_yaml(_yaml(tmp_path, negate=1, free=0.2, occ=0.8))
    np.testing.assert_array_equal(grid.data[0], [0, -1, -1, -1, 100])


def test_sixteen_bit_pgm(tmp_path):
    # maxval 1000, big-endian 16 bit: 0 -> occupied, 1000 -> free, 700 -> occ 0.3 -> unknown
    raster = np.array([0, 1000, 700], dtype=">u2").tobytes()
    (tmp_path / "map.pgm").write_bytes(b"P5\n3 1\n1000\n" + raster)
    np.testing.assert_array_equal(read_map_yaml(_yaml(tmp_path)).data[0], [100, 0, -1])


# --------------------------------------------------------------------------------------------
# every mode x negate: written pixels computed by hand, read back by our reader and by nav2's
# formula written out here (occ = shade if negate else 1 - shade; raw: round(shade * 255))

# one row, bottom = row 0: occupied, free, unknown, intermediate cells and out-of-range values
MODE_CELLS = np.array([[100, 0, -1, 20, 21, 50, 64, 65, 37, 101]], dtype=np.int16)

# map_saver with free 0.196 / occupied 0.65: free_int rint(19.6) = 20, occupied_int 65
# trinary: <= 20 -> 254, >= 65 -> 0, else (and -1, 101) -> 205
TRINARY_PIXELS = [0, 254, 205, 254, 205, 205, 205, 0, 205, 205]
# scale: round(255 * (100 - v) / 100): 0, 255, (unknown 205), 204, 201.45 -> 201, 127.5 -> 128,
# 91.8 -> 92, 89.25 -> 89, 160.65 -> 161, (101 unknown 205)
SCALE_PIXELS = [0, 255, 205, 204, 201, 128, 92, 89, 161, 205]
SCALE_ALPHA = [255, 255, 0, 255, 255, 255, 255, 255, 255, 0]
# raw: the cell value; outside 0..100 -> 255
RAW_PIXELS = [100, 0, 255, 20, 21, 50, 64, 65, 37, 255]


def _nav2_cells(pixels, alpha, mode: str, negate: bool, occ_t: float = 0.65, free_t: float = 0.196):
    out = []
    for p, a in zip(pixels, alpha):
        shade = p / 255.0
        occ = shade if negate else 1.0 - shade
        if mode == "raw":
            v = round(shade * 255)
            out.append(v if 0 <= v <= 100 else -1)
        elif mode == "scale" and a != 255:
            out.append(-1)
        elif occ > occ_t:
            out.append(100)
        elif occ < free_t:
            out.append(0)
        elif mode == "scale":
            out.append(int(np.rint((occ - free_t) / (occ_t - free_t) * 100.0)))
        else:
            out.append(-1)
    return out


# what our reader gives back for MODE_CELLS, by hand, whatever negate says:
# trinary: 254 -> occ 0.0039 free; 205 -> occ 0.19608 (not < 0.196) unknown; 0 -> occupied
EXPECT_TRINARY = [100, 0, -1, 0, -1, -1, -1, 100, -1, -1]
# scale: occ = v/100 (within 1/510); < 0.196 -> 0; > 0.65 -> 100; between rint((occ - 0.196)/0.454*100):
# 20: occ 1 - 204/255 = 0.2 -> rint(0.88) = 1; 21: 1 - 201/255 = 0.21176 -> rint(3.47) = 3;
# 50: 0.49804 -> rint(66.53) = 67; 64: 1 - 92/255 = 0.63922 -> rint(97.62) = 98;
# 65: 1 - 89/255 = 0.65098 > 0.65 -> 100; 37: 1 - 161/255 = 0.36863 -> rint(38.02) = 38
EXPECT_SCALE = [100, 0, -1, 1, 3, 67, 98, 100, 38, -1]
# raw: the value itself, out of range -> unknown
EXPECT_RAW = [100, 0, -1, 20, 21, 50, 64, 65, 37, -1]


@pytest.mark.parametrize("negate", [False, True])
@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
def test_every_mode_and_negate_round_trip(tmp_path, mode, negate):
    grid = GridMap(data=MODE_CELLS, resolution=0.05, origin=(-3.0, 4.5, 0.25))
    write_map(tmp_path / "m.yaml", grid, mode=mode, negate=negate)
    text = (tmp_path / "m.yaml").read_text()
    image = "m.png" if mode == "scale" else "m.pgm"
    assert f"image: {image}\n" in text and f"mode: {mode}\n" in text
    assert f"negate: {int(negate)}\n" in text
    assert "occupied_thresh: 0.65\n" in text and "free_thresh: 0.196\n" in text
    assert "origin: [-3.0, 4.5, 0.25]\n" in text and "resolution: 0.05\n" in text

    pgm = _parse_p5((tmp_path / "m.pgm").read_bytes())[0].tolist()
    png = np.asarray(Image.open(tmp_path / "m.png"))
    if mode == "trinary":
        # negate: the negated image, occupied 255, free 1, unknown 50
        hand = [255 - p for p in TRINARY_PIXELS] if negate else TRINARY_PIXELS
        assert pgm == hand and png.tolist() == [hand]
        alpha = [255] * len(hand)
        expect = EXPECT_TRINARY
    elif mode == "scale":
        hand = [255 - p for p in SCALE_PIXELS] if negate else SCALE_PIXELS
        assert pgm == hand
        assert png[0, :, 0].tolist() == hand and png[0, :, 1].tolist() == SCALE_ALPHA
        alpha = SCALE_ALPHA
        expect = EXPECT_SCALE
    else:
        # nav2 ignores negate in raw mode: the same bytes either way
        hand = RAW_PIXELS
        assert pgm == hand and png.tolist() == [hand]
        alpha = [255] * len(hand)
        expect = EXPECT_RAW
    assert _nav2_cells(hand, alpha, mode, negate) == expect
    back = read_map_yaml(tmp_path / "m.yaml")
    assert back.data.tolist() == [expect]
    assert back.resolution == 0.05 and back.origin == (-3.0, 4.5, 0.25)


def test_negate_and_raw_keep_row_order(tmp_path):
    # 2 x 3, row 0 = bottom: image row 0 is the top row (cells 0, 100, 37)
    data = np.array([[-1, 50, 0], [0, 100, 37]], dtype=np.int8)
    write_map(tmp_path / "r.yaml", GridMap(data, 0.1), mode="raw", negate=True, png=False)
    assert _parse_p5((tmp_path / "r.pgm").read_bytes()).tolist() == [[0, 100, 37], [255, 50, 0]]
    assert read_map_yaml(tmp_path / "r.yaml").data.tolist() == data.tolist()
    write_map(tmp_path / "t.yaml", GridMap(data, 0.1), negate=True, png=False)
    assert _parse_p5((tmp_path / "t.pgm").read_bytes()).tolist() == [[1, 255, 50], [50, 50, 1]]
    assert read_map_yaml(tmp_path / "t.yaml").data.tolist() == [[-1, -1, 0], [0, 100, -1]]
