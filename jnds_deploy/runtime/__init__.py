"""The deployed pipeline: ONNX Runtime for the network graphs, numpy/numba for the filter
stage, no torch. ``Pipeline`` runs frames; ``jnds run`` (``run``) runs sequences.

- ``reformat``: input layers into the network's layout, sanitized (and packed as u8 for an
  int8 network graph);
- ``network``: a network graph run from float feeds, whatever its edges; ``head``: the int8
  head's u8 output, decoded where the filters read it;
- ``history``: the previous frame's signals warped, cleaned and stored;
- ``filters``: the filter stage (the numpy/numba implementation of ``jnds_deploy.filters``);
- ``config``: ``PipelineConfig`` (cheap to import); ``pipeline``: ``Pipeline``, ``FrameResult``;
- ``run``: ``jnds run``; ``profile``: ONNX Runtime's profiler per network stage.

``Pipeline`` and ``FrameResult`` are imported on first use, so that ``PipelineConfig`` and
``tune_numba`` come without numba and ONNX Runtime (``jnds run`` reads its options first).
"""
import os
import sys

from .config import PipelineConfig

__all__ = ["FrameResult", "Pipeline", "PipelineConfig", "tune_numba"]


def __getattr__(name):
    if name in ("FrameResult", "Pipeline"):
        from . import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def tune_numba() -> None:
    """The process-wide numba settings the runtime is measured and served with. Opt-in:
    the ``jnds`` command calls it for the commands that run the pipeline; an application
    that embeds the runtime may call it before the first frame. A setting the user made
    with a ``NUMBA_*`` environment variable is kept.

    - Threading layer ``threadsafe`` (TBB or GNU OpenMP): numba's ``workqueue`` layer
      aborts the process when two threads run parallel loops at once (the server does).
    - LLVM's SLP vectorizer on (numba leaves it off): the warp loop
      (``filters._warp_rows``) relies on it to turn its 12 per-channel sums into vector
      FMAs (docs/design-notes.md). It changes no result: without fast-math flags it
      reorders no sum. It acts on loops compiled after the call (numba's on-disk cache
      keeps what was compiled before).
    - numba's BLAS probe answered "absent": the first loop numba compiles or loads from its
      cache imports ``numba.np.arraymath``, which imports scipy (where installed) to look
      for BLAS, a tenth of a second of every cold start (docs/performance.md). No runtime
      loop calls BLAS; numba code in the same process that did (``np.dot``) would be refused
      with numba's "scipy is required" error.
    - OpenMP's idle threads spin briefly, then sleep (``heap.brief_openmp_spin``), unless
      the user set ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``. It takes effect only where
      nothing loaded libgomp before the call (torch does, when imported).
    """
    from ..heap import brief_openmp_spin

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
