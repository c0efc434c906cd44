"""The project's training and validation sets: fixed lists of render configurations.

``jnds dataset --out data`` renders (or resumes) every sequence; re-running it after an
interruption continues from the last finished frame. Validation seeds never appear in
training. ``--engine cycles`` renders the Blender Cycles sets (``blender.scenes``: other
scene kinds, other seeds) into the same train/ and val/ directories, named ``cycles-*``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from ..blender.scenes import CYCLES_HOLDOUT_KINDS, CYCLES_TEST_KINDS, CYCLES_TRAIN_KINDS
from ..errors import ConfigError
from .camera import CAMERA_PATHS
from .sequence import ENGINES, RenderConfig

SIZE = (192, 108)
# the Cycles splits made of kinds no training or validation sequence has (blender.scenes)
UNSEEN_KINDS = {"test": CYCLES_TEST_KINDS, **CYCLES_HOLDOUT_KINDS}


def _specs(
    split: str, seeds: range, frames: int, spp: int, engine: str = "mitsuba", kind: str | None = None
) -> list[tuple[str, RenderConfig]]:
    """``kind``: every sequence of this scene kind (else the split's rotation of kinds)."""
    out = []
    for k, seed in enumerate(seeds):
        camera = CAMERA_PATHS[k % len(CAMERA_PATHS)]
        if kind is not None:
            scene = kind
            name = f"cycles-{scene}" if engine == "cycles" else scene
        elif engine == "cycles":
            # the test and holdout splits are made of scene kinds the training and validation sets never have
            if split in UNSEEN_KINDS:
                scene = UNSEEN_KINDS[split][k % len(UNSEEN_KINDS[split])]
            else:
                scene = CYCLES_TRAIN_KINDS[(k // len(CAMERA_PATHS) + k) % len(CYCLES_TRAIN_KINDS)]
            name = f"cycles-{scene}"
        else:
            scene = "diffuse" if k % 8 == 3 else "metal" if k % 8 == 6 else "procedural"
            name = scene
        cfg = RenderConfig(scene=scene, seed=seed, camera=camera, frames=frames, size=SIZE, spp=spp, engine=engine)
        out.append((f"{split}/{name}-{camera}-{seed:04d}", cfg))
    return out


TRAIN_SEQUENCES = 24  # the training set's default size; seeds 1000, 1001, ...
# first seeds of each engine's training, validation and test sequences (never overlapping)
SEEDS = {"mitsuba": (1000, 2000, 8000), "cycles": (5000, 6000, 7000)}
MOVING_SEEDS = 4000  # Mitsuba training sequences of scene kind ``moving`` (objects that move)
# first seeds of the Cycles training-only kinds (blender.scenes.CYCLES_EXTRA_KINDS), added on request
EXTRA_SEEDS = {
    "mixed": 9000,
    "lights": 10000,
    "interior": 11000,
    "detail": 12000,
    "layers": 13000,
    "glass": 14000,
    "print": 15000,
    "media": 16000,
}
# the Cycles held-out splits' first seeds, in the order the splits were written
# (blender.scenes.CYCLES_HOLDOUT_KINDS)
HOLDOUT_SEEDS = {"holdout": 7100, "street-studio": 7200, "grove-haze": 7300, "bathroom-fur": 7400}
# the later held-out splits' old names, "holdout" numbered from 2 in the order they were
# written: still accepted, with a warning
OLD_SPLIT_NAMES = {f"holdout{n}": split for n, split in enumerate(list(HOLDOUT_SEEDS)[1:], start=2)}
SPLITS = ("train", "val", "all", "test", *HOLDOUT_SEEDS, "media")
# the media split: unseen seeds of the training-only kind ``media``, rendered after the albedo
# at holes (docs/model-gap.md) had been chosen on media training sequences, to check that choice
MEDIA_SEEDS = 16100


def dataset_specs(
    split: str = "all",
    train_sequences: int = TRAIN_SEQUENCES,
    engine: str = "mitsuba",
    moving_sequences: int = 0,
    extra_sequences: Mapping[str, int] | None = None,
) -> list[tuple[str, RenderConfig]]:
    """(relative directory, config) of every sequence in a split (``SPLITS``): train, val,
    all (both), test, a held-out split or media.

    ``train_sequences`` grows the training set with further seeds (the first 24 are
    always the same sequences); validation seeds (2000+; Cycles: 6000+) never overlap it.
    ``moving_sequences`` adds Mitsuba training sequences whose objects move (scene kind
    ``moving``, seeds 4000+, ``train/moving-*``); ``extra_sequences`` ({kind: N}) N Cycles
    training sequences of each training-only kind (``EXTRA_SEEDS``: ``mixed`` 9000+,
    ``lights`` 10000+, ``interior`` 11000+, ``detail`` 12000+, ``layers`` 13000+, ``glass`` 14000+,
    ``print`` 15000+, ``media`` 16000+; ``train/cycles-<kind>-*``).
    The test split (8000+; Cycles: 7000+) is rendered only when asked for: it is never
    trained on, and no checkpoint or setting is chosen by it. The held-out splits (Cycles
    only) are the same for two more scene kinds each, each written after the split before
    it had been looked at (``blender.scenes.CYCLES_HOLDOUT_KINDS``): holdout (seeds 7100+),
    street-studio (7200+), grove-haze (7300+) and bathroom-fur (7400+); their old names,
    ``holdout`` numbered from 2 (``OLD_SPLIT_NAMES``), are still accepted, with a warning.
    The media split (Cycles only, seeds 16100+) is six sequences of the training
    kind ``media`` at unseen seeds (``MEDIA_SEEDS``).
    """
    if split in OLD_SPLIT_NAMES:
        warnings.warn(
            f"split {split!r} is now called {OLD_SPLIT_NAMES[split]!r} (and renders into a directory of "
            f"that name); the old name will go",
            FutureWarning,
            stacklevel=2,
        )
        split = OLD_SPLIT_NAMES[split]
    if not 1 <= train_sequences <= 1000:
        raise ConfigError(f"train_sequences must be in 1..1000, got {train_sequences}")
    if not 0 <= moving_sequences <= 1000 or (moving_sequences and engine != "mitsuba"):
        raise ConfigError(f"moving_sequences must be in 0..1000 (Mitsuba only), got {moving_sequences}")
    extra_sequences = dict(extra_sequences or {})
    for kind, n in extra_sequences.items():
        if kind not in EXTRA_SEEDS:
            raise ConfigError(f"unknown training-only kind {kind!r}, expected one of {', '.join(EXTRA_SEEDS)}")
        top = MEDIA_SEEDS - EXTRA_SEEDS["media"] if kind == "media" else 1000  # below the media split's seeds
        if not 0 <= n <= top or (n and engine != "cycles"):
            raise ConfigError(f"{kind} sequences must be in 0..{top} (Cycles only), got {n}")
    if engine not in ENGINES:
        raise ConfigError(f"unknown engine {engine!r}, expected one of {', '.join(ENGINES)}")
    train0, val0, test0 = SEEDS[engine]
    specs = {
        "train": _specs("train", range(train0, train0 + train_sequences), frames=12, spp=64, engine=engine)
        + _specs("train", range(MOVING_SEEDS, MOVING_SEEDS + moving_sequences), frames=12, spp=64, kind="moving")
        + [
            spec
            for kind, n in extra_sequences.items()
            for spec in _specs(
                "train", range(EXTRA_SEEDS[kind], EXTRA_SEEDS[kind] + n), frames=12, spp=64, engine="cycles", kind=kind
            )
        ],
        "val": _specs("val", range(val0, val0 + 6), frames=12, spp=128, engine=engine),
        "test": _specs("test", range(test0, test0 + 6), frames=12, spp=128, engine=engine),
    }
    if engine == "cycles":
        for name, first in HOLDOUT_SEEDS.items():
            specs[name] = _specs(name, range(first, first + 6), frames=12, spp=128, engine=engine)
        specs["media"] = _specs(
            "media", range(MEDIA_SEEDS, MEDIA_SEEDS + 6), frames=12, spp=128, engine=engine, kind="media"
        )
    elif split in HOLDOUT_SEEDS or split == "media":
        raise ConfigError(f"the {split} split is rendered with Cycles only (--engine cycles)")
    if split == "all":
        return specs["train"] + specs["val"]
    if split not in specs:
        raise ConfigError(f"unknown split {split!r}, expected one of {', '.join(SPLITS)}")
    return specs[split]


def _render_one(job: tuple[RenderConfig, Path]) -> tuple[Path, dict]:
    from .sequence import render_sequence

    cfg, path = job
    return path, render_sequence(cfg, path)


def render_dataset(
    out: str | Path,
    split: str = "all",
    limit: int | None = None,
    variant: str | None = None,
    train_sequences: int = TRAIN_SEQUENCES,
    jobs: int = 1,
    engine: str = "mitsuba",
    address: str | None = None,
    progress: bool = True,
    moving_sequences: int = 0,
    extra_sequences: Mapping[str, int] | None = None,
    reference: bool = True,
    reference_spp: int | None = None,
) -> list[tuple[Path, dict]]:
    """Render every missing sequence of a split; ``jobs`` > 1 renders that many sequences
    at once in separate processes (Mitsuba's Python-side tracing is single-threaded, so
    many cores or a GPU are only kept busy by several sequences at a time). ``address``
    (a Ray cluster, or ``local``; ``RAY_ADDRESS`` too) renders them as Ray tasks instead
    (``jnds_deploy.cluster.render_on_ray``). ``reference=False`` renders the inputs only (the
    same inputs as with references, in minutes where the references take hours): what a
    teacher-distilled run trains on (``jnds train --teacher``). ``reference_spp`` renders the
    references at that many samples per target pixel instead of the split's: cheap references
    for ``jnds train --clean-references oidn`` (cleaned, 8 samples stand about as close to
    a full reference as its own cleaned self: docs/dataset.md, "Cheap references"), in a
    directory of their own (``out``)."""
    todo = []
    for rel, cfg in dataset_specs(split, train_sequences, engine, moving_sequences, extra_sequences)[:limit]:
        if variant and engine == "mitsuba":
            cfg = replace(cfg, variant=variant)
        if not reference:
            cfg = replace(cfg, reference=False)
        if reference_spp is not None:
            cfg = replace(cfg, spp=reference_spp)
        path = Path(out) / rel
        if not (path / "sequence.json").exists():
            todo.append((cfg, path))
    if address or os.environ.get("RAY_ADDRESS"):
        from ..cluster import render_on_ray

        return render_on_ray(_render_one, todo, None if address == "local" else address, progress) if todo else []
    if jobs <= 1 or len(todo) <= 1:
        return [_render_one(job) for job in todo]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    # spawn: a forked child would inherit the parent's Dr.Jit/LLVM/CUDA state
    with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=mp.get_context("spawn")) as pool:
        return list(pool.map(_render_one, todo))
