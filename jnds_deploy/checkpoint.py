"""Checkpoints: a model from a training or shipped checkpoint, the shipped one's path,
and shipping (a training checkpoint stripped to what inference needs).

A checkpoint is a ``torch.save`` dict: ``model`` (state dict), ``model_config``
(``ModelConfig`` fields), ``train_config``, ``quantized`` (QAT-trained: fake
quantization on), ``quant_ranges`` (the learned activation ranges), ``state`` (step,
phase), ``train_sequences``; a training checkpoint adds ``optimizer`` and ``rng``.
"""

from __future__ import annotations

from pathlib import Path

from .errors import CheckpointError

SHIPPED = Path(__file__).parent / "checkpoints" / "jnds.pt"


def default_checkpoint() -> Path:
    """The QAT checkpoint shipped inside the package."""
    if not SHIPPED.exists():
        raise CheckpointError(SHIPPED, "no shipped checkpoint in this install; pass --checkpoint")
    return SHIPPED


def read_checkpoint(path: str | Path, map_location="cpu") -> dict:
    """The checkpoint dict at ``path``, or CheckpointError naming the file."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(path, "no such checkpoint")
    try:
        data = torch.load(path, weights_only=False, map_location=map_location)
    except Exception as exc:  # torch raises pickle, zip and runtime errors for a bad file
        raise CheckpointError(path, f"unreadable checkpoint ({exc})") from exc
    missing = [k for k in ("model", "model_config") if not isinstance(data, dict) or k not in data]
    if missing:
        raise CheckpointError(path, f"not a jnds checkpoint (no {', '.join(missing)})")
    return data


def load_model(path: str | Path):
    """A model (``model.JNDS``, eval mode) from a training or shipped checkpoint, fake
    quantization on if it was QAT-trained."""
    from .model import JNDS, ModelConfig, set_quantization

    data = read_checkpoint(path)
    model = JNDS(ModelConfig(**data["model_config"]))
    model.load_state_dict(data["model"])
    if data.get("quantized"):
        set_quantization(model, True)
    model.eval()
    return model


def load_fp32_model(path: str | Path):
    """The model as the fp32 graphs run it: activations in float and, from a QAT checkpoint,
    the weights it trained with (rounded to int8 per channel, ``model.round_weights``), so
    that fp32 and int8 differ only in the activations (the float weights' difference: the
    study at commit dfdbcb8, benchmarks/results/int8_rounded_fp32.md)."""
    from .model import round_weights, set_quantization

    model = load_model(path)
    if any(getattr(m, "quantize", False) for m in model.modules()):  # QAT-trained (load_model)
        round_weights(model)
    set_quantization(model, False)
    return model


def ship_checkpoint(ckpt: str | Path, out: str | Path, metrics: dict | None = None) -> Path:
    """Strip a training checkpoint down to what inference needs (weights, configs, ranges)
    and the record of how it was trained (state, training sequences, ``metrics``)."""
    import torch

    data = read_checkpoint(ckpt)
    slim = {k: data[k] for k in ("model", "model_config", "train_config", "quantized", "quant_ranges")}
    slim["train_sequences"] = data.get("train_sequences")
    slim["state"] = data["state"]
    slim["metrics"] = metrics
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(slim, out)
    return out
