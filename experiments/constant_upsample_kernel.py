"""Is the upsample block worth its time? The shipped model's upsample kernel against a
constant one: its mean per phase and tap over the bundled sample's frames, the same at every
pixel (bilinear upsampling of fourth roots, slightly sharpened). Both run in the deployed
int8 pipeline (`make demo`'s out/artifacts) on the given sequences, frame after frame.

    .venv/bin/python experiments/constant_upsample_kernel.py --artifacts out/artifacts --input data/val \\
        [--out benchmarks/results/constant_upsample_kernel]

Why: the learned kernel's centre tap averages 0.99 and its taps vary little from pixel to
pixel (std 0.0035 over the sample for `gen3`), and the upsample block is 18 % of the 720p
frame (benchmarks/results/timing-avx512-vnni.md).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import arguments, command_line, cpu_line, machine_info, write_report  # noqa: E402
from jnds_deploy.calibration.reader import collect_feeds  # noqa: E402
from jnds_deploy.io import expand_sequences, open_sequence  # noqa: E402
from jnds_deploy.metrics import flip, psnr  # noqa: E402
from jnds_deploy.runtime import Pipeline, PipelineConfig  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "orbit-160x90"


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--artifacts", default="out/artifacts")
    ap.add_argument("--input", nargs="+", default=["data/val"])
    ap.add_argument("--out", default="benchmarks/results/constant_upsample_kernel")
    args = ap.parse_args()
    import onnxruntime as ort

    if not (Path(args.artifacts) / "upsample.onnx").is_file():
        raise SystemExit(f"{args.artifacts}: no upsample graph; the model already has one fixed upsample kernel "
                         "(ModelConfig.upsample_width 0): export a checkpoint that predicts it")
    feeds = collect_feeds(Path(args.artifacts), [SAMPLE], frames=8, progress=False)["upsample"]
    sess = ort.InferenceSession(str(Path(args.artifacts) / "upsample.onnx"), providers=["CPUExecutionProvider"])
    kernels = [sess.run(None, f)[0][0].reshape(36, -1) for f in feeds]
    mean_k = np.mean([k.mean(1) for k in kernels], 0).astype(np.float32)
    spread = float(np.mean([k.std(1).mean() for k in kernels]))
    learned = Pipeline(PipelineConfig(artifacts=args.artifacts, precision="int8"))
    const = Pipeline(PipelineConfig(artifacts=args.artifacts, precision="int8"))
    const._upsample_kernel = lambda f, tiles: np.broadcast_to(mean_k[:, None, None],
                                                               (36, *f["composite"].shape[2:])).copy()
    rows = {}
    for path in expand_sequences(args.input):
        seq = open_sequence(path)
        learned.reset()
        const.reset()
        scores = {"learned": [], "constant": []}
        for i in range(len(seq)):
            ref = seq.reference(i)["color"]
            for name, pipe in (("learned", learned), ("constant", const)):
                out = pipe(seq.inputs(i), seq.frames[i].camera_cut).output
                scores[name].append((psnr(out, ref), flip(out, ref)))
        rows[path.name] = {k: np.mean(v, 0).tolist() for k, v in scores.items()}
        print(path.name, rows[path.name], flush=True)
    mean = {k: np.mean([r[k] for r in rows.values()], 0).tolist() for k in ("learned", "constant")}
    md = ["# The learned upsample kernel against a constant one\n", f"`{command_line()}`\n",
          f"Machine: {cpu_line(machine_info())}. The constant kernel: the learned one's mean per phase and "
          f"tap over the sample's 8 frames (centre taps {', '.join(f'{v:.3f}' for v in mean_k.reshape(4, 9)[:, 4])}; "
          f"the learned taps' mean spatial std {spread:.4f}). Deployed int8 pipeline, all frames, history carried.\n",
          "| sequence | learned PSNR / FLIP | constant PSNR / FLIP | constant - learned (dB) |",
          "| --- | --- | --- | ---: |"]
    for name, r in [*rows.items(), ("**mean**", mean)]:
        md.append(f"| {name} | {r['learned'][0]:.2f} / {r['learned'][1]:.4f} | {r['constant'][0]:.2f} / "
                  f"{r['constant'][1]:.4f} | {r['constant'][0] - r['learned'][0]:+.3f} |")
    write_report(args.out, {"command": command_line(), "mean_kernel": mean_k.tolist(), "spatial_std": spread,
                            "sequences": rows, "mean": mean}, "\n".join(md) + "\n")


if __name__ == "__main__":
    main()
