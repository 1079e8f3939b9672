"""``ltmap_cli.jit``: the kernels' target features, chosen before numba builds its code generator
(512-bit vectors where AVX-512 does not lower the clock; the user's ``NUMBA_CPU_*`` kept)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from ltmap_cli.jit import CLOCK_BOUND_AVX512, vector_features


def test_vector_features_by_hand():
    host = "+avx2,+avx512f,-amx-avx512,+fma"
    assert vector_features("rocketlake", host, {}) == host + ",-prefer-256-bit"
    assert vector_features("sapphirerapids", host, {"OTHER": "1"}) == host + ",-prefer-256-bit"
    for name in ("skylake-avx512", "cascadelake"):  # their 512-bit instructions lower the clock
        assert name in CLOCK_BOUND_AVX512 and vector_features(name, host, {}) is None
    assert vector_features("znver3", "+avx2,-avx512f,+fma", {}) is None  # no AVX-512 ("-avx512f")
    assert vector_features("rocketlake", host, {"NUMBA_CPU_FEATURES": "+avx2"}) is None  # the user's choice
    assert vector_features("rocketlake", host, {"NUMBA_CPU_NAME": "generic"}) is None


_PROBE = """
import ltmap_cli.core.raycast  # (a kernel module: ltmap_cli.jit first)
import numpy as np
import llvmlite.binding as llvm
from numba import njit
from numba.core.registry import cpu_target
from ltmap_cli.jit import vector_features

@njit(cache=False)
def axpy(a, x, y):
    for i in range(x.shape[0]):
        y[i] = a * x[i] + y[i]

axpy(2.0, np.ones(64), np.ones(64))
host = llvm.get_host_cpu_features().flatten()
want = vector_features(llvm.get_host_cpu_name(), host, {}) or host
asm = axpy.inspect_asm(axpy.signatures[0])
print(cpu_target.target_context.codegen()._tm_features == want, want.endswith("-prefer-256-bit"), "zmm" in asm)
"""


def test_kernels_are_compiled_for_the_chosen_features_in_a_fresh_process():
    """In a process that imports a kernel module first, numba's code generator takes
    ``vector_features``' choice; where that allows 512-bit vectors, a vectorizable loop compiled
    then uses them (zmm registers), and not when the user's ``NUMBA_CPU_FEATURES`` says so."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True)
    same, wide, zmm = out.stdout.split()
    assert same == "True"
    if wide != "True":
        pytest.skip("this CPU has no AVX-512, or one whose 512-bit instructions lower the clock")
    assert zmm == "True"
    import llvmlite.binding as llvm

    env["NUMBA_CPU_FEATURES"] = llvm.get_host_cpu_features().flatten()  # numba's default, as a user would set it
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "False"]  # (want: our choice; the codegen: the user's)


def test_numbas_avx_switch_is_kept():
    """``NUMBA_ENABLE_AVX=0`` (numba's switch for CPUs whose AVX is slow): numba's host features
    then say no AVX-512, so ltmap sets none of its own."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    probe = "import ltmap_cli.jit; from numba.core import config; print(config.CPU_FEATURES)"
    out = subprocess.run([sys.executable, "-c", probe], env={**env, "NUMBA_ENABLE_AVX": "0"},
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert out.stdout.strip() == "None"


_LOOKUP = """
@{decorator}
def {name}(a, b, i):  # (reads its array arguments, makes none; returns from three places)
    x = 0.0
    for k in range(i, min(i + 3, a.shape[0])):
        if a[k] > 5.0:
            return x + b[k]
        x += a[k] * b[k]
    if x < -2.0:
        return -x
    return x
"""

_REFCOUNT_PROBE = """
import re
import numpy as np
from ltmap_cli.jit import helper, njit
{helper_lookup}
{counted_lookup}
a, b = np.arange(-5.0, 7.0), np.linspace(0.0, 1.0, 12)
assert all(lookup(a, b, i) == lookup_counted(a, b, i) for i in range(12))

def refs(kernel):  # in the function itself, not in the wrapper Python calls it through
    ir = kernel.inspect_llvm(kernel.signatures[0])
    return sum(len(re.findall(r"call void @NRT_(?:incref|decref)", f)) for f in re.split(r"\\ndefine ", ir)[1:]
               if "cpython." not in f.split("(")[0] and "lookup" in f.split("(")[0])

print(refs(lookup), refs(lookup_counted), lookup.targetoptions.get("nogil"))
"""


def test_helpers_take_no_references_to_their_arrays(tmp_path):
    """``helper`` compiles a kernel's helper without numba's reference counting: its code has no
    call to ``NRT_incref`` / ``NRT_decref`` (atomic operations on its arrays' counters at every
    call, in loops over blocks and quarters: 4 % of a room replay's CPU), where the same function
    compiled with ``njit`` has some, and it gives the same results (nogil, as every kernel). The
    core's block lookups and the projection's per-block helpers are such helpers."""
    probe = tmp_path / "probe.py"  # (numba caches only functions of a file; one function each, the same body)
    probe.write_text(_REFCOUNT_PROBE.format(helper_lookup=_LOOKUP.format(decorator="helper()", name="lookup"),
                                            counted_lookup=_LOOKUP.format(decorator="njit(cache=True, nogil=True)",
                                                                          name="lookup_counted")))  # fmt: skip
    out = subprocess.run([sys.executable, str(probe)], env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")},
                         capture_output=True, text=True, check=True)  # fmt: skip
    helper_refs, counted_refs, nogil = out.stdout.split()
    assert int(helper_refs) == 0 and int(counted_refs) > 0 and nogil == "True"
    import ast
    import importlib
    from pathlib import Path

    import ltmap_cli.core

    found = []
    for path in sorted(Path(ltmap_cli.core.__file__).parent.glob("*.py")):
        mod = importlib.import_module(f"ltmap_cli.core.{path.stem}")
        for fn in ast.walk(ast.parse(path.read_text())):
            if isinstance(fn, ast.FunctionDef) and any(ast.unparse(d).startswith("helper(") for d in fn.decorator_list):
                found.append(fn.name)
                assert getattr(mod, fn.name).targetoptions.get("_nrt") is False, fn.name
    assert {"find_block", "get_or_add_block", "_classify", "_block_fill", "_tail_walks", "ray_starts"} <= set(found)
