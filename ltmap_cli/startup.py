"""Python's cyclic garbage collector paused while a process starts: ``pause_gc()`` as the
``ltmap`` program begins (``cli.main``), ``resume_gc()`` once its work is about to start (a
replay: its kernels loaded, ``Replay._warm_up``; any other command: before it runs).

The imports (numba's among them) and the kernels' loading make some 100 k objects that live as
long as the process; the collector's passes over them, three generation-2 passes among them,
were part of a replay's start-up, which one core waits for. Paused, then the objects made so
far frozen out of its passes (``gc.freeze``), a replay of the room took 0.98x its wall time
(4.00 -> 3.93 s over 8 interleaved runs); the frames' own objects are collected as before. A
library user who never calls ``pause_gc`` keeps the collector as it was (``resume_gc`` is then
a no-op)."""

from __future__ import annotations

import gc

_paused = False


def pause_gc() -> None:
    global _paused
    if gc.isenabled():
        gc.disable()
        _paused = True


def resume_gc() -> None:
    global _paused
    if _paused:
        _paused = False
        gc.freeze()
        gc.enable()
