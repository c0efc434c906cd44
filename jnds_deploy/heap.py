"""The process's malloc heap (and OpenMP's idle threads), for the commands that run the
pipeline (``jnds run``, ``jnds serve``, ``jnds batch``'s workers); a light module (numpy and
the standard library) that they use before the runtime's imports.

- ``keep_freed_memory``: freed blocks stay in the heap for the next frame's arrays.
- ``pretouch``: the heap's pages for the first frame faulted in on another thread while the
  interpreter imports (`jnds run`'s cold start).
- ``brief_openmp_spin``: OpenMP's idle threads spin briefly, then sleep.
"""
from __future__ import annotations

import ctypes
import functools
import os
import threading

import numpy as np

# what the first frame of a fresh `jnds run` (int8, 2x) takes from the main heap, per
# native pixel: its ~780 MiB of heap after frame 0 at 1280x720 are mostly the main arena's;
# pretouching 600 MiB there was the fastest of 400, 600 and 800 (docs/performance.md,
# "Speed", stop 52)
FIRST_FRAME_HEAP_PER_PIXEL = 680


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


# iterations GNU OpenMP's idle workers spin before they sleep (libgomp's default 300 000):
# enough to bridge numba's back-to-back loops, too few to spin through a run of the network
# graph (docs/performance.md, "Speed", stop 70)
OPENMP_SPINS = 1000


def brief_openmp_spin() -> bool:
    """Have GNU OpenMP's idle threads spin only briefly (``GOMP_SPINCOUNT=OPENMP_SPINS``)
    unless the user set ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``; returns whether it set
    it. numba's threadsafe layer is GNU OpenMP where TBB is not installed, and by default
    its workers spin 300 000 times after every parallel loop, on the cores ONNX Runtime's
    threads need next: the network graph runs between numba loops (the input packing, the
    glue of the graph's cuts). Not spinning at all (``OMP_WAIT_POLICY=PASSIVE``) made small
    frames slower, each loop waking its threads. libgomp reads the variable once, when it is
    loaded (numba's first parallel loop, or importing torch): call this before either."""
    if "GOMP_SPINCOUNT" in os.environ or "OMP_WAIT_POLICY" in os.environ:
        return False
    os.environ["GOMP_SPINCOUNT"] = str(OPENMP_SPINS)
    return True


@functools.cache
def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed blocks for reuse instead of handing them back to the
    kernel (process-wide; returns False where there is no glibc). By default a block over
    ~32 MB is always a fresh mmap and smaller ones are trimmed when freed, so every frame's
    large arrays come back as new pages that the kernel faults in and zeroes on first
    write (docs/design-notes.md). The price: the process keeps its peak memory.

    Also stops numpy from advising the kernel to back its large arrays with transparent
    huge pages (unless the user set ``NUMPY_MADVISE_HUGEPAGE``): where the kernel compacts
    memory to find them (THP ``defrag`` "madvise", the Debian default), the first touch of
    each new array stalled in the kernel, and a cold `jnds run` spent more time there than
    the huge pages saved; frames that reuse their memory run as fast either way
    (docs/design-notes.md, "Huge pages")."""
    if "NUMPY_MADVISE_HUGEPAGE" not in os.environ:
        try:
            np._core.multiarray._set_madvise_hugepage(False)
        except AttributeError:  # a numpy without the switch
            pass
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

    A cold `jnds run` spends about half a second of system time faulting in and zeroing
    fresh pages, most of them during frame 0, and before it one core idles while the
    interpreter imports numba and ONNX Runtime: the pages faulted in there are not faulted
    in again by the frames (docs/performance.md, "Speed", stop 52). ``nbytes`` is capped at
    half the memory free now."""
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
