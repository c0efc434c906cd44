"""Every process-wide setting the package can make, in one place, and all of them opt-in.

Importing the package changes nothing in the process, and a ``runtime.Pipeline`` changes
nothing beyond itself unless asked. The ``jnds`` commands that own their process opt in:
`jnds run`, `jnds serve` and `jnds batch`'s workers call ``tune_process``, `jnds calibrate`
``tune_numba`` and ``shared_arena``; so do the benchmarks (``benchmarks.common``), so that
their timings are `jnds run`'s. An application that embeds the runtime may call
``tune_process``, or any one setting, before its first pipeline. Why each exists:
docs/architecture.md, "The process".

- ``brief_openmp_spin``: GNU OpenMP's idle threads spin briefly, then sleep
  (``GOMP_SPINCOUNT`` in the environment).
- ``tune_numba``: numba's threading layer, LLVM's SLP vectorizer, numba's BLAS probe.
- ``keep_freed_memory``: glibc's malloc keeps freed blocks for the next frame's arrays, and
  numpy does not advise huge pages (``no_huge_page_advice``). ``PipelineConfig.keep_freed_memory``
  asks for it too.
- ``pretouch``: the heap's pages for the first frame faulted in on another thread while the
  interpreter imports (`jnds run`'s cold start).
- ``shared_arena``: one CPU arena in ONNX Runtime's process-wide environment, which the
  sessions of every ``Pipeline`` built afterwards share.

Elsewhere, because they belong to what they set: ``io.exr_threads`` (OpenEXR's thread
pool), and `jnds run`'s ``gc.freeze`` (``cli``).

This module imports only the standard library: each setting imports what it changes when
it is made, so that `jnds run` can make them before numpy, numba and ONNX Runtime load.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading

# what the first frame of a fresh `jnds run` (int8, 2x) takes from the main heap, per native
# pixel: mostly the main arena's, and pretouching about that much was the fastest choice
# (docs/performance.md, "Memory and cold start"; the record: docs/performance.md at commit
# 5431ce1)
FIRST_FRAME_HEAP_PER_PIXEL = 680

# iterations GNU OpenMP's idle workers spin before they sleep (libgomp's default 300 000):
# enough to bridge numba's back-to-back loops, too few to spin through a run of the network
# graph (docs/architecture.md, "The process")
OPENMP_SPINS = 1000


def tune_process() -> None:
    """Every setting below but ``pretouch``, as `jnds run`, `jnds serve` and `jnds batch`'s
    workers run: numpy's huge-page advice off first (before anything imports numpy, where
    nothing has yet), OpenMP's brief spin, ``tune_numba``, ``keep_freed_memory`` and the
    shared ONNX Runtime arena. Call it before the first ``Pipeline``."""
    no_huge_page_advice()
    brief_openmp_spin()
    tune_numba()
    keep_freed_memory()
    shared_arena()


def brief_openmp_spin() -> bool:
    """Have GNU OpenMP's idle threads spin only briefly (``GOMP_SPINCOUNT=OPENMP_SPINS``)
    unless the user set ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``; returns whether it set
    it. numba's threadsafe layer is GNU OpenMP where TBB is not installed, and by default
    its workers spin 300 000 times after every parallel loop, on the cores ONNX Runtime's
    threads need next: the network graph runs between numba loops (the input packing, the
    glue of the graph's cuts). Not spinning at all (``OMP_WAIT_POLICY=PASSIVE``) made small
    frames slower, each loop waking its threads. libgomp reads the variable once, when it is
    loaded (numba's first parallel loop, or importing torch): call this before either. The
    variable is in the environment, so processes started from this one inherit it."""
    if "GOMP_SPINCOUNT" in os.environ or "OMP_WAIT_POLICY" in os.environ:
        return False
    os.environ["GOMP_SPINCOUNT"] = str(OPENMP_SPINS)
    return True


def tune_numba() -> None:
    """The process-wide numba settings the runtime is measured and served with (also
    ``runtime.tune_numba``). A setting the user made with a ``NUMBA_*`` environment variable
    is kept.

    - Threading layer ``threadsafe`` (TBB or GNU OpenMP): numba's ``workqueue`` layer
      aborts the process when two threads run parallel loops at once (the server does).
    - LLVM's SLP vectorizer on (numba leaves it off): the warp loop
      (``filters._warp_rows``) relies on it to turn its 12 per-channel sums into vector
      FMAs (docs/architecture.md, "The filter stage"). It changes no result: without
      fast-math flags it reorders no sum. It acts on loops compiled after the call (numba's
      on-disk cache keeps what was compiled before).
    - numba's BLAS probe answered "absent": the first loop numba compiles or loads from its
      cache imports ``numba.np.arraymath``, which imports scipy (where installed) to look
      for BLAS, a part of every cold start (docs/performance.md, "Memory and cold start").
      No runtime loop calls BLAS; numba code in the same process that did (``np.dot``)
      would be refused with numba's "scipy is required" error.
    - OpenMP's idle threads spin briefly, then sleep (``brief_openmp_spin``), unless the
      user set ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``. It takes effect only where
      nothing loaded libgomp before the call (torch does, when imported).
    """
    brief_openmp_spin()  # first: before anything below can load libgomp
    import numba

    if "numba.np.arraymath" not in sys.modules and "scipy.linalg" not in sys.modules:
        sys.modules["scipy.linalg"] = None  # ``import scipy.linalg...`` fails: the probe sees no BLAS
        try:
            import numba.np.arraymath  # noqa: F401
        finally:
            del sys.modules["scipy.linalg"]
    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = "threadsafe"
    if "NUMBA_SLP_VECTORIZE" not in os.environ:
        numba.config.SLP_VECTORIZE = 1


@functools.cache
def _libc():
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.malloc.restype = ctypes.c_void_p
        libc.malloc.argtypes = [ctypes.c_size_t]
        libc.free.argtypes = [ctypes.c_void_p]
        libc.memset.restype = ctypes.c_void_p
        libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
        libc.mallopt  # noqa: B018  (glibc's, not every libc has it)
        return libc
    except (OSError, AttributeError):
        return None


def no_huge_page_advice() -> bool:
    """Stop numpy from advising the kernel to back its large arrays with transparent huge
    pages, unless the user set ``NUMPY_MADVISE_HUGEPAGE``; returns whether numpy's advice is
    off. Where the kernel compacts memory to find huge pages (THP ``defrag`` "madvise", the
    Debian default), the first touch of each new array stalled in the kernel, and a cold
    `jnds run` spent more time there than the huge pages saved; frames that reuse their
    memory run as fast either way (docs/architecture.md, "The process").

    numpy reads ``NUMPY_MADVISE_HUGEPAGE``, its documented switch, when it is imported:
    before that, this sets the variable (which processes started from this one inherit).
    Once numpy is imported, only numpy's private ``_set_madvise_hugepage`` can change it,
    and a numpy without it keeps its advice (False)."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return os.environ["NUMPY_MADVISE_HUGEPAGE"] == "0"
    if "numpy" not in sys.modules:
        os.environ["NUMPY_MADVISE_HUGEPAGE"] = "0"
        return True
    import numpy as np

    core = getattr(np, "_core", None) or getattr(np, "core", None)  # numpy 2, numpy 1
    switch = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        return False
    switch(False)
    return True


@functools.cache
def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed blocks for reuse instead of handing them back to the
    kernel (returns False where there is no glibc), and numpy's huge-page advice off
    (``no_huge_page_advice``). By default a block over ~32 MB is always a fresh mmap and
    smaller ones are trimmed when freed, so every frame's large arrays come back as new
    pages that the kernel faults in and zeroes on first write (docs/architecture.md, "The
    process"). The price: the process keeps its peak memory."""
    no_huge_page_advice()
    libc = _libc()
    if libc is None:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(libc.mallopt(m_mmap_threshold, 1 << 30) and libc.mallopt(m_trim_threshold, 1 << 31))


def pretouch(nbytes: int) -> threading.Thread | None:
    """Fault in ``nbytes`` of the main heap on a background thread and free them there, for
    the frames to allocate from (with ``keep_freed_memory``, which this turns on); returns
    the thread, or None where nothing is done (no glibc, nothing asked, not that much
    memory free). The block is taken here, on the calling thread, so that it is the main
    heap's when called from the main thread, which allocates the frames' arrays and ONNX
    Runtime's arena.

    A cold `jnds run` spends a good part of its system time faulting in and zeroing fresh
    pages, most of them during frame 0, and before it one core idles while the interpreter
    imports numba and ONNX Runtime: the pages faulted in there are not faulted in again by
    the frames (docs/performance.md, "Memory and cold start"). ``nbytes`` is capped at half
    the memory free now."""
    try:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError):
        return None
    nbytes = min(int(nbytes), free // 2)
    if nbytes <= 0 or not keep_freed_memory():
        return None
    libc = _libc()
    block = libc.malloc(nbytes)
    if not block:
        return None

    def touch():
        try:
            libc.memset(block, 0, nbytes)  # ctypes lets go of the GIL for the call
        finally:
            libc.free(block)

    thread = threading.Thread(target=touch, name="jnds-pretouch", daemon=True)
    thread.start()
    return thread


_arena_lock = threading.Lock()
_arena_registered = False


def shared_arena() -> bool:
    """Register one CPU arena allocator in ONNX Runtime's process-wide environment; the
    sessions of every ``Pipeline`` built afterwards use it (``session.use_env_allocators``)
    instead of an arena each, and it extends by the size asked (``kSameAsRequested``)
    instead of doubling: the graphs' intermediates reuse the same memory instead of each
    session keeping its own peak (docs/architecture.md, "The process"). Outputs are the
    same either way. Returns whether the arena is there: False where this ONNX Runtime
    cannot register one (the sessions then keep their own). Registered once per process."""
    global _arena_registered
    with _arena_lock:
        if not _arena_registered:
            import onnxruntime as ort

            try:
                info = ort.OrtMemoryInfo("Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT)
                # max_mem 0: no limit; arena_extend_strategy 1: kSameAsRequested; -1: defaults
                ort.create_and_register_allocator(info, ort.OrtArenaCfg(0, 1, -1, -1))
                _arena_registered = True
            except (AttributeError, RuntimeError):
                return False
        return True


def shared_arena_registered() -> bool:
    """Whether ``shared_arena`` registered the arena in this process (``Pipeline`` asks)."""
    return _arena_registered
