"""Outputs of ``ifmi estimate``: one set or none, never a dataset file, links, devices, write failures."""

from __future__ import annotations

import errno
import json
import os
import shutil

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main
from ifmi.errors import OutputError
from ifmi.io import atomic
from ifmi.io.atomic import atomic_write_bytes, atomic_write_files

pytest.importorskip("skimage")
from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset  # noqa: E402

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(127.2, 129.7))
FAST = ["--width", "512", "--tile-size", "64", "--no-progress"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    seq = synthetic_sequence(MODEL, 4, seed=3, band_px=(30.0, 125.0), noise_std=1.0)
    root = write_synthetic_dataset(tmp_path_factory.mktemp("data") / "ds", seq)
    (root / "meta.json").write_text('{"scene_name": "synthetic"}\n')
    return root


def _snapshot(folder) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _old_set(folder) -> dict:
    """An earlier estimate's three files (which a new run may replace)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = {"e.txt": b"# ifmi estimate, method ifmi\n0 0 0 0 0 0 0 1\n",
             "e.frames.csv": b"frame,reference_frame,success,reason\n0,0,true,\n",
             "e.config.json": b'{"method": "ifmi", "config": {}, "versions": {}}\n'}
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return _snapshot(folder)


def _failing_on_call(real, n: int, error: int):
    calls = {"n": 0}

    def fake(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == n:
            raise OSError(error, os.strerror(error))
        return real(*args, **kwargs)
    return fake


# --- the set writer ---------------------------------------------------------------

@pytest.mark.parametrize(("patched", "error"), [("fsync", errno.ENOSPC), ("replace", errno.EIO)])
def test_a_failed_set_leaves_the_old_set_byte_identical(tmp_path, monkeypatch, patched, error):
    before = _old_set(tmp_path / "run")
    # The 2nd file's data cannot be synced (full disk), or the 2nd rename fails after the 1st.
    monkeypatch.setattr(atomic.os, patched, _failing_on_call(getattr(os, patched), 2, error))
    new = {tmp_path / "run" / n: b"new " + n.encode() for n in ("e.config.json", "e.frames.csv", "e.txt")}
    with pytest.raises(OutputError, match=f"cannot write .*e.frames.csv: {os.strerror(error)}"):
        atomic_write_files(new)
    assert _snapshot(tmp_path / "run") == before
    assert sorted(os.listdir(tmp_path / "run")) == sorted(before)


def test_a_failed_first_set_leaves_nothing(tmp_path, monkeypatch):
    """Not even the folders the write made."""
    monkeypatch.setattr(atomic.os, "replace", _failing_on_call(os.replace, 3, errno.ENOSPC))
    with pytest.raises(OutputError):
        atomic_write_files({tmp_path / "new" / "deeper" / n: b"x" for n in ("a", "b", "c")})
    assert os.listdir(tmp_path) == []


def test_a_symlink_is_written_through(tmp_path):
    (tmp_path / "real.txt").write_bytes(b"old")
    (tmp_path / "link.txt").symlink_to("real.txt")
    atomic_write_bytes(tmp_path / "link.txt", b"new")
    assert (tmp_path / "link.txt").is_symlink() and os.readlink(tmp_path / "link.txt") == "real.txt"
    assert (tmp_path / "real.txt").read_bytes() == b"new"
    (tmp_path / "dangling.txt").symlink_to("sub/made.txt")
    atomic_write_bytes(tmp_path / "dangling.txt", b"made")
    assert (tmp_path / "sub" / "made.txt").read_bytes() == b"made"


def test_device_nodes_fifos_and_folders_are_never_replaced(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "dir").mkdir()
    (tmp_path / "to_null").symlink_to(os.devnull)
    for target, kind in ((os.devnull, "device"), (tmp_path / "fifo", "device, FIFO"),
                         (tmp_path / "to_null", "device"), (tmp_path / "dir", "a folder")):
        with pytest.raises(OutputError, match=f"is .*{kind}.*; refusing to replace it"):
            atomic_write_bytes(target, b"x")
    assert (tmp_path / "to_null").is_symlink() and os.path.exists(os.devnull)


def test_a_file_in_the_way_is_named(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError) as info:
        atomic_write_bytes(tmp_path / "file" / "deeper" / "e.txt", b"x")
    assert str(info.value) == (f"cannot write {tmp_path / 'file' / 'deeper' / 'e.txt'}: Not a directory: "
                               f"a file is in the way ({tmp_path / 'file'})")


# --- ifmi estimate ------------------------------------------------------------------

@pytest.mark.parametrize("name", ["groundtruth.txt", "calib_results.txt", "meta.json", "images/000001.png",
                                  "images/new.txt"])
def test_estimate_refuses_to_replace_a_dataset_file(dataset, name, capsys):
    before = (dataset / name).read_bytes() if (dataset / name).exists() else None
    assert main(["estimate", str(dataset), "--out", str(dataset / name), *FAST]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ifmi estimate: error: cannot write {dataset / name}: would ")
    assert "of the input dataset" in err and "\n" not in err
    assert ((dataset / name).read_bytes() if before is not None else None) == before
    if before is None:
        assert not (dataset / name).exists()


def test_estimate_refuses_links_to_dataset_files(dataset, tmp_path, capsys):
    (tmp_path / "gt.txt").symlink_to(dataset / "groundtruth.txt")
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "gt.txt"), *FAST]) == 1
    assert "would replace groundtruth.txt" in capsys.readouterr().err
    # A side file that is a hard link of the calibration.
    os.link(dataset / "calib_results.txt", tmp_path / "e.config.json")
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), *FAST]) == 1
    assert "would replace calib_results.txt" in capsys.readouterr().err
    assert not (tmp_path / "e.txt").exists()


def test_estimate_may_write_beside_the_dataset_files(dataset, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    assert main(["estimate", str(copy), "--out", str(copy / "estimate.txt"), *FAST]) == 0
    assert (copy / "estimate.frames.csv").is_file() and (copy / "estimate.config.json").is_file()


def test_estimate_to_a_device_or_below_a_file(dataset, tmp_path, capsys):
    assert main(["estimate", str(dataset), "--out", os.devnull, *FAST]) == 1
    assert "refusing to replace it" in capsys.readouterr().err
    (tmp_path / "f").write_text("x")
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "f" / "e.txt"), *FAST]) == 1
    err = capsys.readouterr().err
    assert "Not a directory: a file is in the way" in err and "File exists" not in err


def test_estimate_through_a_symlink_keeps_the_link(dataset, tmp_path):
    (tmp_path / "target.txt").write_text("old\n")
    (tmp_path / "link.txt").symlink_to("target.txt")
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "link.txt"), "--force", *FAST]) == 0
    assert (tmp_path / "link.txt").is_symlink()
    assert (tmp_path / "target.txt").read_text().startswith("# ifmi estimate")


# Calls of tempfile.mkstemp: three write probes before the estimate, three more when writing,
# then the three temporaries; the 8th is the second temporary.
_WRITE_TIME_MKSTEMP = 8


@pytest.mark.parametrize(("where", "call", "error"), [
    ("mkstemp", 2, errno.EACCES), ("mkstemp", 2, errno.EROFS),
    ("mkstemp", _WRITE_TIME_MKSTEMP, errno.EACCES), ("mkstemp", _WRITE_TIME_MKSTEMP, errno.EROFS),
    ("fsync", 2, errno.ENOSPC), ("replace", 2, errno.ENOSPC),
])
def test_estimate_write_failures_are_one_line_and_exit_1(dataset, tmp_path, monkeypatch, capsys, where,
                                                         call, error):
    """Permission denied, read-only file system, full disk: the old outputs stay as they were."""
    before = _old_set(tmp_path / "run")
    module = atomic.tempfile if where == "mkstemp" else atomic.os
    real = getattr(module, where)
    monkeypatch.setattr(module, where, _failing_on_call(real, call, error))
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "run" / "e.txt"), *FAST]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"ifmi estimate: error: cannot write {tmp_path / 'run'}/e.")
    assert err[0].endswith(os.strerror(error)) and ".tmp" not in err[0]
    assert _snapshot(tmp_path / "run") == before
    assert sorted(os.listdir(tmp_path / "run")) == sorted(before)


def test_more_than_half_failed_frames_exit_3(dataset, tmp_path, capsys):
    copy = tmp_path / "bad"
    shutil.copytree(dataset, copy)
    for k in (1, 2, 3):
        path = copy / "images" / f"{k:06d}.png"
        path.write_bytes(path.read_bytes()[:1000])
    out = tmp_path / "bad.txt"
    assert main(["estimate", str(copy), "--out", str(out), *FAST]) == 3
    err = capsys.readouterr().err
    assert "3 of 4 frames failed (more than half; see bad.frames.csv); exit status 3" in err
    assert out.is_file() and (tmp_path / "bad.frames.csv").is_file()
    # Two of four failed is not more than half.
    good = copy / "images" / "000003.png"
    shutil.copy(dataset / "images" / "000003.png", good)
    (copy / "images" / "000001.png").unlink()
    shutil.copy(dataset / "images" / "000001.png", copy / "images" / "000001.png")
    assert main(["estimate", str(copy), "--out", str(out), *FAST]) == 0


# --- configuration files --------------------------------------------------------------

@pytest.mark.parametrize(("text", "message"), [
    ("[]", "expected a JSON object {...} at the top level, got an array"),
    ('"x"', "expected a JSON object {...} at the top level, got a string"),
    ('{"relative_pose": {"seed": 1.5}}', "relative_pose.seed: expected an integer, got number 1.5"),
    ('{"ifmi": {"tiling": [1, 2]}}', "ifmi.tiling: expected an object with keys tile_size, overlap, got list [1, 2]"),
    ('{"ifmi": {"panorama": {"width": "abc"}}}', "ifmi.panorama.width: expected an integer or null, got string 'abc'"),
    ('{"keyframe": {"enabled": "yes"}}', "keyframe.enabled: expected true or false, got string 'yes'"),
    ('{"method": "ifmi", "config": []}', "config: expected an object, got list"),
    ('{"ifmi": {"tiling": {"overlap": 1.5}}}', r"ifmi.tiling: overlap must be in [0, 1), got 1.5"),
])
def test_bad_configuration_files_are_one_line(dataset, tmp_path, capsys, text, message):
    config = tmp_path / "c.json"
    config.write_text(text)
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ifmi estimate: error: {config}: ") and message in err and "\n" not in err
    assert not (tmp_path / "e.txt").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["--width", "1000000000"], "ifmi.panorama.width: expected at most "),
    (["--height", "100000"], "ifmi.panorama.height: expected at most "),
    (["--radius-max", "5000"], "ifmi.panorama.radius_max_px: expected a radius under 18"),
    (["--tile-size", "100000"], "calib_results.txt: the 256x256 px image gives a "),
])
def test_sizes_beyond_what_the_images_give_are_refused(dataset, tmp_path, capsys, args, message):
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), "--no-progress", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ifmi estimate: error: ") and message in err and "\n" not in err


def test_the_width_bound_is_four_circumferences_of_the_band(dataset, tmp_path, capsys):
    from ifmi.spectral.panorama import radius_band

    limit = int(4 * 2 * np.pi * radius_band(MODEL)[1])
    main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), "--width", str(limit + 1)])
    assert f"expected at most {limit} px for this camera" in capsys.readouterr().err


def test_a_library_bug_is_not_reported_as_bad_input(dataset, tmp_path, monkeypatch):
    """A ValueError inside the estimator is a bug: it propagates instead of becoming exit 2."""
    import ifmi.pipeline

    def broken(*args, **kwargs):
        raise ValueError("internal inconsistency")
    monkeypatch.setattr(ifmi.pipeline, "track_sequence", broken)
    with pytest.raises(ValueError, match="internal inconsistency"):
        main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), *FAST])


def test_tiles_are_checked_against_the_band_the_first_frame_shows(dataset, tmp_path, capsys):
    """A dark border shrinks the panorama below the calibration's; the check uses the frame."""
    import cv2

    copy = tmp_path / "ring"
    shutil.copytree(dataset, copy)
    rows, cols = np.mgrid[:256, :256]
    radius = np.hypot(rows - MODEL.center[0], cols - MODEL.center[1])
    for path in (copy / "images").glob("*.png"):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        image[(radius < 60) | (radius > 100)] = 0
        cv2.imwrite(str(path), image)
    args = ["estimate", str(copy), "--out", str(tmp_path / "e.txt"), "--width", "512", "--no-progress"]
    assert main([*args, "--tile-size", "80"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ifmi estimate: error: {copy / 'calib_results.txt'}: the 256x256 px image gives a ")
    assert "smaller than the 80 px tile" in err and "\n" not in err


@pytest.mark.parametrize(("features", "message"), [
    ({"n_features": 10 ** 9}, "features.n_features: expected at most 65536 (the image's pixel count), got 1000000000"),
    ({"orb_levels": 10 ** 5}, "features.orb_levels: expected at most 31 (levels down to one pixel"),
    ({"akaze_octaves": 40}, "features.akaze_octaves: expected at most 8 (octaves down to one pixel), got 40"),
    ({"akaze_min_keypoints": 10 ** 11},
     "features.akaze_min_keypoints: expected at most 65536 (the image's pixel count), got 100000000000"),
    ({"orb_patch_size": 10 ** 6}, "features.orb_patch_size: expected at most 256"),
    ({"radius_band": [10, 10 ** 6]}, "features.radius_band: expected a radius under 18"),
])
def test_feature_sizes_beyond_the_image_are_refused(dataset, tmp_path, capsys, features, message):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"features": features}))
    assert main(["estimate", str(dataset), "--method", "orb", "--config", str(config),
                 "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ifmi estimate: error: ") and message in err and "\n" not in err


def test_a_feature_option_out_of_its_range_is_a_one_line_error(dataset, tmp_path, capsys):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"features": {"akaze_octave_layers": 10 ** 6}}))
    assert main(["estimate", str(dataset), "--method", "akaze", "--config", str(config),
                 "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
    assert capsys.readouterr().err == (
        f"ifmi estimate: error: {config}: invalid configuration: features: akaze_octave_layers must be at "
        f"most 32 (scale steps of 2^(1/32) per sublevel), got 1000000\n")
    assert not (tmp_path / "e.txt").exists()


def test_an_unwritable_output_folder_fails_before_the_estimate(dataset, tmp_path, monkeypatch, capsys):
    import ifmi.cli.estimate

    def not_called(*args, **kwargs):
        raise AssertionError("the estimate ran although its outputs cannot be written")
    monkeypatch.setattr(ifmi.cli.estimate, "estimate_run", not_called)
    monkeypatch.setattr(atomic.tempfile, "mkstemp", _failing_on_call(atomic.tempfile.mkstemp, 1, errno.EROFS))
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "e.txt"), *FAST]) == 1
    assert capsys.readouterr().err.strip() == (f"ifmi estimate: error: cannot write {tmp_path / 'e.txt'}: "
                                               f"{os.strerror(errno.EROFS)}")
    assert os.listdir(tmp_path) == []


def test_probe_of_a_folder_still_to_be_made(tmp_path, monkeypatch):
    from ifmi.io.atomic import probe_writable

    assert probe_writable(tmp_path / "a" / "b" / "e.txt") == tmp_path / "a" / "b" / "e.txt"
    assert os.listdir(tmp_path) == []
    monkeypatch.setattr(atomic.os, "access", lambda path, mode: False)
    with pytest.raises(OutputError, match=rf"Permission denied \(cannot create folders in {tmp_path}\)"):
        probe_writable(tmp_path / "a" / "b" / "e.txt")


@pytest.mark.parametrize("patched", ["fsync", "replace"])
def test_an_interrupt_during_a_set_also_keeps_the_old_set(tmp_path, monkeypatch, patched):
    before = _old_set(tmp_path / "run")
    real, calls = getattr(os, patched), {"n": 0}

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(atomic.os, patched, interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_files({tmp_path / "run" / n: b"new" for n in ("e.config.json", "e.frames.csv", "e.txt")})
    assert _snapshot(tmp_path / "run") == before
    assert sorted(os.listdir(tmp_path / "run")) == sorted(before)


def test_estimate_of_a_video_refuses_to_replace_the_video_or_its_calibration(tmp_path, capsys):
    import cv2

    from ifmi.io.calib import write_calib

    writer = cv2.VideoWriter(str(tmp_path / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (256, 256))
    if not writer.isOpened():
        pytest.skip("this OpenCV cannot write MJPG video")
    for _ in range(2):
        writer.write(np.zeros((256, 256, 3), np.uint8))
    writer.release()
    write_calib(tmp_path / "calib.txt", MODEL)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for out in ("calib.txt", "clip.avi"):
        assert main(["estimate", str(tmp_path / "clip.avi"), "--calib", str(tmp_path / "calib.txt"),
                     "--out", str(tmp_path / out), *FAST]) == 1
        assert "would replace the input file" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_limits_for_a_camera_model_other_than_ocamcalib():
    from ifmi.geometry.camera_models import DoubleSphereModel
    from ifmi.spectral.config_limits import check_config_for_model
    from ifmi.errors import InputError
    from ifmi.pipeline import EstimateConfig

    model = DoubleSphereModel(xi=-0.2, alpha=0.59, focal=(156.5, 157.0), principal_point=(187.75, 119.75),
                              size=(240, 376))
    check_config_for_model(EstimateConfig(), model)
    limit = int(4 * 2 * np.pi * 0.5 * np.hypot(240, 376))
    for data, message in (({"ifmi": {"panorama": {"radius_max_px": 100.0}}},
                           "ifmi.panorama.radius_max_px: applies to OCamCalib models only; this camera is a "
                           "DoubleSphereModel"),
                          ({"ifmi": {"panorama": {"width": limit + 1}}},
                           f"ifmi.panorama.width: expected at most {limit} px for this camera")):
        with pytest.raises(InputError) as info:
            check_config_for_model(EstimateConfig.from_dict(data), model)
        assert str(info.value).startswith(message)


def test_failure_reason_naming_a_file_with_a_byte_that_is_not_utf8_is_written(dataset, tmp_path, capsys):
    # The frame's reason names the image, whose lone surrogate UTF-8 cannot hold: every frame was
    # estimated, then writing frames.csv raised UnicodeEncodeError and nothing was written.
    root = tmp_path / "ds"
    shutil.copytree(dataset, root)
    images = sorted((root / "images").iterdir())
    for image in images:
        image.rename(image.with_name(os.fsdecode(b"f\xff") + image.name))
    damaged = root / "images" / (os.fsdecode(b"f\xff") + images[2].name)
    damaged.write_bytes(damaged.read_bytes()[:300])
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), *FAST]) == 0
    reasons = (tmp_path / "e.frames.csv").read_text(encoding="utf-8")
    assert f"image: f\\udcff{images[2].name}: truncated PNG" in reasons


@pytest.mark.parametrize("name, text", [("e.txt", "my own notes\n"), ("e.frames.csv", "my own notes\n"),
                                        ("e.config.json", "my own notes\n"),
                                        # JSON nested too deeply to decode (was a RecursionError)
                                        ("e.config.json", "[" * 100_000 + "]" * 100_000)])
def test_estimate_refuses_to_replace_a_file_no_estimate_wrote(dataset, tmp_path, capsys, name, text):
    """The user's own trajectory or notes at one of the three paths stay; --force replaces them."""
    (tmp_path / name).write_text(text)
    out = str(tmp_path / "e.txt")
    assert main(["estimate", str(dataset), "--out", out, *FAST]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ifmi estimate: error: cannot write {tmp_path / name}: an existing file that no estimate "
                   f"wrote; choose another output path or pass --force to replace it"]
    assert sorted(os.listdir(tmp_path)) == [name] and (tmp_path / name).read_text() == text
    assert main(["estimate", str(dataset), "--out", out, "--force", *FAST]) == 0
    assert (tmp_path / "e.txt").read_text().startswith("# ifmi estimate, method ifmi\n")


def test_estimate_replaces_an_earlier_estimate_and_empty_files(dataset, tmp_path):
    out = str(tmp_path / "e.txt")
    (tmp_path / "e.frames.csv").write_bytes(b"")  # an empty file holds nothing to lose
    assert main(["estimate", str(dataset), "--out", out, *FAST]) == 0
    first = _snapshot(tmp_path)
    assert main(["estimate", str(dataset), "--out", out, "--seed", "1", *FAST]) == 0
    assert sorted(_snapshot(tmp_path)) == sorted(first) == ["e.config.json", "e.frames.csv", "e.txt"]
    assert json.loads((tmp_path / "e.config.json").read_text())["config"]["relative_pose"]["seed"] == 1


def test_estimate_to_a_folder_path_is_refused(dataset, tmp_path, capsys):
    out = str(tmp_path / "runs" / "sub") + "/"
    assert main(["estimate", str(dataset), "--out", out, *FAST]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ifmi estimate: error: cannot write {out}: expected the estimate's file path (DIR/NAME.txt), "
                   f"got a folder path ending in a separator"]
    assert not (tmp_path / "runs").exists()


def test_estimate_to_a_path_without_a_file_name_is_refused(dataset, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["estimate", str(dataset), "--out", ".", *FAST]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["ifmi estimate: error: cannot write '.': expected the estimate's file path (DIR/NAME.txt), "
                   "got a path without a file name"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize(("first", "second"), [("e.txt", "e"), ("e", "e.txt"), ("e.txt", "e.tum")])
def test_estimate_refuses_the_side_files_of_another_estimate_of_the_same_name(dataset, tmp_path, capsys,
                                                                              first, second):
    """e and e.txt share e.frames.csv and e.config.json: the second run would pair its side files with
    the first run's trajectory (evaluate then labels one run's poses with the other's method and times)."""
    assert main(["estimate", str(dataset), "--out", str(tmp_path / first), *FAST]) == 0
    before = _snapshot(tmp_path)
    capsys.readouterr()
    assert main(["estimate", str(dataset), "--out", str(tmp_path / second), "--method", "orb",
                 "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ifmi estimate: error: cannot write {tmp_path / 'e.frames.csv'}: is also the side file of "
                   f"the estimate {tmp_path / first} (side files are named without the suffix, so they would "
                   f"pair with both); choose another output path or pass --force to replace it"]
    assert _snapshot(tmp_path) == before
    assert main(["estimate", str(dataset), "--out", str(tmp_path / second), "--method", "orb",
                 "--no-progress", "--force"]) == 0
