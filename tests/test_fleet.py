"""`ltmap batch` (SPEC 5, issue 19): the manifest's checks, the sweep points, the fingerprints that
say a day is up to date, and batches on a local Dask cluster compared file for file with the same
chains replayed by hand with `ltmap replay --resume`; a failing log retried once and reported
while the other site completes; a worker killed in the middle of a batch."""

from __future__ import annotations

import csv
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("distributed", reason="ltmap batch needs the fleet extra: pip install 'ltmap[fleet]'")

from mapfactory import write_trinary  # noqa: E402

from ltmap_cli.cli import cli  # noqa: E402
from ltmap_cli.fleet.graph import build_plan, sweep_points  # noqa: E402
from ltmap_cli.fleet.manifest import load_manifest  # noqa: E402
from ltmap_cli.fleet.runner import DONE, Engine, execute  # noqa: E402
from ltmap_cli.fleet.tasks import TASK_FILE  # noqa: E402
from ltmap_cli.io.state import read_state  # noqa: E402
from ltmap_cli.outputs.folder import ASIDE, STAGING

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "sample_logs" / "scenarios"
LOG1 = SCEN / "01_static_object" / "log.mcap"  # 30 s, laser only: the quick ones
LOG4 = SCEN / "04_door" / "log.mcap"
LOG5 = SCEN / "05_person" / "log.mcap"
PLAN = ROOT / "sample_logs" / "plans" / "house.svg"
SAME_FILES = (
    "map.pgm",
    "long_term.pgm",
    "events.csv",
    "snapshots/long_term_final.ot",
    "snapshots/long_term_final.ply",
)


def ltmap(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def write_manifest(path: Path, sites: dict, extra: str = "") -> Path:
    lines = [extra] if extra else []
    lines.append("sites:")
    for name, site in sites.items():
        lines.append(f"  {name}:")
        if "static" in site:
            lines.append(f"    static: {site['static']}")
        lines.append("    days:")
        for day in site["days"]:
            lines.append(f"      - [{', '.join(str(p) for p in day)}]")
    path.write_text("\n".join(lines) + "\n")
    return path


def hand_chain(folder: Path, days: list[list[Path]], *extra) -> list[Path]:
    """The chain as a person runs it: `ltmap replay` day after day, each --resume the one before."""
    outs = []
    for i, logs in enumerate(days, start=1):
        out = folder / f"day{i}"
        resume = ["--resume", outs[-1]] if outs else []
        r = ltmap("replay", *logs, "-o", out, "--no-plots", "-q", *resume, *extra)
        assert r.exit_code == 0, r.output
        outs.append(out)
    return outs


def assert_same_maps(a: Path, b: Path, static: bool = False) -> None:
    for name in SAME_FILES + (("static.pgm",) if static else ()):
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{a / name} differs from {b / name}"
    sa, ma = read_state(a / "snapshots" / "state_final.npz")
    sb, mb = read_state(b / "snapshots" / "state_final.npz")
    assert sorted(sa) == sorted(sb) and ma == mb
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)


def summary(out: Path) -> list[dict]:
    with open(out / "summary.csv", newline="") as f:
        return list(csv.DictReader(f))


def one_error_line(result) -> str:
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("ltmap: error: "), result.output
    assert "Traceback" not in result.output
    return lines[0]


# ------------------------------------------------------------------------------------ manifest
@pytest.fixture
def logs(tmp_path):
    (tmp_path / "logs").mkdir()
    for n in ("mon.mcap", "tue.mcap"):
        (tmp_path / "logs" / n).write_bytes(b"\0")  # the checks look at paths only
    (tmp_path / "plan.txt").write_text("x")
    return tmp_path


BAD_MANIFESTS = [
    ("- a\n- b\n", ["top level: expected a mapping with 'sites:', got a list"]),
    (
        "sites:\n  lab:\n    days: [[logs/mon.mcap]]\nsite: {}\n",
        ["top level: unknown key 'site'", "known keys"],
    ),
    ("config: {}\n", ["top level: no 'sites:' mapping"]),
    ("sites: {}\n", ["sites: expected a mapping of site names"]),
    ("sites:\n  lab: [logs/mon.mcap]\n", ["sites.lab: expected a mapping with 'days:'"]),
    ("sites:\n  lab:\n    day: [[logs/mon.mcap]]\n", ["sites.lab: unknown key 'day'"]),
    ("sites:\n  lab:\n    static: plan.svg\n", ["sites.lab.static: plan.svg: no such file"]),
    ("sites:\n  lab:\n    days: []\n", ["sites.lab.days: expected a non-empty list"]),
    (
        "sites:\n  lab:\n    days: logs/mon.mcap\n",
        ["sites.lab.days: expected a non-empty list", "'logs/mon.mcap'"],
    ),
    (
        "sites:\n  lab:\n    days:\n      - [logs/mon.mcap]\n      - logs/tue.mcap\n",
        ["sites.lab.days: day 2: expected a list of logs, got 'logs/tue.mcap'", "- [logs/tue.mcap]"],
    ),
    ("sites:\n  lab:\n    days: [[logs/mon.mcap], []]\n", ["sites.lab.days: day 2: is an empty list"]),
    (
        "sites:\n  lab:\n    days:\n      - [logs/mon.mcap]\n      -\n",
        ["sites.lab.days: day 2: expected a list of logs, got nothing"],
    ),
    (
        "sites:\n  lab:\n    days: [[logs/mon.mcap], [logs/tue.mcap, logs/wed.mcap]]\n",
        ["sites.lab.days: day 2, log logs/wed.mcap: no such file or folder", "relative to the manifest"],
    ),
    (
        "sites:\n  lab:\n    days: [[logs/mon.mcap, 3]]\n",
        ["sites.lab.days: day 1: a log must be a path, got int"],
    ),
    (
        "sites:\n  lab:\n    days: [[logs/mon.mcap, logs/mon.mcap]]\n",
        ["day 1, log logs/mon.mcap: is listed twice"],
    ),
    (
        "sites:\n  lab:\n    static: plan.txt\n    days: [[logs/mon.mcap]]\n",
        ["sites.lab.static: plan.txt: expected an SVG plan (.svg)"],
    ),
    (
        "sites:\n  lab:\n    static_options: {scale: 0.01}\n    days: [[logs/mon.mcap]]\n",
        ["sites.lab.static_options: build-static options apply to an SVG plan only"],
    ),
    (
        "sites:\n  lab:\n    config: {map: {nope: 1}}\n    days: [[logs/mon.mcap]]\n",
        ["sites.lab.config: unknown config key map.nope"],
    ),
    (
        "sites:\n  lab:\n    config: {map: {layers: {st_rise_s: fast}}}\n    days: [[logs/mon.mcap]]\n",
        ["sites.lab.config: config key map.layers.st_rise_s must be a number, got 'fast'"],
    ),
    (
        "config: missing.yaml\nsites:\n  lab:\n    days: [[logs/mon.mcap]]\n",
        ["config: missing.yaml: no such file"],
    ),
    ("sites:\n  a/b:\n    days: [[logs/mon.mcap]]\n", ["site 'a/b': a site name must be letters"]),
    ("sites:\n  lab:\n    days: [[logs/mon.mcap]\n", ["not valid YAML at line"]),
    ("", ["is empty; it needs a 'sites:' mapping"]),
]


@pytest.mark.parametrize("text, needles", BAD_MANIFESTS)
def test_a_bad_manifest_is_one_line_naming_the_entry_exit_2_before_any_work(logs, text, needles):
    manifest = logs / "fleet.yaml"
    manifest.write_text(text)
    line = one_error_line(ltmap("batch", manifest, "-o", logs / "out"))
    assert f"manifest {manifest}" in line
    for n in needles:
        assert n in line, line
    assert not (logs / "out").exists()  # checked before the engine starts or anything is written


def test_a_missing_manifest_and_bad_sweeps_are_one_line_errors(logs):
    manifest = write_manifest(logs / "fleet.yaml", {"lab": {"days": [["logs/mon.mcap"]]}})
    line = one_error_line(ltmap("batch", logs / "nope.yaml", "-o", logs / "out"))
    assert "manifest" in line and "nope.yaml does not exist" in line
    for sweep, needle in [
        ("map.layers.nope=1,2", "--sweep map.layers.nope=1,2: unknown config key map.layers.nope"),
        ("map.layers.st_rise_s", "expected KEY=V1,V2"),
        ("map.layers.st_rise_s=5,,10", "non-empty values"),
        ("map.layers.st_rise_s=5,fast", "must be a number, got 'fast'"),
        ("map.resolution=-1,0.1", "resolution"),
    ]:
        line = one_error_line(ltmap("batch", manifest, "-o", logs / "out", "--sweep", sweep))
        assert needle in line, line
    line = one_error_line(
        ltmap(
            "batch",
            manifest,
            "-o",
            logs / "out",
            "--sweep",
            "map.layers.tick=0.1,0.2",
            "--sweep",
            "map.layers.tick=0.3",
        )
    )
    assert "--sweep map.layers.tick is given twice" in line
    assert not (logs / "out").exists()


def test_sweep_points_are_the_cartesian_product_named_by_key_and_value():
    pts = sweep_points(["map.layers.st_rise_s=5,10", "map.resolution=0.05,0.1"])
    assert [p.name for p in pts] == [
        "st_rise_s=5+resolution=0.05",
        "st_rise_s=5+resolution=0.1",
        "st_rise_s=10+resolution=0.05",
        "st_rise_s=10+resolution=0.1",
    ]
    assert pts[3].values == (("map.layers.st_rise_s", 10), ("map.resolution", 0.1))
    assert [p.name for p in sweep_points([])] == [""]
    pts = sweep_points(["replay.plan_goal=[1, 2],[3.5, -1]"])  # commas inside brackets do not split
    assert [p.name for p in pts] == ["plan_goal=[1,_2]", "plan_goal=[3.5,_-1]"]
    assert pts[1].values == (("replay.plan_goal", [3.5, -1]),)


def test_fingerprints_change_with_the_config_and_from_a_changed_log_on(tmp_path):
    (tmp_path / "logs").mkdir()
    for n in ("a1", "a2", "a3", "b1"):
        (tmp_path / "logs" / f"{n}.mcap").write_bytes(n.encode())
    manifest = write_manifest(
        tmp_path / "fleet.yaml",
        {
            "a": {"days": [["logs/a1.mcap"], ["logs/a2.mcap"], ["logs/a3.mcap"]]},
            "b": {"days": [["logs/b1.mcap"]]},
        },
    )

    def keys(**kw):
        plan = build_plan(load_manifest(manifest), tmp_path / "out", **kw)
        return {(c.site, d.day): d.key for c in plan.chains for d in c.days}

    k0 = keys()
    assert keys() == k0 and len(set(k0.values())) == 4
    st = (tmp_path / "logs" / "a2.mcap").stat()
    os.utime(tmp_path / "logs" / "a2.mcap", ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    k1 = keys()
    # day 2 changed; day 3 builds on it; day 1 and the other site did not
    assert [k1[s] == k0[s] for s in (("a", 1), ("a", 2), ("a", 3), ("b", 1))] == [True, False, False, True]
    # tomorrow's log added to the manifest: the days before keep their fingerprints
    (tmp_path / "logs" / "a4.mcap").write_bytes(b"a4")
    write_manifest(
        manifest,
        {
            "a": {"days": [["logs/a1.mcap"], ["logs/a2.mcap"], ["logs/a3.mcap"], ["logs/a4.mcap"]]},
            "b": {"days": [["logs/b1.mcap"]]},
        },
    )
    k_added = keys()
    assert {s: k for s, k in k_added.items() if s != ("a", 4)} == k1 and k_added[("a", 4)] not in k1.values()
    # a site's static map: its image is an input too
    room_map(tmp_path / "maps" / "room.yaml")
    write_manifest(
        manifest,
        {
            "a": {"days": [["logs/a1.mcap"], ["logs/a2.mcap"], ["logs/a3.mcap"], ["logs/a4.mcap"]]},
            "b": {"static": "maps/room.yaml", "days": [["logs/b1.mcap"]]},
        },
    )
    k_static = keys()
    assert k_static[("b", 1)] != k_added[("b", 1)]
    (tmp_path / "maps" / "room.pgm").write_bytes((tmp_path / "maps" / "room.pgm").read_bytes() + b"\0")
    assert keys()[("b", 1)] != k_static[("b", 1)] and keys()[("a", 1)] == k_static[("a", 1)]
    write_manifest(
        manifest,
        {
            "a": {"days": [["logs/a1.mcap"], ["logs/a2.mcap"], ["logs/a3.mcap"], ["logs/a4.mcap"]]},
            "b": {"days": [["logs/b1.mcap"]]},
        },
    )
    k2 = keys(sets=[("map.layers.lt_fall_s", 4.0)])
    assert not set(k2.values()) & set(k1.values())
    plan = build_plan(load_manifest(manifest), tmp_path / "out", sweeps=["map.layers.lt_fall_s=3,4"])
    assert [str(d.out_dir.relative_to(tmp_path / "out")) for d in plan.chains[0].days][:2] == [
        "a/lt_fall_s=3/day1",
        "a/lt_fall_s=3/day2",
    ]
    # lt_fall_s=3 is the default: the same parameters as no sweep, so the same fingerprints
    assert [d.key for d in plan.chains[0].days] == [k_added[("a", i)] for i in (1, 2, 3, 4)]
    assert [d.key for d in plan.chains[1].days] == [k2[("a", i)] for i in (1, 2, 3, 4)]


# ------------------------------------------------------------------------------------ batches
def room_map(path: Path) -> Path:
    """The samples' 8 x 5 m room as a map_server map (walls 0.1 m), for --static."""
    occ = np.zeros((100, 160), dtype=np.int8)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = 100
    return write_trinary(path, occ)


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_a_small_batch_equals_the_hand_replays_and_a_rerun_skips_complete_days(tmp_path):
    static = room_map(tmp_path / "maps" / "room.yaml")
    manifest = write_manifest(
        tmp_path / "fleet.yaml",
        {"a": {"days": [[LOG1], [LOG4]]}, "b": {"static": "maps/room.yaml", "days": [[LOG5]]}},
    )
    out = tmp_path / "out"
    r = ltmap("batch", manifest, "-o", out, "--workers", "2", "--no-plots")
    assert r.exit_code == 0, r.output
    assert "3 of 3 days done (0 up to date, 3 replayed)" in r.output
    ha = hand_chain(tmp_path / "hand_a", [[LOG1], [LOG4]])
    hb = hand_chain(
        tmp_path / "hand_b", [[LOG5]], "--static", static
    )  # a map YAML goes to the replay as it is
    for got, want in zip([out / "a" / "day1", out / "a" / "day2"], ha):
        assert_same_maps(got, want)
    assert_same_maps(out / "b" / "day1", hb[0], static=True)
    assert not (out / "b" / "static").exists()
    rows = summary(out)
    assert [(r["site"], r["day"], r["status"]) for r in rows] == [
        ("a", "1", "done"),
        ("a", "2", "done"),
        ("a", "all", "done"),
        ("b", "1", "done"),
        ("b", "all", "done"),
        ("all", "all", "done"),
    ]
    import json

    rep = json.loads((out / "a" / "day2" / "report.json").read_text())
    assert rep["resume"]["path"] == str(out / "a" / "day1" / "snapshots" / "state_final.npz")
    a2 = rows[1]
    assert int(a2["frames_used"]) == sum(rep["frames_used"].values())
    assert int(a2["events_appeared"]) == rep["events"]["appear"]
    assert int(a2["long_term_voxels"]) == rep["voxels"]["long_term_occupied"]
    assert float(a2["add_latency_median_s"]) == pytest.approx(rep["events"]["add_latency_s"]["p50"])
    assert int(rows[2]["long_term_voxels"]) == int(a2["long_term_voxels"])  # a site's total: its last day
    assert int(rows[2]["frames_used"]) == int(rows[0]["frames_used"]) + int(a2["frames_used"])
    assert (out / "summary.png").stat().st_size > 10_000
    assert not [p for p in out.rglob("*") if STAGING in p.name or ASIDE in p.name]

    stamps = {p: p.stat().st_mtime_ns for p in out.rglob(TASK_FILE)}
    (out / "a" / f".day2.{STAGING}0123456789ab").mkdir()  # left by a batch killed in the middle
    r = ltmap("batch", manifest, "-o", out, "--workers", "2", "--no-plots")
    assert r.exit_code == 0, r.output
    assert "3 of 3 days done (3 up to date, 0 replayed)" in r.output
    assert {p: p.stat().st_mtime_ns for p in out.rglob(TASK_FILE)} == stamps  # nothing replayed again
    assert not (out / "a" / f".day2.{STAGING}0123456789ab").exists()
    assert [x["status"] for x in summary(out)][:2] == ["up to date", "up to date"]

    # another parameter: every day is to run again (the slow test below runs them)
    r = ltmap("batch", manifest, "-o", out, "--no-plots", "--set", "map.layers.lt_fall_s=4", "--dry-run")
    assert r.exit_code == 0 and r.output.count("to run") == 3 and "up to date" not in r.output, r.output
    r = ltmap("batch", manifest, "-o", out, "--no-plots", "--dry-run")
    assert r.exit_code == 0 and r.output.count("up to date") == 3, r.output


def _trim_threshold():
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_the_local_engine_leaves_malloc_trimming_as_the_environment_has_it():
    # Dask sets MALLOC_TRIM_THRESHOLD_=65536 in its workers for its memory limit, which the local
    # engine does not use; with it a replay faults its arrays' pages in again and again
    # (Dask's nanny also writes it into the driver's own environment before it spawns a worker)
    mine = _trim_threshold()
    with Engine(workers=1) as engine:
        assert set(engine.client.run(_trim_threshold).values()) == {mine}
    assert _trim_threshold() == mine


def test_the_local_engine_starts_without_a_warning_when_port_8787_is_taken():
    import socket
    import warnings

    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", 8787))  # Dask's dashboard port: another batch, a notebook's cluster
            s.listen()
        except OSError:
            pass  # taken already: the same case
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with Engine(workers=1):
                pass
    assert not [w for w in caught if "already in use" in str(w.message)]


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_a_failing_log_is_retried_once_then_reported_and_the_other_sites_complete(tmp_path):
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"not a log" * 100)
    plan = tmp_path / "broken.svg"
    plan.write_text(
        "<svg xmlns='http://www.w3.org/2000/svg'><line x1='0' y1='0' x2='1' y2='1'/></svg>"
    )  # no scale
    manifest = write_manifest(
        tmp_path / "fleet.yaml",
        {
            "bad": {"days": [[LOG1], [bad], [LOG4]]},
            "good": {"days": [[LOG1, LOG1.with_suffix(".bag")]]},
            "noplan": {"static": plan, "days": [[LOG1], [LOG4]]},
        },
    )
    out = tmp_path / "out"
    r = ltmap("batch", manifest, "-o", out, "--workers", "2", "--no-plots")
    assert r.exit_code == 1, r.output
    lines = r.output.splitlines()
    assert sum("bad day 2 failed" in ln and "retrying once" in ln for ln in lines) == 1, r.output
    failed = [ln for ln in lines if ln.startswith("ltmap: failed: ")]
    assert (
        len(failed) == 2 and "bad day 2" in failed[1] and str(bad) in failed[1] and "2 attempts" in failed[1]
    )
    # the plan fails in build-static's own words (no scale), and the site's days cannot run
    assert "noplan static plan" in failed[0] and "2 attempts" in failed[0] and "scale" in failed[0]
    assert [ln for ln in lines if ln.startswith("ltmap: not run: ")] == [
        "ltmap: not run: bad day 3: day 2 failed",
        "ltmap: not run: noplan day 1: the static plan of noplan failed",
        "ltmap: not run: noplan day 2: the static plan of noplan failed",
    ]
    assert "Traceback" not in r.output
    # a replay's warning comes from its worker to the user's terminal, naming the day
    warned = [ln for ln in lines if ln.startswith("ltmap: warning: good day 1: ")]
    assert len(warned) == 1 and "given twice" in warned[0], r.output
    assert (out / "good" / "day1" / TASK_FILE).is_file() and (out / "bad" / "day1" / TASK_FILE).is_file()
    assert not (out / "bad" / "day2").exists() and not (out / "bad" / "day3").exists()
    rows = {(x["site"], x["day"]): x for x in summary(out)}
    assert rows[("bad", "2")]["status"] == "failed" and rows[("bad", "2")]["error"]
    assert rows[("bad", "3")]["status"] == "not run" and rows[("bad", "3")]["error"] == "day 2 failed"
    assert rows[("good", "1")]["status"] == "done" and rows[("bad", "1")]["status"] == "done"
    assert rows[("bad", "all")]["status"] == "2 of 3 not done"
    assert rows[("noplan", "1")]["status"] == "not run" and "scale" in rows[("noplan", "1")]["error"]
    assert not (out / "noplan").exists() or not list((out / "noplan").iterdir())


def test_a_folder_ltmap_did_not_write_is_not_replaced(tmp_path):
    manifest = write_manifest(tmp_path / "fleet.yaml", {"a": {"days": [[LOG1]]}})
    mine = tmp_path / "out" / "a" / "day1"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("mine")
    r = ltmap("batch", manifest, "-o", tmp_path / "out", "--workers", "1", "-q")
    assert r.exit_code == 1, r.output
    assert "was not written by ltmap batch; move it away" in r.output
    assert (mine / "notes.txt").read_text() == "mine" and sorted(p.name for p in mine.iterdir()) == [
        "notes.txt"
    ]


@pytest.mark.slow
def test_a_plan_and_a_sweep_equal_the_hand_replays_with_build_static_and_set(tmp_path):
    manifest = write_manifest(tmp_path / "fleet.yaml", {"house": {"static": PLAN, "days": [[LOG1], [LOG5]]}})
    out = tmp_path / "out"
    r = ltmap(
        "batch", manifest, "-o", out, "--workers", "2", "--no-plots", "--sweep", "map.layers.st_rise_s=5,15"
    )
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (out / "house").iterdir()) == ["st_rise_s=15", "st_rise_s=5", "static"]
    static = tmp_path / "hand_static"
    assert ltmap("build-static", PLAN, "-o", static).exit_code == 0
    for f in ("static.pgm", "static.yaml", "static_layer.npz"):
        assert (out / "house" / "static" / f).read_bytes() == (static / f).read_bytes()
    for v in (5, 15):
        hand = hand_chain(
            tmp_path / f"hand{v}", [[LOG1], [LOG5]], "--static", static, "--set", f"map.layers.st_rise_s={v}"
        )
        for i, h in enumerate(hand, start=1):
            assert_same_maps(out / "house" / f"st_rise_s={v}" / f"day{i}", h, static=True)
    rows = summary(out)
    assert {(x["point"], x["site"], x["day"]) for x in rows} >= {
        ("st_rise_s=5", "house", "1"),
        ("st_rise_s=15", "house", "2"),
        ("st_rise_s=5", "all", "all"),
    }
    # a shorter rise puts more into LT: the sweep shows in the summary
    lt = {x["point"]: int(x["long_term_voxels"]) for x in rows if x["site"] == "house" and x["day"] == "1"}
    assert lt["st_rise_s=5"] > lt["st_rise_s=15"]
    # a changed parameter: every day again, the plan (which does not depend on it) not
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob(TASK_FILE)}
    r = ltmap(
        "batch",
        manifest,
        "-o",
        out,
        "--workers",
        "2",
        "--no-plots",
        "--sweep",
        "map.layers.st_rise_s=5,15",
        "--set",
        "map.layers.lt_fall_s=4",
    )
    assert r.exit_code == 0, r.output
    assert "4 of 4 days done (0 up to date, 4 replayed)" in r.output
    assert [p for p in stamps if p.stat().st_mtime_ns == stamps[p]] == [out / "house" / "static" / TASK_FILE]
    assert "lt_fall_s: 4.0" in (out / "house" / "st_rise_s=5" / "day2" / "config.yaml").read_text()


@pytest.mark.slow
def test_a_worker_killed_in_the_middle_the_batch_completes_with_the_same_results(tmp_path):
    days = {"a": [[LOG1], [LOG4]], "b": [[LOG5], [LOG1]]}
    manifest = write_manifest(tmp_path / "fleet.yaml", {k: {"days": v} for k, v in days.items()})
    out = tmp_path / "out"
    plan = build_plan(load_manifest(manifest), out, sets=[("replay.plots", False)])
    engine = Engine(workers=2).start()
    try:
        client = engine.client
        pids = client.run(os.getpid)
        box = {}
        runner = threading.Thread(target=lambda: box.setdefault("res", execute(plan, engine)))
        runner.start()
        victim = None
        deadline = time.monotonic() + 120
        while victim is None and time.monotonic() < deadline:  # a replay under way: its staging folder exists
            busy = [w for w, keys in client.processing().items() if keys]
            if busy and list(out.glob(f"*/.day1.{STAGING}*")):
                victim = busy[0]
            time.sleep(0.05)
        assert victim is not None, "no task started"
        killed = [k for k in client.processing().get(victim, ()) if str(k).startswith("ltmap-")]
        os.kill(pids[victim], signal.SIGKILL)
        runner.join(300)
        assert not runner.is_alive()
    finally:
        engine.close()
    result, _ = box["res"]
    assert [s.status for s in result.states] == [DONE] * 4
    # the engine rescheduled the killed task (ltmap's own retry of a failed task was not needed)
    assert [s.attempts for s in result.states] == [1] * 4
    assert pids[victim] not in {int(s.result["worker"].rsplit(":", 1)[1]) for s in result.states}
    # the task the killed worker was running was run again elsewhere, to the end
    assert len(killed) == 1
    again = [
        s for s in result.states if killed[0].startswith("ltmap-" + s.task.label.replace(" ", "-") + "-")
    ]
    assert len(again) == 1 and again[0].status == DONE
    assert not [p for p in out.rglob("*") if STAGING in p.name]
    for site, chain in days.items():
        hand = hand_chain(tmp_path / f"hand_{site}", chain)
        for i, h in enumerate(hand, start=1):
            assert_same_maps(out / site / f"day{i}", h)


@pytest.mark.slow
def test_a_batch_on_a_running_cluster_by_address_and_an_address_nobody_answers(tmp_path):
    from dask.distributed import LocalCluster

    manifest = write_manifest(tmp_path / "fleet.yaml", {"a": {"days": [[LOG4]]}})
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        r = ltmap(
            "batch", manifest, "-o", tmp_path / "out", "--no-plots", "--address", cluster.scheduler_address
        )
    assert r.exit_code == 0, r.output
    assert f"engine: Dask cluster at {cluster.scheduler_address} (1 worker)" in r.output
    assert_same_maps(tmp_path / "out" / "a" / "day1", hand_chain(tmp_path / "hand", [[LOG4]])[0])
    line = one_error_line(ltmap("batch", manifest, "-o", tmp_path / "out2", "--address", "tcp://127.0.0.1:9"))
    assert "--address tcp://127.0.0.1:9: cannot reach a Dask scheduler" in line and "dask scheduler" in line


@pytest.mark.slow
def test_a_long_list_of_failures_is_cut_after_20_lines(tmp_path):
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"not a log" * 100)
    manifest = write_manifest(
        tmp_path / "fleet.yaml", {f"s{i:02d}": {"days": [[bad], [LOG1]]} for i in range(21)}
    )
    r = ltmap("batch", manifest, "-o", tmp_path / "out", "--workers", "2", "-q")
    assert r.exit_code == 1, r.output
    lines = r.output.splitlines()
    assert sum(ln.startswith("ltmap: failed: ") for ln in lines) == 20
    assert sum(ln.startswith("ltmap: not run: ") for ln in lines) == 20
    assert f"ltmap: ... 2 more failed or not run: see {tmp_path / 'out' / 'summary.csv'}" in lines
    assert sum(x["status"] == "failed" for x in summary(tmp_path / "out")) == 21
