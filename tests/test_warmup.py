"""The warm-up compiles what a replay calls, in the specializations it calls them with (issue 21):
on a cold cache anything else is compiled in the middle of the run, in the main process (a
read-only depth image once cost a cold run 10 s of compiling while mapping)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ltmap_cli.config import Config
from ltmap_cli.pipeline.warmup import GROUPS, replay_groups

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"
PLAN = ROOT / "sample_logs" / "plans" / "house.svg"

# a fresh process: warm the groups the replay will call, note every kernel's specializations,
# replay, and print the kernels that gained one
_SCRIPT = """
import gc, json, sys
from numba.core.registry import CPUDispatcher
from ltmap_cli.cli import cli
from ltmap_cli.config import Config
from ltmap_cli.pipeline.warmup import replay_groups, warm_up

def kernels():
    return {f"{d.py_func.__module__}.{d.py_func.__qualname__}": len(d.signatures)
            for d in gc.get_objects() if isinstance(d, CPUDispatcher)}

cfg = Config()
cfg.replay.mcap_out, cfg.replay.plan_goal = True, [5.0, 4.0]
warm_up(cfg.map, replay_groups(cfg.replay, raw_depth=True))
before = kernels()
try:
    cli(sys.argv[1:], prog_name="ltmap")
except SystemExit as e:
    assert not e.code, e.code
print(json.dumps({k: [before.get(k, 0), n] for k, n in kernels().items() if n != before.get(k, 0)}))
"""


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_replay_compiles_nothing_the_warm_up_did_not(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "ltmap_cli", "build-static", str(PLAN), "-o", str(tmp_path / "static")],
                   check=True, capture_output=True, env=env)  # fmt: skip
    out = subprocess.run([sys.executable, "-c", _SCRIPT, "replay", str(HOUSE), "--static", str(tmp_path / "static"),
                          "-o", str(tmp_path / "out"), "--mcap", "--plan-goal", "5,4", "--no-plots"],
                         check=True, capture_output=True, text=True, env=env)  # fmt: skip
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {}


def test_replay_groups():
    cfg = Config()
    assert replay_groups(cfg.replay) == ["rays", "maps"]
    assert replay_groups(cfg.replay, raw_depth=True) == ["rays", "maps", "depth16"]
    cfg.replay.mcap_out, cfg.replay.plan_goal = True, [1.0, 2.0]
    assert replay_groups(cfg.replay) == ["rays", "maps", "fused_scan", "planner"]
    assert set(replay_groups(cfg.replay, raw_depth=True)) <= set(GROUPS)


def test_background_compile_says_each_group_ended():
    """A first run waits for its compiling children; ``wait`` reports each one that ends (the
    progress line then says "1 of 3 kernel groups compiled", so half a minute is not silence)."""
    from ltmap_cli.pipeline.warmup import BackgroundCompile

    bc = BackgroundCompile([])  # no groups: children of our own, ending one after another
    bc.procs = [subprocess.Popen([sys.executable, "-c", f"import time; time.sleep({d})"]) for d in (0.6, 0.0, 0.3)]
    seen = []
    bc.wait(lambda ended, total: seen.append((ended, total)), poll_s=0.05)
    assert seen[-1] == (3, 3) and [e for e, _ in seen] == sorted({e for e, _ in seen})  # rising, each once
    assert len(seen) >= 2 and bc.procs == []  # (two ending within one poll are said together)
