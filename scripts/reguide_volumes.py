"""Bring Cycles sequences made before stop 55 to the import's volume pixels
(``jnds_deploy.cycles``: a camera ray that scattered in a volume used to import as
background), in two steps, each recorded in ``render.json`` and skipped once done:

1. ``volume_normals``: the inputs rendered again so volume pixels get normals. The
   references are kept: Cycles' Denoising Data passes change no other pass (checked here
   frame by frame: every input layer but ``normal`` and ``motion`` must come out
   bit-identical, ``normal`` may change only where it was 0, ``motion`` only where a volume
   pixel's normal did).
2. ``volume_motion``: volume pixels take the motion of the surfaces around them
   (``cycles.volume_motion``), from the stored layers: a volume pixel is one with depth 0
   and a normal, a surface one with depth > 0.

    python scripts/reguide_volumes.py data/train/cycles-media-static-16000 ...

Resumable: a sequence's new inputs are rendered under ``<seq>/.reguide`` (Blender skips the
frames on disk), then swapped in file by file. Nothing is replaced when a check fails.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from jnds_deploy.cycles import volume_motion
from jnds_deploy.io import SequenceWriter, open_sequence
from jnds_deploy.render.sequence import RenderConfig, render_sequence

MARK = "volume_normals"  # render.json key: the inputs carry volume normals
MOTION = "volume_motion"  # render.json key: their volume pixels carry the surfaces' motion


def _volume(layers) -> np.ndarray:
    """(H, W) bool: the volume pixels of imported layers, those with a normal but no depth
    (before stop 55 such a pixel had no normal)."""
    return (layers["depth"][..., 0] == 0) & np.any(layers["normal"] != 0, axis=-1)


def reguide(seq: Path) -> str:
    marker = seq / "render.json"
    meta = json.loads(marker.read_text())
    if meta.get(MARK):
        return "already done"
    cfg = RenderConfig(**{**meta["config"], "size": tuple(meta["config"]["size"]), "reference": False})
    if cfg.engine != "cycles":
        return "not a Cycles render: nothing to do"
    first = open_sequence(seq)
    if any(_volume(first.inputs(i)).any() for i in range(len(first))):
        # before stop 55 a pixel without depth had no normal: this import already gave them
        marker.write_text(json.dumps({**meta, MARK: True}, indent=1))
        return "rendered with volume normals"
    tmp = seq / ".reguide"
    render_sequence(cfg, tmp, progress=False)
    old, new = open_sequence(seq), open_sequence(tmp)
    if [f.jitter for f in old.frames] != [f.jitter for f in new.frames] or len(old) != len(new):
        raise SystemExit(f"{seq}: the re-render's frames or jitter differ; nothing replaced")
    changed = 0
    for i in range(len(old)):
        a, b = old.inputs(i), new.inputs(i)
        moved = np.any(a["normal"] != b["normal"], axis=-1)
        for name, v in a.items():
            if name == "normal":
                if np.any(v[moved] != 0):
                    raise SystemExit(f"{seq}: frame {i}: a surface normal changed; nothing replaced")
                changed += int(moved.sum())
            elif name == "motion" and np.array_equal(v[~moved], b[name][~moved]):
                continue  # the new import fills volume pixels' motion (step 2's)
            elif not np.array_equal(v, b[name]):
                raise SystemExit(f"{seq}: frame {i}: layer {name} differs from the first render; nothing replaced")
    for p in sorted((tmp / "inputs").iterdir()):
        os.replace(p, seq / "inputs" / p.name)
    marker.write_text(json.dumps({**meta, MARK: True, MOTION: True}, indent=1))
    shutil.rmtree(tmp)
    return f"{changed} volume pixels given normals and motion over {len(old)} frames"


def remotion(seq: Path) -> str:
    marker = seq / "render.json"
    meta = json.loads(marker.read_text())
    if meta.get(MOTION):
        return "motion already done"
    if not meta.get(MARK):
        raise SystemExit(f"{seq}: no volume normals yet (step 1)")
    old = open_sequence(seq)
    tmp = seq / ".remotion"
    writer = SequenceWriter(tmp, old.native_size)
    filled = 0
    for i in range(len(old)):
        layers = old.inputs(i)
        volume = _volume(layers)
        layers["motion"] = volume_motion(layers["motion"], volume, layers["depth"][..., 0] > 0)
        filled += int((volume & np.any(layers["motion"] != 0, axis=-1)).sum())
        writer.write_inputs(i, layers)
    for p in sorted((tmp / "inputs").iterdir()):
        os.replace(p, seq / "inputs" / p.name)
    marker.write_text(json.dumps({**meta, MOTION: True}, indent=1))
    shutil.rmtree(tmp)
    return f"{filled} volume pixels given motion over {len(old)} frames"


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(arg, reguide(Path(arg)), remotion(Path(arg)), flush=True)
