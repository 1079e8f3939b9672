"""map_server maps: YAML + PGM/PNG, read with nav2 map_io semantics, written like map_saver.

``GridMap`` is the project's plain 2D grid, in the ROS ``nav_msgs/OccupancyGrid`` convention:
``data[row, col]`` with row 0 the *bottom* row (lowest y) and col 0 the lowest x; values -1
unknown, 0..100 occupancy percent. ``origin`` is (x, y, yaw) of the lower-left corner of cell
(0, 0). The image on disk has row 0 at the *top*; the reader and writer flip.

Reading follows nav2_map_server ``loadMapYaml`` / ``loadMapFromFile``:

- keys ``image`` (relative to the YAML's folder unless absolute), ``resolution``, ``origin``
  ``[x, y, yaw]``, ``negate``, ``occupied_thresh``, ``free_thresh`` are required; ``mode``
  (``trinary`` | ``scale`` | ``raw``) defaults to ``trinary``;
- shade = mean of the R, G, B channels in [0, 1] (a grey image counts its grey three times); in
  trinary mode an image with an alpha channel averages alpha (1 = opaque) in as a fourth channel.
  The arithmetic is GraphicsMagick Q16's, as nav2 runs it: channels are 16-bit quanta (an 8-bit
  level v is v * 257), their mean is cut to an integer quantum and divided by 65535, so pixels
  exactly at a threshold fall on the same side as in nav2;
- occ = shade if negate else 1 - shade;
- trinary: occ > occupied_thresh -> 100, occ < free_thresh -> 0, else -1;
- scale: a pixel that is not fully opaque -> -1, then as trinary, and in between
  rint((occ - free) / (occupied - free) * 100);
- raw: v = round(shade * 255) (negate ignored), v in 0..100 -> v, else -1.

Writing follows nav2_map_server ``map_saver`` (``tryWriteMapToFile``):

- trinary: cell < 0 or > 100 -> 205; cell <= rint(free_thresh*100) -> 254;
  cell >= rint(occupied_thresh*100) -> 0; else 205. With the default free_thresh 0.196, 205
  reads back as unknown (occ(205) = 0.19608 is not < 0.196), 254 as free and 0 as occupied.
- scale: grey = round(255 * (100 - cell) / 100) (0 -> 255 white, 100 -> 0 black); unknown is
  a transparent pixel. A PGM has no alpha, so in scale mode the map image that the YAML names is
  ``<stem>.png`` (grey + alpha, exactly what map_saver writes in scale mode); ``<stem>.pgm`` is
  still written, with unknown as 205, for tools that want a PGM.
- raw: the byte is the cell value, cell 0..100 -> grey 0..100, unknown (or any value outside
  0..100) -> 255 (map_saver: q = cell / 255 * MaxRGB, else MaxRGB). nav2 reads it back
  exactly (v = round(shade * 255), 0..100 -> v, else -1); the YAML names the PGM.
- negate (map_saver always writes ``negate: 0``; we add it): in trinary and scale mode the image
  is the negated one, every grey g (and the scale PGM's unknown 205) written as 255 - g, so that
  occ = shade reads back the same cells (trinary: occupied 255, free 1, unknown 50). nav2 ignores
  negate in raw mode, so raw pixels do not change with it and the YAML just says ``negate: 1``
  (ROS 1 map_server would apply it in raw mode and read 255 - v: write raw maps for ROS 1
  without negate).
- The YAML carries full float precision (map_saver rounds to 3 significant digits, which moves
  origins of large maps).

Preview PNG: in trinary and raw mode ``<stem>.png`` holds the very same pixels as ``<stem>.pgm`` (one
pixel per cell, no upscaling: image viewers zoom, and the file stays a faithful copy).
"""

from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ltmap_cli.errors import ConfigError, LtmapWarning, MapFileError, shown
from ltmap_cli.io.atomic import atomic_path, write_bytes_atomic, write_text_atomic

from ..thresholds import FREE_THRESH, OCCUPIED_THRESH

UNKNOWN = -1
FREE = 0
OCCUPIED = 100

MODES = ("trinary", "scale", "raw")
REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")

# the largest map read before anything is decoded or allocated: 64 M cells (8000 x 8000, 400 m
# x 400 m at 0.05 m) need about 1 GB in build-static and replay; raise it with --max-cells
DEFAULT_MAX_CELLS = 64_000_000
MAX_MAP_YAML_BYTES = 2**20  # a map_server YAML is a few lines

# map_saver's grey levels (trinary)
PIXEL_OCCUPIED = 0
PIXEL_FREE = 254
PIXEL_UNKNOWN = 205


@dataclass
class GridMap:
    data: np.ndarray  # int8 (H, W): -1 unknown, 0..100; row 0 = bottom (lowest y)
    resolution: float  # m / cell
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y, yaw of cell (0,0)'s lower-left corner

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])


# --------------------------------------------------------------------------------------------
# reading


def _yaml_number(doc: dict, key: str, path: Path) -> float:
    value = doc[key]
    if isinstance(value, bool):
        value = None  # a YAML true/false is not a number here
    try:
        number = float(value)  # ints, floats and numeric strings, as yaml-cpp's as<double>
    except (TypeError, ValueError):
        raise MapFileError(
            f"{path}: key '{key}' must be a number, got {shown(doc[key])}; fix the map YAML"
        ) from None
    if not math.isfinite(number):
        raise MapFileError(f"{path}: key '{key}' must be a finite number, got {shown(doc[key])}; fix the map YAML")
    return number


def _load_yaml(path: Path) -> dict:
    from . import safe_yaml

    if not path.exists():
        raise MapFileError(f"{path}: map YAML not found; give the path of an existing map_server .yaml file")
    doc = safe_yaml.load_file(path, "map YAML", MapFileError, max_bytes=MAX_MAP_YAML_BYTES)
    if not isinstance(doc, dict):
        raise MapFileError(
            f"{path}: not a map_server YAML (expected a mapping with keys {', '.join(REQUIRED_KEYS)})"
        )
    return doc


QUANTUM_MAX = 65535  # GraphicsMagick Q16 (the build nav2 uses on Ubuntu / Debian)


def _pgm_header(raw: bytes, path: Path) -> tuple[int, int, int, int]:
    """(width, height, maxval, offset of the raster) of a P5 / P2 PGM from its first bytes."""
    tokens: list[bytes] = []
    pos = 2
    n = len(raw)
    while len(tokens) < 3:
        while pos < n and raw[pos : pos + 1].isspace():
            pos += 1
        if pos < n and raw[pos : pos + 1] == b"#":
            while pos < n and raw[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < n and not raw[pos : pos + 1].isspace() and raw[pos : pos + 1] != b"#":
            pos += 1
        if start == pos:
            raise MapFileError(f"{path}: truncated PGM header; re-export the map image")
        tokens.append(raw[start:pos])
    try:
        width, height, maxval = (int(t) for t in tokens)
    except ValueError:
        raise MapFileError(f"{path}: bad PGM header {shown(b' '.join(tokens))}; re-export the map image") from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise MapFileError(
            f"{path}: bad PGM header (width {width}, height {height}, maxval {maxval}); "
            "re-export the map image"
        )
    return width, height, maxval, pos


def _parse_pgm(raw: bytes, path: Path) -> tuple[np.ndarray, int]:
    """Decode a P5 (binary) or P2 (ASCII) PGM: (pixels (H, W) as stored, uint8 or uint16, maxval)."""
    magic = raw[:2]
    width, height, maxval, pos = _pgm_header(raw, path)
    count = width * height
    if magic == b"P5":
        pos += 1  # exactly one whitespace byte separates maxval from the raster
        dtype = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
        need = count * dtype.itemsize
        if len(raw) - pos < need:
            raise MapFileError(
                f"{path}: PGM raster truncated ({len(raw) - pos} of {need} bytes); re-export the map image"
            )
        pixels = np.frombuffer(raw, dtype=dtype, count=count, offset=pos)
    else:  # P2
        body = re.sub(rb"#[^\n\r]*", b" ", raw[pos:])
        try:
            pixels = np.array(body.split()[:count], dtype=np.int64)
        except ValueError:
            raise MapFileError(f"{path}: non-numeric pixel in ASCII PGM; re-export the map image") from None
        if pixels.size < count:
            raise MapFileError(
                f"{path}: PGM raster truncated ({pixels.size} of {count} pixels); re-export the map image"
            )
        pixels = np.clip(pixels, 0, 65535).astype(np.uint16)
    return pixels.reshape(height, width), maxval


def _too_big(path: Path, width: int, height: int, max_cells: int) -> MapFileError:
    return MapFileError(
        f"{path}: the map image is {width} x {height} = {width * height:.3g} pixels, more than --max-cells "
        f"{max_cells:.3g} (decoding it would need about {width * height * 20 / 2**30:.1f} GB); check the "
        f"image, or raise --max-cells if the map is really that large")


def _read_image(path: Path, max_cells: int = DEFAULT_MAX_CELLS) -> tuple[np.ndarray, str, int]:
    """The map image's pixels as stored: (array, kind, maxval) with kind ``pgm`` ((H, W), levels
    0..maxval), ``I`` ((H, W) 16-bit grey), or a PIL mode ``L`` / ``LA`` / ``RGB`` / ``RGBA``
    ((H, W[, C]) uint8). Only a regular file is opened; the size in its header is checked against
    ``max_cells`` before any pixel is decoded."""
    from .safe_yaml import check_regular_file

    if not path.exists():
        raise MapFileError(f"{path}: map image not found; check the 'image' key of the map YAML")
    check_regular_file(path, "map image", MapFileError, max_bytes=max_cells * 8 + 2**20)
    try:
        with path.open("rb") as f:
            head = f.read(1 << 20)  # a PGM header with long comments is still read whole
            if head[:2] in (b"P5", b"P2"):
                width, height, _maxval, _pos = _pgm_header(head, path)
                if width * height > max_cells:
                    raise _too_big(path, width, height, max_cells)
                f.seek(0)
                raw = f.read()
    except OSError as exc:
        raise MapFileError(f"{path}: cannot read the map image ({exc.strerror or exc}); check the file") from None
    if head[:2] in (b"P5", b"P2"):
        pixels, maxval = _parse_pgm(raw, path)
        return pixels, "pgm", maxval

    import warnings

    from PIL import Image, UnidentifiedImageError

    pil_bound = Image.MAX_IMAGE_PIXELS
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            Image.MAX_IMAGE_PIXELS = None  # max_cells is the bound, checked on the header below
            with Image.open(path) as img:  # reads the header only
                width, height = img.size
                if width * height > max_cells:
                    raise _too_big(path, width, height, max_cells)
                img.load()
                mode = img.mode
                if mode == "P":
                    img = img.convert("RGBA" if "transparency" in img.info else "RGB")
                elif mode == "PA":
                    img = img.convert("RGBA")
                elif mode == "1":
                    img = img.convert("L")
                elif mode in ("CMYK", "YCbCr", "LAB", "HSV", "RGBX"):
                    img = img.convert("RGB")
                elif mode in ("La", "RGBa"):
                    img = img.convert("LA" if mode == "La" else "RGBA")
                arr = np.asarray(img)
                mode = img.mode
    except MapFileError:
        raise
    except Image.DecompressionBombError:
        raise MapFileError(f"{path}: the map image is too large to decode safely (a decompression bomb?); "
                           f"check the image, or raise --max-cells") from None
    except UnidentifiedImageError:
        raise MapFileError(
            f"{path}: not a readable PGM or PNG image (format not recognised); re-export the map image "
            "as PGM or PNG (grayscale or RGB)"
        ) from None
    except (OSError, ValueError, SyntaxError, MemoryError) as exc:
        raise MapFileError(
            f"{path}: not a readable PGM or PNG image ({shown(str(exc))}); re-export the map image as PGM "
            "or PNG (grayscale or RGB)"
        ) from None
    finally:
        Image.MAX_IMAGE_PIXELS = pil_bound
    if mode.startswith("I"):  # 16-bit grey (a 16-bit PNG opens as mode I / I;16)
        return arr, "I", QUANTUM_MAX
    if mode not in ("L", "LA", "RGB", "RGBA"):
        raise MapFileError(f"{path}: unsupported image mode {mode}; use a PGM or PNG grayscale/RGB image")
    return arr, mode, 255


def _quanta(pixels: np.ndarray, kind: str, maxval: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(colour (h, W, 3), alpha (h, W) or None) as Q16 quanta (uint32, 0..65535) of some rows."""
    if kind == "pgm":
        p = np.clip(pixels.astype(np.int64), 0, maxval)
        grey = ((p * QUANTUM_MAX + maxval // 2) // maxval).astype(np.uint32)  # maxval 255: exactly v * 257
        return np.repeat(grey[:, :, None], 3, axis=2), None
    if kind == "I":
        grey = np.clip(pixels.astype(np.int64), 0, QUANTUM_MAX).astype(np.uint32)
        return np.repeat(grey[:, :, None], 3, axis=2), None
    quanta = pixels.astype(np.uint32) * 257  # 8-bit level -> Q16 quantum
    if kind == "L":
        return np.repeat(quanta[:, :, None], 3, axis=2), None
    if kind == "LA":
        return np.repeat(quanta[:, :, :1], 3, axis=2), quanta[:, :, 1]
    if kind == "RGB":
        return quanta, None
    return quanta[:, :, :3], quanta[:, :, 3]


STRIPE_PIXELS = 1 << 20  # pixels converted at once: the arithmetic's arrays stay ~40 MB


def _image_cells(path: Path, mode: str, negate: bool, occupied_thresh: float, free_thresh: float,
                 max_cells: int, saver_grey: int | None = None) -> tuple[np.ndarray, tuple | None]:
    """int8 cells of the map image in image row order, converted a stripe of rows at a time, and
    (what nav2 made of them, how many) for the pixels of ``saver_grey`` kept unknown (or None)."""
    pixels, kind, maxval = _read_image(path, max_cells)
    height, width = pixels.shape[:2]
    cells = np.empty((height, width), dtype=np.int8)
    rows = max(1, STRIPE_PIXELS // max(width, 1))
    kept, all_free = 0, True
    for r0 in range(0, height, rows):
        colour, alpha = _quanta(pixels[r0 : r0 + rows], kind, maxval)
        part = cells_from_image(colour, alpha, mode, negate, occupied_thresh, free_thresh)
        if saver_grey is not None:
            mask = (colour == saver_grey * 257).all(axis=2) & (part != UNKNOWN)  # levels are Q16 quanta
            if alpha is not None:
                mask &= alpha == QUANTUM_MAX
            if mask.any():
                kept += int(mask.sum())
                all_free &= bool((part[mask] == FREE).all())
                part[mask] = UNKNOWN
        cells[r0 : r0 + rows] = part
    return cells, (("free" if all_free else "known"), kept) if kept else None


def cells_from_image(
    colour: np.ndarray,
    alpha: np.ndarray | None,
    mode: str,
    negate: bool,
    occupied_thresh: float,
    free_thresh: float,
) -> np.ndarray:
    """nav2 ``loadMapFromFile``'s per-pixel rule, in its arithmetic. ``colour`` (H, W, 3) and
    ``alpha`` (H, W) are Q16 quanta (alpha 65535 = opaque) with image row 0 at the top; returns
    int8 cells in image row order (no flip)."""
    total = colour.astype(np.int64).sum(axis=2)
    count = 3
    if mode == "trinary" and alpha is not None:
        total = total + alpha
        count = 4
    # nav2: scaleQuantumToDouble(sum / n): the mean is cut to an integer Quantum, then / MaxRGB
    shade = (total // count).astype(np.float64) / QUANTUM_MAX
    occ = shade if negate else 1.0 - shade
    if mode == "raw":
        value = np.floor(shade * 255.0 + 0.5)  # std::round on non-negative values
        return np.where(value <= OCCUPIED, value, UNKNOWN).astype(np.int8)
    cells = np.full(shade.shape, UNKNOWN, dtype=np.int8)
    if mode == "scale":
        between = np.rint((occ - free_thresh) / (occupied_thresh - free_thresh) * 100.0)
        cells[:] = np.clip(between, -128, 127).astype(np.int8)
    cells[occ < free_thresh] = FREE
    cells[occupied_thresh < occ] = OCCUPIED
    if mode == "scale" and alpha is not None:
        cells[alpha < QUANTUM_MAX] = UNKNOWN
    return cells


def read_map_yaml(path: str | Path, max_cells: int = DEFAULT_MAX_CELLS, saver_unknown: bool = False) -> GridMap:
    """Read a map_server YAML and its image with nav2 map_io semantics (modes trinary, scale,
    raw; negate; occupied_thresh / free_thresh). Raises MapFileError with a one-line message;
    an image of more than ``max_cells`` pixels is refused from its header, before decoding.

    ``saver_unknown``: in trinary mode, pixels of map_saver's unknown grey (205; 50 negated) are
    unknown whatever the thresholds say. nav2's map_saver wrote ``free_thresh: 0.25`` until 2025
    (navigation2 #5278), under which nav2 reads its own unknown grey (occ 0.196) as free; the
    pixel values of a trinary image are constants, so the thresholds cannot mean that. The cells
    this changes are reported as one ``LtmapWarning``."""
    path = Path(path)
    doc = _load_yaml(path)
    for key in REQUIRED_KEYS:
        if key not in doc or doc[key] is None:
            raise MapFileError(
                f"{path}: missing key '{key}'; a map_server YAML needs {', '.join(REQUIRED_KEYS)}"
            )

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise MapFileError(
            f"{path}: key 'image' must be the image file name, got {shown(image)}; fix the map YAML"
        )
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path

    resolution = _yaml_number(doc, "resolution", path)
    if resolution <= 0.0:
        raise MapFileError(
            f"{path}: key 'resolution' must be > 0 (metres per cell), got {shown(doc['resolution'])}"
        )

    origin = doc["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise MapFileError(
            f"{path}: key 'origin' must be a list of 3 numbers [x, y, yaw], got {shown(origin)}; fix the map YAML"
        )
    origin_values = []
    for item in origin:
        if isinstance(item, bool) or not isinstance(item, (int, float, str)):
            raise MapFileError(f"{path}: key 'origin' must be 3 numbers [x, y, yaw], got {shown(origin)}")
        try:
            number = float(item)
        except ValueError:
            raise MapFileError(
                f"{path}: key 'origin' must be 3 numbers [x, y, yaw], got {shown(origin)}"
            ) from None
        if not math.isfinite(number):
            raise MapFileError(f"{path}: key 'origin' must be 3 finite numbers, got {shown(origin)}")
        origin_values.append(number)

    negate_raw = doc["negate"]
    if isinstance(negate_raw, (bool, int)):
        negate = bool(negate_raw)
    else:
        raise MapFileError(f"{path}: key 'negate' must be 0 or 1 (or false/true), got {shown(negate_raw)}")

    occupied_thresh = _yaml_number(doc, "occupied_thresh", path)
    free_thresh = _yaml_number(doc, "free_thresh", path)

    mode = doc.get("mode", "trinary")
    if mode is None:
        mode = "trinary"
    if mode not in MODES:
        raise MapFileError(f"{path}: key 'mode' must be one of {', '.join(MODES)}, got {shown(mode)}")
    if mode == "scale" and not free_thresh < occupied_thresh:
        raise MapFileError(
            f"{path}: scale mode needs free_thresh < occupied_thresh, got {free_thresh} and {occupied_thresh}"
        )

    grey = (255 - PIXEL_UNKNOWN if negate else PIXEL_UNKNOWN) if saver_unknown and mode == "trinary" else None
    cells, kept = _image_cells(image_path, mode, negate, occupied_thresh, free_thresh, max_cells, grey)
    if kept:
        warnings.warn(LtmapWarning(
            f"{path}: {kept[1]} cells of map_saver's unknown grey {grey} are kept unknown although "
            f"free_thresh {free_thresh:g} / occupied_thresh {occupied_thresh:g} make them {kept[0]} in nav2 "
            f"(map_saver wrote free_thresh 0.25 until 2025; free_thresh 0.196 in the YAML says what it meant)"),
            stacklevel=2)  # fmt: skip
    data = np.ascontiguousarray(cells[::-1])  # image row 0 is the top of the map
    return GridMap(data=data, resolution=resolution, origin=tuple(origin_values))


# --------------------------------------------------------------------------------------------
# writing


def _yaml_scalar(text: str) -> str:
    if re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*", text):
        return text
    return json.dumps(text)  # a JSON string is a valid YAML double-quoted scalar


def _yaml_float(value: float) -> str:
    return repr(float(value))


def trinary_pixels(data: np.ndarray, occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """map_saver's trinary grey level per cell (same row order as ``data``)."""
    cells = data.astype(np.int16)
    free_int = int(np.rint(free_thresh * 100.0))
    occupied_int = int(np.rint(occupied_thresh * 100.0))
    pixels = np.full(cells.shape, PIXEL_UNKNOWN, dtype=np.uint8)
    known = (cells >= 0) & (cells <= 100)
    pixels[known & (cells <= free_int)] = PIXEL_FREE
    pixels[known & (cells > free_int) & (cells >= occupied_int)] = PIXEL_OCCUPIED
    return pixels


def scale_pixels(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """map_saver's scale grey level and alpha per cell: grey round(255 * (100 - v) / 100), alpha
    255; unknown (outside 0..100) grey 205, alpha 0."""
    cells = data.astype(np.int32)
    known = (cells >= 0) & (cells <= 100)
    grey = np.where(known, (255 * (100 - cells) + 50) // 100, PIXEL_UNKNOWN).astype(np.uint8)
    alpha = np.where(known, 255, 0).astype(np.uint8)
    return grey, alpha


def raw_pixels(data: np.ndarray) -> np.ndarray:
    """map_saver's raw grey level per cell: the cell value for 0..100, 255 for anything else."""
    cells = data.astype(np.int32)
    known = (cells >= 0) & (cells <= 100)
    return np.where(known, cells, 255).astype(np.uint8)


def _check_trinary_levels(occupied_thresh: float, free_thresh: float, negate: bool) -> None:
    """The three trinary grey levels must read back (with the reader's own arithmetic) as
    occupied, free and unknown; else ConfigError naming the threshold at fault."""
    levels = np.array([PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN], dtype=np.uint32)
    if negate:
        levels = 255 - levels
    colour = np.repeat((levels * 257)[None, :, None], 3, axis=2)
    occupied, free, unknown = (int(v) for v in cells_from_image(
        colour, None, "trinary", negate, occupied_thresh, free_thresh)[0])  # fmt: skip
    if free != FREE or unknown == FREE:
        raise ConfigError(
            f"free_thresh {free_thresh} would make map_server read unknown (grey 205) or free (grey 254) "
            f"wrongly; use a value in (0.0039, 0.1960], e.g. 0.196"
        )
    if occupied != OCCUPIED or unknown == OCCUPIED:
        raise ConfigError(
            f"occupied_thresh {occupied_thresh} would make map_server read occupied (grey 0) or unknown "
            f"(grey 205) wrongly; use a value in [0.1961, 1.0), e.g. 0.65"
        )


def _pgm_bytes(pixels: np.ndarray) -> bytes:
    height, width = pixels.shape
    return b"P5\n%d %d\n255\n" % (width, height) + np.ascontiguousarray(pixels, dtype=np.uint8).tobytes()


def _write_png(path: Path, pixels: np.ndarray, alpha: np.ndarray | None = None) -> None:
    from PIL import Image

    # a 2D uint8 array becomes mode L, an (H, W, 2) one mode LA
    array = pixels if alpha is None else np.stack([pixels, alpha], axis=2)
    img = Image.fromarray(np.ascontiguousarray(array, dtype=np.uint8))
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")


def map_file_paths(yaml_path: str | Path) -> tuple[Path, Path, Path]:
    """(yaml, pgm, png) paths that ``write_map`` writes for ``yaml_path``: a ``.yaml`` / ``.yml``
    suffix is kept, any other name gets ``.yaml`` appended."""
    yaml_path = Path(yaml_path)
    if yaml_path.suffix.lower() in (".yaml", ".yml"):
        stem = yaml_path.with_suffix("")
    else:
        stem = yaml_path
        yaml_path = Path(f"{yaml_path}.yaml")
    return yaml_path, Path(f"{stem}.pgm"), Path(f"{stem}.png")


def write_map(
    yaml_path: str | Path,
    grid: GridMap,
    mode: str = "trinary",
    occupied_thresh: float = OCCUPIED_THRESH,
    free_thresh: float = FREE_THRESH,
    png: bool = True,
    negate: bool = False,
) -> None:
    """Write ``<stem>.pgm`` + ``<stem>.yaml`` (+ ``<stem>.png``) atomically, like map_saver.

    trinary: occupied 0, free 254, unknown 205 in the PGM, which the YAML names; ``png`` adds a
    preview with the same pixels. scale: grey 255..0 for 0..100; the YAML names ``<stem>.png``
    (grey + alpha, unknown transparent: nav2 needs the alpha to see unknown in scale mode), so the
    PNG is written whatever ``png`` says; the PGM (unknown 205) is written too. raw: the cell
    value as the grey level, unknown 255, in the PGM, which the YAML names (``png``: same pixels).
    ``negate``: trinary and scale images are negated (255 - g) and the YAML says ``negate: 1``;
    raw pixels are unchanged (nav2 ignores negate in raw mode). The images are written before
    the YAML, so a YAML on disk never names a missing image.

    Raises ConfigError for a bad mode or thresholds, ValueError for an empty or non-2D grid.
    """
    if mode not in MODES:
        raise ConfigError(f"map mode must be 'trinary', 'scale' or 'raw', got {shown(mode)}")
    if not isinstance(negate, (bool, np.bool_, int, np.integer)) or negate not in (0, 1):
        raise ConfigError(f"negate must be true or false, got {negate!r}")
    negate = bool(negate)
    if not (0.0 <= free_thresh < occupied_thresh <= 1.0):
        raise ConfigError(
            f"map thresholds need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh {free_thresh} "
            f"and occupied_thresh {occupied_thresh}"
        )
    if mode == "trinary":
        _check_trinary_levels(occupied_thresh, free_thresh, negate)
    data = np.asarray(grid.data)
    if data.ndim != 2 or data.size == 0:
        raise ValueError(f"write_map needs a non-empty 2D grid, got shape {data.shape}")
    if not np.issubdtype(data.dtype, np.integer):
        raise ValueError(f"write_map needs integer cells (-1, 0..100), got dtype {data.dtype}")
    resolution = float(grid.resolution)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise ValueError(f"write_map needs a resolution > 0, got {grid.resolution}")
    origin = tuple(float(v) for v in grid.origin)
    if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
        raise ValueError(f"write_map needs a finite origin (x, y, yaw), got {grid.origin}")

    yaml_file, pgm_file, png_file = map_file_paths(yaml_path)
    image_rows = data[::-1]  # image row 0 is the top of the map

    if mode == "scale":
        grey, alpha = scale_pixels(image_rows)
        if negate:
            grey = 255 - grey
        write_bytes_atomic(pgm_file, _pgm_bytes(grey))
        _write_png(png_file, grey, alpha)
        image_name = png_file.name
    else:
        if mode == "trinary":
            pixels = trinary_pixels(image_rows, occupied_thresh, free_thresh)
            if negate:
                pixels = 255 - pixels
        else:  # raw: nav2 reads round(shade * 255) whatever negate says
            pixels = raw_pixels(image_rows)
        write_bytes_atomic(pgm_file, _pgm_bytes(pixels))
        if png:
            _write_png(png_file, pixels)
        image_name = pgm_file.name

    text = (
        f"image: {_yaml_scalar(image_name)}\n"
        f"mode: {mode}\n"
        f"resolution: {_yaml_float(resolution)}\n"
        f"origin: [{', '.join(_yaml_float(v) for v in origin)}]\n"
        f"negate: {int(negate)}\n"
        f"occupied_thresh: {_yaml_float(occupied_thresh)}\n"
        f"free_thresh: {_yaml_float(free_thresh)}\n"
    )
    write_text_atomic(yaml_file, text)
