from pathlib import Path

import numpy as np
import pytest

from jnds_deploy.io import FrameInfo, SequenceWriter, open_sequence
from jnds_deploy.runtime import tune_numba

# the numba settings `jnds run` and `jnds serve` opt into (the server tests run streams
# concurrently, which numba's default threading layer may not survive)
tune_numba()

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "orbit-160x90"


def assert_same_sequences(a_root: Path, b_root: Path, rels, reference: bool = True) -> None:
    """The sequences ``rels`` under both roots hold the same inputs and (``reference``)
    reference colour, bit for bit."""
    for rel in rels:
        a, b = open_sequence(a_root / rel), open_sequence(b_root / rel)
        assert len(a) == len(b), rel
        for i in range(len(a)):
            for k, v in a.inputs(i).items():
                np.testing.assert_array_equal(b.inputs(i)[k], v, err_msg=f"{rel} frame {i} {k}")
            if reference:
                np.testing.assert_array_equal(b.reference(i)["color"], a.reference(i)["color"])


def random_inputs(rng: np.random.Generator, w: int, h: int) -> dict:
    n = rng.normal(size=(h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return {
        "diffuse": rng.exponential(1.0, (h, w, 3)).astype(np.float32),
        "specular": rng.exponential(0.5, (h, w, 3)).astype(np.float32) * 100,
        "albedo": rng.random((h, w, 3)).astype(np.float32),
        "normal": n,
        "roughness": rng.random((h, w, 1)).astype(np.float32),
        "motion": rng.normal(scale=3, size=(h, w, 2)).astype(np.float32),
        "depth": rng.random((h, w, 1)).astype(np.float32) * 10,
    }


def random_reference(rng: np.random.Generator, w: int, h: int) -> dict:
    return {"color": rng.random((h, w, 3)).astype(np.float32) * 4, "albedo": rng.random((h, w, 3)).astype(np.float32)}


@pytest.fixture
def make_sequence(tmp_path):
    """Write a small random sequence; returns (path, inputs, references)."""

    def make(frames=3, size=(7, 5), reference=True, name="seq"):
        rng = np.random.default_rng(0)
        w, h = size
        path = tmp_path / name
        writer = SequenceWriter(path, size, (2 * w, 2 * h) if reference else None)
        ins, refs = [], []
        for i in range(frames):
            ins.append(random_inputs(rng, w, h))
            writer.write_inputs(i, ins[-1])
            if reference:
                refs.append(random_reference(rng, 2 * w, 2 * h))
                writer.write_reference(i, refs[-1])
        infos = [FrameInfo(i, (0.25, -0.125), i == 2) for i in range(frames)]
        writer.close(infos)
        return path, ins, refs

    return make


def _tiny_artifacts(tmp_path_factory, **config):
    import torch

    from jnds_deploy.export import ExportConfig, export
    from jnds_deploy.model import JNDS, ModelConfig

    d = tmp_path_factory.mktemp("artifacts")
    torch.manual_seed(1)
    model = JNDS(ModelConfig.preset("tiny", **config))
    for name, p in model.named_parameters():
        if "head" in name or name == "upsample_block.fixed":
            p.data += 0.3 * torch.randn_like(p)
    ckpt = d / "tiny.pt"
    torch.save(
        {
            "model": model.state_dict(),
            "model_config": model.cfg.__dict__,
            "train_config": {},
            "quantized": False,
            "quant_ranges": None,
            "state": {},
        },
        ckpt,
    )
    export(ExportConfig(checkpoint=str(ckpt), out=str(d / "a")), log=lambda s: None)
    return d / "a", model


def guided_copy(src: Path, dst: Path) -> Path:
    """A copy of sequence ``src`` whose frames have the guide albedo layer
    (``denoising_albedo``, what Cycles writes): 1 - albedo, unlike the albedo everywhere."""
    seq = open_sequence(src)
    writer = SequenceWriter(dst, seq.native_size, seq.target_size)
    for i in range(len(seq)):
        layers = dict(seq.inputs(i))
        layers["denoising_albedo"] = (1.0 - layers["albedo"]).astype(np.float32)
        writer.write_inputs(i, layers)
        if seq.has_reference:
            writer.write_reference(i, seq.reference(i))
    writer.close(seq.frames)
    return dst


@pytest.fixture(scope="session")
def guided_sample(tmp_path_factory):
    """The bundled sample with a guide albedo layer (``guided_copy``)."""
    return guided_copy(SAMPLE, tmp_path_factory.mktemp("guided") / "orbit-guided")


@pytest.fixture(scope="session")
def tiny_artifacts_guided(tmp_path_factory):
    """The same as ``tiny_artifacts`` for a network that reads the guide albedo."""
    return _tiny_artifacts(tmp_path_factory, guide_albedo=True)


@pytest.fixture(scope="session")
def tiny_artifacts_s2d(tmp_path_factory):
    """The same as ``tiny_artifacts`` for a network with the space-to-depth input block."""
    return _tiny_artifacts(tmp_path_factory, input_block="space_to_depth", input_hidden=8)


@pytest.fixture(scope="session")
def tiny_artifacts(tmp_path_factory):
    """fp32 artifacts of a randomly initialized `tiny` model (heads perturbed away from the
    identity init so every path matters), and the model."""
    return _tiny_artifacts(tmp_path_factory)


@pytest.fixture(scope="session")
def tiny_artifacts_root4(tmp_path_factory):
    """The same with ``upsample_root=4``."""
    return _tiny_artifacts(tmp_path_factory, upsample_root=4)


@pytest.fixture(scope="session")
def tiny_artifacts_fixed(tmp_path_factory):
    """The same with one learned upsample kernel for every pixel (no upsample graph)."""
    return _tiny_artifacts(tmp_path_factory, upsample_root=4, upsample_width=0, upsample_features=0)


@pytest.fixture(scope="session")
def shipped_artifacts(tmp_path_factory):
    """The shipped checkpoint exported and calibrated as the packaged artifacts are
    (``tools.package_artifacts.build``: qat, three frames of the sample): what the README
    and the benchmarks run on."""
    from tools.package_artifacts import build

    return build(tmp_path_factory.mktemp("shipped-artifacts"))
