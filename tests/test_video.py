"""Video input: frames decoded in order by OpenCV, timestamps from the container, estimate CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.errors import InputError, InputWarning
from ifmi.io.calib import write_calib
from ifmi.io.tum import read_tum
from ifmi.io.video import VideoFrames, is_video_path
from ifmi.geometry.rotations import geodesic_angle
from ifmi.synthetic import synthetic_sequence
from video_files import write_gray_video

SIZE = 160
FPS = 12.5
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=50.0)


def _write_video(path, images, *, fourcc="MJPG", fps=FPS):
    write_gray_video(path, images, fps=fps, fourcc=fourcc)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    root = tmp_path_factory.mktemp("video")
    sequence = synthetic_sequence(MODEL, 6, seed=4, max_step_rad=0.05, band_px=(16.0, 75.0))
    _write_video(root / "clip.avi", sequence.images)
    write_calib(root / "calib_results.txt", MODEL)
    return root, sequence


def test_frames_come_in_order_with_container_timestamps(video):
    root, sequence = video
    frames = VideoFrames(root / "clip.avi", size=MODEL.size)
    decoded = list(frames)
    assert len(decoded) == 6 and decoded[0].shape == MODEL.size and decoded[0].dtype == np.uint8
    assert frames.timestamps == pytest.approx(np.arange(6) / FPS, abs=1e-3)
    # MJPG is lossy: each frame is its source image up to compression noise, and not its neighbour.
    for k in range(6):
        errors = [np.abs(decoded[k].astype(float) - image.astype(float)).mean() for image in sequence.images]
        assert int(np.argmin(errors)) == k


def test_estimate_cli_reads_a_video(video, tmp_path):
    from ifmi.cli import main

    root, sequence = video
    out = tmp_path / "est.txt"
    code = main(["estimate", str(root / "clip.avi"), "--calib", str(root / "calib_results.txt"),
                 "--out", str(out), "--no-progress"])
    assert code == 0
    estimate = read_tum(out)
    assert estimate.timestamps == pytest.approx(np.arange(6) / FPS, abs=1e-3)
    # The run file names the video and the calibration it used, so the run can be repeated.
    run = json.loads(out.with_name("est.config.json").read_text())
    assert (run["video"], run["calib"], run["dataset"]) == (
        str((root / "clip.avi").resolve()), str((root / "calib_results.txt").resolve()), None)
    # Steps of 3.4 degrees through MJPG compression at 160 px; measured at most 0.13 degree.
    assert np.max(geodesic_angle(sequence.rotations, estimate.rotations)) < np.radians(0.4)


def test_video_errors_name_the_file(video, tmp_path, capsys):
    from ifmi.cli import main

    root, _ = video
    with pytest.raises(InputError, match="video file not found"):
        VideoFrames(tmp_path / "missing.mp4")
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(b"not a video at all")
    with pytest.raises(InputError, match="garbage.mp4"):
        list(VideoFrames(garbage))
    with pytest.raises(InputError, match="calibration names 100x100"):
        list(VideoFrames(root / "clip.avi", size=(100, 100)))
    code = main(["estimate", str(root / "clip.avi"), "--out", str(tmp_path / "e.txt"), "--no-progress"])
    assert code == 2 and "needs --calib" in capsys.readouterr().err
    assert is_video_path(root / "clip.avi") and not is_video_path(root)


def test_video_panorama_smaller_than_a_tile_names_the_calibration(video, tmp_path, capsys):
    from ifmi.cli import main

    root, _ = video
    out = tmp_path / "e.txt"
    code = main(["estimate", str(root / "clip.avi"), "--calib", str(root / "calib_results.txt"),
                 "--out", str(out), "--tile-size", "128", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and not out.exists()
    assert f"{root / 'calib_results.txt'}: the 160x160 px image gives a " in err
    assert "smaller than the 128 px tile; expected a panorama at least 128x128 px" in err


def _indices_of(decoded, images):
    """Index of the source image closest to each decoded frame (MJPG is lossy)."""
    return [int(np.argmin([np.abs(d.astype(float) - im.astype(float)).mean() for im in images]))
            for d in decoded]


@pytest.fixture(scope="module")
def shaded_clip(tmp_path_factory):
    """Nine frames; in the first, a dark object covers the outer part of the ring at almost every azimuth."""
    root = tmp_path_factory.mktemp("shaded")
    sequence = synthetic_sequence(MODEL, 9, seed=7, max_step_rad=0.04, band_px=BAND)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius = np.hypot(rows - MODEL.center[0], cols - MODEL.center[1])
    azimuth = np.arctan2(cols - MODEL.center[1], rows - MODEL.center[0])
    first = sequence.images[0].copy()
    first[(radius > 45.0) & (np.abs(azimuth) < np.radians(170))] = 2
    images = (first,) + sequence.images[1:]
    _write_video(root / "clip.avi", images)
    write_calib(root / "calib_results.txt", MODEL)
    return root, images


# Imaged band of the shaded clip's frames (sensor radius, pixels).
BAND = (16.0, 75.0)


def test_spread_frames_come_from_the_whole_clip(shaded_clip):
    root, images = shaded_clip
    video = VideoFrames(root / "clip.avi", size=MODEL.size)
    assert _indices_of(video.spread_frames(5), images) == [0, 2, 4, 6, 8]
    assert _indices_of(video.spread_frames(20), images) == list(range(9))
    # A container that declares no frame count: one decoding pass keeping at most 2 x 2 frames.
    video.frame_count = 0
    assert _indices_of(video.spread_frames(2), images) == [0, 8]
    assert _indices_of(video.spread_frames(3), images) == [0, 4, 8]
    assert video.timestamps == []
    with pytest.raises(ValueError, match="expected count >= 1, got 0"):
        video.spread_frames(0)


def test_spread_frames_of_a_broken_video_name_the_file(shaded_clip, tmp_path):
    root, _ = shaded_clip
    garbage = tmp_path / "garbage.avi"
    garbage.write_bytes(b"not a video at all")
    with pytest.raises(InputError, match="garbage.avi"):
        VideoFrames(garbage).spread_frames(5)
    with pytest.raises(InputError, match="calibration names 100x100"):
        VideoFrames(root / "clip.avi", size=(100, 100)).spread_frames(5)


def test_a_dark_first_frame_does_not_narrow_a_videos_band(shaded_clip, tmp_path):
    from ifmi.pipeline import EstimateConfig, estimate_video
    from ifmi.spectral.panorama import radius_band

    root, images = shaded_clip
    config = EstimateConfig()
    panorama = config.ifmi.panorama
    alone = radius_band(MODEL, images[0], config=panorama)
    clean = radius_band(MODEL, images[1], config=panorama, frames=images[2:])
    assert alone[1] < 46.0 and clean[1] > BAND[1] - 5.0  # the first frame alone would cut the band
    estimate = estimate_video(root / "clip.avi", root / "calib_results.txt", method="ifmi", config=config)
    band = (estimate.config.ifmi.panorama.radius_min_px, estimate.config.ifmi.panorama.radius_max_px)
    # Judged on frames decoded through MJPG: measured 0.1 and 0.3 px (about one ring step of the
    # band profile) from the band of the uncompressed frames.
    assert band == pytest.approx(clean, abs=1.0)
    assert all(r.success for r in estimate.frames)


def test_given_band_radii_decode_no_band_frames(shaded_clip, monkeypatch):
    from dataclasses import replace

    from ifmi.pipeline import EstimateConfig, estimate_video

    root, _ = shaded_clip

    def refuse(self, count):
        raise AssertionError("band frames decoded although both radii are given")

    monkeypatch.setattr(VideoFrames, "spread_frames", refuse)
    base = EstimateConfig()
    config = replace(base, ifmi=replace(base.ifmi, panorama=replace(base.ifmi.panorama, radius_min_px=22.0,
                                                                    radius_max_px=73.0)))
    estimate = estimate_video(root / "clip.avi", root / "calib_results.txt", method="ifmi", config=config)
    panorama = estimate.config.ifmi.panorama
    assert (panorama.radius_min_px, panorama.radius_max_px) == (22.0, 73.0)


def _write_gray16_video(path, images):
    """``images`` ((H, W) uint16) as a lossless 16-bit gray FFV1 video; skip when OpenCV cannot."""
    import cv2

    height, width = images[0].shape
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), FPS, (width, height),
                             [cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U, cv2.VIDEOWRITER_PROP_IS_COLOR, 0])
    if not writer.isOpened():
        pytest.skip("this OpenCV cannot write 16-bit FFV1 video")
    for image in images:
        writer.write(image)
    writer.release()


@pytest.mark.parametrize("bits", [12, 16])
def test_a_16_bit_gray_video_is_read_at_its_recorded_depth(video, tmp_path, bits):
    # 12-bit samples stored unscaled in a 16-bit video read as their high byte, 16 gray levels, and
    # every frame after the first failed; now they read as 16-bit images do, with one warning.
    root, sequence = video
    images = [image.astype(np.uint16) << (bits - 8) | np.uint16(2 ** (bits - 8) - 1) for image in sequence.images]
    path = tmp_path / "clip.mkv"
    _write_gray16_video(path, images)
    if bits < 16:
        with pytest.warns(InputWarning, match=f"clip.mkv: 16-bit frames whose values stay below {2 ** bits} "
                                              f"are read as {bits}-bit data"):
            decoded = list(VideoFrames(path, size=MODEL.size))
    else:
        decoded = list(VideoFrames(path, size=MODEL.size))
    assert len(decoded) == len(images) and all(d.dtype == np.uint8 for d in decoded)
    for frame, image in zip(decoded, sequence.images):
        assert np.array_equal(frame, image)


def test_frame_times_that_do_not_increase_are_restamped_with_a_warning(video, monkeypatch):
    # A clip whose times restart (two recordings joined) gave a trajectory with repeated and falling
    # timestamps, exit 0: evaluate refused it, and other tools would associate it wrongly.
    import cv2

    import ifmi.io.video as video_module

    root, _ = video
    times = iter([0.0, 80.0, 160.0, 80.0, 160.0, 400.0])
    plain_get = video_module._Capture.get
    monkeypatch.setattr(video_module._Capture, "get", lambda self, prop: next(times)
                        if prop == cv2.CAP_PROP_POS_MSEC else plain_get(self, prop))
    frames = VideoFrames(root / "clip.avi", size=MODEL.size)
    with pytest.warns(InputWarning, match=r"clip.avi: 2 frames \(the first: frame 3\) had a presentation time "
                                          r"not after the previous frame's .* stamped one frame interval after it"):
        assert len(list(frames)) == 6
    assert frames.timestamps == pytest.approx([0.0, 0.08, 0.16, 0.24, 0.32, 0.4])
