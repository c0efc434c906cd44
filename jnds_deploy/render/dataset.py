"""The project's training and validation sets: fixed lists of render configurations.

``jnds dataset --out data`` renders (or resumes) every sequence; re-running it after an
interruption continues from the last finished frame. Validation seeds never appear in
training.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..errors import ConfigError
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


TRAIN_SEQUENCES = 24  # the training set's default size; seeds 1000, 1001, ...


def dataset_specs(split: str = "all", train_sequences: int = TRAIN_SEQUENCES) -> list[tuple[str, RenderConfig]]:
    """(relative directory, config) of every sequence in a split: train, val or all.

    ``train_sequences`` grows the training set with further seeds (the first 24 are
    always the same sequences); validation seeds (2000+) never overlap it.
    """
    if not 1 <= train_sequences <= 1000:
        raise ConfigError(f"train_sequences must be in 1..1000, got {train_sequences}")
    specs = {
        "train": _specs("train", range(1000, 1000 + train_sequences), frames=12, spp=64),
        "val": _specs("val", range(2000, 2006), frames=12, spp=128),
    }
    if split == "all":
        return specs["train"] + specs["val"]
    if split not in specs:
        raise ConfigError(f"unknown split {split!r}, expected train, val or all")
    return specs[split]


def _render_one(job: tuple[RenderConfig, Path]) -> tuple[Path, dict]:
    from .sequence import render_sequence

    cfg, path = job
    return path, render_sequence(cfg, path)


def render_dataset(out: str | Path, split: str = "all", limit: int | None = None,
                   variant: str | None = None, train_sequences: int = TRAIN_SEQUENCES,
                   jobs: int = 1) -> list[tuple[Path, dict]]:
    """Render every missing sequence of a split; ``jobs`` > 1 renders that many sequences
    at once in separate processes (Mitsuba's Python-side tracing is single-threaded, so
    many cores or a GPU are only kept busy by several sequences at a time)."""
    todo = []
    for rel, cfg in dataset_specs(split, train_sequences)[:limit]:
        if variant:
            cfg = replace(cfg, variant=variant)
        path = Path(out) / rel
        if not (path / "sequence.json").exists():
            todo.append((cfg, path))
    if jobs <= 1 or len(todo) <= 1:
        return [_render_one(job) for job in todo]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    # spawn: a forked child would inherit the parent's Dr.Jit/LLVM/CUDA state
    with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=mp.get_context("spawn")) as pool:
        return list(pool.map(_render_one, todo))
