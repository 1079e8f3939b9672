"""Depth images recorded through image_transport: ``sensor_msgs/CompressedImage``.

Hours of RGB-D logs are mostly recorded compressed, on the transports' topics next to the image:

- ``<image>/compressedDepth`` (compressed_depth_image_transport): 12 bytes of ``ConfigHeader``
  (int32 format, float32 depthParam[2], little-endian as the publisher's memcpy wrote them), then
  the pixels, by the message's ``format`` (``"16UC1; compressedDepth png"``, ``"...; compressedDepth
  rvl"``, or ``"16UC1; compressedDepth"`` from the older plugin, which wrote PNG only): a PNG of
  16-bit grey pixels, or RVL (run lengths and variable-length deltas, A. D. Wilson, 2017) after 8
  bytes of width and height. 16UC1 pixels are the millimetres themselves (lossless); 32FC1 images
  are quantized inverse depth: v != 0 is ``depthParam[0] / (v - depthParam[1])`` m, 0 is invalid.
- ``<image>/compressed`` (compressed_image_transport) of a 16-bit image with ``png`` in its format
  (``"16UC1; png compressed mono16"``): a plain PNG of the pixels. JPEG is lossy and 8-bit: refused.

The size is read from the PNG's IHDR or the RVL header before anything is decompressed and must be
the CameraInfo's (or at most ``MAX_PIXELS`` when the CameraInfo gives none): a few kB declaring
14000 x 14000 pixels are refused, not decoded.
"""

from __future__ import annotations

import io
import struct

import numpy as np

from ..errors import LogReadError

CONFIG_HEADER = 12  # bytes of compressed_depth_image_transport's ConfigHeader before the pixels
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_PIXELS = 1 << 24  # pixels of a compressed depth image whose CameraInfo gives no size (4096 x 4096)
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
MAX_FORMAT_CHARS = 80  # of a message's format string, read and shown


class DamagedPayload(ValueError):
    """The compressed pixels of one message cannot be decoded (a damaged message: skipped)."""


def decode(data: bytes, fmt: str, size: tuple[int, int] | None, where: str) -> np.ndarray:
    """The (H, W) pixels of a CompressedImage depth message: uint16 (16UC1 / mono16: millimetres
    or the camera's depth units, 0 invalid) or float32 metres (32FC1, NaN invalid). ``size``:
    (width, height) from its CameraInfo, None when that gives none. ``LogReadError`` for what no
    message of the topic can be (a colour or lossy image, a size that is not the camera's);
    ``DamagedPayload`` for pixels that cannot be decoded."""
    if not isinstance(data, bytes):
        data = bytes(data)  # (a deserializer's uint8 array)
    fmt = str(fmt)
    if len(fmt) > MAX_FORMAT_CHARS:  # (a format string is a few words: one line stays one line)
        fmt = fmt[:MAX_FORMAT_CHARS] + "..."
    encoding, _, rest = fmt.partition(";")
    encoding, rest = encoding.strip(), rest.strip()
    if encoding not in DEPTH_ENCODINGS:
        raise LogReadError(f"compressed image {where} has format {fmt!r}: not a depth image (16UC1, mono16 or "
                           f"32FC1); choose the depth topic with --depth-topic")  # fmt: skip
    if "compressedDepth" in rest or (not rest and data[CONFIG_HEADER:CONFIG_HEADER + 8] == PNG_SIGNATURE):
        if len(data) <= CONFIG_HEADER:
            raise DamagedPayload(f"{len(data)} bytes, less than compressedDepth's {CONFIG_HEADER}-byte header")
        _, quant_a, quant_b = struct.unpack_from("<iff", data, 0)
        body = memoryview(data)[CONFIG_HEADER:]
        pixels = _rvl(body, size, fmt, where) if "rvl" in rest.split() else _png(body, size, fmt, where)
        if encoding != "32FC1":
            return pixels
        depth = np.float32(quant_a) / (pixels.astype(np.float32) - np.float32(quant_b))
        depth[pixels == 0] = np.nan
        return depth
    if "png" in rest.split() or (not rest and bytes(data[:8]) == PNG_SIGNATURE):
        if encoding == "32FC1":
            raise LogReadError(f"compressed image {where} has format {fmt!r}: a 32FC1 image is not stored as a plain "
                               f"PNG; its compressedDepth topic holds it")  # fmt: skip
        return _png(memoryview(data), size, fmt, where)
    raise LogReadError(f"compressed image {where} has format {fmt!r}: ltmap reads depth compressed as PNG or RVL "
                       f"(image_transport's compressedDepth, or compressed with png); JPEG loses depth. Record "
                       f"the compressedDepth topic, or choose another with --depth-topic")  # fmt: skip


def _check_size(w: int, h: int, size: tuple[int, int] | None, fmt: str, where: str) -> None:
    if size is not None and size != (0, 0):
        if (w, h) != size:
            raise LogReadError(f"depth image {where} ({fmt}) is {w}x{h} but its CameraInfo says {size[0]}x{size[1]}; "
                               f"pair it with the right camera_info topic")  # fmt: skip
    elif w * h > MAX_PIXELS or w == 0 or h == 0:
        raise LogReadError(f"depth image {where} ({fmt}) declares {w}x{h} pixels and its CameraInfo gives no size; "
                           f"at most {MAX_PIXELS} pixels are decoded: the message is corrupt or the CameraInfo lacks "
                           f"width and height")  # fmt: skip


def _png(png: memoryview, size: tuple[int, int] | None, fmt: str, where: str) -> np.ndarray:
    if len(png) < 26 or bytes(png[:8]) != PNG_SIGNATURE or bytes(png[12:16]) != b"IHDR":
        raise DamagedPayload("the pixels are not a PNG")
    w, h = struct.unpack_from(">II", png, 16)
    depth_bits, colour = png[24], png[25]
    if colour != 0 or depth_bits != 16:
        raise LogReadError(f"depth image {where} ({fmt}) is a PNG of {depth_bits}-bit {'grey' if colour == 0 else 'colour'}"
                           f" pixels, not 16-bit grey: not a depth image; choose the depth topic with --depth-topic")  # fmt: skip
    _check_size(w, h, size, fmt, where)
    from PIL import Image

    try:
        with Image.open(io.BytesIO(png)) as im:
            im.load()
            if im.size != (w, h) or im.mode not in ("I;16", "I;16B", "I;16L", "I"):
                raise DamagedPayload(f"the PNG decodes to {im.mode} {im.size[0]}x{im.size[1]}")
            pixels = np.asarray(im)
    except DamagedPayload:
        raise
    except Exception as err:  # noqa: BLE001 - Pillow raises OSError, SyntaxError, ValueError, zlib errors
        raise DamagedPayload(f"its PNG cannot be decoded ({str(err).strip() or type(err).__name__})") from None
    return pixels.astype(np.uint16, copy=False) if pixels.dtype != np.uint16 or not pixels.dtype.isnative \
        else pixels  # fmt: skip


def _rvl(body: memoryview, size: tuple[int, int] | None, fmt: str, where: str) -> np.ndarray:
    if len(body) < 8:
        raise DamagedPayload("the RVL pixels lack their 8-byte size")
    w, h = struct.unpack_from("<II", body, 0)
    _check_size(w, h, size, fmt, where)
    stream = bytes(body[8:])
    pad = (-len(stream)) % 4
    words = np.frombuffer(stream + b"\x00" * pad, dtype="<u4").astype(np.uint32)
    out = np.empty(w * h, dtype=np.uint16)
    from .rvl import rvl_decode  # (numba: compiled on first use, only for logs recorded with RVL)

    status = rvl_decode(words, out)
    if status != 0:
        raise DamagedPayload("its RVL stream " + ("ends before the image does" if status == 1
                                                   else "runs past the image's pixels"))  # fmt: skip
    return out.reshape(h, w)
