"""Hostile and broken inputs (SPEC 9, issue 16): each is a small file (under 1 MB, made here)
that asks for gigabytes, forever, or a traceback. Each runs the real command in a subprocess
and must end with exit status 2, exactly one stderr line, no traceback, within 60 s and below
1 GB peak memory (the child's own ru_maxrss, from os.wait4; an address-space limit of 3 GB
keeps a regression from hurting the machine)."""

from __future__ import annotations

import json
import os
import re
import resource
import struct
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hostilefactory import (
    bz2_bomb_bag,
    map_yaml,
    mcap_with_chunk,
    png,
    scans_bag,
    yaml_bomb,
    zstd_rle,
)

GB = 2**30
AS_LIMIT = 3 * GB  # a safety net only: the assertion is on the measured peak below


class Run:
    def __init__(self, code: int, out: str, err: str, peak_mb: float, wall_s: float):
        self.code, self.out, self.err, self.peak_mb, self.wall_s = code, out, err, peak_mb, wall_s

    @property
    def lines(self) -> list[str]:
        return [line for line in self.err.splitlines() if line.strip()]


def run_cli(tmp_path: Path, *args, timeout: float = 60.0) -> Run:
    """``python -m ltmap_cli ARGS`` in a fresh process; its peak RSS and wall time."""
    out_f, err_f = tmp_path / "_stdout.txt", tmp_path / "_stderr.txt"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    env.pop("LTMAP_DEBUG", None)
    t0 = time.monotonic()
    with out_f.open("w") as fo, err_f.open("w") as fe:
        proc = subprocess.Popen([sys.executable, "-m", "ltmap_cli", *map(str, args)], stdout=fo, stderr=fe,
                                stdin=subprocess.DEVNULL, cwd=tmp_path, env=env,
                                preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT)))
        timer = threading.Timer(timeout, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.monotonic() - t0
    return Run(proc.returncode, out_f.read_text(), err_f.read_text(), usage.ru_maxrss / 1024, wall)


def refused(r: Run, *words: str) -> str:
    """Exit 2, one stderr line that is an ltmap error, no traceback, in time, below 1 GB."""
    assert "Traceback" not in r.err + r.out, r.err[-2000:]
    assert "MemoryError" not in r.err, r.err[-500:]
    assert r.code == 2, (r.code, r.err[-1000:])
    assert len(r.lines) == 1, r.err[-2000:]
    line = r.lines[0]
    assert line.startswith("ltmap: error: "), line
    assert len(line) < 600, line
    assert r.wall_s < 60, r.wall_s
    assert r.peak_mb < 1024, r.peak_mb
    for w in words:
        assert w in line, (w, line)
    return line


# ----------------------------------------------------------------------------- compressed logs

BOMB = 3 * GB


@pytest.fixture(scope="module")
def bombs(tmp_path_factory):
    d = tmp_path_factory.mktemp("bombs")
    rle = zstd_rle(BOMB)
    files = {
        "mcap-indexed": mcap_with_chunk(d / "indexed.mcap", "zstd", rle, BOMB),
        "mcap-streamed": mcap_with_chunk(d / "streamed.mcap", "zstd", rle, BOMB, summary=False),
        "bag-bz2": bz2_bomb_bag(d / "bomb.bag", BOMB),
    }
    for f in files.values():
        assert f.stat().st_size < 2**20
    return files


@pytest.mark.parametrize("kind", ["mcap-indexed", "mcap-streamed", "bag-bz2"])
@pytest.mark.parametrize("command", ["info", pytest.param("replay", marks=pytest.mark.slow),
                                     pytest.param("replay --allow-truncated", marks=pytest.mark.slow)])
def test_a_chunk_declaring_3_gb_is_refused_before_decompressing(tmp_path, bombs, kind, command):
    args = command.split() + [bombs[kind]]
    if command.startswith("replay"):
        args += ["-o", tmp_path / "out", "-q"]
    line = refused(run_cli(tmp_path, *args), str(bombs[kind]), "3,072.0 MB", "replay.max_message_mb")
    assert "chunk at byte" in line or "chunk before byte" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_the_limit_is_a_setting(tmp_path, bombs):
    """Raised above the declared size, the chunk is decompressed (bounded by what it declares):
    the RLE frame of zeros is not an MCAP record stream, so the chunk is damaged, not a 3 GB read."""
    r = run_cli(tmp_path, "replay", bombs["mcap-indexed"], "-o", tmp_path / "out", "-q",
                "--set", "replay.max_message_mb=100")
    refused(r, "100 MB")


@pytest.mark.parametrize("kind", [pytest.param("mcap", marks=pytest.mark.slow), "bag"])
def test_a_chunk_that_expands_past_what_it_declares_stops_there(tmp_path, kind):
    """Declares 1000 bytes, expands to 3 GB: decompression stops at 1001 bytes; the chunk is damaged."""
    if kind == "mcap":
        path = mcap_with_chunk(tmp_path / "lie.mcap", "zstd", zstd_rle(BOMB), 1000)
    else:
        path = bz2_bomb_bag(tmp_path / "lie.bag", 1000)
    for extra in ([], ["--allow-truncated"]):
        r = run_cli(tmp_path, "replay", path, "-o", tmp_path / "out", "-q", *extra)
        refused(r, str(path) if not extra else "no sensor frames")
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- YAML


def test_yaml_alias_bomb_as_config(tmp_path):
    cfg = tmp_path / "bomb.yaml"
    cfg.write_text(yaml_bomb())
    assert cfg.stat().st_size < 400
    refused(run_cli(tmp_path, "replay", "--config", cfg, "--dump-config"), str(cfg), "aliases")


def test_yaml_alias_bomb_as_set_value(tmp_path):
    bomb = yaml_bomb().replace("\n", ", ").rstrip(", ")
    refused(run_cli(tmp_path, "replay", "--set", "replay.scan_topics={" + bomb + "}", "--dump-config"),
            "--set replay.scan_topics", "aliases")


def test_yaml_alias_bomb_as_map_yaml(tmp_path):
    m = tmp_path / "map.yaml"
    m.write_text(yaml_bomb() + "image: map.pgm\nresolution: 0.05\norigin: *i\nnegate: 0\n"
                 "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    refused(run_cli(tmp_path, "build-static", m, "-o", tmp_path / "out"), str(m), "aliases")
    refused(run_cli(tmp_path, "plan", m, "--start", "0,0", "--goal", "1,1"), str(m), "aliases")


def test_yaml_alias_bomb_as_scenario(tmp_path):
    s = tmp_path / "scenario.yaml"
    s.write_text(yaml_bomb("walls"))
    refused(run_cli(tmp_path, "simulate", s, "-o", tmp_path / "out.mcap"), str(s), "aliases")


def test_yaml_alias_bomb_as_ros2_metadata(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(yaml_bomb("rosbag2_bagfile_information"))
    (bag / "bag_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    refused(run_cli(tmp_path, "info", bag), str(bag))


def test_bad_values_are_shown_cut(tmp_path):
    """A user value in a message is cut to a bounded length (no 100 kB line)."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text("map:\n  resolution: '" + "x" * 100_000 + "'\n")
    line = refused(run_cli(tmp_path, "replay", "--config", cfg, "--dump-config"), "map.resolution")
    assert "100000 characters" in line


def test_scientific_notation_is_a_number(tmp_path):
    r = run_cli(tmp_path, "replay", "--set", "map.resolution=1e-1", "--set", "replay.snapshot_every=1.5E+2",
                "--dump-config")
    assert r.code == 0, r.err
    assert "resolution: 0.1\n" in r.out and "snapshot_every: 150.0" in r.out
    line = refused(run_cli(tmp_path, "replay", "--set", "map.resolution=1e9", "--dump-config"))
    assert "must be within" in line and "1000000000.0" in line  # a number, out of range; not "not a number"


def test_empty_output_is_refused(tmp_path):
    bag = scans_bag(tmp_path / "s.bag", n=5)
    refused(run_cli(tmp_path, "replay", bag, "-o", ""), "-o")
    svg = tmp_path / "p.svg"
    svg.write_text(SVG_700.replace("700", "7"))
    refused(run_cli(tmp_path, "build-static", svg, "-o", ""), "-o")
    scenario = tmp_path / "s.yaml"
    scenario.write_text("duration: 1\n")
    refused(run_cli(tmp_path, "simulate", scenario, "-o", ""), "-o")
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("_")) == ["p.svg", "s.bag", "s.yaml"]


# ----------------------------------------------------------------------------- images


@pytest.mark.parametrize("side", [12000, pytest.param(14000, marks=pytest.mark.slow)])
def test_a_huge_map_image_is_refused_from_its_header(tmp_path, side):
    img = png(tmp_path / "big.png", side, side)
    assert img.stat().st_size < 2**20
    m = map_yaml(tmp_path / "big.yaml", "big.png")
    line = refused(run_cli(tmp_path, "build-static", m, "-o", tmp_path / "out"), str(img), "--max-cells",
                   f"{side} x {side}")
    assert not (tmp_path / "out").exists()
    refused(run_cli(tmp_path, "plan", m, "--start", "1,1", "--goal", "2,2"), str(img), "--max-cells")
    refused(run_cli(tmp_path, "replay", scans_bag(tmp_path / "s.bag", n=5), "--static", m, "-o",
                    tmp_path / "out", "-q"), str(img))
    assert line


@pytest.mark.parametrize("target", ["/dev/zero", "fifo"])
def test_a_map_image_that_is_a_device_or_fifo_is_refused_at_once(tmp_path, target):
    if target == "fifo":
        image = tmp_path / "pipe.pgm"
        os.mkfifo(image)
        word = "FIFO"
    else:
        image = Path(target)
        if not image.exists():
            pytest.skip("no /dev/zero")
        word = "device"
    m = map_yaml(tmp_path / "map.yaml", str(image))
    refused(run_cli(tmp_path, "build-static", m, "-o", tmp_path / "out", timeout=30), word, str(image))
    refused(run_cli(tmp_path, "plan", m, "--start", "1,1", "--goal", "2,2", timeout=30), word)
    refused(run_cli(tmp_path, "replay", scans_bag(tmp_path / "s.bag", n=5), "--static", m, "-o",
                    tmp_path / "out", "-q", timeout=30), word)


def test_a_log_or_config_that_is_a_fifo_is_refused_at_once(tmp_path):
    pipe = tmp_path / "log.bag"
    os.mkfifo(pipe)
    refused(run_cli(tmp_path, "info", pipe, timeout=30), "FIFO")
    cfg = tmp_path / "cfg.yaml"
    os.mkfifo(cfg)
    refused(run_cli(tmp_path, "replay", "--config", cfg, "--dump-config", timeout=30), "FIFO")


# ----------------------------------------------------------------------------- static map size

SVG_700 = ('<svg xmlns="http://www.w3.org/2000/svg" width="700m" height="700m" viewBox="0 0 700 700">'
           '<g id="walls"><rect x="0" y="0" width="700" height="700" fill="none" stroke="black" '
           'stroke-width="0.2"/></g></svg>')


def test_a_700_m_plan_is_refused_before_allocating(tmp_path):
    svg = tmp_path / "huge.svg"
    svg.write_text(SVG_700)
    assert svg.stat().st_size < 300
    line = refused(run_cli(tmp_path, "build-static", svg, "-o", tmp_path / "out"), str(svg), "--max-cells",
                   "GB")
    assert re.search(r"the map would be 140\d\d x 140\d\d = 1.96e\+08 cells \(700.\d x 700.\d m", line), line
    assert not (tmp_path / "out").exists()


def test_a_static_map_too_large_for_the_voxel_lattice_is_refused(tmp_path):
    """A 200 m map (4000 x 4000 at 0.05 m, 60 kB of PNG) under --resolution 0.005 would be a
    40000 x 40000 lattice (over 100 GB): refused with the size, the setting and what to do."""
    png(tmp_path / "m.png", 4000, 4000)
    m = map_yaml(tmp_path / "m.yaml", "m.png")
    bag = scans_bag(tmp_path / "s.bag", n=5)
    line = refused(run_cli(tmp_path, "replay", bag, "--static", m, "--resolution", "0.005", "-o",
                           tmp_path / "out", "-q"), str(m), "replay.max_static_mb", "4000 x 4000")
    assert "GB" in line


# ----------------------------------------------------------------------------- state files


def _state(path: Path, static: bool = False) -> Path:
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.io.state import write_state

    lmap = LayeredMap(MapConfig())
    keys = np.array([[i, 3, 5] for i in range(20)], dtype=np.int64)
    lmap.seed_long_term(keys, np.full(20, 0.9, dtype=np.float32))
    write_state(path, lmap.state_arrays(), {"log_time_s": None, "static_digest": None})
    return path


def _rewrite(src: Path, dst: Path, header=None, drop=(), change=None) -> Path:
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("__header__")))
    if header is not None:
        meta = header(meta)
    for k in drop:
        arrays.pop(k)
    if change:
        change(arrays)
    with dst.open("wb") as f:
        np.savez_compressed(f, __header__=np.array(json.dumps(meta)), **arrays)
    return dst


def _set(key, value):
    def f(meta):
        meta[key] = value
        return meta
    return f


STATE_FAULTS = {
    "version abc": (dict(header=_set("version", "abc")), "bad state version 'abc'"),
    "version null": (dict(header=_set("version", None)), "bad state version None"),
    "version 0": (dict(header=_set("version", 0)), "bad state version 0"),
    "version -7": (dict(header=_set("version", -7)), "bad state version -7"),
    "version 1.9": (dict(header=_set("version", 1.9)), "bad state version 1.9"),
    "header list": (dict(header=lambda m: [1, 2, 3]), "JSON list, not an object"),
    "no resolution": (dict(drop=["resolution"]), "missing array resolution"),
    "no D_lt": (dict(drop=["D_lt"]), "missing array D_lt"),
    "wrong shape": (dict(change=lambda a: a.__setitem__("D_lt", a["D_lt"][:, :100])), "D_lt has shape"),
    "NaN lt": (dict(change=lambda a: a["D_lt"].__setitem__((0, 0), np.nan)), "NaN"),
    "ints for lt": (dict(change=lambda a: a.__setitem__("D_lt", a["D_lt"].astype(np.int64))), "holds int64"),
}

COMMANDS = {
    "replay --resume": lambda s, tmp: ["replay", scans_bag(tmp / "s.bag", n=5), "--resume", s, "-o", tmp / "out", "-q"],
    "diff": lambda s, tmp: ["diff", s, s],
    "diff --3d": lambda s, tmp: ["diff", "--3d", s, s],
    "plan": lambda s, tmp: ["plan", s, "--start", "0,0", "--goal", "1,1"],
}


@pytest.mark.parametrize("fault", [f if k < len(COMMANDS) else pytest.param(f, marks=pytest.mark.slow)
                                   for k, f in enumerate(STATE_FAULTS)])
def test_a_broken_state_file_is_one_line(tmp_path, fault):
    good = _state(tmp_path / "good.npz")
    kwargs, words = STATE_FAULTS[fault]
    bad = _rewrite(good, tmp_path / "state_bad.npz", **kwargs)
    names = list(COMMANDS)
    command = names[list(STATE_FAULTS).index(fault) % len(names)]  # each fault through one command here
    line = refused(run_cli(tmp_path, *COMMANDS[command](bad, tmp_path)), str(bad), words)
    assert "write it again" in line


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_state_fault_through_every_command_in_process(tmp_path, command):
    """The whole matrix, in this process (fast): exit 2 and one line naming the file."""
    from click.testing import CliRunner

    from ltmap_cli.cli import cli

    good = _state(tmp_path / "good.npz")
    for fault, (kwargs, words) in STATE_FAULTS.items():
        bad = _rewrite(good, tmp_path / "state_bad.npz", **kwargs)
        res = CliRunner().invoke(cli, [str(a) for a in COMMANDS[command](bad, tmp_path)])
        assert res.exit_code == 2 and res.exception is None or isinstance(res.exception, SystemExit), \
            (fault, res.output)
        assert res.exit_code == 2, (fault, res.output)
        lines = [x for x in res.output.splitlines() if x.startswith("ltmap: error")]
        assert len(lines) == 1 and str(bad) in lines[0] and words in lines[0], (fault, res.output)


def test_flipped_bytes_in_a_state_file(tmp_path):
    """Bytes flipped inside the compressed arrays (zlib errors, CRC errors) are one line."""
    good = _state(tmp_path / "good.npz")
    data = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as zf:
        info = zf.getinfo("D_lt.npy")
    name_len, extra_len = struct.unpack_from("<HH", data, info.header_offset + 26)  # the local header's own
    start = info.header_offset + 30 + name_len + extra_len
    for k, off in enumerate((10, info.compress_size // 2, info.compress_size - 5)):
        bad = bytearray(data)
        bad[start + off] ^= 0xFF
        path = tmp_path / f"state_flip{k}.npz"
        path.write_bytes(bytes(bad))
        refused(run_cli(tmp_path, "diff", path, path), str(path), "not a readable ltmap state file")


def test_resume_with_another_static_map_warns(tmp_path):
    """The state file stores a hash of S: resuming with another S (or none) is said in a warning."""
    from click.testing import CliRunner

    from ltmap_cli.cli import cli

    png(tmp_path / "a.png", 60, 60, grey=254)
    png(tmp_path / "b.png", 60, 60, grey=0)
    a = map_yaml(tmp_path / "a.yaml", "a.png")
    b = map_yaml(tmp_path / "b.yaml", "b.png")
    bag = scans_bag(tmp_path / "s.bag", n=30)
    base = ["replay", str(bag), "-q", "--no-plots", "--tf", "map:laser=1.5,1.5,0.3,0,0,0", "--fixed-frame", "map"]
    res = CliRunner().invoke(cli, [*base, "--static", str(a), "-o", str(tmp_path / "day1")])
    assert res.exit_code == 0, res.output
    state = tmp_path / "day1" / "snapshots" / "state_final.npz"
    same = CliRunner().invoke(cli, [*base, "--static", str(a), "--resume", str(state), "-o", str(tmp_path / "d2")])
    assert same.exit_code == 0 and "another static map" not in same.output, same.output
    other = CliRunner().invoke(cli, [*base, "--static", str(b), "--resume", str(state), "-o", str(tmp_path / "d3")])
    assert other.exit_code == 0, other.output
    assert "ltmap: warning: --resume" in other.output and "another static map" in other.output
    none = CliRunner().invoke(cli, [*base, "--resume", str(state), "-o", str(tmp_path / "d4")])
    assert none.exit_code == 0 and "no static map, and the run that wrote it had one" in none.output


def test_state_file_fuzz_200_seeded_mutations(tmp_path):
    """Seeded mutations of a state file (bytes flipped, runs overwritten, cut, bytes inserted,
    anywhere: zip headers, numpy array headers, deflated data) read as --resume and diff read
    it: the arrays, or one MapFileError; never another exception (numpy's header parser raised
    tokenize's TokenError on a damaged header)."""
    import random

    from ltmap_cli.errors import MapFileError
    from ltmap_cli.outputs.snapshots import read_snapshot_voxels

    good = _state(tmp_path / "good.npz").read_bytes()
    rng = random.Random(4321)
    outcomes = {"read": 0, "refused": 0}
    for k in range(200):
        bad = bytearray(good)
        kind = rng.choice(("flip", "run", "cut", "insert"))
        at = rng.randrange(len(bad))
        if kind == "flip":
            for _ in range(rng.randint(1, 4)):
                bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
        elif kind == "run":
            bad[at:at + 16] = bytes(rng.randrange(256) for _ in range(16))
        elif kind == "cut":
            del bad[at:]
        else:
            bad[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
        path = tmp_path / f"m{k}.npz"
        path.write_bytes(bytes(bad))
        try:
            read_snapshot_voxels(path)
            outcomes["read"] += 1
        except MapFileError as err:
            assert str(path) in str(err) and "\n" not in str(err), (k, kind, at)
            outcomes["refused"] += 1
    assert outcomes["refused"] > 100, outcomes  # most damage is found (zip CRCs)
