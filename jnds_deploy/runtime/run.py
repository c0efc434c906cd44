"""``jnds run``: a sequence through the pipeline, frames to ``OUT/NNNN.exr``, a report to
``OUT/run.json`` (artifacts, precision, per-frame and median stage timings, and PSNR/FLIP
against the reference when the sequence has one), and for a sequence with references a
contact sheet ``OUT/contact.png``: input, OIDN (where ``pyoidn`` is installed), the
output and the reference of the first, middle and last frames."""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from .. import contact_sheet
from ..io import OUTPUT_FORMATS, check_headers, open_sequence, write_output
from ..metrics import changed_mask
from ..video import Mp4Writer, display
from .pipeline import Pipeline, PipelineConfig

STAGE_ORDER = (
    "reformat",
    "diffuse_fill",
    "warp",
    "firefly_clamp",
    "tile_skip",
    "network",
    "filter_diffuse",
    "filter_specular",
    "filter_auxiliary",
    "composite",
    "albedo_at_holes",
    "upsample_kernel",
    "upsample_filter",
)


def stage_table(report: dict) -> str:
    """Median milliseconds per stage and share of the total, as a markdown table."""
    med = report["median_ms"]
    total = med["total"]
    rows = ["| stage | median ms | % of total |", "| --- | ---: | ---: |"]
    for k in STAGE_ORDER:
        if k in med:
            rows.append(f"| {k} | {med[k]:.1f} | {100 * med[k] / total:.1f} |")
    rows.append(f"| **total** | **{total:.1f}** | 100.0 |")
    return "\n".join(rows)


def score_lines(report: dict) -> list[str]:
    """The report's scores against the reference as a user reads them: the output's and
    the baseline's PSNR, FLIP and changed-pixel PSNR; none without a reference."""
    lines = []
    for name, m in (("JNDS", report.get("metrics")), (BASELINE, report.get("baseline"))):
        if m:
            flip = f", FLIP {m['flip']:.4f}" if "flip" in m else ""
            lines.append(
                f"{name:>24}: PSNR {m['psnr']:.2f} dB{flip}, changed pixels "
                f"({100 * m['changed_fraction']:.1f} %) PSNR {m['changed_psnr']:.2f} dB"
            )
    return lines


def run_sequence(
    cfg: PipelineConfig,
    input_path: str | Path,
    output: str | Path,
    progress: bool = True,
    metrics: bool = True,
    output_format: str = "float",
    video: bool = False,
    png: str | Path | None = None,
) -> dict:
    """The sequence through a new pipeline; returns the report ``OUT/run.json`` holds.
    ``output_format``: one of ``io.OUTPUT_FORMATS``; ``video``, ``png``: see ``iter_run``."""
    from tqdm import tqdm

    n = len(open_sequence(input_path))
    with tqdm(total=n, desc=f"run {Path(input_path).name}", unit="frame", disable=not progress) as bar:
        for item in iter_run(Pipeline(cfg), input_path, output, metrics, output_format, video, png):
            if isinstance(item, dict):
                return item
            bar.update(1)
    raise AssertionError("iter_run ends with its report")


def iter_run(
    pipe: Pipeline,
    input_path: str | Path,
    output: str | Path,
    metrics: bool = True,
    output_format: str = "float",
    video: bool = False,
    png: str | Path | None = None,
):
    """``run_sequence`` on an existing pipeline (its history is reset first), one step at a
    time: yields each frame's index once the frame is written, then the report, after
    ``OUT/run.json`` (written last, atomically: a directory with it is complete). The
    metrics score the frame as computed (float32), before it is stored. With ``video``,
    also ``OUT/output.mp4``; with ``png``, each frame as ``png/NNNN.png``: the output through
    the display mapping of every picture here (``video.display``)."""
    cfg = pipe.cfg
    if output_format not in OUTPUT_FORMATS:
        raise ValueError(f"output format {output_format!r}: expected one of {', '.join(OUTPUT_FORMATS)}")
    seq = open_sequence(input_path)
    check_headers(seq)  # a bad frame fails here, before anything is written
    pipe.reset()
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    frames, scores, baseline_scores, nonfinite, decisions, rejected = [], [], [], [], [], []
    previous = None  # the previous frame's inputs, for the changed-pixel mask
    shown = set(contact_sheet.sheet_frames(len(seq)))
    sheet = []
    mp4 = Mp4Writer(out / "output.mp4") if video else None
    if png is not None:
        Path(png).mkdir(parents=True, exist_ok=True)
    # reading and writing beside the computation: OpenEXR lets go of the GIL while it reads
    # and writes, so frame i + 1 is read and frame i - 1 written while frame i runs
    # (benchmarks/results/memory.md). Leaving the block waits for the writes, also on an error.
    with (
        ThreadPoolExecutor(1, thread_name_prefix="jnds-read") as reader,
        ThreadPoolExecutor(1, thread_name_prefix="jnds-write") as writer,
    ):
        pending = reader.submit(seq.inputs, 0) if len(seq) else None
        writing = None  # (index, future) of the frame being written
        for i in range(len(seq)):
            inputs = pending.result()
            pending = reader.submit(seq.inputs, i + 1) if i + 1 < len(seq) else None
            frame = pipe(inputs, seq.frames[i].camera_cut)
            color = frame.output
            if writing is not None:
                writing[1].result()
                yield writing[0]
            writing = (
                i,
                writer.submit(
                    _write,
                    out / f"{i:04d}.exr",
                    color,
                    output_format,
                    mp4,
                    None if png is None else Path(png) / f"{i:04d}.png",
                ),
            )
            frames.append(frame.ms)
            nonfinite.append(frame.nonfinite)
            decisions.append({k: v for k, v in frame.decisions.items() if v})
            rejected.append(
                {
                    "pixels": frame.disoccluded,
                    "tiles": frame.rejected,
                    "fireflies_clamped": frame.clamped,
                    "diffuse_filled": frame.filled,
                }
            )
            ref = baseline = mask = None
            if seq.has_reference and (metrics or i in shown):
                ref = seq.reference(i)["color"]
                if ref.shape[:2] != color.shape[:2]:  # --native: the reference at the output size
                    ref = cv2.resize(ref, color.shape[1::-1], interpolation=cv2.INTER_AREA)
                baseline = _baseline(inputs, pipe.out_scale)
                if previous is not None and not seq.frames[i].camera_cut:
                    mask = changed_mask(inputs, previous, pipe.out_scale)
            if metrics and ref is not None:
                scores.append(_scores(color, ref, mask))
                if baseline is not None:
                    baseline_scores.append(_scores(baseline, ref, mask))
            if i in shown:
                if baseline is None:  # no reference: OIDN for the sheet alone
                    baseline = _baseline(inputs, pipe.out_scale)
                sheet.append((f"frame {i}", _sheet_row(inputs, color, ref, baseline, mask)))
            previous = inputs
        if writing is not None:
            writing[1].result()
            yield writing[0]
    if mp4 is not None:
        mp4.close()
    stages = sorted({k for f in frames for k in f})
    report = {
        "input": str(seq.path),
        "artifacts": str(Path(cfg.artifacts)),
        "checkpoint_sha256": pipe.manifest.checkpoint["sha256"],
        "precision": cfg.precision,
        "filter_dtype": cfg.filter_dtype,
        "threads": cfg.threads,
        "native_size": list(seq.native_size),
        "output_size": [seq.native_size[0] * pipe.out_scale, seq.native_size[1] * pipe.out_scale],
        "frames": len(seq),
        "output_format": output_format,
        "median_ms": {k: float(np.median([f.get(k, 0.0) for f in frames])) for k in stages},
        "frame_ms": frames,
        # NaN/Inf values replaced per frame and input layer (only layers that had any)
        "nonfinite": nonfinite,
        # adaptive execution per frame: what was skipped (FrameResult.decisions)
        "adaptive": cfg.adaptive,
        "native_output": cfg.native_output,
        "decisions": decisions,
        # history replaced by the current inputs per frame: pixels by the geometric test
        # (filter_spec.history_rejected), 32x32 tiles by the brightness test (history.reject_history)
        "history_rejected": rejected,
    }
    if scores:
        report["metrics"] = _summary(scores)
        if baseline_scores:
            report["baseline"] = dict(_summary(baseline_scores), method=BASELINE)
    if sheet:
        report["contact_sheet"] = str(contact_sheet.write(out / "contact.png", sheet))
    if mp4 is not None:
        report["video"] = str(mp4.path)
    if png is not None:
        report["png"] = str(png)
    tmp = out / ".run.json.tmp"
    tmp.write_text(json.dumps(report, indent=1))
    os.replace(tmp, out / "run.json")
    yield report


# what `jnds run` scores the output against besides the reference: a single-frame denoiser
# at native resolution, upscaled (baselines.oidn_bicubic), where pyoidn is installed
BASELINE = "OIDN balanced + bicubic"


def _baseline(inputs: dict, scale: int) -> np.ndarray | None:
    import importlib.util

    from .. import baselines

    if not importlib.util.find_spec("pyoidn"):
        return None
    return baselines.oidn_bicubic(inputs, scale) if scale > 1 else baselines.oidn(inputs)


def _scores(color: np.ndarray, ref: np.ndarray, mask: np.ndarray | None) -> dict:
    """One frame's PSNR, FLIP (where ``flip-evaluator``, the bench extra, is installed) and
    the squared error over its changed pixels (pooled by ``_summary``)."""
    import importlib.util

    from ..metrics import flip, masked_squared_error, psnr

    s = {"psnr": psnr(color, ref)}
    if importlib.util.find_spec("flip_evaluator"):
        s["flip"] = flip(color, ref)
    if mask is not None:
        s["changed_sq"], s["changed_n"] = masked_squared_error(color, ref, mask)
        s["changed_fraction"] = float(mask.mean())
    return s


def _summary(scores: list[dict]) -> dict:
    """Mean PSNR and FLIP over the frames; the PSNR over every frame's changed pixels,
    pooled (``metrics.changed_psnr``); per frame PSNR and FLIP."""
    from ..metrics import psnr_of

    changed = [s for s in scores if "changed_n" in s]
    keys = [k for k in ("psnr", "flip") if k in scores[0]]
    return {
        **{k: float(np.mean([s[k] for s in scores])) for k in keys},
        "changed_psnr": psnr_of(sum(s["changed_sq"] for s in changed), sum(s["changed_n"] for s in changed)),
        "changed_fraction": float(np.mean([s["changed_fraction"] for s in changed])) if changed else float("nan"),
        "per_frame": [{k: s[k] for k in keys} for s in scores],
    }


def _sheet_row(inputs: dict, output, reference, baseline, mask) -> dict:
    """The images of one contact-sheet row: the noisy input, OIDN (if installed), output
    and, where the sequence has one, the reference and the reference with the changed
    pixels marked."""
    from .. import baselines

    row = {"input": baselines.noisy_composite(inputs)}
    if baseline is not None:
        row[BASELINE] = baseline
    row["JNDS"] = output
    if reference is not None:
        row["reference"] = reference
        row["changed pixels"] = contact_sheet.mark(reference, mask)
    return row


def _write(path: Path, color: np.ndarray, output_format: str, mp4: Mp4Writer | None, png: Path | None) -> None:
    """One output frame, on the writer thread: the EXR, the video's frame, the PNG."""
    write_output(path, color, output_format)
    if mp4 is not None or png is not None:
        shown = display(color)
        if mp4 is not None:
            mp4.write(shown)
        if png is not None and not cv2.imwrite(str(png), shown[..., ::-1]):
            raise OSError(f"{png}: could not write the PNG")
