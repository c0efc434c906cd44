"""Running a network graph: float feeds in, float (or still coded) outputs out, whatever
the graph's precision at its edges.

An int8 network graph from ``jnds calibrate`` starts at the input block's first
convolution (``calibration.inputs``: input ``inputs``, u8 channels last) and ends in the
output block's u8 head (``calibration.head_ranges``: output ``head``), and the feature extractor's
level heads in u8 planes (outputs ``<path>.level<k>``). ``run_network`` takes the
float ``current`` and ``history`` every graph's users have (the pipeline, calibration,
validation) and returns the outputs by the float graph's names, so that each caller runs
any graph the same way. The layouts of those u8 edges are in each graph's metadata
(``artifacts.layouts``). A graph cut at its upsamplings and concatenations
(``calibration.block``) runs in segments of its one session, one run each: each cut's
upsampling and concatenation in numba (``reformat.block_input``) between the run that made
its two u8 tensors and the run it feeds.
"""

from __future__ import annotations

from ..artifacts.layouts import (
    BLOCK_KEY,
    HEAD,
    HEAD_KEY,
    INPUTS,
    INPUTS_KEY,
    LEVELS_KEY,
    BlockLayout,
    HeadLayout,
    InputsLayout,
    levels_of_session,
)
from ..errors import ArtifactError
from ..layout import head_kind
from .head import Head
from .reformat import block_input, pack_inputs


class Edges:
    """What a session's graph needs at its edges, read from its metadata once."""

    def __init__(self, sess):
        self.inputs = self.head = None
        # a cut graph has an entry per segment, each an input with a default (an overridable
        # initializer), so that each can be run without feeding the others
        names = {i.name for i in sess.get_inputs()} | {i.name for i in sess.get_overridable_initializers()}
        if INPUTS in names:
            self.inputs = InputsLayout.of_session(sess)
            if self.inputs is None:
                raise ArtifactError(f"network graph has an {INPUTS!r} input but no {INPUTS_KEY!r} metadata")
        outputs = [o.name for o in sess.get_outputs()]
        if HEAD in outputs:
            layout = HeadLayout.of_session(sess)
            if layout is None:
                raise ArtifactError(f"network graph has a {HEAD!r} output but no {HEAD_KEY!r} metadata")
            self.head = Head(layout)
        self.levels = {n: Head(lay) for n, lay in levels_of_session(sess).items()}
        if set(self.levels) - set(outputs):
            raise ArtifactError(
                f"network graph's {LEVELS_KEY!r} metadata names outputs it lacks: "
                f"{sorted(set(self.levels) - set(outputs))}"
            )
        self.block = BlockLayout.of_session(sess)
        if self.block is not None:
            made = [n for _, o in self.block.segments for n in o]
            if {e for e, _ in self.block.segments} - names or sorted(made) != sorted(outputs):
                raise ArtifactError(
                    f"network graph's {BLOCK_KEY!r} metadata does not match its inputs "
                    f"{sorted(names)} and outputs {outputs}"
                )
        # what run returns: every output but the ones the cuts are made from
        self.outputs = [n for n in outputs if n not in self.block.internal] if self.block else outputs

    def feeds(self, feeds: dict) -> dict:
        """``feeds`` ({current, history} and perhaps guide: float NCHW) as the graph takes them."""
        if self.inputs is None:
            return feeds
        return {INPUTS: pack_inputs(feeds["current"], feeds["history"], self.inputs, feeds.get("guide"))}

    def run(self, sess, feeds: dict, internal: bool = False) -> dict:
        """The graph on ``feeds`` as it takes them (``feeds``): {output: array} for
        ``self.outputs``, segment by segment where the graph is cut (with ``internal``, the
        tensors the cuts are made from kept too)."""
        if self.block is None:
            return dict(zip(self.outputs, sess.run(None, feeds)))
        cuts = {c.entry: c for c in self.block.cuts}
        out: dict = {}
        for entry, names in self.block.segments:
            if entry == INPUTS:
                feed = feeds
            else:
                c = cuts[entry]
                up, skip = (out[c.up], out[c.skip]) if internal else (out.pop(c.up), out.pop(c.skip))
                feed = {entry: block_input(up, skip, c)}
            out.update(zip(names, sess.run(list(names), feed)))
        return out


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
    (N, C, H, W) float32} (N = 1 where the graph has u8 heads), the heads (if the graph has
    them) in the outputs they hold: decoded, or with ``coded`` as ``runtime.head.Coded``
    (C, H, W) parts, except the upsample block's features, which ONNX Runtime reads as
    float. ``cache`` keeps each session's ``Edges``."""
    e = edges(sess, cache)
    out = e.run(sess, e.feeds(feeds))
    parts = {}
    if e.head is not None:
        parts.update(e.head.coded(out.pop(HEAD)))
    for name, head in e.levels.items():
        parts.update(head.planar(out.pop(name)))
    for name, part in parts.items():
        out[name] = part if coded and head_kind(name) != "relu" else part.decode()[None]
    return out


def output_names(sess) -> list[str]:
    """The outputs ``run_network`` returns for ``sess``, in order."""
    e = Edges(sess)
    heads = {**({HEAD: e.head} if e.head is not None else {}), **e.levels}
    return [n for n in e.outputs if n not in heads] + [p for h in heads.values() for p, _ in h.layout.parts]


def quiet(opts=None):
    """``opts`` (new ones if None) with ONNX Runtime's log at errors: a cut graph has inputs
    with defaults, and ONNX Runtime warns at every session it creates that they are not
    constant, which is what they are for (``calibration.block``)."""
    import onnxruntime as ort

    opts = opts or ort.SessionOptions()
    opts.log_severity_level = 3
    return opts
