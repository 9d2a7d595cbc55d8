"""Video input that is damaged, truncated or rotated: flagged, warned of or refused, never silently wrong.

Every video is written here with ``cv2.VideoWriter`` (MJPG in AVI, mp4v in
MP4) and then damaged byte by byte: an AVI frame is a ``00dc`` chunk (4-byte
id, 4-byte little-endian size, JPEG data); an MP4's display rotation is the
matrix of its ``tkhd`` box.
"""

from __future__ import annotations

import struct
import warnings

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io.calib import write_calib
from ifmi.io.tum import read_tum
from ifmi.io.video import VideoFrames
from ifmi.synthetic import synthetic_sequence
from video_files import write_gray_video

SIZE = 160
FPS = 12.5
FRAMES = 6
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=50.0)
# Header of an AVI chunk: 4-byte id and 4-byte size.
CHUNK_HEADER = 8
# Fixed-point 1.0 of an MP4 matrix's a, b, c, d (16.16) and w (2.30) entries.
ONE_16, ONE_30 = 1 << 16, 1 << 30
# Offset of the matrix in a version-0 and a version-1 tkhd box, from the box type.
TKHD_MATRIX = {0: 44, 1: 56}
# What a short AVI is told about its times.
UNTIMED = ("an AVI stores no frame times: if a frame was lost before the end, the frames after it are "
           "stamped early")
# Offset of dwStart in an AVI strh chunk, from the chunk id (id, size, type, handler, flags,
# priority, language, initial frames, scale, rate).
STRH_START = 36


def _write(path, images, *, fourcc="MJPG"):
    write_gray_video(path, images, fps=FPS, fourcc=fourcc)
    return path.read_bytes()


def _frame_chunks(data: bytes) -> list[tuple[int, int]]:
    """(offset of the chunk id, size of the JPEG data) of each video frame of an MJPG AVI."""
    chunks, position = [], data.index(b"movi") + 4
    while (found := data.find(b"00dc", position)) >= 0 and data[position:position + 4] != b"idx1":
        size = struct.unpack("<I", data[found + 4:found + CHUNK_HEADER])[0]
        chunks.append((found, size))
        position = found + CHUNK_HEADER + size + (size & 1)
    return chunks


def _zeroed(data: bytes, start: int, stop: int) -> bytes:
    return data[:start] + bytes(stop - start) + data[stop:]


def _sources(items, images):
    """Index of the source image closest to each decoded frame (MJPG is lossy), or the flag's reason."""
    return [item.reason if isinstance(item, MissingFrame) else
            int(np.argmin([np.abs(item.astype(float) - image.astype(float)).mean() for image in images]))
            for item in items]


def _read(path, **kwargs):
    """All items of a VideoFrames, the reader, and the InputWarnings given on reading."""
    frames = VideoFrames(path, size=MODEL.size, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        items = list(frames)
    return items, frames, [str(w.message) for w in caught if issubclass(w.category, InputWarning)]


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("integrity")
    sequence = synthetic_sequence(MODEL, FRAMES, seed=4, max_step_rad=0.05, band_px=(16.0, 75.0))
    data = _write(root / "clip.avi", sequence.images)
    write_calib(root / "calib_results.txt", MODEL)
    return root, sequence.images, data, _frame_chunks(data)


def test_the_chunk_parser_finds_every_frame(clip):
    _, _, data, chunks = clip
    assert len(chunks) == FRAMES and all(data[offset + CHUNK_HEADER:offset + CHUNK_HEADER + 2] == b"\xff\xd8"
                                         for offset, _ in chunks)


def test_a_damaged_frame_is_flagged_and_the_others_keep_their_times(clip, tmp_path, capfd):
    _, images, data, chunks = clip
    offset, size = chunks[2]
    path = tmp_path / "damaged.avi"
    path.write_bytes(_zeroed(data, offset + CHUNK_HEADER + size // 2, offset + CHUNK_HEADER + size))
    items, frames, warned = _read(path)
    found = _sources(items, images)
    assert found[:2] + found[3:] == [0, 1, 3, 4, 5] and not warned
    assert found[2].startswith("damaged.avi frame 2 at 0.160 s: the decoder reported damage (")
    assert frames.timestamps == pytest.approx(np.arange(FRAMES) / FPS)
    assert capfd.readouterr().err == ""  # FFmpeg's "[mjpeg @ 0x...] overread" stays off the terminal


def test_a_frame_the_decoder_rejects_is_a_gap_in_the_times(clip, tmp_path, capfd):
    _, images, data, chunks = clip
    offset, size = chunks[2]
    path = tmp_path / "rejected.avi"
    path.write_bytes(_zeroed(data, offset + CHUNK_HEADER, offset + CHUNK_HEADER + size))
    items, frames, warned = _read(path)
    assert _sources(items, images) == [0, 1, 3, 4, 5]  # decoding goes on after the rejected frame
    assert frames.timestamps == pytest.approx(np.array([0, 1, 3, 4, 5]) / FPS)
    assert len(warned) == 1 and warned[0].startswith(f"{path}: skipped 1 frame the decoder rejected (")
    assert warned[0].endswith("; estimated from the 5 frames decoded")
    assert capfd.readouterr().err == ""


def test_a_frame_lost_before_decoding_is_warned_of(clip, tmp_path):
    _, images, data, chunks = clip
    offset, _ = chunks[3]
    path = tmp_path / "lost.avi"
    path.write_bytes(_zeroed(data, offset, offset + CHUNK_HEADER))  # the demuxer skips the frame
    items, _, warned = _read(path)
    assert _sources(items, images) == [0, 1, 2, 4, 5]
    assert warned == [f"{path}: only 5 of the 6 frames the container declares were found (truncated or "
                      f"damaged file); {UNTIMED}; estimated from the 5 frames decoded"]


def test_a_half_written_last_frame_is_flagged(clip, tmp_path):
    _, images, data, chunks = clip
    offset, size = chunks[-1]
    path = tmp_path / "cut.avi"
    path.write_bytes(data[:offset + CHUNK_HEADER + size // 2])
    items, _, warned = _read(path)
    found = _sources(items, images)
    assert found[:-1] == [0, 1, 2, 3, 4] and not warned
    assert found[-1].startswith("cut.avi frame 5 at 0.400 s: the decoder reported damage (")


def test_a_truncated_video_says_how_many_frames_it_lacks(clip, tmp_path):
    _, images, data, chunks = clip
    offset, _ = chunks[3]
    path = tmp_path / "half.avi"
    path.write_bytes(data[:offset])
    items, _, warned = _read(path)
    assert _sources(items, images) == [0, 1, 2]
    assert warned == [f"{path}: only 3 of the 6 frames the container declares were found (truncated or "
                      f"damaged file); {UNTIMED}; estimated from the 3 frames decoded"]


def test_a_truncated_video_ending_in_a_damaged_frame_is_not_said_to_shift_times(clip, tmp_path):
    _, images, data, chunks = clip
    offset, size = chunks[3]
    path = tmp_path / "half.avi"
    path.write_bytes(data[:offset + CHUNK_HEADER + size // 2])
    items, _, warned = _read(path)
    assert _sources(items, images)[:3] == [0, 1, 2] and isinstance(items[3], MissingFrame)
    assert warned == [f"{path}: only 4 of the 6 frames the container declares were found (truncated or "
                      f"damaged file); estimated from the 4 frames decoded"]


def test_damaged_frames_do_not_decide_the_band(clip, tmp_path):
    _, images, data, chunks = clip
    offset, size = chunks[2]
    path = tmp_path / "damaged.avi"
    path.write_bytes(_zeroed(data, offset + CHUNK_HEADER + size // 2, offset + CHUNK_HEADER + size))
    video = VideoFrames(path, size=MODEL.size)
    assert _sources(video.spread_frames(FRAMES), images) == [0, 1, 3, 4, 5]
    video.frame_count = 0  # one decoding pass instead of seeks
    assert _sources(video.spread_frames(FRAMES), images) == [0, 1, 3, 4, 5]


def test_timestamps_count_from_the_first_frame(clip, tmp_path):
    _, _, data, _ = clip
    strh = data.index(b"strh")
    path = tmp_path / "late.avi"
    # The stream starts 125 frames (10 s) into the file's time line.
    path.write_bytes(data[:strh + STRH_START] + struct.pack("<I", 125) + data[strh + STRH_START + 4:])
    capture = cv2.VideoCapture(str(path))
    capture.grab()
    assert capture.get(cv2.CAP_PROP_POS_MSEC) == pytest.approx(10000.0)  # OpenCV's own time of frame 0
    capture.release()
    _, frames, _ = _read(path)
    assert frames.timestamps == pytest.approx(np.arange(FRAMES) / FPS)


def test_ffmpeg_lines_stay_off_the_terminal_and_errors_keep_one_line(clip, tmp_path, capfd):
    from ifmi.cli import main

    root, images, data, chunks = clip
    mp4 = _write(tmp_path / "whole.mp4", list(images), fourcc="mp4v")
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(mp4[:len(mp4) // 2])  # the moov box (the index) is at the end
    with pytest.raises(InputError, match=r"cut.mp4: not a video OpenCV can read "
                                         r"\(FFmpeg: moov atom not found\)"):
        VideoFrames(cut)
    assert capfd.readouterr().err == ""
    # A damaged frame 2 and a frame 3 the demuxer loses: one warning line, frame 2 flagged.
    (offset2, size2), (offset3, _) = chunks[2], chunks[3]
    damaged = _zeroed(_zeroed(data, offset2 + CHUNK_HEADER + size2 // 2, offset2 + CHUNK_HEADER + size2),
                      offset3, offset3 + CHUNK_HEADER)
    path = tmp_path / "damaged.avi"
    path.write_bytes(damaged)
    out = tmp_path / "est.txt"
    code = main(["estimate", str(path), "--calib", str(root / "calib_results.txt"), "--out", str(out),
                 "--no-progress"])
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 0 and len(err) == 1
    assert err[0].startswith(f"ifmi estimate: warning: {path}: only 5 of the 6")
    assert "frames after it (probably those after the damaged frame 2 at 0.160 s) are stamped early" in err[0]
    assert read_tum(out).timestamps == pytest.approx(np.arange(5) / FPS)
    rows = (tmp_path / "est.frames.csv").read_text().splitlines()
    assert ",false,image: damaged.avi frame 2 at 0.160 s: the decoder reported damage (" in rows[3]


def _rotated_mp4(path, images, matrix) -> bool:
    """Write ``images`` as an mp4v MP4 whose track asks for the display ``matrix``; False if
    this OpenCV does not read the rotation back."""
    data = bytearray(_write(path, images, fourcc="mp4v"))
    box = data.index(b"tkhd")
    start = box + TKHD_MATRIX[data[box + 4]]
    data[start:start + 36] = struct.pack(">9i", *matrix)
    path.write_bytes(bytes(data))
    capture = cv2.VideoCapture(str(path))
    rotation = capture.get(cv2.CAP_PROP_ORIENTATION_META)
    capture.release()
    return rotation != 0


# Display matrices (a, b, u, c, d, v, x, y, w) of a half turn and of a quarter turn.
HALF_TURN = (-ONE_16, 0, 0, 0, -ONE_16, 0, 0, 0, ONE_30)
QUARTER_TURN = (0, ONE_16, 0, -ONE_16, 0, 0, 0, 0, ONE_30)


def test_rotation_metadata_is_not_applied(clip, tmp_path):
    _, images, _, _ = clip
    path = tmp_path / "upside_down.mp4"
    if not _rotated_mp4(path, list(images), HALF_TURN):
        pytest.skip("this OpenCV does not read MP4 rotation metadata")
    items, frames, _ = _read(path)
    # mp4v at 160 px: measured at most 2.5 gray levels from its source; turned by 180 degrees, 29 to 31.
    errors = [np.abs(item.astype(float) - image.astype(float)).mean() for item, image in zip(items, images)]
    assert len(items) == FRAMES and max(errors) < 8.0
    assert frames.rotation == 180.0


def test_a_quarter_turn_is_named_when_the_calibration_has_the_turned_size(tmp_path, rng):
    images = [cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 2) for _ in range(3)]
    path = tmp_path / "upright.mp4"
    if not _rotated_mp4(path, images, QUARTER_TURN):
        pytest.skip("this OpenCV does not read MP4 rotation metadata")
    with pytest.raises(InputError, match=r"frame 0 is 120x160 \(height x width\), but the calibration "
                                         r"names 160x120 \(the video's rotation metadata of 90 degrees is "
                                         r"not applied"):
        list(VideoFrames(path, size=(160, 120)))


class _Wrapped:
    """A cv2.VideoCapture with some behaviour changed by a subclass."""

    real = cv2.VideoCapture

    def __init__(self, *args):
        self._capture = _Wrapped.real(*args)

    def __getattr__(self, name):
        return getattr(self._capture, name)


def test_rotation_that_cannot_be_turned_off_is_an_error(clip, tmp_path, monkeypatch):
    _, images, _, _ = clip

    class StuckRotation(_Wrapped):
        def set(self, prop, value):
            return False if prop == cv2.CAP_PROP_ORIENTATION_AUTO else self._capture.set(prop, value)

        def get(self, prop):
            return 1.0 if prop == cv2.CAP_PROP_ORIENTATION_AUTO else self._capture.get(prop)

    path = tmp_path / "upside_down.mp4"
    if not _rotated_mp4(path, list(images), HALF_TURN):
        pytest.skip("this OpenCV does not read MP4 rotation metadata")
    monkeypatch.setattr(cv2, "VideoCapture", StuckRotation)
    with pytest.raises(InputError, match=r"upside_down.mp4: the video asks to be shown rotated by 180 "
                                         r"degrees, and this OpenCV cannot turn that rotation off"):
        VideoFrames(path)


def test_a_later_frame_of_another_size_is_flagged(clip, monkeypatch):
    root, images, _, _ = clip

    class Shrinking(_Wrapped):
        """A back end that gives frame 3 at half size (OpenCV's FFmpeg scales it back)."""

        retrieved = 0

        def retrieve(self):
            ok, frame = self._capture.retrieve()
            Shrinking.retrieved += 1
            return ok, (cv2.resize(frame, (SIZE // 2, SIZE // 2)) if Shrinking.retrieved == 4 else frame)

    monkeypatch.setattr(cv2, "VideoCapture", Shrinking)
    items, _, _ = _read(root / "clip.avi")
    assert _sources(items, images) == [0, 1, 2, "clip.avi: frame 3 is 80x80 (height x width), but the "
                                                "calibration names 160x160", 4, 5]


def test_a_damaged_first_frame_is_a_one_line_error(clip, tmp_path):
    from ifmi.pipeline import estimate_video

    root, _, data, chunks = clip
    offset, size = chunks[0]
    path = tmp_path / "bad_start.avi"
    path.write_bytes(_zeroed(data, offset + CHUNK_HEADER + size // 2, offset + CHUNK_HEADER + size))
    with pytest.raises(InputError, match=r"bad_start.avi: first frame unusable: bad_start.avi frame 0 at "
                                         r"0.000 s: the decoder reported damage \(") as raised:
        estimate_video(path, root / "calib_results.txt", method="ifmi")
    assert "\n" not in str(raised.value)
