"""The ``jnds`` command line. Every error a user can make with a path -- missing data,
checkpoint, artifacts, sequence -- is one line on stderr naming the path, and exit code 2.
Each option is written once, on its configuration dataclass, its default included."""

import pytest

from jnds_deploy.cli import main

from .conftest import SAMPLE


@pytest.mark.parametrize(
    "argv, names",
    [
        (["train", "--data", "{tmp}/nodata", "--run", "{tmp}/run", "--quiet"], "{tmp}/nodata/train"),
        (["train-feature-net", "--data", "{tmp}/nodata", "--out", "{tmp}/f.pt", "--quiet"], "{tmp}/nodata/train"),
        (["evaluate", "--checkpoint", "{tmp}/none.pt", "--data", str(SAMPLE), "--baselines"], "{tmp}/none.pt"),
        (["evaluate", "--data", "{tmp}/noseq", "--baselines", "bicubic"], "{tmp}/noseq"),
        (["export", "--checkpoint", "{tmp}/none.pt", "--out", "{tmp}/art"], "{tmp}/none.pt"),
        (["calibrate", "--artifacts", "{tmp}/noart", "--data", str(SAMPLE)], "{tmp}/noart/manifest.json"),
        (
            ["run", "--artifacts", "{tmp}/noart", "--input", str(SAMPLE), "--output", "{tmp}/o", "--quiet"],
            "{tmp}/noart/manifest.json",
        ),
        (
            ["run", "--artifacts", "{tmp}/noart", "--input", "{tmp}/noseq", "--output", "{tmp}/o", "--quiet"],
            "{tmp}/noseq",
        ),
        (["validate", "{tmp}/noseq"], "{tmp}/noseq"),
        (["serve", "--artifacts", "{tmp}/noart"], "{tmp}/noart/manifest.json"),
        (
            ["batch", "--artifacts", "{tmp}/noart", "--input", str(SAMPLE), "--output", "{tmp}/o", "--quiet"],
            "{tmp}/noart/manifest.json",
        ),
    ],
)
def test_missing_paths_are_one_line_errors(argv, names, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"jnds {argv[0]}: error: "), err
    assert names.replace("{tmp}", str(tmp_path)) in err[0]


def test_a_file_that_is_not_a_checkpoint_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert main(["export", "--checkpoint", str(bad), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}: unreadable checkpoint" in err[0]


def test_batch_without_sequences_is_a_one_line_error(tiny_artifacts, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    for root in ("empty", "missing"):
        assert (
            main(
                [
                    "batch",
                    "--artifacts",
                    str(tiny_artifacts[0]),
                    "--input",
                    str(tmp_path / root),
                    "--output",
                    str(tmp_path / "o"),
                    "--quiet",
                ]
            )
            == 2
        )
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("jnds batch: error: ") and str(tmp_path / root) in err[0], err


def test_dataset_reports_a_resumed_sequence(tmp_path, capsys, monkeypatch):
    """A sequence whose frames were all rendered before a resume has no timings of this run
    (None): the summary says so instead of failing after the work is done."""
    import jnds_deploy.render.dataset as dataset

    seq = tmp_path / "train" / "a"
    monkeypatch.setattr(dataset, "render_dataset", lambda *a, **k: [(seq, {"inputs": None, "reference": 12.5})])
    assert main(["dataset", "--out", str(tmp_path), "--split", "train", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"{seq}: inputs none rendered in this run, reference 12.50 s/frame" in out


def test_int8_by_default_needs_calibrated_artifacts(tiny_artifacts, tmp_path, capsys):
    """`jnds run`, `jnds batch`, `jnds serve` and PipelineConfig run int8 unless told
    otherwise: artifacts without int8 graphs are a one-line error saying what to do."""
    from jnds_deploy.cluster import BatchConfig
    from jnds_deploy.runtime import PipelineConfig
    from jnds_deploy.serve import ServeConfig

    assert (
        PipelineConfig(artifacts="a").precision
        == BatchConfig(input="b", output="c", artifacts="a").precision
        == ServeConfig(artifacts="a").precision
        == "int8"
    )
    assert (
        main(
            [
                "run",
                "--artifacts",
                str(tiny_artifacts[0]),
                "--input",
                str(SAMPLE),
                "--output",
                str(tmp_path / "o"),
                "--quiet",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no int8 graphs" in err[0], err
    assert "`jnds calibrate" in err[0] and "--precision fp32" in err[0]


def test_train_init_carries_the_checkpoints_model_settings_unless_given(tmp_path, monkeypatch):
    """`jnds train --init CKPT` trains the checkpoint's model: the settings a flag does not
    give (preset and output width, upsample root, firefly clamp, fill, albedo at holes,
    fixed upsample...) are the checkpoint's, not the command line's defaults."""
    import torch

    import jnds_deploy.training.train as training
    from jnds_deploy.model import ModelConfig
    from jnds_deploy.training.config import TrainConfig

    model = ModelConfig.preset(
        "tiny",
        output_width=2,
        upsample_root=4,
        firefly_clamp=16.0,
        diffuse_fill=True,
        albedo_at_holes=True,
        upsample_width=0,
        upsample_features=0,
    )
    ckpt = tmp_path / "init.pt"
    torch.save({"model": {}, "model_config": model.__dict__, "train_config": {"preset": "tiny"}}, ckpt)
    seen = []
    monkeypatch.setattr(training, "train", lambda cfg, progress: seen.append(cfg) or tmp_path / "c.pt")

    def trained(*flags):
        assert main(["train", "--run", str(tmp_path / "r"), "--quiet", *flags]) == 0
        return seen[-1]

    cfg = trained("--init", str(ckpt))
    assert cfg.model_config() == model
    assert (cfg.preset, cfg.output_width, cfg.fixed_upsample, cfg.init) == ("tiny", 2, True, str(ckpt))
    cfg = trained("--init", str(ckpt), "--upsample-root", "1", "--firefly-clamp", "0", "--no-diffuse-fill")
    assert (cfg.upsample_root, cfg.firefly_clamp, cfg.diffuse_fill, cfg.albedo_at_holes) == (1, 0.0, False, True)
    cfg = trained("--init", str(ckpt), "--preset", "small")  # the architecture as a whole from the flags
    assert (cfg.preset, cfg.output_width, cfg.upsample_root) == ("small", 0, 4)
    assert trained() == TrainConfig(run=str(tmp_path / "r"))  # no --init: the dataclass's defaults


# the commands whose options are derived from a configuration dataclass (options.add_options)
CONFIGS = {
    "render": "jnds_deploy.render.RenderConfig",
    "train": "jnds_deploy.training.config.TrainConfig",
    "train-feature-net": "jnds_deploy.training.feature_loss.FeatureNetConfig",
    "export": "jnds_deploy.export.ExportConfig",
    "calibrate": "jnds_deploy.calibration.CalibrateConfig",
    "serve": "jnds_deploy.serve.ServeConfig",
    "batch": "jnds_deploy.cluster.BatchConfig",
    "run": "jnds_deploy.runtime.PipelineConfig",
}


@pytest.mark.parametrize("command", sorted(CONFIGS))
def test_every_flags_default_is_its_dataclass_fields(command, monkeypatch):
    """No default is written twice: each option of a command built from a dataclass has the
    default of its field and no other. The parser holds none (a command line without the
    flag gives the field's default), --help shows the field's, and no flag written by hand
    sets a field."""
    import argparse
    import dataclasses
    import importlib

    from jnds_deploy.cli import COMMANDS, build_parser, command_parser
    from jnds_deploy.options import given, options_of, shown_default

    monkeypatch.setenv("COLUMNS", "10000")  # --help's lines unwrapped

    module, name = CONFIGS[command].rsplit(".", 1)
    cls = getattr(importlib.import_module(module), name)
    parser = command_parser(command)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    derived = {a.dest: a for a in parser._actions if hasattr(a, "field")}
    assert set(derived) == {f.name for f in options_of(cls)}
    text = parser.format_help()
    for dest, action in derived.items():
        assert action.field is fields[dest] and action.default is argparse.SUPPRESS, dest
        default = fields[dest].default
        if default is not dataclasses.MISSING and not action.required:
            shown = shown_default(action)
            assert shown is None or f"(default: {shown})" in text, (dest, shown)
            if isinstance(action, argparse.BooleanOptionalAction):
                assert shown == f"--{'' if default else 'no-'}{action.option_strings[0][2:]}"
    for action in parser._actions:  # the options written by hand set no field
        assert hasattr(action, "field") or action.dest not in fields, action.dest
    required = [a for a in parser._actions if a.required and a.option_strings]
    argv = [command] + [v for a in required for v in (a.option_strings[0], "x")]
    args = build_parser().parse_args(argv)
    assert given(args, cls) == {a.dest: ("x",) if a.nargs == "+" else "x" for a in required if a.dest in fields}
    assert set(COMMANDS) >= set(CONFIGS)


def test_hand_written_defaults_follow_their_source():
    """`jnds run --output-format` (not a PipelineConfig field) has `jnds batch`'s default,
    which is the runtime's."""
    import inspect

    from jnds_deploy.cli import command_parser
    from jnds_deploy.cluster import BatchConfig
    from jnds_deploy.runtime.run import run_sequence

    fmt = next(a for a in command_parser("run")._actions if a.dest == "output_format")
    runtime = inspect.signature(run_sequence).parameters["output_format"].default
    assert fmt.default == BatchConfig.output_format == runtime


def test_the_parser_imports_no_torch():
    """`jnds --help`, `jnds run --help` and `jnds run`'s options need no torch (nor, for
    --help, numpy): a command's options load with the command."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['torch'] = None\n"
        "from jnds_deploy.cli import build_parser\n"
        "for argv in (['--help'], ['run', '--help'], ['batch', '--help'], ['train', '--help']):\n"
        "    try:\n"
        "        build_parser().parse_args(argv)\n"
        "    except SystemExit as e:\n"
        "        assert e.code == 0, argv\n"
        "    if argv == ['--help']:\n"
        "        assert 'numpy' not in sys.modules, 'numpy was imported'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
