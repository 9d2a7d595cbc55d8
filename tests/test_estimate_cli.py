"""``ifmi estimate`` on DATASET folders: outputs, side files, bad input."""

from __future__ import annotations

import csv
import json
import shutil
import signal

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main
from ifmi.io.dataset import read_dataset, read_image
from ifmi.io.tum import read_tum
from ifmi.geometry.rotations import geodesic_angle

pytest.importorskip("skimage")
from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset  # noqa: E402

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(127.2, 129.7),
                               affine=(1.001, 0.002, -0.001))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    seq = synthetic_sequence(MODEL, 6, seed=7, band_px=(30.0, 125.0), noise_std=1.0)
    root = write_synthetic_dataset(tmp_path_factory.mktemp("data") / "synthetic", seq)
    return root, seq


def test_estimate_writes_trajectory_and_side_files(dataset, tmp_path, capsys):
    root, seq = dataset
    out = tmp_path / "run" / "estimate.txt"
    code = main(["estimate", str(root), "--method", "ifmi", "--out", str(out), "--width", "512",
                 "--tile-size", "64", "--no-progress"])
    assert code == 0
    traj = read_tum(out)
    assert len(traj) == 6
    # 512 px panorama (0.0123 rad/px), 5 chained estimates good to ~0.03 px (4e-4 rad) each.
    assert geodesic_angle(seq.rotations, traj.rotations).max() < 4e-3
    with open(tmp_path / "run" / "estimate.frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["frame"] for r in rows] == [str(k) for k in range(6)]
    for key in ("reference_frame", "success", "reason", "n_correspondences", "n_inliers", "seconds",
                "rotation_sigma_rad"):
        assert key in rows[0]
    # Frame 0 has no fit; every other frame a finite, positive predicted error, the largest reported.
    sigmas = [float(r["rotation_sigma_rad"]) for r in rows[1:]]
    assert rows[0]["rotation_sigma_rad"] == "" and all(0 < s < 4e-3 for s in sigmas)
    largest = int(np.argmax(sigmas)) + 1
    assert f"largest predicted rotation error {max(sigmas):.2g} rad (frame {largest})" in capsys.readouterr().out
    config = json.loads((tmp_path / "run" / "estimate.config.json").read_text())
    assert config["method"] == "ifmi"
    assert config["config"]["ifmi"]["panorama"]["width"] == 512
    assert config["config"]["ifmi"]["tiling"]["tile_size"] == 64


def test_estimate_without_groundtruth_and_with_rgb(dataset, tmp_path):
    root, _ = dataset
    copy = tmp_path / "rgb"
    shutil.copytree(root, copy)
    (copy / "groundtruth.txt").unlink()
    for path in sorted((copy / "images").glob("*.png")):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(path.with_suffix(".jpg")), cv2.merge([gray, gray, gray]), [cv2.IMWRITE_JPEG_QUALITY, 92])
        path.unlink()
    out = tmp_path / "rgb.txt"
    assert main(["estimate", str(copy), "--out", str(out), "--width", "512", "--keyframes", "--no-progress"]) == 0
    assert len(read_tum(out)) == 6
    assert read_image(next((copy / "images").iterdir()), gray=False).shape == (256, 256, 3)


def _frames_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_bad_images_inside_the_sequence_are_flagged(dataset, tmp_path):
    """A wrong-size and an unreadable image mid-sequence fail their frames only."""
    root, seq = dataset
    copy = tmp_path / "bad"
    shutil.copytree(root, copy)
    cv2.imwrite(str(copy / "images" / "000002.png"), np.zeros((100, 120), np.uint8))
    (copy / "images" / "000004.png").write_bytes(b"not a png")
    out = tmp_path / "bad.txt"
    assert main(["estimate", str(copy), "--out", str(out), "--no-progress"]) == 0
    rows = _frames_csv(tmp_path / "bad.frames.csv")
    assert [r["success"] for r in rows] == ["true", "true", "false", "true", "false", "true"]
    assert "100x120" in rows[2]["reason"] and "calibration names 256x256" in rows[2]["reason"]
    assert "not a readable PNG/JPEG image" in rows[4]["reason"]
    est = read_tum(out)
    assert len(est) == 6
    # A flagged frame holds the previous pose; the good frames stay on the ground truth.
    np.testing.assert_allclose(est.rotations[2], est.rotations[1])
    good = [0, 1, 3, 5]
    assert geodesic_angle(est.rotations[good], seq.rotations[good]).max() < 0.01


def test_a_broken_link_inside_the_sequence_is_a_flagged_frame(dataset, tmp_path):
    """A frame whose link points nowhere keeps its place in the sequence and fails with the reason."""
    root, _ = dataset
    copy = tmp_path / "links"
    shutil.copytree(root, copy)
    (copy / "images" / "000003.png").unlink()
    (copy / "images" / "000003.png").symlink_to(tmp_path / "gone.png")
    assert main(["estimate", str(copy), "--out", str(tmp_path / "l.txt"), "--no-progress"]) == 0
    rows = _frames_csv(tmp_path / "l.frames.csv")
    assert [r["frame"] for r in rows] == ["0", "1", "2", "3", "4", "5"]
    assert rows[3]["success"] == "false" and "image file not found" in rows[3]["reason"]


def test_unreadable_first_image_names_the_file(dataset, tmp_path, capsys):
    root, _ = dataset
    copy = tmp_path / "junk"
    shutil.copytree(root, copy)
    (copy / "images" / "000000.png").write_bytes(b"not a png")
    out = tmp_path / "j.txt"
    assert main(["estimate", str(copy), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "000000.png: first frame unusable: 000000.png: not a readable PNG/JPEG image" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_missing_calibration(tmp_path, capsys):
    (tmp_path / "images").mkdir()
    assert main(["estimate", str(tmp_path), "--out", str(tmp_path / "e.txt")]) == 2
    assert "calib_results.txt: calibration file not found" in capsys.readouterr().err


def test_no_images(dataset, tmp_path, capsys):
    root, _ = dataset
    copy = tmp_path / "empty"
    shutil.copytree(root, copy)
    for p in (copy / "images").iterdir():
        p.unlink()
    assert main(["estimate", str(copy), "--out", str(tmp_path / "e.txt")]) == 2
    assert "no frame images" in capsys.readouterr().err


def test_bad_option_value_is_one_line(dataset, tmp_path, capsys):
    root, _ = dataset
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--overlap", "1.5"]) == 2
    assert "overlap must be in [0, 1)" in capsys.readouterr().err


def test_dataset_reader_sorts_images(dataset):
    root, _ = dataset
    ds = read_dataset(root)
    assert [p.name for p in ds.image_paths] == sorted(p.name for p in ds.image_paths)
    assert ds.groundtruth_path is not None and len(ds) == 6


def test_config_file_and_overrides(dataset, tmp_path):
    root, _ = dataset
    first = tmp_path / "first.txt"
    assert main(["estimate", str(root), "--out", str(first), "--width", "512", "--no-prior",
                 "--rotation-only", "--th-pr", "1.8", "--no-progress"]) == 0
    second = tmp_path / "second.txt"
    assert main(["estimate", str(root), "--out", str(second), "--config",
                 str(tmp_path / "first.config.json"), "--overlap", "0.25", "--no-progress"]) == 0
    config = json.loads((tmp_path / "second.config.json").read_text())["config"]
    assert config["ifmi"]["tracking"]["use_prior"] is False and config["relative_pose"]["rotation_only"] is True
    assert config["ifmi"]["registration"]["th_pr"] == 1.8 and config["ifmi"]["tiling"]["overlap"] == 0.25
    assert config["ifmi"]["panorama"]["width"] == 512


def test_unreadable_config_file(dataset, tmp_path, capsys):
    root, _ = dataset
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt"), "--config", str(bad)]) == 2
    assert "bad.json: invalid JSON at line 1 column 2" in capsys.readouterr().err


def test_pixel_threshold_option_is_converted_and_recorded(dataset, tmp_path):
    from ifmi.spectral.panorama import angular_pixel_size_in_band

    root, _ = dataset
    out = tmp_path / "px.txt"
    assert main(["estimate", str(root), "--out", str(out), "--ransac-threshold-px", "2",
                 "--max-failures", "3", "--no-progress"]) == 0
    config = json.loads((tmp_path / "px.config.json").read_text())["config"]
    pixel = angular_pixel_size_in_band(read_dataset(root).model)
    assert config["relative_pose"]["ransac_threshold_px"] == 2.0
    assert config["relative_pose"]["ransac_threshold_rad"] == pytest.approx(2.0 * pixel)
    assert config["keyframe"]["max_failures"] == 3


def _tiny_dataset(folder, model):
    """DATASET of three seeded noise images of ``model`` (enough to reach the front end's setup)."""
    from ifmi.io.camera_file import write_camera

    (folder / "images").mkdir(parents=True)
    write_camera(folder, model)
    rng = np.random.default_rng(3)
    for k in range(3):
        cv2.imwrite(str(folder / "images" / f"{k:06d}.png"),
                    rng.integers(0, 256, model.size, dtype=np.uint8))
    return folder


def _small_cameras():
    from camera_examples import EXAMPLES

    ds = EXAMPLES["ds"]
    ocam = EXAMPLES["ocamcalib"]
    # 192 px wide double sphere: 30 px panorama; 96 px OCamCalib: 19 px panorama (tiles are 32 px).
    return {"camera.yaml": ds.scaled(192 / ds.width), "calib_results.txt": ocam.scaled(96 / ocam.width)}


@pytest.mark.parametrize("calib_name", ["camera.yaml", "calib_results.txt"])
def test_panorama_smaller_than_a_tile_is_one_line(tmp_path, capsys, calib_name):
    root = _tiny_dataset(tmp_path / "tiny", _small_cameras()[calib_name])
    out = tmp_path / "e.txt"
    assert main(["estimate", str(root), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and not out.exists()
    assert f"{root / calib_name}: " in err
    assert "smaller than the 32 px tile; expected a panorama at least 32x32 px" in err
    assert "--tile-size" in err


@pytest.mark.slow
def test_panorama_smaller_than_a_tile_from_the_library(tmp_path):
    from ifmi.errors import CalibrationFitError
    from ifmi.pipeline import estimate_dataset, estimate_sequence

    model = _small_cameras()["camera.yaml"]
    root = _tiny_dataset(tmp_path / "tiny", model)
    with pytest.raises(CalibrationFitError, match=r"camera\.yaml: the 123x192 px image gives a 30x256 px"):
        estimate_dataset(root, method="ifmi")
    # Without a file the model is named generically; the feature baselines have no tiles.
    images = [read_image(p) for p in sorted((root / "images").iterdir())]
    with pytest.raises(CalibrationFitError, match="^camera model: "):
        estimate_sequence(images, model, method="ifmi")
    assert len(estimate_sequence(images, model, method="orb").frames) == 3


@pytest.mark.slow
@pytest.mark.parametrize("calib_name", ["camera.yaml", "calib_results.txt"])
def test_run_file_names_the_calibration_the_dataset_holds(tmp_path, calib_name):
    """The run file records the dataset and the calibration file it was estimated with."""
    import json

    from camera_examples import EXAMPLES

    from ifmi.io.camera_file import write_camera

    root = tmp_path / "d"
    (root / "images").mkdir(parents=True)
    model = EXAMPLES["kb" if calib_name == "camera.yaml" else "ocamcalib"]
    write_camera(root, model)
    still = np.random.default_rng(5).integers(0, 256, model.size, dtype=np.uint8)
    for k in range(3):  # a camera at rest
        cv2.imwrite(str(root / "images" / f"{k:06d}.png"), still)
    assert (root / calib_name).is_file()
    out = tmp_path / "e.txt"
    assert main(["estimate", str(root), "--method", "orb", "--out", str(out), "--no-progress"]) == 0
    run = json.loads(out.with_name("e.config.json").read_text())
    assert (run["dataset"], run["calib"]) == (str(root.resolve()), str((root / calib_name).resolve()))


def test_twelve_bit_frames_in_16_bit_files_estimate_as_their_8_bit_originals(dataset, tmp_path, capsys):
    """Unscaled 12-bit samples (a machine-vision camera's PNGs) are read at 12 bits, with one warning."""
    root, _ = dataset
    copy = tmp_path / "deep"
    shutil.copytree(root, copy)
    for path in sorted((copy / "images").glob("*.png")):
        cv2.imwrite(str(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.uint16) << 4)
    assert main(["estimate", str(root), "--out", str(tmp_path / "eight.txt"), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["estimate", str(copy), "--out", str(tmp_path / "deep.txt"), "--no-progress"]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "16-bit" in line]
    assert warned == [f"ifmi estimate: warning: {copy / 'images'}: 16-bit images whose values stay below "
                      f"4096 are read as 12-bit data (their top 8 of 12 bits), not as 16-bit data"]
    np.testing.assert_array_equal(read_tum(tmp_path / "deep.txt").rotations,
                                  read_tum(tmp_path / "eight.txt").rotations)


def _kalibr_dataset(root, model, image_size):
    from ifmi.io.kalibr import write_kalibr

    (root / "images").mkdir(parents=True)
    write_kalibr(root / "camera.yaml", model)
    texture = (np.random.default_rng(0).random(image_size) * 255).astype(np.uint8)
    for k in range(3):
        cv2.imwrite(str(root / "images" / f"{k:06d}.png"), np.roll(texture, 3 * k, axis=1))
    return root


def _cut_eucm(height):
    """The example EUCM camera at half size (240 x 376), its image cut to ``height`` rows: no full ring."""
    from ifmi.geometry.camera_models import ExtendedUnifiedModel

    from camera_examples import EXAMPLES

    m = EXAMPLES["eucm"].scaled(0.5)
    return ExtendedUnifiedModel(m.alpha, m.beta, tuple(m.focal), tuple(m.principal_point), (height, m.size[1]))


@pytest.mark.parametrize("method", ["ifmi", "orb"])
def test_kalibr_resolution_other_than_the_images_is_named_as_a_size_mismatch(tmp_path, capsys, method):
    root = _kalibr_dataset(tmp_path / "ds", _cut_eucm(121), (240, 376))
    assert main(["estimate", str(root), "--method", method, "--out", str(tmp_path / "e.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.endswith("000000.png: image is 240x376 (height x width), but the calibration names 121x376")


def test_camera_imaging_no_full_ring_is_an_error_naming_its_calibration(tmp_path, capsys):
    root = _kalibr_dataset(tmp_path / "ds", _cut_eucm(121), (121, 376))
    assert main(["estimate", str(root), "--out", str(tmp_path / "e.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"{root / 'camera.yaml'}: the camera model images no full ring of rays about its axis" in err


def test_interrupt_while_the_library_imports_is_one_line_exit_130(monkeypatch, capsys, default_sigint):
    import ifmi.cli

    def interrupted_build():
        signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(ifmi.cli, "build_parser", interrupted_build)
    code = main(["estimate", "anything", "--out", "x.txt"])
    assert code == 130 and capsys.readouterr().err == "ifmi: interrupted\n"


def test_interrupt_swallowed_by_library_code_still_exits_130(dataset, tmp_path, monkeypatch, capsys, default_sigint):
    """An interrupt that library code catches (or turns into another error) is not lost: the
    estimate it lets finish is written, and the exit status says it was interrupted."""
    import ifmi.cli.estimate

    real = ifmi.cli.estimate.estimate_run

    def swallowing(*args, **kwargs):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass
        return real(*args, **kwargs)

    monkeypatch.setattr(ifmi.cli.estimate, "estimate_run", swallowing)
    root, _ = dataset
    code = main(["estimate", str(root), "--out", str(tmp_path / "est.txt"), "--width", "512",
                 "--tile-size", "64", "--no-progress"])
    assert code == 130 and capsys.readouterr().err == "ifmi estimate: interrupted\n"
