"""The exact state file of a snapshot (``state_*.npz``): plain arrays plus a small header.

``replay --resume`` loads it to continue where a run stopped. The arrays come from the map core
(``LayeredMap.state_arrays``); this module only stores them, atomically, and checks the header.
"""

from __future__ import annotations

import json
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..errors import MapFileError, first_line, shown
from .atomic import atomic_path

FORMAT = "ltmap-state"
VERSION = 1
# deflate level of the arrays: 3 writes a 100 m floor's 650 MB of arrays in half the time of
# numpy's savez_compressed (level 6: 3.3 s), into a file 1.5 times as big (18 MB against 12 MB)
ZIP_LEVEL = 3


def _deflate_with_zlib_ng(member) -> bool:
    """Have zipfile's writer of ``member`` deflate with zlib-ng (a dependency: io/sources.py's
    CRC) instead of zlib: the same deflate format at ``ZIP_LEVEL``, in about half the time (a
    110 MB state of the depot bench scene: 0.30 s against 0.53 s, 6.2 MB against 6.6 MB; the map
    thread waits for it at every snapshot). zipfile takes its compressor when a member is
    opened and has no option for another one: its writer's ``_compressor`` is replaced before
    the first byte; False (zlib kept) where zlib-ng or that attribute is missing."""
    try:
        from zlib_ng import zlib_ng
    except ImportError:
        return False
    if not hasattr(member, "_compressor"):
        return False
    member._compressor = zlib_ng.compressobj(ZIP_LEVEL, zlib_ng.DEFLATED, -15)  # (raw deflate, as zipfile's)
    return True


def write_state(path: str | Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """An ``.npz`` (``np.load`` reads it) of ``arrays`` and the header ``meta``, deflated."""
    header = json.dumps({"format": FORMAT, "version": VERSION, **meta})
    with atomic_path(path) as tmp, open(tmp, "wb") as f, \
            zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED, compresslevel=ZIP_LEVEL, allowZip64=True) as zf:  # fmt: skip
        for name, a in {"__header__": np.array(header), **arrays}.items():
            with zf.open(name + ".npy", "w", force_zip64=True) as out:
                _deflate_with_zlib_ng(out)
                np.lib.format.write_array(out, np.asanyarray(a), allow_pickle=False)


# what reading a damaged state file raises (numpy parses a damaged array header with tokenize;
# zipfile raises NotImplementedError for an unknown compression method, RuntimeError for a member
# flagged as encrypted)
UNREADABLE = (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error, KeyError, MemoryError,
              tokenize.TokenError, SyntaxError, NotImplementedError, RuntimeError)  # fmt: skip

MAX_STATE_BYTES = 8 * 2**30  # the arrays a state file may expand to (a 100 m floor's is ~1 GB)


def _fault(p: Path, what: str) -> MapFileError:
    return MapFileError(f"state file {p}: {what}; write it again with ltmap replay (or give another snapshot)")


def read_state(path: str | Path, max_bytes: int = MAX_STATE_BYTES) -> tuple[dict[str, np.ndarray], dict]:
    """The arrays and header of a state file. Every fault (not a zip, flipped bytes, a header
    that is not an object, a bad version, arrays declaring more than ``max_bytes`` in all) is one
    ``MapFileError`` naming the file; the arrays themselves are checked by the caller, which
    knows their layout (``outputs.snapshots.check_state``)."""
    from .safe_yaml import check_regular_file

    p = Path(path)
    if not p.exists():
        raise MapFileError(f"state file {p} does not exist; give a replay output folder or its snapshots/state_*.npz")
    check_regular_file(p, "state file", MapFileError)
    try:
        with zipfile.ZipFile(p) as zf:
            declared = sum(i.file_size for i in zf.infolist())
            if declared > max_bytes:
                raise _fault(p, f"its arrays declare {declared / 2**30:.1f} GB, more than a state file holds "
                                f"({max_bytes / 2**30:.0f} GB)")
            arrays = {}
            for info in zf.infolist():
                with zf.open(info) as fh:
                    arr = np.lib.format.read_array(fh, allow_pickle=False)
                    # numpy stops at the array's end; reading on to the member's end is what
                    # checks its CRC (flipped bytes), without decompressing it a second time
                    if fh.read(1):
                        raise ValueError(f"array {shown(info.filename)} holds more than its header says")
                arrays[info.filename.removesuffix(".npy")] = arr
    except MapFileError:
        raise
    except UNREADABLE as exc:
        text = first_line(exc, 120)
        raise _fault(p, f"not a readable ltmap state file ({text})") from None
    try:
        header = arrays.pop("__header__")
        if header.dtype.kind not in "US" or header.shape != ():
            raise ValueError("not a string")
        meta = json.loads(str(header))
    except (KeyError, ValueError, RecursionError):
        raise _fault(p, "no ltmap state header (it was not written by ltmap replay)") from None
    if not isinstance(meta, dict):
        raise _fault(p, f"its header is a JSON {type(meta).__name__}, not an object")
    if meta.get("format") != FORMAT:
        raise _fault(p, f"not an ltmap state file (format {shown(meta.get('format'))})")
    version = meta.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise _fault(p, f"bad state version {shown(version)} (ltmap writes versions 1 to {VERSION})")
    if version > VERSION:
        raise MapFileError(f"state file {p} was written by a newer ltmap (state version {version}); upgrade ltmap")
    return arrays, meta


def read_state_meta(path: str | Path) -> dict:
    """The header of a state file alone (its arrays are not read); {} when it has none readable."""
    try:
        with zipfile.ZipFile(path) as zf:
            info = zf.getinfo("__header__.npy")
            if info.file_size > 1 << 20:
                return {}
            with zf.open(info) as fh:
                meta = json.loads(str(np.lib.format.read_array(fh, allow_pickle=False)))
    except UNREADABLE:
        return {}
    return meta if isinstance(meta, dict) else {}
