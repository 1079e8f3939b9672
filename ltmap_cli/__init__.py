"""ltmap: replay robot logs through a layered long-term 3D map."""

import os
import stat
import sys
import tempfile
from pathlib import Path

__version__ = "0.1.0"


def _writable_folder(path: Path) -> bool:
    """Whether ``path`` is, or could be made as, a folder this process can write: its nearest
    existing ancestor is a folder we may write into (a file in the way: no)."""
    while not path.exists():
        if path.parent == path:
            return False
        path = path.parent
    return path.is_dir() and os.access(path, os.W_OK | os.X_OK)


def _kernel_cache_fallback(environ=os.environ, package: Path | None = None) -> str | None:
    """Where numba is told to cache the compiled kernels when it could not do so by itself (None:
    it can). numba caches them beside the modules (``__pycache__``) or in the user's cache folder
    (``$XDG_CACHE_HOME/numba``, ``~/.cache/numba``), and when it can write neither (an install
    owned by root with a read-only home, a container whose root file system is read-only) it
    refuses at import, in every command, ``ltmap --help`` included: "cannot cache function
    'pack_block': no locator available". Then ``NUMBA_CACHE_DIR`` is set to a folder of this user
    in the temp folder, so ltmap runs and compiles once (again after the temp folder is emptied).
    A few file checks when ``NUMBA_CACHE_DIR`` is not set, before numba is imported (its setting
    is read then; set on numba's config too if it was imported already)."""
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    package = package or Path(__file__).resolve().parent
    if _writable_folder(package / "core" / "__pycache__"):
        return None
    try:
        user = Path(environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "numba"
    except RuntimeError:  # (no home to be found)
        user = None
    if user is not None and _writable_folder(user):
        return None
    folder = Path(tempfile.gettempdir()) / f"ltmap-numba-cache-{os.getuid()}"
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        st = folder.lstat()
    except OSError:
        return None  # (nothing writable: numba's own error)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        return None  # made by someone else (numba would load their pickles as our kernels): numba's error
    environ["NUMBA_CACHE_DIR"] = str(folder)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(folder)
    return str(folder)


_kernel_cache_fallback()
