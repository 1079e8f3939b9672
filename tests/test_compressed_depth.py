"""Depth recorded through image_transport (sensor_msgs/CompressedImage): compressedDepth PNG and
RVL, the compressed transport's PNG; written as the plugins write them (``logfactory.compressed_depth``,
with its own RVL encoder and Pillow's PNG writer), read back exactly; the real RealSense frames
map the same raw or compressed; the same images on several transports are used once; hostile and
damaged payloads are one line or one skipped message, never a decoded bomb."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from logfactory import FORMATS, SUFFIX, camera_info, compressed_depth, image, tf, write_log

from ltmap_cli.cli import cli
from ltmap_cli.errors import LogReadError
from ltmap_cli.io import compressed_depth as cd
from ltmap_cli.io.logs import open_logs

S = 1_000_000_000
REALSENSE = Path(__file__).resolve().parents[1].parent / "shared" / "real_logs" / "realsense_d435_single_depth_640x480.bag"
TOPIC = "/cam/depth/image_raw"


def _pixels(h=48, w=64, seed=1):
    rng = np.random.default_rng(seed)
    px = rng.integers(1, 65535, size=(h, w)).astype(np.uint16)
    px[rng.random(px.shape) < 0.2] = 0
    px[5:9, :] = 0  # a run of zeros across rows
    px[20, 10:50] = 1234  # a flat run (delta 0)
    px[0, 0], px[-1, -1] = 65535, 1
    return px


@pytest.mark.parametrize("codec", ["png", "rvl", "old", "plain-png"])
def test_every_codec_decodes_to_the_recorded_pixels(codec):
    px = _pixels()
    m = compressed_depth(TOPIC, S, px, codec=codec, depth_max=70.0)  # (nothing above depth_max: kept whole)
    got = cd.decode(m.fields["data"].tobytes(), m.fields["format"], (64, 48), "here")
    assert got.dtype == np.uint16 and np.array_equal(got, px)


def test_32fc1_is_the_plugins_inverse_depth_within_one_quantization_step():
    """32FC1 through compressedDepth (ROS defaults: depth_quantization 100, depth_max 10 m): the
    pixel is A / d + B truncated, so the decoded depth is at most one step, about d^2 / A, farther;
    invalid (NaN) where the image had none or was at depth_max or beyond."""
    rng = np.random.default_rng(2)
    d = rng.uniform(0.3, 12.0, size=(30, 40)).astype(np.float32)
    d[rng.random(d.shape) < 0.1] = np.nan
    for codec in ("png", "rvl"):
        m = compressed_depth(TOPIC, S, d, encoding="32FC1", codec=codec)
        got = cd.decode(m.fields["data"].tobytes(), m.fields["format"], (40, 30), "here")
        ok = np.isfinite(d) & (d < 10.0)
        assert got.dtype == np.float32 and np.array_equal(np.isnan(got), ~ok)
        a = 100.0 * 101.0
        err = (got[ok] - d[ok]) / (d[ok].astype(np.float64) ** 2 / a)  # in steps
        assert err.min() > -1e-3 and err.max() < 1.01 and err.mean() > 0.3, (err.min(), err.max())


def _depth_log(tmp_path, fmt, frames, topics=("raw",), name="log", size=None, **kw):
    """A log of ``frames`` (16UC1 arrays) on the raw topic and/or its transports ("compressedDepth",
    "compressed"), with CameraInfo and the camera placed by a static tf."""
    h, w = frames[0].shape
    cw, ch = size if size is not None else (w, h)
    msgs = [tf(S // 2, [("map", "camera_optical", (0.0, 0.0, 1.0), (0.5, -0.5, 0.5, -0.5))], static=True)]
    for i, px in enumerate(frames):
        t = S + i * S // 10
        msgs.append(camera_info("/cam/depth/camera_info", t, width=cw, height=ch, fx=0.9 * w, fy=0.9 * w,
                                cx=(w - 1) / 2, cy=(h - 1) / 2))  # fmt: skip
        for k, topic in enumerate(topics):
            if topic == "raw":
                msgs.append(image(TOPIC, t + 1 + k, px))
            else:
                codec = kw.get("codec", "png") if topic == "compressedDepth" else "plain-png"
                msgs.append(compressed_depth(f"{TOPIC}/{topic}", t + 1 + k, px, codec=codec))
    return write_log(tmp_path / (name + SUFFIX[fmt]), fmt, msgs)


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_log_format_reads_compressed_depth_back_exactly(tmp_path, fmt):
    frames = [np.clip(_pixels(24, 32, seed=s), 0, 9000) for s in range(3)]
    log = _depth_log(tmp_path, fmt, frames, topics=("compressedDepth",), codec="rvl" if fmt != "ros1" else "png")
    with open_logs(log) as logs:
        sel = logs.select()
        assert list(sel.depths) == [f"{TOPIC}/compressedDepth"] and sel.depths[f"{TOPIC}/compressedDepth"] == \
            "/cam/depth/camera_info"  # fmt: skip
        fast = [f for _, _, f in logs.messages(sel, fast=True) if hasattr(f, "raw")]
    with open_logs(log) as logs:
        slow = [f for _, _, f in logs.messages(logs.select()) if hasattr(f, "depth_m")]
    assert len(fast) == len(slow) == 3
    for px, a, b in zip(frames, fast, slow):
        assert np.array_equal(a.raw, px) and a.stamp_ns == b.stamp_ns and a.frame_id == "camera_optical"
        want = px.astype(np.float32) * np.float32(0.001)
        want[px == 0] = np.nan
        assert np.array_equal(b.depth_m, want, equal_nan=True)


def _replay(log, out, *extra):
    r = CliRunner().invoke(cli, ["replay", str(log), "-o", str(out), "-q", "--no-plots", *extra])
    return r, (json.loads((out / "report.json").read_text()) if r.exit_code == 0 else None)


def _state(out):
    from ltmap_cli.io.state import read_state

    return read_state(out / "snapshots" / "state_final.npz")[0]


@pytest.mark.skipif(not REALSENSE.is_file(), reason=f"RealSense recording not present at {REALSENSE}")
def test_the_real_realsense_frames_map_the_same_raw_or_compressed(tmp_path):
    """The two real D435 frames (holes, flying pixels) recorded raw, as compressedDepth PNG and
    RVL, and through the compressed transport's PNG: the same map, array for array."""
    from rosbags.highlevel import AnyReader

    with AnyReader([REALSENSE]) as reader:
        conns = [c for c in reader.connections if c.topic == "/device_0/sensor_0/Depth_0/image/data"]
        frames = [np.frombuffer(reader.deserialize(raw, c.msgtype).data, "<u2").reshape(480, 640).copy()
                  for c, _, raw in reader.messages(conns)]  # fmt: skip
    assert len(frames) == 2 and (frames[0] == 0).mean() > 0.02
    states = {}
    for name, topics, kw in (("raw", ("raw",), {}), ("png", ("compressedDepth",), {}),
                             ("rvl", ("compressedDepth",), {"codec": "rvl"}), ("plain", ("compressed",), {})):
        log = _depth_log(tmp_path, "mcap-ros2", frames, topics=topics, name=name, **kw)
        r, rep = _replay(log, tmp_path / f"o_{name}")
        assert r.exit_code == 0, r.output
        assert sum(rep["frames_used"].values()) == 2 and not rep["frames_skipped"], rep["frames_used"]
        states[name] = _state(tmp_path / f"o_{name}")
    assert (states["raw"]["O_logodds"] > 0).sum() > 1000  # (the real scene: thousands of occupied voxels)
    for name in ("png", "rvl", "plain"):
        assert states[name].keys() == states["raw"].keys()
        assert all(np.array_equal(states[name][k], states["raw"][k]) for k in states["raw"]), name


def test_the_same_images_on_several_transports_are_used_once(tmp_path):
    """``rosbag record -a`` keeps the raw image and image_transport's compressedDepth and
    compressed topics of it: the raw one is used, else compressedDepth; the others are named as
    the same images, and --depth-topic chooses any of them."""
    frames = [np.full((24, 32), 1500, np.uint16) for _ in range(3)]
    log = _depth_log(tmp_path, "mcap-ros2", frames, topics=("raw", "compressedDepth", "compressed"))
    r, rep = _replay(log, tmp_path / "a")
    assert r.exit_code == 0, r.output
    assert rep["frames_used"] == {TOPIC: 3}
    for tr in ("compressedDepth", "compressed"):
        assert rep["topics_not_used"][f"{TOPIC}/{tr}"].startswith(f"the same depth images as {TOPIC} "
                                                                  f"(image_transport's {tr} transport)")  # fmt: skip
    log2 = _depth_log(tmp_path, "mcap-ros2", frames, topics=("compressed", "compressedDepth"), name="b")
    r, rep2 = _replay(log2, tmp_path / "b")
    assert r.exit_code == 0 and rep2["frames_used"] == {f"{TOPIC}/compressedDepth": 3}, r.output
    assert "the same depth images as " + f"{TOPIC}/compressedDepth" in rep2["topics_not_used"][f"{TOPIC}/compressed"]
    r, rep3 = _replay(log2, tmp_path / "c", "--depth-topic", f"{TOPIC}/compressed")
    assert r.exit_code == 0 and rep3["frames_used"] == {f"{TOPIC}/compressed": 3}, r.output
    assert [np.array_equal(_state(tmp_path / o)[k], _state(tmp_path / "a")[k]) for o in ("b", "c")
            for k in _state(tmp_path / "a")].count(False) == 0


def _bomb_png(w, h) -> bytes:
    """A PNG declaring w x h 16-bit grey pixels whose IDAT holds a few kB (zlib of a few rows)."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)
    return cd.PNG_SIGNATURE + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 200_000, 9)) + \
        chunk(b"IEND", b"")  # fmt: skip


def _one_line(r, *needles):
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("ltmap: error: "), r.stderr
    for n in needles:
        assert n in lines[0], lines[0]


def test_hostile_and_damaged_compressed_depth(tmp_path):
    """A few kB declaring 14000 x 14000 pixels (PNG or RVL) is refused from its header, in one
    line; with a CameraInfo that gives no size, above MAX_PIXELS; a JPEG or 8-bit PNG is not
    depth (one line); a damaged payload (cut PNG, cut RVL, a run past the image) skips that
    message with one warning, and the other frames are mapped."""
    head = struct.pack("<iff", 0, 0.0, 0.0)
    for body in (_bomb_png(14000, 14000), struct.pack("<II", 14000, 14000) + b"\x11" * 3000):
        codec = "png" if body.startswith(cd.PNG_SIGNATURE) else "rvl"
        assert len(head + body) < 8000
        for size, words in (((640, 480), ["is 14000x14000 but its CameraInfo says 640x480"]),
                            (None, ["declares 14000x14000 pixels", f"at most {cd.MAX_PIXELS}"])):
            with pytest.raises(LogReadError) as e:
                cd.decode(head + body, f"16UC1; compressedDepth {codec}", size, "on /x, message index 0")
            assert all(w in str(e.value) for w in words), str(e.value)

    frames = [np.full((24, 32), 1500, np.uint16) for _ in range(4)]
    log = _depth_log(tmp_path, "mcap-ros2", frames, topics=("compressedDepth",), name="bomb", size=(640, 480))
    r, _ = _replay(log, tmp_path / "o_bomb")
    _one_line(r, "is 32x24 but its CameraInfo says 640x480")

    msgs = [tf(S // 2, [("map", "camera_optical")], static=True),
            camera_info("/cam/depth/camera_info", S, width=32, height=24, fx=30, fy=30, cx=15.5, cy=11.5)]
    good = [compressed_depth(f"{TOPIC}/compressedDepth", S + i * S // 10, frames[0], codec=c)
            for i, c in enumerate(("png", "rvl", "png", "rvl"))]
    cut_png, cut_rvl = good[2], good[3]
    cut_png.fields["data"] = cut_png.fields["data"][:60]
    cut_rvl.fields["data"] = cut_rvl.fields["data"][:26]
    log = write_log(tmp_path / "damaged.mcap", "mcap-ros2", msgs + good)
    res = CliRunner().invoke(cli, ["replay", str(log), "-o", str(tmp_path / "o_dmg"), "-q", "--no-plots"])
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "o_dmg" / "report.json").read_text())
    assert rep["frames_used"] == {f"{TOPIC}/compressedDepth": 2}
    assert rep["messages_not_decoded"] == {f"cannot decode the message on {TOPIC}/compressedDepth": 2}
    warns = [ln for ln in res.stderr.splitlines() if "cannot decode" in ln]
    assert len(warns) == 1 and "message index 2" in warns[0] and "PNG cannot be decoded" in warns[0], res.stderr

    for fmt_words, data, words in (
            ("16UC1; jpeg compressed mono8", b"\xff\xd8\xff\xe0" * 10, ["JPEG loses depth"]),
            ("bgr8; jpeg compressed bgr8", b"\xff\xd8\xff\xe0" * 10, ["not a depth image"]),
            ("16UC1; compressedDepth png", head + _bomb_png(32, 24)[:26] + b"\0" * 40, [])):
        if not words:  # an 8-bit PNG header instead
            data = bytearray(data)
            data[12 + 24] = 8
            words = ["PNG of 8-bit grey pixels, not 16-bit grey"]
        with pytest.raises(LogReadError) as e:
            cd.decode(bytes(data), fmt_words, (32, 24), "on /x")
        assert all(w in str(e.value) for w in words), str(e.value)


def test_seeded_mutations_of_compressed_payloads_decode_or_are_refused():
    """200 seeded mutations (flipped bytes, cuts, repeats) of PNG and RVL payloads: each decodes
    to the camera's size, or raises DamagedPayload / LogReadError; nothing else, nothing larger."""
    rng = np.random.default_rng(7)
    px = _pixels(24, 32)
    base = [compressed_depth(TOPIC, S, px, codec=c, depth_max=70.0).fields["data"].tobytes()
            for c in ("png", "rvl", "plain-png")]
    fmts = ["16UC1; compressedDepth png", "16UC1; compressedDepth rvl", "16UC1; png compressed mono16"]
    outcomes = {"decoded": 0, "damaged": 0, "refused": 0}
    for k in range(200):
        j = k % 3
        b = bytearray(base[j])
        kind = rng.integers(3)
        if kind == 0:
            for _ in range(int(rng.integers(1, 6))):
                b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            b = b[: int(rng.integers(len(b)))]
        else:
            a = int(rng.integers(len(b)))
            b = b[:a] + b[a: a + int(rng.integers(1, 64))] * 3 + b[a:]
        try:
            got = cd.decode(bytes(b), fmts[j], (32, 24), "here")
        except cd.DamagedPayload:
            outcomes["damaged"] += 1
        except LogReadError:
            outcomes["refused"] += 1
        else:
            assert got.shape == (24, 32)
            outcomes["decoded"] += 1
    assert outcomes["decoded"] and outcomes["damaged"], outcomes  # (both kinds met: the mutations bite)


def test_info_says_what_replay_does_with_compressed_depth(tmp_path):
    """``ltmap info`` names the transport's format of a compressed depth topic it would use, and
    warns, with replay's own line, when its first image is not depth replay can read (JPEG)."""
    frames = [np.full((24, 32), 1500, np.uint16) for _ in range(2)]
    log = _depth_log(tmp_path, "ros1", frames, topics=("compressedDepth",), codec="rvl")
    r = CliRunner().invoke(cli, ["info", str(log)])
    assert r.exit_code == 0, r.output
    row = next(ln for ln in r.stdout.splitlines() if ln.startswith(f"{TOPIC}/compressedDepth "))
    assert row.endswith("uses: depth, frame camera_optical (CameraInfo /cam/depth/camera_info), "
                        "32x24 fx 28.8 fy 28.8 cx 15.5 cy 11.5, 16UC1; compressedDepth rvl"), row  # fmt: skip
    msgs = [tf(S // 2, [("map", "camera_optical")], static=True),
            camera_info("/cam/depth/camera_info", S, width=32, height=24, fx=30, fy=30, cx=15.5, cy=11.5),
            compressed_depth(f"{TOPIC}/compressed", S + 1, frames[0], codec="jpeg")]
    log = write_log(tmp_path / "jpeg.mcap", "mcap-ros2", msgs)
    r = CliRunner().invoke(cli, ["info", str(log)])
    assert r.exit_code == 0 and f"  - {TOPIC}/compressed: replay would stop on its first message: compressed image " \
        f"on {TOPIC}/compressed, message index 0 in {log} has format '16UC1; jpeg compressed mono8'" in r.stdout, \
        r.stdout  # fmt: skip
    r, _ = _replay(log, tmp_path / "o")
    _one_line(r, "JPEG loses depth", "message index 0")


def test_a_format_string_of_a_megabyte_gives_a_short_line():
    with pytest.raises(LogReadError) as e:
        cd.decode(b"\0" * 40, "x" * 1_000_000, (32, 24), "on /x")
    assert len(str(e.value)) < 400 and "not a depth image" in str(e.value)
