"""Limits on what a log may make ltmap allocate, checked before the work.

A chunk or message declares its uncompressed size; a declared size over the limit is refused
before anything is read or decompressed, and decompression stops at the declared size (a chunk
that expands to more is corrupt). Real logs stay far below the limit: a 640x480 depth image is
0.6 MB, a dense lidar cloud tens of MB, a bag chunk a few MB.
"""

from __future__ import annotations

from ..errors import LogReadError, first_line

DEFAULT_MAX_MESSAGE_MB = 256.0  # replay.max_message_mb: a chunk or a message, uncompressed
PIECE = 16 * 2**20  # decompressed at most this much at a time


class TooLargeError(LogReadError):
    """A chunk or message declares more bytes than ``replay.max_message_mb`` allows."""


class DecompressError(ValueError):
    """Compressed data that is corrupt, or expands to other than its declared size."""


def too_large(where: str, size: int, limit: int) -> TooLargeError:
    return TooLargeError(
        f"{where} declares {size / 2**20:,.1f} MB uncompressed, more than replay.max_message_mb "
        f"({limit / 2**20:g} MB) allows: the log is corrupt or hostile; if it is real, raise the limit with "
        f"--set replay.max_message_mb=N")


def decompress(compression: str, data: bytes, declared: int, limit: int, where: str) -> bytes:
    """``data`` decompressed (``none``/"" as is, ``bz2``, ``lz4``, ``zstd``), never more than
    ``declared`` bytes: ``TooLargeError`` when ``declared`` exceeds ``limit``, ``DecompressError``
    when the data is corrupt or expands to more or less than ``declared``."""
    if declared > limit:
        raise too_large(where, declared, limit)
    comp = compression or "none"
    if comp == "none":
        if len(data) != declared:
            raise DecompressError(f"holds {len(data)} bytes, not the {declared} it declares")
        return data
    out = bytearray()
    try:
        if comp == "bz2":
            import bz2

            d = bz2.BZ2Decompressor()
            out = d.decompress(data, max_length=declared + 1)
            ended = d.eof
        elif comp == "lz4":
            import lz4.frame

            d = lz4.frame.LZ4FrameDecompressor()
            out = d.decompress(data, max_length=declared + 1)
            ended = d.eof
        elif comp == "zstd":
            import io

            import zstandard

            # one frame that says its size (what MCAP writers make): one call into a buffer of
            # that size, once the size is checked against the declared one
            size = zstandard.frame_content_size(data)
            if size > declared:
                raise DecompressError(f"expands to more than the {declared} bytes it declares")
            if size == declared:
                try:
                    one = zstandard.ZstdDecompressor().decompress(data, max_output_size=declared,
                                                                  allow_extra_data=False)  # fmt: skip
                except zstandard.ZstdError:
                    one = None  # several frames, or corrupt: the stream below tells which
                if one is not None and len(one) == declared:
                    return one
            reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True)
            while len(out) <= declared:
                piece = reader.read(min(PIECE, declared + 1 - len(out)))
                if not piece:
                    break
                out += piece
            ended = True
        else:
            raise DecompressError(f"uses compression {comp[:20]!r}, which ltmap does not read (none, bz2, lz4, zstd)")
    except DecompressError:
        raise
    except Exception as err:  # noqa: BLE001 - each library has its own error classes
        text = first_line(err, 120)
        raise DecompressError(f"its {comp} data is corrupt ({text})") from None
    if len(out) > declared:
        raise DecompressError(f"expands to more than the {declared} bytes it declares")
    if len(out) < declared or not ended:
        raise DecompressError(f"expands to {len(out)} bytes, not the {declared} it declares")
    return out if isinstance(out, bytes) else bytes(out)  # only the zstd stream collects a bytearray


def decompress_zstd_message(data: bytes, limit: int, where: str) -> bytes:
    """One message compressed by itself with zstd (rosbag2 ``--compression-mode message``):
    ``decompress`` at the size its frame declares, or, when it declares none, read up to
    ``limit`` (``TooLargeError`` beyond)."""
    import zstandard

    try:
        size = zstandard.frame_content_size(data)
    except zstandard.ZstdError as err:
        raise DecompressError(f"its zstd data is corrupt ({first_line(err, 120)})") from None
    if size >= 0:
        return decompress("zstd", data, size, limit, where)
    import io

    try:
        out = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True).read(limit + 1)
    except zstandard.ZstdError as err:
        raise DecompressError(f"its zstd data is corrupt ({first_line(err, 120)})") from None
    if len(out) > limit:
        raise too_large(where, len(out), limit)
    return out


__all__ = ["DEFAULT_MAX_MESSAGE_MB", "TooLargeError", "DecompressError", "decompress", "decompress_zstd_message",
           "too_large"]
