"""The project's training and validation sets: fixed lists of render configurations.

``jnds dataset --out data`` renders (or resumes) every sequence; re-running it after an
interruption continues from the last finished frame. Validation seeds never appear in
training.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from .camera import CAMERA_PATHS
from .sequence import RenderConfig

SIZE = (192, 108)


def _specs(split: str, seeds: range, frames: int, spp: int) -> list[tuple[str, RenderConfig]]:
    out = []
    for k, seed in enumerate(seeds):
        camera = CAMERA_PATHS[k % len(CAMERA_PATHS)]
        scene = "diffuse" if k % 8 == 3 else "metal" if k % 8 == 6 else "procedural"
        cfg = RenderConfig(scene=scene, seed=seed, camera=camera, frames=frames, size=SIZE, spp=spp)
        out.append((f"{split}/{scene}-{camera}-{seed:04d}", cfg))
    return out


def dataset_specs(split: str = "all") -> list[tuple[str, RenderConfig]]:
    """(relative directory, config) of every sequence in a split: train, val or all."""
    specs = {
        "train": _specs("train", range(1000, 1024), frames=12, spp=64),
        "val": _specs("val", range(2000, 2006), frames=12, spp=128),
    }
    if split == "all":
        return specs["train"] + specs["val"]
    if split not in specs:
        raise ValueError(f"unknown split {split!r}, expected train, val or all")
    return specs[split]


def render_dataset(out: str | Path, split: str = "all", limit: int | None = None,
                   variant: str | None = None) -> list[tuple[Path, dict]]:
    from .sequence import render_sequence

    done = []
    for rel, cfg in dataset_specs(split)[:limit]:
        if variant:
            cfg = replace(cfg, variant=variant)
        path = Path(out) / rel
        if (path / "sequence.json").exists():
            continue
        done.append((path, render_sequence(cfg, path)))
    return done
