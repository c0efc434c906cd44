"""Training data in memory: whole sequences as NCHW-ready arrays, and random patches of
consecutive frames drawn from them."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import TrainError
from ..io import find_sequences, open_sequence
from ..layout import CURRENT

REFERENCE_COMPONENTS = ("color", "diffuse", "specular", "albedo")


@dataclass
class SequenceArrays:
    """One sequence in memory, NCHW-ready float32: current (T, 13, H, W) in
    ``layout.CURRENT`` order, motion (T, 2, H, W), reference components (T, 3, sH, sW),
    camera cuts."""

    name: str
    current: np.ndarray
    motion: np.ndarray
    ref: dict[str, np.ndarray]
    cuts: list[bool]

    @property
    def scale(self) -> int:
        return self.ref["color"].shape[-1] // self.current.shape[-1]


def load_sequence(path: str | Path) -> SequenceArrays:
    """A sequence with references in memory: the reference components it has (colour
    always; training needs diffuse, specular and albedo too, ``PatchSampler`` checks)."""
    seq = open_sequence(path)
    present = seq.reference(0) if len(seq) else {}
    cur, mot, refs = [], [], {k: [] for k in REFERENCE_COMPONENTS if k in present}
    for i in range(len(seq)):
        a = seq.inputs(i)
        cur.append(np.concatenate([a[n] for n, _ in CURRENT], -1).transpose(2, 0, 1))
        mot.append(a["motion"].transpose(2, 0, 1))
        r = seq.reference(i)
        for k in refs:
            refs[k].append(r[k].transpose(2, 0, 1))
    return SequenceArrays(Path(path).name, np.stack(cur), np.stack(mot),
                          {k: np.stack(v) for k, v in refs.items()},
                          [f.camera_cut for f in seq.frames])


def load_split(root: str | Path, limit: int | None = None) -> list[SequenceArrays]:
    """Every sequence under ``root`` (e.g. data/train), or TrainError if there is none."""
    paths = find_sequences(root)[:limit]
    if not paths:
        raise TrainError(f"{root}: no sequences found; run `jnds dataset --out {Path(root).parent}` first")
    return [load_sequence(p) for p in paths]


class PatchSampler:
    """Random (sequence, window, crop) samples; windows never cross a camera cut."""

    def __init__(self, seqs: list[SequenceArrays], patch: int, unroll: int, rng: np.random.Generator):
        self.seqs, self.patch, self.unroll, self.rng = seqs, patch, unroll, rng
        for s in seqs:
            if missing := [c for c in REFERENCE_COMPONENTS if c not in s.ref]:
                raise TrainError(f"{s.name}: the reference has no {', '.join(missing)}; training needs every "
                                 "component (the renderers write them)")
        self.windows = []
        for si, s in enumerate(seqs):
            starts = [0] + [t for t, c in enumerate(s.cuts) if c] + [len(s.cuts)]
            for a, b in zip(starts[:-1], starts[1:]):
                self.windows += [(si, t) for t in range(a, b - unroll + 1)]
        if not self.windows:
            raise TrainError(f"no window of {unroll} frames without a cut in the training data")

    def batch(self, n: int, device: str | torch.device = "cpu") -> dict[str, torch.Tensor]:
        """Tensors (T, N, C, H, W): current, motion (native patch), reference color,
        diffuse, specular, albedo (target patch)."""
        out = {k: [] for k in ("current", "motion", *REFERENCE_COMPONENTS)}
        for _ in range(n):
            si, t = self.windows[self.rng.integers(len(self.windows))]
            s = self.seqs[si]
            h, w = s.current.shape[-2:]
            p = self.patch
            y = int(self.rng.integers(0, h - p + 1))
            x = int(self.rng.integers(0, w - p + 1))
            k = s.scale
            sl = slice(t, t + self.unroll)
            out["current"].append(s.current[sl, :, y:y + p, x:x + p])
            out["motion"].append(s.motion[sl, :, y:y + p, x:x + p])
            for c in REFERENCE_COMPONENTS:
                out[c].append(s.ref[c][sl, :, k * y:k * (y + p), k * x:k * (x + p)])
        return {k: torch.from_numpy(np.ascontiguousarray(np.stack(v, 1))).to(device) for k, v in out.items()}
