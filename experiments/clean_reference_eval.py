"""Two checkpoints scored against the references and against the same references cleaned
(``training.data.clean_references``: OIDN ``high`` on the reference's diffuse and specular,
colour recomposed, as ``jnds train --clean-references oidn`` trains). A diagnostic for a
choice between two of our models whose references keep noise (docs/model-gap.md, "The
references keep noise"), not a score against OIDN: cleaned references favour OIDN's look,
so no OIDN column.

    .venv/bin/python experiments/clean_reference_eval.py --checkpoint A.pt B.pt --data data/val \
        [--out benchmarks/results/clean_reference_eval]

Writes the means and per-sequence PSNR / FLIP of each checkpoint against both references.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, cpu_line, machine_info, write_report  # noqa: E402
from jnds_deploy.checkpoint import load_model  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.training.evaluate import evaluate_model, method_name  # noqa: E402
from jnds_deploy.training.data import clean_references, load_sequence  # noqa: E402


def main() -> int:
    ap = arguments(__doc__, RESULTS / "clean_reference_eval")
    ap.add_argument("--checkpoint", nargs="+", required=True)
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    paths = expand_sequences(args.data)
    rendered = [load_sequence(p) for p in paths]  # read once, cleaned in memory
    refs = {"as rendered": rendered, "cleaned": [clean_references(s, p) for s, p in zip(rendered, paths)]}
    report = {"command": command_line(), "machine": machine_info(), "data": args.data, "results": {}}
    for ck in args.checkpoint:
        model = load_model(ck)
        report["results"][method_name(ck)] = {k: evaluate_model(model, seqs) for k, seqs in refs.items()}
    names = list(report["results"])
    md = ["# Against the references as rendered and cleaned", "", f"Command: `{report['command']}`  ",
          f"Machine: {cpu_line(report['machine'])}. Cleaned: OIDN `high` on each reference's diffuse and "
          "specular, colour recomposed (`training.data.clean_references`); a diagnostic between our own "
          "checkpoints, not a score against OIDN.", "",
          "| checkpoint | as rendered PSNR / FLIP / temporal | cleaned PSNR / FLIP / temporal |", "| --- | --- | --- |"]
    for n in names:
        cells = [f"{r['mean']['psnr']:.2f} / {r['mean']['flip']:.4f} / {r['mean']['temporal']:.5f}"
                 for r in report["results"][n].values()]
        md.append(f"| {n} | " + " | ".join(cells) + " |")
    md += ["", "| sequence | " + " | ".join(f"{n} as rendered | {n} cleaned" for n in names) + " |",
           "| --- |" + " --- |" * (2 * len(names))]
    for p in paths:
        cells = []
        for n in names:
            for r in report["results"][n].values():
                s = r["sequences"][p.name]
                cells.append(f"{s['psnr']:.2f} / {s['flip']:.4f}")
        md.append(f"| {p.name} | " + " | ".join(cells) + " |")
    write_report(args.out, report, "\n".join(md) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
