"""The malloc heap of the commands that run the pipeline (``jnds_deploy.heap``). Each test
runs in a fresh interpreter: the settings are process-wide."""
import os
import subprocess
import sys

import pytest

# a block's pages faulted in (minor faults) while it is filled, after a pretouch of
# PRETOUCH bytes or without one; malloc's settings as `jnds run` has them in both
_FAULTS = """
import resource, sys
import numpy as np
from jnds_deploy.heap import keep_freed_memory, pretouch
assert keep_freed_memory()
n = int(sys.argv[1])
if n:
    t = pretouch(n)
    assert t is not None
    t.join()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.empty(48 << 20, np.uint8)
a.fill(1)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(pretouched: int) -> int:
    proc = subprocess.run([sys.executable, "-c", _FAULTS, str(pretouched)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return int(proc.stdout.strip())


def test_pretouch_faults_in_the_heap_that_the_next_arrays_take():
    """What `jnds run` does while it imports: the pages of a pretouched block are not
    faulted in again by the arrays allocated after it (12 288 4-KiB pages for 48 MiB
    without)."""
    cold = _faults(0)
    if cold < 1000:
        pytest.skip(f"{cold} faults for 48 MiB: the kernel backs the heap with huge pages here")
    assert _faults(64 << 20) < cold // 10


def test_pretouch_does_nothing_when_asked_for_nothing():
    from jnds_deploy.heap import pretouch

    assert pretouch(0) is None


@pytest.mark.parametrize("env", [None, "1"])
def test_keep_freed_memory_turns_numpys_huge_page_advice_off_unless_the_user_set_it(env):
    """``keep_freed_memory`` (what `jnds run` and `jnds serve` turn on) stops numpy from
    advising huge pages for its arrays (their first touch stalled a cold run in the
    kernel's compaction); a ``NUMPY_MADVISE_HUGEPAGE`` the user set is kept."""
    code = ("import numpy._core.multiarray as m\n"
            "from jnds_deploy.heap import keep_freed_memory\n"
            "assert keep_freed_memory()\n"
            "print(m._set_madvise_hugepage(True))\n")
    environ = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if env is not None:
        environ["NUMPY_MADVISE_HUGEPAGE"] = env
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == ("False" if env is None else "True")


# the spin count libgomp runs with (OMP_DISPLAY_ENV=VERBOSE prints its settings when it is
# loaded), after the given imports and one numba parallel loop
_OPENMP = """
import sys
sys.path.insert(0, sys.argv[1])
{imports}
import numpy as np
from numba import njit, prange
@njit(parallel=True)
def add(a):
    for i in prange(a.shape[0]):
        a[i] += 1
add(np.zeros(8))
import numba
print(numba.threading_layer())
"""


@pytest.mark.parametrize("imports, env, spins", [
    # `jnds run` and `jnds serve`: tune_numba before the first loop
    ("from jnds_deploy.runtime import tune_numba; tune_numba()", {}, "1000"),
    # a spin count or a wait policy the user set is kept
    ("from jnds_deploy.runtime import tune_numba; tune_numba()", {"GOMP_SPINCOUNT": "5000"}, "5000"),
    ("from jnds_deploy.runtime import tune_numba; tune_numba()", {"OMP_WAIT_POLICY": "PASSIVE"}, "0"),
    # the benchmarks that import torch (which loads libgomp) before main() calls tune_process
    ("import benchmarks.common; import torch; benchmarks.common.tune_process()", {}, "1000"),
])
def test_openmps_idle_threads_spin_briefly_in_the_processes_that_run_the_pipeline(imports, env, spins):
    """GNU OpenMP's workers (numba's threadsafe layer) spin 300 000 times after every
    parallel loop by default, on the cores ONNX Runtime's threads need next
    (docs/performance.md, "Speed", stop 70): ``heap.brief_openmp_spin`` (through
    ``tune_numba``, and the benchmarks' import of ``benchmarks.common``) has libgomp load
    with ``heap.OPENMP_SPINS``."""
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    environ = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    proc = subprocess.run([sys.executable, "-c", _OPENMP.format(imports=imports), root],
                          env={**environ, **env, "OMP_DISPLAY_ENV": "VERBOSE"}, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    if proc.stdout.strip() != "omp":
        pytest.skip(f"numba's threading layer here is {proc.stdout.strip()!r}, not GNU OpenMP")
    assert f"GOMP_SPINCOUNT = '{spins}'" in proc.stderr, proc.stderr[-2000:]
