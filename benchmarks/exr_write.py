"""Writing one output frame: time and size per EXR storage (`jnds run --output-format`).

    python -m benchmarks.exr_write [--size 1280x720] [--runs 7]
        [--threads 2] [--out benchmarks/results/exr_write]

The frame is a real output: the bundled sample's frames resized to --size (native) run
through the int8 pipeline, the last one kept (2x the size). Each storage writes it --runs
times, interleaved, with OpenEXR's --threads threads (as `jnds run` sets them): medians.
`float ZIP` is what `jnds run` wrote before commit 3830aa3; `float` and `half` are its
``io.OUTPUT_FORMATS`` since. Writes benchmarks/results/exr_write.md and .json.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    ROOT,
    arguments,
    command_line,
    cpu_line,
    interleaved,
    machine_info,
    parse,
    parse_size,
    pipeline,
    resized_frames,
    tune_process,
    write_report,
)
from jnds_deploy import io
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS


def main() -> None:
    ap = arguments(__doc__, RESULTS / "exr_write", smoke={"size": "160x96", "runs": 1})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    args = parse(ap)
    tune_process()
    size = parse_size(args.size)
    pipe = pipeline(args.artifacts, precision="int8", threads=args.threads)
    for layers, cut in resized_frames(io.open_sequence(ROOT / "samples" / "orbit-160x90"), size)[:4]:
        frame = pipe(layers, cut).output
    io.exr_threads(args.threads)
    import OpenEXR

    storages = {
        "float ZIP (before 3830aa3)": (frozenset(), OpenEXR.ZIP_COMPRESSION),
        **{f"{k} (--output-format {k})": v for k, v in io.OUTPUT_FORMATS.items()},
    }
    with tempfile.TemporaryDirectory() as tmp:
        paths = {name: Path(tmp) / f"{i}.exr" for i, name in enumerate(storages)}
        calls = {
            name: (lambda n=name: io.write_exr(paths[n], {"color": frame}, io.OUTPUT_LAYERS, *storages[n]))
            for name in storages
        }
        ms = interleaved(calls, args.runs)
        sizes = {name: paths[name].stat().st_size for name in storages}
        back = {name: io.read_exr(paths[name]) for name in storages}
    exact = {
        name: bool(
            np.array_equal(
                np.stack([back[name][f"color.{c}"] for c in "RGB"], -1),
                frame.astype(np.float16 if "color" in storages[name][0] else np.float32),
            )
        )
        for name in storages
    }
    med = {name: float(np.median(v)) for name, v in ms.items()}
    base = "float ZIP (before 3830aa3)"
    h, w = frame.shape[:2]
    md = [
        "# Writing an output frame\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(machine_info())}; OpenEXR with {args.threads} threads. One {w}x{h} RGB output "
        f"frame of the int8 pipeline ({size[0]}x{size[1]} native, the sample resized); medians of {args.runs} "
        "interleaved writes.\n",
        "| storage | median ms | vs float ZIP | MB | lossless for its type |",
        "| --- | ---: | ---: | ---: | --- |",
    ]
    for name in storages:
        md.append(
            f"| {name} | {med[name]:.0f} | {med[base] / med[name]:.1f}x | {sizes[name] / 1e6:.1f} | "
            f"{'yes' if exact[name] else 'no'} |"
        )
    write_report(
        Path(args.out),
        {
            "machine": machine_info(),
            "command": command_line(),
            "size": [w, h],
            "median_ms": med,
            "ms": ms,
            "bytes": sizes,
            "exact": exact,
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
