"""The exact state file of a snapshot (``state_*.npz``): plain arrays plus a small header.

``replay --resume`` loads it to continue where a run stopped. The arrays come from the map core
(``LayeredMap.state_arrays``); this module only stores them, atomically, and checks the header.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from ..errors import MapFileError
from .atomic import atomic_path

FORMAT = "ltmap-state"
VERSION = 1


def write_state(path: str | Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    header = json.dumps({"format": FORMAT, "version": VERSION, **meta})
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, __header__=np.array(header), **arrays)


def read_state(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    p = Path(path)
    if not p.is_file():
        raise MapFileError(f"state file {p} does not exist; give a replay output folder or its snapshots/state_*.npz")
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise MapFileError(f"{p} is not a readable ltmap state file ({exc}); write it again with ltmap replay") from exc
    try:
        meta = json.loads(str(arrays.pop("__header__")))
    except (KeyError, ValueError) as exc:
        raise MapFileError(f"{p} has no ltmap state header; it was not written by ltmap replay") from exc
    if meta.get("format") != FORMAT:
        raise MapFileError(f"{p} is not an ltmap state file (format {meta.get('format')!r})")
    if int(meta.get("version", 0)) > VERSION:
        raise MapFileError(f"{p} was written by a newer ltmap (state version {meta['version']}); upgrade ltmap")
    return arrays, meta
