"""Cheap references: a sequence's reference rendered again at few samples per pixel and
cleaned as `jnds train --clean-references oidn` cleans one, against the full reference.

    .venv/bin/python experiments/cheap_references.py --data SEQ [SEQ ...] [--spp 8]
        [--work /tmp/cheap_references] [--out benchmarks/results/cheap_references]

Each sequence is rendered again (``jnds_deploy.render.sequence.render_sequence``: its own
render.json's configuration, the reference at ``--spp`` samples per target pixel; resumed
from ``--work``). Four comparisons per sequence, mean over its frames (PSNR and FLIP of
``jnds_deploy.metrics``, as `jnds evaluate` scores): the cheap reference raw and cleaned
against the full one; the cheap one cleaned against the full one cleaned (two estimates of
the same noise-free image); the full one against itself cleaned (how much noise the full
reference keeps). If the cheap cleaned reference is as close to the full one as the full
one is to its own cleaned self, it is as good a training target for a loss that cannot
see the noise anyway. Writes .md and .json, and a sheet (.jpg) of the middle frames.
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, cpu_line, machine_info, write_report  # noqa: E402
from jnds_deploy import contact_sheet  # noqa: E402
from jnds_deploy.metrics import frame_metrics  # noqa: E402
from jnds_deploy.render.sequence import RenderConfig, render_sequence  # noqa: E402
from jnds_deploy.training.data import clean_references, load_sequence  # noqa: E402

COMPARISONS = (("cheap raw", "full"), ("cheap cleaned", "full"), ("cheap cleaned", "full cleaned"),
               ("full", "full cleaned"))


def colours(seq) -> np.ndarray:
    return seq.ref["color"].transpose(0, 2, 3, 1)


def cleaned(seq, path: Path) -> np.ndarray:
    """The cleaned colour, computed afresh: no cache is written beside ``path``'s frames (a
    data set): ``clean_references`` skips the cache where it cannot write it."""
    return colours(clean_references(seq, Path("/nonexistent") / path.name))


def scores(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    f = [frame_metrics(x, y) for x, y in zip(a, b)]
    return {"psnr": float(np.mean([g["psnr"] for g in f])), "flip": float(np.mean([g["flip"] for g in f]))}


def main() -> None:
    p = arguments(__doc__, RESULTS / "cheap_references")
    p.add_argument("--data", nargs="+", required=True, help="sequences with their full references")
    p.add_argument("--spp", type=int, default=8, help="the cheap reference's samples per target pixel")
    p.add_argument("--work", default="/tmp/cheap_references", help="where the cheap renders go (resumed)")
    args = p.parse_args()
    rows, shown = {}, []
    for full_path in map(Path, args.data):
        config = json.loads((full_path / "render.json").read_text())["config"]
        cfg = replace(RenderConfig(**{**config, "size": tuple(config["size"])}), spp=args.spp)
        cheap_path = Path(args.work) / f"{full_path.name}-spp{args.spp}"
        # a finished sequence is kept (a Cycles render starts again where its frames are imported)
        times = {} if (cheap_path / "sequence.json").exists() else render_sequence(cfg, cheap_path, progress=False)
        full, cheap = load_sequence(full_path), load_sequence(cheap_path)
        if np.abs(full.ref["albedo"] - cheap.ref["albedo"]).mean() > 0.05:
            raise SystemExit(f"{cheap_path}: not the scene of {full_path} (albedo differs)")
        images = {"full": colours(full), "full cleaned": cleaned(full, full_path),
                  "cheap raw": colours(cheap), "cheap cleaned": cleaned(cheap, cheap_path)}
        row = {"full_spp": config["spp"], "cheap_spp": args.spp, "engine": config.get("engine", "mitsuba"),
               "cheap_reference_s_per_frame": times.get("reference")}
        for a, b in COMPARISONS:
            row[f"{a} vs {b}"] = scores(images[a], images[b])
        rows[full_path.name] = row
        print(full_path.name, json.dumps(row), flush=True)
        mid = len(images["full"]) // 2
        shown.append((full_path.name, {k: images[k][mid] for k in ("cheap raw", "cheap cleaned", "full cleaned",
                                                                   "full")}))
    out = Path(args.out)
    contact_sheet.write(out.with_suffix(".jpg"), shown)
    report = {"command": command_line(), "machine": machine_info(), "spp": args.spp, "sequences": rows}
    md = ["# Cheap references, cleaned, against the full ones", "",
          f"Command: `{report['command']}`  ",
          f"Machine: {cpu_line(report['machine'])}; cleaning: OIDN `high` on the reference's diffuse and specular "
          "components, colour recomposed (`jnds train --clean-references oidn`).", "",
          "PSNR (dB) / FLIP, mean over each sequence's frames; \"full\": the sequence's own reference; \"cheap\": "
          f"the same frames rendered again with {args.spp} samples per target pixel. "
          f"Sheet: [{out.with_suffix('.jpg').name}]({out.with_suffix('.jpg').name}) (middle frames: cheap raw, cheap "
          "cleaned, full cleaned, full).", "",
          "| sequence | full spp | cheap ref s/frame | " + " | ".join(f"{a} vs {b}" for a, b in COMPARISONS) + " |",
          "| --- | ---: | ---: |" + " ---: |" * len(COMPARISONS)]
    for name, r in rows.items():
        t = r["cheap_reference_s_per_frame"]
        md.append(f"| {name} | {r['full_spp']} | {'-' if t is None else f'{t:.1f}'} | " + " | ".join(
            f"{r[f'{a} vs {b}']['psnr']:.2f} / {r[f'{a} vs {b}']['flip']:.4f}" for a, b in COMPARISONS) + " |")
    write_report(out, report, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
