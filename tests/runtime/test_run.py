"""``jnds run``'s outputs besides the frames: the contact sheet a person looks at."""

import importlib.util

import cv2
import numpy as np
import pytest

from jnds_deploy import contact_sheet
from jnds_deploy.io import read_exr
from jnds_deploy.metrics import to_ldr
from jnds_deploy.runtime.pipeline import PipelineConfig
from jnds_deploy.runtime.run import run_sequence

from ..conftest import SAMPLE


def test_run_writes_a_contact_sheet_of_first_middle_last_frames(tiny_artifacts, tmp_path):
    report = run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"), SAMPLE, tmp_path, progress=False
    )
    sheet = cv2.imread(report["contact_sheet"])
    # input, (OIDN,) JNDS, reference, changed pixels
    columns = 5 if importlib.util.find_spec("pyoidn") else 4
    w, h = 320, 180
    assert sheet.shape == (3 * (h + contact_sheet.LABEL_H), columns * (w + contact_sheet.GAP) - contact_sheet.GAP, 3)
    # the JNDS column of the last row is frame 7's output through the display mapping
    out = read_exr(tmp_path / "0007.exr")
    rgb = np.stack([out[f"color.{c}"] for c in "RGB"], -1)
    x0 = (columns - 3) * (w + contact_sheet.GAP)
    tile = sheet[-h:, x0 : x0 + w, ::-1]
    np.testing.assert_allclose(tile, to_ldr(rgb) * 255, atol=1.0)
    # the scores against the reference: the output's, OIDN's where installed, and both
    # over the changed pixels (none on frame 0, some on the orbit's later frames)
    m = report["metrics"]
    assert 0 < m["changed_fraction"] < 0.5 and np.isfinite(m["changed_psnr"])
    if importlib.util.find_spec("pyoidn"):
        assert report["baseline"]["changed_fraction"] == m["changed_fraction"]


def test_sheet_frames():
    assert contact_sheet.sheet_frames(8) == [0, 4, 7]
    assert contact_sheet.sheet_frames(1) == [0]
    assert contact_sheet.sheet_frames(0) == []


def test_output_formats_store_the_frames_as_computed(tiny_artifacts, tmp_path):
    """float: the pipeline's float32 frame bit for bit, uncompressed; half: the same frame
    rounded to half, PIZ; an unknown format is refused before anything is written."""
    import OpenEXR
    import pytest

    from jnds_deploy.runtime.pipeline import Pipeline
    from jnds_deploy.runtime.run import iter_run

    cfg = PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32")
    frames = {}
    for fmt in ("float", "half"):
        report = run_sequence(cfg, SAMPLE, tmp_path / fmt, progress=False, metrics=False, output_format=fmt)
        assert report["output_format"] == fmt
        with OpenEXR.File(
            str(tmp_path / fmt / "0003.exr"), separate_channels=True
        ) as f:  # read inside: closing clears them
            compression = f.header()["compression"]
            frames[fmt] = np.stack([f.channels()[f"color.{c}"].pixels for c in "RGB"], -1)
        assert compression == {"float": OpenEXR.NO_COMPRESSION, "half": OpenEXR.PIZ_COMPRESSION}[fmt]
    assert frames["float"].dtype == np.float32 and frames["half"].dtype == np.float16
    np.testing.assert_array_equal(frames["half"], frames["float"].astype(np.float16))
    with pytest.raises(ValueError, match="output format 'png'"):
        next(iter_run(Pipeline(cfg), SAMPLE, tmp_path / "png", output_format="png"))
    assert not (tmp_path / "png").exists()


def test_run_yields_each_frame_once_its_file_is_complete(tiny_artifacts, tmp_path):
    """iter_run reads ahead and writes behind (threads): still every index in order, each
    yielded only when its frame is on disk, and the frames those of a run frame by frame."""
    from jnds_deploy.io import open_sequence
    from jnds_deploy.runtime.pipeline import Pipeline
    from jnds_deploy.runtime.run import iter_run

    cfg = PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32")
    seen = []
    for item in iter_run(Pipeline(cfg), SAMPLE, tmp_path, metrics=False):
        if isinstance(item, dict):
            break
        seen.append((item, read_exr(tmp_path / f"{item:04d}.exr")))  # there, and whole, when yielded
    seq = open_sequence(SAMPLE)
    assert [i for i, _ in seen] == list(range(len(seq)))
    pipe = Pipeline(cfg)
    for i, stored in seen:
        expected = pipe(seq.inputs(i), seq.frames[i].camera_cut).output
        np.testing.assert_array_equal(np.stack([stored[f"color.{c}"] for c in "RGB"], -1), expected)


@pytest.mark.parametrize("damage", ["not_exr", "channel", "size"])
def test_a_bad_frame_fails_before_anything_is_written(tiny_artifacts, tmp_path, damage):
    """A PNG renamed to .exr, a frame missing a channel, a frame of another size: frame 3
    of 8 is reported, naming the file, and no output (not even the directory) exists."""
    import shutil

    from jnds_deploy.errors import SequenceError
    from jnds_deploy.io import INPUT_LAYERS, read_exr, write_exr

    seq = tmp_path / "seq"
    shutil.copytree(SAMPLE, seq)
    bad = seq / "inputs" / "0003.exr"
    if damage == "not_exr":
        cv2.imwrite(str(bad.with_suffix(".png")), np.zeros((4, 4, 3), np.uint8))
        bad.with_suffix(".png").replace(bad)
    else:
        raw = read_exr(bad)
        layers = {n: np.stack([raw[f"{n}.{c}" if c else n] for c in sfx], -1) for n, sfx in INPUT_LAYERS.items()}
        if damage == "channel":
            layers.pop("roughness")
        else:
            layers = {n: v[:-2] for n, v in layers.items()}
        write_exr(bad, layers, {n: INPUT_LAYERS[n] for n in layers})
    out = tmp_path / "out"
    with pytest.raises(SequenceError, match="0003.exr"):
        run_sequence(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"), seq, out, progress=False)
    assert not out.exists()


def test_video_and_png_frames(tiny_artifacts, tmp_path):
    """--video: an MP4 of every output frame that decodes back to the --png frames it was
    made from (H.264, lossy: a few levels of 255 on average), in order."""
    pytest.importorskip("imageio_ffmpeg")
    from jnds_deploy.video import read_mp4

    report = run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"),
        SAMPLE,
        tmp_path,
        progress=False,
        video=True,
        png=tmp_path / "png",
    )
    frames = read_mp4(report["video"])
    pngs = [cv2.imread(str(tmp_path / "png" / f"{i:04d}.png"))[..., ::-1].astype(np.float32) for i in range(8)]
    assert len(frames) == 8 and all(f.shape == (180, 320, 3) for f in frames)
    for i, f in enumerate(frames):
        diffs = [np.abs(f - p).mean() for p in pngs]
        assert diffs[i] < 8 and int(np.argmin(diffs)) == i, diffs  # a random model: grainy, costly to encode
    # the PNG is the output through the display mapping
    out = read_exr(tmp_path / "0005.exr")
    rgb = np.stack([out[f"color.{c}"] for c in "RGB"], -1)
    np.testing.assert_allclose(pngs[5], to_ldr(rgb) * 255, atol=1.0)


def test_a_sequence_without_references_gets_a_contact_sheet(tiny_artifacts, tmp_path):
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(SAMPLE, seq, ignore=shutil.ignore_patterns("reference"))
    report = run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"), seq, tmp_path / "out", progress=False
    )
    assert "metrics" not in report
    sheet = cv2.imread(report["contact_sheet"])
    columns = 3 if importlib.util.find_spec("pyoidn") else 2  # input, (OIDN,) JNDS
    assert sheet.shape[1] == columns * (320 + contact_sheet.GAP) - contact_sheet.GAP
