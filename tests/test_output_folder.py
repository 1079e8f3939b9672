"""An output folder is replaced as a whole (SPEC 4): after any kill, crash or full disk the folder
is exactly the old run or exactly the new one; a second run on the folder is refused while one
runs; stale staging folders are removed, never reused; a folder ltmap did not write is refused
unless --force; readers (--resume, diff, plan) take only a completed run.

The unit tests drive ``OutputFolder`` directly; the slow ones run ``ltmap`` in subprocesses and
kill them with SIGKILL at moments spread over a replay (by time, when a file appears in the
staging folder, and at the named points of ``outputs.folder._pause``)."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import ltmap_cli.outputs.folder as folder_mod
from ltmap_cli.cli import cli
from ltmap_cli.errors import MapFileError, OutputError
from ltmap_cli.outputs.folder import LOCK, MANIFEST, TEST_PAUSE_ENV, OutputFolder, recover

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs" / "scenarios"
LOG_NEW = SAMPLES / "01_static_object" / "log.mcap"
LOG_OLD = SAMPLES / "02_table" / "log.mcap"
PLAN = ROOT / "sample_logs" / "plans" / "office.svg"


def write(out: OutputFolder, files: dict[str, bytes]) -> None:
    for name, data in files.items():
        p = out.staging / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)


def make_run(path: Path, files: dict[str, bytes], command: str = "replay") -> dict:
    with OutputFolder(path, command=command) as out:
        write(out, files)
        return out.commit({"note": "test"})


def contents(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def beside(path: Path) -> list[str]:
    """What lies beside ``path`` in its parent (staging, aside and lock files included)."""
    return sorted(os.listdir(path.parent))


OLD = {"map.pgm": b"old map", "report.json": b"{}", "plots/a.png": b"old plot", "replay.mcap": b"old mcap"}
NEW = {"map.pgm": b"new map!", "report.json": b'{"new": 1}', "snapshots/state_final.npz": b"state"}


# -- unit: commit, abort, replacement -----------------------------------------------------------
def test_commit_writes_the_manifest_last_and_leaves_nothing_beside(tmp_path):
    out_path = tmp_path / "out"
    manifest = make_run(out_path, NEW)
    assert contents(out_path) == {**NEW, MANIFEST: (out_path / MANIFEST).read_bytes()}
    assert manifest["files"] == {n: {"size": len(d), "sha256": hashlib.sha256(d).hexdigest()} for n, d in NEW.items()}
    assert manifest["command"] == "replay" and manifest["written_by"] == "ltmap" and manifest["note"] == "test"
    assert OutputFolder.completed(out_path) == manifest
    assert beside(out_path) == ["out"]  # no staging folder, no lock file


def test_a_completed_run_leaves_nothing_of_the_earlier_one(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    make_run(out_path, NEW)
    assert set(contents(out_path)) == set(NEW) | {MANIFEST}  # plots/ and replay.mcap of the old run gone
    assert beside(out_path) == ["out"]


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_leaving_without_commit_keeps_the_old_folder_and_removes_the_staging(tmp_path, exc):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    before = contents(out_path)
    with pytest.raises(type(exc)), OutputFolder(out_path, command="replay") as out:
        write(out, NEW)
        raise exc
    assert contents(out_path) == before and beside(out_path) == ["out"]
    make_run(out_path, NEW)  # the lock was released


def test_a_failed_first_run_leaves_no_folder(tmp_path):
    out_path = tmp_path / "new" / "out"
    with pytest.raises(RuntimeError), OutputFolder(out_path, command="replay") as out:
        write(out, NEW)
        raise RuntimeError
    assert not out_path.exists() and beside(out_path) == []


# -- unit: stale staging -----------------------------------------------------------------------
def test_stale_staging_folders_are_removed_whatever_their_pid_and_never_reused(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    stale = [tmp_path / f".out.ltmap-staging-{os.getpid()}", tmp_path / ".out.ltmap-staging-1",
             tmp_path / ".out.ltmap-staging-abcd1234", tmp_path / ".out.ltmap-old-1"]  # fmt: skip
    for s in stale:  # what killed runs left, one with this very PID (PID 1 in a container)
        (s / "snapshots").mkdir(parents=True)
        (s / "snapshots" / "state_final.npz").write_bytes(b"another log's state")
    other = tmp_path / ".other.ltmap-staging-1"  # another output folder's: not ours to remove
    other.mkdir()
    with OutputFolder(out_path, command="replay") as out:
        assert not any(s.exists() for s in stale)
        assert out.staging not in stale and list(out.staging.iterdir()) == []
        write(out, NEW)
        out.commit()
    assert set(contents(out_path)) == set(NEW) | {MANIFEST} and other.is_dir()


# -- unit: foreign folders ----------------------------------------------------------------------
def test_a_foreign_folder_is_refused_unless_forced(tmp_path):
    out_path = tmp_path / "photos"
    out_path.mkdir()
    (out_path / "holiday.jpg").write_bytes(b"precious")
    with pytest.raises(OutputError) as e:
        OutputFolder(out_path, command="replay").__enter__()
    msg = str(e.value)
    assert "\n" not in msg and f"-o {out_path}: holds files ltmap did not write (holiday.jpg)" in msg
    assert "--force" in msg
    assert contents(out_path) == {"holiday.jpg": b"precious"} and beside(out_path) == ["photos"]
    with OutputFolder(out_path, command="replay", force=True) as out:
        write(out, NEW)
        out.commit()
    assert set(contents(out_path)) == set(NEW) | {MANIFEST}


def test_empty_legacy_and_other_command_folders(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    make_run(empty, NEW)  # an empty folder is fine
    legacy = tmp_path / "legacy"  # what an ltmap without the manifest left: report.json + config.yaml
    legacy.mkdir()
    for name in ("report.json", "config.yaml", "map.pgm"):
        (legacy / name).write_text("x")
    make_run(legacy, NEW)
    assert set(contents(legacy)) == set(NEW) | {MANIFEST}
    static = tmp_path / "static"
    make_run(static, {"static.yaml": b"s"}, command="build-static")
    with pytest.raises(OutputError, match="holds an ltmap build-static output, not a replay one"):
        make_run(static, NEW)
    make_run(static, {"static.yaml": b"t"}, command="build-static")


def test_paths_that_cannot_be_an_output_folder(tmp_path, monkeypatch):
    (tmp_path / "afile").write_text("x")
    monkeypatch.chdir(tmp_path)
    for path, needle in ((".", "is the current folder"), ("", "is the current folder"),
                         ("..", "is the current folder or one above it"), ("afile", "is a file, not a folder"),
                         ("afile/sub", "afile is a file, not a folder")):  # fmt: skip
        with pytest.raises(OutputError, match=needle):
            OutputFolder(Path(path), command="replay").__enter__()


def test_a_symbolic_link_keeps_pointing_at_the_new_run(tmp_path):
    real = tmp_path / "real"
    make_run(real, OLD)
    (tmp_path / "link").symlink_to(real)
    make_run(tmp_path / "link", NEW)
    assert (tmp_path / "link").is_symlink() and set(contents(real)) == set(NEW) | {MANIFEST}


# -- unit: the lock -----------------------------------------------------------------------------
HOLD = """
import sys, time
from pathlib import Path
from ltmap_cli.outputs.folder import OutputFolder
with OutputFolder(Path(sys.argv[1]), command="replay") as out:
    print("locked", flush=True)
    time.sleep(60)
"""


def test_a_second_run_is_refused_with_one_line_naming_the_first(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out_path)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputError) as e:
            OutputFolder(out_path, command="replay").__enter__()
        msg = str(e.value)
        assert "\n" not in msg
        assert f"another ltmap replay (pid {holder.pid} on {socket.gethostname()}, started " in msg
        assert "is writing this folder" in msg
    finally:
        holder.kill()
        holder.wait()
    assert msg.endswith("is writing this folder; wait for it to end, or choose another output folder")
    # killed: the kernel released its lock; its staging folder is removed by the next run
    assert any(".out.ltmap-staging-" in n for n in beside(out_path))
    make_run(out_path, NEW)
    assert set(contents(out_path)) == set(NEW) | {MANIFEST} and beside(out_path) == ["out"]


def test_a_lock_file_removed_by_its_holder_is_not_shared(tmp_path):
    """A waiter that opened the lock file before its holder removed it must not lock the removed
    file while a third run locks the new one."""
    lock_path = tmp_path / f".out.{LOCK}"
    first = folder_mod._Lock(lock_path, "-o out", "replay")
    assert first.try_acquire()
    waiter_fd = os.open(lock_path, os.O_RDWR)  # opened the old file
    first.release()
    second = folder_mod._Lock(lock_path, "-o out", "replay")
    assert second.try_acquire()  # creates a new lock file
    import fcntl

    fcntl.flock(waiter_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # the old inode is free...
    assert not os.path.samestat(os.fstat(waiter_fd), os.stat(lock_path))  # ...and try_acquire sees it is stale
    third = folder_mod._Lock(lock_path, "-o out", "replay")
    assert not third.try_acquire()
    os.close(waiter_fd)
    second.release()


def test_a_single_output_file_is_locked_and_a_killed_runs_temporary_files_go(tmp_path):
    log = tmp_path / "log.mcap"
    stale = [tmp_path / ".log.k1ll3d.tmp.mcap"]  # what atomic_path left when a run was killed
    kept = [tmp_path / ".log.k1ll3d.tmp.bag", tmp_path / ".other.k1ll3d.tmp.mcap", tmp_path / "log.mcap"]
    for f in stale + kept:
        f.write_bytes(b"x")
    with folder_mod.locked_file(log, "simulate"):
        assert not any(f.exists() for f in stale) and all(f.exists() for f in kept)
        with pytest.raises(OutputError) as e, folder_mod.locked_file(log, "simulate"):
            pass
        assert f"-o {log}: another ltmap simulate (pid {os.getpid()} on " in str(e.value)
        assert str(e.value).endswith("is writing this file; wait for it to end, or choose another output file")
    assert sorted(os.listdir(tmp_path)) == sorted(f.name for f in kept)


# -- unit: a kill between the two renames --------------------------------------------------------
def test_a_kill_between_the_two_renames_is_restored_at_the_next_start(tmp_path):
    """Where names cannot be exchanged atomically: the old folder is renamed aside, then the new
    one into place. A kill between the two leaves no folder, the old run aside and the new one
    complete in its staging folder (the state built here; the slow test kills a real run there).
    The next ltmap command restores the old run: a run that did not end is as if it never started."""
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    before = contents(out_path)
    staged = tmp_path / "staged"
    make_run(staged, NEW)
    os.rename(out_path, tmp_path / ".out.ltmap-old-k1ll3d00")
    os.rename(staged, tmp_path / ".out.ltmap-staging-k1ll3d00")
    (tmp_path / f".out.{LOCK}").write_text('{"pid": 1}')  # a killed run's lock file: not locked
    OutputFolder.completed(out_path)  # a reader restores it
    assert contents(out_path) == before and beside(out_path) == ["out"]


def test_ctrl_c_between_the_two_renames_puts_the_old_run_back(tmp_path, monkeypatch):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    before = contents(out_path)
    monkeypatch.setattr(folder_mod, "_exchange", lambda a, b: False)

    def pause(point):
        if point == "aside":
            raise KeyboardInterrupt

    monkeypatch.setattr(folder_mod, "_pause", pause)
    with pytest.raises(KeyboardInterrupt), OutputFolder(out_path, command="replay") as out:
        write(out, NEW)
        out.commit()
    assert contents(out_path) == before and beside(out_path) == ["out"]
    monkeypatch.setattr(folder_mod, "_pause", lambda point: None)
    make_run(out_path, NEW)  # two renames, uninterrupted
    assert set(contents(out_path)) == set(NEW) | {MANIFEST} and beside(out_path) == ["out"]


def test_restore_takes_only_a_complete_aside(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    aside = tmp_path / ".out.ltmap-old-x"
    os.rename(out_path, aside)
    (aside / "map.pgm").unlink()  # an aside that lost a file is not a run to bring back
    recover(out_path)
    assert not out_path.exists() and beside(out_path) == []


# -- unit: full disk ----------------------------------------------------------------------------
def test_a_full_disk_while_writing_is_one_line_and_keeps_the_old_folder(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    before = contents(out_path)
    with pytest.raises(OutputError) as e, OutputFolder(out_path, command="replay") as out:
        write(out, {"map.pgm": b"half"})
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out.staging / "snapshots" / "state_final.npz"))
    msg = str(e.value)
    assert "\n" not in msg and "ltmap-staging" not in msg
    assert msg.startswith(f"cannot write {out_path / 'snapshots' / 'state_final.npz'}: No space left on device")
    assert f"-o {out_path} is left as it was" in msg
    assert contents(out_path) == before and beside(out_path) == ["out"]


def test_an_error_reading_an_input_is_not_called_a_write_error(tmp_path):
    log = tmp_path / "log.mcap"
    with pytest.raises(PermissionError), OutputFolder(tmp_path / "out", command="replay"):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(log))
    assert beside(tmp_path / "out") == []


def test_a_full_disk_while_writing_the_manifest_keeps_the_old_folder(tmp_path, monkeypatch):
    out_path = tmp_path / "out"
    make_run(out_path, OLD)
    before = contents(out_path)
    real_write = folder_mod._write_all

    def full(fd, data):
        if b'"written_by"' in data:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_write(fd, data)

    monkeypatch.setattr(folder_mod, "_write_all", full)
    with pytest.raises(OutputError, match="No space left on device"), OutputFolder(out_path, command="replay") as out:
        write(out, NEW)
        out.commit()
    assert contents(out_path) == before and beside(out_path) == ["out"]


# -- unit: readers take only a completed run ------------------------------------------------------
def test_completed_refuses_what_a_run_did_not_complete(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, NEW)
    (out_path / "map.pgm").write_bytes(b"changed size")
    with pytest.raises(MapFileError, match=r"map.pgm has 12 bytes, the manifest says 8"):
        OutputFolder.completed(out_path, "--resume")
    (out_path / MANIFEST).unlink()
    with pytest.raises(MapFileError, match=f"--resume {out_path}: not a completed ltmap output"):
        OutputFolder.completed(out_path, "--resume")
    with pytest.raises(MapFileError, match="no such folder"):
        OutputFolder.completed(tmp_path / "nope", "--resume")


def test_resume_takes_a_completed_folder_or_an_explicit_snapshot_only(tmp_path):
    from ltmap_cli.outputs.snapshots import resolve_resume

    out_path = tmp_path / "out"
    make_run(out_path, NEW)
    assert resolve_resume(out_path) == out_path / "snapshots" / "state_final.npz"
    (out_path / MANIFEST).unlink()  # e.g. a run killed before its manifest, or an older ltmap
    with pytest.raises(MapFileError, match="not a completed ltmap output.*or a snapshot file"):
        resolve_resume(out_path)
    assert resolve_resume(out_path / "snapshots" / "state_final.npz") == out_path / "snapshots" / "state_final.npz"


def test_resume_from_the_folder_the_run_replaces(tmp_path):
    """Day 2 into day 1's folder: --resume reads the old run before the new one is swapped in."""
    out_path = tmp_path / "out"
    assert CliRunner().invoke(cli, ["replay", str(LOG_NEW), "-o", str(out_path), "-q", "--no-plots"]).exit_code == 0
    day1 = json.loads((out_path / "report.json").read_text())["voxels"]["long_term_occupied"]
    r = CliRunner().invoke(cli, ["replay", str(LOG_OLD), "--resume", str(out_path), "-o", str(out_path), "-q",
                                 "--no-plots"])  # fmt: skip
    assert r.exit_code == 0, r.output
    report = json.loads((out_path / "report.json").read_text())
    assert report["resume"]["long_term_voxels"] > 0 and day1 > 0
    assert report["resume"]["path"] == str(out_path / "snapshots" / "state_final.npz")
    assert OutputFolder.completed(out_path)["logs"] == [str(LOG_OLD)] and beside(out_path) == ["out"]


def test_inputs_inside_the_output_folder_are_refused(tmp_path):
    out_path = tmp_path / "out"
    make_run(out_path, {"log.mcap": b"x"})
    r = CliRunner().invoke(cli, ["replay", str(out_path / "log.mcap"), "-o", str(out_path), "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1
    assert f"LOG {out_path / 'log.mcap'}: is inside the output folder -o {out_path}" in r.output
    assert (out_path / "log.mcap").read_bytes() == b"x" and beside(out_path) == ["out"]


def test_a_static_folder_no_run_completed_is_refused_before_anything_is_written(tmp_path):
    static = tmp_path / "static"
    static.mkdir()
    (static / "static.yaml").write_text("image: static.pgm\n")
    r = CliRunner().invoke(cli, ["replay", str(LOG_NEW), "--static", str(static), "-o", str(tmp_path / "out"), "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1
    assert f"--static {static}: not a completed ltmap output" in r.output and "give its static.yaml" in r.output
    assert sorted(os.listdir(tmp_path)) == ["static"]


# -- end to end (subprocesses, SIGKILL) ---------------------------------------------------------
def ltmap(*args, pause: str | None = None, exchange: bool = True) -> list[str]:
    """The command line of ``ltmap ARGS`` in a subprocess (``exchange=False``: as on a file system
    that cannot exchange two names, so the swap takes two renames)."""
    code = "" if exchange else "import ltmap_cli.outputs.folder as f; f._exchange = lambda a, b: False; "
    code += "import sys; from ltmap_cli.cli import main; main()"
    return [sys.executable, "-c", code, *map(str, args)]


def env(pause: str | None = None) -> dict:
    e = {**os.environ, "PYTHONPATH": str(ROOT)}
    e.pop(TEST_PAUSE_ENV, None)
    if pause:
        e[TEST_PAUSE_ENV] = pause
    return e


def staging_of(out_path: Path) -> Path | None:
    for n in os.listdir(out_path.parent):
        if n.startswith(f".{out_path.name}.ltmap-staging-"):
            return out_path.parent / n
    return None


def manifest_set(path: Path) -> dict:
    """The folder's files with their sha256, checked against its manifest."""
    m = json.loads((path / MANIFEST).read_text())
    files = {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
             for p in path.rglob("*") if p.is_file() and p.name != MANIFEST}  # fmt: skip
    assert files == {n: i["sha256"] for n, i in m["files"].items()}, "the folder is not what its manifest says"
    return {"logs": m.get("logs"), "files": files}


def kill_when(proc: subprocess.Popen, out_path: Path, trigger, timeout: float = 60.0) -> bool:
    """SIGKILL ``proc`` when ``trigger(staging folder or None)`` holds; True if it was killed (not
    already ended)."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if proc.poll() is not None:
            return False
        if trigger(staging_of(out_path)):
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            return proc.returncode == -signal.SIGKILL
        time.sleep(0.0005)
    proc.kill()
    raise AssertionError("the trigger never came")


REPLAY = ["replay", LOG_NEW, "--no-plots", "-q", "--snapshot-every", "10"]


@pytest.mark.slow
def test_kill_9_at_20_moments_leaves_the_old_or_the_new_complete_run(tmp_path):
    out_path = tmp_path / "out"
    pristine = tmp_path / "pristine"
    # the earlier run: another sample, into the folder
    r = subprocess.run(ltmap("replay", LOG_OLD, "-o", pristine, "--no-plots", "-q"), env=env(), capture_output=True)
    assert r.returncode == 0, r.stderr
    old = manifest_set(pristine)
    # the new run, uninterrupted, for reference (maps and events are deterministic)
    ref = tmp_path / "ref"
    t0 = time.monotonic()
    r = subprocess.run(ltmap(*REPLAY, "-o", ref), env=env(), capture_output=True)
    assert r.returncode == 0, r.stderr
    run_s = time.monotonic() - t0
    new = manifest_set(ref)
    assert new["logs"] == [str(LOG_NEW)] and old["logs"] == [str(LOG_OLD)]
    deterministic = ("map.pgm", "map.yaml", "long_term.pgm", "long_term.yaml", "events.csv")

    def has(name):
        return lambda s: s is not None and (s / name).exists()

    moments = [(f"time {f:.2f}", lambda s, f=f: time.monotonic() - started >= f * run_s, None, True)
               for f in (0.45, 0.55, 0.65, 0.75, 0.85, 0.95)]  # fmt: skip
    moments += [(f"file {n}", has(n), None, True) for n in (
        "snapshots/long_term_t000010.0s.ot", "snapshots/state_t000020.0s.npz", "snapshots/state_final.npz",
        "map.pgm", "long_term.yaml", "events.csv", "config.yaml", "report.json")]  # fmt: skip
    moments += [(f"pause {p}", None, p, x) for p, x in (("locked", True), ("commit", True), ("manifest", True),
                                                       ("exchanged", True), ("aside", False), ("renamed", False))]  # fmt: skip
    assert len(moments) == 20
    outcome = {}
    for label, trigger, pause, exchange in moments:
        if out_path.exists():
            shutil.rmtree(out_path)
        shutil.copytree(pristine, out_path)
        marker = tmp_path / "paused"
        marker.unlink(missing_ok=True)
        started = time.monotonic()
        proc = subprocess.Popen(ltmap(*REPLAY, "-o", out_path, exchange=exchange),
                                env=env(f"{pause}:{marker}" if pause else None),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        killed = kill_when(proc, out_path, (lambda s, m=marker: m.exists()) if pause else trigger)
        print(f"{label}: killed={killed} at {time.monotonic() - started:.2f} s")
        left = [n for n in os.listdir(tmp_path) if n.startswith(".out.")]
        OutputFolder.completed(out_path)  # the next ltmap command on the folder (restores, cleans)
        got = manifest_set(out_path)
        if got["logs"] == old["logs"]:
            assert got == old, f"{label}: a mix"
            outcome[label] = "old"
        else:
            assert set(got["files"]) == set(new["files"]), f"{label}: a mix"
            assert all(got["files"][n] == new["files"][n] for n in deterministic), f"{label}: a mix"
            outcome[label] = "new"
        assert [n for n in os.listdir(tmp_path) if n.startswith(".out.")] == [], f"{label}: left {left}"
        assert killed or outcome[label] == "new", label
    # every kill before the swap keeps the old run; after the exchange (or the second rename) the new one
    assert all(outcome[f"file {n}"] == "old" for n in ("map.pgm", "events.csv", "report.json")), outcome
    assert [outcome[f"pause {p}"] for p in ("locked", "commit", "manifest", "exchanged", "aside", "renamed")] == [
        "old", "old", "old", "new", "old", "new"]
    assert "old" in {outcome[f"time {f:.2f}"] for f in (0.45, 0.55)}, outcome


@pytest.mark.slow
def test_two_concurrent_replays_on_one_folder(tmp_path):
    out_path = tmp_path / "out"
    marker = tmp_path / "locked"
    # the first holds the lock, paused just after taking it until the marker goes: however fast it
    # replays, the second starts while the first holds the lock
    first = subprocess.Popen(ltmap(*REPLAY, "-o", out_path), env=env(f"locked:{marker}"), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    t_end = time.monotonic() + 60
    while not marker.exists() and first.poll() is None and time.monotonic() < t_end:
        time.sleep(0.001)
    assert first.poll() is None and marker.exists(), first.communicate()
    second = subprocess.run(ltmap("replay", LOG_OLD, "-o", out_path, "--no-plots", "-q"), env=env(),
                            capture_output=True, text=True)  # fmt: skip
    marker.unlink()  # the first goes on
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert second.returncode == 2 and second.stdout == ""
    assert second.stderr.count("\n") == 1 and "Traceback" not in second.stderr
    assert (f"ltmap: error: -o {out_path}: another ltmap replay (pid {first.pid} on {socket.gethostname()}, "
            "started ") in second.stderr  # fmt: skip
    got = manifest_set(out_path)
    assert got["logs"] == [str(LOG_NEW)] and beside(out_path) == ["out"]


@pytest.mark.slow
def test_replay_on_a_full_tmpfs_keeps_the_old_run(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root (the injected ENOSPC tests cover the logic)")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        out_path = mnt / "out"
        r = subprocess.run(ltmap(*REPLAY, "-o", out_path), env=env(), capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        before = contents(out_path)
        free = shutil.disk_usage(mnt).free
        (mnt / "filler").write_bytes(b"\0" * max(free - 100_000, 0))  # 100 kB left: less than a run
        r = subprocess.run(ltmap(*REPLAY, "-o", out_path), env=env(), capture_output=True, text=True)
        lines = r.stderr.splitlines()  # (the periodic snapshots stop first, with a warning)
        assert r.returncode == 2 and r.stdout == "" and lines[-1].startswith("ltmap: error: "), r.stderr
        assert all(x.startswith("ltmap: warning: the disk of ") for x in lines[:-1]) and len(lines) <= 2, r.stderr
        assert "No space left on device" in lines[-1] and f"-o {out_path} is left as it was" in lines[-1]
        assert "ltmap-staging" not in r.stderr
        assert contents(out_path) == before and sorted(os.listdir(mnt)) == ["filler", "out"]
        (mnt / "filler").unlink()
        r = subprocess.run(ltmap("replay", LOG_OLD, "-o", out_path, "--no-plots", "-q"), env=env(),
                           capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert manifest_set(out_path)["logs"] == [str(LOG_OLD)]
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_build_static_follows_the_same_rules(tmp_path):
    out_path = tmp_path / "static"
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("x")
    r = CliRunner().invoke(cli, ["build-static", str(PLAN), "-o", str(foreign)])
    assert r.exit_code == 2 and "holds files ltmap did not write (mine.txt)" in r.output
    assert r.output.count("\n") == 1 and (foreign / "mine.txt").exists()
    assert CliRunner().invoke(cli, ["build-static", str(PLAN), "-o", str(foreign), "--force"]).exit_code == 0
    assert not (foreign / "mine.txt").exists() and OutputFolder.completed(foreign)["command"] == "build-static"
    r = subprocess.run(ltmap("build-static", PLAN, "-o", out_path, "--wall-height", "2"), env=env(),
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "wrote static.pgm, static.png, static.yaml, static_layer.npz in" in r.stdout
    old = manifest_set(out_path)
    for pause, want in (("manifest", "old"), ("exchanged", "new")):
        marker = tmp_path / f"paused-{pause}"
        proc = subprocess.Popen(ltmap("build-static", PLAN, "-o", out_path, "--wall-height", "3"),
                                env=env(f"{pause}:{marker}"))  # fmt: skip
        assert kill_when(proc, out_path, lambda s, m=marker: m.exists())
        OutputFolder.completed(out_path)
        got = manifest_set(out_path)
        assert (got == old) is (want == "old"), pause
        assert [n for n in beside(out_path) if n.startswith(".static.")] == []
        if want == "new":  # the whole new build (another wall height: another static_layer.npz)
            assert set(got["files"]) == set(old["files"])
            assert got["files"]["static_layer.npz"] != old["files"]["static_layer.npz"]


def test_simulate_follows_the_same_rules(tmp_path):
    scenario = SAMPLES / "01_static_object" / "scenario.yaml"
    bag = tmp_path / "log_ros2"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("a bag a robot recorded")
    r = CliRunner().invoke(cli, ["simulate", str(scenario), "-o", str(bag), "--format", "ros2", "-q"])
    assert r.exit_code == 2 and "holds files ltmap did not write (metadata.yaml)" in r.output
    assert (bag / "metadata.yaml").read_text() == "a bag a robot recorded"
    assert sorted(os.listdir(tmp_path)) == ["log_ros2"]
    marker = tmp_path / "paused"
    proc = subprocess.Popen(ltmap("simulate", scenario, "-o", bag, "--format", "ros2", "-q", "--force"),
                            env=env(f"manifest:{marker}"))  # fmt: skip
    assert kill_when(proc, bag, lambda s: marker.exists())
    assert sorted(os.listdir(bag)) == ["metadata.yaml"]  # a kill before the swap: the bag as it was
    assert [n for n in os.listdir(tmp_path) if ".log_ros2.ltmap-staging-" in n]  # until the next run
    r = CliRunner().invoke(cli, ["simulate", str(scenario), "-o", str(bag), "--format", "ros2", "-q", "--force"])
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(bag)) == ["log_ros2.mcap", MANIFEST, "metadata.yaml"]
    assert sorted(os.listdir(tmp_path)) == ["ground_truth.json", "log_ros2", "paused"]
    m = OutputFolder.completed(bag, command="simulate")
    assert m["format"] == "ros2" and set(m["files"]) == {"log_ros2.mcap", "metadata.yaml"}
    from ltmap_cli.io.logs import open_logs

    with open_logs(bag) as logs:
        assert logs.topics["/scan"].count == 300
    r = CliRunner().invoke(cli, ["simulate", str(scenario), "-o", str(bag), "--format", "ros2", "-q", "--seed", "2"])
    assert r.exit_code == 0, r.output  # ltmap's own bag: replaced without --force
    assert OutputFolder.completed(bag)["seed"] == 2


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_a_killed_replays_last_snapshot_is_kept_with_the_command_that_maps_the_rest(tmp_path):
    """A replay killed (SIGKILL) after its first periodic snapshots: the next run into the same
    folder removes the killed run's staging folder, as always, but first keeps its last state
    as OUT.killed_run_state.npz and says so, with the --start that maps the rest of the log (the
    log time its snapshot reached) and the --resume that carries its long-term layer on. That
    command runs and maps from there. (Before, hours of replay were lost with the run.)"""
    from ltmap_cli.io.state import read_state_meta

    out_path = tmp_path / "out"
    proc = subprocess.Popen(ltmap("replay", LOG_NEW, "--no-plots", "-q", "--snapshot-every", "2", "-o", out_path),
                            env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    assert kill_when(proc, out_path, lambda s: s is not None and (s / "snapshots/state_t000004.0s.npz").exists())
    kept = tmp_path / "out.killed_run_state.npz"
    assert not kept.exists() and staging_of(out_path) is not None
    r = subprocess.run(ltmap("replay", LOG_OLD, "--no-plots", "-q", "--end", "3", "-o", out_path), env=env(),
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert staging_of(out_path) is None and kept.is_file()
    meta = read_state_meta(kept)
    mapped = meta["mapped_to_s"]
    # the snapshot's tick (header time since the first frame), and the record time its frames reached
    assert meta["log_time_s"] >= 4.0 and abs(mapped - meta["log_time_s"]) < 1.0
    line = [x for x in r.stderr.splitlines() if "was killed" in x]
    assert len(line) == 1 and f"--start {mapped:g} --resume {kept}" in line[0], r.stderr
    rest = tmp_path / "rest"
    r = subprocess.run(ltmap("replay", LOG_NEW, "--no-plots", "-q", "--start", f"{mapped:g}", "--resume", kept,
                             "-o", rest), env=env(), capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    rep = json.loads((rest / "report.json").read_text())
    assert rep["window"]["start_s"] == pytest.approx(mapped, abs=1e-3)
    assert rep["resume"]["path"] == str(kept)


def test_recover_keeps_the_newest_state_of_a_killed_replay_only(tmp_path):
    """Unit: of a killed replay's staging folder the final state (a run killed in its last
    moments) or else the latest periodic one is kept, replacing an older kept one; a staging
    folder without snapshots (build-static, batch) or with an unreadable one keeps nothing."""
    import warnings

    from ltmap_cli.io.state import read_state_meta, write_state

    target = tmp_path / "out"
    target.mkdir()

    def staging(name, states):
        s = tmp_path / f".out.ltmap-staging-{name}"
        (s / "snapshots").mkdir(parents=True)
        for t in states:
            write_state(s / "snapshots" / f"state_t{t:08.1f}s.npz", {"x": np.zeros(3)},
                        {"log_time_s": t, "mapped_to_s": t + 0.5})  # fmt: skip
        return s

    staging("a", [60.0, 120.0, 1200.0])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        recover(target)
    kept = tmp_path / "out.killed_run_state.npz"
    assert read_state_meta(kept)["log_time_s"] == 1200.0
    assert len(w) == 1 and "--start 1200.5 --resume" in str(w[0].message)
    s = staging("b", [60.0])
    (s / "snapshots" / "state_t000120.0s.npz").write_bytes(b"not a zip")  # the newest, unreadable
    staging("c", [])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        recover(target)
    assert read_state_meta(kept)["log_time_s"] == 1200.0 and not w  # kept as it was
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".out.")]
    # a batch redoes a killed day whole (OutputFolder / tidy with keep_killed=False): nothing kept
    kept.unlink()
    staging("d", [60.0])
    recover(target, keep_killed=False)
    assert not kept.exists() and not [n for n in os.listdir(tmp_path) if n.startswith(".out.")]
