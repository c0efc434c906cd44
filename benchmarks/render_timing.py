"""Render time per frame at the dataset's size, inputs (with motion vectors) and
reference separately: median over frames 1..N-1 (frame 0 pays for kernel compilation).

    python -m benchmarks.render_timing [--frames 4] [--size 192x108] [--spp 64 128]
        [--out benchmarks/results/render_timing.json]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    arguments,
    command_line,
    machine_info,
    machine_line,
    parse,
    parse_size,
    timed,
    write_report,
)
from jnds_deploy.render.camera import camera_path
from jnds_deploy.render.dataset import SIZE
from jnds_deploy.render.integrator import SplitPathTracer, load_mitsuba
from jnds_deploy.render.scene import build_scene
from jnds_deploy.render.sequence import RenderConfig, motion_vectors, render_inputs, render_reference
from jnds_deploy.sampling import jitter


def main() -> None:
    ap = arguments(
        __doc__, RESULTS / "render_timing.json", "the JSON report", smoke={"frames": 2, "size": "32x18", "spp": [2]}
    )
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1002)
    ap.add_argument("--size", default=f"{SIZE[0]}x{SIZE[1]}", help="native size (default: the dataset's)")
    ap.add_argument("--spp", type=int, nargs="+", default=[64, 128], help="reference samples per pixel")
    args = parse(ap)
    size = parse_size(args.size)

    mi, dr = load_mitsuba()
    scene, materials = build_scene(mi, args.seed, "procedural")
    tracer = SplitPathTracer(mi, dr, scene, materials)
    cams, _ = camera_path("orbit", args.frames, np.random.default_rng(args.seed))
    result = {
        "command": command_line(),
        "machine": machine_line(),
        "machine_info": machine_info(),
        "variant": mi.variant(),
        "size": list(size),
    }
    for spp in args.spp:
        cfg = RenderConfig(size=size, spp=spp)
        t_in, t_ref = [], []
        for i in range(args.frames):
            ms_in = timed(render_inputs, tracer, cfg, cams[i], jitter(i), seed=i)[1]
            if i:
                ms_in += timed(motion_vectors, tracer, cams[i], cams[i - 1], cfg.size)[1]
            ms_ref = timed(render_reference, tracer, cfg, cams[i], seed=100 + i)[1]
            if i:
                t_in.append(ms_in / 1000)
                t_ref.append(ms_ref / 1000)
        result[f"spp{spp}"] = {
            "inputs_s": float(np.median(t_in)),
            "reference_s": float(np.median(t_ref)),
            "inputs_all": t_in,
            "reference_all": t_ref,
        }
        print(
            f"{size[0]}x{size[1]} -> {2 * size[0]}x{2 * size[1]}, reference {spp} spp: inputs "
            f"{np.median(t_in):.2f} s/frame, reference {np.median(t_ref):.2f} s/frame"
        )
    write_report(Path(args.out).with_suffix(""), result)


if __name__ == "__main__":
    main()
