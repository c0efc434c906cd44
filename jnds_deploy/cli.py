"""``jnds``: one console script, a subcommand per action.

Heavy imports (mitsuba, torch, onnxruntime) happen inside the subcommand that needs
them, so ``jnds --help`` stays instant. Library errors (``JndsError``) become a one-line
message and exit code 2.
"""
from __future__ import annotations

import argparse
import gc
import json
import sys
import time

from .errors import JndsError


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 160x90, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def cmd_render(args) -> int:
    from .io import validate
    from .render import RenderConfig, render_sequence

    scene = args.scene or ("procedural" if args.engine == "mitsuba" else "sunroom")
    cfg = RenderConfig(scene=scene, seed=args.seed, camera=args.camera, frames=args.frames,
                       size=args.size, scale=args.scale, spp=args.spp, spp_input=args.spp_input,
                       max_depth=args.max_depth, reference=not args.no_reference,
                       variant=args.variant, engine=args.engine)
    t0 = time.perf_counter()
    times = render_sequence(cfg, args.out, progress=not args.quiet)
    report = validate(args.out)
    print(report.summary())
    per = ", ".join(f"{k} {v:.2f} s" for k, v in times.items() if v is not None)
    print(f"rendered in {time.perf_counter() - t0:.1f} s (median per frame: {per or 'all frames resumed'})")
    return 0


def cmd_validate(args) -> int:
    from .io import validate

    status = 0
    for path in args.sequences:
        report = validate(path)
        print(report.summary())
        if args.strict and not report.clean:
            status = 1
    return status


def cmd_import_cycles(args) -> int:
    from .cycles import import_cycles

    report = import_cycles(args.raw, args.out, args.reference, progress=not args.quiet)
    print(report.summary())
    return 0


# the training-only Cycles kinds (blender_scene.CYCLES_EXTRA_KINDS), for --<kind>-sequences' help
EXTRA_KIND_HELP = {
    "mixed": "random combinations of the training kinds' ingredients",
    "lights": "mixed with spot, shaped area and emissive bar lights",
    "interior": "closed rooms lit mostly by bounced light",
    "detail": "bump-mapped surfaces, dense and curved shapes",
    "layers": "sheen, coat, subsurface, anisotropic, thin-film and frosted materials on smooth shapes, meshes of "
              "thin struts",
    "glass": "thin-walled, solid, frosted and tinted glass, water, caustics",
    "print": "lettering and signs of every size",
    "media": "participating media: haze, drifting mist, smoke, glowing clouds",
}


def _extra_sequences(args) -> dict[str, int]:
    """{kind: N} of the training-only Cycles kinds from --<kind>-sequences."""
    from .blender_scene import CYCLES_EXTRA_KINDS

    return {kind: getattr(args, f"{kind}_sequences") for kind in CYCLES_EXTRA_KINDS
            if getattr(args, f"{kind}_sequences")}


def cmd_dataset(args) -> int:
    from .render.dataset import dataset_specs, render_dataset

    if args.list:
        for rel, cfg in dataset_specs(args.split, args.train_sequences, args.engine, args.moving_sequences,
                                      _extra_sequences(args)):
            print(rel, json.dumps({"scene": cfg.scene, "seed": cfg.seed, "camera": cfg.camera,
                                   "frames": cfg.frames, "size": cfg.size, "spp": cfg.spp}))
        return 0
    t0 = time.perf_counter()
    done = render_dataset(args.out, args.split, args.limit, variant=args.variant,
                          train_sequences=args.train_sequences, jobs=args.jobs, engine=args.engine,
                          address=args.address, progress=not args.quiet, moving_sequences=args.moving_sequences,
                          extra_sequences=_extra_sequences(args), reference=not args.no_reference,
                          reference_spp=args.reference_spp)
    for path, times in done:
        # None: every frame of that kind was rendered before a resume (the medians are of this run's)
        rates = ", ".join(f"{k} " + ("none rendered in this run" if v is None else f"{v:.2f} s/frame")
                          for k, v in times.items())
        print(f"{path}: {rates}")
    print(f"{len(done)} sequence(s) rendered in {time.perf_counter() - t0:.0f} s")
    return 0


def cmd_train(args) -> int:
    from .training.config import TrainConfig
    from .training.train import train

    cfg = TrainConfig(data=args.data, run=args.run, preset=args.preset, output_width=args.output_width,
                      upsample_root=args.upsample_root,
                      firefly_clamp=args.firefly_clamp, diffuse_fill=args.diffuse_fill,
                      albedo_at_holes=args.albedo_at_holes, guide_albedo=args.guide_albedo,
                      guide_init=args.guide_init, input_block=args.input_block, input_hidden=args.input_hidden,
                      input_fit_steps=args.input_fit_steps,
                      patch=args.patch, unroll=args.unroll, batch=args.batch, fp32_steps=args.fp32_steps,
                      qat_steps=args.qat_steps, lr=args.lr, qat_lr=args.qat_lr, spatial_loss=args.spatial_loss,
                      feature_net=args.feature_net, init=args.init, deepen_blend=args.deepen_blend,
                      val_every=args.val_every, checkpoint_every=args.checkpoint_every, val_sequences=args.val_sequences,
                      threads=args.threads, seed=args.seed,
                      device=args.device, exposure=args.exposure, rotate_normals=args.rotate_normals,
                      flips=args.flips, colours=args.colours, warmup_steps=args.warmup_steps,
                      channels_last=not args.no_channels_last,
                      fixed_upsample=args.fixed_upsample, cross_cuts=args.cross_cuts,
                      balance_renderers=args.balance_renderers, burn_in=args.burn_in,
                      clean_references=args.clean_references, lowfreq_loss=args.lowfreq_loss,
                      teacher=args.teacher, train_only=tuple(args.train_only), w_spatial=args.w_spatial)
    ckpt = train(cfg, progress=not args.quiet)
    print(f"checkpoint: {ckpt}")
    return 0


def cmd_train_feature_net(args) -> int:
    from .training.feature_loss import FeatureNetConfig, train_feature_net

    out = train_feature_net(FeatureNetConfig(data=args.data, out=args.out, steps=args.steps,
                                             threads=args.threads, clean_references=args.clean_references),
                            progress=not args.quiet)
    print(f"feature-loss network: {out}")
    return 0


def cmd_evaluate(args) -> int:
    from .training.evaluate import evaluate_sets, markdown_sets

    reports = evaluate_sets(args.checkpoint, args.data, args.baselines, args.out, args.threads, args.sheet)
    print(markdown_sets(reports))
    if args.sheet:
        print(f"contact sheet (input, each method, reference): {args.sheet}")
    return 0


def cmd_export(args) -> int:
    from .export import ExportConfig, export

    manifest = export(ExportConfig(checkpoint=args.checkpoint, out=args.out))
    print(f"wrote {', '.join(g.file for g in manifest.graphs.values())} and manifest.json to {args.out}")
    return 0


def cmd_calibrate(args) -> int:
    from .calibration import CalibrateConfig, calibrate
    from .io import expand_sequences
    from .runtime import tune_numba

    tune_numba()
    cfg = CalibrateConfig(artifacts=args.artifacts, data=tuple(map(str, expand_sequences(args.data))),
                          method=args.method, activation_type=args.activation_type, frames=args.frames,
                          checkpoint=args.checkpoint, threads=args.threads, u8_edges=not args.float_edges)
    manifest = calibrate(cfg)
    files = ", ".join(g.int8[args.method].file for g in manifest.graphs.values())
    print(f"wrote {files} and calibration.{args.method}.json to {args.artifacts} (int8 default: {args.method})")
    return 0


def cmd_run(args) -> int:
    # the cold start (docs/performance.md, "Speed", stop 52): while this thread imports,
    # another faults in the heap that frame 0 will take; no garbage collection passes over
    # what the imports build (numba's and ONNX Runtime's objects, kept to the end), which
    # is then frozen out of later collections
    gc.disable()
    try:
        from .heap import FIRST_FRAME_HEAP_PER_PIXEL, pretouch
        from .io import exr_threads, open_sequence

        w, h = open_sequence(args.input).native_size
        pretouch(FIRST_FRAME_HEAP_PER_PIXEL * w * h)
        from .runtime import PipelineConfig, tune_numba
        from .runtime.run import run_sequence, score_lines, stage_table

        tune_numba()
    finally:
        gc.freeze()
        gc.enable()
    exr_threads(args.threads)
    cfg = PipelineConfig(artifacts=args.artifacts, precision=args.precision,
                         filter_dtype=args.filter_dtype, threads=args.threads, adaptive=not args.no_adaptive,
                         native_output=args.native, keep_freed_memory=True, firefly_clamp=args.firefly_clamp,
                         diffuse_fill=None if args.diffuse_fill is None else args.diffuse_fill == "on",
                         albedo_at_holes=None if args.albedo_at_holes is None else args.albedo_at_holes == "on")
    report = run_sequence(cfg, args.input, args.output, progress=not args.quiet, output_format=args.output_format)
    med = report["median_ms"]
    print(f"{report['frames']} frames -> {args.output}: median {med['total']:.1f} ms/frame "
          f"({report['native_size'][0]}x{report['native_size'][1]} -> "
          f"{report['output_size'][0]}x{report['output_size'][1]}, {args.precision})")
    for line in score_lines(report):
        print(line)
    print(stage_table(report))
    if "contact_sheet" in report:
        print(f"contact sheet (input, OIDN, output, reference, changed pixels): {report['contact_sheet']}")
    return 0


def cmd_batch(args) -> int:
    from .cluster import BatchConfig, batch

    cfg = BatchConfig(artifacts=args.artifacts, input=args.input, output=args.output, precision=args.precision,
                      filter_dtype=args.filter_dtype, adaptive=not args.no_adaptive, threads=args.threads,
                      workers=args.workers, address=args.address, retries=args.retries,
                      output_format=args.output_format)
    summary = batch(cfg, progress=not args.quiet)
    c = summary["counts"]
    print(f"{c['done']} sequence(s) done, {c['skipped']} already complete, {c['failed']} failed: "
          f"{summary['frames_processed']} frames in {summary['wall_s']:.1f} s "
          f"({summary['workers']} worker(s) x {args.threads} thread(s)); summary: {args.output}/batch.json")
    for name, rec in summary["sequences"].items():
        if rec["status"] == "failed":
            print(f"failed: {name}: {rec['error']}", file=sys.stderr)
    return 1 if c["failed"] else 0


def cmd_serve(args) -> int:
    import logging

    from .io import exr_threads
    from .runtime import tune_numba
    from .serve import ServeConfig, serve

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    tune_numba()
    exr_threads(args.threads)
    cfg = ServeConfig(artifacts=args.artifacts, host=args.host, port=args.port, precision=args.precision,
                      threads=args.threads, workers=args.workers, queue=args.queue,
                      max_streams=args.max_streams, idle_timeout=args.idle_timeout, max_pixels=args.max_pixels,
                      request_timeout=args.request_timeout, max_connections=args.max_connections,
                      max_memory=int(args.max_memory * 2**30) if args.max_memory else None,
                      keep_freed_memory=True, warmup=tuple(args.warmup))
    serve(cfg, ready=lambda h, p: print(f"jnds serve: listening on http://{h}:{p}", flush=True))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .blender_scene import CYCLES_SCENE_KINDS
    from .render.camera import CAMERA_PATHS
    from .render.dataset import EXTRA_SEEDS, TRAIN_SEQUENCES
    from .render.scene import SCENE_KINDS
    from .render.sequence import ENGINES
    from .training.config import GUIDE_INITS, SPATIAL_LOSSES
    from .layout import INPUT_BLOCKS

    p = argparse.ArgumentParser(prog="jnds", description="Joint neural denoising and supersampling, deployed.")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render an animated sequence with Mitsuba 3 or Blender Cycles")
    r.add_argument("--engine", default="mitsuba", choices=ENGINES,
                   help="mitsuba: this package's path tracer; cycles: Blender (its environment, .venv-blender)")
    r.add_argument("--scene", default=None, choices=SCENE_KINDS + CYCLES_SCENE_KINDS,
                   help=f"default: procedural (mitsuba), {CYCLES_SCENE_KINDS[0]} (cycles)")
    r.add_argument("--seed", type=int, default=0, help="scene, camera path and noise seed")
    r.add_argument("--camera", default="orbit", choices=CAMERA_PATHS)
    r.add_argument("--frames", type=int, default=8)
    r.add_argument("--size", type=_size, default=(160, 90), help="native size WxH")
    r.add_argument("--scale", type=int, default=2, help="reference size = scale x native")
    r.add_argument("--spp", type=int, default=64, help="reference samples per target pixel")
    r.add_argument("--spp-input", type=int, default=1, help="input samples per native pixel")
    r.add_argument("--max-depth", type=int, default=5, help="path vertices, the first included")
    r.add_argument("--no-reference", action="store_true", help="render inputs only")
    r.add_argument("--variant", default=None, help="Mitsuba variant (default: llvm_ad_rgb if LLVM 19 is installed, else scalar_rgb)")
    r.add_argument("--out", required=True)
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("validate", help="check sequences against jnds-sequence/1, count NaN/Inf")
    v.add_argument("sequences", nargs="+")
    v.add_argument("--strict", action="store_true", help="exit 1 if any channel holds NaN/Inf")
    v.set_defaults(func=cmd_validate)

    im = sub.add_parser("import", help="convert another renderer's frames into jnds-sequence/1")
    im_sub = im.add_subparsers(dest="source", required=True)
    ic = im_sub.add_parser("cycles", help="Blender Cycles frames rendered after jnds_deploy.blender.configure")
    ic.add_argument("raw", help="directory of Blender's <prefix>NNNN.exr multilayer frames (and jnds.json)")
    ic.add_argument("--out", required=True, help="the sequence directory to write")
    ic.add_argument("--reference", default=None,
                    help="directory of the same frames rendered by jnds_deploy.blender.configure_reference")
    ic.add_argument("--quiet", action="store_true")
    ic.set_defaults(func=cmd_import_cycles)

    d = sub.add_parser("dataset", help="render (or resume) the training and validation sets")
    d.add_argument("--out", default="data")
    d.add_argument("--split", default="all",
                   choices=("train", "val", "all", "test", "holdout", "holdout2", "holdout3", "holdout4", "media"),
                   help="all = train + val; test (seeds never trained or selected on) holdout (Cycles: kinds written after the test was read) holdout2 (kinds written after the holdout was read), holdout3 (after holdout2 was read), holdout4 (after holdout3 was) and media (Cycles: unseen seeds of the media training kind) only when asked for")
    d.add_argument("--limit", type=int, default=None, help="only the first N sequences")
    d.add_argument("--list", action="store_true", help="print the sequences and exit")
    d.add_argument("--train-sequences", type=int, default=TRAIN_SEQUENCES,
                   help="training sequences (seeds 1000, 1001, ...; the first 24 are the default set)")
    d.add_argument("--moving-sequences", type=int, default=0,
                   help="Mitsuba training sequences whose objects move (scene kind moving, seeds 4000, ...)")
    for kind, what in EXTRA_KIND_HELP.items():
        d.add_argument(f"--{kind}-sequences", type=int, default=0,
                       help=f"Cycles training sequences of scene kind {kind} ({what}; seeds {EXTRA_SEEDS[kind]}, ...)")
    d.add_argument("--jobs", type=int, default=1, help="sequences rendered at once, in separate processes")
    d.add_argument("--variant", default=None, help="Mitsuba variant, e.g. cuda_ad_rgb on a GPU machine")
    d.add_argument("--engine", default="mitsuba", choices=ENGINES,
                   help="cycles: the Blender Cycles sets (seeds 5000+ / 6000+, train/cycles-*, val/cycles-*)")
    d.add_argument("--address", default=None,
                   help="render the sequences as Ray tasks on this cluster ('local': an embedded Ray here); "
                        "RAY_ADDRESS also selects a cluster")
    d.add_argument("--no-reference", action="store_true",
                   help="inputs only (no reference frames): training data for jnds train --teacher, in a "
                        "directory of its own (--out)")
    d.add_argument("--reference-spp", type=int, default=None, metavar="N",
                   help="references at N samples per target pixel instead of the split's (training: 64): "
                        "cheap references for jnds train --clean-references oidn, in a directory of their own (--out)")
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=cmd_dataset)

    t = sub.add_parser("train", help="train the network (fp32, then QAT); resumes from <run>/checkpoint.pt")
    t.add_argument("--data", default="data", help="directory with train/ and val/ sequences")
    t.add_argument("--run", default="runs/small", help="output directory (checkpoint, log, config)")
    t.add_argument("--preset", default="small")
    t.add_argument("--output-width", type=int, default=0, metavar="C",
                   help="the output block's hidden channels instead of the preset's (an AVX2 CPU's int8 "
                        "convolution costs in steps of 16; --init narrows or widens a checkpoint to it)")
    t.add_argument("--upsample-root", type=int, default=1, choices=(1, 2, 4, 8),
                   help="the upsample filter interpolates the composite's root of this degree (1: linear, "
                        "the paper)")
    t.add_argument("--firefly-clamp", type=float, default=0.0, metavar="K",
                   help="train with the firefly clamp (model.ModelConfig.firefly_clamp; 0: off)")
    t.add_argument("--diffuse-fill", action="store_true",
                   help="train with the diffuse of samples that hit no diffuse surface filled from their "
                        "neighbours' (model.ModelConfig.diffuse_fill)")
    t.add_argument("--albedo-at-holes", action="store_true",
                   help="train with the composite's albedo averaged where such samples lie scattered "
                        "(model.ModelConfig.albedo_at_holes)")
    t.add_argument("--guide-albedo", action="store_true",
                   help="the network also reads the guide albedo (the optional layer denoising_albedo, the albedo "
                        "where a frame has none; model.ModelConfig.guide_albedo); --init from a checkpoint without "
                        "it adds the input with zero weights (see --guide-init)")
    t.add_argument("--guide-init", choices=GUIDE_INITS, default=GUIDE_INITS[0],
                   help="how --guide-albedo --init from a checkpoint without the input starts its weights: zero (the "
                        "same outputs), or split (the albedo's weights halved and shared with the guide: the same "
                        "outputs where the two agree, the guide in use from the first step)")
    t.add_argument("--input-block", choices=INPUT_BLOCKS, default=INPUT_BLOCKS[0],
                   help="the input block's design (model.ModelConfig.input_block): native, the paper's, or "
                        "space_to_depth (each 2x2 pixel block as one half-resolution pixel); --init from a "
                        "checkpoint of the other design fits the new block to its features first")
    t.add_argument("--input-hidden", type=int, default=32, metavar="C",
                   help="space_to_depth: the input block's projection width")
    t.add_argument("--input-fit-steps", type=int, default=800, metavar="N",
                   help="--init of the other input block design: steps fitting the new block to the old "
                        "one's features (the rest of the network frozen) before training")
    t.add_argument("--fixed-upsample", action="store_true",
                   help="one learned upsample kernel for every pixel instead of the upsample block's "
                        "per-pixel prediction (no upsample graph; --init from a predicting checkpoint "
                        "drops its upsample block and features)")
    t.add_argument("--patch", type=int, default=64, help="native patch side")
    t.add_argument("--unroll", type=int, default=6, help="consecutive frames per sample")
    t.add_argument("--batch", type=int, default=4)
    t.add_argument("--fp32-steps", type=int, default=4000)
    t.add_argument("--qat-steps", type=int, default=1500)
    t.add_argument("--lr", type=float, default=1e-3, help="fp32 phase learning rate")
    t.add_argument("--qat-lr", type=float, default=1e-4, help="QAT phase learning rate")
    t.add_argument("--warmup-steps", type=int, default=0, metavar="N",
                   help="the fp32 learning rate rises linearly over the first N steps (a fine-tune's fresh "
                        "optimizer moments otherwise move every weight by a full step at once)")
    t.add_argument("--spatial-loss", default="l1", choices=SPATIAL_LOSSES)
    t.add_argument("--feature-net", default=None, help="feature-loss network checkpoint")
    t.add_argument("--lowfreq-loss", type=float, default=0.0, metavar="W",
                   help="add W x the L1 of 4-, 8- and 16-pixel box averages (target pixels) of output and "
                        "reference to each radiance task's spatial loss (0: the paper's loss)")
    t.add_argument("--init", default=None,
                   help="start a new run from this checkpoint's weights (e.g. the shipped one) to fine-tune it")
    t.add_argument("--w-spatial", type=float, default=0.2, metavar="W",
                   help="each task's loss: W x spatial + (1 - W) x temporal (Sec. 3.3's 0.2)")
    t.add_argument("--teacher", default=None, metavar="CHECKPOINT",
                   help="distil: this checkpoint's outputs are the targets, not the references (the training "
                        "sequences need none: jnds dataset --no-reference)")
    t.add_argument("--train-only", action="append", default=[], metavar="PREFIX",
                   help="train only the parameters whose names start with PREFIX (repeatable; e.g. "
                        "network.output_block)")
    t.add_argument("--deepen-blend", type=float, default=-4.0, metavar="LOGIT",
                   help="--init one U-Net level shallower than --preset: the new level enters the old coarsest "
                        "one with blend weight sigmoid(LOGIT)")
    t.add_argument("--val-every", type=int, default=500)
    t.add_argument("--checkpoint-every", type=int, default=100, metavar="N",
                   help="write <run>/checkpoint.pt every N steps (and at the end)")
    t.add_argument("--val-sequences", type=int, default=None)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--device", default="cpu", help="torch device of the training steps: cpu or cuda")
    t.add_argument("--exposure", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="augmentation: radiance (inputs and reference) x 2^u, u uniform in [LO, HI] stops")
    t.add_argument("--rotate-normals", action="store_true",
                   help="augmentation: a uniformly random rotation of the normals' world frame per sample")
    t.add_argument("--flips", action="store_true", help="augmentation: random horizontal and vertical mirroring")
    t.add_argument("--colours", action="store_true",
                   help="augmentation: half the samples with R, G, B permuted (radiance and albedo) and the "
                        "radiance tinted by up to half a stop per channel")
    t.add_argument("--burn-in", type=int, default=0, metavar="N",
                   help="up to N frames before each training window run without gradients (drawn per "
                        "batch from 0..N): the history the loss sees has accumulated longer")
    t.add_argument("--cross-cuts", action="store_true",
                   help="training windows may span a camera cut (the history restarts there)")
    t.add_argument("--balance-renderers", action="store_true",
                   help="draw each renderer's sequences (mitsuba, cycles: render.json's engine, or "
                        "sequence.json's renderer.engine; sequences with neither are a group of their own) "
                        "as often as another's, whatever their counts")
    t.add_argument("--clean-references", choices=["oidn"], default=None,
                   help="train against references whose diffuse and specular components OIDN denoised (colour "
                        "recomposed from them; cached in each sequence's .cache/): the renders' references keep "
                        "noise (benchmarks/results/reference_noise.md)")
    t.add_argument("--no-channels-last", action="store_true",
                   help="keep convolutions in NCHW memory (the default NHWC gives the same values, faster on a CPU)")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=cmd_train)

    f = sub.add_parser("train-feature-net", help="train the feature-loss network on rendered data")
    f.add_argument("--data", default="data")
    f.add_argument("--out", default="runs/feature/feature_net.pt")
    f.add_argument("--steps", type=int, default=1500)
    f.add_argument("--threads", type=int, default=2)
    f.add_argument("--clean-references", choices=["oidn"], default=None,
                   help="learn from the references cleaned as jnds train --clean-references cleans them")
    f.add_argument("--quiet", action="store_true")
    f.set_defaults(func=cmd_train_feature_net)

    x = sub.add_parser("export", help="write the ONNX graphs and manifest.json, validated against PyTorch")
    x.add_argument("--checkpoint", default=None, help="default: the shipped checkpoint")
    x.add_argument("--out", required=True)
    x.set_defaults(func=cmd_export)

    c = sub.add_parser("calibrate", help="write int8 QDQ graphs next to the fp32 ones")
    c.add_argument("--artifacts", required=True, help="a directory written by `jnds export`")
    c.add_argument("--data", nargs="+", required=True, help="sequences, or directories of sequences")
    c.add_argument("--method", default="qat", choices=("qat", "minmax", "percentile", "entropy"))
    c.add_argument("--activation-type", default="u8", choices=("u8", "s8"))
    c.add_argument("--frames", type=int, default=None, help="at most this many frames per sequence")
    c.add_argument("--checkpoint", default=None, help="PyTorch reference for validation (default: the manifest's)")
    c.add_argument("--threads", type=int, default=2)
    c.add_argument("--float-edges", action="store_true",
                   help="keep the input block's preprocessing and the output block's head float (default: the "
                        "graph takes u8 inputs packed by the runtime and gives the head's u8 output to the filters)")
    c.set_defaults(func=cmd_calibrate)

    sv = sub.add_parser("serve", help="serve frame streams over HTTP (protocol: jnds_deploy/serve/server.py)")
    sv.add_argument("--artifacts", required=True)
    sv.add_argument("--host", default="127.0.0.1")
    sv.add_argument("--port", type=int, default=8765, help="0 picks a free port")
    sv.add_argument("--precision", default="int8", choices=("int8", "fp32"))
    sv.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads per graph run")
    sv.add_argument("--workers", type=int, default=1, help="frames processed at once, over all streams")
    sv.add_argument("--queue", type=int, default=2, help="frames waiting per stream before 429")
    sv.add_argument("--max-streams", type=int, default=64)
    sv.add_argument("--idle-timeout", type=float, default=300.0, help="seconds before an idle stream is closed")
    sv.add_argument("--max-pixels", type=int, default=1920 * 1080,
                    help="native pixels a frame may have (checked on its EXR header before decoding; 413 beyond)")
    sv.add_argument("--request-timeout", type=float, default=30.0,
                    help="seconds a read may wait (request line, headers, keep-alive idle) before the connection closes")
    sv.add_argument("--max-connections", type=int, default=256, help="connections at once; the next gets a 503")
    sv.add_argument("--max-memory", type=float, default=None,
                    help="GiB the frames in flight may take (estimated per pixel); default: half the machine's memory")
    sv.add_argument("--warmup", type=_size, nargs="+", default=[], metavar="WxH",
                    help="run one frame at each of these native sizes before serving, so that a stream's first "
                         "frame at that size is not the slow one")
    sv.set_defaults(func=cmd_serve)

    b = sub.add_parser("batch", help="every sequence under a directory through the pipeline, on Ray "
                                     "(embedded locally, or a cluster)")
    b.add_argument("--artifacts", required=True)
    b.add_argument("--input", required=True, help="ROOT: every directory under it with a sequence.json")
    b.add_argument("--output", required=True, help="OUT: ROOT/<path> goes to OUT/<path>; OUT/batch.json sums up")
    b.add_argument("--precision", default="fp32", choices=("fp32", "int8"))
    b.add_argument("--filter-dtype", default="float32", choices=("float32", "float16"))
    b.add_argument("--no-adaptive", action="store_true")
    b.add_argument("--threads", type=int, default=1, help="threads (and Ray CPUs) per worker")
    b.add_argument("--workers", type=int, default=None, help="default: the cluster's CPUs / --threads")
    b.add_argument("--address", default=None,
                   help="a Ray cluster (ray start --head prints it; default RAY_ADDRESS, else a local Ray)")
    b.add_argument("--retries", type=int, default=2, help="further attempts of a sequence whose worker died")
    b.add_argument("--output-format", default="float", choices=("float", "half"),
                   help="output frames: float (32-bit, uncompressed) or half (16-bit, PIZ: a quarter of the size)")
    b.add_argument("--quiet", action="store_true")
    b.set_defaults(func=cmd_batch)

    rn = sub.add_parser("run", help="denoise and upsample a sequence with the exported pipeline")
    rn.add_argument("--artifacts", required=True)
    rn.add_argument("--input", required=True, help="a jnds-sequence/1 directory")
    rn.add_argument("--output", required=True)
    rn.add_argument("--precision", default="fp32", choices=("fp32", "int8"))
    rn.add_argument("--filter-dtype", default="float32", choices=("float32", "float16"))
    rn.add_argument("--no-adaptive", action="store_true",
                    help="run every stage on every frame (default: skip what a frame does not need)")
    rn.add_argument("--native", action="store_true",
                    help="denoise only: output at the input size, no upsample block (a renderer "
                         "already at display resolution); metrics against the reference area-downsampled")
    rn.add_argument("--firefly-clamp", type=float, default=None, metavar="K",
                    help="limit each pixel's current radiance to K x the brightest of its neighbours and its "
                         "history (0: off; default: the model's, model_config.firefly_clamp in the manifest)")
    rn.add_argument("--diffuse-fill", default=None, choices=("on", "off"),
                    help="fill the diffuse of samples that hit no diffuse surface from their neighbours' "
                         "(default: the model's, model_config.diffuse_fill in the manifest)")
    rn.add_argument("--albedo-at-holes", default=None, choices=("on", "off"),
                    help="composite with the local mean of the filtered albedo where samples that hit no diffuse "
                         "surface lie scattered (default: the model's, model_config.albedo_at_holes in the manifest)")
    rn.add_argument("--threads", type=int, default=2)
    rn.add_argument("--output-format", default="float", choices=("float", "half"),
                   help="output frames: float (32-bit, uncompressed) or half (16-bit, PIZ: a quarter of the size)")
    rn.add_argument("--quiet", action="store_true")
    rn.set_defaults(func=cmd_run)

    e = sub.add_parser("evaluate", help="PSNR/SSIM/FLIP/temporal error of checkpoints and baselines")
    e.add_argument("--checkpoint", nargs="*", default=[], help="model checkpoints to score")
    e.add_argument("--data", nargs="+", default=["data/val"],
                   help="sets, each a sequence or a directory of sequences (e.g. data/val data/test): "
                        "reported side by side")
    e.add_argument("--sheet", default=None, help="write a contact sheet here, a JPEG if the name ends in .jpg or .jpeg, else a PNG (middle frame of every sequence)")
    e.add_argument("--baselines", nargs="*", default=["bicubic", "oidn-balanced"],
                   help="bicubic, oidn-fast, oidn-balanced, oidn-high")
    e.add_argument("--out", default=None, help="write the report as JSON")
    e.add_argument("--threads", type=int, default=2)
    e.set_defaults(func=cmd_evaluate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except JndsError as exc:
        print(f"jnds {args.command}: error: {exc}", file=sys.stderr)
        return 2


def program() -> None:
    """The ``jnds`` program: ``main`` on the command line, then exit. The objects left are
    frozen first so that the interpreter's last garbage collections skip them: walking what
    numba and ONNX Runtime built took about a tenth of a second of a short `jnds run`
    (benchmarks/results/memory.md). Exit handlers and module teardown still run."""
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    program()
