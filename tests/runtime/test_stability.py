"""Numerical stability and bad input: extreme values, broken motion, odd sizes, fp16
limits, fuzzed files and frames. Each case states its expectation. Long runs and
larger fuzzing budgets are in benchmarks/stability.py."""

import json

import numpy as np
import OpenEXR
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jnds_deploy.errors import ExrReadError, JndsError, SequenceError
from jnds_deploy.io import INPUT_LAYERS, exr_bytes, open_sequence, read_exr, read_exr_bytes
from jnds_deploy.layout import INPUT_CHANNELS, ROOT_FLOOR
from jnds_deploy.runtime.pipeline import Pipeline, PipelineConfig
from jnds_deploy.runtime.run import run_sequence

from ..conftest import SAMPLE, random_inputs

FUZZ = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module", params=["predicted", "fixed"])
def pipes(request):
    """Pipelines of a model predicting its upsample kernel, and of one with a fixed kernel
    (whose upsample filter is one fused pass into the output, ``filters.upsample_fixed_hwc``)."""
    a = str(request.getfixturevalue({"predicted": "tiny_artifacts", "fixed": "tiny_artifacts_fixed"}[request.param])[0])
    return {
        "float32": Pipeline(PipelineConfig(artifacts=a, precision="fp32")),
        "float16": Pipeline(PipelineConfig(artifacts=a, precision="fp32", filter_dtype="float16")),
    }


def _ok(out, shape=None):
    """The invariant of every case: finite, non-negative, the right size."""
    assert np.isfinite(out).all() and out.min() >= 0
    if shape:
        assert out.shape == shape


def _sample(i=0):
    return {k: v.copy() for k, v in open_sequence(SAMPLE).inputs(i).items()}


@pytest.mark.parametrize("case", ["tiny", "huge", "beyond_clamp", "log_uniform"])
def test_extreme_radiance(pipes, case):
    """Radiance from 1e-8 to 1e6 and beyond the clamp: output finite and non-negative;
    beyond 65535 the input is clamped, so 1e6 and 1e30 give the same output."""
    rng = np.random.default_rng(1)
    pipe = pipes["float32"]
    layers = _sample()
    shape = layers["diffuse"].shape
    value = {"tiny": 1e-8, "huge": 1e6, "beyond_clamp": 1e30}.get(case)
    for k in ("diffuse", "specular"):
        layers[k] = (
            np.full(shape, value, np.float32) if value else (10.0 ** rng.uniform(-8, 6, shape)).astype(np.float32)
        )
    out = pipe(layers, camera_cut=True).output
    _ok(out, (180, 320, 3))
    if case == "beyond_clamp":
        clamped = {
            **layers,
            "diffuse": np.full(shape, 65535, np.float32),
            "specular": np.full(shape, 65535, np.float32),
        }
        np.testing.assert_array_equal(out, pipe(clamped, camera_cut=True).output)


def test_zero_constant_and_black_albedo(pipes):
    """All-zero radiance gives zero (every filter is linear in radiance): exactly, or with
    the upsample filter interpolating roots, the root's floor (layout.ROOT_FLOOR) times the
    kernel's taps; a constant frame and black albedo give finite, non-negative output."""
    pipe = pipes["float32"]
    layers = _sample()
    zero = {**layers, "diffuse": np.zeros_like(layers["diffuse"]), "specular": np.zeros_like(layers["specular"])}
    floor = 0.0 if pipe.upsample_root == 1 else 9 * ROOT_FLOOR
    for i in range(3):  # with history too
        out = pipe(zero, camera_cut=i == 0).output
        assert out.max() <= floor
    const = {k: np.full_like(v, 0.5) for k, v in layers.items()}
    const["motion"][:] = 0
    for i in range(3):
        _ok(pipe(const, camera_cut=i == 0).output)
    black = {**layers, "albedo": np.zeros_like(layers["albedo"])}
    _ok(pipe(black, camera_cut=True).output)


@pytest.mark.parametrize("motion", ["huge", "offscreen", "nan", "disocclusion"])
def test_broken_motion_vectors(pipes, motion):
    """Motion of 1e9 px, pointing off screen, NaN, or random per pixel (every pixel
    disoccluded): history is resampled at the border or not at all; output finite."""
    pipe = pipes["float32"]
    pipe(_sample(0), camera_cut=True)
    layers = _sample(1)
    m = layers["motion"]
    rng = np.random.default_rng(2)
    m[:] = {"huge": 1e9, "offscreen": -500.0, "nan": np.nan}.get(motion, 0.0)
    if motion == "disocclusion":
        m[:] = rng.normal(scale=40, size=m.shape)
    frame = pipe(layers)
    _ok(frame.output, (180, 320, 3))
    if motion == "nan":
        assert frame.nonfinite == {"motion": m.size}


@pytest.mark.parametrize("w,h", [(1, 1), (7, 5), (33, 17), (1921, 1081)])
def test_odd_sizes(pipes, w, h):
    """Padded to the network's multiple and cropped back; two frames so history is used."""
    rng = np.random.default_rng(3)
    pipe = pipes["float32"]
    for i in range(2):
        layers = random_inputs(rng, w, h)
        out = pipe(layers, camera_cut=i == 0).output
        _ok(out, (2 * h, 2 * w, 3))


def test_fp16_filter_stage_does_not_overflow(pipes):
    """Radiance up to and beyond 65504 (the largest half): the float16 filter stage
    scales such frames by a power of two, filters, scales back. Without that, the
    specular input alone would be Inf in half precision. Output stays within 1% (mean)
    of the float32 filter stage."""
    layers = _sample(2)
    for peak in (6.0e4, 65535.0, 1e6):
        bright = {**layers, "specular": layers["specular"] * np.float32(peak / layers["specular"].max())}
        with np.errstate(over="ignore"):  # what half precision would hold
            naive = np.minimum(bright["specular"], 65535).astype(np.float16)
        assert np.isinf(naive).any() == (peak > 65504)
        f32 = pipes["float32"](bright, camera_cut=True).output
        f16 = pipes["float16"](bright, camera_cut=True).output
        _ok(f16)
        assert np.abs(f16 - f32).mean() < 0.01 * np.abs(f32).mean(), peak


@FUZZ
@given(data=st.data())
def test_any_finite_input_gives_finite_nonnegative_output(pipes, data):
    """The property: any finite float32 input, any size, output finite and >= 0."""
    pipe = pipes["float32"]
    h = data.draw(st.integers(1, 12), label="h")
    w = data.draw(st.integers(1, 12), label="w")
    elements = st.floats(width=32, allow_nan=False, allow_infinity=False)  # all finite float32
    layers = {
        n: data.draw(hnp.arrays(np.float32, (h, w, c), elements=elements), label=n) for n, c in INPUT_CHANNELS.items()
    }
    for cut in (True, False):  # the second frame warps the first one's history
        out = pipe(layers, camera_cut=cut).output
        _ok(out, (2 * h, 2 * w, 3))
        assert np.isfinite(pipe.history.frame).all()


@FUZZ
@given(cut=st.integers(0, 10_000), flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=8))
def test_fuzzed_exr_bytes_read_or_raise_exr_error(cut, flips):
    """Truncated and byte-flipped EXR files: read, or ExrReadError naming the file;
    never another exception (and never a crash of the OpenEXR library)."""
    rng = np.random.default_rng(0)
    layers = random_inputs(rng, 9, 7)
    data = bytearray(exr_bytes({k: layers[k] for k in INPUT_LAYERS}, INPUT_LAYERS))
    data = data[: cut % (len(data) + 1)]
    for pos, val in flips:
        if data:
            data[pos % len(data)] = val
    try:
        channels = read_exr_bytes(bytes(data), "fuzzed.exr")
    except ExrReadError as exc:
        assert "fuzzed.exr" in str(exc)
    else:
        assert all(c.dtype == np.float32 for c in channels.values())


@FUZZ
@given(
    key=st.sampled_from(["format", "native_size", "target_size", "frame_count", "frames", "scale"]),
    value=st.recursive(
        st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=True) | st.text(max_size=5),
        lambda kids: st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=5), kids, max_size=3),
        max_leaves=6,
    ),
)
def test_fuzzed_sequence_json_opens_or_raises_sequence_error(make_sequence, key, value):
    """Any JSON value for any key of sequence.json: the sequence opens, or a
    SequenceError names sequence.json; never another exception."""
    path, _, _ = make_sequence()
    meta = json.loads((path / "sequence.json").read_text())
    meta[key] = value
    (path / "sequence.json").write_text(json.dumps(meta))
    try:
        seq = open_sequence(path)
        seq.inputs(0)
    except SequenceError as exc:
        assert exc.path.name in ("sequence.json", "0000.exr", "inputs", "reference"), exc


@pytest.mark.parametrize("damage", ["truncate", "garbage", "missing_channel", "uint"])
def test_jnds_run_stops_at_a_bad_frame_keeping_what_it_wrote(tiny_artifacts, tmp_path, damage):
    """A broken frame mid-sequence: a clear error naming the file. A header that says so
    (not OpenEXR, a channel missing) stops the run before anything is written
    (``io.check_headers``); broken pixels behind a sound header stop it at the frame, and the
    frames written before it are complete and equal to a clean run's; no temporary files left."""
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(SAMPLE, seq)
    bad = seq / "inputs" / "0005.exr"
    data = bad.read_bytes()
    if damage == "truncate":
        bad.write_bytes(data[: len(data) // 3])
    elif damage == "garbage":
        bad.write_bytes(b"\x76\x2f\x31\x01" + b"\x00" * 200)  # EXR magic, then nothing sensible
    else:
        ch = read_exr(bad)
        if damage == "missing_channel":
            del ch["normal.Y"]
        else:
            ch["roughness"] = ch["roughness"].astype(np.uint32)
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, ch).write(str(bad))
    cfg = PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32")
    with pytest.raises(JndsError, match="0005.exr") as exc:
        run_sequence(cfg, seq, tmp_path / "out", progress=False, metrics=False)
    assert isinstance(exc.value, SequenceError)
    if damage in ("garbage", "missing_channel"):
        assert not (tmp_path / "out").exists()
        return
    run_sequence(cfg, SAMPLE, tmp_path / "clean", progress=False, metrics=False)
    written = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert written == [f"{i:04d}.exr" for i in range(5)], written
    for name in written:
        a, b = read_exr(tmp_path / "out" / name), read_exr(tmp_path / "clean" / name)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_history_rejection_restarts_only_runaway_tiles():
    """A history tile far brighter than the current frame restarts from it; a history
    in line with the current frame is left alone (bit for bit)."""
    from jnds_deploy.runtime.history import REJECT_TILE, reject_history

    rng = np.random.default_rng(4)
    h, w = 2 * REJECT_TILE, 3 * REJECT_TILE
    current = rng.exponential(size=(16, h, w)).astype(np.float32)
    history = current[:12] * rng.uniform(0.5, 2.0, size=(12, h, w)).astype(np.float32)
    kept = history.copy()
    assert reject_history(current, kept) == 0 and np.array_equal(kept, history)
    runaway = history.copy()
    runaway[3:6, REJECT_TILE:, :REJECT_TILE] *= 1e4  # specular, one tile
    assert reject_history(current, runaway) == 1
    tile = (slice(REJECT_TILE, None), slice(None, REJECT_TILE))
    np.testing.assert_array_equal(runaway[3:6][:, tile[0], tile[1]], current[3:6][:, tile[0], tile[1]])
    # only the specular history of that tile restarts; everything else is kept
    kept = np.ones(history.shape, bool)
    kept[3:6, REJECT_TILE:, :REJECT_TILE] = False
    np.testing.assert_array_equal(runaway[kept], history[kept])


def test_history_rejection_partial_tiles_use_their_own_pixels():
    """The last row and column of tiles are partial: their means are over the pixels they
    have, so a runaway 5-pixel strip at the bottom restarts, and only it (10x brighter: over
    the ~18-row areas the opencv area resize used before, it was diluted below the ratio)."""
    from jnds_deploy.runtime.history import REJECT_TILE, reject_history

    rng = np.random.default_rng(5)
    h, w = REJECT_TILE + 5, 2 * REJECT_TILE + 3
    current = rng.exponential(size=(13, h, w)).astype(np.float32)
    history = current[:12].copy()
    history[0:3, REJECT_TILE:, REJECT_TILE : 2 * REJECT_TILE] *= 10  # diffuse, the partial tile below
    assert reject_history(current, history) == 1
    np.testing.assert_array_equal(history, current[:12])
