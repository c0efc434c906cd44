"""Blender in: a real Blender (bpy in its own environment) sets up and renders a scene, and
``jnds import cycles`` turns it into a sequence the pipeline runs. Skipped only where the
Blender environment is absent (``tools/setup.sh`` makes it; CI has it)."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from jnds_deploy.blender.importer import components, import_cycles, read_passes
from jnds_deploy.blender.scenes import CYCLES_SCENE_KINDS
from jnds_deploy.cli import main
from jnds_deploy.errors import RenderError, SequenceError
from jnds_deploy.io import open_sequence, read_exr, validate
from jnds_deploy.runtime import filters as N

from ..conftest import ROOT

SCENE = Path(__file__).with_name("tiny_scene.py")


def _blender_python():
    from jnds_deploy.blender.render import blender_python

    try:
        return blender_python()
    except RenderError as exc:
        pytest.skip(str(exc))


def _render(out: Path, mode: str) -> Path:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [str(_blender_python()), str(SCENE), str(out), mode], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return out


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """The tiny scene rendered as JNDS inputs (jittered), without jitter, and as reference."""
    root = tmp_path_factory.mktemp("blender")
    return {mode: _render(root / mode, mode) for mode in ("inputs", "nojitter", "reference")}


def test_configured_render_imports_validates_and_runs(renders, tmp_path, tiny_artifacts, capsys):
    assert (
        main(
            [
                "import",
                "cycles",
                str(renders["inputs"]),
                "--out",
                str(tmp_path / "seq"),
                "--reference",
                str(renders["reference"]),
                "--quiet",
            ]
        )
        == 0
    )
    report = validate(tmp_path / "seq")
    assert report.clean
    from jnds_deploy.training.data import load_sequence

    assert load_sequence(tmp_path / "seq").renderer == "cycles"  # for --balance-renderers
    seq = open_sequence(tmp_path / "seq")
    assert len(seq) == 4 and seq.native_size == (64, 40) and seq.target_size == (128, 80)
    assert [f.jitter for f in seq.frames] != [(0.0, 0.0)] * 4  # the keyed Halton jitter
    layers = seq.inputs(1)
    # the metal cube: no diffuse albedo in the format, its tint in the OIDN baseline's guide
    metal = (layers["albedo"].max(-1) == 0) & (np.abs(layers["normal"]).sum(-1) > 0.5)
    assert metal.mean() > 0.01 and layers["denoising_albedo"][metal].mean() > 0.3
    roughness = layers["roughness"]
    assert roughness.min() >= 0 and np.isclose(roughness.max(), 1.0)  # the background
    assert np.isclose(np.median(roughness[roughness < 1]), 0.6**2, atol=1e-3)  # floor: alpha = r^2
    assert main(["validate", str(tmp_path / "seq"), "--strict"]) == 0
    assert (
        main(
            [
                "run",
                "--artifacts",
                str(tiny_artifacts[0]),
                "--input",
                str(tmp_path / "seq"),
                "--output",
                str(tmp_path / "run"),
                "--precision",
                "fp32",
                "--quiet",
            ]
        )
        == 0
    )
    # on Cycles' data the run computes what the torch specification does (as on the sample,
    # tests/runtime/test_pipeline.py), and scores the frames it wrote against the reference
    from jnds_deploy.metrics import psnr
    from jnds_deploy.training.evaluate import infer_sequence

    want = infer_sequence(tiny_artifacts[1], load_sequence(tmp_path / "seq"))
    scores = json.loads((tmp_path / "run" / "run.json").read_text())["metrics"]["per_frame"]
    assert len(want) == len(scores) == len(seq)
    for i in range(len(seq)):
        out = read_exr(tmp_path / "run" / f"{i:04d}.exr")
        out = np.stack([out[f"color.{c}"] for c in "RGB"], -1)
        assert out.shape == (80, 128, 3) and np.isfinite(out).all() and out.min() >= 0
        rel = np.abs(out - want[i]).mean() / np.abs(want[i]).mean()
        assert rel < 1e-4, (i, rel)
        assert scores[i]["psnr"] == pytest.approx(psnr(out, seq.reference(i)["color"]), abs=1e-9), i
    assert (tmp_path / "run" / "contact.png").is_file()


def test_composite_reproduces_combined(renders):
    for n in (1, 2, 3, 4):
        for kind in ("inputs", "reference"):
            passes = read_passes(renders[kind] / f"{n:04d}.exr")
            c = components(passes)
            combined = passes["Combined"][..., :3]
            err = np.abs(c["albedo"] * c["diffuse"] + c["specular"] - combined)
            assert err.max() <= 1e-5 * np.abs(combined).max(), (kind, n, err.max())


def test_motion_vectors_warp_the_previous_frame(renders, tmp_path):
    """Warping frame t-1's G-buffer (albedo, normal: noise-free) along the motion vectors
    into frame t cuts the error outside disocclusions at least 1.5x against zero motion,
    and the jittered render's vectors equal an unjittered render's (the pixel centre's point)."""
    import_cycles(renders["inputs"], tmp_path / "seq", progress=False)
    import_cycles(renders["nojitter"], tmp_path / "plain", progress=False)
    seq, plain = open_sequence(tmp_path / "seq"), open_sequence(tmp_path / "plain")
    for i in (1, 2, 3):
        a, b = plain.inputs(i - 1), plain.inputs(i)
        prev = np.concatenate([a["albedo"], a["normal"]], -1).transpose(2, 0, 1)
        cur = np.concatenate([b["albedo"], b["normal"]], -1).transpose(2, 0, 1)
        warped = N.warp(prev, b["motion"].transpose(2, 0, 1))
        same = ((warped[3:] * cur[3:]).sum(0) > 0.95) & (np.abs(cur[3:]).sum(0) > 0)  # not disoccluded
        moved = np.abs(warped - cur).mean(0)[same].mean()
        still = np.abs(prev - cur).mean(0)[same].mean()
        assert moved * 1.5 < still, (i, moved, still)
        assert np.abs(b["motion"]).max() > 0.5  # camera and cube do move
        jittered = seq.inputs(i)["motion"]
        fg = (np.abs(b["normal"]).sum(-1) > 0) & (np.abs(seq.inputs(i)["normal"]).sum(-1) > 0)
        assert np.median(np.abs(jittered - b["motion"])[fg]) < 0.05


def test_reference_after_configure_is_not_jittered(renders, tmp_path):
    """configure_reference on a scene configure set up renders what it renders on a fresh
    scene: the jitter keys are gone and the lens shift is back where it was."""
    again = _render(tmp_path / "ref", "reference-after-inputs")
    for n in (1, 4):
        a, b = read_passes(renders["reference"] / f"{n:04d}.exr"), read_passes(again / f"{n:04d}.exr")
        np.testing.assert_array_equal(a["Combined"], b["Combined"])


def test_a_render_missing_passes_is_refused_naming_them(tmp_path):
    raw = _render(tmp_path / "plain", "plain")
    with pytest.raises(
        SequenceError,
        match=r"missing Cycles pass\(es\): .*Diffuse Direct \(Passes > Light.*"
        r"Vector \(Passes > Data > Vector.*Roughness",
    ):
        import_cycles(raw, tmp_path / "seq", progress=False)
    assert not (tmp_path / "seq" / "sequence.json").exists()


def test_jnds_render_cycles_is_deterministic(tmp_path):
    _blender_python()
    args = [
        "render",
        "--engine",
        "cycles",
        "--scene",
        "metals",
        "--seed",
        "4",
        "--camera",
        "orbit",
        "--frames",
        "2",
        "--size",
        "32x18",
        "--spp",
        "4",
        "--quiet",
    ]
    for d in ("a", "b"):
        assert main(args + ["--out", str(tmp_path / d)]) == 0
    a, b = open_sequence(tmp_path / "a"), open_sequence(tmp_path / "b")
    assert not (tmp_path / "a" / ".cycles").exists()  # the raw frames are gone once imported
    for i in range(2):
        for k, v in a.inputs(i).items():
            np.testing.assert_array_equal(b.inputs(i)[k], v, err_msg=f"frame {i} {k}")
        np.testing.assert_array_equal(b.reference(i)["color"], a.reference(i)["color"])


@pytest.mark.parametrize("kind", CYCLES_SCENE_KINDS)
def test_every_cycles_scene_kind_renders_a_lit_valid_frame(kind, tmp_path):
    _blender_python()
    out = tmp_path / kind
    assert (
        main(
            [
                "render",
                "--engine",
                "cycles",
                "--scene",
                kind,
                "--seed",
                "3",
                "--camera",
                "static",
                "--frames",
                "1",
                "--size",
                "32x18",
                "--spp",
                "2",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert validate(out).clean
    seq = open_sequence(out)
    inputs, ref = seq.inputs(0), seq.reference(0)["color"]
    assert np.isfinite(ref).all() and ref.mean() > 0
    assert (inputs["diffuse"] + inputs["specular"]).max() > 0


def test_the_cycles_test_and_holdout_splits_are_made_of_kinds_training_never_has():
    """Each unseen split (test, then the holdouts in the order they were written) is made of its
    own kinds and seeds, none of which any split before it, training or validation has."""
    from jnds_deploy.blender.scenes import CYCLES_EXTRA_KINDS, CYCLES_GHOST_KINDS, CYCLES_SCENE_KINDS
    from jnds_deploy.cli import EXTRA_KIND_HELP
    from jnds_deploy.render.dataset import EXTRA_SEEDS, UNSEEN_KINDS, dataset_specs

    assert set(EXTRA_SEEDS) == set(CYCLES_EXTRA_KINDS)  # every training-only kind has its seeds
    assert set(EXTRA_KIND_HELP) == set(CYCLES_EXTRA_KINDS)  # and its --<kind>-sequences
    extra = dict.fromkeys(CYCLES_EXTRA_KINDS, 20)
    seen = [
        (cfg.scene, cfg.seed)
        for split in ("train", "val")
        for _, cfg in dataset_specs(split, 200, engine="cycles", extra_sequences=extra)
    ]
    kinds, seeds = {k for k, _ in seen}, {s for _, s in seen}
    assert set(CYCLES_EXTRA_KINDS) <= kinds
    assert list(UNSEEN_KINDS) == ["test", "holdout", "street-studio", "grove-haze", "bathroom-fur"]
    for split, split_kinds in UNSEEN_KINDS.items():
        specs = [cfg for _, cfg in dataset_specs(split, engine="cycles")]
        got = {cfg.scene for cfg in specs}
        assert got == set(split_kinds) and not got & kinds, split
        assert not {cfg.seed for cfg in specs} & seeds, split
        kinds |= got
        seeds |= {cfg.seed for cfg in specs}
    # every kind is in some split, but the ghosting sets' (rendered by `jnds render`, docs/ghosting.md)
    assert kinds | set(CYCLES_GHOST_KINDS) == set(CYCLES_SCENE_KINDS) and not kinds & set(CYCLES_GHOST_KINDS)


def test_the_held_out_splits_old_names_are_their_new_ones_with_a_warning(capsys):
    """``holdout2``, ``holdout3`` and ``holdout4`` are what ``street-studio``, ``grove-haze`` and
    ``bathroom-fur`` were called: the same sequences under the new name, and a warning."""
    from jnds_deploy.render.dataset import OLD_SPLIT_NAMES, dataset_specs

    assert OLD_SPLIT_NAMES == {"holdout2": "street-studio", "holdout3": "grove-haze", "holdout4": "bathroom-fur"}
    for old, new in OLD_SPLIT_NAMES.items():
        with pytest.warns(FutureWarning, match=f"{old}.*now called.*{new}"):
            assert dataset_specs(old, engine="cycles") == dataset_specs(new, engine="cycles")
        assert main(["dataset", "--engine", "cycles", "--split", old, "--list"]) == 0
        out, err = capsys.readouterr()
        assert f"split {old} is now called {new}" in err
        assert [line.split()[0] for line in out.splitlines()] == [rel for rel, _ in dataset_specs(new, engine="cycles")]
        assert all(line.startswith(f"{new}/") for line in out.splitlines())


def test_the_media_split_is_unseen_seeds_of_the_media_training_kind():
    from jnds_deploy.errors import ConfigError
    from jnds_deploy.render.dataset import dataset_specs

    train = {cfg.seed for _, cfg in dataset_specs("train", 200, engine="cycles", extra_sequences={"media": 100})}
    media = [cfg for _, cfg in dataset_specs("media", engine="cycles")]
    assert len(media) == 6 and {cfg.scene for cfg in media} == {"media"}
    assert not {cfg.seed for cfg in media} & train
    with pytest.raises(ConfigError, match="media sequences must be in 0..100"):
        dataset_specs("train", engine="cycles", extra_sequences={"media": 101})
    with pytest.raises(ConfigError, match="Cycles only"):
        dataset_specs("media")


def test_procedural_cameras_stay_inside_their_rooms():
    """The ``mixed``, ``lights`` and ``interior`` training kinds draw a room's size and the camera's radius
    apart; before the clamp, lights 10002, 10009 and 10012 looked at walls from outside
    (docs/dataset.md). Every training seed rendered so far, built and not rendered."""
    from jnds_deploy.blender.render import scene_job
    from jnds_deploy.render.dataset import dataset_specs

    jobs = [
        scene_job(c)
        for _, c in dataset_specs("train", 1, "cycles", extra_sequences={"mixed": 24, "lights": 24, "interior": 16})
        if c.scene in ("mixed", "lights", "interior")
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [str(_blender_python()), str(Path(__file__).with_name("camera_paths.py")), json.dumps(jobs)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    found = [json.loads(line[7:]) for line in proc.stdout.splitlines() if line.startswith("CAMERA ")]
    assert len(found) == len(jobs) == 64
    assert sum(r["half"] is not None for r in found) >= 10  # rooms were drawn, so the check saw some
    assert [r for r in found if r["outside"]] == []


def test_pixels_scattered_in_a_volume_import_facing_the_camera_not_as_background(tmp_path):
    """A camera ray that scatters in a medium before any surface leaves Normal, Depth and
    Vector empty, as the background does, but its radiance is noisy: the import gives it the
    direction back to the camera (Cycles' Denoising Normal marks it), so the pipeline's
    disocclusion test keeps its history. The world's pixels stay background."""
    raw = _render(tmp_path / "vol", "volume")
    toward = json.loads((raw / "jnds.json").read_text())["toward_camera"]
    # the tiny scene's camera is turned 65 degrees about X: its +Z axis is (0, -sin 65, cos 65)
    expected = np.array([0.0, -np.sin(np.radians(65)), np.cos(np.radians(65))])
    import_cycles(raw, tmp_path / "seq", progress=False)
    seq = open_sequence(tmp_path / "seq")
    for i in range(len(seq)):
        np.testing.assert_allclose(toward[str(i + 1)], expected, atol=1e-6)
        passes = read_passes(raw / f"{i + 1:04d}.exr")
        no_surface = ~np.any(passes["Normal"][..., :3] != 0, -1)
        volume = no_surface & np.any(passes["Denoising Normal"][..., :3] != 0, -1)
        assert volume.mean() > 0.02 and (no_surface & ~volume).mean() > 0.005, (volume.mean(), no_surface.mean())
        layers = seq.inputs(i)
        np.testing.assert_allclose(
            layers["normal"][volume], np.broadcast_to(expected, (volume.sum(), 3)), atol=1e-3
        )  # stored as half
        assert not layers["normal"][no_surface & ~volume].any()
        assert not layers["motion"][no_surface & ~volume].any() and (layers["roughness"][no_surface] == 1).all()
        if i > 0:  # the camera moves: volume pixels take the surfaces' motion around them
            assert np.abs(layers["motion"][volume]).max() > 0.1
        # the medium's light is what makes these pixels noisy
        assert (passes["Volume Direct"][..., :3].sum(-1) + passes["Volume Indirect"][..., :3].sum(-1))[volume].max() > 0


def _volume_passes(volume_mark: bool) -> dict:
    """One frame's passes, 2x2: a surface, the background, and two pixels whose camera rays
    scattered in a volume (one lit, one not)."""
    z3 = np.zeros((2, 2, 3), np.float32)
    normal = z3.copy()
    normal[0, 0] = (0, 0, 1)
    passes = {
        n: z3.copy()
        for n in (
            "Combined",
            "Diffuse Direct",
            "Diffuse Indirect",
            "Diffuse Color",
            "Glossy Direct",
            "Glossy Indirect",
            "Glossy Color",
            "Transmission Direct",
            "Transmission Indirect",
            "Transmission Color",
            "Volume Direct",
            "Volume Indirect",
            "Emission",
            "Environment",
        )
    }
    passes.update(
        {
            "Normal": normal,
            "Vector": np.zeros((2, 2, 4), np.float32),
            "Depth": np.full((2, 2, 1), 1e10, np.float32),
            "Roughness": np.full((2, 2, 1), 0.5, np.float32),
        }
    )
    passes["Volume Direct"][1, 0] = 0.7
    if volume_mark:
        passes["Denoising Normal"] = z3.copy()
        passes["Denoising Normal"][1, :] = (0, 0, -1)
    return passes


def test_volume_pixels_need_the_camera_direction_and_a_render_without_the_mark_is_counted(tmp_path):
    from jnds_deploy.blender.importer import input_layers, unmarked_volume_pixels

    layers = input_layers(_volume_passes(True), tmp_path / "0001.exr", [0.0, -1.0, 0.0])
    np.testing.assert_array_equal(layers["normal"][1], [[0, -1, 0], [0, -1, 0]])
    np.testing.assert_array_equal(layers["normal"][0], [[0, 0, 1], [0, 0, 0]])
    with pytest.raises(SequenceError, match=r"0001\.exr.*2 pixels scattered in a volume.*toward_camera"):
        input_layers(_volume_passes(True), tmp_path / "0001.exr", None)
    assert unmarked_volume_pixels(_volume_passes(True)) == 0
    unmarked = _volume_passes(False)
    assert unmarked_volume_pixels(unmarked) == 1  # the lit one: the unlit one cannot be told from the world
    assert not input_layers(unmarked, tmp_path / "0001.exr", None)["normal"][1].any()


def test_volume_pixels_take_the_motion_of_the_surfaces_around_them():
    from jnds_deploy.blender.importer import volume_motion

    h, w = 40, 64
    motion = np.zeros((h, w, 2), np.float32)
    surface = np.ones((h, w), bool)
    surface[14:18, 23:27] = False  # a block of medium in front of a surface moving by (1.5, -2)
    motion[surface] = (1.5, -2.0)
    volume = ~surface
    out = volume_motion(motion, volume, surface)
    np.testing.assert_allclose(out[volume], np.broadcast_to((1.5, -2.0), (volume.sum(), 2)), rtol=1e-5)
    np.testing.assert_array_equal(out[surface], motion[surface])
    # a frame all medium has nothing to take it from; one without a medium is left alone
    assert not volume_motion(np.zeros_like(motion), np.ones((h, w), bool), np.zeros((h, w), bool)).any()
    np.testing.assert_array_equal(volume_motion(motion, np.zeros((h, w), bool), surface), motion)
