import json
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from jnds_deploy.errors import (
    ChannelError,
    ExrReadError,
    FrameCountError,
    ImageSizeError,
    SequenceFormatError,
)
from jnds_deploy.io import open_sequence, read_exr, validate

from .conftest import SAMPLE


def _rewrite_json(path, **changes):
    meta = json.loads((path / "sequence.json").read_text())
    meta.update(changes)
    (path / "sequence.json").write_text(json.dumps(meta))


def _rewrite_exr(path, drop=(), resize=None, dtype=None):
    chans = read_exr(path)
    chans = {k: v for k, v in chans.items() if k not in drop}
    if resize:
        chans = {k: np.zeros((resize[1], resize[0]), np.float32) for k in chans}
    if dtype:
        chans = {k: v.astype(dtype) for k, v in chans.items()}
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans).write(str(path))


def test_round_trip(make_sequence):
    path, ins, refs = make_sequence()
    seq = open_sequence(path)
    assert seq.native_size == (7, 5) and seq.target_size == (14, 10) and len(seq) == 3
    assert seq.frames[1].jitter == (0.25, -0.125) and seq.frames[2].camera_cut
    for i in range(3):
        got = seq.inputs(i)
        assert set(got) == set(ins[i])
        for k in ("diffuse", "specular", "motion", "depth"):  # stored as float32: exact
            np.testing.assert_array_equal(got[k], ins[i][k])
        for k in ("albedo", "normal", "roughness"):  # stored as half
            np.testing.assert_allclose(got[k], ins[i][k], rtol=1e-3, atol=1e-3)
        assert got["roughness"].shape == (5, 7, 1) and got["motion"].shape == (5, 7, 2)
        assert all(v.dtype == np.float32 for v in got.values())
        ref = seq.reference(i)
        np.testing.assert_allclose(ref["color"], refs[i]["color"], rtol=1e-3)
    assert validate(path).clean


def test_the_optional_denoising_albedo_round_trips_and_validates(make_sequence):
    """The OIDN baseline's guide albedo (``denoising_albedo``, a Cycles import's Denoising
    Albedo) is optional: written and read back where a frame has it, absent where not,
    and a NaN in it is reported by channel like any other."""
    from jnds_deploy.io import SequenceWriter

    path, ins, _ = make_sequence(frames=2, reference=False)
    seq = open_sequence(path)
    assert "denoising_albedo" not in seq.inputs(0)
    guide = np.random.default_rng(1).random((5, 7, 3)).astype(np.float32)
    SequenceWriter(path, (7, 5)).write_inputs(0, {**ins[0], "denoising_albedo": guide})
    np.testing.assert_allclose(open_sequence(path).inputs(0)["denoising_albedo"], guide, atol=1e-3)  # half
    guide[2, 3, 1] = np.nan
    SequenceWriter(path, (7, 5)).write_inputs(1, {**ins[1], "denoising_albedo": guide})
    report = validate(path)
    assert report.nonfinite["inputs"] == {"denoising_albedo.G": {1: 1}}


def test_reads_tiled_half_piz(make_sequence):
    path, ins, _ = make_sequence(frames=1, reference=False)
    chans = {k: v.astype(np.float16) for k, v in read_exr(path / "inputs/0000.exr").items()}
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 4
    OpenEXR.File({"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles}, chans).write(
        str(path / "inputs/0000.exr")
    )
    got = open_sequence(path).inputs(0)
    np.testing.assert_allclose(got["diffuse"], ins[0]["diffuse"], rtol=1e-3)


def test_frames_key_is_optional(make_sequence):
    path, _, _ = make_sequence()
    meta = json.loads((path / "sequence.json").read_text())
    del meta["frames"]
    meta["a_future_key"] = {"anything": 1}
    (path / "sequence.json").write_text(json.dumps(meta))
    seq = open_sequence(path)
    assert seq.frames[0].jitter == (0.0, 0.0) and not seq.frames[2].camera_cut


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"format": "jnds-sequence/2"}, "format is 'jnds-sequence/2'"),
        ({"native_size": [7]}, "'native_size' must be"),
        ({"native_size": [7, -5]}, "'native_size' must be"),
        ({"frame_count": 0}, "'frame_count' must be a positive integer"),
        ({"frames": [{"index": 0, "jitter": [0.7, 0.0]}] * 3}, r"frames\[0\].jitter"),
        ({"frames": [{"index": 0}]}, "'frames' must list 3 entries"),
    ],
)
def test_bad_sequence_json(make_sequence, changes, match):
    path, _, _ = make_sequence()
    _rewrite_json(path, **changes)
    with pytest.raises(SequenceFormatError, match=match) as err:
        open_sequence(path)
    assert err.value.path == path / "sequence.json"


def test_missing_or_broken_sequence_json(make_sequence):
    path, _, _ = make_sequence()
    (path / "sequence.json").write_text("{not json")
    with pytest.raises(SequenceFormatError, match="not valid JSON"):
        open_sequence(path)
    (path / "sequence.json").unlink()
    with pytest.raises(SequenceFormatError, match="missing sequence.json"):
        open_sequence(path)


def test_missing_frame(make_sequence):
    path, _, _ = make_sequence()
    (path / "inputs/0001.exr").unlink()
    with pytest.raises(FrameCountError, match=r"missing frame\(s\) 0001.exr"):
        open_sequence(path)


def test_extra_frame(make_sequence):
    path, _, _ = make_sequence()
    (path / "inputs/0003.exr").write_bytes((path / "inputs/0000.exr").read_bytes())
    with pytest.raises(FrameCountError, match=r"extra frame\(s\) 0003.exr"):
        open_sequence(path)


def test_missing_reference_frame(make_sequence):
    path, _, _ = make_sequence()
    (path / "reference/0002.exr").unlink()
    with pytest.raises(FrameCountError, match="0002.exr") as err:
        open_sequence(path)
    assert err.value.path == path / "reference"


def test_missing_channel(make_sequence):
    path, _, _ = make_sequence()
    _rewrite_exr(path / "inputs/0001.exr", drop=("normal.Y", "roughness"))
    seq = open_sequence(path)
    seq.inputs(0)
    with pytest.raises(ChannelError, match=r"0001.exr: missing channel\(s\) normal.Y, roughness"):
        seq.inputs(1)


def test_wrong_size(make_sequence):
    path, _, _ = make_sequence()
    _rewrite_exr(path / "reference/0000.exr", resize=(13, 10))
    with pytest.raises(ImageSizeError, match="is 13x10, expected 14x10") as err:
        open_sequence(path).reference(0)
    assert err.value.path.name == "0000.exr"


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_unreadable_exr(make_sequence, damage):
    path, _, _ = make_sequence()
    f = path / "inputs/0002.exr"
    data = f.read_bytes()
    f.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"this is not an EXR", "empty": b""}[damage])
    with pytest.raises(ExrReadError, match="0002.exr: unreadable or truncated"):
        open_sequence(path).inputs(2)


def test_wrong_channel_type(make_sequence):
    path, _, _ = make_sequence()
    _rewrite_exr(path / "inputs/0000.exr", dtype=np.uint32)
    with pytest.raises(ExrReadError, match="stored as uint32, expected half or float"):
        open_sequence(path).inputs(0)


def test_nonfinite_counted_per_channel(make_sequence):
    path, _, _ = make_sequence()
    f = path / "inputs/0001.exr"
    chans = read_exr(f)
    chans["specular.G"][0, :3] = np.nan
    chans["motion.X"][2, 2] = np.inf
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans).write(str(f))
    report = validate(path)
    assert not report.clean
    assert report.nonfinite["inputs"] == {"specular.G": {1: 3}, "motion.X": {1: 1}}
    assert "specular.G: 3 non-finite value(s) in 1 frame(s)" in report.summary()


def test_cli_reports_one_line_error(make_sequence):
    path, _, _ = make_sequence()
    (path / "inputs/0000.exr").write_bytes(b"junk")
    proc = subprocess.run([sys.executable, "-m", "jnds_deploy", "validate", str(path)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("jnds validate: error:")
    assert "0000.exr" in proc.stderr and "Traceback" not in proc.stderr


def test_sample_sequence_is_valid():
    report = validate(SAMPLE)
    assert report.clean and report.frame_count == 8
    seq = open_sequence(SAMPLE)
    assert seq.native_size == (160, 90) and seq.target_size == (320, 180)
    frame = seq.inputs(3)
    assert frame["albedo"].min() >= 0 and frame["albedo"].max() <= 1
    assert frame["diffuse"].min() >= 0 and frame["specular"].min() >= 0
    n = np.linalg.norm(frame["normal"], axis=-1)
    assert np.allclose(n[n > 0], 1.0, atol=2e-3)  # unit normals (half precision), 0 for background
