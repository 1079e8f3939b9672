"""``ltmap_cli.startup``: the garbage collector paused while the ``ltmap`` program starts (the
imports and the kernels' loading), then the objects made so far frozen out of its passes; a
replay's frames, and every other command, run with it as before."""

from __future__ import annotations

import gc
import subprocess
import sys
from pathlib import Path

from ltmap_cli import startup

HOUSE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "06_house" / "log.mcap"


def test_pause_and_resume_by_hand():
    was = gc.isenabled()
    frozen = gc.get_freeze_count()
    try:
        gc.enable()
        startup.pause_gc()
        assert not gc.isenabled()
        startup.pause_gc()  # (twice: still one pause)
        objs = [[i] for i in range(100)]
        startup.resume_gc()
        assert gc.isenabled() and gc.get_freeze_count() > frozen  # (the start-up's objects frozen)
        assert gc.is_tracked(objs[0])
        gc.unfreeze()
        n = gc.get_freeze_count()
        startup.resume_gc()  # not paused: nothing
        assert gc.isenabled() and gc.get_freeze_count() == n
        gc.disable()  # a process that turned it off itself keeps it off
        startup.pause_gc()
        startup.resume_gc()
        assert not gc.isenabled() and gc.get_freeze_count() == n
    finally:
        gc.unfreeze()
        (gc.enable if was else gc.disable)()


_PROBE = """
import gc, sys
from ltmap_cli import cli
import ltmap_cli.pipeline.replay as R
import ltmap_cli.commands.info as I

warm, first = R.Replay._warm_up, R.Replay._integrate
def warm_up(self):
    print("warm-up:", gc.isenabled(), file=sys.stderr)
    warm(self)
def integrate(self, *a):
    if not getattr(self, "said", False):
        self.said = True
        print("frames:", gc.isenabled(), gc.get_freeze_count() > 0, file=sys.stderr)
    return first(self, *a)
R.Replay._warm_up, R.Replay._integrate = warm_up, integrate
info = I.info.callback
def info_cb(*a, **k):
    print("info:", gc.isenabled(), file=sys.stderr)
    return info(*a, **k)
I.info.callback = info_cb
sys.argv = ["ltmap", *sys.argv[1:]]
cli.main()
"""


def test_the_program_pauses_the_collector_until_a_replays_kernels_are_loaded(tmp_path):
    r = subprocess.run([sys.executable, "-c", _PROBE, "replay", str(HOUSE_LOG), "-o", str(tmp_path / "o"), "-q",
                        "--no-plots", "--end", "3"], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "warm-up: False" in r.stderr and "frames: True True" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-c", _PROBE, "info", str(HOUSE_LOG)], capture_output=True, text=True,
                       timeout=300)  # fmt: skip
    assert r.returncode == 0 and "info: True" in r.stderr, r.stderr
