"""The deployed pipeline: ONNX Runtime for the network graphs, numpy/numba for the filter
stage, no torch. ``Pipeline`` runs frames; ``jnds run`` (``run``) runs sequences.

- ``reformat``: input layers into the network's layout, sanitized (and packed as u8 for an
  int8 network graph);
- ``network``: a network graph run from float feeds, whatever its edges; ``head``: the int8
  head's u8 output, decoded where the filters read it;
- ``history``: the previous frame's signals warped, cleaned and stored;
- ``filters``: the filter stage (the numpy/numba implementation of ``jnds_deploy.filter_spec``);
- ``config``: ``PipelineConfig`` (cheap to import); ``pipeline``: ``Pipeline``, ``FrameResult``;
- ``run``: ``jnds run``; ``profile``: ONNX Runtime's profiler per network stage.

``Pipeline`` and ``FrameResult`` are imported on first use, so that ``PipelineConfig`` and
``tune_numba`` come without numba and ONNX Runtime (``jnds run`` reads its options first).
``tune_numba`` is ``jnds_deploy.process.tune_numba``: the runtime changes no process-wide
setting unless asked (``jnds_deploy.process``).
"""

from ..process import tune_numba
from .config import PipelineConfig

__all__ = ["FrameResult", "Pipeline", "PipelineConfig", "tune_numba"]


def __getattr__(name):
    if name in ("FrameResult", "Pipeline"):
        from . import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
