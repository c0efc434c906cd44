"""``jnds render --engine cycles``: one sequence rendered by Blender Cycles, in
Blender's own environment (``.venv-blender``: bpy pins numpy < 2, so it cannot share
this one), then imported into ``jnds-sequence/1``.

The scene is built by ``jnds_deploy.blender.scenes`` (procedural kinds unlike the Mitsuba
ones), set up by ``jnds_deploy.blender.configure`` and rendered frame by frame into
``<out>/.cycles/raw`` (and ``ref``); ``jnds_deploy.blender.importer`` imports them and the raw
frames are deleted. An interrupted render resumes: Blender skips the frames on disk.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..errors import RenderError

ROOT = Path(__file__).resolve().parents[2]  # the directory holding jnds_deploy/
BLENDER_ENV = "JNDS_BLENDER_PYTHON"  # the Python that has bpy; default .venv-blender/bin/python


def blender_python() -> Path:
    """The Python interpreter of the Blender environment, or RenderError saying how to make one."""
    path = Path(os.environ.get(BLENDER_ENV) or ROOT / ".venv-blender" / "bin" / "python")
    if not path.is_file():
        raise RenderError(
            f"{path}: no Blender environment; `make setup` (tools/setup.sh) creates "
            f".venv-blender with bpy==5.0.1, or point {BLENDER_ENV} at a Python that has bpy"
        )
    return path


def scene_job(cfg) -> dict:
    """What ``blender.scenes`` is given of a ``RenderConfig``: the scene's kind, seed, camera
    path, frames, size, samples and scale."""
    return {
        "scene": cfg.scene,
        "seed": cfg.seed,
        "camera": cfg.camera,
        "frames": cfg.frames,
        "size": list(cfg.size),
        "spp": cfg.spp,
        "scale": cfg.scale,
    }


def render_sequence(cfg, out: str | Path, progress: bool = True) -> dict:
    """Render ``cfg`` (a ``RenderConfig`` with engine ``cycles``) into ``out``; returns the
    median seconds per frame of the inputs and the reference."""
    from tqdm import tqdm

    from .importer import import_cycles

    out = Path(out)
    work = out / ".cycles"
    marker = out / "render.json"
    config = json.loads(json.dumps(asdict(cfg)))
    if marker.exists() and json.loads(marker.read_text()).get("config") != config:
        raise RenderError(f"{out}: holds a render of another configuration; use a new --out")
    out.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps({"config": config, "engine": "cycles"}, indent=1))
    cmd = [str(blender_python()), "-m", "jnds_deploy.blender.scenes", json.dumps(scene_job(cfg)), str(work / "raw")]
    if cfg.reference:
        cmd.append(str(work / "ref"))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    times: dict[str, list[float]] = {"inputs": [], "reference": []}
    tail: list[str] = []
    total = cfg.frames * (2 if cfg.reference else 1)
    with (
        subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) as proc,
        tqdm(total=total, desc=f"render {out.name} (cycles)", unit="frame", disable=not progress) as bar,
    ):
        for line in proc.stdout:
            tail = (tail + [line.rstrip()])[-20:]
            if line.startswith("jnds-frame "):
                _, label, _, seconds = line.split()
                if seconds != "skipped":
                    times[label].append(float(seconds))
                bar.update(1)
    if proc.returncode != 0:
        raise RenderError(f"{out}: Blender exited with {proc.returncode}:\n" + "\n".join(tail))
    import_cycles(work / "raw", out, work / "ref" if cfg.reference else None, progress=False)
    shutil.rmtree(work)
    return {k: float(np.median(v)) if v else None for k, v in times.items()}
