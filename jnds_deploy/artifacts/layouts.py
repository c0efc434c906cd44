"""The layouts of an int8 network graph's u8 edges, kept as JSON in the graph's own
metadata (the ONNX model's ``metadata_props``): written by ``jnds calibrate``
(``calibration.inputs``, ``calibration.head_ranges``, ``calibration.block``), read by the
runtime (``runtime.network``, ``runtime.reformat``, ``runtime.head``). One graph file
carries what it takes to run it; docs/artifact-format.md describes every key.

- ``INPUTS_KEY`` (``InputsLayout``): the graph's input ``inputs``, the input block's
  preprocessing of current and history quantized, u8, channels last;
- ``HEAD_KEY`` (``HeadLayout``): its output ``head``, the output block's head, u8,
  channels last;
- ``LEVELS_KEY`` ({output: ``HeadLayout``}): the feature extractor's level heads'
  outputs ``<path>.level<k>``, u8 planes;
- ``BLOCK_KEY`` (``BlockLayout``): the graph cut at its upsamplings and concatenations
  into segments, each cut's entry made between their runs.

Numbers in these layouts are (scale, zero point) pairs: value = (q - zero_point) * scale.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import ArtifactError
from ..layout import CURRENT, HISTORY, N_GUIDE, RADIANCE, head_kind

INPUTS = "inputs"  # the u8 input of an int8 network graph (calibration.inputs)
HEAD = "head"  # the u8 output of its output block's head (calibration.head_ranges)
INPUTS_KEY = "jnds.inputs"
HEAD_KEY = "jnds.head"
LEVELS_KEY = "jnds.levels"
BLOCK_KEY = "jnds.block"

# what model.tonemap_inputs does to each channel of current then history: 1 Eq. 1's tonemap
# (radiance), 2 n * 0.5 + 0.5 (normals), 0 nothing; a network with the guide albedo input
# reads its channels after them, as they are (``preprocess``)
_PREPROCESS = np.array(
    [
        1 if n in RADIANCE else 2 if n == "normal" else 0
        for layout in (CURRENT, HISTORY)
        for n, c in layout
        for _ in range(c)
    ],
    np.int64,
)
_GUIDED = np.append(_PREPROCESS, np.zeros(N_GUIDE, np.int64))


def preprocess(channels: int) -> np.ndarray:
    """``_PREPROCESS`` for a projection of ``channels`` inputs: current and history's, and
    the guide albedo's after them where it reads one; or each of those four times, the 2x2
    pixels of a space-to-depth input block (``model.InputBlock``), channel c's as 4c..4c+3."""
    for kinds in (_PREPROCESS, _GUIDED):
        for block in (1, 2):
            if channels == len(kinds) * block * block:
                return np.repeat(kinds, block * block)
    raise ArtifactError(
        f"an input projection reads {len(_PREPROCESS)} channels (current, history) or "
        f"{len(_GUIDED)} (and the guide albedo), or 4x either (in 2x2 blocks), not {channels}"
    )


def _metadata(sess, key: str) -> str | None:
    """The metadata ``key`` of an ONNX Runtime session's graph, or None."""
    return sess.get_modelmeta().custom_metadata_map.get(key)


class _Kept:
    """A layout kept as JSON (``to_json``, ``from_json``) under ``KEY`` in a graph's metadata."""

    KEY: ClassVar[str]

    @classmethod
    def of_session(cls, sess):
        """The layout of an ONNX Runtime session's graph, or None where it has none (the
        graph does not have that u8 edge)."""
        text = _metadata(sess, cls.KEY)
        return None if text is None else cls.from_json(text)


@dataclass(frozen=True)
class InputsLayout(_Kept):
    """The u8 ``inputs`` of an int8 network graph: value = (q - zero_point) * scale."""

    KEY: ClassVar[str] = INPUTS_KEY

    scale: float
    zero_point: int
    channels: int  # current and history's (and the guide albedo's), then padding
    # the channel of ``inputs`` each of current and history's (and the guide albedo's) channels
    # goes to; the others are padding. Empty: current and history's in order, the padding last.
    # calibration.inputs chooses it so that no two neighbours can overflow the 16-bit sums of
    # AVX2's u8 x s8 multiply (calibration.inputs.safe_slots says why)
    slots: tuple[int, ...] = ()
    # 2: a space-to-depth input block's (model.InputBlock): each 2x2 block of pixels is one
    # pixel of ``inputs`` (1, H/2, W/2, channels), channel c's four pixels (row-major) the
    # inputs 4c..4c+3 that ``slots`` places
    block: int = 1

    def __post_init__(self):
        object.__setattr__(self, "slots", tuple(int(c) for c in self.slots))

    @property
    def order(self) -> np.ndarray:
        """``slots``, or the identity where empty."""
        return np.array(self.slots or range(len(_PREPROCESS) * self.block**2), np.int64)

    @property
    def guided(self) -> bool:
        """The graph reads the guide albedo (after current and history)."""
        return len(self.order) == len(_GUIDED) * self.block**2

    def to_json(self) -> str:
        return json.dumps(
            {
                "scale": self.scale,
                "zero_point": self.zero_point,
                "channels": self.channels,
                "slots": list(self.slots),
                "block": self.block,
            }
        )

    @classmethod
    def from_json(cls, text: str) -> InputsLayout:
        try:
            d = json.loads(text)
            layout = cls(
                float(d["scale"]),
                int(d["zero_point"]),
                int(d["channels"]),
                tuple(d.get("slots", ())),
                int(d.get("block", 1)),
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise ArtifactError(f"inputs metadata {INPUTS_KEY!r} malformed ({exc!r})") from exc
        order = layout.order
        if (
            layout.channels < len(order)
            or not layout.scale > 0
            or not 0 <= layout.zero_point <= 255
            or layout.block not in (1, 2)
            or len(order) not in (len(_PREPROCESS) * layout.block**2, len(_GUIDED) * layout.block**2)
            or len(set(order.tolist())) != len(order)
            or not (0 <= order.min() and order.max() < layout.channels)
        ):
            raise ArtifactError(f"inputs metadata {INPUTS_KEY!r}: {layout}")
        return layout


@dataclass(frozen=True)
class HeadLayout(_Kept):
    """Where each output lies in a u8 head (the output block's, or a level head's) and how
    it dequantizes: channel c of output ``name`` holds ``raw = (q - zero_point) * scale[c] +
    centre[c]``, the head's float output, to which ``layout.head_kind(name)`` applies as in
    ``model.OutputBlock``."""

    KEY: ClassVar[str] = HEAD_KEY

    parts: tuple[tuple[str, int], ...]  # (network output, channels), in channel order
    scale: tuple[float, ...]  # per channel (padding excluded): raw = (q - zero_point) * scale + centre
    centre: tuple[float, ...]
    zero_point: int
    channels: int  # of the tensor, padding included

    def __post_init__(self):
        used = sum(n for _, n in self.parts)
        if (
            used != len(self.scale)
            or used != len(self.centre)
            or used > self.channels
            or not 0 <= self.zero_point <= 255
        ):
            raise ArtifactError(
                f"head layout: {used} channels in parts, {len(self.scale)} scales, "
                f"{len(self.centre)} centres, {self.channels} in the tensor, "
                f"zero point {self.zero_point}"
            )
        bad = [n for n, c in self.parts if head_kind(n) == "normalized" and c != 9]
        if bad:  # the runtime's decoding (runtime.head.decode_row) normalizes 3x3 kernels
            raise ArtifactError(f"head layout: normalized kernel(s) {', '.join(bad)} without 9 taps")

    def to_dict(self) -> dict:
        return {
            "parts": [list(p) for p in self.parts],
            "scale": list(self.scale),
            "centre": list(self.centre),
            "zero_point": self.zero_point,
            "channels": self.channels,
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str) -> HeadLayout:
        try:
            return cls.from_dict(json.loads(text))
        except ValueError as exc:
            raise ArtifactError(f"head layout metadata {HEAD_KEY!r} malformed ({exc!r})") from exc

    @classmethod
    def from_dict(cls, d: dict) -> HeadLayout:
        """The layout from its JSON object (``to_dict``'s)."""
        try:
            return cls(
                tuple((str(n), int(c)) for n, c in d["parts"]),
                tuple(float(s) for s in d["scale"]),
                tuple(float(s) for s in d["centre"]),
                int(d["zero_point"]),
                int(d["channels"]),
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise ArtifactError(f"head layout metadata {HEAD_KEY!r} malformed ({exc!r})") from exc


def levels_to_json(layouts: dict[str, HeadLayout]) -> str:
    """``LEVELS_KEY``'s value: {graph output: layout}."""
    return json.dumps({h: lay.to_dict() for h, lay in layouts.items()})


def levels_of_session(sess) -> dict[str, HeadLayout]:
    """{graph output: layout} of a session's u8 level heads (none if it has none)."""
    text = _metadata(sess, LEVELS_KEY)
    if text is None:
        return {}
    try:
        return {str(k): HeadLayout.from_dict(v) for k, v in json.loads(text).items()}
    except (ValueError, AttributeError, ArtifactError) as exc:
        raise ArtifactError(f"level head metadata {LEVELS_KEY!r} malformed ({exc!r})") from exc


@dataclass(frozen=True)
class Cut:
    """One concatenation of a 2x upsampling with a skip connection cut out of the graph:
    its outputs ``up`` (the features to upsample) and ``skip`` (u8, channels last) become
    its input ``entry``, concat(bilinear 2x upsampling of up, skip), requantized. Each
    (scale, zero point): value = (q - zero_point) * scale."""

    entry: str
    up: str
    skip: str
    up_q: tuple[float, int]
    skip_q: tuple[float, int]
    entry_q: tuple[float, int]
    stage: str = ""  # the paper's stage it belongs to (runtime.profile.STAGES)
    # 2: ``skip`` holds the native features as 2x2 phases at half resolution, (1, H/2, W/2,
    # 4 Cs), channel c's pixel (2y + py, 2x + px) at (2py + px) Cs + c, phase first (a
    # space-to-depth input block's, model.InputBlock, ordered so by calibration.block): the
    # runtime's pass that makes the entry (runtime.reformat.block_input) does the depth-to-space
    skip_phases: int = 1


@dataclass(frozen=True)
class BlockLayout(_Kept):
    """An int8 network graph cut at upsamplings and concatenations (``calibration.block``,
    its ``CUT_AT``): ``segments`` in the order they run, each (the input it is fed, the graph
    outputs it computes), and the ``cuts``."""

    KEY: ClassVar[str] = BLOCK_KEY

    cuts: tuple[Cut, ...]
    segments: tuple[tuple[str, tuple[str, ...]], ...]

    def to_json(self) -> str:
        return json.dumps(
            {
                "cuts": [
                    {
                        "entry": c.entry,
                        "up": c.up,
                        "skip": c.skip,
                        "up_q": list(c.up_q),
                        "skip_q": list(c.skip_q),
                        "entry_q": list(c.entry_q),
                        "stage": c.stage,
                        "skip_phases": c.skip_phases,
                    }
                    for c in self.cuts
                ],
                "segments": [[e, list(o)] for e, o in self.segments],
            }
        )

    @classmethod
    def from_json(cls, text: str) -> BlockLayout:
        try:
            d = json.loads(text)
            cuts = tuple(
                Cut(
                    str(c["entry"]),
                    str(c["up"]),
                    str(c["skip"]),
                    *((float(c[k][0]), int(c[k][1])) for k in ("up_q", "skip_q", "entry_q")),
                    str(c.get("stage", "")),
                    int(c.get("skip_phases", 1)),
                )
                for c in d["cuts"]
            )
            layout = cls(cuts, tuple((str(e), tuple(str(n) for n in o)) for e, o in d["segments"]))
        except (ValueError, KeyError, TypeError, IndexError) as exc:
            raise ArtifactError(f"block metadata {BLOCK_KEY!r} malformed ({exc!r})") from exc
        entries = [e for e, _ in layout.segments]
        made = {n for _, o in layout.segments for n in o}
        if (
            entries[:1] != [INPUTS]
            or sorted(entries[1:]) != sorted(c.entry for c in layout.cuts)
            or not all({c.up, c.skip} <= made and c.skip_phases in (1, 2) for c in layout.cuts)
            or not all(s > 0 and 0 <= z <= 255 for c in layout.cuts for s, z in (c.up_q, c.skip_q, c.entry_q))
        ):
            raise ArtifactError(f"block metadata {BLOCK_KEY!r}: {layout}")
        return layout

    @property
    def internal(self) -> set[str]:
        """The outputs the cuts are made from (not the network's)."""
        return {n for c in self.cuts for n in (c.up, c.skip)}
