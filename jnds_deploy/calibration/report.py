"""The calibration report: where int8 loses accuracy, tensor by tensor and end to end.

- per tensor (ONNX Runtime's ``qdq_loss_debug``): the signal-to-quantization-noise ratio
  (dB) of every quantized activation inside the int8 graph (``qdq``: what rounding to the
  range costs there) and against the same tensor of the fp32 graph (``vs fp32``: the error
  accumulated up to that point), on recorded calibration inputs; the worst are named;
- end to end: the int8 pipeline against the fp32 pipeline and both against the reference,
  PSNR and FLIP per sequence.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from ..io import open_sequence
from ..runtime.pipeline import Pipeline, PipelineConfig
from .reader import FeedReader


def tensor_errors(fp32_path: Path, int8_path: Path, feeds: list[dict]) -> list[dict]:
    """Per quantized activation: SQNR (dB) of QDQ rounding and of int8 vs fp32, worst first."""
    from onnxruntime.quantization.qdq_loss_debug import (
        collect_activations,
        compute_activation_error,
        create_activation_matching,
        modify_model_output_intermediate_tensors,
    )

    with tempfile.TemporaryDirectory() as tmp:
        aug_f, aug_q = Path(tmp) / "f.onnx", Path(tmp) / "q.onnx"
        modify_model_output_intermediate_tensors(str(fp32_path), str(aug_f))
        modify_model_output_intermediate_tensors(str(int8_path), str(aug_q))
        acts_f = collect_activations(str(aug_f), FeedReader(feeds))
        acts_q = collect_activations(str(aug_q), FeedReader(feeds))
    errors = compute_activation_error(create_activation_matching(acts_q, acts_f))
    rows = [
        {"tensor": k, "qdq_sqnr_db": float(v["qdq_err"]), "vs_fp32_sqnr_db": float(v.get("xmodel_err", np.nan))}
        for k, v in errors.items()
    ]
    return sorted(rows, key=lambda r: r["vs_fp32_sqnr_db"])


def end_to_end(
    artifacts: str | Path, method: str, sequences: list[Path], threads: int = 2, progress: bool = True
) -> dict:
    """PSNR/FLIP of the int8 (``method``) and fp32 pipelines against the reference, and of
    int8 against fp32, per sequence and averaged over sequences."""
    from tqdm import tqdm

    from ..metrics import flip, psnr

    pipes = {
        p: Pipeline(
            PipelineConfig(
                artifacts=str(artifacts), precision=p, threads=threads, int8_method=method if p == "int8" else None
            )
        )
        for p in ("fp32", "int8")
    }
    per_seq = {}
    for path in sequences:
        seq = open_sequence(path)
        for p in pipes.values():
            p.reset()
        acc: dict[str, list[float]] = {}
        for i in tqdm(range(len(seq)), desc=f"int8 vs fp32 {seq.path.name}", unit="frame", disable=not progress):
            layers, cut = seq.inputs(i), seq.frames[i].camera_cut
            out = {k: p(layers, cut).output for k, p in pipes.items()}
            scores = {"int8_vs_fp32_psnr": psnr(out["int8"], out["fp32"])}
            if seq.has_reference:
                ref = seq.reference(i)["color"]
                for k, o in out.items():
                    scores[f"{k}_psnr"] = psnr(o, ref)
                    scores[f"{k}_flip"] = flip(o, ref)
            for k, v in scores.items():
                acc.setdefault(k, []).append(v)
        per_seq[seq.path.name] = {k: float(np.mean(v)) for k, v in acc.items()}
    keys = sorted({k for v in per_seq.values() for k in v})
    mean = {k: float(np.mean([v[k] for v in per_seq.values() if k in v])) for k in keys}
    if "int8_psnr" in mean:
        mean["psnr_loss_db"] = mean["fp32_psnr"] - mean["int8_psnr"]
    return {"method": method, "per_sequence": per_seq, "mean": mean}


def markdown(tensors: dict[str, list[dict]], e2e: dict | None, worst: int = 8) -> str:
    lines = []
    if e2e:
        m = e2e["mean"]
        lines += [
            f"### End to end ({e2e['method']}, mean over {len(e2e['per_sequence'])} sequences)",
            "",
            "| pipeline | PSNR dB | FLIP |",
            "| --- | ---: | ---: |",
        ]
        for p in ("fp32", "int8"):
            if f"{p}_psnr" in m:
                lines.append(f"| {p} | {m[f'{p}_psnr']:.2f} | {m[f'{p}_flip']:.4f} |")
        if "psnr_loss_db" in m:
            lines += [
                "",
                f"int8 loses {m['psnr_loss_db']:.3f} dB PSNR against fp32 "
                f"(int8 vs fp32 output: {m['int8_vs_fp32_psnr']:.2f} dB PSNR).",
            ]
        lines.append("")
    for graph, rows in tensors.items():
        lines += [
            f"### {graph}: {min(worst, len(rows))} worst of {len(rows)} quantized tensors",
            "",
            "| tensor | QDQ SQNR dB | vs fp32 SQNR dB |",
            "| --- | ---: | ---: |",
        ]
        lines += [f"| `{r['tensor']}` | {r['qdq_sqnr_db']:.1f} | {r['vs_fp32_sqnr_db']:.1f} |" for r in rows[:worst]]
        lines.append("")
    return "\n".join(lines)
