"""Write the shipped checkpoint and its model card from a finished (or stopped) run.

    python -m tools.model_card --run runs/small --eval benchmarks/results/model_eval.json
    python -m tools.model_card --run runs/ft-feature-long --base-run runs/small runs/ft-feature \
        --model ft-feature-long --compare runs/ft-l1 runs/ft-feature --eval benchmarks/results/model_eval.json
    python -m tools.model_card --run runs/gpu-mixed-from-l1 --base-run runs/small \
        --compare runs/gpu-feature runs/gpu-mixed runs/gpu-mixed-from-l1 --limitations L.md --gap G.md
    python -m tools.model_card --run runs/NAME --lineage HEAD:jnds_deploy/checkpoints/MODEL_CARD.md \
        --eval benchmarks/results/model_eval.json --model NAME --gap docs/model-gap.md

The run directories (``runs/``, not tracked in git) are the ones training wrote
(``jnds train --run DIR``): ``checkpoint.pt`` and ``log.jsonl`` in each.

A run trained with ``--device cuda`` (``tools/gpu_train.sh``) is described as trained
on ``--gpu`` with the data that script renders.

A run started with ``jnds train --init`` (fine-tuning) is described with the runs it
descends from (``--base-run``); ``--compare`` adds a table of runs and the training
settings they differ in (e.g. the L1 / feature-loss comparison of Sec. 3.3).

Copies ``<run>/checkpoint.pt`` (stripped of optimizer state, ``checkpoint.ship_checkpoint``)
to ``jnds_deploy/checkpoints/jnds.pt`` (or --out-dir) and writes ``MODEL_CARD.md``
beside it with the configuration, data, steps, hours and the validation numbers of
``jnds evaluate``.
"""
from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import ROOT, arguments, cpu_model, write_text
from jnds_deploy.checkpoint import read_checkpoint, ship_checkpoint
from jnds_deploy.model import ModelConfig, count_macs
from jnds_deploy.training.evaluate import markdown_sets, markdown_table

PKG = ROOT / "jnds_deploy" / "checkpoints"


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--run", default="runs/small")
    ap.add_argument("--eval", default="benchmarks/results/model_eval.json")
    ap.add_argument("--command", default="", help="the jnds evaluate command that made --eval")
    ap.add_argument("--model", default=None, help="the method of --eval that is this run (default: the first)")
    ap.add_argument("--base-run", nargs="*", default=[],
                    help="the runs a fine-tuning run (--init) descends from, from scratch to its parent")
    ap.add_argument("--compare", nargs="*", default=[], help="runs to tabulate with the training settings they differ in")
    ap.add_argument("--cpu", default=cpu_model(), help="processor the run trained on (default: this one)")
    ap.add_argument("--gpu", default="one NVIDIA H100 80GB HBM3 of a lent machine, shared by the 3 runs of "
                    "tools/gpu_train.sh", help="the GPU a --device cuda run trained on")
    ap.add_argument("--limitations", default=None, help="a markdown file of known limitations to include")
    ap.add_argument("--gap", default=None, help="a markdown file: where it falls short of OIDN and why")
    ap.add_argument("--lineage", default=None,
                    help="a previous model card (a file, or REV:PATH in git) whose runs this run descends "
                         "from, when their run directories are gone (sessions start without runs/): its run "
                         "paragraphs, totals and validation histories are carried over")
    ap.add_argument("--data-command", default=None, help="the jnds dataset commands that rendered the run's data/train")
    ap.add_argument("--out-dir", default=str(PKG), help="where the checkpoint and card go (default: the package)")
    args = ap.parse_args()

    run = Path(args.run)
    log = _log(run)
    ckpt = read_checkpoint(run / "checkpoint.pt")
    sets = json.loads(Path(args.eval).read_text())
    if any("mean" in v for v in sets.values()):  # one set's report (jnds evaluate --data with one set)
        sets = {"val": sets}
    report = sets["val"] if "val" in sets else next(iter(sets.values()))  # validation: the card's verdict
    training = [_training_lines(run, ckpt, log, args.cpu, args.gpu, args.data_command)]
    if ckpt["train_config"].get("init") and not (args.base_run or args.lineage):
        raise SystemExit(f"{run} was fine-tuned from {ckpt['train_config']['init']}: pass --base-run or --lineage")
    if args.lineage:
        training.insert(0, _lineage(Path(args.lineage)))
    for i, base in enumerate(map(Path, args.base_run)):
        # the first run of the chain trained in an earlier session, on another machine
        cpu = "AMD EPYC with AVX-512, as recorded by hand then" if i == 0 else args.cpu
        base_ckpt = read_checkpoint(base / "checkpoint.pt")
        training.insert(i, _training_lines(base, base_ckpt, _log(base), cpu, args.gpu))
    out_dir = Path(args.out_dir)
    out = ship_checkpoint(run / "checkpoint.pt", out_dir / "jnds.pt", metrics=sets)

    cfg = ModelConfig(**ckpt["model_config"])
    macs = count_macs(cfg)
    baselines = {"bicubic", "oidn-fast", "oidn-balanced", "oidn-high"}
    model_key = args.model or next(k for k in report if k not in baselines)
    verdict = []
    for (set_name, rep), b in ((x, b) for x in sets.items() for b in ("bicubic", "oidn-balanced")):
        if b in rep:
            m, o = rep[model_key]["mean"], rep[b]["mean"]
            verdict.append(f"- {set_name}, vs {b}: PSNR {m['psnr'] - o['psnr']:+.2f} dB, FLIP {m['flip'] - o['flip']:+.4f}, "
                           f"temporal error {m['temporal'] - o['temporal']:+.5f} "
                           f"({'beats' if m['psnr'] > o['psnr'] and m['flip'] < o['flip'] else 'does not beat'} it "
                           f"in PSNR and FLIP; temporal error {'lower' if m['temporal'] < o['temporal'] else 'higher'})")
    verdict += _renderer_verdict(sets, model_key)
    verdict = "\n".join(verdict)
    steps = sum(t["steps"] for t in training)
    hours = sum(t["hours"] for t in training)
    training_text = "\n\n".join(t["text"] for t in training)
    compare = _compare_table(args.compare, report) if args.compare else ""
    limitations = (f"Known limitations:\n\n{Path(args.limitations).read_text().strip()}\n\n"
                   if args.limitations else "")
    history = "\n\n".join(t["history"] for t in training)
    gap = (Path(args.gap).read_text().strip() if args.gap else
           f"Where it falls short of OIDN, what would close the gap: this is {steps} steps ({hours:.1f} h; "
           "the paper trains 500 + 500 epochs on GPUs); longer training and the wider `paper` preset.")
    text = f"""# Model card: jnds

The default checkpoint of `jnds export` and the runtime: the JNDS network
(Thomas et al. 2022) in the `{ckpt["train_config"]["preset"]}` configuration, trained on this project's renders
(docs/dataset.md), full precision then quantization-aware (int8 fake quantization).

## Configuration

```json
{json.dumps(ckpt["model_config"], indent=1)}
```

{sum(p.numel() for p in ckpt["model"].values() if p.dtype.is_floating_point):,} parameters (activation ranges included);
{macs["total"]:.1f} GMAC per 1280x720 frame (input block {macs["input_block"]:.1f}, feature extractor
{macs["feature_extractor"]:.1f}, output block {macs["output_block"]:.1f}, upsample block
{macs.get("upsample_block", 0):.1f}{"; one fixed upsample kernel, no upsample graph" if ckpt["model_config"].get("upsample_width", 8) == 0 else ""}), counted by `jnds_deploy.model.count_macs`.

## Training

Data: `jnds dataset --out data` (docs/dataset.md): data/train, 24 sequences x 12 frames at
192x108 -> 384x216 by default, reference 64 spp per target pixel; `--train-sequences`
adds seeds (a run below that had more says so), and runs on a GPU render their own
copy. In all: {steps} steps, {hours:.2f} h (machines per run below).

{training_text}
{compare}
## Validation{" and test" if len(sets) > 1 else ""} ({", ".join(f"{k}: {len(v[model_key]['sequences'])} sequences" for k, v in sets.items())}; 12 frames each, unseen seeds, 128 spp references)

Against the 2x reference colour; metrics of `jnds_deploy.metrics` (LDR: Reinhard then
gamma 2.2); temporal error is Eq. 5 against the reference. {args.command}

{markdown_table(report) if len(sets) == 1 else markdown_sets(sets)}

`{model_key}` is this checkpoint at int8 fake quantization.

{verdict}

{limitations}{gap}

During training (step, phase, PSNR, SSIM, FLIP, temporal error; validation inside
`jnds train`, on the sequences present at the time, by the model code of the time:
runs before 2026-11-23 had no geometric history rejection):

{history}

This card: `python -m tools.model_card {" ".join(shlex.quote(a) for a in sys.argv[1:])}`.
"""
    write_text(out_dir / "MODEL_CARD.md", text)
    print(f"wrote {out} ({out.stat().st_size / 1e3:.0f} kB) and {out_dir / 'MODEL_CARD.md'}")


def _log(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines() if line.strip()]


def _lineage(card: Path) -> dict:
    """The runs of a previous model card, as that card described them: its run paragraphs
    (from its Training section), its step and hour totals and its validation histories."""
    # a file, or a card in git (REV:PATH, e.g. the one shipped before: HEAD:jnds_deploy/checkpoints/MODEL_CARD.md)
    text = card.read_text() if card.is_file() else subprocess.run(["git", "show", str(card)], cwd=ROOT, check=True,
                                                                  capture_output=True, text=True).stdout
    body = text.split("## Training\n", 1)[1].split("\n\n", 1)[1]
    runs = re.split(r"\nRuns compared|\n## Validation", body, maxsplit=1)[0].strip()
    history = text.split("had no geometric history rejection):\n\n", 1)[1].split("\n\nThis card:", 1)[0].strip()
    steps, hours = re.search(r"In all: (\d+) steps, ([\d.]+) h", text).groups()
    return {"text": runs, "history": history, "steps": int(steps), "hours": float(hours)}


def _training_lines(run: Path, ckpt: dict, log: list[dict], cpu: str, gpu: str, data_command: str | None = None) -> dict:
    """One run's part of the card: what it trained, how long, with which command."""
    tcfg = ckpt["train_config"]
    # wall-clock hours from the log's timestamps, skipping gaps (pauses) longer than 10 min
    times = [r["time"] for r in log]
    hours = sum(min(b - a, 600) for a, b in zip(times, times[1:])) / 3600
    step = ckpt["state"]["step"]
    init = tcfg.get("init")
    on_gpu = tcfg.get("device", "cpu") != "cpu"
    data = "/tmp/data" if on_gpu else "data"
    cmd = (f"jnds train --data {data} --run {run} --preset {tcfg['preset']} --fp32-steps {tcfg['fp32_steps']} "
           f"--qat-steps {tcfg['qat_steps']}")
    if tcfg.get("upsample_root", 1) != 1:
        cmd += f" --upsample-root {tcfg['upsample_root']}"
    if tcfg.get("firefly_clamp"):
        cmd += f" --firefly-clamp {tcfg['firefly_clamp']:g}"
    for key, default in (("batch", 4), ("patch", 64), ("unroll", 6), ("burn_in", 0), ("seed", 0)):
        if tcfg.get(key, default) != default:
            cmd += f" --{key.replace('_', '-')} {tcfg[key]}"
    if tcfg.get("threads", 2) != 2:
        cmd += f" --threads {tcfg['threads']}"
    if init:
        cmd += f" --init {init} --lr {tcfg['lr']} --qat-lr {tcfg['qat_lr']}"
        if tcfg.get("deepen_blend", -4.0) != -4.0:
            cmd += f" --deepen-blend {tcfg['deepen_blend']:g}"
    if tcfg.get("warmup_steps"):
        cmd += f" --warmup-steps {tcfg['warmup_steps']}"
    if tcfg["spatial_loss"] != "l1":
        cmd += f" --spatial-loss {tcfg['spatial_loss']} --feature-net {tcfg['feature_net']}"
    if tcfg.get("exposure"):
        cmd += " --exposure {:g} {:g}".format(*tcfg["exposure"])
    for key in ("rotate_normals", "flips", "colours", "fixed_upsample", "cross_cuts", "balance_renderers"):
        if tcfg.get(key):
            cmd += " --" + key.replace("_", "-")
    if tcfg.get("clean_references"):
        cmd += f" --clean-references {tcfg['clean_references']}"
    if on_gpu:
        cmd += f" --device {tcfg['device']}"
    where = f"one GPU ({gpu})" if on_gpu else f"2 CPU cores ({cpu})"
    data_line = ("\n- Data: rendered on that machine by `tools/gpu_train.sh` (`jnds dataset --train-sequences "
                 "40 --variant cuda_ad_rgb`): the 24 training sequences and 16 more seeds (1024-1039), "
                 "same sizes and spp; validation inside the run on its own render of data/val."
                 if on_gpu else _data_line(ckpt.get("train_sequences"), data_command))
    # --init widens a narrower checkpoint to the run's preset (train._widened)
    start = (f"fine-tuned from `{init}` as it was then (the run above) in the `{tcfg['preset']}` preset"
             if init else "trained from scratch")
    text = f"""`{run}`, {start}:
- Steps: {step} ({tcfg["fp32_steps"]} fp32, then up to {tcfg["qat_steps"]} QAT; phase at save:
  {ckpt["state"]["phase"]}); batch {tcfg["batch"]} x unroll {tcfg["unroll"]} frames x {tcfg["patch"]}^2 native patches;
  AdamW, lr {tcfg["lr"]} (QAT {tcfg["qat_lr"]}) decaying x{tcfg["lr_decay"]} per phase.
- Loss: Eq. 3-5, w_spatial {tcfg["w_spatial"]}, spatial loss `{tcfg["spatial_loss"]}`{_lowfreq(tcfg)}.{_feature_net_line(tcfg)}{data_line}
- Time: {hours:.2f} h on {where}.
- Command: `{cmd}`"""
    vals = [r for r in log if r.get("event") == "val"]
    history = "\n".join([f"`{run}`:", "", "| step | phase | PSNR | SSIM | FLIP | temporal |",
                         "| --- | --- | --- | --- | --- | --- |"]
                        + [f"| {r['step']} | {r['phase']} | {r['mean']['psnr']:.2f} | {r['mean']['ssim']:.4f} | "
                           f"{r['mean']['flip']:.4f} | {r['mean']['temporal']:.5f} |" for r in vals])
    return {"text": text, "history": history, "steps": step, "hours": hours}


def _data_line(names: list[str] | None, command: str | None = None) -> str:
    """The training sequences a CPU run sampled from, as its checkpoint recorded them
    (older checkpoints did not record them: they sampled the default 24)."""
    if not names:
        return ""
    if command:  # several generators: count each (the name's prefix up to its seed says which)
        groups: dict[str, list[int]] = {}
        for n in names:
            head, seed = n.rsplit("-", 1)
            kind = "Cycles " + head.split("-")[1] if head.startswith("cycles-") else "Mitsuba " + head.split("-")[0]
            groups.setdefault(kind, []).append(int(seed))
        parts = ", ".join(f"{len(v)} {k} (seed{'s' if len(v) > 1 else ''} {min(v)}{f'-{max(v)}' if len(v) > 1 else ''})"
                          for k, v in sorted(groups.items()))
        return f"\n- Data: {len(names)} sequences of data/train: {parts}; rendered by `{command}`."
    tails = [n.rsplit("-", 1)[-1] for n in names]
    seeds = sorted(int(t) for t in tails if t.isdigit())
    which = f"seeds {seeds[0]}-{seeds[-1]}" if len(seeds) == len(names) else ", ".join(names)
    return (f"\n- Data: {len(names)} sequences of data/train ({which}; "
            f"`jnds dataset --out data --split train --train-sequences {len(names)}` renders seeds 1000 on).")


def _lowfreq(tcfg: dict) -> str:
    """The low-frequency term of the spatial loss, where the run had one (not in the paper)."""
    w = tcfg.get("lowfreq_loss", 0.0)
    return (f" plus {w:g} x the L1 of 4-, 8- and 16-pixel box averages on the radiance tasks "
            "(`--lowfreq-loss`, `training.losses.lowfreq`)") if w else ""


def _feature_net_line(tcfg: dict) -> str:
    if "feature" not in tcfg["spatial_loss"]:
        return ""
    f = torch.load(tcfg["feature_net"], weights_only=False)
    return (f"\n- Feature-loss network (Eq. 6, `jnds_deploy.training.feature_loss`): `{tcfg['feature_net']}`, "
            f"`jnds train-feature-net`, {f['config']['steps']} steps predicting the G-buffer from converged "
            f"renders of data/train, final L1 {f['final_l1']:.4f}.")


def _renderer_verdict(sets: dict, model_key: str, baseline: str = "oidn-balanced") -> list[str]:
    """Verdict lines against ``baseline`` for each renderer's sequences apart, in the sets
    that hold both: the test set's Cycles half is made of scene kinds no training
    generator makes, its Mitsuba half of new seeds of the training generators, and a
    mean over both can hide a loss on the first (issue 24)."""
    lines = []
    for set_name, rep in sets.items():
        if baseline not in rep:
            continue
        names = list(rep[model_key]["sequences"])
        halves = {"Cycles": [n for n in names if n.startswith("cycles-")],
                  "Mitsuba": [n for n in names if not n.startswith("cycles-")]}
        if not all(halves.values()):
            continue
        for renderer, part in halves.items():
            m, o = ({q: float(np.mean([rep[k]["sequences"][n][q] for n in part])) for q in ("psnr", "flip", "temporal")}
                    for k in (model_key, baseline))
            lines.append(f"- {set_name}, {renderer} sequences only ({len(part)}), vs {baseline}: "
                         f"PSNR {m['psnr'] - o['psnr']:+.2f} dB, FLIP {m['flip'] - o['flip']:+.4f}, "
                         f"temporal error {m['temporal'] / o['temporal']:.2f}x")
    return lines


def _compare_table(runs: list[str], report: dict) -> str:
    """Runs scored by the same ``jnds evaluate``, with the training settings they differ in
    (read from their checkpoints, so the sentence cannot go stale)."""
    ckpts = [read_checkpoint(Path(r) / "checkpoint.pt") for r in runs]
    tcfgs = [c["train_config"] for c in ckpts]
    seqs = [len(c["train_sequences"]) if c.get("train_sequences") else "not recorded" for c in ckpts]
    keys = sorted({k for t in tcfgs for k in t} - {"run"})
    differ = [k for k in keys if len({json.dumps(t.get(k), sort_keys=True) for t in tcfgs}) > 1]
    rows = []
    for r, tcfg, n in zip(runs, tcfgs, seqs):
        m = report[Path(r).name]["mean"]
        rows.append(f"| `{r}` | `{tcfg.get('init')}` | {n} | {tcfg['spatial_loss']} | {tcfg.get('upsample_root', 1)} | "
                    f"{tcfg['fp32_steps']} + {tcfg['qat_steps']} | {tcfg['batch']} x {tcfg['unroll']} x "
                    f"{tcfg['patch']}^2 | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['flip']:.4f} | "
                    f"{m['temporal']:.5f} |")
    same = ", ".join(f"`{k}`" for k in differ) or "nothing"
    return "\n".join(["", "Runs compared (scores from `--eval`, int8 fake quantization). Their training",
                      f"settings (`train_config` in the checkpoints) differ only in: {same}. An init",
                      "of the shipped checkpoint means the one shipped when the run started.", "",
                      "Training sequences: the number in data/train when the run sampled it (checkpoints",
                      "record it since 2026-11-23; earlier CPU runs sampled the default 24, GPU runs 40).", "",
                      "| run | init | training sequences | spatial loss | upsample root | steps (fp32 + QAT) "
                      "| batch x unroll x patch | PSNR (dB) | SSIM | FLIP | temporal error |",
                      "| --- | --- | ---: | --- | ---: | --- | --- | --- | --- | --- | --- |", *rows, ""])


if __name__ == "__main__":
    main()
