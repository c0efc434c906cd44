"""Running a network graph: float feeds in, float (or still coded) outputs out, whatever
the graph's precision at its edges.

An int8 network graph from ``jnds calibrate`` starts at the input block's first
convolution (``calibration.inputs``: input ``inputs``, u8 channels last) and ends in the
output block's u8 head (``calibration.head``: output ``head``). ``run_network`` takes the
float ``current`` and ``history`` every graph's users have (the pipeline, calibration,
validation) and returns the outputs by the float graph's names, so that each caller runs
any graph the same way.
"""
from __future__ import annotations

from ..errors import ArtifactError
from ..layout import head_kind
from .head import HEAD, LAYOUT_KEY, Head, HeadLayout
from .reformat import INPUTS, INPUTS_KEY, InputsLayout, pack_inputs


class Edges:
    """What a session's graph needs at its edges, read from its metadata once."""

    def __init__(self, sess):
        self.inputs = self.head = None
        if any(i.name == INPUTS for i in sess.get_inputs()):
            self.inputs = InputsLayout.of_session(sess)
            if self.inputs is None:
                raise ArtifactError(f"network graph has an {INPUTS!r} input but no {INPUTS_KEY!r} metadata")
        if any(o.name == HEAD for o in sess.get_outputs()):
            layout = HeadLayout.of_session(sess)
            if layout is None:
                raise ArtifactError(f"network graph has a {HEAD!r} output but no {LAYOUT_KEY!r} metadata")
            self.head = Head(layout)

    def feeds(self, feeds: dict) -> dict:
        """``feeds`` ({current, history}: float NCHW) as the graph takes them."""
        if self.inputs is None:
            return feeds
        return {INPUTS: pack_inputs(feeds["current"], feeds["history"], self.inputs)}


def edges(sess, cache: dict | None = None) -> Edges:
    """The ``Edges`` of ``sess`` (``cache``: per session, for callers that run it often)."""
    if cache is None:
        return Edges(sess)
    e = cache.get(id(sess))
    if e is None:
        e = cache[id(sess)] = Edges(sess)
    return e


def run_network(sess, feeds: dict, cache: dict | None = None, coded: bool = False) -> dict:
    """Run a network graph's session on float ``feeds`` ({current, history}): {output:
    (N, C, H, W) float32} (N = 1 where the graph has a u8 head), the head (if the graph has
    one) in the outputs it holds: decoded, or with ``coded`` as ``runtime.head.Coded``
    (C, H, W) parts, except the upsample block's features, which ONNX Runtime reads as
    float. ``cache`` keeps each session's ``Edges``."""
    e = edges(sess, cache)
    names = [o.name for o in sess.get_outputs()]
    out = dict(zip(names, sess.run(None, e.feeds(feeds))))
    if e.head is None:
        return out
    q = out.pop(HEAD)
    for name, part in e.head.coded(q).items():
        out[name] = part if coded and head_kind(name) != "relu" else part.decode()[None]
    return out


def output_names(sess) -> list[str]:
    """The outputs ``run_network`` returns for ``sess``, in order."""
    names = [o.name for o in sess.get_outputs()]
    if HEAD not in names:
        return names
    layout = HeadLayout.of_session(sess)
    return [n for n in names if n != HEAD] + [n for n, _ in layout.parts]
