"""Re-render the inputs of Cycles sequences made before stop 55 so their volume pixels get
normals (``jnds_deploy.cycles``: a camera ray that scattered in a volume used to import as
background). The references are kept: Cycles' Denoising Data passes change no other pass
(checked here frame by frame: every input layer but ``normal`` must come out bit-identical,
and ``normal`` may change only where it was 0), so only the 1-spp inputs are rendered again.

    python scripts/reguide_volumes.py data/train/cycles-media-static-16000 ...

Resumable: a sequence's new inputs are rendered under ``<seq>/.reguide`` (Blender skips the
frames on disk), then swapped in file by file; a sequence already done is skipped
(``render.json`` records it). Nothing is replaced when a check fails.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from jnds_deploy.io import open_sequence
from jnds_deploy.render.sequence import RenderConfig, render_sequence

MARK = "volume_normals"  # render.json key: the inputs carry volume normals


def reguide(seq: Path) -> str:
    marker = seq / "render.json"
    meta = json.loads(marker.read_text())
    if meta.get(MARK):
        return "already done"
    cfg = RenderConfig(**{**meta["config"], "size": tuple(meta["config"]["size"]), "reference": False})
    if cfg.engine != "cycles":
        return "not a Cycles render: nothing to do"
    tmp = seq / ".reguide"
    render_sequence(cfg, tmp, progress=False)
    old, new = open_sequence(seq), open_sequence(tmp)
    if [f.jitter for f in old.frames] != [f.jitter for f in new.frames] or len(old) != len(new):
        raise SystemExit(f"{seq}: the re-render's frames or jitter differ; nothing replaced")
    changed = 0
    for i in range(len(old)):
        a, b = old.inputs(i), new.inputs(i)
        for name, v in a.items():
            if name == "normal":
                moved = np.any(v != b[name], axis=-1)
                if np.any(v[moved] != 0):
                    raise SystemExit(f"{seq}: frame {i}: a surface normal changed; nothing replaced")
                changed += int(moved.sum())
            elif not np.array_equal(v, b[name]):
                raise SystemExit(f"{seq}: frame {i}: layer {name} differs from the first render; nothing replaced")
    for p in sorted((tmp / "inputs").iterdir()):
        os.replace(p, seq / "inputs" / p.name)
    marker.write_text(json.dumps({**meta, MARK: True}, indent=1))
    shutil.rmtree(tmp)
    return f"{changed} volume pixels given normals over {len(old)} frames"


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(arg, reguide(Path(arg)), flush=True)
