"""Benchmark of a long replay: memory bounded and speed steady over tens of minutes of log, as
users with hours of RGB-D logs replay them.

The long log is a cached 30 s bench log (default: bench_long_rays' ``room``, 640x480 16UC1 depth
at 30 Hz, a 720-beam laser at 15 Hz, /odom, /tf, /tf_static; ROS 2 CDR, zstd chunks) repeated
``--repeats`` times back to back: copy k has every time shifted by k * (duration + one depth frame
period), both the MCAP log_time / publish_time and the header stamps inside the CDR payloads
(std_msgs/Header at the start of Image, CameraInfo, LaserScan, PointCloud2, Odometry; the Header of
each TransformStamped of a TFMessage). /tf_static is written once, unshifted. Schemas and channels
are copied once, payloads raw (only the stamp bytes are patched); the stamps written are checked
by decoding copies 1 and N-1 with mcap_ros2 against the source's plus the shift. The log is cached
as ``bench/.cache/long_log_<source folder>_<N>x.mcap`` (git-ignored; 347 MB per repeat of the
default source) and reused.

The replay runs in a fresh process (``ltmap_cli.pipeline.replay.Replay``, ``Config()`` with no
plots, as bench_long_rays; the numba kernels are compiled or loaded in another process first, so
the peak memory is the replay's alone). A thread samples the process's RSS (VmRSS in
/proc/self/status), the replay's progress (its ``progress`` callback: log seconds done, wall
seconds) and the sizes of what grows with the log every 0.5 s. Printed:

- per segment of log time (``--segment``, 60 s): RSS at its end and its peak inside it, speed
  over the segment (log seconds / wall seconds), the seconds of the stages that do the work in it
  (``rays``, ``cast``, ``integrate``, ``ticks``, ``output``), rows of the event history used /
  allocated and times thinned, transitions, O and D blocks, trajectory points, tf samples buffered;
- at the end: total wall, peak RSS (ru_maxrss), the end phase (wall from the progress callback at
  the log's end to the end of ``run()``, split by sink ``finish`` and, in the events sink, by
  ``find_events`` / ``event_histories``; and the report's stage times, ``stage_s``), the final
  sizes of the event history, transitions, O and D blocks and of the Python lists that grow per
  frame (``RunState.trajectory``, the MetricsSink's ``frame_ms`` / ``stamps`` / ``tick_ms``), the
  warnings the run raised, report.json's event count and events.csv's rows.

A looped log is not a real long log: the scene is the same room 30 s at a time, so the map's
extent stops growing after the first copy (O and D blocks stay flat); what should grow with the
log's length is only what the replay keeps per frame or per tick.

Run: python bench/bench_long_log.py [--repeats 20] [--source LOG] [--segment 60] [--keep]
     (--repeats 4 for a 2-minute check; 20 is a 10-minute log, ~7 GB cached, a few minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_replay  # noqa: E402  (machine, warm_kernels)

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "bench" / ".cache"
DEFAULT_SOURCE = CACHE / "long_rays_room_c9a724e9fd" / "log.mcap"
NS = 1_000_000_000
SAMPLE_S = 0.5
# stage seconds per segment in the table (rays, cast: busy time summed over the worker threads)
SEG_STAGES = ["rays", "cast", "integrate", "ticks", "output"]

# ---------------------------------------------------------------------------------------------
# The long log: the source repeated, times shifted

# Types whose CDR payload starts with a std_msgs/Header (its stamp right after the encapsulation).
HEADER_FIRST = {
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/LaserScan",
    "sensor_msgs/msg/PointCloud2",
    "nav_msgs/msg/Odometry",
}
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STATIC_TOPICS = {"/tf_static"}  # written once, unshifted
CDR_LE = b"\x00\x01"  # encapsulation kind: plain CDR, little endian (the alignment below assumes it)
STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec
U32 = struct.Struct("<I")


def _shift_stamp(buf: bytearray, off: int, shift_ns: int) -> None:
    sec, nsec = STAMP.unpack_from(buf, off)
    t = sec * NS + nsec + shift_ns
    STAMP.pack_into(buf, off, t // NS, t % NS)


def stamp_offsets(schema: str, data: bytes) -> list[int]:
    """Byte offsets of the header stamps in a CDR payload of type ``schema``."""
    if data[:2] != CDR_LE:
        raise ValueError(f"{schema}: encapsulation {data[:4].hex()} is not plain little-endian CDR")
    if schema in HEADER_FIRST:
        return [4]
    if schema != TF_MESSAGE:
        raise ValueError(f"{schema}: no rule for where its stamps are; add one to stamp_offsets")

    # tf2_msgs/TFMessage: uint32 n, then n x geometry_msgs/TransformStamped {Header {stamp, string
    # frame_id}, string child_frame_id, Transform (7 float64)}; CDR aligns each primitive to its
    # size, relative to the start of the body (after the 4-byte encapsulation header).
    def align(pos: int, n: int) -> int:
        return pos + (-(pos - 4) % n)

    (count,) = U32.unpack_from(data, 4)
    pos, out = 8, []
    for _ in range(count):
        pos = align(pos, 4)
        out.append(pos)
        pos += 8  # stamp
        for _string in range(2):  # frame_id, child_frame_id: uint32 length (with the NUL) + bytes
            pos = align(pos, 4)
            (n,) = U32.unpack_from(data, pos)
            pos += 4 + n
        pos = align(pos, 8) + 7 * 8  # translation xyz, rotation xyzw
    if pos > len(data):
        raise ValueError(f"{schema}: payload of {len(data)} bytes shorter than its {count} transforms")
    return out


def shifted(schema: str, data: bytes, shift_ns: int) -> bytes:
    """The payload with its header stamps moved by ``shift_ns`` (the rest byte for byte)."""
    if shift_ns == 0:
        return data
    buf = bytearray(data)
    for off in stamp_offsets(schema, data):
        _shift_stamp(buf, off, shift_ns)
    return bytes(buf)


def source_info(source: Path) -> dict:
    """Duration, the shift between copies, chunk size and the schemas of the source log."""
    from mcap.reader import make_reader

    with open(source, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise SystemExit(f"{source}: no summary section (not a finished MCAP file?)")
        st = summary.statistics
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        # one frame period: the median spacing of the busiest sensor topic (the depth images)
        sensor = [
            c.id
            for c in summary.channels.values()
            if schemas[c.topic] in HEADER_FIRST - {"nav_msgs/msg/Odometry"}
        ]
        busiest = max(
            sensor,
            key=lambda cid: (
                st.channel_message_counts.get(cid, 0),
                schemas[summary.channels[cid].topic] == "sensor_msgs/msg/Image",
            ),
        )
        times = [m.log_time for _s, _c, m in reader.iter_messages(topics=[summary.channels[busiest].topic])]
    gaps = sorted(b - a for a, b in zip(times, times[1:]))
    period = gaps[len(gaps) // 2] if gaps else NS // 30
    chunks = summary.chunk_indexes
    return {
        "start_ns": st.message_start_time,
        "end_ns": st.message_end_time,
        "duration_ns": st.message_end_time - st.message_start_time,
        "period_ns": period,
        "period_topic": summary.channels[busiest].topic,
        "shift_ns": st.message_end_time - st.message_start_time + period,
        "chunk_size": int(sum(c.uncompressed_size for c in chunks) / max(len(chunks), 1)),
        "schemas": schemas,
        "messages": st.message_count,
        "counts": {summary.channels[cid].topic: n for cid, n in st.channel_message_counts.items()},
    }


def write_long_log(source: Path, out: Path, repeats: int, info: dict) -> None:
    """``repeats`` copies of ``source`` back to back into ``out`` (zstd chunks)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    for topic, schema in info["schemas"].items():  # refuse a type without a rule before writing
        if topic not in STATIC_TOPICS and schema not in HEADER_FIRST and schema != TF_MESSAGE:
            raise SystemExit(f"{source}: topic {topic} of type {schema}: no rule for its stamps")
    t0 = time.perf_counter()
    with open(source, "rb") as fin, open(out, "wb") as fout:
        reader = make_reader(fin)
        summary = reader.get_summary()
        header = reader.get_header()
        writer = Writer(fout, chunk_size=info["chunk_size"], compression=CompressionType.ZSTD)
        writer.start(profile=header.profile, library=f"bench_long_log ({repeats} x {source.name})")
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata)
            for cid, c in summary.channels.items()
        }
        for k in range(repeats):
            shift = k * info["shift_ns"]
            for schema, channel, m in reader.iter_messages(log_time_order=True):
                if channel.topic in STATIC_TOPICS:
                    if k:
                        continue
                    data = m.data
                else:
                    data = shifted(schema.name, m.data, shift)
                writer.add_message(
                    channel_ids[channel.id], m.log_time + shift, data, m.publish_time + shift, m.sequence
                )
            print(f"  copy {k + 1}/{repeats} written ({time.perf_counter() - t0:.0f} s)", flush=True)
        writer.finish()


def check_long_log(source: Path, out: Path, repeats: int, info: dict) -> None:
    """The output's counts and time range, and the stamps of copies 1 and N-1 (decoded with
    mcap_ros2, independent of ``stamp_offsets``) against the source's plus the shift: each
    message's log_time and every header stamp in its first 0.5 s and last 0.5 s."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def stamps(msg) -> list[int]:
        hs = [t.header for t in msg.transforms] if hasattr(msg, "transforms") else [msg.header]
        return [h.stamp.sec * NS + h.stamp.nanosec for h in hs]

    def window(path: Path, t0: int, t1: int) -> list[tuple[str, int, int, list[int]]]:
        with open(path, "rb") as f:
            r = make_reader(f, decoder_factories=[DecoderFactory()])
            return [(c.topic, m.log_time, m.publish_time, stamps(d))
                    for _s, c, m, d in r.iter_decoded_messages(starting_at=t0, ending_before=t1)]  # fmt: skip

    with open(out, "rb") as f:
        st = make_reader(f).get_summary().statistics
    n_static = sum(n for t, n in info["counts"].items() if t in STATIC_TOPICS)
    want = repeats * (info["messages"] - n_static) + n_static
    end = info["start_ns"] + (repeats - 1) * info["shift_ns"] + info["duration_ns"]
    problems = []
    if st.message_count != want:
        problems.append(f"{st.message_count} messages, expected {want}")
    if (st.message_start_time, st.message_end_time) != (info["start_ns"], end):
        problems.append(
            f"time range {st.message_start_time}..{st.message_end_time}, expected {info['start_ns']}..{end}"
        )
    checked = 0
    half = NS // 2
    for k in copies_checked(repeats):
        shift = k * info["shift_ns"]
        for a, b in [
            (info["start_ns"], info["start_ns"] + half),
            (info["end_ns"] - half, info["end_ns"] + 1),
        ]:
            src = [x for x in window(source, a, b) if x[0] not in STATIC_TOPICS]
            got = window(out, a + shift, b + shift)
            got = [x for x in got if x[0] not in STATIC_TOPICS]
            exp = [(t, lt + shift, pt + shift, [s + shift for s in ss]) for t, lt, pt, ss in src]
            if sorted(got) != sorted(exp):
                problems.append(f"copy {k}, source window {(a - info['start_ns']) / NS:.1f} s: "
                                f"{len(got)} messages decoded, stamps differ from the source's + {shift / NS:.3f} s")  # fmt: skip
            checked += len(got)
    if problems:
        raise SystemExit(f"{out}: " + "; ".join(problems))
    print(
        f"  checked: {st.message_count} messages, {st.message_start_time / NS:.3f} .. {end / NS:.3f} s, "
        f"header stamps of {checked} decoded messages of copies {copies_checked(repeats)} = source + shift"
    )


def copies_checked(repeats: int) -> list[int]:
    return sorted({min(1, repeats - 1), repeats - 1})


def ensure_long_log(source: Path, repeats: int) -> tuple[Path, dict]:
    info = source_info(source)
    out = CACHE / f"long_log_{source.parent.name}_{repeats}x.mcap"
    print(
        f"source {source}: {info['duration_ns'] / NS:.3f} s, {info['messages']} messages, "
        f"{source.stat().st_size / 2**20:.0f} MB; copies shifted by {info['shift_ns'] / NS:.6f} s "
        f"(duration + one {info['period_topic']} period of {info['period_ns'] / 1e6:.3f} ms)",
        flush=True,
    )
    if out.is_file():
        print(f"long log: {out} (cached, {out.stat().st_size / 2**30:.2f} GB)")
        return out, info
    need = repeats * source.stat().st_size * 1.05
    free = shutil.disk_usage(CACHE).free
    if need > free:
        raise SystemExit(f"{out} would need about {need / 2**30:.1f} GB, {free / 2**30:.1f} GB free")
    CACHE.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(f"writing {out} ({repeats} copies) ...", flush=True)
    part = out.with_name(out.name + ".part")  # renamed into the cache once written and checked
    write_long_log(source, part, repeats, info)
    print(f"  {part.stat().st_size / 2**30:.2f} GB in {time.perf_counter() - t0:.0f} s", flush=True)
    check_long_log(source, part, repeats, info)
    os.replace(part, out)
    return out, info


# ---------------------------------------------------------------------------------------------
# The replay (child process)


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def sizes(run) -> dict:
    """What grows with the log, read from the running replay (plain reads of counters and list
    lengths: safe from another thread)."""
    out: dict = {}
    lmap = getattr(run, "lmap", None)
    if lmap is not None:
        ev = lmap.events
        out["hist_rows"] = int(ev.hist_meta[0])
        out["hist_alloc"] = len(ev.hist_i)
        out["thinned"] = getattr(ev, "thinned", None)
        out["transitions"] = int(ev.tr_meta[0])
        out["O_blocks"] = lmap.O.n_blocks
        out["D_blocks"] = lmap.D.n_blocks
    state = getattr(run, "state", None)
    if state is not None:
        out["trajectory"] = len(state.trajectory)
    out["stage_s"] = dict(run.timer.seconds)
    sched = getattr(run, "scheduler", None)
    if sched is not None:
        out["tf_samples"] = sum(len(e.times) for e in list(sched.tf.edges.values()))
    return out


def child(log: Path, out: Path, segment_s: float) -> None:
    """The replay of ``log`` in this process, sampled; prints the segment table as it goes and
    writes the rest to ``out``/bench_samples.json."""
    import resource
    import warnings

    from ltmap_cli.config import Config
    from ltmap_cli.pipeline import sinks as sinks_mod
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest
    from ltmap_cli.pipeline.sinks import McapSink, MetricsSink, Sink

    cfg = Config()
    cfg.replay.plots = False
    progress: list[tuple[float, float, str | None]] = []  # (log_done_s, wall_s, phase) per callback

    def on_progress(p) -> None:
        progress.append((p.log_done_s, p.wall_s, p.phase))

    finish_s: dict[str, float] = {}  # the end phase: wall of Replay._finish and of each sink's finish
    for cls in [Replay, *Sink.__subclasses__()]:
        name = "_finish" if cls is Replay else "finish"
        setattr(cls, name, _timed(getattr(cls, name), f"{cls.__name__}.{name}", finish_s))
    for name in ("find_events", "event_histories", "event_history"):  # EventsSink.finish's parts (module globals)
        if hasattr(sinks_mod, name):  # (event_history in the code before 5d48ccd)
            setattr(sinks_mod, name, _timed(getattr(sinks_mod, name), name, finish_s))
    run = Replay(cfg, ReplayRequest([log], out / "replay"), progress=on_progress)
    samples: list[dict] = []
    stop = threading.Event()
    cols = ["log min", "wall s", "RSS MB", "peak in seg MB", "x real (seg)", *(f"{k} s" for k in SEG_STAGES),
            "hist rows", "hist alloc", "thinned", "transitions", "O blocks", "D blocks", "trajectory", "tf samples"]  # fmt: skip
    print("| " + " | ".join(cols) + " |\n" + "|---" * len(cols) + "|", flush=True)
    last_row = {"log": 0.0, "wall": 0.0, "stage_s": {}}

    def row(boundary: float, s: dict, seg_peak: float) -> None:
        wall = wall_at(progress, boundary)
        dt = wall - last_row["wall"]
        speed = (boundary - last_row["log"]) / dt if dt > 0 else float("nan")
        z = s.get("sizes", {})
        st, st0 = z.get("stage_s", {}), last_row["stage_s"]
        last_row.update(log=boundary, wall=wall, stage_s=st)
        vals = [f"{boundary / 60:.1f}", f"{wall:.1f}", f"{s['rss_mb']:.0f}", f"{seg_peak:.0f}", f"{speed:.2f}",
                *(f"{st.get(k, 0.0) - st0.get(k, 0.0):.1f}" for k in SEG_STAGES),
                *(str(z.get(k, "")) for k in ("hist_rows", "hist_alloc", "thinned", "transitions", "O_blocks",
                                              "D_blocks", "trajectory", "tf_samples"))]  # fmt: skip
        print("| " + " | ".join(vals) + " |", flush=True)

    def sampler() -> None:
        t0 = time.perf_counter()
        nxt, seg_peak = segment_s, 0.0
        while True:
            done = progress[-1][0] if progress else 0.0
            s = {"t": time.perf_counter() - t0, "rss_mb": rss_mb(), "log_s": done, "sizes": {}}
            try:
                s["sizes"] = sizes(run)
            except Exception as e:  # a structure replaced between two reads: try again next time
                s["sizes"] = {"error": repr(e)}
            samples.append(s)
            seg_peak = max(seg_peak, s["rss_mb"])
            while done >= nxt:
                row(nxt, s, seg_peak)
                nxt, seg_peak = nxt + segment_s, s["rss_mb"]
            if stop.wait(SAMPLE_S):
                return

    th = threading.Thread(target=sampler, daemon=True)
    rss0 = rss_mb()
    t0 = time.perf_counter()
    th.start()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rep = run.run()
    wall = time.perf_counter() - t0
    stop.set()
    th.join()
    total = rep["log_duration_s"]
    log_end = [w for d, w, ph in progress if ph is None and d >= total - 1e-6]
    end_wall = (log_end[0] if log_end else progress[-1][1]) if progress else 0.0
    metrics = next(s for s in run.sinks if isinstance(s, MetricsSink))
    mcap_sink = next((s for s in run.sinks if isinstance(s, McapSink)), None)
    ev = run.lmap.events
    lists = {
        "trajectory": len(run.state.trajectory),
        **{f"frame_ms[{t}]": len(v) for t, v in metrics.frame_ms.items()},
        **{f"stamps[{t}]": len(v) for t, v in metrics.stamps.items()},
        "tick_ms": len(metrics.tick_ms),
    }
    if mcap_sink is not None:
        lists["McapSink.frame_log"] = len(mcap_sink.frame_log)
    # their bytes: 8 a value (array.array; the trajectory 3 values a point), or, in lists (the code
    # before: a pointer plus a float, 24 B, or an int, 32 B; a trajectory point a 3-tuple, 64 B)
    def nbytes(v, per_item_list: int) -> int:
        return v.buffer_info()[1] * v.itemsize if hasattr(v, "buffer_info") else len(v) * per_item_list

    traj = run.state.trajectory
    traj_bytes = nbytes(traj._a, 0) if hasattr(traj, "_a") else len(traj) * (8 + 64 + 3 * 24)
    list_mb = (traj_bytes + sum(nbytes(v, 8 + 24) for v in metrics.frame_ms.values())
                + sum(nbytes(v, 8 + 32) for v in metrics.stamps.values()) + nbytes(metrics.tick_ms, 8 + 24)) / 2**20
    events_csv = run.req.out_dir / "events.csv"
    csv_rows = max(len(events_csv.read_text().splitlines()) - 1, 0) if events_csv.is_file() else None
    (out / "bench_samples.json").write_text(
        json.dumps(
            {
                "log_s": total,
                "wall_s": wall,
                "report_wall_s": rep["wall_time_s"],
                "rss_start_mb": rss0,
                "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                "rss_end_mb": rss_mb(),
                "end_phase_s": wall - end_wall,
                "finish_s": finish_s,
                "mapping_wall_s": rep.get("mapping_wall_time_s"),
                "phases": [(ph, w) for _d, w, ph in progress if ph is not None],
                "stage_s": rep.get("stage_s", {}),
                "hist_rows": len(ev.history[0]),
                "hist_alloc": len(ev.hist_i),
                "thinned": getattr(ev, "thinned", None),
                "hist_mb": (ev.hist_i.nbytes + ev.hist_v.nbytes + ev.hist_p.nbytes) / 2**20,
                "transitions": len(ev.transitions),
                "tr_alloc": len(ev.tr),
                "O_blocks": run.lmap.O.n_blocks,
                "D_blocks": run.lmap.D.n_blocks,
                "map_mb": run.lmap.nbytes() / 2**20,
                "lists": lists,
                "lists_mb": list_mb,
                "ticks": rep.get("ticks"),
                "frames_used": rep.get("frames_used"),
                "frames_skipped": rep.get("frames_skipped"),
                "events": {k: v for k, v in (rep.get("events") or {}).items() if k != "list"},
                "events_list": (rep.get("events") or {}).get("list", []),
                "events_csv_rows": csv_rows,
                "snapshots": len(rep.get("snapshots") or []),
                "report_warnings": find_warnings(rep),
                "warnings": sorted({str(w.message) for w in caught}),
                "speed": rep.get("speed_vs_real_time"),
                "samples": samples,
                "progress": progress,
            },
            default=str,
        )
        + "\n"
    )


def _timed(fn, name: str, into: dict):
    """``fn`` recording its wall seconds in ``into[name]`` (the child's end-phase breakdown)."""

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            into[name] = into.get(name, 0.0) + time.perf_counter() - t0

    return timed


def wall_at(progress: list, log_s: float) -> float:
    """Wall seconds when the replay reached ``log_s`` (interpolated between progress callbacks)."""
    prev = (0.0, 0.0)
    for d, w, ph in progress:
        if ph is None and d >= log_s:
            if d == prev[0]:
                return w
            return prev[1] + (w - prev[1]) * (log_s - prev[0]) / (d - prev[0])
        if ph is None:
            prev = (d, w)
    return progress[-1][1] if progress else 0.0


def find_warnings(obj, path: str = "") -> dict:
    """Every entry of the report whose key names warnings (none today unless a sink adds one)."""
    found = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            p = f"{path}.{k}" if path else str(k)
            if "warn" in str(k).lower() and v:
                found[p] = v
            elif isinstance(v, (dict, list)):
                found.update(find_warnings(v, p))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:50]):
            found.update(find_warnings(v, f"{path}[{i}]"))
    return found


# ---------------------------------------------------------------------------------------------


def warm_child(out: Path) -> None:
    """Compile or load every kernel (a replay of the house sample), in its own process."""
    from ltmap_cli.config import Config
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    bench_replay.warm_kernels(Replay, ReplayRequest, Config, out, True, True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--repeats", type=int, default=20, help="copies of the source log (20: 10 min of the default)"
    )
    ap.add_argument(
        "--source", type=Path, default=DEFAULT_SOURCE, help="the log repeated (an MCAP file, ROS 2 CDR)"
    )
    ap.add_argument("--segment", type=float, default=60.0, help="log seconds per row of the table")
    ap.add_argument("--keep", action="store_true", help="keep the replay's output folder")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")
    if not args.source.is_file():
        ap.error(f"{args.source} not found (bench/bench_long_rays.py --generate-only room makes the default)")
    print(f"bench_long_log: {datetime.date.today()}, {bench_replay.machine()}")
    log, info = ensure_long_log(args.source.resolve(), args.repeats)
    work = Path(tempfile.mkdtemp(prefix="bench_long_log_"))
    subprocess.run([sys.executable, __file__, "--warm", str(work)], check=True, stdout=subprocess.DEVNULL)
    shutil.rmtree(work / "warmup", ignore_errors=True)
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print(
        f"replay of {log.name} ({args.repeats * info['shift_ns'] / NS / 60:.1f} min of log), sampled every "
        f"{SAMPLE_S:g} s; rows every {args.segment:g} s of log:",
        flush=True,
    )
    subprocess.run([sys.executable, __file__, "--child", str(log), str(work), str(args.segment)], check=True)
    r = json.loads((work / "bench_samples.json").read_text())
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    report(r, args.segment)
    if args.keep:
        print(f"outputs kept in {work} (replay/, bench_samples.json)")
    else:
        shutil.rmtree(work, ignore_errors=True)


def report(r: dict, segment_s: float) -> None:
    """The end summary and the growth rates, from the child's JSON."""
    log_min = r["log_s"] / 60
    print()
    print(
        f"log {r['log_s']:.1f} s, wall {r['wall_s']:.1f} s ({r['log_s'] / r['wall_s']:.2f}x real time), "
        f"mapping wall {r['mapping_wall_s']} s; peak RSS (ru_maxrss) {r['peak_mb']:.0f} MB, RSS at start "
        f"{r['rss_start_mb']:.0f} MB, at end {r['rss_end_mb']:.0f} MB"
    )
    print(
        f"end phase (from the progress at the log's end to the end of run()): {r['end_phase_s']:.2f} s; "
        f"phases named: {r['phases'] or 'none'}"
    )
    fin = r["finish_s"]
    print(
        "  of which: "
        + ", ".join(f"{k} {v:.2f} s" for k, v in sorted(fin.items(), key=lambda kv: -kv[1]) if v >= 0.005)
    )
    print("stage_s: " + ", ".join(f"{k} {v}" for k, v in r["stage_s"].items()))
    print(
        f"event history: {r['hist_rows']} rows used of {r['hist_alloc']} allocated ({r['hist_mb']:.0f} MB), "
        f"thinned {r['thinned']} x; transitions {r['transitions']} (of {r['tr_alloc']} allocated); "
        f"O blocks {r['O_blocks']}, D blocks {r['D_blocks']} (map {r['map_mb']:.0f} MB); ticks {r['ticks']}"
    )
    print(
        "lists grown per frame / tick: "
        + ", ".join(f"{k} {v}" for k, v in r["lists"].items())
        + f" (about {r['lists_mb']:.1f} MB)"
    )
    print(f"frames used {r['frames_used']}, skipped {r['frames_skipped']}; snapshots {r['snapshots']}")
    ev = r["events"]
    print(
        f"events: {ev.get('count')} ({ev.get('appear')} appear, {ev.get('disappear')} disappear), "
        f"events.csv rows {r['events_csv_rows']}; filtered {ev.get('filtered')}"
    )
    kinds: dict = {}
    for e in r["events_list"]:
        t = e.get("t_lt_s") if e.get("t_lt_s") is not None else e.get("t_start_s")
        kinds.setdefault(e.get("kind"), []).append(t)
    for k, ts in kinds.items():
        ts = sorted(x for x in ts if x is not None)
        print(f"  {k}: times (s) {', '.join(f'{x:.0f}' for x in ts[:40])}{' ...' if len(ts) > 40 else ''}")
    print(f"warnings raised: {r['warnings'] or 'none'}; report warnings: {r['report_warnings'] or 'none'}")
    # growth after the first two segments (the map, the buffers and the tf window filling up):
    # RSS as a least-squares slope over every sample (it swings by ~100 MB with the reader's
    # chunks and the history's buffers), the structures from the first to the last sample
    s = [x for x in r["samples"] if 2 * segment_s <= x["log_s"] < r["log_s"]]
    if len(s) >= 2 and s[-1]["log_s"] > s[0]["log_s"]:
        a, b = s[0], s[-1]
        dm = (b["log_s"] - a["log_s"]) / 60
        t = [x["log_s"] / 60 for x in s]
        m = [x["rss_mb"] for x in s]
        tm, mm = sum(t) / len(t), sum(m) / len(m)
        slope = sum((x - tm) * (y - mm) for x, y in zip(t, m)) / sum((x - tm) ** 2 for x in t)
        parts = [f"RSS {slope:+.1f} MB (fit over {len(s)} samples)"]
        for k in ("hist_rows", "transitions", "O_blocks", "D_blocks", "trajectory", "tf_samples"):
            if isinstance(a["sizes"].get(k), int) and isinstance(b["sizes"].get(k), int):
                parts.append(f"{k} {(b['sizes'][k] - a['sizes'][k]) / dm:+.0f}")
        print(
            f"growth per minute of log, {a['log_s'] / 60:.1f} to {b['log_s'] / 60:.1f} min: "
            + ", ".join(parts)
        )
    print(f"(log {log_min:.1f} min)")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(Path(sys.argv[2]), Path(sys.argv[3]), float(sys.argv[4]))
    elif len(sys.argv) > 1 and sys.argv[1] == "--warm":
        warm_child(Path(sys.argv[2]))
    else:
        main()
