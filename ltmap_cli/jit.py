"""numba's ``njit``, with the vector width the kernels are compiled for chosen first.

numba compiles for the host CPU with LLVM's defaults, and LLVM prefers 256-bit vectors even on
CPUs with AVX-512 (the ``prefer-256-bit`` tuning: on the first Xeons with AVX-512, 512-bit
instructions lowered the core's clock). On a CPU whose AVX-512 does not cost that, the kernels'
vectorized loops (the depth kernel's first pass, the projection's, the tails' starts) do twice
the work per instruction: on the 2-core Intel Xeon VM of the benches (LLVM's ``rocketlake``) the
depth kernel took 0.83x its time, the ray workers 0.92x to 0.95x their CPU and the room and hall
replays 4 % less wall time, the maps the same bit for bit (IEEE arithmetic, no fast-math: the
width changes no result). So every module that defines kernels takes ``njit`` from here, and
the features are set once, before numba builds its code generator (at the first kernel compiled
or loaded from the cache; numba keys its cache by them). ``NUMBA_CPU_NAME`` or
``NUMBA_CPU_FEATURES`` set by the user are kept as they are, and so is ``NUMBA_ENABLE_AVX=0``
(the host's features are numba's, which then have no AVX).
"""

from __future__ import annotations

import os

from numba import njit
from numba.core import config
from numba.core.cpu import CPUTargetOptions

__all__ = ["helper", "njit", "vector_features"]

_NO_REFCOUNT = {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}  # (numba's private option: helper)

# LLVM's names of the CPUs whose 512-bit instructions lower the clock (Skylake-SP and its
# successors before Ice Lake; Xeon Phi): LLVM's 256-bit preference stands there
CLOCK_BOUND_AVX512 = frozenset({"skylake-avx512", "cascadelake", "cooperlake", "knl", "knm"})


def helper(**options):
    """``njit`` for a kernel's helper that makes no array (a block's classes, a block lookup, a
    chunk of DDA starts): compiled without numba's reference counting (its ``_nrt`` option).
    Called from a kernel, a helper that numba does not inline took a reference to each of its
    array arguments on entry and gave it back on every way out, atomic increments and decrements
    on the arrays' shared counters: in a room replay, 4 % of the process's CPU (perf), in loops
    over blocks and quarters. Without them the projection took 0.87x to 0.89x its time (room,
    hall and depot frames) and the ray workers 0.94x their CPU, with the same maps. numba refuses
    to compile such a helper if it makes an array; it may take views of its arguments, which live
    longer than the call, but must not return an array, not even an argument as it came (numba
    accepts that, and the caller's reference counts are then wrong: a heap corrupted in a trial).
    (A numba without that option compiles them as ``njit`` does.)"""
    return njit(cache=True, nogil=True, **_NO_REFCOUNT, **options)


def vector_features(cpu_name: str, features: str, env) -> str | None:
    """The target features to compile the kernels for: the host's ``features`` (LLVM's "+a,-b"
    string) with 512-bit vectors allowed when it has AVX-512 and is not one of
    ``CLOCK_BOUND_AVX512``; None to leave numba's choice (no AVX-512, such a CPU, or the user set
    ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` in ``env``)."""
    if env.get("NUMBA_CPU_NAME") or env.get("NUMBA_CPU_FEATURES"):
        return None
    if "+avx512f" not in features.split(",") or cpu_name in CLOCK_BOUND_AVX512:
        return None
    return features + ",-prefer-256-bit"


def _configure() -> None:
    if config.CPU_NAME is not None or config.CPU_FEATURES is not None:
        return
    import llvmlite.binding as llvm  # (loaded by numba already)
    from numba.core.codegen import get_host_cpu_features  # (numba's: NUMBA_ENABLE_AVX=0 honoured)

    chosen = vector_features(llvm.get_host_cpu_name(), get_host_cpu_features(), os.environ)
    if chosen is not None:
        config.CPU_FEATURES = chosen


_configure()
