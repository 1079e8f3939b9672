"""The engine and the driver loop of ``ltmap batch``.

Engine: Dask.distributed. Embedded by default (a ``LocalCluster`` of worker processes, one
thread each, started in a couple of seconds, nothing to set up); with ``address`` a running
scheduler (``dask scheduler`` + ``dask worker`` on each machine). The scheduler reschedules the
tasks of a worker that dies on another worker.

Driver: the static plans are submitted first; a site's chains start when its plan is built; day
N+1 of a chain is submitted when day N is done. A failed task (an exception in the replay) is
submitted once more; failing again, it is reported and the later days of its chain (all chains
of the site, for a plan) are not run. The other chains go on.
"""

from __future__ import annotations

import fcntl
import logging
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError, OutputError, output_error
from ..pipeline.executor import usable_cores
from .graph import BatchPlan, Chain, DayTask, StaticTask
from .tasks import DONE, FAILED, UP_TO_DATE, run_task

LOCK_FILE = ".ltmap-batch.lock"
POLL_S = 0.5  # the driver's refresh period (progress, completed tasks)
CONNECT_TIMEOUT_S = 10
WORKER_WAIT_S = 30  # a cluster without workers: how long to wait for the first before giving up
TRIM_ENV = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"  # None: not set in the workers

# the states of a task, as the progress line and summary.csv show them (and DONE, UP_TO_DATE, FAILED)
QUEUED, NOT_RUN = "queued", "not run"


@dataclass
class TaskState:
    task: StaticTask | DayTask
    status: str = QUEUED
    attempts: int = 0
    result: dict = field(default_factory=dict)
    reason: str = ""  # why NOT_RUN


@dataclass
class Counts:
    total: int
    done: int = 0  # replayed or built in this batch
    up_to_date: int = 0
    running: int = 0
    failed: int = 0
    not_run: int = 0
    elapsed_s: float = 0.0
    left_s: float | None = None  # None: not known yet

    @property
    def finished(self) -> int:
        return self.done + self.up_to_date + self.failed + self.not_run


@dataclass
class BatchResult:
    states: list[TaskState]
    wall_s: float
    engine: str

    def by_status(self, status: str) -> list[TaskState]:
        return [s for s in self.states if s.status == status]


# ------------------------------------------------------------------------------------ engine
class Engine:
    """A Dask client: on an embedded local cluster, or on the scheduler at ``address``."""

    def __init__(self, address: str | None = None, workers: int | None = None):
        self.address = address
        self.workers = workers or usable_cores()
        self.client = None
        self.cluster = None
        self.startup_s = 0.0
        self.description = ""

    def start(self) -> Engine:
        try:
            import dask
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError(
                "ltmap batch needs Dask.distributed; install it with pip install 'ltmap[fleet]'"
            ) from None
        t0 = time.perf_counter()
        if self.address:
            try:
                self.client = Client(self.address, timeout=f"{CONNECT_TIMEOUT_S}s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(
                    f"--address {self.address}: cannot reach a Dask scheduler ({exc}); start one with "
                    "`dask scheduler` or leave --address out to run on this machine"
                ) from None
            try:
                self.client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError:
                self.client.close()
                raise ConfigError(
                    f"--address {self.address}: the scheduler has no workers after {WORKER_WAIT_S} s; "
                    f"start some with `dask worker {self.address}`"
                ) from None
            n = len(self.client.scheduler_info().get("workers", {}))
            self.description = f"Dask cluster at {self.address} ({_workers(n)})"
        else:
            # one process per worker (the replay holds the GIL in places), one task at a time each;
            # no memory limit: a replay's memory is bounded by the map, not by Dask's share; and
            # so without the MALLOC_TRIM_THRESHOLD_ Dask sets in its workers for that limit (it
            # hands freed memory back to the system at once: a replay then faults its arrays' pages
            # in again and again, 20 times the page faults and 12 % more CPU, bench_fleet.py). A
            # MALLOC_TRIM_THRESHOLD_ of the user's environment is inherited as it is.
            with dask.config.set({TRIM_ENV: None}):
                self.cluster = LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    # its scheduler's HTTP server (health and metrics: no dashboard) on a free port,
                    # not on 8787, taken by another batch or a notebook's cluster (a UserWarning)
                    scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                    memory_limit=0,
                    silence_logs=logging.CRITICAL,  # a worker's failure reaches the user as its task's result
                )
            self.client = Client(self.cluster)
            self.description = f"local Dask cluster ({_workers(self.workers)})"
        self.startup_s = time.perf_counter() - t0
        return self

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    def __enter__(self) -> Engine:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def _workers(n: int) -> str:
    return f"{n} worker" + ("s" if n != 1 else "")


# ------------------------------------------------------------------------------------ output folder
class OutputLock:
    """OUT is written by one batch at a time (an advisory lock on OUT/.ltmap-batch.lock)."""

    def __init__(self, out: Path):
        self.out = out
        self._fd = None

    def __enter__(self) -> OutputLock:
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.out / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise output_error(err, f"the output folder {self.out}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise OutputError(
                f"{self.out}: another ltmap batch is writing this folder; wait for it to end or "
                "choose another -o"
            ) from None
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


# ------------------------------------------------------------------------------------ driver
def execute(
    plan: BatchPlan,
    engine: Engine,
    *,
    rerun: bool = False,
    progress: Callable[[Counts], None] | None = None,
    notify: Callable[[str], None] | None = None,
) -> tuple[BatchResult, list[Path]]:
    """The whole batch: OUT locked (each task's folder cleans what a killed run of it left, as
    every OutputFolder does), the engine started (unless
    the caller did) and closed, every task run, the summary written. Returns the result and the
    summary files."""
    from .summary import write_summary

    with OutputLock(plan.out):
        started_here = engine.client is None
        try:
            if started_here:
                engine.start()
                if notify is not None:
                    notify(
                        f"engine: {engine.description}, started in {engine.startup_s:.1f} s; "
                        f"{len(plan.tasks())} tasks ({len(plan.chains)} chains of days)"
                    )
            result = run_batch(plan, engine.client, rerun=rerun, progress=progress, notify=notify)
        finally:
            if started_here:
                engine.close()
        result.engine = engine.description
        return result, write_summary(plan, result)


def run_batch(
    plan: BatchPlan,
    client,
    *,
    retries: int = 1,
    rerun: bool = False,
    progress: Callable[[Counts], None] | None = None,
    notify: Callable[[str], None] | None = None,
) -> BatchResult:
    """Run every task of ``plan`` on the Dask ``client``; returns each task's final state.

    ``rerun``: replay every day even when its folder is up to date. ``notify``: one-line notes
    for the user (the engine, retries, a task's warnings), as ``ltmap: <note>`` would show them."""
    from dask.distributed import wait

    t0 = time.perf_counter()
    states = {id(t): TaskState(t) for t in plan.tasks()}
    chains_of_site: dict[str, list[Chain]] = {}
    for c in plan.chains:
        chains_of_site.setdefault(c.site, []).append(c)
    next_day = {id(d): c.days[i + 1] for c in plan.chains for i, d in enumerate(c.days[:-1])}
    chain_of = {id(d): c for c in plan.chains for d in c.days}
    futures: dict = {}
    replayed_weight = 0
    note = notify or (lambda text: None)

    def submit(task) -> None:
        st = states[id(task)]
        st.attempts += 1
        slug = task.label.replace(" ", "-").replace("[", "").replace("]", "")
        fut = client.submit(run_task, task, rerun, key=f"ltmap-{slug}-{uuid.uuid4().hex[:8]}", pure=False)
        futures[fut] = task

    def not_run(tasks, why: str) -> None:
        for t in tasks:
            states[id(t)].status, states[id(t)].reason = NOT_RUN, why

    for task in plan.statics.values():
        submit(task)
    for c in plan.chains:
        if c.static is None:
            submit(c.days[0])
    last_draw = 0.0
    while futures:
        try:
            done, _ = wait(list(futures), timeout=POLL_S, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        for fut in done:
            task = futures.pop(fut)
            st = states[id(task)]
            try:
                res = fut.result()
            except Exception as exc:  # the engine gave up on it (a worker lost too often, a cancel)
                res = {"status": FAILED, "error": f"the engine lost the task: {type(exc).__name__}: {exc}"}
            st.result = res
            if res["status"] == FAILED and st.attempts <= retries:
                note(f"warning: {task.label} failed ({res['error']}); retrying once")
                submit(task)
                continue
            st.status = res["status"]
            for w in res.get("warnings") or []:
                note(f"warning: {task.label}: {w}")
            if isinstance(task, DayTask) and st.status == DONE:
                replayed_weight += task.weight
            if st.status == FAILED:
                if isinstance(task, StaticTask):
                    for c in chains_of_site.get(task.site, []):
                        not_run(c.days, f"the static plan of {task.site} failed")
                else:
                    chain = chain_of[id(task)]
                    not_run(chain.days[task.day :], f"day {task.day} failed")
                continue
            if isinstance(task, StaticTask):
                for c in chains_of_site.get(task.site, []):
                    submit(c.days[0])
            elif id(task) in next_day:
                submit(next_day[id(task)])
        now = time.perf_counter()
        if progress is not None and (done or now - last_draw >= POLL_S):
            last_draw = now
            progress(_counts(states.values(), client, futures, now - t0, replayed_weight))
    wall = time.perf_counter() - t0
    if progress is not None:
        progress(_counts(states.values(), None, {}, wall, replayed_weight))
    return BatchResult(list(states.values()), wall, "")


def _counts(states, client, futures: dict, elapsed: float, replayed_weight: int) -> Counts:
    c = Counts(total=0, elapsed_s=elapsed)
    in_flight = {f.key for f in futures}
    running_keys = set()
    if client is not None and in_flight:
        try:
            for keys in client.processing().values():
                running_keys.update(k for k in keys if k in in_flight)
        except Exception:  # progress must not stop the batch
            running_keys = set()
    running_ids = {id(t) for f, t in futures.items() if f.key in running_keys}
    left_weight = 0
    for st in states:
        c.total += 1
        if st.status == DONE:
            c.done += 1
        elif st.status == UP_TO_DATE:
            c.up_to_date += 1
        elif st.status == FAILED:
            c.failed += 1
        elif st.status == NOT_RUN:
            c.not_run += 1
        elif isinstance(st.task, DayTask):
            left_weight += st.task.weight
        if id(st.task) in running_ids:
            c.running += 1
    if replayed_weight > 0 and elapsed > 0:
        c.left_s = left_weight / (replayed_weight / elapsed)
    elif left_weight == 0:
        c.left_s = 0.0
    return c
