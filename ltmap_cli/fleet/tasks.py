"""What a worker runs: one static plan build or one day's replay, idempotent.

A task writes its folder through ``OutputFolder`` as ``ltmap replay`` and ``ltmap build-static``
do (staged beside it, the manifest written last, swapped in whole), with ``batch_task.json`` (its
fingerprint) inside: a worker killed in the middle leaves the final folder as it was, and a task run again (the engine rescheduling it
after a worker died) finds its folder complete and returns at once. A task never raises: it
returns a result dict (``status`` done / up to date / failed, with a one-line ``error``) so that
the driver decides on retries; only the engine's own failures (a worker lost too often) reach
the driver as exceptions.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
import traceback
import warnings
from pathlib import Path

from ..errors import LtmapError, LtmapWarning, OutputError
from ..io.static_layer import LAYER_FILE, MAP_YAML
from ..outputs.folder import OutputFolder, tidy
from ..outputs.snapshots import final_state
from ..pipeline.replay import Replay, ReplayRequest
from .graph import DayTask, StaticTask

BATCH_RAY_WORKERS = 2  # ray workers of each replay of a batch whose config leaves replay.workers at 0

DONE, UP_TO_DATE, FAILED = "done", "up to date", "failed"  # a task's result["status"]
TASK_FILE = "batch_task.json"  # written last, inside the staging folder: the folder is complete
DAY_OUTPUTS = ("report.json", "map.yaml", "long_term.yaml", final_state())
STATIC_OUTPUTS = (MAP_YAML, LAYER_FILE)


def is_complete(folder: Path, key: str, required: tuple[str, ...]) -> bool:
    """``folder`` holds a finished task with fingerprint ``key`` (and its main outputs)."""
    try:
        doc = json.loads((folder / TASK_FILE).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("key") == key and all((folder / r).is_file() for r in required)


def run_task(task: StaticTask | DayTask, rerun: bool = False) -> dict:
    """Run one task on a worker; never raises (but BaseExceptions such as KeyboardInterrupt).
    ``rerun``: run it even when its folder is up to date."""
    t0 = time.perf_counter()
    where = {"worker": f"{socket.gethostname()}:{os.getpid()}"}
    required = STATIC_OUTPUTS if isinstance(task, StaticTask) else DAY_OUTPUTS
    try:
        tidy(Path(os.path.abspath(task.out_dir)), task.label, keep_killed=False)  # what a killed run of it left
        if not rerun and is_complete(task.out_dir, task.key, required):
            return {"status": UP_TO_DATE, "wall_s": time.perf_counter() - t0, **where}
        _check_ours(task.out_dir)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", LtmapWarning)
            _in_staging(task, _build_static if isinstance(task, StaticTask) else _replay_day)
        shown = [str(w.message) for w in caught if issubclass(w.category, LtmapWarning)]
        return {"status": DONE, "wall_s": time.perf_counter() - t0, "warnings": shown, **where}
    except Exception as exc:  # reported to the driver, which retries once
        return {
            "status": FAILED,
            "error": one_line(exc),
            "traceback": traceback.format_exc(),
            "wall_s": time.perf_counter() - t0,
            **where,
        }


def one_line(exc: BaseException) -> str:
    if isinstance(exc, LtmapError):
        text = str(exc)
    elif isinstance(exc, OSError):
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        text = f"{where}{exc.strerror or exc}"
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def _check_ours(folder: Path) -> None:
    """Replace only what ltmap batch wrote: a folder without batch_task.json is someone else's."""
    if folder.exists() and not (folder / TASK_FILE).is_file():
        raise OutputError(
            f"{folder} exists and was not written by ltmap batch; move it away or choose another "
            "output folder (-o)"
        )


def _in_staging(task: StaticTask | DayTask, work) -> None:
    command = "build-static" if isinstance(task, StaticTask) else "replay"
    with OutputFolder(task.out_dir, command=command, option=task.label, keep_killed=False) as out:
        work(task, out.staging, out.final)
        doc = {"key": task.key, "task": task.label, "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        (out.staging / TASK_FILE).write_text(json.dumps(doc, indent=2) + "\n")
        out.commit({"batch_task": task.label})


def _replay_day(task: DayTask, staging: Path, final: Path) -> None:
    request = ReplayRequest(list(task.logs), staging, static=task.static, resume=task.resume, final_dir=final)
    cfg = task.cfg
    if cfg.replay.workers == 0:  # a batch runs a replay per core already: not one ray worker per core each
        cfg = dataclasses.replace(cfg, replay=dataclasses.replace(cfg.replay, workers=BATCH_RAY_WORKERS))
    Replay(cfg, request).run()


def _build_static(task: StaticTask, staging: Path, final: Path) -> None:
    """What ``ltmap build-static PLAN -o OUT/<site>/static`` writes, with the site's options."""
    from ..static.build import build_from_plan, write_static
    from ..static.svgplan import parse_plan

    o = task.options
    parse_kw = {
        k: (tuple(o[k]) if k == "origin" else o[k]) for k in ("scale", "wall_thickness", "origin") if k in o
    }
    build_kw = {k: o[k] for k in ("resolution", "wall_height", "furniture") if k in o}
    layer, _ = build_from_plan(parse_plan(task.plan, **parse_kw), **build_kw)
    write_static(staging, layer)
