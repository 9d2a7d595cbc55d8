"""Dataset folders: frames named by index, skipped entries, damaged image files."""

from __future__ import annotations

import os
import shutil
import struct
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main
from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io.calib import write_calib
from ifmi.io.dataset import frame_index, read_dataset
from ifmi.io.images import image_file_problem, read_image
from ifmi.io.results import read_frames_csv
from ifmi.io.tum import read_tum
from ifmi.geometry.rotations import geodesic_angle

MODEL = paracatadioptric_model((64, 64), horizon_radius_px=20.0)


def _png(seed: int = 0, shape=(64, 64)) -> bytes:
    image = (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def _folder(tmp_path, names) -> object:
    root = tmp_path / "ds"
    (root / "images").mkdir(parents=True)
    write_calib(root / "calib_results.txt", MODEL)
    for k, name in enumerate(names):
        (root / "images" / name).write_bytes(_png(k))
    return root


@pytest.mark.parametrize(("name", "index"), [
    ("000123.png", 123), ("0.png", 0), ("10.JPG", 10), ("frame_0007.jpeg", 7),
    ("._000003.png", None), (".000003.png", None), ("Thumbs.db", None), ("000003.txt", None),
    ("preview.png", None), ("000003 copy.png", None), ("cam0_000003.png", None),
])
def test_frame_index_of_file_names(name, index):
    assert frame_index(name) == index


def test_unpadded_names_are_read_in_natural_order(tmp_path):
    root = _folder(tmp_path, [f"{k}.png" for k in (0, 1, 2, 10, 11, 9)])
    ds = read_dataset(root)
    assert ds.frame_indices == (0, 1, 2, 9, 10, 11)
    assert [p.name for p in ds.image_paths] == ["0.png", "1.png", "2.png", "9.png", "10.png", "11.png"]


def test_two_files_with_one_index_are_an_error(tmp_path):
    root = _folder(tmp_path, ["000004.png", "000005.png"])
    (root / "images" / "000005.jpg").write_bytes((root / "images" / "000005.png").read_bytes())
    with pytest.raises(InputError, match=r"frame 5 has two files, 000005.jpg and 000005.png; keep one"):
        read_dataset(root)
    (root / "images" / "000005.jpg").unlink()
    (root / "images" / "5.png").write_bytes(_png(9))
    with pytest.raises(InputError, match="frame 5 has two files"):
        read_dataset(root)


def test_entries_that_are_not_frames_are_skipped_with_one_warning(tmp_path):
    root = _folder(tmp_path, ["000000.png", "000001.png", "._000001.png", ".DS_Store", "Thumbs.db"])
    (root / "images" / "sub").mkdir()
    with pytest.warns(InputWarning) as record:
        ds = read_dataset(root)
    assert ds.frame_indices == (0, 1)
    assert len(record) == 1
    message = str(record[0].message)
    assert "skipped 4 entries that are not frame images" in message
    for name in ("._000001.png", ".DS_Store", "Thumbs.db", "sub"):
        assert name in message
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_dataset(_folder(tmp_path / "clean", ["000000.png"]))


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_calibration_that_is_a_fifo_is_one_line_error(tmp_path, capsys):
    # Reading it waited for a writer forever.
    root = _folder(tmp_path, ["000000.png", "000001.png"])
    (root / "calib_results.txt").unlink()
    os.mkfifo(root / "calib_results.txt")
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == (f"ifmi estimate: error: {root / 'calib_results.txt'}: is a "
                                               "FIFO, device or socket, not a calibration file; expected a "
                                               "regular file")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_meta_json_that_is_a_fifo_is_ignored(tmp_path):
    # Optional provenance; reading it waited for a writer forever.
    root = _folder(tmp_path, ["000000.png", "000001.png"])
    os.mkfifo(root / "meta.json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_dataset(root).frame_indices == (0, 1)


def test_frame_numbers_one_timestamp_cannot_tell_apart_are_refused(tmp_path, capsys):
    # Nanosecond stamps 1 ns apart: the estimate was written with equal timestamps, exit 0.
    root = _folder(tmp_path, [f"17000000000000000{k:02d}.png" for k in range(2)])
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"ifmi estimate: error: {root / 'images'}: frames 1700000000000000000 (1700000000000000000.png) and "
        "1700000000000000001 (1700000000000000001.png) get one timestamp, 1700000000000000000, in a "
        "trajectory file (64-bit floats hold integers this large only to a multiple of 256); expected frame "
        "numbers that differ by more")
    assert not (tmp_path / "e.txt").exists()


def test_dataset_marked_incomplete_warns_with_the_count(tmp_path):
    root = _folder(tmp_path, ["000000.png", "000001.png"])
    meta = '{"frames": 5, "images": {"000000.png": "x", "000001.png": "y"}, "complete": %s}'
    (root / "meta.json").write_text(meta % "false")
    with pytest.warns(InputWarning, match=r"meta.json: the dataset is marked incomplete \(2 of 5 frames written\)"):
        read_dataset(root)
    # Complete, or provenance that says nothing (the last, nested too deeply, was a RecursionError).
    for text in (meta % "true", "[1, 2]", "{broken", "[" * 100_000 + "]" * 100_000):
        (root / "meta.json").write_text(text)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            read_dataset(root)


def test_cli_prints_the_warning_as_one_line(tmp_path, capsys):
    root = _folder(tmp_path, ["000000.png", "Thumbs.db"])
    (root / "images" / "000000.png").write_bytes(b"junk")
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith("ifmi estimate: warning: ") and "Thumbs.db" in lines[0]
    assert lines[1].startswith("ifmi estimate: error: ") and len(lines) == 2


def test_cli_prints_the_mirror_band_fallback_as_one_line(tmp_path, capfd):
    """An all-black dataset: the project's own UserWarning is one ``ifmi estimate: warning:`` line."""
    root = tmp_path / "black"
    (root / "images").mkdir(parents=True)
    write_calib(root / "calib_results.txt", MODEL)
    for k in range(2):
        (root / "images" / f"{k:06d}.png").write_bytes(cv2.imencode(".png", np.zeros((64, 64), np.uint8))[1])
    main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--no-progress"])
    lines = capfd.readouterr().err.strip().splitlines()
    band = [line for line in lines if "no clear mirror band" in line]
    assert len(band) == 1 and band[0].startswith("ifmi estimate: warning: no clear mirror band in the image")
    assert not any("UserWarning" in line or "radius_band(" in line for line in lines)


def _warn_inside_own_package(code: str) -> None:
    """Run ``code`` as if it were a module of the ifmi package (its frames name a file there)."""
    import ifmi

    exec(compile(code, str(Path(ifmi.__file__).parent / "example_module.py"), "exec"), {})


def test_warning_lines_of_own_and_foreign_user_warnings(capsys):
    from ifmi.runtime.warning_lines import input_warnings_as_lines

    # pytest.warns records what reaches Python's default display.
    with pytest.warns(UserWarning) as default_display, input_warnings_as_lines(lambda: "ifmi test"):
        _warn_inside_own_package("import warnings\nwarnings.warn('fell back to the default')")
        warnings.warn("a library's own warning")  # raised from this test file: not the project's
    assert capsys.readouterr().err == "ifmi test: warning: fell back to the default\n"
    assert [str(w.message) for w in default_display] == ["a library's own warning"]


def test_warning_line_during_a_progress_bar_starts_a_line_of_its_own(capsys):
    import sys

    from tqdm import tqdm

    from ifmi.runtime.warning_lines import input_warnings_as_lines

    with input_warnings_as_lines(lambda: "ifmi estimate"), tqdm(total=3, file=sys.stderr, desc="estimate") as bar:
        bar.update(1)
        bar.refresh()
        warnings.warn("clip.avi: only 7 of the 13 frames could be read", InputWarning)
        bar.update(2)
    err = capsys.readouterr().err
    line = "ifmi estimate: warning: clip.avi: only 7 of the 13 frames could be read\n"
    before = err[:err.index(line)]
    # Everything the bar drew before it on that line is wiped by a carriage return and blanks.
    assert before.endswith("\r") and before[before.rstrip("\r").rfind("\r") + 1:].strip(" \r") == ""


def test_warning_lines_of_numpy_runtime_warnings_name_the_project_line(capsys):
    from ifmi.runtime.warning_lines import input_warnings_as_lines

    with input_warnings_as_lines(lambda: "omnisim warp"):
        with np.errstate(invalid="warn"):
            for _ in range(3):  # shown once
                _warn_inside_own_package("import numpy as np\n\nnp.zeros(2) / np.zeros(2)")
            np.mean(np.zeros(0))  # only NumPy's own line and this test on the stack
    err = capsys.readouterr().err.splitlines()
    prefix = "omnisim warp: warning: "
    assert err[0] == prefix + "invalid value encountered in divide (at ifmi/example_module.py:3)"
    assert err[1].startswith(prefix + "Mean of empty slice (at ")
    assert len(err) == 3 and err[2].startswith(prefix + "invalid value encountered in scalar divide (at ")


def test_no_frame_images_names_the_folder(tmp_path):
    root = _folder(tmp_path, ["preview.png"])
    with pytest.raises(InputError, match=r"images: no frame images in folder .*; found only preview.png$"):
        read_dataset(root)


def test_missing_folder_and_a_file_instead_of_a_folder(tmp_path, capsys):
    assert main(["estimate", str(tmp_path / "nonexist"), "--out", str(tmp_path / "e.txt")]) == 2
    assert capsys.readouterr().err.strip() == f"ifmi estimate: error: {tmp_path / 'nonexist'}: dataset folder not found"
    (tmp_path / "file").write_text("x")
    assert main(["estimate", str(tmp_path / "file"), "--out", str(tmp_path / "e.txt")]) == 2
    assert "file: neither a dataset folder nor a video" in capsys.readouterr().err
    # A video type OpenCV may read but the estimator does not take is named with the ones it does.
    (tmp_path / "clip.mpg").write_bytes(b"\x00\x00\x01\xba")
    assert main(["estimate", str(tmp_path / "clip.mpg"), "--calib", str(tmp_path / "c.txt"),
                 "--out", str(tmp_path / "e.txt")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"ifmi estimate: error: {tmp_path / 'clip.mpg'}: neither a dataset folder nor a video nor a ROS bag "
        "(expected a folder with calib_results.txt or camera.yaml and images/, a video file ending in .mp4, "
        ".avi, .mov, .mkv, .m4v, .webm, or a bag ending in .bag, .mcap, .db3 or a ROS 2 bag folder, with --calib)")
    # read_dataset itself, which no video reaches, keeps its own words.
    with pytest.raises(InputError, match="not a folder"):
        read_dataset(tmp_path / "file")


# --- damaged image files ---------------------------------------------------------

def _with_chunk_crc_fixed(data: bytes, offset: int) -> bytes:
    """``data`` with the CRC of the chunk holding byte ``offset`` recomputed."""
    pos = 8
    while True:
        length, _ = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + 12 + length
        if pos <= offset < end:
            crc = struct.pack(">I", zlib.crc32(data[pos + 4:pos + 8 + length]))
            return data[:pos + 8 + length] + crc + data[end:]
        pos = end


def _damaged_pngs() -> dict:
    good = _png(3)
    flipped = bytearray(good)
    flipped[60] ^= 0xFF
    bad_filter = bytearray(good)
    # An IDAT whose inflated rows start with filter type 7: valid zlib, valid CRC.
    raw = b"".join(b"\x07" + bytes(64) for _ in range(64))
    idat = zlib.compress(raw)
    header = good[:33]
    chunk = struct.pack(">I", len(idat)) + b"IDAT" + idat + struct.pack(">I", zlib.crc32(b"IDAT" + idat))
    bad_filter = header + chunk + b"\x00\x00\x00\x00IEND\xaeB`\x82"
    return {
        "truncated": (good[:len(good) // 2], "truncated PNG"),
        "crc": (bytes(flipped), "corrupt PNG (checksum error in its IDAT chunk)"),
        "zlib": (_with_chunk_crc_fixed(bytes(flipped), 60), "corrupt PNG (image data: "),
        "filter": (bad_filter, "corrupt PNG (invalid row filter)"),
        "jpeg": (cv2.imencode(".jpg", np.zeros((64, 64), np.uint8))[1].tobytes()[:300],
                 "truncated JPEG (no end-of-image marker)"),
        "text": (b"not an image", "not a readable PNG/JPEG image"),
    }


@pytest.mark.parametrize("kind", list(_damaged_pngs()))
def test_damaged_files_are_one_input_error_without_decoder_output(kind, tmp_path, capfd):
    data, message = _damaged_pngs()[kind]
    path = tmp_path / "000001.png"
    path.write_bytes(data)
    assert image_file_problem(data).startswith(message)
    with pytest.raises(InputError, match="000001.png: " + message.replace("(", r"\(").replace(")", r"\)")):
        read_image(path)
    captured = capfd.readouterr()
    assert "libpng" not in captured.err and captured.err == ""


def test_sound_files_pass_the_check():
    for image in (np.zeros((5, 7), np.uint8), np.full((9, 3, 3), 200, np.uint8)):
        for ext in (".png", ".jpg"):
            data = cv2.imencode(ext, image)[1].tobytes()
            assert image_file_problem(data) is None


def test_bad_middle_frame_is_flagged_with_its_file_name(tmp_path, capfd):
    root = _folder(tmp_path, [f"{k:06d}.png" for k in range(3)])
    data = (root / "images" / "000001.png").read_bytes()
    (root / "images" / "000001.png").write_bytes(data[:len(data) // 2])
    frames = list(read_dataset(root).iter_images(skip_unreadable=True))
    assert isinstance(frames[1], MissingFrame)
    assert frames[1].reason.startswith("000001.png: truncated PNG")
    assert capfd.readouterr().err == ""


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_frame_linked_to_a_fifo_is_flagged_not_waited_for(tmp_path):
    # The read waited for a writer forever.
    root = _folder(tmp_path, [f"{k:06d}.png" for k in range(3)])
    os.mkfifo(tmp_path / "fifo")
    (root / "images" / "000001.png").unlink()
    (root / "images" / "000001.png").symlink_to(tmp_path / "fifo")
    frames = list(read_dataset(root).iter_images(skip_unreadable=True))
    assert isinstance(frames[1], MissingFrame)
    assert frames[1].reason == ("000001.png: is a FIFO, device or socket, not an image file; expected a "
                                "regular file")


# --- estimates of datasets with gaps ------------------------------------------------

skimage = pytest.importorskip("skimage")


@pytest.fixture(scope="module")
def sequence_dataset(tmp_path_factory):
    from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset

    model = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(127.2, 129.7))
    seq = synthetic_sequence(model, 8, seed=7, band_px=(30.0, 125.0), noise_std=1.0)
    return write_synthetic_dataset(tmp_path_factory.mktemp("gap") / "syn", seq), seq


@pytest.mark.slow
def test_missing_frame_leaves_a_gap_and_evaluates_right(sequence_dataset, tmp_path, capsys):
    """Deleting 000005.png: the estimate has no line 5, and lines 6, 7 keep their timestamps."""
    root, seq = sequence_dataset
    copy = tmp_path / "gap"
    shutil.copytree(root, copy)
    (copy / "images" / "000005.png").unlink()
    out = tmp_path / "gap.txt"
    assert main(["estimate", str(copy), "--out", str(out), "--width", "512", "--no-progress"]) == 0
    est = read_tum(out)
    np.testing.assert_array_equal(est.timestamps, [0, 1, 2, 3, 4, 6, 7])
    frames = read_frames_csv(tmp_path / "gap.frames.csv")
    np.testing.assert_array_equal(frames.frame, [0, 1, 2, 3, 4, 6, 7])
    np.testing.assert_array_equal(frames.reference_frame, [0, 0, 1, 2, 3, 4, 6])
    # Each pose matches the ground truth of its own index (a shift would be off by a whole step).
    truth = seq.rotations[[0, 1, 2, 3, 4, 6, 7]]
    step = geodesic_angle(seq.rotations[5], seq.rotations[6])
    assert geodesic_angle(truth, est.rotations).max() < 0.1 * step
    capsys.readouterr()
    assert main(["evaluate", "--gt", str(copy / "groundtruth.txt"), "--est", str(out)]) == 0
    report = capsys.readouterr().out
    assert "frames 7/8 associated" in report


def test_reference_frames_across_two_gaps_keep_their_timestamps():
    """frames.csv names reference frames by index: with frames 3 and 5 missing,
    the last poses (rows 4 and 5, frames 6 and 7) still find their references."""
    from ifmi.evaluation.trajectory_files import _reference_timestamps
    from ifmi.io.results import EstimateSideFiles, FrameTable
    from ifmi.geometry.trajectory import Trajectory

    frame = np.array([0, 1, 2, 4, 6, 7], dtype=float)
    reference = np.array([0, 0, 1, 2, 4, 6], dtype=float)
    table = FrameTable({"frame": frame, "reference_frame": reference,
                        "success": np.ones(6, bool), "seconds": np.zeros(6)})
    est = Trajectory(frame, np.zeros((6, 3)), np.repeat(np.eye(3)[None], 6, axis=0))
    side = EstimateSideFiles(table, None, Path("x.frames.csv"), Path("x.config.json"))
    got = _reference_timestamps(est, side)
    np.testing.assert_array_equal(got, [np.nan, 0, 1, 2, 4, 6])


def test_frame_number_beyond_64_bits_is_refused_naming_the_file(tmp_path):
    stamps = ["1403636579763555584.png", "1403636579813555456.png"]  # EuRoC nanosecond names fit
    assert read_dataset(_folder(tmp_path / "ok", stamps)).frame_indices[0] == 1403636579763555584
    root = _folder(tmp_path / "bad", ["000000.png", "99999999999999999999999999.png"])
    with pytest.raises(InputError, match=r"99999999999999999999999999.png: frame number 99999999999999999999999999 "
                                         r"is larger than 9223372036854775807"):
        read_dataset(root)
