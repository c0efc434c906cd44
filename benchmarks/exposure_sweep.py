"""int8 against fp32 across exposure and across sequences: radiance scaled by 2^k, the
deployed pipeline (ONNX Runtime) at both precisions.

    python -m benchmarks.exposure_sweep --input data/val/SEQ [SEQ|DIR ...]
        [--stops -4 -2 0 2 4 6 8] [--out benchmarks/results/exposure_sweep]

Every sequence given (or found in a directory given) at every exposure 2^k (``--stops 0``
alone: int8 against fp32 per sequence). For each exposure, the input radiance layers (diffuse, specular) are multiplied by
2^k and the sequence runs through the fp32 and the int8 pipelines (history carried, all
frames); each output is divided by 2^k again before it is compared with the reference,
so every exposure is scored on the same image (PSNR and FLIP of ``jnds_deploy.metrics``,
means over frames): what changes is only the brightness the network sees. The int8
graphs are the manifest's last calibration. Writes benchmarks/results/exposure_sweep.md
and .json.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    ROOT,
    arguments,
    command_line,
    cpu_line,
    machine_info,
    parse,
    pipeline,
    tune_process,
    write_report,
)
from jnds_deploy.io import expand_sequences, open_sequence
from jnds_deploy.layout import RADIANCE
from jnds_deploy.metrics import flip, psnr
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS


def run(pipe, frames, gain: float, refs) -> dict:
    pipe.reset()
    scores = []
    for (layers, cut), ref in zip(frames, refs):
        scaled = {k: v * np.float32(gain) if k in RADIANCE else v for k, v in layers.items()}
        out = pipe(scaled, cut).output / np.float32(gain)
        scores.append((psnr(out, ref), flip(out, ref)))
    return {"psnr": float(np.mean([s[0] for s in scores])), "flip": float(np.mean([s[1] for s in scores]))}


def main() -> None:
    ap = arguments(
        __doc__, RESULTS / "exposure_sweep", smoke={"input": [str(ROOT / "samples" / "orbit-160x90")], "stops": [0, 8]}
    )
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--input", nargs="+", help="sequences with references, or directories of them (required)")
    ap.add_argument("--stops", type=float, nargs="+", default=[-4, -2, 0, 2, 4, 6, 8])
    args = parse(ap)
    if not args.input:
        ap.error("--input is required")
    tune_process()
    pipes = {p: pipeline(args.artifacts, precision=p) for p in ("fp32", "int8")}
    rows = []
    for path in expand_sequences(args.input):
        seq = open_sequence(path)
        frames = [(seq.inputs(i), seq.frames[i].camera_cut) for i in range(len(seq))]
        refs = [seq.reference(i)["color"] for i in range(len(seq))]
        for k in args.stops:
            r = {"sequence": str(path), "stops": k, **{p: run(pipe, frames, 2.0**k, refs) for p, pipe in pipes.items()}}
            r["int8_minus_fp32_db"] = r["int8"]["psnr"] - r["fp32"]["psnr"]
            rows.append(r)
            print(path.name, k, round(r["fp32"]["psnr"], 3), round(r["int8"]["psnr"], 3), flush=True)
    info = machine_info()
    worst = min(r["int8_minus_fp32_db"] for r in rows)
    best = max(r["int8_minus_fp32_db"] for r in rows)
    md = [
        "# int8 against fp32 across exposure\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(info)}. Radiance x 2^k in, output / 2^k scored against the reference (all frames, "
        f"history carried); the deployed ONNX Runtime pipeline at both precisions.\n",
        "| sequence | exposure | fp32 PSNR (dB) | int8 PSNR (dB) | int8 - fp32 (dB) | fp32 FLIP | int8 FLIP |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        md.append(
            f"| {Path(r['sequence']).parent.name}/{Path(r['sequence']).name} | 2^{r['stops']:g} | "
            f"{r['fp32']['psnr']:.2f} | {r['int8']['psnr']:.2f} | {r['int8_minus_fp32_db']:+.2f} | "
            f"{r['fp32']['flip']:.4f} | {r['int8']['flip']:.4f} |"
        )
    md += ["", f"int8 - fp32 from {worst:+.2f} to {best:+.2f} dB."]
    write_report(
        Path(args.out),
        {
            "machine": info,
            "command": command_line(),
            "input": args.input,
            "rows": rows,
            "worst_int8_minus_fp32_db": worst,
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
