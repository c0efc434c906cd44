"""Adaptive execution: the exact skips give the full pipeline's output."""
import numpy as np
import pytest

from jnds_deploy.io import open_sequence
from jnds_deploy.runtime.pipeline import Pipeline, PipelineConfig

from ..conftest import SAMPLE


def _run(artifacts, frames, adaptive):
    pipe = Pipeline(PipelineConfig(artifacts=str(artifacts), adaptive=adaptive))
    outs, decisions = [], []
    for i, layers in enumerate(frames):
        outs.append(pipe(layers, camera_cut=i == 0)[0])
        decisions.append(dict(pipe.decisions))
    return outs, decisions


@pytest.mark.parametrize("scene", ["diffuse_only", "specular_only", "static_camera"])
def test_exact_skips_equal_the_full_pipeline(tiny_artifacts, scene):
    seq = open_sequence(SAMPLE)
    frames = [{k: v.copy() for k, v in seq.inputs(i).items()} for i in range(4)]
    for f in frames:
        if scene == "diffuse_only":
            f["specular"][:] = 0
        elif scene == "specular_only":
            f["diffuse"][:] = 0
        else:
            f["motion"][:] = 0
    full, off = _run(tiny_artifacts[0], frames, adaptive=False)
    fast, on = _run(tiny_artifacts[0], frames, adaptive=True)
    assert not any(v for d in off for v in d.values())
    key = {"diffuse_only": "skip_specular", "specular_only": "skip_diffuse", "static_camera": "static"}[scene]
    # static needs a history to reuse: every frame after the first
    assert [d[key] for d in on] == ([False, True, True, True] if scene == "static_camera" else [True] * 4)
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


def test_skip_decision_looks_at_the_history(tiny_artifacts):
    """Specular vanishes from the whole frame: its history is dropped (rejection: nothing
    current supports it) and the path is skipped, exactly; while the current frame still
    has specular somewhere, the path runs."""
    seq = open_sequence(SAMPLE)
    frames = [seq.inputs(0), seq.inputs(1)]
    spec = np.zeros_like(frames[1]["specular"])
    spec[:4, :4] = 1.0  # a little specular left in one corner
    frames.append({**seq.inputs(2), "specular": spec})
    frames.append({**seq.inputs(3), "specular": np.zeros_like(spec)})
    full, _ = _run(tiny_artifacts[0], frames, adaptive=False)
    fast, on = _run(tiny_artifacts[0], frames, adaptive=True)
    assert [d["skip_specular"] for d in on] == [False, False, False, True]
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)
