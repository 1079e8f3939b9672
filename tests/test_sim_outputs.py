"""`ltmap simulate`: the log and its ground truth are written together or not at all."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_sim_log import write_scenario

from ltmap_cli.cli import cli


def run(*args: str | Path):
    return CliRunner().invoke(cli, ["simulate", *map(str, args)])


def one_error_line(res, *parts: str) -> str:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ltmap: error: "), res.output
    for p in parts:
        assert p in lines[0], lines[0]
    return lines[0]


def files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def scen(tmp_path) -> Path:
    (tmp_path / "in").mkdir()
    return write_scenario(tmp_path / "in")


def test_ground_truth_under_a_file_writes_no_log(tmp_path, scen):
    (tmp_path / "afile").write_text("x")
    res = run(scen, "-o", tmp_path / "h" / "log.mcap", "--ground-truth", tmp_path / "afile" / "gt.json")
    one_error_line(res, f"--ground-truth {tmp_path / 'afile' / 'gt.json'}", "is a file, not a folder")
    assert not (tmp_path / "h").exists()


def test_ground_truth_under_a_file_keeps_the_old_log_and_ground_truth(tmp_path, scen):
    h = tmp_path / "h"
    assert run(scen, "-o", h / "log.mcap", "-q").exit_code == 0
    (h / "log.mcap").write_bytes(b"old log")
    (h / "ground_truth.json").write_text("old gt")
    (tmp_path / "afile").write_text("x")
    res = run(scen, "-o", h / "log.mcap", "--ground-truth", tmp_path / "afile" / "gt.json", "-q")
    one_error_line(res, "afile")
    assert files(h) == {"log.mcap": b"old log", "ground_truth.json": b"old gt"}


@pytest.mark.parametrize("fmt", ["mcap", "ros2"])
def test_ground_truth_that_cannot_be_written_leaves_both_as_they_were(tmp_path, scen, monkeypatch, fmt):
    """A failure writing the ground truth after the whole log was simulated (disk full): the old log
    and ground truth stay, no temp file is left."""
    import ltmap_cli.sim.simulate as sim

    h = tmp_path / "h"
    out = h / ("log.mcap" if fmt == "mcap" else "log_ros2")
    assert run(scen, "-o", out, "-q").exit_code == 0
    before = files(h)

    def full(path, simulator):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(sim, "_write_ground_truth", full)
    res = run(scen, "-o", out, "-q", "--seed", "7")  # another seed: a different log
    one_error_line(res, "ground_truth.json", "No space left on device")
    assert files(h) == before
    assert sorted(p.name for p in h.iterdir()) == sorted({"ground_truth.json", out.name})


def test_both_replaced_on_success(tmp_path, scen):
    h = tmp_path / "h"
    assert run(scen, "-o", h / "log.mcap", "-q").exit_code == 0
    a = files(h)
    assert run(scen, "-o", h / "log.mcap", "-q", "--seed", "7").exit_code == 0
    b = files(h)
    assert sorted(b) == ["ground_truth.json", "log.mcap"]
    assert a["log.mcap"] != b["log.mcap"] and a["ground_truth.json"] != b["ground_truth.json"]
    assert b'"seed": 7' in b["ground_truth.json"]


@pytest.mark.parametrize(
    ("gt", "want"),
    [
        ("h", "is the folder of the log"),  # the log's folder, not there yet
        ("h/log.mcap", "is the log"),
        ("h/log.mcap/gt.json", "is the log"),
    ],
)
def test_ground_truth_that_is_a_folder_or_the_log(tmp_path, scen, gt, want):
    res = run(scen, "-o", tmp_path / "h" / "log.mcap", "--ground-truth", tmp_path / gt)
    one_error_line(res, f"--ground-truth {tmp_path / gt}", want)
    assert not (tmp_path / "h" / "log.mcap").exists()


def test_default_ground_truth_is_a_folder(tmp_path, scen):
    (tmp_path / "h" / "ground_truth.json").mkdir(parents=True)
    res = run(scen, "-o", tmp_path / "h" / "log.mcap")
    one_error_line(res, "(the ground truth beside -o", "is a folder", "--ground-truth")
    assert sorted(p.name for p in (tmp_path / "h").iterdir()) == ["ground_truth.json"]


def test_log_under_a_file(tmp_path, scen):
    (tmp_path / "afile").write_text("x")
    one_error_line(run(scen, "-o", tmp_path / "afile" / "log.mcap"), "-o ", "afile is a file, not a folder")
