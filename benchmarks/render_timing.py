"""Render time per frame at the dataset's size, inputs (with motion vectors) and
reference separately: median over frames 1..N-1 (frame 0 pays for kernel compilation).

    python benchmarks/render_timing.py --frames 4 --out benchmarks/results/render_timing.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from jnds_deploy.render.camera import camera_path, jitter
from jnds_deploy.render.dataset import SIZE
from jnds_deploy.render.integrator import SplitPathTracer, load_mitsuba
from jnds_deploy.render.scene import build_scene
from jnds_deploy.render.sequence import RenderConfig, motion_vectors, render_inputs, render_reference


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1002)
    ap.add_argument("--out", default="benchmarks/results/render_timing.json")
    args = ap.parse_args()

    mi, dr = load_mitsuba()
    scene, materials = build_scene(mi, args.seed, "procedural")
    tracer = SplitPathTracer(mi, dr, scene, materials)
    cams, _ = camera_path("orbit", args.frames, np.random.default_rng(args.seed))
    result = {"machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
              "variant": mi.variant(), "size": SIZE}
    for spp in (64, 128):
        cfg = RenderConfig(size=SIZE, spp=spp)
        t_in, t_ref = [], []
        for i in range(args.frames):
            t0 = time.perf_counter()
            render_inputs(tracer, cfg, cams[i], jitter(i), seed=i)
            if i:
                motion_vectors(tracer, cams[i], cams[i - 1], cfg.size)
            t1 = time.perf_counter()
            render_reference(tracer, cfg, cams[i], seed=100 + i)
            t2 = time.perf_counter()
            if i:
                t_in.append(t1 - t0)
                t_ref.append(t2 - t1)
        result[f"spp{spp}"] = {"inputs_s": float(np.median(t_in)), "reference_s": float(np.median(t_ref)),
                               "inputs_all": t_in, "reference_all": t_ref}
        print(f"{SIZE[0]}x{SIZE[1]} -> {2 * SIZE[0]}x{2 * SIZE[1]}, reference {spp} spp: inputs "
              f"{np.median(t_in):.2f} s/frame, reference {np.median(t_ref):.2f} s/frame")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
