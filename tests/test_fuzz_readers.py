"""Seeded byte mutations of a ROS 1 bag, an MCAP, a ROS 2 db3 and one compressed file by file
(its .db3.zstd: ltmap decompresses it into TMPDIR first) (laser, tf and a depth camera
recorded through image_transport's compressedDepth, PNG and RVL) through ``ltmap info``,
``ltmap replay --allow-truncated`` (issue 15) and the same with a window (``--start`` /
``--end``: the readers' seeking): the exit status is 0 or 2, never an exception
escaping the CLI (a traceback), whatever the damage. Run in this process through click's
runner (600 subprocesses would take minutes); each run is bounded by an alarm.

The full run (200 mutations per format) is marked slow; a 30-mutation run per format is not.
A failure prints the format, seed and mutation, to replay it by hand."""

from __future__ import annotations

import random
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path

import pytest
from click.testing import CliRunner
from logfactory import write_log
from test_replay import room_messages

from ltmap_cli.cli import cli

FORMATS = ("ros1", "mcap-ros2", "ros2-sqlite3", "ros2-sqlite3-zstd")  # the last compressed file by file
SEED = 1234


@pytest.fixture(scope="module")
def originals(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("fuzz_originals")
    msgs = sorted(room_messages(0.0, 3.0, pillar=True) + _compressed_camera(3.0), key=lambda m: m.log_time_ns)
    long_msgs = room_messages(0.0, 9.0, pillar=True)  # for a window past the tf lead: chunks before it go unread
    out = {}
    for fmt in FORMATS:
        kw = {"chunk_size": 4096} if fmt == "mcap-ros2" else {"ros1_chunk_size": 4096} if fmt == "ros1" else {}
        name = {"ros1": "log.bag", "mcap-ros2": "log.mcap", "ros2-sqlite3": "bag", "ros2-sqlite3-zstd": "bagz"}[fmt]
        writer = fmt.removesuffix("-zstd")
        if fmt.endswith("-zstd"):
            kw["ros2_compression"] = "file"
        out[fmt] = write_log(d / name, writer, msgs, **kw)
        out[fmt + "-long"] = write_log(d / ("long_" + name), writer, long_msgs, **kw)
    return out


def _compressed_camera(duration_s: float) -> list:
    """A small depth camera recorded through image_transport's compressedDepth (PNG and RVL in
    turn) at 5 Hz, so the mutations reach the compressed depth decoder too."""
    import numpy as np
    from logfactory import camera_info, compressed_depth, tf
    from test_replay import T0

    s = 1_000_000_000
    px = np.full((12, 16), 1800, np.uint16)
    px[3:6, 4:9] = 900
    px[0, :] = 0
    out = [tf(T0 + s // 100, [("base_link", "cam_optical", (0.1, 0.0, 0.5), (0.5, -0.5, 0.5, -0.5))], static=True)]
    for i in range(int(duration_s * 5)):
        t = T0 + s // 10 + i * s // 5
        out.append(camera_info("/cam/depth/camera_info", t, width=16, height=12, fx=14, fy=14, cx=7.5, cy=5.5,
                               frame_id="cam_optical"))  # fmt: skip
        out.append(compressed_depth("/cam/depth/image_raw/compressedDepth", t + 1, px, codec=("png", "rvl")[i % 2],
                                    frame_id="cam_optical"))  # fmt: skip
    return out


def _target(path: Path) -> Path:
    """The file to mutate: the bag or .mcap itself, or the ROS 2 bag's .db3 (or .db3.zstd)."""
    return next(f for f in sorted(path.iterdir()) if f.suffix in (".db3", ".zstd")) if path.is_dir() else path


def mutate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One seeded mutation: flipped bytes, a 32-bit field set to an extreme, a range zeroed,
    deleted or duplicated, or the file cut short."""
    b = bytearray(data)
    n = len(b)
    kind = rng.choice(("flip", "flip", "u32", "zero", "delete", "duplicate", "truncate"))
    at = rng.randrange(n)
    if kind == "flip":
        k = rng.randint(1, 8)
        for _ in range(k):
            i = rng.randrange(n)
            b[i] ^= 1 << rng.randrange(8)
        return bytes(b), f"flip {k} bits from byte {at}"
    if kind == "u32":
        v = rng.choice((0, 0xFFFFFFFF, 0x80000000, 0x7FFFFFFF, rng.randrange(2**32)))
        b[at : at + 4] = v.to_bytes(4, "little")
        return bytes(b[:n]), f"u32 {v:#x} at byte {at}"
    span = rng.randint(1, max(1, n // 20))
    if kind == "zero":
        b[at : at + span] = bytes(len(b[at : at + span]))
        return bytes(b), f"zero {span} bytes at {at}"
    if kind == "delete":
        del b[at : at + span]
        return bytes(b), f"delete {span} bytes at {at}"
    if kind == "duplicate":
        b[at:at] = b[at : at + span]
        return bytes(b), f"duplicate {span} bytes at {at}"
    return bytes(b[: max(1, at)]), f"truncate at {max(1, at)}"


@contextmanager
def _alarm(seconds: int, what: str):
    def boom(*_):
        raise TimeoutError(f"no answer within {seconds} s: {what}")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _check(res, what: str) -> None:
    exc = res.exception
    if exc is not None and not isinstance(exc, SystemExit):
        import traceback

        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        pytest.fail(f"{what}: {type(exc).__name__} escaped the CLI:\n{tb[-3000:]}")
    assert res.exit_code in (0, 2), f"{what}: exit {res.exit_code}: {res.output[-1500:]}"
    if res.exit_code == 2:
        errors = [x for x in res.output.splitlines() if x.startswith("ltmap: error: ")]
        assert len(errors) == 1 and len(errors[0]) < 2000, f"{what}: {res.output[-1500:]}"


def _mutated_copy(original: Path, case: Path, rng: random.Random) -> tuple[Path, str]:
    if original.is_dir():
        shutil.copytree(original, case / original.name)
    else:
        shutil.copy(original, case / original.name)
    path = case / original.name
    target = _target(path)
    data, how = mutate(target.read_bytes(), rng)
    target.write_bytes(data)
    return path, how


def fuzz(fmt: str, original: Path, work: Path, count: int, long_original: Path | None = None) -> dict[int, int]:
    rng = random.Random(f"{SEED}-{fmt}")
    rng_long = random.Random(f"{SEED}-{fmt}-long")
    runner = CliRunner()
    statuses: dict[int, int] = {}
    for k in range(count):
        case = work / f"case{k}"
        case.mkdir()
        path, how = _mutated_copy(original, case, rng)
        what = f"{fmt} mutation {k} (seed {SEED}: {how})"
        with _alarm(60, what):
            res = runner.invoke(cli, ["info", str(path)])
        _check(res, f"info, {what}")
        statuses[res.exit_code] = statuses.get(res.exit_code, 0) + 1
        with _alarm(120, what):
            res = runner.invoke(cli, ["replay", str(path), "--allow-truncated", "-q", "--no-plots",
                                      "-o", str(case / "out")])
        _check(res, f"replay --allow-truncated, {what}")
        statuses[100 + res.exit_code] = statuses.get(100 + res.exit_code, 0) + 1
        if long_original is not None:  # a window past the tf lead: the readers skip what lies before it
            (case / "long").mkdir()
            lpath, lhow = _mutated_copy(long_original, case / "long", rng_long)
            lwhat = f"{fmt} long mutation {k} (seed {SEED}-long: {lhow})"
            with _alarm(120, lwhat):
                res = runner.invoke(cli, ["replay", str(lpath), "--allow-truncated", "-q", "--no-plots", "--start",
                                          "7", "--end", "8", "-o", str(case / "out_window")])  # fmt: skip
            _check(res, f"replay --allow-truncated --start 7 --end 8, {lwhat}")
            statuses[200 + res.exit_code] = statuses.get(200 + res.exit_code, 0) + 1
        shutil.rmtree(case)
    return statuses


@pytest.mark.parametrize("fmt", FORMATS)
def test_fuzz_30_mutations(fmt, originals, tmp_path):
    statuses = fuzz(fmt, originals[fmt], tmp_path, 30, originals[fmt + "-long"])
    assert sum(v for k, v in statuses.items() if k < 100) == 30


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS)
def test_fuzz_200_mutations(fmt, originals, tmp_path):
    statuses = fuzz(fmt, originals[fmt], tmp_path, 200, originals[fmt + "-long"])
    assert sum(v for k, v in statuses.items() if k < 100) == 200
    # the mutations do damage: some runs are refused, and some still replay
    assert statuses.get(2, 0) + statuses.get(102, 0) > 0 and statuses.get(100, 0) > 0, statuses
