"""Where the model's error comes from: each filtered signal replaced by the reference.

    .venv/bin/python experiments/error_sources.py --data data/val [--checkpoint CKPT]
        [--out benchmarks/results/error_sources]

PyTorch, the shipped checkpoint (or --checkpoint) at int8 fake quantization, every frame
of every sequence, history as in ``jnds evaluate``. At each frame's composite (Eq. 2) the
filtered diffuse, specular or albedo -- or all three -- is replaced by the reference
component, 2x2 average-pooled to native resolution; the upsample block then runs as
usual on that composite with the network's features. The history always carries the
model's own filtered signals, so a replacement changes that frame's output only. The
PSNR gained by a replacement is what a perfect filter for that signal would give; what
is left with all three replaced is the upsample block's share (with a native composite
that is not quite the pooled reference colour: the product of pooled albedo and pooled
diffuse is not the pooled product).

For scale, the reference colour itself is pooled to native and upsampled back with
nearest, bilinear and bicubic interpolation (cv2.resize), and bilinearly in fourth roots
(``ModelConfig.upsample_root`` 4): what is lost there is detail finer than a native
pixel, which no native-resolution signal holds. OIDN balanced + bicubic
(``baselines.oidn_bicubic``, the baseline of issue 3) is scored on the same frames, and
OIDN's output upsampled in 4th roots too.
Writes benchmarks/results/error_sources.md and .json.
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, write_report  # noqa: E402
from jnds_deploy import baselines, filters  # noqa: E402
from jnds_deploy.checkpoint import default_checkpoint, load_model  # noqa: E402
from jnds_deploy.io import expand_sequences, open_sequence  # noqa: E402
from jnds_deploy.metrics import psnr  # noqa: E402
from jnds_deploy.model import pad_to_multiple  # noqa: E402
from jnds_deploy.training.data import load_sequence  # noqa: E402

REPLACED = ("none", "diffuse", "specular", "albedo", "all three")
RESIZE = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "bicubic": cv2.INTER_CUBIC}


@torch.no_grad()
def replaced_outputs(model, seq) -> dict[str, list[np.ndarray]]:
    """Per REPLACED entry, the target-resolution output of every frame (HWC)."""
    model.eval()
    s, m = model.cfg.scale, model.cfg.pad_multiple
    net = {}
    hook = model.network.register_forward_hook(lambda mod, inp, out: net.update(out))
    outs = {r: [] for r in REPLACED}
    history = None
    try:
        for t in range(len(seq.cuts)):
            cur, (h, w) = pad_to_multiple(torch.from_numpy(seq.current[t:t + 1]), m)
            mv, _ = pad_to_multiple(torch.from_numpy(seq.motion[t:t + 1]), m)
            out = model(cur, mv, None if (t == 0 or seq.cuts[t]) else history)
            history = out.history()
            ref = {c: pad_to_multiple(F.avg_pool2d(torch.from_numpy(seq.ref[c][t:t + 1]), s), m)[0]
                   for c in ("diffuse", "specular", "albedo")}
            for r in REPLACED:
                sig = {"diffuse": out.diffuse, "specular": out.specular, "albedo": out.albedo}
                for c in sig:
                    if r in (c, "all three"):
                        sig[c] = ref[c]
                comp = filters.composite(sig["albedo"], sig["diffuse"], sig["specular"])
                y = model.upsample(comp, net.get("features"))
                outs[r].append(y[0, :, :h * s, :w * s].permute(1, 2, 0).numpy())
    finally:
        hook.remove()
    return outs


def resized_reference(refs: list[np.ndarray], scale: int) -> dict[str, list[np.ndarray]]:
    out = {name: [] for name in (*RESIZE, "bilinear, 4th roots")}
    for r in refs:
        h, w = r.shape[:2]
        native = cv2.resize(r, (w // scale, h // scale), interpolation=cv2.INTER_AREA)
        for name, interp in RESIZE.items():
            out[name].append(np.maximum(cv2.resize(native, (w, h), interpolation=interp), 0))
        out["bilinear, 4th roots"].append(root_upsample(native, scale))
    return out


def root_upsample(image: np.ndarray, scale: int) -> np.ndarray:
    """Bilinear upsampling of an HWC image's 4th roots, raised back to the 4th power."""
    h, w = image.shape[:2]
    roots = np.sqrt(np.sqrt(np.maximum(image, 0)))
    return cv2.resize(roots, (w * scale, h * scale), interpolation=cv2.INTER_LINEAR) ** 4


def main() -> int:
    ap = arguments(__doc__, RESULTS / "error_sources")
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument("--checkpoint", default=None)
    args = ap.parse_args()
    torch.set_num_threads(2)
    model = load_model(args.checkpoint or default_checkpoint())
    if model.upsample_block is None:
        raise SystemExit("error_sources.py needs a model with an upsample block (scale > 1)")
    result = {"checkpoint": str(args.checkpoint or "shipped"), "sequences": {}}
    for path in expand_sequences(args.data):
        seq = load_sequence(path)
        refs = [r.transpose(1, 2, 0) for r in seq.ref["color"]]
        raw = open_sequence(path)
        methods = {f"model, {r} replaced": o for r, o in replaced_outputs(model, seq).items()}
        denoised = [baselines.oidn(raw.inputs(i), quality="balanced") for i in range(len(raw))]
        methods["OIDN balanced + bicubic"] = [baselines.bicubic(d, seq.scale) for d in denoised]
        methods["OIDN balanced + bilinear of 4th roots"] = [root_upsample(d, seq.scale) for d in denoised]
        methods.update({f"reference pooled, {k} up": o for k, o in resized_reference(refs, seq.scale).items()})
        name = f"{Path(path).parent.name}/{Path(path).name}"
        result["sequences"][name] = {k: float(np.mean([psnr(o, r) for o, r in zip(v, refs)]))
                                     for k, v in methods.items()}
        print(name, "  ".join(f"{k}: {v:.2f}" for k, v in result["sequences"][name].items()), flush=True)
    out = Path(args.out)
    seqs = list(result["sequences"])
    cols = list(result["sequences"][seqs[0]])
    mean = {c: float(np.mean([result["sequences"][s][c] for s in seqs])) for c in cols}
    lines = ["# Where the model's error comes from",
             "",
             f"Command: `{command_line()}`  ",
             f"Checkpoint: {result['checkpoint']}, PyTorch, int8 fake quantization. PSNR (dB) against the "
             "reference colour, mean over each sequence's frames. \"replaced\": that filtered signal is "
             "the reference's, pooled to native, at the composite (see the script's docstring).",
             "",
             "| method | " + " | ".join(s.split("/")[-1] for s in seqs) + " | mean |",
             "| --- | " + " | ".join("---:" for _ in seqs) + " | ---: |"]
    for c in cols:
        lines.append(f"| {c} | " + " | ".join(f"{result['sequences'][s][c]:.2f}" for s in seqs)
                     + f" | {mean[c]:.2f} |")
    base = mean["model, none replaced"]
    lines += ["", "Mean gain over the model when a signal is replaced: "
              + ", ".join(f"{r} {mean[f'model, {r} replaced'] - base:+.2f} dB" for r in REPLACED[1:]) + "."]
    write_report(out, result, "\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
