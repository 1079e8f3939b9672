"""The CLI's own errors: click's usage errors in one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli

PLAN = Path(__file__).resolve().parents[1] / "sample_logs" / "plans" / "house.svg"


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
