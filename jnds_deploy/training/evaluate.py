"""``jnds evaluate``: the model against the baselines on validation sequences.

Every method turns each sequence into a list of target-resolution frames; all are then
scored by the same ``jnds_deploy.metrics`` (PSNR, SSIM, FLIP per frame; temporal error
per sequence) against the reference colour. The model runs in PyTorch (``infer_sequence``,
as in training's validation); the ONNX pipeline's own scores come from ``jnds run``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .. import baselines
from ..errors import ConfigError
from ..io import expand_sequences, open_sequence
from .data import SequenceArrays, load_sequence


def infer_sequence(model, seq: SequenceArrays) -> list[np.ndarray]:
    """Run the model (``model.JNDS``) over a whole sequence (padding to the model's
    multiple, on the model's device); HWC outputs."""
    import torch

    from ..model import pad_to_multiple

    model.eval()
    outs, history = [], None
    s = model.cfg.scale
    dev = next(model.parameters()).device
    with torch.no_grad():
        for t in range(len(seq.cuts)):
            cur, (h, w) = pad_to_multiple(torch.from_numpy(seq.current[t : t + 1]).to(dev), model.cfg.pad_multiple)
            mv, _ = pad_to_multiple(torch.from_numpy(seq.motion[t : t + 1]).to(dev), model.cfg.pad_multiple)
            guide = None
            if model.cfg.guide_albedo and seq.guide is not None:
                guide, _ = pad_to_multiple(torch.from_numpy(seq.guide[t : t + 1]).to(dev), model.cfg.pad_multiple)
            out = model(cur, mv, None if (t == 0 or seq.cuts[t]) else history, guide=guide)
            history = out.history()
            outs.append(out.output[0, :, : h * s, : w * s].permute(1, 2, 0).cpu().numpy())
    return outs


def evaluate_model(model, seqs: list[SequenceArrays], with_flip: bool = True) -> dict:
    """The model's scores on sequences in memory: the mean over sequences and per sequence."""
    per_seq = {}
    for seq in seqs:
        outs = infer_sequence(model, seq)
        per_seq[seq.name] = score_frames(
            outs,
            [r.transpose(1, 2, 0) for r in seq.ref["color"]],
            [m.transpose(1, 2, 0) for m in seq.motion],
            seq.cuts,
            with_flip,
        )
    return {"mean": mean_over_sequences(per_seq), "sequences": per_seq}


def score_frames(outs, refs, motions, cuts, with_flip: bool = True, masks=None) -> dict[str, float]:
    """Mean per-frame PSNR/SSIM/FLIP and the sequence's temporal error; HWC arrays. With
    ``masks`` (``metrics.changed_masks``), also the PSNR over the pixels whose previous
    frame showed another surface (``changed_psnr``) and their share."""
    from ..metrics import changed_psnr, frame_metrics, temporal_error

    fm = [frame_metrics(o, r, with_flip) for o, r in zip(outs, refs)]
    m = {k: float(np.mean([f[k] for f in fm])) for k in fm[0]}
    m["temporal"] = temporal_error(outs, refs, motions, cuts)
    if masks is not None:
        m.update(changed_psnr(outs, refs, masks))
    return m


def ground_truth(seq_path: Path) -> tuple[list, list, list, list]:
    """Reference colours, motion vectors, camera cuts and changed-pixel masks
    (``metrics.changed_masks``) of a sequence (HWC)."""
    from ..metrics import changed_masks

    seq = open_sequence(seq_path)
    refs = [seq.reference(i)["color"] for i in range(len(seq))]
    inputs = [seq.inputs(i) for i in range(len(seq))]
    cuts = [f.camera_cut for f in seq.frames]
    masks = changed_masks(inputs, cuts, seq.target_size[0] // seq.native_size[0])
    return refs, [a["motion"] for a in inputs], cuts, masks


def mean_over_sequences(per_seq: dict[str, dict[str, float]]) -> dict[str, float]:
    keys = next(iter(per_seq.values())).keys()
    return {k: float(np.mean([m[k] for m in per_seq.values()])) for k in keys}


def baseline_outputs(method: str, seq_path: Path) -> list[np.ndarray]:
    seq = open_sequence(seq_path)
    scale = seq.target_size[0] // seq.native_size[0]
    outs = []
    for i in range(len(seq)):
        a = seq.inputs(i)
        if method == "bicubic":
            outs.append(baselines.bicubic(baselines.noisy_composite(a), scale))
        elif method.startswith("oidn-"):
            outs.append(baselines.oidn_bicubic(a, scale, quality=method.split("-", 1)[1]))
        else:
            raise ConfigError(f"unknown baseline {method!r}")
    return outs


def model_outputs(model, seq_path: Path) -> list[np.ndarray]:
    return infer_sequence(model, load_sequence(seq_path))


def evaluate_methods(seq_paths: list[Path], methods: dict, with_flip: bool = True, shown: dict | None = None) -> dict:
    """``methods``: name -> callable(seq_path) -> list of HWC frames. Returns per method
    the mean over sequences of each metric, the per-sequence values and ms per frame.
    ``shown``, if given, receives the contact sheet's images: {sequence: {column: middle
    frame}}, the input first and the reference last."""
    truth = {p: ground_truth(p) for p in seq_paths}  # read once, shared by every method
    report = {}
    for name, run in methods.items():
        per_seq, ms = {}, []
        for p in seq_paths:
            t0 = time.perf_counter()
            outs = run(p)
            ms.append(1000 * (time.perf_counter() - t0) / len(outs))
            refs, motions, cuts, masks = truth[p]
            per_seq[p.name] = score_frames(outs, refs, motions, cuts, with_flip, masks)
            if shown is not None:
                mid = len(outs) // 2
                if p.name not in shown:
                    shown[p.name] = {"input": baselines.noisy_composite(open_sequence(p).inputs(mid))}
                shown[p.name][name] = outs[mid]
        # ms_per_frame includes reading the input EXRs: a rough figure, not a benchmark
        report[name] = {
            "mean": mean_over_sequences(per_seq),
            "ms_per_frame": float(np.median(ms)),
            "sequences": per_seq,
        }
    for p in seq_paths if shown is not None else []:
        refs = truth[p][0]
        shown[p.name]["reference"] = refs[len(refs) // 2]
    return report


def markdown_table(report: dict) -> str:
    lines = [
        "| method | PSNR (dB) ↑ | SSIM ↑ | FLIP ↓ | temporal error ↓ | changed-pixel PSNR (dB) ↑ |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, r in report.items():
        m = r["mean"]
        lines.append(
            f"| {name} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m.get('flip', float('nan')):.4f} | "
            f"{m['temporal']:.5f} | {m.get('changed_psnr', float('nan')):.2f} |"
        )
    return "\n".join(lines)


def method_name(checkpoint: str | Path) -> str:
    """A checkpoint's name in reports: its file stem, or its run directory's name for a
    training checkpoint (``runs/ft-l1/checkpoint.pt`` -> ``ft-l1``)."""
    p = Path(checkpoint)
    return p.parent.name if p.stem == "checkpoint" and p.parent.name else p.stem


def run_evaluation(checkpoints: list[str], data: str, baselines_: list[str], out: str | None, threads: int = 2) -> dict:
    """``evaluate_sets`` on one set: its report."""
    return next(iter(evaluate_sets(checkpoints, [data], baselines_, out, threads).values()))


def evaluate_sets(
    checkpoints: list[str],
    sets: list[str],
    baselines_: list[str],
    out: str | None = None,
    threads: int = 2,
    sheet: str | None = None,
) -> dict:
    """Every checkpoint and baseline on each set (a sequence or a directory of sequences,
    e.g. data/val and a test set): {set name: report}, written to ``out`` as JSON (one
    set: its report alone, the format of ``benchmarks/results/model_eval.json``), and a
    contact sheet (``sheet``, PNG: per sequence the middle frame's input, each method's
    output and the reference)."""
    import torch

    from .. import contact_sheet
    from ..checkpoint import load_model

    torch.set_num_threads(threads)
    methods = {}
    for ck in checkpoints:
        model = load_model(ck)
        methods[method_name(ck)] = lambda p, m=model: model_outputs(m, p)
    for b in baselines_:
        methods[b] = lambda p, b=b: baseline_outputs(b, p)
    reports, rows = {}, []
    for data in sets:
        seqs = expand_sequences([data])
        shown = {} if sheet else None
        reports[set_name(data)] = evaluate_methods(seqs, methods, shown=shown)
        rows += [(f"{set_name(data)}/{p.name}", shown[p.name]) for p in seqs] if sheet else []
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(reports if len(reports) > 1 else next(iter(reports.values())), indent=1))
    if sheet:
        contact_sheet.write(sheet, rows)
    return reports


def set_name(data: str | Path) -> str:
    """A set's name in reports: its directory's name (data/val -> val)."""
    return Path(data).resolve().name


def markdown_sets(reports: dict) -> str:
    """Per set the mean table and the per-sequence PSNR / FLIP of every method, so the sets
    (validation, test) read side by side."""
    parts = []
    for name, report in reports.items():
        methods = list(report)
        seqs = list(next(iter(report.values()))["sequences"])
        lines = [
            f"### {name} ({len(seqs)} sequences)",
            "",
            markdown_table(report),
            "",
            "| sequence | " + " | ".join(f"{m} PSNR / FLIP / changed PSNR" for m in methods) + " |",
            "| --- |" + " --- |" * len(methods),
        ]
        for sq in seqs:
            cells = [
                f"{report[m]['sequences'][sq]['psnr']:.2f} / {report[m]['sequences'][sq].get('flip', float('nan')):.4f}"
                f" / {report[m]['sequences'][sq].get('changed_psnr', float('nan')):.2f}"
                for m in methods
            ]
            lines.append(f"| {sq} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts)
