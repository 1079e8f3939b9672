"""Write files so that a reader never sees a half-written one: temp file, then rename."""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

# what a bulk write ltmap makes for itself (a bag's decompressed copy) leaves free on its disk:
# filling it would fail the run, or the user's machine
KEEP_FREE_BYTES = 1 << 30

@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` if the block succeeds.

    The temporary file keeps ``path``'s suffix so that libraries which pick a format from the
    file name (PIL, open3d) still work. On any exception the temporary file is removed and the
    existing ``path`` (if any) is left untouched.
    """
    path = Path(path)
    if path.is_dir():  # else the rename fails naming the hidden temporary file
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~current_umask())  # mkstemp makes 0600; give the file normal permissions
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def check_file_target(path: Path, option: str, example: str) -> None:
    """Refuse, before any work, an output file option naming a folder or a path under a file:
    one line naming the option and the path the user gave."""
    from ..errors import OutputError

    if path.is_dir():
        raise OutputError(f"{option} {path}: is a folder; give a file name such as {path / example}")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{option} {path}: {parent} is a file, not a folder; choose another path")
            break


def current_umask() -> int:
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))
