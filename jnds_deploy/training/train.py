"""``jnds train``: recurrent training of the JNDS network on rendered sequences.

Two phases, as in the paper (Sec. 3.4.3): full precision, then quantization-aware
training with int8 fake quantization (activation ranges first observed, then trained).
Each step unrolls ``unroll`` consecutive frames of random native patches (never across
a camera cut) and back-propagates through the whole unroll (losses: ``training.losses``).
``device`` runs the steps on a GPU (``--device cuda``, docs/gpu-training.md).

Everything needed to resume lives in ``<run>/checkpoint.pt``, written atomically every
``checkpoint_every`` steps; ``<run>/log.jsonl`` has one line per log/validation event.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ..checkpoint import read_checkpoint
from ..errors import ConfigError, TrainError
from ..io import find_sequences
from ..model import JNDS, ActQuant, ModelConfig, QConv, quant_ranges, set_observing, set_quantization
from .config import TrainConfig
from .data import Augment, PatchSampler, SequenceArrays, load_sequence, load_split
from .evaluate import evaluate_model
from .losses import Loss
from .surgery import carried


@dataclass
class TrainState:
    step: int = 0
    phase: str = "fp32"  # fp32 | qat | done


def run_unroll(model: JNDS, batch: dict, burn_in: int = 0) -> list:
    """The model's outputs for the batch's frames after the first ``burn_in``, which run
    without gradients only to build the history (``PatchSampler.batch``)."""
    outs, history = [], None
    cut = batch.get("cut")
    for t in range(batch["current"].shape[0]):
        reset = cut[t] if cut is not None and t > 0 and bool(cut[t].any()) else None
        with torch.set_grad_enabled(torch.is_grad_enabled() and t >= burn_in):
            out = model(
                batch["current"][t],
                batch["motion"][t],
                history,
                reset=reset,
                guide=batch["guide"][t] if "guide" in batch else None,
            )
        if t >= burn_in:
            outs.append(out)
        history = out.history()
    return outs


def after_burn_in(batch: dict, burn_in: int) -> dict:
    """The batch's frames that ``run_unroll`` returns outputs for (the losses' batch)."""
    return {k: v[burn_in:] for k, v in batch.items()}


def _lr(cfg: TrainConfig, state: TrainState) -> float:
    base, steps, start = (
        (cfg.lr, cfg.fp32_steps, 0) if state.phase == "fp32" else (cfg.qat_lr, cfg.qat_steps, cfg.fp32_steps)
    )
    frac = min(1.0, (state.step - start) / max(1, steps))
    warmup = min(1.0, (state.step + 1) / cfg.warmup_steps) if state.phase == "fp32" and cfg.warmup_steps else 1.0
    return warmup * base * cfg.lr_decay**frac


def save_checkpoint(
    path: Path, model: JNDS, opt, state: TrainState, cfg: TrainConfig, rng, train_sequences: list[str] | None = None
) -> None:
    """``train_sequences``: names of the sequences the run sampled from (data/train grows
    with ``jnds dataset --train-sequences``, so the config alone does not say)."""
    tmp = path.with_name(path.name + ".tmp")
    # saved on the host, so that a checkpoint trained on a GPU loads anywhere (the
    # optimizer moves its state back to its parameters' device when it is loaded)
    torch.save(
        {
            "model": _on_host(model.state_dict()),
            "optimizer": _on_host(opt.state_dict()),
            "state": asdict(state),
            "train_config": asdict(cfg),
            "model_config": asdict(model.cfg),
            "quantized": state.phase != "fp32",
            "rng": rng.bit_generator.state,
            "quant_ranges": quant_ranges(model) if state.phase != "fp32" else None,
            "train_sequences": train_sequences,
        },
        tmp,
    )
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
        raise TrainError(f"--device {cfg.device}: torch {torch.__version__} sees no CUDA device here")
    train_seqs = load_split(Path(cfg.data) / "train", clean=cfg.clean_references)
    run = Path(cfg.run)
    run.mkdir(parents=True, exist_ok=True)
    ckpt = run / "checkpoint.pt"

    model = JNDS(cfg.model_config()).to(cfg.device)
    if cfg.train_only:
        _freeze_except(model, cfg.train_only)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=0.0)
    rng = np.random.default_rng(cfg.seed)
    state = TrainState()
    if ckpt.exists():
        data = read_checkpoint(ckpt, map_location=cfg.device)
        model.load_state_dict(data["model"])
        opt.load_state_dict(data["optimizer"])
        state = TrainState(step=data["state"]["step"], phase=data["state"]["phase"])
        rng.bit_generator.state = data["rng"]
        if state.phase != "fp32":
            set_quantization(model, True)
    elif cfg.init:
        state = _init_from(model, cfg)
    names = [s.name for s in train_seqs]
    (run / "config.json").write_text(
        json.dumps({"train": asdict(cfg), "model": asdict(model.cfg), "train_sequences": names}, indent=1)
    )
    val_seqs: dict[Path, SequenceArrays] = {}

    def validation_set() -> list[SequenceArrays]:
        # re-scanned at every validation: sequences still rendering join when finished
        for p in find_sequences(Path(cfg.data) / "val")[: cfg.val_sequences]:
            if p not in val_seqs:
                val_seqs[p] = load_sequence(p)
        return list(val_seqs.values())

    sampler = PatchSampler(
        train_seqs,
        cfg.patch,
        cfg.unroll,
        rng,
        Augment(cfg.exposure, cfg.rotate_normals, cfg.flips, cfg.colours),
        cross_cuts=cfg.cross_cuts,
        balance_renderers=cfg.balance_renderers,
        references=cfg.teacher is None,
        guide=model.cfg.guide_albedo,
    )
    loss_fn = Loss(cfg, model.cfg.scale)
    if state.step == 0 and not ckpt.exists() and (old := _other_input_block(cfg, model)) is not None:
        _fit_input_block(model, old, sampler, cfg, emit_to=run / "log.jsonl")
    teacher = _teacher(cfg, model.cfg) if cfg.teacher else None
    if cfg.channels_last:
        model.to(memory_format=torch.channels_last)
        loss_fn.to(memory_format=torch.channels_last)
        if teacher is not None:
            teacher.to(memory_format=torch.channels_last)
    total_steps = cfg.fp32_steps + cfg.qat_steps
    log = (run / "log.jsonl").open("a")

    def emit(**rec):
        rec.update(step=state.step, phase=state.phase, time=time.time())
        log.write(json.dumps(rec) + "\n")
        log.flush()

    bar = tqdm(total=total_steps, initial=state.step, desc=f"train {run.name}", unit="step", disable=not progress)
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
        burn = int(rng.integers(cfg.burn_in + 1)) if cfg.burn_in else 0
        batch = sampler.batch(cfg.batch, cfg.device, burn_in=burn)
        targets = None
        if teacher is not None:
            with torch.no_grad():
                targets = loss_fn.teacher_targets(run_unroll(teacher, batch, burn))
        loss, parts = loss_fn(run_unroll(model, batch, burn), after_burn_in(batch, burn), targets)
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
                emit(event="val", n_sequences=len(seqs), **evaluate_model(model, seqs))
        if state.step % cfg.checkpoint_every == 0 or state.step == total_steps:
            save_checkpoint(ckpt, model, opt, state, cfg, rng, names)
    state.phase = "done"
    save_checkpoint(ckpt, model, opt, state, cfg, rng, names)
    bar.close()
    log.close()
    return ckpt


def _freeze_except(model: JNDS, prefixes: tuple[str, ...]) -> None:
    """Only the parameters named with one of ``prefixes`` train; ConfigError if none is."""
    if not any(n.startswith(prefixes) for n, _ in model.named_parameters()):
        raise ConfigError(
            f"train_only {list(prefixes)}: no parameter of the model is named so (e.g. network.output_block)"
        )
    for n, p in model.named_parameters():
        p.requires_grad_(n.startswith(prefixes))


def _teacher(cfg: TrainConfig, student: ModelConfig) -> JNDS:
    """The distillation teacher (``TrainConfig.teacher``), eval mode, frozen, as it was trained
    (fake quantization on if it was QAT-trained). Its runtime switches (fill, clamp, albedo
    at holes, upsample root) must be the student's: the student learns to equal it."""
    from ..checkpoint import load_model

    teacher = load_model(cfg.teacher).to(cfg.device)
    same = ("upsample_root", "firefly_clamp", "diffuse_fill", "albedo_at_holes", "scale")
    if diff := [k for k in same if getattr(teacher.cfg, k) != getattr(student, k)]:
        raise ConfigError(
            f"--teacher {cfg.teacher}: {', '.join(f'{k} {getattr(teacher.cfg, k)}' for k in diff)} "
            f"where the trained model has {', '.join(str(getattr(student, k)) for k in diff)}"
        )
    for p in teacher.parameters():
        p.requires_grad_(False)
    return teacher


def _other_input_block(cfg: TrainConfig, model: JNDS) -> JNDS | None:
    """``cfg.init`` as a model (float, eval mode) where its input block's design is not
    ``model``'s (``ModelConfig.input_block``), else None."""
    from ..checkpoint import load_model

    old = load_model(cfg.init) if cfg.init else None
    if old is None or old.cfg.input_block == model.cfg.input_block:
        return None
    set_quantization(old, False)
    return old.to(cfg.device)


def _fit_input_block(
    model: JNDS, old: JNDS, sampler: PatchSampler, cfg: TrainConfig, emit_to: Path, reuse: int = 4
) -> float:
    """Fit ``model``'s input block to ``old``'s native features (mean squared error; the pooled
    ones are their average either way) on the inputs ``old``'s input block sees in training
    windows, its own recurrence making the history; each window's inputs serve ``reuse``
    steps. Only the input block's weights change. Returns the last relative RMS error."""
    captured = []
    hook = old.network.input_block.register_forward_pre_hook(lambda mod, args: captured.append(args))

    def window():
        captured.clear()
        with torch.no_grad():
            run_unroll(old, sampler.batch(cfg.batch, cfg.device))
            args = [torch.cat([a[i] for a in captured]) if captured[0][i] is not None else None for i in range(3)]
            return args, old.network.input_block(*args)[0]

    block = model.network.input_block
    quantized = any(m.quantize for m in block.modules() if isinstance(m, QConv))
    set_quantization(block, False)  # fitted in float; a QAT run's ranges are observed after
    opt = torch.optim.Adam(block.parameters(), lr=1e-3)
    steps = cfg.input_fit_steps
    rel = float("nan")
    with emit_to.open("a") as log:
        for step in range(steps):
            for g in opt.param_groups:  # exponential decay to a tenth
                g["lr"] = 1e-3 * 0.1 ** (step / max(steps, 1))
            if step % reuse == 0:
                args, target = window()
            loss = torch.nn.functional.mse_loss(block(*args)[0], target)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            rel = float(loss.detach().sqrt() / target.pow(2).mean().sqrt())
            if (step + 1) % 50 == 0 or step + 1 == steps:
                log.write(
                    json.dumps(
                        {
                            "event": "input_fit",
                            "fit_step": step + 1,
                            "mse": float(loss.detach()),
                            "relative_rms": rel,
                            "time": time.time(),
                        }
                    )
                    + "\n"
                )
                log.flush()
        if quantized:
            # the rest of the network keeps its learned ranges; the new block's are observed
            # (min/max) on windows as ``_start_qat`` observes a whole network's
            for m in block.modules():
                if isinstance(m, ActQuant):
                    m.lo.data.fill_(0.0)
                    m.hi.data.fill_(1e-3)
            set_observing(block, True)
            with torch.no_grad():
                for _ in range(cfg.observe_batches):
                    block(*window()[0])
            set_observing(block, False)
            set_quantization(block, True)
            log.write(
                json.dumps({"event": "input_fit_ranges", "ranges": quant_ranges(block), "time": time.time()}) + "\n"
            )
    hook.remove()
    return rel


def _init_from(model: JNDS, cfg: TrainConfig) -> TrainState:
    """Weights (and learned activation ranges) of ``cfg.init`` for a new run, carried to
    ``model``'s configuration by ``surgery.carried``. A QAT-trained checkpoint with
    ``fp32_steps == 0`` goes on in the QAT phase with its ranges; with fp32 steps it is
    fine-tuned in full precision first and its ranges are observed afresh."""
    data = read_checkpoint(cfg.init, map_location=cfg.device)
    init_cfg, weights = carried(
        ModelConfig(**data["model_config"]), data["model"], model, cfg.guide_init, cfg.deepen_blend
    )
    if init_cfg != model.cfg:
        raise ConfigError(
            f"--init {cfg.init}: model config {data['model_config']} is not preset {cfg.preset!r} ({asdict(model.cfg)})"
        )
    model.load_state_dict(weights)
    if data.get("quantized") and cfg.fp32_steps == 0:
        set_quantization(model, True)
        return TrainState(step=0, phase="qat")
    return TrainState()


@torch.no_grad()
def _start_qat(model: JNDS, sampler: PatchSampler, cfg: TrainConfig) -> None:
    """Observe activation ranges (min/max over a few batches), then turn fake quant on."""
    for m in model.modules():
        if isinstance(m, ActQuant):
            m.lo.fill_(0.0)
            m.hi.fill_(1e-3)
    set_observing(model, True)
    for _ in range(cfg.observe_batches):
        run_unroll(model, sampler.batch(cfg.batch, cfg.device))
    set_observing(model, False)
    set_quantization(model, True)
