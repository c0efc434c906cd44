"""Write the model card of the shipped checkpoint; ship a training run's checkpoint with it.

    python -m tools.model_card --eval "benchmarks/results/model_eval*.json"
    python -m tools.model_card --run runs/NAME --model NAME --eval runs/NAME/eval.json

The first writes ``jnds_deploy/checkpoints/MODEL_CARD.md`` for the checkpoint beside it
(``--checkpoint``). The second ships a run first: its ``checkpoint.pt``, stripped of the
optimizer state (``checkpoint.ship_checkpoint``), becomes ``jnds.pt`` with the reports as
its metrics, then the card is written for it.

Everything on the card is read from the checkpoint and from ``jnds evaluate`` reports, so
the card cannot say more than they hold: the configuration, the training data and the
recipe in brief (``docs/training.md`` owns the full recipe), the scores per set against
OIDN ``balanced`` + bicubic, and where the model falls behind (``docs/model-gap.md`` says
why). The lineage of shipped models is in ``docs/changelog.md``, not on the card.
``--note`` adds a line under the scores, e.g. how the reports' settings differ from the
checkpoint's.
"""

from __future__ import annotations

import argparse
import glob
import json
import textwrap
from dataclasses import asdict
from pathlib import Path

import numpy as np

from jnds_deploy.checkpoint import read_checkpoint, ship_checkpoint
from jnds_deploy.model import ModelConfig, count_macs

ROOT = Path(__file__).resolve().parents[1]  # the repository root
PKG = ROOT / "jnds_deploy" / "checkpoints"
BASELINE = "oidn-balanced"
BASELINES = {"bicubic", "oidn-fast", "oidn-balanced", "oidn-high"}
METRICS = ("psnr", "flip", "temporal")
# the settings of ModelConfig that change no weight, and how `jnds run` turns each off
INFERENCE_SETTINGS = {
    "firefly_clamp": ("the firefly clamp at k = {v:g}", "--firefly-clamp 0"),
    "diffuse_fill": ("the diffuse fill", "--diffuse-fill off"),
    "albedo_at_holes": ("the albedo at holes", "--albedo-at-holes off"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--eval",
        nargs="+",
        required=True,
        metavar="REPORT",
        help="jnds evaluate reports (JSON) or quoted globs of them; a report of one set is named "
        "after its file (model_eval_<set>.json)",
    )
    ap.add_argument("--model", default="jnds", help="the method in the reports that is this checkpoint")
    ap.add_argument("--checkpoint", default=str(PKG / "jnds.pt"), help="the checkpoint the card describes")
    ap.add_argument("--run", default=None, help="ship this training run's checkpoint.pt as --out-dir/jnds.pt first")
    ap.add_argument("--note", action="append", default=[], help="a line under the scores (repeatable)")
    ap.add_argument("--out-dir", default=str(PKG), help="where the card (and a shipped checkpoint) go")
    args = ap.parse_args()

    sets = read_reports(args.eval, args.model)
    out_dir = Path(args.out_dir)
    ckpt_path = Path(args.checkpoint)
    if args.run:
        metrics = {name: {k: v for k, v in rep.items() if k != "_report"} for name, rep in sets.items()}
        ckpt_path = ship_checkpoint(Path(args.run) / "checkpoint.pt", out_dir / "jnds.pt", metrics=metrics)
    ckpt = read_checkpoint(ckpt_path)
    text = card(ckpt, sets, args.model, args.eval, args.note)
    out = out_dir / "MODEL_CARD.md"
    out.write_text(text)
    print(f"wrote {out} ({len(text.splitlines())} lines) for {ckpt_path}")


def read_reports(patterns: list[str], model: str) -> dict[str, dict]:
    """{set name: {method: result}} from every report, each set's report path under
    ``"_report"``; a set without ``model`` is an error."""
    sets: dict[str, dict] = {}
    for pattern in patterns:
        paths = sorted(glob.glob(pattern)) or [pattern]
        for path in map(Path, paths):
            report = json.loads(path.read_text())
            if any("mean" in v for v in report.values()):  # one set: name it after the file
                report = {path.stem.removeprefix("model_eval_") if path.stem != "model_eval" else "val": report}
            for name, rep in report.items():
                if model not in rep:
                    raise SystemExit(f"{path}: set {name} has no method {model!r} (it has {', '.join(rep)})")
                sets[name] = {**rep, "_report": str(path)}
    return sets


def parse_sequence(name: str) -> tuple[str, str, int]:
    """(renderer, scene kind, seed) of a sequence name: cycles-<kind>-<camera>-<seed> or
    <kind>-<camera>-<seed> (Mitsuba)."""
    head, seed = name.rsplit("-", 1)
    if head.startswith("cycles-"):
        return "Cycles", head.split("-")[1], int(seed)
    return "Mitsuba", head.split("-")[0], int(seed)


def _para(text: str) -> str:
    """A paragraph wrapped at 100 characters (markdown reads the same)."""
    return textwrap.fill(" ".join(text.split()), width=100, break_on_hyphens=False, break_long_words=False)


def card(ckpt: dict, sets: dict, model: str, reports: list[str], notes: list[str]) -> str:
    cfg = ModelConfig(**ckpt["model_config"])
    tcfg = ckpt.get("train_config") or {}
    trained = {parse_sequence(n)[:2] for n in ckpt.get("train_sequences") or []}
    intro = _para(f"""The default checkpoint of `jnds export` and the runtime (`jnds_deploy/checkpoints/jnds.pt`):
        the network of Thomas et al. 2022, "Temporally Stable Real-Time Joint Neural Denoising and
        Supersampling", in the `{tcfg.get("preset", "?")}` configuration. It denoises a frame of 1 sample per
        pixel and upsamples it {cfg.scale}x; trained in full precision, then quantization-aware for the int8
        pipeline. Where it falls short of OIDN and why: [docs/model-gap.md](../../docs/model-gap.md). How it
        came to be: [docs/changelog.md](../../docs/changelog.md).""")
    parts = [
        "# Model card: jnds",
        intro,
        configuration(ckpt, cfg),
        data(ckpt),
        recipe(tcfg, ckpt.get("state") or {}),
        scores(sets, model, trained, reports, notes),
        limitations(sets, model, trained),
    ]
    return "\n\n".join(parts) + "\n"


def configuration(ckpt: dict, cfg: ModelConfig) -> str:
    macs = count_macs(cfg)
    params = sum(p.numel() for p in ckpt["model"].values() if p.dtype.is_floating_point)
    rows = "\n".join(f"| `{k}` | `{json.dumps(v)}` |" for k, v in asdict(cfg).items())
    upsample = (
        "one learned upsample kernel for every pixel, no upsample graph"
        if cfg.upsample_width == 0
        else f"upsample block {macs.get('upsample_block', 0):.1f}"
    )
    on = [
        f"- {text.format(v=getattr(cfg, k))}: `jnds run {off}` turns it off"
        for k, (text, off) in INFERENCE_SETTINGS.items()
        if getattr(cfg, k)
    ]
    size = _para(f"""{params:,} parameters (activation ranges included); {macs["total"]:.1f} GMAC per 1280x720
        frame: input block {macs["input_block"]:.1f}, feature extractor {macs["feature_extractor"]:.1f}, output
        block {macs["output_block"]:.1f}; {upsample} (`jnds_deploy.model.count_macs`).""")
    settings = (
        ("\n\nSettings that change no weight (not in the paper; docs/model-gap.md says why), on:\n\n" + "\n".join(on))
        if on
        else ""
    )
    return f"""## Configuration

`model_config` of the checkpoint (`jnds_deploy.model.ModelConfig`; its comments say what each
field is):

| field | value |
| --- | --- |
{rows}

{size}{settings}"""


def _counts(items) -> list[tuple[str, int]]:
    counts: dict[str, int] = {}
    for item in items:
        counts[item] = counts.get(item, 0) + 1
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))


def data(ckpt: dict) -> str:
    parsed = [parse_sequence(n) for n in ckpt.get("train_sequences") or []]
    if parsed:
        per = [
            f"{n} {r} ({', '.join(f'{k} {c}' for k, c in _counts(p[1] for p in parsed if p[0] == r))})"
            for r, n in _counts(p[0] for p in parsed)
        ]
        what = f"{len(parsed)} training sequences: {' and '.join(per)}"
    else:
        what = "The training sequences are not recorded in the checkpoint"
    return "## Data\n\n" + _para(f"""{what}; 12 frames each at 192x108, 1 sample per pixel, with references
        at 384x216 rendered at 64 samples per target pixel. The scene kinds, camera paths and the commands
        that render them: [docs/dataset.md](../../docs/dataset.md). The evaluation sets below are other seeds,
        with references at 128 samples per target pixel.""")


def recipe(tcfg: dict, state: dict) -> str:
    if not tcfg:
        return "## Recipe\n\nNot recorded in the checkpoint."
    start = "Fine-tuned from the checkpoint shipped before it" if tcfg.get("init") else "Trained from scratch"
    aug = [
        text
        for key, text in (
            ("rotate_normals", "normal rotations"),
            ("flips", "flips"),
            ("colours", "colour permutations"),
            ("cross_cuts", "windows across camera cuts"),
            ("balance_renderers", "each renderer drawn half the time"),
        )
        if tcfg.get(key)
    ]
    if tcfg.get("exposure"):
        aug.insert(0, "exposure x2^{:g}..2^{:g}".format(*tcfg["exposure"]))
    loss = f"Eq. 3-5 (spatial weight {tcfg.get('w_spatial')}, spatial loss `{tcfg.get('spatial_loss')}`"
    loss += ", the feature loss being Eq. 6" if "feature" in str(tcfg.get("spatial_loss")) else ""
    loss += (
        f"), plus {tcfg['lowfreq_loss']:g} x the L1 of 4-, 8- and 16-pixel box averages (not in the paper)"
        if tcfg.get("lowfreq_loss")
        else ")"
    )
    device = f"{tcfg.get('threads', 2)} CPU cores" if tcfg.get("device", "cpu") == "cpu" else tcfg["device"]
    return "## Recipe\n\n" + _para(f"""{start}: {tcfg.get("fp32_steps")} fp32 steps, then
        {tcfg.get("qat_steps")} quantization-aware ({state.get("step", "?")} in all; phase at save:
        {state.get("phase", "?")}); batches of {tcfg.get("batch")} x {tcfg.get("unroll")} frames x
        {tcfg.get("patch")}^2 native pixels; AdamW at {tcfg.get("lr")} (quantization-aware {tcfg.get("qat_lr")}),
        x{tcfg.get("lr_decay")} over each phase; seed {tcfg.get("seed")}; on {device}. Loss: {loss}.
        Augmentations: {", ".join(aug) or "none"}. The recipe in full, its commands and why each choice:
        [docs/training.md](../../docs/training.md).""")


def _means(results: dict, names: list[str]) -> dict[str, float]:
    return {q: float(np.mean([results["sequences"][n][q] for n in names])) for q in METRICS}


def _seeds(parsed: list[tuple[str, str, int]]) -> str:
    """Seed ranges per renderer: '2000-2005, 6000-6005'."""
    ranges = []
    for r in sorted({p[0] for p in parsed}):
        seeds = [p[2] for p in parsed if p[0] == r]
        ranges.append(f"{min(seeds)}-{max(seeds)}" if len(seeds) > 1 else str(seeds[0]))
    return ", ".join(ranges)


def _rows(sets: dict, model: str, trained: set) -> list[tuple[str, str, dict, dict]]:
    """(label, sequences, model means, baseline means) per set, its renderers apart where it
    has both, then every set's sequences of trained and of unseen kinds together."""
    rows, pooled = [], {True: {}, False: {}}
    for name, rep in sets.items():
        seqs = list(rep[model]["sequences"])
        parsed = {n: parse_sequence(n) for n in seqs}
        renderers = sorted({p[0] for p in parsed.values()})
        label = name if name in ("val", "test") else " and ".join(sorted({p[1] for p in parsed.values()}))
        rows.append(
            (
                label,
                f"{len(seqs)} ({_seeds(list(parsed.values()))})",
                _means(rep[model], seqs),
                _means(rep[BASELINE], seqs),
            )
        )
        if len(renderers) > 1:
            for r in renderers:
                part = [n for n in seqs if parsed[n][0] == r]
                rows.append(
                    (f"{label}, its {r} half", str(len(part)), _means(rep[model], part), _means(rep[BASELINE], part))
                )
        for n in seqs:
            pooled[parsed[n][:2] in trained][n] = (rep[model]["sequences"][n], rep[BASELINE]["sequences"][n])
    for seen, label in ((True, "**all: kinds it trained on**"), (False, "**all: kinds it never trained on**")):
        if pooled[seen]:
            m, b = ({q: float(np.mean([v[i][q] for v in pooled[seen].values()])) for q in METRICS} for i in (0, 1))
            rows.append((label, str(len(pooled[seen])), m, b))
    return rows


def scores(sets: dict, model: str, trained: set, reports: list[str], notes: list[str]) -> str:
    lines = [
        f"| {label} | {n} | {m['psnr']:.2f} / {m['flip']:.4f} / {m['temporal']:.4f} | "
        f"{b['psnr']:.2f} / {b['flip']:.4f} / {b['temporal']:.4f} | {m['psnr'] - b['psnr']:+.2f} dB, "
        f"{m['flip'] - b['flip']:+.4f}, {m['temporal'] / b['temporal']:.2f}x |"
        for label, n, m, b in _rows(sets, model, trained)
    ]
    kinds = {parse_sequence(n)[:2] for rep in sets.values() for n in rep[model]["sequences"]}
    unseen = sorted(k for r, k in kinds - trained)
    multi: dict[str, list[str]] = {}
    for name, rep in sets.items():
        multi.setdefault(rep["_report"], []).append(name)
    commands = [
        f"`jnds evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt --data "
        f"{' '.join('data/' + n for n in names)} --baselines bicubic oidn-balanced --threads 2 --out {path}`"
        for path, names in multi.items()
        if len(names) > 1
    ]
    how = _para(f"""The checkpoint at int8 fake quantization, as `jnds evaluate` runs it (the deployed int8
        pipeline against fp32: [benchmarks/results/exposure_sweep.md](../../benchmarks/results/exposure_sweep.md)),
        against OIDN `balanced` on the 1-spp frame, upsampled bicubically; OIDN is given the albedo and
        normals (on Cycles frames Cycles' Denoising Albedo, as Blender's Denoise node). Every frame of
        every sequence against the reference at the target size; PSNR and FLIP on the displayed image
        (Reinhard, then gamma 2.2); temporal error is Eq. 5. The reports: `{"`, `".join(reports)}`, the column
        `{model}`, a contact sheet beside each; {" and ".join(commands) or "one `jnds evaluate` per set"},
        the other reports likewise on their sets. Scene kinds it never trained on: {", ".join(unseen) or "none"}.""")
    note = "\n" + "\n".join(_para(f"- {n}").replace("\n", "\n  ") for n in notes) if notes else ""
    return f"""## Scores

{how}

| set | sequences (seeds) | PSNR / FLIP / temporal | OIDN `balanced` + bicubic | difference, temporal ratio |
| --- | --- | --- | --- | --- |
{chr(10).join(lines)}
{note}"""


def limitations(sets: dict, model: str, trained: set) -> str:
    behind, ahead = [], []
    for label, _, m, b in _rows(sets, model, trained):
        if label.startswith("**") or ", its " in label:
            continue
        (behind if m["psnr"] < b["psnr"] else ahead).append(f"{label} ({m['psnr'] - b['psnr']:+.2f} dB)")
    return (
        "## Limitations\n\n"
        + _para(
            f"""- Behind OIDN `balanced` + bicubic in PSNR on: {"; ".join(behind) or "no set"}. Ahead on: {
                "; ".join(ahead) or "no set"
            }."""
        ).replace("\n", "\n  ")
        + "\n"
        + _para(
            """- Known failures, measured and explained in [docs/model-gap.md](../../docs/model-gap.md): scene
        kinds unlike its training data, participating media, mirrors and glossy reflections, hair, thin
        geometry, the first frame and the frame after a camera cut, and trails behind moving objects where
        the history is wrong."""
        ).replace("\n", "\n  ")
    )


if __name__ == "__main__":
    main()
