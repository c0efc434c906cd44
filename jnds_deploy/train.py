"""``jnds train``: recurrent training of the JNDS network on rendered sequences.

Two phases, as in the paper (Sec. 3.4.3): full precision, then quantization-aware
training with int8 fake quantization (activation ranges first observed, then trained).
Each step unrolls ``unroll`` consecutive frames of random native patches (never across
a camera cut) and back-propagates through the whole unroll.

Losses (Sec. 3.3): for each task -- diffuse, specular, auxiliary (albedo), upsample --
``w_spatial * L_spatial + (1 - w_spatial) * L_temporal`` with w_spatial = 0.2, all task
weights 1. Native-resolution tasks compare with the 2x2-box-downsampled reference
component; all radiance is compared after the tonemap of Eq. 1. L_temporal is Eq. 5.
L_spatial is L1, the feature loss of ``jnds_deploy.feature_loss``, or their sum.
``device`` runs the steps on a GPU (``--device cuda``, docs/gpu-training.md).

Everything needed to resume lives in ``<run>/checkpoint.pt``, written atomically every
``checkpoint_every`` steps; ``<run>/log.jsonl`` has one line per log/validation event.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from . import filters
from .io import find_sequences, open_sequence
from .model import (CURRENT, JNDS, ModelConfig, quant_ranges, set_observing, set_quantization,
                    pad_to_multiple)


SPATIAL_LOSSES = ("l1", "feature", "l1+feature")


@dataclass
class TrainConfig:
    data: str = "data"  # holds train/ and val/ sequence directories
    run: str = "runs/small"
    preset: str = "small"
    upsample_root: int = 1  # ModelConfig.upsample_root of the trained model
    patch: int = 64  # native patch side, a multiple of the model's pad multiple
    unroll: int = 6  # consecutive frames per sample
    batch: int = 4
    fp32_steps: int = 4000
    qat_steps: int = 1500
    lr: float = 1e-3
    qat_lr: float = 1e-4
    lr_decay: float = 0.1  # exponential decay to lr * lr_decay over each phase
    w_spatial: float = 0.2
    spatial_loss: str = "l1"  # l1 | feature | l1+feature (the sum of both)
    feature_net: str | None = None  # checkpoint of the feature-loss network
    init: str | None = None  # start a new run from this checkpoint's weights (fine-tuning)
    observe_batches: int = 8  # batches to observe activation ranges before QAT
    val_every: int = 500
    checkpoint_every: int = 100
    val_sequences: int | None = None  # limit validation to the first N sequences
    threads: int = 2
    seed: int = 0
    device: str = "cpu"  # torch device of the training steps (cpu, cuda); data stays on the host

    def __post_init__(self):
        if self.spatial_loss not in SPATIAL_LOSSES:
            raise ValueError(f"spatial_loss must be one of {', '.join(SPATIAL_LOSSES)}, got {self.spatial_loss!r}")
        if "feature" in self.spatial_loss and not self.feature_net:
            raise ValueError(f"spatial_loss={self.spatial_loss} needs feature_net")
        if not 0 <= self.w_spatial <= 1:
            raise ValueError(f"w_spatial must be in [0, 1], got {self.w_spatial}")


# ---------------------------------------------------------------------------------------
# data


@dataclass
class SequenceArrays:
    """One sequence in memory, NCHW-ready float32: current (T, 13, H, W), motion
    (T, 2, H, W), reference components (T, 3, sH, sW), camera cuts."""

    name: str
    current: np.ndarray
    motion: np.ndarray
    ref: dict[str, np.ndarray]
    cuts: list[bool]

    @property
    def scale(self) -> int:
        return self.ref["color"].shape[-1] // self.current.shape[-1]


def load_sequence(path: str | Path) -> SequenceArrays:
    seq = open_sequence(path)
    cur, mot, refs = [], [], {k: [] for k in ("color", "diffuse", "specular", "albedo")}
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


class PatchSampler:
    """Random (sequence, window, crop) samples; windows never cross a camera cut."""

    def __init__(self, seqs: list[SequenceArrays], patch: int, unroll: int, rng: np.random.Generator):
        self.seqs, self.patch, self.unroll, self.rng = seqs, patch, unroll, rng
        self.windows = []
        for si, s in enumerate(seqs):
            starts = [0] + [t for t, c in enumerate(s.cuts) if c] + [len(s.cuts)]
            for a, b in zip(starts[:-1], starts[1:]):
                self.windows += [(si, t) for t in range(a, b - unroll + 1)]
        if not self.windows:
            raise ValueError(f"no window of {unroll} frames without a cut in the training data")

    def batch(self, n: int, device: str | torch.device = "cpu") -> dict[str, torch.Tensor]:
        """Tensors (T, N, C, H, W): current, motion (native patch), reference color,
        diffuse, specular, albedo (target patch)."""
        out = {k: [] for k in ("current", "motion", "color", "diffuse", "specular", "albedo")}
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
            for c in ("color", "diffuse", "specular", "albedo"):
                out[c].append(s.ref[c][sl, :, k * y:k * (y + p), k * x:k * (x + p)])
        return {k: torch.from_numpy(np.ascontiguousarray(np.stack(v, 1))).to(device) for k, v in out.items()}


# ---------------------------------------------------------------------------------------
# losses


def loss_tonemap(x: torch.Tensor) -> torch.Tensor:
    """Eq. 1 shifted by a small offset so its gradient stays bounded near 0 (the offset
    cancels in every difference the losses take)."""
    return (torch.log1p(x.clamp(0.0, filters.HDR_MAX)) + 1e-3).pow(1.0 / 2.2)


def _upsampled_motion(motion: torch.Tensor, scale: int) -> torch.Tensor:
    return F.interpolate(motion, scale_factor=scale, mode="nearest") * scale if scale > 1 else motion


class Loss:
    """Eq. 3-5: per task w_spatial * L_spatial + (1 - w_spatial) * L_temporal."""

    def __init__(self, cfg: TrainConfig, scale: int):
        self.w = cfg.w_spatial
        self.scale = scale
        self.feature_net = None
        self.with_l1 = cfg.spatial_loss != "feature"
        if "feature" in cfg.spatial_loss:
            from .feature_loss import load_feature_net
            self.feature_net = load_feature_net(cfg.feature_net).to(cfg.device)

    def spatial(self, o: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """L1, the feature loss (of 3-channel images), or their sum: the feature loss alone
        compares tonemapped features and lets bright HDR regions darken
        (benchmarks/results/brightness.md); the L1 term holds their level."""
        if self.feature_net is not None and o.shape[1] == 3:
            feat = self.feature_net.loss(o, r)
            return feat + (o - r).abs().mean() if self.with_l1 else feat
        return (o - r).abs().mean()

    def __call__(self, outs: list, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        s, tm = self.scale, loss_tonemap
        tasks = {
            "diffuse": ([tm(o.diffuse) for o in outs], tm(F.avg_pool2d(batch["diffuse"].flatten(0, 1), s)), False),
            "specular": ([tm(o.specular) for o in outs], tm(F.avg_pool2d(batch["specular"].flatten(0, 1), s)), False),
            "auxiliary": ([o.albedo for o in outs], F.avg_pool2d(batch["albedo"].flatten(0, 1), s), False),
            "upsample": ([tm(o.output) for o in outs], tm(batch["color"].flatten(0, 1)), True),
        }
        T, N = batch["current"].shape[:2]
        total, parts = 0.0, {}
        for name, (o_list, r_flat, target_res) in tasks.items():
            r = r_flat.view(T, N, *r_flat.shape[1:])
            o = torch.stack(o_list)
            l_sp = self.spatial(o.flatten(0, 1), r.flatten(0, 1))
            l_t = o.new_zeros(())
            if T > 1:
                mv = batch["motion"][1:].flatten(0, 1)
                if target_res:
                    mv = _upsampled_motion(mv, s)
                o_prev = filters.warp(o[:-1].flatten(0, 1), mv)
                r_prev = filters.warp(r[:-1].flatten(0, 1), mv)
                l_t = ((o[1:].flatten(0, 1) - o_prev) - (r[1:].flatten(0, 1) - r_prev)).abs().mean()
            task = self.w * l_sp + (1 - self.w) * l_t
            total = total + task
            parts[name] = float(task.detach())
        return total, parts


def run_unroll(model: JNDS, batch: dict) -> list:
    outs, history = [], None
    for t in range(batch["current"].shape[0]):
        out = model(batch["current"][t], batch["motion"][t], history)
        outs.append(out)
        history = out.history()
    return outs


# ---------------------------------------------------------------------------------------
# validation


@torch.no_grad()
def infer_sequence(model: JNDS, seq: SequenceArrays) -> list[np.ndarray]:
    """Run the model over a whole sequence (padding to the model's multiple, on the model's
    device); HWC outputs."""
    model.eval()
    outs, history = [], None
    s = model.cfg.scale
    dev = next(model.parameters()).device
    for t in range(len(seq.cuts)):
        cur, (h, w) = pad_to_multiple(torch.from_numpy(seq.current[t:t + 1]).to(dev), model.cfg.pad_multiple)
        mv, _ = pad_to_multiple(torch.from_numpy(seq.motion[t:t + 1]).to(dev), model.cfg.pad_multiple)
        out = model(cur, mv, None if (t == 0 or seq.cuts[t]) else history)
        history = out.history()
        outs.append(out.output[0, :, :h * s, :w * s].permute(1, 2, 0).cpu().numpy())
    return outs


def evaluate(model: JNDS, seqs: list[SequenceArrays], with_flip: bool = True) -> dict:
    from .evaluate import mean_over_sequences, score_frames

    per_seq = {}
    for seq in seqs:
        outs = infer_sequence(model, seq)
        per_seq[seq.name] = score_frames(outs, [r.transpose(1, 2, 0) for r in seq.ref["color"]],
                                         [m.transpose(1, 2, 0) for m in seq.motion], seq.cuts, with_flip)
    return {"mean": mean_over_sequences(per_seq), "sequences": per_seq}


# ---------------------------------------------------------------------------------------
# the loop


@dataclass
class TrainState:
    step: int = 0
    phase: str = "fp32"  # fp32 | qat | done


def _lr(cfg: TrainConfig, state: TrainState) -> float:
    base, steps, start = ((cfg.lr, cfg.fp32_steps, 0) if state.phase == "fp32"
                          else (cfg.qat_lr, cfg.qat_steps, cfg.fp32_steps))
    frac = min(1.0, (state.step - start) / max(1, steps))
    return base * cfg.lr_decay ** frac


def save_checkpoint(path: Path, model: JNDS, opt, state: TrainState, cfg: TrainConfig, rng,
                    train_sequences: list[str] | None = None) -> None:
    """``train_sequences``: names of the sequences the run sampled from (data/train grows
    with ``jnds dataset --train-sequences``, so the config alone does not say)."""
    tmp = path.with_name(path.name + ".tmp")
    # saved on the host, so that a checkpoint trained on a GPU loads anywhere (the
    # optimizer moves its state back to its parameters' device when it is loaded)
    torch.save({"model": _on_host(model.state_dict()), "optimizer": _on_host(opt.state_dict()), "state": asdict(state),
                "train_config": asdict(cfg), "model_config": asdict(model.cfg),
                "quantized": state.phase != "fp32", "rng": rng.bit_generator.state,
                "quant_ranges": quant_ranges(model) if state.phase != "fp32" else None,
                "train_sequences": train_sequences}, tmp)
    os.replace(tmp, path)


def _on_host(obj):
    """``obj`` (nested dicts and lists of tensors) with every tensor on the CPU."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: _on_host(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_on_host(v) for v in obj)
    return obj


def train(cfg: TrainConfig, progress: bool = True) -> Path:
    from tqdm import tqdm

    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    if torch.device(cfg.device).type == "cuda" and not torch.cuda.is_available():
        from .errors import TrainError
        raise TrainError(f"--device {cfg.device}: torch {torch.__version__} sees no CUDA device here")
    run = Path(cfg.run)
    run.mkdir(parents=True, exist_ok=True)
    ckpt = run / "checkpoint.pt"
    log = (run / "log.jsonl").open("a")

    model = JNDS(ModelConfig.preset(cfg.preset, upsample_root=cfg.upsample_root)).to(cfg.device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=0.0)
    rng = np.random.default_rng(cfg.seed)
    state = TrainState()
    if ckpt.exists():
        data = torch.load(ckpt, weights_only=False, map_location=cfg.device)
        model.load_state_dict(data["model"])
        opt.load_state_dict(data["optimizer"])
        state = TrainState(step=data["state"]["step"], phase=data["state"]["phase"])
        rng.bit_generator.state = data["rng"]
        if state.phase != "fp32":
            set_quantization(model, True)
    elif cfg.init:
        state = _init_from(model, cfg)
    train_seqs = [load_sequence(p) for p in find_sequences(Path(cfg.data) / "train")]
    names = [s.name for s in train_seqs]
    (run / "config.json").write_text(json.dumps({"train": asdict(cfg), "model": asdict(model.cfg),
                                                 "train_sequences": names}, indent=1))
    val_seqs: dict[Path, SequenceArrays] = {}

    def validation_set() -> list[SequenceArrays]:
        # re-scanned at every validation: sequences still rendering join when finished
        for p in find_sequences(Path(cfg.data) / "val")[:cfg.val_sequences]:
            if p not in val_seqs:
                val_seqs[p] = load_sequence(p)
        return list(val_seqs.values())
    if not train_seqs:
        raise FileNotFoundError(f"no sequences under {Path(cfg.data) / 'train'}; run `jnds dataset` first")
    sampler = PatchSampler(train_seqs, cfg.patch, cfg.unroll, rng)
    loss_fn = Loss(cfg, model.cfg.scale)
    total_steps = cfg.fp32_steps + cfg.qat_steps

    def emit(**rec):
        rec.update(step=state.step, phase=state.phase, time=time.time())
        log.write(json.dumps(rec) + "\n")
        log.flush()

    bar = tqdm(total=total_steps, initial=state.step, desc=f"train {run.name}", unit="step",
               disable=not progress)
    running = []
    while state.step < total_steps:
        if state.phase == "fp32" and state.step >= cfg.fp32_steps:
            _start_qat(model, sampler, cfg)
            state.phase = "qat"
            opt = torch.optim.AdamW(model.parameters(), lr=cfg.qat_lr, weight_decay=0.0)
            emit(event="qat_start", ranges=quant_ranges(model))
        model.train()
        for g in opt.param_groups:
            g["lr"] = _lr(cfg, state)
        batch = sampler.batch(cfg.batch, cfg.device)
        loss, parts = loss_fn(run_unroll(model, batch), batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        state.step += 1
        running.append(float(loss.detach()))
        bar.update(1)
        bar.set_postfix(loss=f"{np.mean(running[-50:]):.4f}", phase=state.phase)
        if state.step % 50 == 0:
            emit(event="train", loss=float(np.mean(running[-50:])), parts=parts, lr=_lr(cfg, state))
        if state.step % cfg.val_every == 0 or state.step == total_steps:
            seqs = validation_set()
            if seqs:
                emit(event="val", n_sequences=len(seqs), **evaluate(model, seqs))
        if state.step % cfg.checkpoint_every == 0 or state.step == total_steps:
            save_checkpoint(ckpt, model, opt, state, cfg, rng, names)
    state.phase = "done"
    save_checkpoint(ckpt, model, opt, state, cfg, rng, names)
    bar.close()
    return ckpt


def _init_from(model: JNDS, cfg: TrainConfig) -> TrainState:
    """Weights (and learned activation ranges) of ``cfg.init`` for a new run. A QAT-trained
    checkpoint with ``fp32_steps == 0`` goes on in the QAT phase with its ranges; with fp32
    steps it is fine-tuned in full precision first and its ranges are observed afresh."""
    data = torch.load(cfg.init, weights_only=False, map_location=cfg.device)
    # upsample_root changes no weight: a checkpoint can be fine-tuned with another
    if replace(ModelConfig(**data["model_config"]), upsample_root=model.cfg.upsample_root) != model.cfg:
        raise ValueError(f"--init {cfg.init}: model config {data['model_config']} is not preset "
                         f"{cfg.preset!r} ({asdict(model.cfg)})")
    model.load_state_dict(data["model"])
    if data.get("quantized") and cfg.fp32_steps == 0:
        set_quantization(model, True)
        return TrainState(step=0, phase="qat")
    return TrainState()


@torch.no_grad()
def _start_qat(model: JNDS, sampler: PatchSampler, cfg: TrainConfig) -> None:
    """Observe activation ranges (min/max over a few batches), then turn fake quant on."""
    from .model import ActQuant

    for m in model.modules():
        if isinstance(m, ActQuant):
            m.lo.fill_(0.0)
            m.hi.fill_(1e-3)
    set_observing(model, True)
    for _ in range(cfg.observe_batches):
        run_unroll(model, sampler.batch(cfg.batch, cfg.device))
    set_observing(model, False)
    set_quantization(model, True)


def export_checkpoint(ckpt: str | Path, out: str | Path, metrics: dict | None = None) -> Path:
    """Strip a training checkpoint down to what inference needs (weights, configs, ranges)."""
    data = torch.load(ckpt, weights_only=False, map_location="cpu")
    slim = {k: data[k] for k in ("model", "model_config", "train_config", "quantized", "quant_ranges")}
    slim["train_sequences"] = data.get("train_sequences")
    slim["state"] = data["state"]
    slim["metrics"] = metrics
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(slim, out)
    return out


def default_checkpoint() -> Path:
    """The QAT checkpoint shipped inside the package."""
    path = Path(__file__).parent / "checkpoints" / "jnds-small.pt"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no shipped checkpoint in this install; pass --checkpoint")
    return path


def load_model(path: str | Path) -> JNDS:
    """A model from a (training or shipped) checkpoint, fake quantization on if it was QAT-trained."""
    data = torch.load(path, weights_only=False, map_location="cpu")
    model = JNDS(ModelConfig(**data["model_config"]))
    model.load_state_dict(data["model"])
    if data.get("quantized"):
        set_quantization(model, True)
    model.eval()
    return model

