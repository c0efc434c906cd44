"""``jnds``: one console script, a subcommand per action.

A command's options are declared on its configuration dataclass (``options.option``) and
derived from it, defaults included: ``TrainConfig`` (train), ``PipelineConfig`` (run),
``BatchConfig`` (batch), ``ServeConfig`` (serve), ``RenderConfig`` (render),
``ExportConfig`` (export), ``CalibrateConfig`` (calibrate), ``FeatureNetConfig``
(train-feature-net). Only the options a command has beyond its configuration are written
here.

A command's options are added to its parser when that command is chosen (``Commands``),
and heavy imports (mitsuba, torch, onnxruntime) happen inside the command that needs
them, so ``jnds --help`` stays instant and ``jnds run`` imports no torch. Library errors
(``JndsError``) become a one-line message and exit code 2.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time

from .errors import JndsError
from .options import HelpFormatter, add_options, given


def cmd_render(args) -> int:
    from .io import validate
    from .render import RenderConfig, render_sequence

    cfg = RenderConfig(**given(args, RenderConfig))
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
    from .blender.importer import import_cycles

    report = import_cycles(args.raw, args.out, args.reference, progress=not args.quiet)
    print(report.summary())
    return 0


# the training-only Cycles kinds (blender.scenes.CYCLES_EXTRA_KINDS), for --<kind>-sequences' help
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
    from .blender.scenes import CYCLES_EXTRA_KINDS

    return {
        kind: getattr(args, f"{kind}_sequences") for kind in CYCLES_EXTRA_KINDS if getattr(args, f"{kind}_sequences")
    }


def cmd_dataset(args) -> int:
    from .render.dataset import dataset_specs, render_dataset

    if args.list:
        for rel, cfg in dataset_specs(
            args.split, args.train_sequences, args.engine, args.moving_sequences, _extra_sequences(args)
        ):
            print(
                rel,
                json.dumps(
                    {
                        "scene": cfg.scene,
                        "seed": cfg.seed,
                        "camera": cfg.camera,
                        "frames": cfg.frames,
                        "size": cfg.size,
                        "spp": cfg.spp,
                    }
                ),
            )
        return 0
    t0 = time.perf_counter()
    done = render_dataset(
        args.out,
        args.split,
        args.limit,
        variant=args.variant,
        train_sequences=args.train_sequences,
        jobs=args.jobs,
        engine=args.engine,
        address=args.address,
        progress=not args.quiet,
        moving_sequences=args.moving_sequences,
        extra_sequences=_extra_sequences(args),
        reference=not args.no_reference,
        reference_spp=args.reference_spp,
    )
    for path, times in done:
        # None: every frame of that kind was rendered before a resume (the medians are of this run's)
        rates = ", ".join(
            f"{k} " + ("none rendered in this run" if v is None else f"{v:.2f} s/frame") for k, v in times.items()
        )
        print(f"{path}: {rates}")
    print(f"{len(done)} sequence(s) rendered in {time.perf_counter() - t0:.0f} s")
    return 0


def cmd_train(args) -> int:
    from .training.config import TrainConfig, init_settings

    options = given(args, TrainConfig)
    if options.get("init"):
        from .checkpoint import read_checkpoint

        options = {**init_settings(read_checkpoint(options["init"]), options), **options}
    from .training.train import train

    ckpt = train(TrainConfig(**options), progress=not args.quiet)
    print(f"checkpoint: {ckpt}")
    return 0


def cmd_train_feature_net(args) -> int:
    from .training.feature_loss import FeatureNetConfig, train_feature_net

    out = train_feature_net(FeatureNetConfig(**given(args, FeatureNetConfig)), progress=not args.quiet)
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

    cfg = ExportConfig(**given(args, ExportConfig))
    manifest = export(cfg)
    print(f"wrote {', '.join(g.file for g in manifest.graphs.values())} and manifest.json to {cfg.out}")
    return 0


def cmd_calibrate(args) -> int:
    from .calibration import CalibrateConfig, calibrate
    from .io import expand_sequences
    from .process import shared_arena, tune_numba

    tune_numba()
    shared_arena()  # the fp32 pipelines that make the calibration inputs share one arena
    options = given(args, CalibrateConfig)
    cfg = CalibrateConfig(**{**options, "data": tuple(map(str, expand_sequences(options["data"])))})
    manifest = calibrate(cfg)
    files = ", ".join(g.int8[cfg.method].file for g in manifest.graphs.values())
    print(f"wrote {files} and calibration.{cfg.method}.json to {cfg.artifacts} (int8 default: {cfg.method})")
    return 0


def cmd_run(args) -> int:
    # the cold start (docs/performance.md): while this thread imports, another faults in
    # the heap that frame 0 will take; no garbage collection passes over what the imports
    # build (numba's and ONNX Runtime's objects, kept to the end), which is then frozen out
    # of later collections
    gc.disable()
    try:
        from .io import exr_threads, open_sequence
        from .process import FIRST_FRAME_HEAP_PER_PIXEL, pretouch, tune_process

        w, h = open_sequence(args.input).native_size
        pretouch(FIRST_FRAME_HEAP_PER_PIXEL * w * h)
        from .runtime import PipelineConfig
        from .runtime.run import run_sequence, score_lines, stage_table

        tune_process()  # jnds run owns its process (jnds_deploy.process)
    finally:
        gc.freeze()
        gc.enable()
    cfg = PipelineConfig(**given(args, PipelineConfig))
    exr_threads(cfg.threads)
    report = run_sequence(
        cfg,
        args.input,
        args.output,
        progress=not args.quiet,
        output_format=args.output_format,
        video=args.video,
        png=args.png,
    )
    med = report["median_ms"]
    print(
        f"{report['frames']} frames -> {args.output}: median {med['total']:.1f} ms/frame "
        f"({report['native_size'][0]}x{report['native_size'][1]} -> "
        f"{report['output_size'][0]}x{report['output_size'][1]}, {cfg.precision})"
    )
    for line in score_lines(report):
        print(line)
    print(stage_table(report))
    for key, what in (("contact_sheet", "contact sheet"), ("video", "video"), ("png", "PNG frames")):
        if key in report:
            print(f"{what}: {report[key]}")
    return 0


def cmd_batch(args) -> int:
    from .cluster import BatchConfig, batch

    cfg = BatchConfig(**given(args, BatchConfig))
    summary = batch(cfg, progress=not args.quiet)
    c = summary["counts"]
    print(
        f"{c['done']} sequence(s) done, {c['skipped']} already complete, {c['failed']} failed: "
        f"{summary['frames_processed']} frames in {summary['wall_s']:.1f} s "
        f"({summary['workers']} worker(s) x {cfg.threads} thread(s)); summary: {cfg.output}/batch.json"
    )
    for name, rec in summary["sequences"].items():
        if rec["status"] == "failed":
            print(f"failed: {name}: {rec['error']}", file=sys.stderr)
    return 1 if c["failed"] else 0


def cmd_serve(args) -> int:
    import logging

    from .io import exr_threads
    from .process import tune_process
    from .serve import ServeConfig, serve

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    tune_process()  # jnds serve owns its process (jnds_deploy.process)
    cfg = ServeConfig(**given(args, ServeConfig))
    exr_threads(cfg.threads)
    serve(cfg, ready=lambda h, p: print(f"jnds serve: listening on http://{h}:{p}", flush=True))
    return 0


class Commands(argparse._SubParsersAction):
    """``jnds``'s subcommands. A command's options are added to its parser when the command
    is chosen (or ``complete`` asks for them), so that a command imports only what its own
    options need: ``jnds --help`` nothing, ``jnds run`` no torch."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._options = {}

    def command(self, name: str, help: str, options, func) -> None:
        """Command ``name`` running ``func(args)``; ``options(parser)`` adds its options."""
        parser = self.add_parser(name, help=help, description=help, formatter_class=HelpFormatter)
        if func is not None:  # None: the command's subcommands set it
            parser.set_defaults(func=func)
        self._options[name] = options

    def complete(self, name: str) -> argparse.ArgumentParser:
        """Command ``name``'s parser, its options added."""
        parser = self.choices[name]
        if (options := self._options.pop(name, None)) is not None:
            options(parser)
        return parser

    def __call__(self, parser, namespace, values, option_string=None):
        if values and values[0] in self.choices:
            self.complete(values[0])
        super().__call__(parser, namespace, values, option_string)


def _quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _render_options(p: argparse.ArgumentParser) -> None:
    from .render import RenderConfig

    add_options(p, RenderConfig)
    p.add_argument("--out", required=True, help="the sequence directory to write")
    _quiet(p)


def _validate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("sequences", nargs="+")
    p.add_argument("--strict", action="store_true", help="exit 1 if any channel holds NaN/Inf")


def _import_options(p: argparse.ArgumentParser) -> None:
    sources = p.add_subparsers(dest="source", required=True)
    ic = sources.add_parser(
        "cycles",
        help="Blender Cycles frames rendered after jnds_deploy.blender.configure",
        formatter_class=HelpFormatter,
    )
    ic.add_argument("raw", help="directory of Blender's <prefix>NNNN.exr multilayer frames (and jnds.json)")
    ic.add_argument("--out", required=True, help="the sequence directory to write")
    ic.add_argument(
        "--reference",
        default=None,
        help="directory of the same frames rendered by jnds_deploy.blender.configure_reference",
    )
    _quiet(ic)
    ic.set_defaults(func=cmd_import_cycles)


def _split(name: str) -> str:
    """``--split``'s value, a held-out split's old name as its new one (with a note)."""
    from .render.dataset import OLD_SPLIT_NAMES

    if name in OLD_SPLIT_NAMES:
        print(
            f"jnds dataset: split {name} is now called {OLD_SPLIT_NAMES[name]} and renders into a directory "
            f"of that name; the old name will go",
            file=sys.stderr,
        )
    return OLD_SPLIT_NAMES.get(name, name)


def _dataset_options(d: argparse.ArgumentParser) -> None:
    from .render.dataset import EXTRA_SEEDS, SPLITS, TRAIN_SEQUENCES
    from .render.sequence import ENGINES

    d.add_argument("--out", default="data", help="the directory the splits go to")
    d.add_argument(
        "--split",
        default="all",
        choices=SPLITS,
        type=_split,
        help="all = train + val; test (seeds never trained or selected on); Cycles only: the held-out "
        "splits of kinds no training set has, each written after the one before had been looked "
        'at (holdout, street-studio, grove-haze, bathroom-fur; docs/dataset.md, "Splits"), and '
        "media (unseen seeds of the media training kind)",
    )
    d.add_argument("--limit", type=int, default=None, help="only the first N sequences")
    d.add_argument("--list", action="store_true", help="print the sequences and exit")
    d.add_argument(
        "--train-sequences",
        type=int,
        default=TRAIN_SEQUENCES,
        help="training sequences (seeds 1000, 1001, ...; the first 24 are the default set)",
    )
    d.add_argument(
        "--moving-sequences",
        type=int,
        default=0,
        help="Mitsuba training sequences whose objects move (scene kind moving, seeds 4000, ...)",
    )
    for kind, what in EXTRA_KIND_HELP.items():
        d.add_argument(
            f"--{kind}-sequences",
            type=int,
            default=0,
            help=f"Cycles training sequences of scene kind {kind} ({what}; seeds {EXTRA_SEEDS[kind]}, ...)",
        )
    d.add_argument("--jobs", type=int, default=1, help="sequences rendered at once, in separate processes")
    d.add_argument("--variant", default=None, help="Mitsuba variant, e.g. cuda_ad_rgb on a GPU machine")
    d.add_argument(
        "--engine",
        default="mitsuba",
        choices=ENGINES,
        help="cycles: the Blender Cycles sets (seeds 5000+ / 6000+, train/cycles-*, val/cycles-*)",
    )
    d.add_argument(
        "--address",
        default=None,
        help="render the sequences as Ray tasks on this cluster ('local': an embedded Ray here); "
        "RAY_ADDRESS also selects a cluster",
    )
    d.add_argument(
        "--no-reference",
        action="store_true",
        help="inputs only (no reference frames): training data for jnds train --teacher, in a "
        "directory of its own (--out)",
    )
    d.add_argument(
        "--reference-spp",
        type=int,
        default=None,
        metavar="N",
        help="references at N samples per target pixel instead of the split's (training: 64): "
        "cheap references for jnds train --clean-references oidn, in a directory of their own (--out)",
    )
    _quiet(d)


def _train_options(p: argparse.ArgumentParser) -> None:
    from .training.config import TrainConfig

    add_options(p, TrainConfig)
    _quiet(p)


def _train_feature_net_options(p: argparse.ArgumentParser) -> None:
    from .training.feature_loss import FeatureNetConfig

    add_options(p, FeatureNetConfig)
    _quiet(p)


def _export_options(p: argparse.ArgumentParser) -> None:
    from .export import ExportConfig

    add_options(p, ExportConfig)


def _calibrate_options(p: argparse.ArgumentParser) -> None:
    from .calibration import CalibrateConfig

    add_options(p, CalibrateConfig)


def _serve_options(p: argparse.ArgumentParser) -> None:
    from .serve import ServeConfig

    add_options(p, ServeConfig)


def _batch_options(p: argparse.ArgumentParser) -> None:
    from .cluster import BatchConfig

    add_options(p, BatchConfig)
    _quiet(p)


def _run_options(p: argparse.ArgumentParser) -> None:
    from .cluster import OUTPUT_FORMAT_HELP, BatchConfig
    from .io import OUTPUT_FORMATS
    from .runtime import PipelineConfig

    p.add_argument("--input", required=True, help="a jnds-sequence/1 directory")
    p.add_argument("--output", required=True, help="the directory to write the frames and run.json to")
    add_options(p, PipelineConfig)
    # the output formats of `jnds batch`, the same default
    p.add_argument(
        "--output-format", default=BatchConfig.output_format, choices=tuple(OUTPUT_FORMATS), help=OUTPUT_FORMAT_HELP
    )
    p.add_argument(
        "--video",
        action="store_true",
        help="also OUTPUT/output.mp4: the output frames, tonemapped (needs the video extra)",
    )
    p.add_argument("--png", default=None, metavar="DIR", help="also each output frame tonemapped, as DIR/NNNN.png")
    _quiet(p)


def _evaluate_options(e: argparse.ArgumentParser) -> None:
    e.add_argument("--checkpoint", nargs="*", default=[], help="model checkpoints to score")
    e.add_argument(
        "--data",
        nargs="+",
        default=["data/val"],
        help="sets, each a sequence or a directory of sequences (e.g. data/val data/test): reported side by side",
    )
    e.add_argument(
        "--sheet",
        default=None,
        help="write a contact sheet here, a JPEG if the name ends in .jpg or "
        ".jpeg, else a PNG (middle frame of every sequence)",
    )
    e.add_argument(
        "--baselines",
        nargs="*",
        default=["bicubic", "oidn-balanced"],
        help="bicubic, oidn-fast, oidn-balanced, oidn-high",
    )
    e.add_argument("--out", default=None, help="write the report as JSON")
    e.add_argument("--threads", type=int, default=2, help="torch threads")


# name: (help, options, the function that runs it)
COMMANDS = {
    "render": ("render an animated sequence with Mitsuba 3 or Blender Cycles", _render_options, cmd_render),
    "validate": ("check sequences against jnds-sequence/1, count NaN/Inf", _validate_options, cmd_validate),
    "import": ("convert another renderer's frames into jnds-sequence/1", _import_options, None),
    "dataset": ("render (or resume) the training and validation sets", _dataset_options, cmd_dataset),
    "train": ("train the network (fp32, then QAT); resumes from <run>/checkpoint.pt", _train_options, cmd_train),
    "train-feature-net": (
        "train the feature-loss network on rendered data",
        _train_feature_net_options,
        cmd_train_feature_net,
    ),
    "export": ("write the ONNX graphs and manifest.json, validated against PyTorch", _export_options, cmd_export),
    "calibrate": ("write int8 QDQ graphs next to the fp32 ones", _calibrate_options, cmd_calibrate),
    "serve": ("serve frame streams over HTTP (protocol: jnds_deploy/serve/server.py)", _serve_options, cmd_serve),
    "batch": (
        "every sequence under a directory through the pipeline, on Ray (embedded locally, or a cluster)",
        _batch_options,
        cmd_batch,
    ),
    "run": ("denoise and upsample a sequence with the exported pipeline", _run_options, cmd_run),
    "evaluate": ("PSNR/SSIM/FLIP/temporal error of checkpoints and baselines", _evaluate_options, cmd_evaluate),
}


def build_parser() -> argparse.ArgumentParser:
    """``jnds``'s parser; a command's options are added when it is chosen (``Commands``)."""
    p = argparse.ArgumentParser(prog="jnds", description="Joint neural denoising and supersampling, deployed.")
    p.commands = p.add_subparsers(dest="command", required=True, action=Commands)
    for name, (help, options, func) in COMMANDS.items():
        p.commands.command(name, help, options, func)
    return p


def command_parser(name: str) -> argparse.ArgumentParser:
    """Command ``name``'s parser with all its options."""
    return build_parser().commands.complete(name)


# the commands that need PyTorch and ONNX (the train extra); the others run without them
NEEDS_TRAIN = ("train", "train-feature-net", "evaluate", "export", "calibrate")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] and argv[0] in NEEDS_TRAIN:
        import importlib.util

        missing = [m for m in ("torch", "onnx") if importlib.util.find_spec(m) is None]
        if missing:
            print(
                f"jnds {argv[0]}: error: needs {' and '.join(missing)}: pip install 'jnds-deploy[train]' "
                "(jnds run, serve and batch need neither)",
                file=sys.stderr,
            )
            return 2
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except JndsError as exc:
        print(f"jnds {args.command}: error: {exc}", file=sys.stderr)
        return 2


# the commands that run the pipeline in a process of their own, which they tune
# (process.tune_process)
OWN_THEIR_PROCESS = ("run", "serve", "batch")


def program() -> None:
    """The ``jnds`` program: ``main`` on the command line, then exit. For the commands that
    own their process, numpy's huge-page advice is turned off first, before their options
    import numpy, by numpy's own environment variable (``process.no_huge_page_advice``).
    The objects left are frozen before exit so that the interpreter's last garbage
    collections skip them: walking what numba and ONNX Runtime built is a visible part of a
    short `jnds run` (benchmarks/results/memory.md). Exit handlers and module teardown
    still run."""
    if sys.argv[1:2] and sys.argv[1] in OWN_THEIR_PROCESS:
        from .process import no_huge_page_advice

        no_huge_page_advice()
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    program()
