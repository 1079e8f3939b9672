"""An output folder replaced as a whole (SPEC 4: a killed or failed run leaves the folder exactly
as it was; a completed run leaves nothing of an earlier one).

Every command that writes a folder (``replay``, ``build-static``, ``simulate`` of a ROS 2 bag)
goes through ``OutputFolder``::

    with OutputFolder(path, command="replay", force=force) as out:
        ...write everything into out.staging...
        manifest = out.commit({"logs": [...]})

Beside ``OUT`` (same parent, so the same file system) it keeps, with ``NAME`` = ``OUT``'s name:

- ``.NAME.ltmap-lock``: a file locked with ``flock`` while a run writes ``OUT``, holding the
  run's pid, host, command and start time for the refusal message of a second run. The kernel
  drops the lock of a killed process.
- ``.NAME.ltmap-staging-XXXXXXXX``: the folder a run writes into (a fresh random name: never
  reused). At ``commit`` the manifest ``ltmap_manifest.json`` is written into it last (every
  file with its size and sha256, the command, ltmap's version, the caller's extras), every file
  and folder is fsynced, and the staging folder is swapped with ``OUT`` in one atomic step
  (``renameat2(RENAME_EXCHANGE)``); the old run, now under the staging name, is then removed.
- ``.NAME.ltmap-old-XXXXXXXX``: only where the kernel or file system cannot exchange two names
  atomically: ``OUT`` is renamed aside, the staging folder renamed to ``OUT``, the aside removed.
  A kill between the two renames leaves no ``OUT``; the next ltmap command on ``OUT`` (a run, or
  a reader through ``OutputFolder.completed``) renames the aside back first.

A run that starts removes, under the lock, every staging and aside folder a killed run left
(whatever its pid). A folder that exists, is not empty and was not written by ltmap is refused
unless ``force``: ltmap's folders hold the manifest, or, written before the manifest existed,
the files an older ltmap wrote last (``LEGACY_MARKERS``).

Tests hold a run at named points (``_pause``: ``locked``, ``commit``, ``manifest``, ``exchanged``,
``aside``, ``renamed``) with ``LTMAP_TEST_PAUSE=POINT:FILE``, to kill it there or to let it go on;
nothing else reads that variable.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import hashlib
import json
import os
import shutil
import socket
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .. import __version__
from ..errors import MapFileError, OutputError
from ..io.atomic import current_umask

MANIFEST = "ltmap_manifest.json"
MANIFEST_MAX_BYTES = 64 * 2**20  # a manifest is a few kB; a bigger file is not one
SYNC_THREADS = 8  # files hashed and fsynced at once by commit
# the files an older ltmap (no manifest) wrote last into its folders: such a folder is ltmap's
# (build-static's: io.static_layer's MAP_YAML and LAYER_FILE, spelled out: that module imports
# numpy, and every command, --help too, imports this one)
LEGACY_MARKERS = {"replay": ("report.json", "config.yaml"), "build-static": ("static.yaml", "static_layer.npz")}
STAGING = "ltmap-staging-"
ASIDE = "ltmap-old-"
LOCK = "ltmap-lock"
READER = "(reader)"  # the lock's command while OutputFolder.completed restores a folder
TEST_PAUSE_ENV = "LTMAP_TEST_PAUSE"  # tests only: "POINT:FILE" -> at POINT touch FILE, sleep (see _pause)

# errors that mean the output could not be written, wherever they are raised
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG}
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


class OutputFolder:
    """The output folder ``path`` of one run of ``command``: staging, lock, manifest, swap.

    ``force``: replace a folder that ltmap did not write. ``option``: how the user named the
    path (messages say ``-o OUT: ...``). After ``__enter__``: ``staging`` (write here) and
    ``final`` (the path as the user gave it: show it in reports). Leaving the block without
    ``commit`` removes the staging folder and leaves ``path`` as it was; an ``OSError`` met while
    writing (a full disk) becomes one ``OutputError`` line naming the final path."""

    def __init__(self, path: str | os.PathLike, command: str, force: bool = False, option: str = "-o",
                 keep_killed: bool = True):  # fmt: skip
        self.final = Path(path)
        self.command = command
        self.force = force
        self.option = option
        self.keep_killed = keep_killed  # recover(): keep a killed replay's last snapshot (not a batch's: it redoes the day)
        self.staging: Path | None = None
        self.manifest: dict | None = None
        self._lock: _Lock | None = None
        self._target = output_target(self.final, option)

    # -- lifecycle ------------------------------------------------------------------------------
    def __enter__(self) -> OutputFolder:
        target, label = self._target, f"{self.option} {self.final}"
        parent = target.parent
        for p in (target, *target.parents):  # the first that exists must be a folder
            if p.exists():
                if p == target and not p.is_dir():
                    raise OutputError(f"{label}: is a file, not a folder; choose another output folder")
                if p != target and not p.is_dir():
                    raise OutputError(f"{label}: {p} is a file, not a folder; choose another output folder")
                break
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"{label}: cannot create {parent}: {err.strerror or err}; choose another "
                              "output folder") from None  # fmt: skip
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputError(f"{label}: cannot write in {parent} (permission denied); choose another output folder")
        self._lock = _Lock(parent / f".{target.name}.{LOCK}", label, self.command)
        self._lock.acquire()
        try:
            recover(target, self.keep_killed)
            self._check_replaceable()
            _pause("locked")
            self.staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.{STAGING}", dir=parent))
            os.chmod(self.staging, 0o777 & ~current_umask())  # mkdtemp makes 0700; the folder gets normal permissions
        except BaseException:
            self._lock.release()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if self.staging is not None and self.manifest is None:
                shutil.rmtree(self.staging, ignore_errors=True)
        finally:
            self._lock.release()
        if isinstance(exc, OSError):
            error = self._write_error(exc)
            if error is not None:
                raise error from None

    def _write_error(self, err: OSError) -> OutputError | None:
        """One line for a failure writing the staging folder (a full disk), naming the file as
        it would have been in the final folder; None for other errors (reading an input)."""
        name = getattr(err, "filename", None)
        where = None
        if name and self.staging is not None:
            with contextlib.suppress(ValueError, OSError):
                where = self.final / Path(name).resolve().relative_to(self.staging.resolve())
        if where is None and err.errno in WRITE_ERRNOS:
            where = name or self.final
        if where is None:
            return None
        return OutputError(f"cannot write {where}: {err.strerror or err}; {self.option} {self.final} is left as it "
                           "was (free some space, or choose another output folder)")  # fmt: skip

    # -- checks ---------------------------------------------------------------------------------
    def _check_replaceable(self) -> None:
        target, label = self._target, f"{self.option} {self.final}"
        if not target.is_dir():
            return
        entries = sorted(os.listdir(target))
        if not entries:
            return
        manifest = _read_manifest(target)
        what = None
        if manifest is not None:
            if manifest.get("command") != self.command:
                what = f"holds an ltmap {manifest.get('command')} output, not a {self.command} one"
        elif not (self.command in LEGACY_MARKERS and all((target / m).is_file() for m in LEGACY_MARKERS[self.command])):
            shown = ", ".join(entries[:3]) + (f", ... {len(entries) - 3} more" if len(entries) > 3 else "")
            what = f"holds files ltmap did not write ({shown})"
        if what is not None and not self.force:
            raise OutputError(f"{label}: {what}; a run replaces its output folder as a whole: choose a new or "
                              "empty folder, or add --force to replace this one")  # fmt: skip

    def refuse_inputs_inside(self, paths, option: str) -> None:
        """Refuse an input (a log, a static map) inside the folder this run replaces: the swap
        would delete it."""
        target = self._target.resolve()
        for p in paths:
            if p is None:
                continue
            r = Path(p).resolve()
            if r == target or target in r.parents:
                raise OutputError(f"{option} {p}: is inside the output folder {self.option} {self.final}, which the "
                                  "run replaces as a whole; choose another output folder")  # fmt: skip

    # -- commit ---------------------------------------------------------------------------------
    def commit(self, extra: dict | None = None) -> dict:
        """Write the manifest last, fsync, and swap the staging folder in as ``path``; return the
        manifest."""
        staging, target = self.staging, self._target
        _pause("commit")
        paths, dirs = [], [staging]
        for root, dnames, fnames in os.walk(staging):
            dnames.sort()
            dirs += [Path(root) / d for d in dnames]
            paths += [Path(root) / f for f in sorted(fnames) if Path(root) / f != staging / MANIFEST]
        # fsyncs issued together share the file system's journal commits (18 files of a replay:
        # 0.01 s instead of 0.15 s one after the other)
        with ThreadPoolExecutor(max(1, min(SYNC_THREADS, len(paths)))) as pool:
            files = dict(zip((p.relative_to(staging).as_posix() for p in paths), pool.map(_hash_and_sync, paths)))
        manifest = {"written_by": "ltmap", "version": __version__, "command": self.command, **(extra or {}),
                    "files": files}  # fmt: skip
        data = (json.dumps(manifest, indent=1, sort_keys=False) + "\n").encode()
        fd = os.open(staging / MANIFEST, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        with ThreadPoolExecutor(max(1, min(SYNC_THREADS, len(dirs)))) as pool:
            list(pool.map(_fsync_dir, dirs))
        _pause("manifest")
        try:
            _swap(staging, target)
        except OSError as err:
            raise OutputError(f"{self.option} {self.final}: cannot replace the folder: {err.strerror or err} (a mount "
                              "point or a busy folder?); choose another output folder") from None  # fmt: skip
        self.manifest = manifest
        return manifest

    # -- readers --------------------------------------------------------------------------------
    @staticmethod
    def completed(path: str | os.PathLike, option: str = "", command: str | None = None,
                  fix: str = "") -> dict:  # fmt: skip
        """The manifest of the completed run in folder ``path``; else ``MapFileError`` (one line).

        A folder is complete when its manifest (written last) parses and every file it names is
        there with its size. A run killed between its two renames is restored first (when no run
        holds the folder). ``command``: the command that must have written it; ``fix``: what the
        user can do instead (e.g. give the snapshot file)."""
        p = Path(path)
        label = f"{option} {p}".strip()
        target = Path(os.path.abspath(p))
        tidy(target, label)
        if not target.is_dir():
            raise MapFileError(f"{label}: no such folder; {fix or 'give an ltmap output folder'}")
        manifest = _read_manifest(target)
        if manifest is None:
            why = (f"its {MANIFEST} is damaged" if (target / MANIFEST).exists() else
                   f"no {MANIFEST}: ltmap did not write it, an older ltmap did, or the run was killed")
            raise MapFileError(f"{label}: not a completed ltmap output ({why}); {fix or 'run ltmap again into it'}")
        if command is not None and manifest.get("command") != command:
            raise MapFileError(f"{label}: holds an ltmap {manifest.get('command')} output, not a {command} one; "
                               f"{fix or 'give a ' + command + ' output folder'}")  # fmt: skip
        bad = _incomplete(target, manifest)
        if bad:
            raise MapFileError(f"{label}: {bad} (the folder was changed after ltmap wrote it); "
                               f"{fix or 'run ltmap again into it'}")  # fmt: skip
        return manifest


@contextlib.contextmanager
def locked_file(path: str | os.PathLike, command: str, option: str = "-o"):
    """Hold the lock of an output *file* (``simulate -o log.mcap``, its ground truth) while it is
    written under a temporary name and renamed (``io.atomic``), and remove the temporary files a
    killed run left beside it (``.STEM.*.tmpSUFFIX``)."""
    label = f"{option} {path}"
    path = Path(os.path.abspath(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = _Lock(path.parent / f".{path.name}.{LOCK}", label, command, what="file")
    lock.acquire()
    try:
        for n in os.listdir(path.parent):
            if n.startswith(f".{path.stem}.") and n.endswith(f".tmp{path.suffix}") and (path.parent / n).is_file():
                with contextlib.suppress(OSError):
                    (path.parent / n).unlink()
        yield
    finally:
        lock.release()


def check_completed_input(path: str | os.PathLike | None, option: str, fix: str, command: str | None = None) -> None:
    """An input argument that names a folder must name a completed ltmap output (a file is
    read as it is): ``MapFileError`` otherwise, saying ``fix``."""
    if path is not None and Path(path).is_dir():
        OutputFolder.completed(path, option, command=command, fix=fix)


def listing(manifest: dict) -> str:
    """What a manifest holds, for a summary line: top-level files, then folders with their file
    counts: ``map.pgm, map.yaml, ..., plots/ (5 files), snapshots/ (3 files)``."""
    top, folders = [], {}
    for name in manifest["files"]:
        head, _, rest = name.partition("/")
        if rest:
            folders[head] = folders.get(head, 0) + 1
        else:
            top.append(name)
    return ", ".join(top + [f"{d}/ ({n} file{'s' if n != 1 else ''})" for d, n in sorted(folders.items())])


def tidy(target: Path, label: str = "", keep_killed: bool = True) -> None:
    """``recover`` what a killed run left beside the folder ``target``, when no run holds it now
    (a reader's check, or a batch finding a day up to date)."""
    lock = _Lock(target.parent / f".{target.name}.{LOCK}", label or str(target), READER)
    if target.parent.is_dir() and os.access(target.parent, os.W_OK) and lock.try_acquire():
        try:
            recover(target, keep_killed)
        finally:
            lock.release()


def recover(target: Path, keep_killed: bool = True) -> None:
    """Under the lock: bring back the old folder if a run was killed between its two renames
    (``target`` missing, a complete aside), then remove every staging and aside folder left;
    first, with ``keep_killed``, keeping a killed replay's last snapshot beside ``target``
    (``snapshots.keep_killed_run_state``)."""
    parent = target.parent
    if not parent.is_dir():
        return
    prefix = f".{target.name}."
    left = [parent / n for n in os.listdir(parent)
            if n.startswith(prefix) and n[len(prefix):].startswith((STAGING, ASIDE))]  # fmt: skip
    if not left:
        return
    if not os.path.lexists(target):
        asides = [p for p in left if p.name[len(prefix):].startswith(ASIDE) and p.is_dir()]
        for a in sorted(asides, key=lambda p: p.stat().st_mtime, reverse=True):
            m = _read_manifest(a)
            if m is not None and not _incomplete(a, m):
                os.rename(a, target)
                _fsync_dir(parent)
                left.remove(a)
                break
    for p in left:
        if p.is_dir() and not p.is_symlink():
            if keep_killed and p.name[len(prefix):].startswith(STAGING):  # a killed replay's last snapshot
                from .snapshots import keep_killed_run_state

                with contextlib.suppress(OSError):
                    keep_killed_run_state(p, target)
            shutil.rmtree(p, ignore_errors=True)


# -- internals --------------------------------------------------------------------------------
def output_target(path: Path, option: str) -> Path:
    """The folder the swap replaces: ``path`` made absolute, a symbolic link followed (the
    link's target is replaced, the link kept). Refuses the current folder or one above it, and /."""
    label = f"{option} {path}".strip()
    if str(path) in ("", "."):
        raise OutputError(f"{label or repr(str(path))}: is the current folder; a run replaces its output folder as "
                          "a whole: give a folder of its own, such as ltmap_out")  # fmt: skip
    target = Path(os.path.abspath(path))
    if target.is_symlink():
        target = target.resolve()
    cwd = Path.cwd().resolve()
    resolved = target.resolve()
    if resolved == cwd or resolved in cwd.parents or resolved.parent == resolved:
        raise OutputError(f"{label}: is the current folder or one above it; a run replaces its output folder as "
                          "a whole: give a folder of its own, such as ltmap_out")  # fmt: skip
    return target


def _read_manifest(folder: Path) -> dict | None:
    p = folder / MANIFEST
    try:
        if not p.is_file() or p.stat().st_size > MANIFEST_MAX_BYTES:
            return None
        m = json.loads(p.read_bytes())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("written_by") != "ltmap" or not isinstance(m.get("files"), dict):
        return None
    return m


def _incomplete(folder: Path, manifest: dict) -> str | None:
    """What is missing or of another size than the manifest says, or None."""
    for name, info in manifest["files"].items():
        p = folder / name
        try:
            size = p.stat().st_size
        except OSError:
            return f"{name} is missing"
        if not isinstance(info, dict) or size != info.get("size"):
            return f"{name} has {size} bytes, the manifest says {info.get('size') if isinstance(info, dict) else '?'}"
    return None


def _hash_and_sync(p: Path) -> dict:
    h = hashlib.sha256()
    size = 0
    with open(p, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
        os.fsync(f.fileno())
    return {"size": size, "sha256": h.hexdigest()}


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _fsync_dir(d: Path) -> None:
    with contextlib.suppress(OSError):  # some file systems cannot fsync a folder
        fd = os.open(d, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names ``a`` and ``b`` in one atomic step (Linux ``renameat2``); False where the
    kernel, libc or file system cannot."""
    fn = _renameat2()
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    e = ctypes.get_errno()
    if e in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(e, os.strerror(e), str(b))


def _renameat2():
    try:
        return ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None


def _swap(staging: Path, target: Path) -> None:
    """``staging`` becomes ``target``; the old ``target`` (if any) is removed."""
    parent = target.parent
    if not os.path.lexists(target):
        os.rename(staging, target)
    elif _exchange(staging, target):
        _fsync_dir(parent)
        _pause("exchanged")
        shutil.rmtree(staging, ignore_errors=True)  # the old run, now under the staging name
    else:
        aside = parent / (f".{target.name}.{ASIDE}" + staging.name.rsplit(STAGING, 1)[-1])
        os.rename(target, aside)
        try:
            _pause("aside")
            os.rename(staging, target)
        except BaseException:  # Ctrl-C, or the rename failed: the old run back (a kill: the next start)
            with contextlib.suppress(OSError):
                os.rename(aside, target)
            raise
        _fsync_dir(parent)
        _pause("renamed")
        shutil.rmtree(aside, ignore_errors=True)
    _fsync_dir(parent)


class _Lock:
    """An exclusive ``flock`` on a file beside the folder, holding who took it."""

    def __init__(self, path: Path, label: str, command: str, what: str = "folder"):
        self.path = path
        self.label = label
        self.command = command  # READER: OutputFolder.completed restoring a folder
        self.what = what
        self.fd: int | None = None

    def acquire(self) -> None:
        if not self.try_acquire():
            raise OutputError(f"{self.label}: {self._holder()} this {self.what}; wait for it to end, or "
                              f"choose another output {self.what}")  # fmt: skip

    def try_acquire(self) -> bool:
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as err:
                raise OutputError(f"{self.label}: cannot create the lock file {self.path}: "
                                  f"{err.strerror or err}; choose another output folder") from None  # fmt: skip
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                return False
            try:  # the holder before us may have removed the file we opened: lock the file that is there
                same = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            self.fd = fd
            info = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                    "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())}  # fmt: skip
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
                _write_all(fd, (json.dumps(info) + "\n").encode())
            return True

    def _holder(self) -> str:
        try:
            info = json.loads(self.path.read_text()[:4096])
            who = "another ltmap command" if info["command"] == READER else f"another ltmap {info['command']}"
            doing = "is checking" if info["command"] == READER else "is writing"
            return f"{who} (pid {info['pid']} on {info['host']}, started {info['started']}) {doing}"
        except (OSError, ValueError, KeyError, TypeError):
            return "another ltmap process is writing"

    def release(self) -> None:
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)  # while still locked: a waiter that opened it retries (try_acquire)
        os.close(self.fd)
        self.fd = None


def _pause(point: str) -> None:
    """Tests only (``tests/test_output_folder.py``): with ``LTMAP_TEST_PAUSE`` = ``POINT:FILE``, at
    ``POINT`` create FILE and wait while it exists (at most 600 s), so the test kills the run at a
    known moment, or deletes FILE to let it go on."""
    spec = os.environ.get(TEST_PAUSE_ENV)
    if spec and spec.split(":", 1)[0] == point:
        marker = Path(spec.split(":", 1)[1])
        marker.touch()
        t_end = time.monotonic() + 600
        while marker.exists() and time.monotonic() < t_end:
            time.sleep(0.01)
