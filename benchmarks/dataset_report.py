"""Dataset report: sequences, frames, bytes, and the motion-vector warp error of every
sequence (reference albedo of frame t-1 warped into frame t, outside disocclusions).

    python -m benchmarks.dataset_report --data data --out benchmarks/results/dataset.md
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, arguments, command_line, parse, write_report
from jnds_deploy.io import open_sequence
from jnds_deploy.metrics import motion_warp_error


def main() -> None:
    ap = arguments(
        __doc__,
        RESULTS / "dataset.md",
        "the markdown report (the JSON goes beside it)",
        smoke={"data": str(ROOT), "splits": ["samples"]},
    )
    ap.add_argument("--data", default="data")
    ap.add_argument("--splits", nargs="+", default=["train", "val"], help="directories of --data holding sequences")
    args = parse(ap)

    rows, totals = [], {}
    for split in args.splits:
        seqs = sorted(p.parent for p in (Path(args.data) / split).glob("*/sequence.json"))
        n_frames = n_bytes = 0
        for p in seqs:
            seq = open_sequence(p)
            size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
            n_frames += len(seq)
            n_bytes += size
            errs = [motion_warp_error(seq, t) for t in range(1, len(seq)) if not seq.frames[t].camera_cut]
            w = float(np.mean([e["warped"] for e in errs]))
            u = float(np.mean([e["unwarped"] for e in errs]))
            v = float(np.mean([e["valid"] for e in errs]))
            rows.append((split, p.name, len(seq), size, w, u, v))
        totals[split] = (len(seqs), n_frames, n_bytes)

    lines = [
        "# Dataset",
        "",
        f"Made by `{command_line()}`.",
        "",
        "| split | sequences | frames | size (GB) |",
        "| --- | --- | --- | --- |",
    ]
    for split, (s, f, b) in totals.items():
        lines.append(f"| {split} | {s} | {f} | {b / 1e9:.3f} |")
    lines += [
        "",
        "Motion vectors: mean |error| of the reference albedo of frame t-1 warped into frame t "
        "(bilinear, along the motion vectors) against frame t, outside disocclusions (depth "
        "discontinuities, silhouettes, off-screen), and the same without warping.",
        "",
        "| split | sequence | frames | MB | warped | unwarped | ratio | pixels used |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for split, name, f, b, w, u, v in rows:
        lines.append(
            f"| {split} | {name} | {f} | {b / 1e6:.1f} | {w:.5f} | {u:.5f} | {w / max(u, 1e-9):.3f} | {v:.1%} |"
        )
    moving = [r for r in rows if r[5] > 1e-6]
    summary = {
        "command": command_line(),
        "warped_mean": float(np.mean([r[4] for r in moving])),
        "unwarped_mean": float(np.mean([r[5] for r in moving])),
        "totals": {k: {"sequences": s, "frames": f, "bytes": b} for k, (s, f, b) in totals.items()},
    }
    lines += [
        "",
        f"Over moving-camera sequences: warped {summary['warped_mean']:.5f}, unwarped {summary['unwarped_mean']:.5f}.",
    ]
    write_report(Path(args.out).with_suffix(""), summary, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
