"""How much noise the references keep: each reference frame against the same frame cleaned
as ``jnds train --clean-references oidn`` cleans it (``training.data.clean_references``:
OIDN on the diffuse and specular components, colour recomposed).

    .venv/bin/python experiments/reference_noise.py --data data/train data/val data/test \
        [--sheet benchmarks/results/reference_noise.jpg] [--out benchmarks/results/reference_noise]

Per sequence: the reference's samples per pixel (render.json), PSNR of the reference colour
against the cleaned colour over all frames (``jnds_deploy.metrics.psnr``, the tonemapped
comparison the evaluation uses). A low PSNR means a denoiser changes the reference a lot:
noise, or detail OIDN removes; the sheet (reference | cleaned, frame 6, the noisiest
sequences of each split first) shows which. Fills the cache ``--clean-references`` reads.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, machine_info, write_report  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.metrics import psnr, to_ldr  # noqa: E402
from jnds_deploy.training.data import clean_references, load_sequence, oidn_version  # noqa: E402


def _spp(path: Path) -> int | None:
    try:
        return int(json.loads((path / "render.json").read_text())["config"]["spp"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def main() -> int:
    ap = arguments(__doc__, RESULTS / "reference_noise")
    ap.add_argument("--data", nargs="+", default=["data/train", "data/val", "data/test"])
    ap.add_argument("--sheet", default=None, help="reference | cleaned for the noisiest sequences (.jpg or .png)")
    ap.add_argument("--sheet-rows", type=int, default=2, help="sequences per split on the sheet")
    args = ap.parse_args()
    oidn = oidn_version()
    result = {"machine": machine_info(), "oidn": oidn, "sequences": {}}
    pictures = {}
    for path in map(Path, expand_sequences(args.data)):
        raw = load_sequence(path)
        clean = clean_references(raw, path)  # the frames read once, not again by load_sequence(clean=)
        ref = [r.transpose(1, 2, 0) for r in raw.ref["color"]]
        cleaned = [c.transpose(1, 2, 0) for c in clean.ref["color"]]
        name = f"{path.parent.name}/{path.name}"
        result["sequences"][name] = {"renderer": raw.renderer, "spp": _spp(path),
                                     "psnr": float(np.mean([psnr(r, c) for r, c in zip(ref, cleaned)]))}
        t = min(6, len(ref) - 1)
        pictures[name] = np.concatenate([to_ldr(ref[t]), to_ldr(cleaned[t])], 1)
        print(f"{name:50s} {result['sequences'][name]['psnr']:.2f}", flush=True)
    seqs = result["sequences"]
    lines = ["# How much noise the references keep", "", f"Command: `{command_line()}`  ", f"pyoidn {oidn}", "",
             "PSNR (dB) of each reference against itself cleaned as `jnds train --clean-references oidn` "
             "cleans it (OIDN `high` on the diffuse and specular components, colour recomposed), mean over "
             "the frames. Lower: a denoiser changes the reference more.", "",
             "| split | renderer | spp | sequences | PSNR mean | min | max |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    groups = {}
    for name, s in seqs.items():
        groups.setdefault((name.split("/")[0], s["renderer"], s["spp"]), []).append(s["psnr"])
    for (split, renderer, spp), v in groups.items():
        lines.append(f"| {split} | {renderer} | {spp} | {len(v)} | {np.mean(v):.2f} | {min(v):.2f} | {max(v):.2f} |")
    lines += ["", "| sequence | spp | PSNR |", "| --- | ---: | ---: |"]
    lines += [f"| {n} | {s['spp']} | {s['psnr']:.2f} |" for n, s in seqs.items()]
    lines.append("")
    if args.sheet:
        rows = []
        for split in dict.fromkeys(n.split("/")[0] for n in seqs):
            names = sorted((n for n in seqs if n.startswith(split + "/")), key=lambda n: seqs[n]["psnr"])
            for n in names[:args.sheet_rows]:
                img = np.ascontiguousarray((np.clip(pictures[n], 0, 1) * 255).astype(np.uint8)[..., ::-1])
                cv2.putText(img, f"{n} {seqs[n]['psnr']:.1f} dB", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                            (0, 255, 255), 1)
                rows.append(img)
        width = max(r.shape[1] for r in rows)
        rows = [cv2.copyMakeBorder(r, 0, 0, 0, width - r.shape[1], cv2.BORDER_CONSTANT) for r in rows]
        cv2.imwrite(args.sheet, np.concatenate(rows, 0), [cv2.IMWRITE_JPEG_QUALITY, 85])
        result["sheet"] = args.sheet
        lines += [f"Sheet: [{Path(args.sheet).name}]({Path(args.sheet).name}) (reference | cleaned, frame 6, the "
                  f"{args.sheet_rows} lowest PSNR of each split).", ""]
    write_report(Path(args.out), result, "\n".join(lines))
    print("\n".join(lines[:9 + len(groups)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
