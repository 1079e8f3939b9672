"""The CLI's own errors: click's usage errors in one line, and the same log given twice."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from logfactory import write_log
from test_replay import room_messages

from ltmap_cli.cli import cli

PLAN = Path(__file__).resolve().parents[1] / "sample_logs" / "plans" / "house.svg"
HOUSE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "06_house" / "log.mcap"


def _invoke(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.parametrize("args, line", [
    (["build-static", PLAN, "--scale", "0"],
     "ltmap: error: Invalid value for '--scale': must be a positive number, got 0.0; see ltmap build-static --help"),
    (["build-static", PLAN, "--resolution", "nan"],
     "ltmap: error: Invalid value for '--resolution': must be a positive number, got nan; "
     "see ltmap build-static --help"),
    (["replay"],
     "ltmap: error: give at least one LOG (a .bag, a ROS 2 bag folder or an .mcap); see ltmap replay --help"),
    (["replay", "x.mcap", "--snapshot-every", "abc"],
     "ltmap: error: Invalid value for '--snapshot-every': 'abc' is not a valid float; see ltmap replay --help"),
    (["replay", "x.mcap", "--mode", "grey"],
     "ltmap: error: Invalid value for '--mode': 'grey' is not one of 'trinary', 'scale', 'raw'; "
     "see ltmap replay --help"),
    (["replay", "x.mcap", "--no-such-flag"], "ltmap: error: No such option '--no-such-flag'; see ltmap replay --help"),
    (["info"], "ltmap: error: Missing argument 'LOGS...'; see ltmap info --help"),
    (["plan", "m.yaml", "--start", "0,0", "--goal", "1,1", "--robot-radius"],
     "ltmap: error: Option '--robot-radius' requires an argument; see ltmap plan --help"),
    (["replay", "x.mcap", "--snapshot-every"],
     "ltmap: error: Option '--snapshot-every' requires an argument; see ltmap replay --help"),
    (["bogus"], "ltmap: error: No such command 'bogus'; see ltmap --help"),
])
def test_usage_errors_are_one_line_with_status_2(tmp_path, args, line):
    r = _invoke(args)
    assert r.exit_code == 2
    assert r.stdout == ""
    assert r.stderr == line + "\n"


def test_help_and_version_still_exit_0():
    for args in (["--help"], ["replay", "--help"], ["build-static", "-h"]):
        r = _invoke(args)
        assert r.exit_code == 0 and r.stdout.startswith("Usage: ltmap") and r.stderr == "", args
    r = _invoke(["--version"])
    assert r.exit_code == 0 and r.stdout.startswith("ltmap, version ")


def test_the_same_log_given_twice_is_refused(tmp_path):
    log = write_log(tmp_path / "a.mcap", "mcap-ros2", room_messages(0.0, 2.0, False))
    out = tmp_path / "o"
    r = _invoke(["replay", log, log, "-o", out, "-q", "--no-plots"])
    assert r.exit_code == 2
    assert r.stderr == (f"ltmap: error: log {log} is given twice; its messages would be integrated twice: "
                        f"give each log once\n")
    assert not out.exists()
    os.symlink(log, tmp_path / "b.mcap")
    r = _invoke(["replay", log, tmp_path / "b.mcap", "-o", out, "-q", "--no-plots"])
    assert r.exit_code == 2 and f"log {tmp_path / 'b.mcap'} is given twice (the same log as {log})" in r.stderr
    r = _invoke(["info", log, log])
    assert r.exit_code == 2 and "is given twice" in r.stderr
    # once is fine: 10 scans (5 Hz for 2 s), each used once
    r = _invoke(["replay", log, "-o", out, "-q", "--no-plots"])
    assert r.exit_code == 0, r.output
    assert json.loads((out / "report.json").read_text())["frames_used"] == {"/scan": 10}


def test_a_ros2_bag_as_folder_and_as_metadata_is_the_same_log(tmp_path):
    bag = write_log(tmp_path / "bag", "ros2-sqlite3", room_messages(0.0, 2.0, False))
    r = _invoke(["replay", bag, bag / "metadata.yaml", "-o", tmp_path / "o", "-q", "--no-plots"])
    assert r.exit_code == 2
    assert f"log {bag / 'metadata.yaml'} is given twice (the same log as {bag})" in r.stderr
    assert not (tmp_path / "o").exists()


def test_the_same_recording_in_two_formats_is_warned_about(tmp_path):
    """A .bag and its MCAP conversion hold the same messages at the same log times: one warning
    (the frames were integrated twice). Logs recorded one after the other, or split by topic (a
    shared /tf_static aside), give none."""
    from logfactory import tf
    from test_replay import MOUNT

    msgs = room_messages(0.0, 2.0, False)
    bag = write_log(tmp_path / "a.bag", "ros1", msgs)
    conv = write_log(tmp_path / "a.mcap", "mcap-ros2", msgs)
    r = _invoke(["replay", bag, conv, "-o", tmp_path / "o1", "-q", "--no-plots"])
    assert r.exit_code == 0, r.output
    # (a 2 s log also gets the hint that its long-term map is nearly empty: analysis.hints)
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("ltmap: warning:") and "st_rise_s" not in ln]
    n_tf = sum(1 for m in msgs if m.topic == "/tf")
    assert warn == [f"ltmap: warning: {n_tf} messages on /tf are in both {bag} and {conv} at the same log times: the "
                    f"same recording given twice (e.g. a .bag and its conversion)? Their frames were integrated "
                    f"twice; give one of them"]
    # a window's end stops the reading early (8 s of log, read to 1 s + the 5 s tf trail): still said
    long = room_messages(0.0, 8.0, False)
    bag8, conv8 = write_log(tmp_path / "b.bag", "ros1", long), write_log(tmp_path / "b.mcap", "mcap-ros2", long)
    r = _invoke(["replay", bag8, conv8, "-o", tmp_path / "o_win", "-q", "--no-plots", "--end", "1"])
    assert r.exit_code == 0, r.output
    assert any(" messages on /tf are in both " in ln for ln in r.stderr.splitlines()), r.stderr
    later = write_log(tmp_path / "b.mcap", "mcap-ros2", room_messages(10.0, 2.0, False))
    static = tf(1_000_000_000, [("base_link", "laser", MOUNT, (0, 0, 0, 1))], static=True)
    scans_only = write_log(tmp_path / "s.mcap", "mcap-ros2", [static] + [m for m in msgs if m.topic == "/scan"])
    tf_only = write_log(tmp_path / "t.mcap", "mcap-ros2", [m for m in msgs if m.topic != "/scan"])
    for pair, out in (((conv, later), "o2"), ((scans_only, tf_only), "o3")):
        r = _invoke(["replay", *pair, "-o", tmp_path / out, "-q", "--no-plots"])
        assert r.exit_code == 0, r.stderr
        assert [ln for ln in r.stderr.splitlines() if "warning" in ln and "st_rise_s" not in ln] == [], r.stderr


def test_the_program_ends_a_replay_at_once_with_its_summary_and_outputs_written(tmp_path):
    """``main`` ends a successful replay with ``os._exit`` (no interpreter teardown): the summary
    on a pipe is flushed first, the output folder is complete; a failed replay exits as usual."""
    import subprocess
    import sys

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "ltmap_cli", "replay", str(log), "-o", str(out), "-q", "--no-plots",
                        "--end", "5"], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("replayed 5.0 s of log") and r.stdout.rstrip().splitlines()[-1].startswith("wrote ")
    from ltmap_cli.outputs.folder import OutputFolder

    assert "report.json" in OutputFolder.completed(out, command="replay")["files"]  # every file there, synced
    bad = subprocess.run([sys.executable, "-m", "ltmap_cli", "replay", str(tmp_path / "none.mcap"), "-o",
                          str(tmp_path / "o2")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.startswith("ltmap: error: log not found")


def test_a_reader_of_stdout_that_goes_away_is_not_an_error_line(tmp_path):
    """`ltmap replay LOG | head -0`: the summary meets a closed pipe; no ``ltmap: error`` line (it
    said to check the path and the free space), status 1, and the outputs are complete."""
    import subprocess
    import sys

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "ltmap_cli", "replay", str(log), "-o", str(out), "-q", "--no-plots",
                          "--end", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    p.stdout.close()  # before the summary is printed
    err = p.stderr.read().decode()
    assert p.wait(timeout=300) == 1, err
    assert "error" not in err and "Traceback" not in err and "Exception ignored" not in err, err
    from ltmap_cli.outputs.folder import OutputFolder

    assert "report.json" in OutputFolder.completed(out, command="replay")["files"]


def _replay_until(tmp_path, out, fraction, *extra):
    """An ``ltmap replay`` subprocess (SIGINT as in a terminal, not ignored as for a background
    job), returned once its progress bar (on a pipe: a line per 10 %, at most 5 a second) shows
    ``fraction`` of the log, and not all of it. The log is the house sample (50 s of depth
    images and scans: a few seconds to replay): a log without depth images replayed at 128x on a
    2-core Intel Xeon, so its bar went from 0 to 100 % in one line and the Ctrl-C came too late."""
    import signal
    import subprocess
    import sys

    log = HOUSE_LOG
    p = subprocess.Popen([sys.executable, "-m", "ltmap_cli", "replay", str(log), "-o", str(out), *extra],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    lines = []
    for line in p.stderr:
        lines.append(line)
        m = re.match(r"^\[[#.]+\] +(\d+\.\d)/(\d+\.\d) s log", line)
        if m and float(m.group(1)) >= fraction * float(m.group(2)):
            assert float(m.group(1)) < float(m.group(2)), "the replay ended before it could be interrupted:\n" + "".join(lines)
            return p, lines
    raise AssertionError("".join(lines))


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_ctrl_c_maps_what_was_read_and_a_second_one_writes_nothing(tmp_path):
    """Ctrl-C once: the replay stops reading, writes the outputs of the log read so far (a complete
    folder: report.json says where it stopped) and says how to go on; status 130. Twice: it stops
    at once and the output folder keeps what it held (here the first run's folder); status 130."""
    import signal

    from ltmap_cli.outputs.folder import OutputFolder

    out = tmp_path / "out"
    p, lines = _replay_until(tmp_path, out, 0.3, "--no-plots")
    p.send_signal(signal.SIGINT)
    stdout, rest = p.communicate(timeout=300)
    err = "".join(lines) + rest
    assert p.returncode == 130, err
    rep = json.loads((out / "report.json").read_text())
    stop = rep["interrupted_at_s"]
    total = float(re.search(r"/(\d+\.\d) s log", lines[-1]).group(1))
    assert 0.3 * total <= stop < total and rep["log_duration_s"] == stop, rep["log_duration_s"]
    assert "report.json" in OutputFolder.completed(out, command="replay")["files"]
    assert stdout.startswith(f"replayed {stop:.1f} s of log") and "wrote " in stdout, stdout
    assert f"ltmap: interrupted at {stop:.1f} s of log time" in err and f"--start {stop:g} --resume {out}" in err, err
    assert "Traceback" not in err and "error" not in err, err
    first = (out / "report.json").read_bytes()

    p, lines = _replay_until(tmp_path, out, 0.3)  # plots on: the outputs take long enough for the second
    p.send_signal(signal.SIGINT)
    for line in p.stderr:
        lines.append(line)
        if line.startswith("ltmap: interrupted: mapping the frames read so far"):
            break
    p.send_signal(signal.SIGINT)
    stdout, rest = p.communicate(timeout=300)
    err = "".join(lines) + rest
    assert p.returncode == 130 and stdout == "", err
    assert err.rstrip().splitlines()[-1] == "ltmap: interrupted; nothing was written (an output folder keeps what it held)"
    assert "Traceback" not in err, err
    assert (out / "report.json").read_bytes() == first
    OutputFolder.completed(out, command="replay")
    assert [q.name for q in tmp_path.iterdir()] == ["out"]  # no staging folder left behind


def test_a_ctrl_c_after_the_whole_log_was_read_stops_nothing_and_says_so(monkeypatch):
    """The CLI's first Ctrl-C while the log is read stops the reading (``Replay.interrupt``) and
    says the frames read so far are mapped; one after the whole log was read (the last ticks,
    the outputs) stops nothing, the run ends as a complete one (status 0), and says that (it said
    "mapping the frames read so far" before). A second one raises KeyboardInterrupt and arms the
    ``HardStop`` that ends the process if the clean-up takes more than ``HARD_STOP_S``; a clean-up
    that ends in time (the HardStop's context left) stops its watcher. The previous SIGINT
    handler is put back after. In a
    process that ignores SIGINT (a job started in the background by a shell), it installs nothing:
    Ctrl-C stays ignored. (Python's own handler is installed first: pytest itself may run with
    SIGINT ignored, as under CI started in the background, and the test failed there.)"""
    import os
    import signal
    import time
    from types import SimpleNamespace

    from ltmap_cli.commands import replay as command
    from ltmap_cli.commands.replay import HardStop, first_ctrl_c_stops

    monkeypatch.setattr(command, "HARD_STOP_S", 120.0)  # (this test's process must outlive a slow run of it)
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        for read_all in (False, True):
            stopped, said = [], []
            run = SimpleNamespace(whole_log_read=read_all, interrupt=lambda stopped=stopped: stopped.append(True))
            hard_stop = HardStop(Path("out"))
            with hard_stop, first_ctrl_c_stops(run, said.append, Path("out"), hard_stop):
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(200):  # (the handler runs in this thread, between two bytecodes)
                    if said:
                        break
                    time.sleep(0.01)
                assert not hard_stop.armed
                with pytest.raises(KeyboardInterrupt):  # a second one stops at once ...
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(2)
                # ... the clean-up given HARD_STOP_S (a third raises again)
                assert hard_stop.armed and hard_stop._thread.is_alive()
                assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
            # the clean-up ended in time: the watcher stopped, nothing left to end this process
            assert not hard_stop.armed and not hard_stop._thread.is_alive()
            assert len(said) == 1 and said[0].endswith("(Ctrl-C again to stop at once; out/ then keeps what it held)")
            if read_all:
                assert not stopped and said[0].startswith("ltmap: interrupted after the whole log was read: finishing out/")
            else:
                assert stopped == [True] and said[0].startswith("ltmap: interrupted: mapping the frames read so far")
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # (put back: outer)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        stopped, said = [], []
        run = SimpleNamespace(whole_log_read=False, interrupt=lambda: stopped.append(True))
        with first_ctrl_c_stops(run, said.append, Path("out")):
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        assert not said and not stopped and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, outer)


_STUCK_POOL = """
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from ltmap_cli import cli
from ltmap_cli.pipeline import replay

def stuck(pool):
    pool.submit(time.sleep, 0.3)
    pool._idle_semaphore._cond.acquire()  # left held, as a KeyboardInterrupt inside submit() can leave it
    time.sleep(0.6)  # the worker, its job done, now blocks on it releasing the idle semaphore
    raise KeyboardInterrupt  # the second Ctrl-C

def run(self):
    stuck(ThreadPoolExecutor(2, thread_name_prefix="stuck"))

if sys.argv[3] == "run":
    replay.Replay.run = run
else:  # in the replay's own pool of ray workers, at its 5th frame
    from ltmap_cli.pipeline.executor import OrderedExecutor
    submit, calls = OrderedExecutor.submit, []

    def stuck_submit(self, *a, **k):
        calls.append(1)
        if len(calls) == 5 and self.pool is not None:
            stuck(self.pool)
        return submit(self, *a, **k)

    OrderedExecutor.submit = stuck_submit
sys.argv = ["ltmap", "replay", sys.argv[1], "-o", sys.argv[2]]
cli.main()
"""


@pytest.mark.parametrize("where", ["run", "ray workers"])
def test_a_second_ctrl_c_exits_though_a_worker_thread_is_stuck(tmp_path, where):
    """A second Ctrl-C raised while the map thread was inside a thread pool's own locks can leave
    one held; a replay then hung at its exit (the interpreter joins every pool's workers, and
    one was blocked on that lock for ever; the replay's own pool was waited for first). Made
    here by holding the lock of a pool's idle semaphore and interrupting, in a pool of its own
    and in the replay's ray workers: the process ends at once with status 130, the line said,
    the staging folder removed."""
    import subprocess
    import sys

    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-c", _STUCK_POOL, str(HOUSE_LOG), str(out), where.split()[0]],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path)  # fmt: skip
    assert p.returncode == 130, p.stderr
    assert p.stderr.rstrip().splitlines()[-1] == "ltmap: interrupted; nothing was written (an output folder keeps what it held)"
    assert [q.name for q in tmp_path.iterdir()] == []  # no staging folder left, no output


_BROKEN_CLEAN_UP = """
import sys
import numpy as np
from ltmap_cli import cli
from ltmap_cli.pipeline import replay

def run(self):
    try:
        raise KeyboardInterrupt  # the second Ctrl-C ...
    finally:  # ... and a clean-up it left a half-done state to
        if sys.argv[3] == "numpy":  # (the error seen once)
            np.zeros(1, [("a", "i4")]) == np.zeros(1, [("b", "f4")])
        else:
            raise OSError(28, "No space left on device")

replay.Replay.run = run
debug = ["--debug"] if sys.argv[4] == "debug" else []
sys.argv = ["ltmap", *debug, "replay", sys.argv[1], "-o", sys.argv[2]]
cli.main()
"""


@pytest.mark.parametrize("error", ["numpy", "os"])
@pytest.mark.parametrize("debug", ["", "debug"])
def test_an_error_in_the_clean_up_after_a_ctrl_c_is_still_the_interrupt(tmp_path, error, debug):
    """A second Ctrl-C once ended a replay with status 1 and numpy's "Cannot compare structured
    arrays unless they have a common dtype": a clean-up the interrupt had broken raised its own
    error. Any error raised while a KeyboardInterrupt unwinds is the interrupt: status 130 and its
    line (with --debug, the traceback first)."""
    import subprocess
    import sys

    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-c", _BROKEN_CLEAN_UP, str(HOUSE_LOG), str(out), error, debug or "-"],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path)  # fmt: skip
    assert p.returncode == 130, p.stderr
    assert p.stderr.rstrip().splitlines()[-1] == "ltmap: interrupted; nothing was written (an output folder keeps what it held)"
    assert ("Traceback" in p.stderr) == bool(debug), p.stderr
    assert [q.name for q in tmp_path.iterdir()] == []


_STUCK_CLEAN_UP = """
import sys
import threading
import time
from pathlib import Path
from ltmap_cli import cli
from ltmap_cli.commands import replay
from ltmap_cli.outputs import folder, snapshots

replay.HARD_STOP_S = 1.0
marker, where = Path(sys.argv[3]), sys.argv[4]

def stuck(*a, **k):  # as on a disk that hangs
    marker.touch()
    threading.Event().wait()

if where == "state":  # the final snapshot's state writer (the pool's exit waits for it)
    snapshots.write_state = stuck
else:  # the staging folder's removal, after the run
    def run(self):
        marker.touch()
        while True:  # (the second Ctrl-C raises in here)
            time.sleep(0.05)

    replay.Replay.run = run
    folder.shutil.rmtree = stuck
sys.argv = ["ltmap", "replay", sys.argv[1], "-o", sys.argv[2], "--no-plots"]
cli.main()
"""


@pytest.mark.parametrize("where", ["state", "staging"])
def test_a_second_ctrl_c_ends_the_process_though_the_clean_up_waits_for_ever(tmp_path, where):
    """The clean-up after a second Ctrl-C waits for the replay's threads (the final snapshot's
    state writer here, stuck as on a disk that hangs: the pool's exit joins it) and removes the
    staging folder (stuck too). It hung for ever; now the process ends ``HARD_STOP_S`` (1 s here)
    after the second Ctrl-C, with status 130 and a line that says so, and the output folder is
    not made."""
    import signal
    import subprocess
    import sys
    import time

    out, marker = tmp_path / "out", tmp_path / "stuck"
    p = subprocess.Popen([sys.executable, "-c", _STUCK_CLEAN_UP, str(HOUSE_LOG), str(out), str(marker), where],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)  # fmt: skip
    try:
        t0 = time.monotonic()
        while not marker.exists():  # (the run stuck, or running)
            if p.poll() is not None or time.monotonic() - t0 > 120:
                p.kill()
                raise AssertionError(p.communicate()[1])
            time.sleep(0.05)
        p.send_signal(signal.SIGINT)  # the first: finishing, or stopping the reading
        time.sleep(0.5)
        assert p.poll() is None
        if where == "staging":
            marker.unlink()
        t1 = time.monotonic()
        p.send_signal(signal.SIGINT)  # at once: the clean-up waits
        if where == "staging":
            while not marker.exists():  # (the staging folder's removal reached)
                assert time.monotonic() - t1 < 30
                time.sleep(0.05)
        _, err = p.communicate(timeout=30)
        took = time.monotonic() - t1
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert 0.9 < took < 10, took
    assert err.rstrip().splitlines()[-1] == (
        f"ltmap: interrupted; the clean-up did not end within 1 s, so ltmap stopped without it: nothing was "
        f"written ({out}/ keeps what it held; the next run removes its staging folder)"), err  # fmt: skip
    assert "Traceback" not in err and not out.exists(), err


def test_a_recording_split_into_more_files_than_the_open_file_limit(tmp_path):
    """102 files of one recording (rosbag2 --max-bag-duration 0.2) under a soft limit of 64 open
    files (often 1024, and a day of one-minute splits is 1440 files): replay raises the soft limit
    toward the hard one and maps them all; under a hard limit of 64, one line, status 2 (before:
    "Too many open files; check the path, its permissions and the free space")."""
    import resource
    import subprocess
    import sys

    msgs = room_messages(0.0, 20.0, False)
    t0 = min(m.log_time_ns for m in msgs)
    parts: dict = {}
    for m in msgs:
        parts.setdefault(0 if m.topic == "/tf_static" else (m.log_time_ns - t0) // 200_000_000, []).append(m)
    logs = [write_log(tmp_path / f"part_{k:03d}.mcap", "mcap-ros2", ms) for k, ms in sorted(parts.items())]
    assert len(logs) > 100

    def run(soft_hard):
        def limit():
            resource.setrlimit(resource.RLIMIT_NOFILE, soft_hard)

        return subprocess.run([sys.executable, "-m", "ltmap_cli", "replay", *map(str, logs), "-o",
                               str(tmp_path / f"o{soft_hard[1]}"), "-q", "--no-plots"], capture_output=True, text=True,
                              timeout=300, preexec_fn=limit)  # fmt: skip

    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    r = run((64, hard))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / f"o{hard}" / "report.json").read_text())["frames_used"] == {"/scan": 100}
    r = run((64, 64))
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"ltmap: error: {len(logs)} log files need more open files than this process may have (ulimit -Hn: 64); "
        f"merge them first (`mcap merge`, `ros2 bag convert`) or raise the hard limit"], r.stderr
