"""The process-wide settings (``jnds_deploy.process``): opt-in, what they set, and that a
pipeline changes none unless asked. Each test runs in a fresh interpreter: the settings are
process-wide."""

import json
import os
import subprocess
import sys

import pytest

# a block's pages faulted in (minor faults) while it is filled, after a pretouch of
# PRETOUCH bytes or without one; malloc's settings as `jnds run` has them in both
_FAULTS = """
import resource, sys
import numpy as np
from jnds_deploy.process import keep_freed_memory, pretouch
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
    from jnds_deploy.process import pretouch

    assert pretouch(0) is None


@pytest.mark.parametrize("env", [None, "1"])
def test_keep_freed_memory_turns_numpys_huge_page_advice_off_unless_the_user_set_it(env):
    """``keep_freed_memory`` (what `jnds run` and `jnds serve` turn on) stops numpy from
    advising huge pages for its arrays (their first touch stalled a cold run in the
    kernel's compaction); a ``NUMPY_MADVISE_HUGEPAGE`` the user set is kept."""
    code = (
        "import numpy._core.multiarray as m\n"
        "from jnds_deploy.process import keep_freed_memory\n"
        "assert keep_freed_memory()\n"
        "print(m._set_madvise_hugepage(True))\n"
    )
    environ = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if env is not None:
        environ["NUMPY_MADVISE_HUGEPAGE"] = env
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == ("False" if env is None else "True")


def test_huge_page_advice_goes_by_numpys_environment_variable_before_numpy_is_imported():
    """Called before numpy is imported (as `jnds run`, `serve` and `batch` do, ``cli.program``),
    ``no_huge_page_advice`` sets ``NUMPY_MADVISE_HUGEPAGE=0``, which numpy reads when imported:
    numpy's advice is off without its private switch."""
    code = (
        "import sys\n"
        "from jnds_deploy.process import no_huge_page_advice\n"
        "assert 'numpy' not in sys.modules\n"
        "assert no_huge_page_advice()\n"
        "import os, numpy._core.multiarray as m\n"
        "print(os.environ['NUMPY_MADVISE_HUGEPAGE'], m._set_madvise_hugepage(True))\n"
    )
    environ = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["0", "False"]


# a Pipeline built without asking, then one after process.shared_arena: what it changed in the
# process (environment, ONNX Runtime's allocators), whether its sessions take the shared arena,
# and its output (the arena holds memory, not values)
_PIPELINE = """
import json, os, sys
import numpy as np
import onnxruntime as ort
from jnds_deploy import process
from jnds_deploy.io import open_sequence
from jnds_deploy.runtime import Pipeline, PipelineConfig
registered = []
register = ort.create_and_register_allocator
ort.create_and_register_allocator = lambda *a: (registered.append(1), register(*a))[1]
env = dict(os.environ)
seq = open_sequence(sys.argv[2])

def frames(pipe):
    return [pipe(seq.inputs(i)).output for i in range(3)]

def shares(pipe):
    try:
        return pipe._opts.get_session_config_entry("session.use_env_allocators") == "1"
    except RuntimeError:  # not set
        return False

cfg = PipelineConfig(artifacts=sys.argv[1], precision="fp32")
alone = Pipeline(cfg)
a = frames(alone)
out = {"env": sorted(set(os.environ.items()) ^ set(env.items())), "registered": len(registered),
       "shares": shares(alone)}
assert process.shared_arena()
shared = Pipeline(cfg)
b = frames(shared)
out.update(after=len(registered), shared=shares(shared), equal=all(np.array_equal(x, y) for x, y in zip(a, b)))
print(json.dumps(out))
"""


def test_a_pipeline_changes_no_process_wide_setting_unless_asked(tiny_artifacts):
    """A ``Pipeline`` built by a library user sets no environment variable and registers no
    ONNX Runtime allocator; its sessions keep their own arenas. After ``process.shared_arena``
    (what `jnds run`, `serve` and `batch` call, through ``tune_process``) one allocator is
    registered, the next pipeline's sessions share it, and its frames are bit-equal."""
    from .conftest import SAMPLE

    proc = subprocess.run(
        [sys.executable, "-c", _PIPELINE, str(tiny_artifacts[0]), str(SAMPLE)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout) == {
        "env": [],
        "registered": 0,
        "shares": False,
        "after": 1,
        "shared": True,
        "equal": True,
    }


def test_tune_process_makes_every_setting_once():
    """``tune_process``: numpy's advice off, OpenMP's brief spin, numba's settings, malloc's,
    the shared arena; a second call changes nothing more."""
    code = (
        "import json, os, sys\n"
        "from jnds_deploy import process\n"
        "process.tune_process(); process.tune_process()\n"
        "import numba\n"
        "print(json.dumps([os.environ.get('NUMPY_MADVISE_HUGEPAGE'), os.environ.get('GOMP_SPINCOUNT'),\n"
        "                  numba.config.THREADING_LAYER, numba.config.SLP_VECTORIZE,\n"
        "                  process.shared_arena_registered(), process.keep_freed_memory()]))\n"
    )
    settings = ("NUMPY_MADVISE_HUGEPAGE", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
    environ = {k: v for k, v in os.environ.items() if k not in settings and not k.startswith("NUMBA_")}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout) == ["0", "1000", "threadsafe", 1, True, True]


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


@pytest.mark.parametrize(
    "imports, env, spins",
    [
        # `jnds run` and `jnds serve`: tune_numba before the first loop
        ("from jnds_deploy.runtime import tune_numba; tune_numba()", {}, "1000"),
        # a spin count or a wait policy the user set is kept
        ("from jnds_deploy.runtime import tune_numba; tune_numba()", {"GOMP_SPINCOUNT": "5000"}, "5000"),
        ("from jnds_deploy.runtime import tune_numba; tune_numba()", {"OMP_WAIT_POLICY": "PASSIVE"}, "0"),
        # the benchmarks that import torch (which loads libgomp) before main() calls tune_process
        ("import benchmarks.common; import torch; benchmarks.common.tune_process()", {}, "1000"),
    ],
)
def test_openmps_idle_threads_spin_briefly_in_the_processes_that_run_the_pipeline(imports, env, spins):
    """GNU OpenMP's workers (numba's threadsafe layer) spin 300 000 times after every
    parallel loop by default, on the cores ONNX Runtime's threads need next
    (docs/architecture.md, "The process"): ``process.brief_openmp_spin`` (through
    ``tune_numba``, and the benchmarks' import of ``benchmarks.common``) has libgomp load
    with ``process.OPENMP_SPINS``."""
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    environ = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    proc = subprocess.run(
        [sys.executable, "-c", _OPENMP.format(imports=imports), root],
        env={**environ, **env, "OMP_DISPLAY_ENV": "VERBOSE"},
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    if proc.stdout.strip() != "omp":
        pytest.skip(f"numba's threading layer here is {proc.stdout.strip()!r}, not GNU OpenMP")
    assert f"GOMP_SPINCOUNT = '{spins}'" in proc.stderr, proc.stderr[-2000:]
