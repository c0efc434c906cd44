import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from jnds_deploy.errors import RenderError
from jnds_deploy.io import open_sequence, validate
from jnds_deploy.metrics import motion_warp_error
from jnds_deploy.render.camera import Camera, camera_path
from jnds_deploy.sampling import jitter

from .conftest import SAMPLE, assert_same_sequences

mitsuba = pytest.importorskip("mitsuba", reason="render extra not installed")


# ---------------------------------------------------------------------------------------
# camera math (numpy only)


def test_project_inverts_rays():
    cam = Camera((3.0, 2.0, 5.0), (0.0, 0.5, 0.0), 50.0)
    size = (64, 36)
    rng = np.random.default_rng(1)
    px, py = rng.uniform(0, 64, 100), rng.uniform(0, 36, 100)
    o, d = cam.rays(px, py, size)
    pos, front = cam.project(o + d * rng.uniform(1, 20, (100, 1)), size)
    assert front.all()
    np.testing.assert_allclose(pos, np.stack([px, py], 1), atol=1e-9)
    # directions project as points at infinity
    pos_inf, _ = cam.project(np.full((100, 3), np.nan), size, directions=d)
    np.testing.assert_allclose(pos_inf, np.stack([px, py], 1), atol=1e-9)


def test_jitter_is_halton_in_range():
    js = np.array([jitter(i) for i in range(16)])
    assert (np.abs(js) <= 0.5).all()
    assert len({tuple(j) for j in js}) == 16
    np.testing.assert_allclose(js[0], (0.0, -1 / 6))  # Halton(1) = (1/2, 1/3), centred
    assert jitter(16) == jitter(0)


@pytest.mark.parametrize("kind", ["static", "dolly", "orbit", "pan", "cut"])
def test_camera_paths_move_as_named(kind):
    cams, cuts = camera_path(kind, 6, np.random.default_rng(3))
    assert len(cams) == 6 and len(cuts) == 6
    origins = np.array([c.origin for c in cams])
    targets = np.array([c.target for c in cams])
    moved_o = np.linalg.norm(np.diff(origins, axis=0), axis=1)
    moved_t = np.linalg.norm(np.diff(targets, axis=0), axis=1)
    if kind == "static":
        assert moved_o.max() == 0 and moved_t.max() == 0
    if kind in ("dolly", "orbit"):
        assert moved_o.min() > 0 and moved_t.max() == 0
    if kind == "pan":
        assert moved_o.max() == 0 and moved_t.min() > 0
    assert cuts == ([False, False, False, True, False, False] if kind == "cut" else [False] * 6)


# ---------------------------------------------------------------------------------------
# motion vectors: warping frame t-1's reference into frame t


def warp_errors(seq, t):
    m = motion_warp_error(seq, t)
    return m["warped"], m["unwarped"], m["valid"]


def test_motion_vectors_warp_sample_reference():
    seq = open_sequence(SAMPLE)
    for t in range(1, len(seq)):
        warped, identity, valid = warp_errors(seq, t)
        # measured on the sample: warped ~0.0028, identity ~0.013-0.015, ~82% of pixels valid
        assert valid > 0.7
        assert warped < 0.005 and warped < 0.35 * identity, (t, warped, identity)


# ---------------------------------------------------------------------------------------
# rendering with Mitsuba


def _render(tmp_path, name, *args):
    out = tmp_path / name
    proc = subprocess.run(
        [sys.executable, "-m", "jnds_deploy", "render", "--quiet", "--out", str(out), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return out, proc


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The issue's example: 4 frames at 64x36, 16 spp reference, with a camera cut."""
    out, proc = _render(
        tmp_path_factory.mktemp("render"),
        "tiny",
        "--scene",
        "procedural",
        "--camera",
        "cut",
        "--seed",
        "11",
        "--frames",
        "4",
        "--size",
        "64x36",
        "--spp",
        "16",
    )
    return out, proc.stdout


def test_tiny_render_validates(tiny):
    out, stdout = tiny
    assert "4 frames, all files readable" in stdout and "no NaN or Inf" in stdout
    report = validate(out)
    assert report.clean
    seq = open_sequence(out)
    assert seq.native_size == (64, 36) and seq.target_size == (128, 72)
    assert [f.camera_cut for f in seq.frames] == [False, False, True, False]
    assert [f.jitter for f in seq.frames] == [jitter(i) for i in range(4)]
    for i in range(4):
        a = seq.inputs(i)
        still = i in (0, 2)  # first frame and the cut: no previous camera
        assert (np.abs(a["motion"]).max() == 0) == still
        assert a["specular"].min() >= 0 and a["diffuse"].min() >= 0
        # demodulated diffuse is 0 where albedo is ~0 (background, metal)
        dark = a["albedo"] <= 1e-3
        assert (a["diffuse"][dark] == 0).all()
        assert set(seq.reference(i)) == {"color", "diffuse", "specular", "albedo"}
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["renderer"]["config"]["seed"] == 11 and len(meta["renderer"]["cameras"]) == 4


def test_tiny_render_motion_vectors(tiny):
    seq = open_sequence(tiny[0])
    warped, identity, _ = warp_errors(seq, 3)
    assert warped < 0.5 * identity, (warped, identity)


def test_moving_objects_motion_vectors_follow_the_objects():
    """Scene kind ``moving``: a static camera, objects that move and turn. Where a moving
    object's pixel's vector points, the previous frame sees the same object, at the point
    of it the pixel sees now (carried back with the object); nothing else moves."""
    from jnds_deploy.render.integrator import SplitPathTracer, load_mitsuba
    from jnds_deploy.render.scene import EXTENT, OBJECT_PREFIX, build_scene, object_motion
    from jnds_deploy.render.sequence import _turn_y, motion_vectors, moved_objects

    mi, dr = load_mitsuba(None)
    seed, frames, size = 5, 4, (160, 90)
    cam = camera_path("static", frames, np.random.default_rng(0), extent=EXTENT)[0][0]
    names = [k for k in build_scene(mi, seed, "moving")[0] if k.startswith(OBJECT_PREFIX)]
    motion = object_motion(seed, "moving", names)
    assert 0 < len(motion) < len(names)
    assert object_motion(seed, "procedural", names) == {}
    moved = moved_objects(
        build_scene(mi, seed, "moving", 2, frames)[0], build_scene(mi, seed, "moving", 1, frames)[0], motion
    )
    prev, now = (SplitPathTracer(mi, dr, *build_scene(mi, seed, "moving", i, frames)) for i in (1, 2))
    mv = motion_vectors(now, cam, cam, size, moved).reshape(-1, 2)

    rows, cols = np.mgrid[0 : size[1], 0 : size[0]]
    pix = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], 1)  # pixel centres (x, y)
    o, d = cam.rays(pix[:, 0], pix[:, 1], size)
    t, shape = now.intersect(o, d, shapes=True)
    hit = np.array(now.shape_names + [""])[shape]
    on = np.isin(hit, list(motion))
    assert on.sum() > 100
    assert np.abs(mv[~on]).max() < 1e-3  # the camera and the other objects stand still
    q = pix + mv
    o0, d0 = cam.rays(q[:, 0], q[:, 1], size)
    t0, shape0 = prev.intersect(o0, d0, shapes=True)
    same = on & (np.array(prev.shape_names + [""])[shape0] == hit)
    assert same.sum() > 0.8 * on.sum()  # the rest: hidden in the previous frame
    p_now, p_prev = o + t[:, None] * d, o0 + t0[:, None] * d0
    carried = np.zeros_like(p_now)
    for name, (centre, move, turn) in moved.items():
        k = same & (hit == name)
        carried[k] = _turn_y(p_now[k] - centre, -turn) + centre - move
    assert np.abs(p_prev[same] - carried[same]).max() < 2e-3


def test_render_is_deterministic_and_resumes(tmp_path, tiny):
    args = ("--camera", "cut", "--seed", "11", "--frames", "4", "--size", "64x36", "--spp", "16")
    first = open_sequence(tiny[0])
    # resume: keep frames 0 and 1, drop the rest; the re-render must equal the original
    out = tmp_path / "again"
    import shutil

    shutil.copytree(tiny[0], out)
    (out / "sequence.json").unlink()
    for i in (2, 3):
        (out / "inputs" / f"{i:04d}.exr").unlink()
    (out / "reference" / "0003.exr").unlink()
    _render(tmp_path, "again", "--scene", "procedural", *args)
    again = open_sequence(out)
    for i in range(4):
        for k, v in first.inputs(i).items():
            np.testing.assert_array_equal(again.inputs(i)[k], v, err_msg=f"frame {i} {k}")
        np.testing.assert_array_equal(again.reference(i)["color"], first.reference(i)["color"])
    # another configuration into the same directory is refused, nothing is overwritten
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "jnds_deploy",
            "render",
            "--quiet",
            "--out",
            str(out),
            "--seed",
            "12",
            "--frames",
            "4",
            "--size",
            "64x36",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "another configuration" in proc.stderr
    assert validate(out).frame_count == 4


def test_bad_render_config():
    from jnds_deploy.render import RenderConfig

    with pytest.raises(RenderError, match="--frames must be >= 1"):
        RenderConfig(frames=0)
    with pytest.raises(RenderError, match="--scene 'moon'"):
        RenderConfig(scene="moon")


@pytest.fixture(scope="module")
def tracer():
    from jnds_deploy.render.integrator import SplitPathTracer, load_mitsuba
    from jnds_deploy.render.scene import build_scene

    mi, dr = load_mitsuba()
    scene, materials = build_scene(mi, 5, "procedural")
    # small bright bulbs make point sampling (inputs) and box filtering (reference) differ
    # by several percent of the frame mean at 32x18; this test is about the estimators
    scene = {k: v for k, v in scene.items() if not k.startswith("bulb")}
    return SplitPathTracer(mi, dr, scene, materials)


def test_high_spp_input_matches_reference_and_1spp_mean(tracer):
    """The three estimators of one static frame agree:
    - input composite albedo*diffuse + specular at 256 spp (all at the jittered position),
    - the 2x reference at 64 spp per target pixel, box-downsampled to native,
    - the mean of 8 independent 1-spp inputs.
    """
    from jnds_deploy.render.sequence import RenderConfig, render_inputs, render_reference

    cam = camera_path("static", 1, np.random.default_rng(4))[0][0]
    cfg = RenderConfig(size=(32, 18), spp=64, spp_input=256)
    comp = lambda a: a["albedo"] * a["diffuse"] + a["specular"]  # noqa: E731
    hi = comp(render_inputs(tracer, cfg, cam, (0.0, 0.0), seed=1))
    ref = render_reference(tracer, cfg, cam, seed=2)["color"]
    ref = ref.reshape(18, 2, 32, 2, 3).mean((1, 3))
    one = RenderConfig(size=(32, 18), spp_input=1)
    mean1 = np.mean([comp(render_inputs(tracer, one, cam, (0.0, 0.0), seed=100 + k)) for k in range(8)], 0)

    def rel(a, b):  # relative difference of the frame means, per channel
        return np.abs(a.mean((0, 1)) - b.mean((0, 1))) / b.mean((0, 1))

    # tolerance 5% on frame means; measured 0.1-2.4% (Monte Carlo noise)
    assert rel(hi, ref).max() < 0.05, rel(hi, ref)
    assert rel(mean1, hi).max() < 0.05, rel(mean1, hi)
    # per pixel, on 4x4-blurred log images (edges differ: the input is point-sampled);
    # measured medians 0.005-0.007
    blur = lambda a: cv2.blur(np.log1p(a), (4, 4))  # noqa: E731
    assert np.median(np.abs(blur(hi) - blur(ref))) < 0.02
    assert np.median(np.abs(blur(mean1) - blur(hi))) < 0.02


def test_the_scene_renders_the_same_in_whatever_order_mitsuba_loads_its_emitters():
    """Mitsuba orders a loaded scene's emitters differently from one load to the next (2 of
    the 4 emitters swapped in 4 of 12 loads when measured); the tracer picks emitters in a
    fixed order, so every load renders the same samples."""
    from jnds_deploy.render.integrator import SplitPathTracer, load_mitsuba
    from jnds_deploy.render.integrator import emitter_id as name
    from jnds_deploy.render.scene import build_scene
    from jnds_deploy.render.sequence import RenderConfig, render_inputs

    mi, dr = load_mitsuba()
    cfg = RenderConfig(size=(24, 14), spp_input=2)
    cam = camera_path("static", 1, np.random.default_rng(4))[0][0]
    outs = []
    for _ in range(6):
        tracer = SplitPathTracer(mi, dr, *build_scene(mi, 1000, "procedural"))
        assert [name(e) for e in tracer._emitter_list] == sorted(name(e) for e in tracer.scene.emitters())
        outs.append(render_inputs(tracer, cfg, cam, (0.0, 0.0), seed=3))
    assert len(tracer._emitter_list) >= 3  # a sky, a bulb and area lights to choose from
    for out in outs[1:]:
        for k, v in outs[0].items():
            np.testing.assert_array_equal(out[k], v, err_msg=k)


def test_scalar_fallback_matches_llvm(tmp_path):
    """Without LLVM the renderer runs on scalar_rgb: same scene, statistically same image."""
    common = ("--seed", "5", "--frames", "1", "--size", "16x9", "--spp", "64", "--camera", "static")
    s, _ = _render(tmp_path, "scalar", "--variant", "scalar_rgb", *common)
    v, _ = _render(tmp_path, "llvm", *common)
    a, b = open_sequence(s), open_sequence(v)
    assert json.loads((s / "sequence.json").read_text())["renderer"]["variant"] == "scalar_rgb"
    np.testing.assert_allclose(a.inputs(0)["albedo"], b.inputs(0)["albedo"], atol=1e-3)
    np.testing.assert_allclose(a.inputs(0)["normal"], b.inputs(0)["normal"], atol=2e-3)
    ca, cb = a.reference(0)["color"].mean((0, 1)), b.reference(0)["color"].mean((0, 1))
    np.testing.assert_allclose(ca, cb, rtol=0.03)


def test_dataset_grows_with_new_training_seeds_only():
    from jnds_deploy.render.dataset import dataset_specs

    base, grown = dataset_specs("train"), dataset_specs("train", 40)
    assert len(base) == 24 and len(grown) == 40 and grown[:24] == base
    val_seeds = {cfg.seed for _, cfg in dataset_specs("val")}
    assert not val_seeds & {cfg.seed for _, cfg in dataset_specs("train", 1000)}
    with pytest.raises(ValueError, match="train_sequences"):
        dataset_specs("train", 0)
    # the kinds rotate with the seed: every 8th a diffuse-only and a metal-only scene
    assert [rel for rel, _ in base[:8]] == [
        "train/procedural-static-1000",
        "train/procedural-dolly-1001",
        "train/procedural-orbit-1002",
        "train/diffuse-pan-1003",
        "train/procedural-cut-1004",
        "train/procedural-static-1005",
        "train/metal-dolly-1006",
        "train/procedural-orbit-1007",
    ]
    assert all(rel.split("/")[1].startswith(cfg.scene) for rel, cfg in base)
    moving = dataset_specs("train", 24, moving_sequences=3)
    assert moving[:24] == base and [(rel, cfg.scene) for rel, cfg in moving[24:]] == [
        ("train/moving-static-4000", "moving"),
        ("train/moving-dolly-4001", "moving"),
        ("train/moving-orbit-4002", "moving"),
    ]
    assert not {cfg.seed for _, cfg in moving} & val_seeds
    with pytest.raises(ValueError, match="moving_sequences"):
        dataset_specs("train", 24, "cycles", moving_sequences=1)


def test_dataset_jobs_render_what_one_process_renders(tmp_path, monkeypatch):
    """--jobs N renders in spawned processes; the sequences are the same bit for bit."""
    from jnds_deploy.render import RenderConfig, dataset

    specs = [
        (f"train/s{i}", RenderConfig(scene="procedural", seed=30 + i, camera="orbit", frames=2, size=(32, 18), spp=4))
        for i in range(2)
    ]
    monkeypatch.setattr(dataset, "dataset_specs", lambda split, n, engine="mitsuba", moving=0, mixed=0, lights=0: specs)
    one = dataset.render_dataset(tmp_path / "one", jobs=1)
    two = dataset.render_dataset(tmp_path / "two", jobs=2)
    assert [p.name for p, _ in one] == [p.name for p, _ in two] == ["s0", "s1"]
    assert_same_sequences(tmp_path / "one", tmp_path / "two", [rel for rel, _ in specs])
    assert dataset.render_dataset(tmp_path / "two", jobs=2) == []  # finished sequences are kept
    # without references (jnds dataset --no-reference): the same inputs, and no reference
    dataset.render_dataset(tmp_path / "bare", reference=False)
    assert_same_sequences(tmp_path / "one", tmp_path / "bare", [rel for rel, _ in specs], reference=False)
    assert not any(open_sequence(tmp_path / "bare" / rel).has_reference for rel, _ in specs)
    # cheap references (jnds dataset --reference-spp): the same inputs, references of 1 sample
    dataset.render_dataset(tmp_path / "cheap", reference_spp=1)
    assert_same_sequences(tmp_path / "one", tmp_path / "cheap", [rel for rel, _ in specs], reference=False)
    for rel, _ in specs:
        assert json.loads((tmp_path / "cheap" / rel / "render.json").read_text())["config"]["spp"] == 1
        one, cheap = open_sequence(tmp_path / "one" / rel), open_sequence(tmp_path / "cheap" / rel)
        assert not np.array_equal(one.reference(1)["color"], cheap.reference(1)["color"])


def test_the_test_split_is_apart_and_only_rendered_when_asked_for():
    from jnds_deploy.render.dataset import dataset_specs

    for engine in ("mitsuba", "cycles"):
        test = {cfg.seed for _, cfg in dataset_specs("test", engine=engine)}
        seen = {cfg.seed for _, cfg in dataset_specs("all", 1000, engine=engine)}
        assert len(test) == 6 and not test & seen
        assert all(rel.startswith("test/") for rel, _ in dataset_specs("test", engine=engine))
    assert not {cfg.seed for _, cfg in dataset_specs("test")} & {
        cfg.seed for _, cfg in dataset_specs("all", 1000, engine="cycles")
    }
