"""The top-level Python API (``ifmi.estimate``, ``ifmi.evaluate``, ``omnisim.load_scene``) on exact
synthetic data: the same numbers as the command line, in memory and as files."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import FrozenInstanceError, replace
from pathlib import Path

import numpy as np
import pytest

import ifmi
from ifmi.cli import main
from ifmi.errors import InputError
from ifmi.io.tum import read_tum
from ifmi.geometry.rotations import geodesic_angle
from ifmi.synthetic import example_omni_model, synthetic_sequence, write_synthetic_dataset
from ifmi.spectral.panorama import PanoramaConfig

pytest.importorskip("skimage")

SCENES = Path(__file__).resolve().parents[1] / "scenes"
MODEL = example_omni_model(256)
# 512 px panorama: 1 px is 0.0123 rad; tiles register to a few hundredths of a pixel.
CONFIG = ifmi.EstimateConfig()
CONFIG = replace(CONFIG, ifmi=replace(CONFIG.ifmi, panorama=PanoramaConfig(width=512)))
# Bound on the geodesic ATE of 6 chained frames on noise-free renders: a pair errs by ~4e-4 rad
# (see tests/test_pipeline.py); five of them chained as a random walk stay well under this.
MAX_ATE_RAD = 2.5e-3


@pytest.fixture(scope="module")
def sequence():
    return synthetic_sequence(MODEL, 6, seed=11, band_px=(30.0, 120.0), noise_std=1.0)


@pytest.fixture(scope="module")
def dataset(sequence, tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("api") / "synthetic", sequence)


@pytest.fixture(scope="module")
def folder_estimate(dataset):
    return ifmi.estimate(dataset, config=CONFIG)


def test_import_is_light():
    code = "import sys, ifmi, omnisim; print(sorted(m for m in ('cv2', 'mitsuba', 'drjit', 'numpy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    assert {"estimate", "evaluate", "read_calibration", "Estimate", "Evaluation"} <= set(ifmi.__all__)


def test_estimate_of_a_folder_follows_the_ground_truth(folder_estimate, sequence):
    result = folder_estimate
    assert result.rotations.shape == (6, 3, 3) and result.timestamps.tolist() == list(range(6))
    assert result.method == "ifmi" and result.failed == 0
    error = geodesic_angle(sequence.rotations, result.rotations)
    assert np.sqrt(np.mean(error ** 2)) < MAX_ATE_RAD
    table = result.table()
    assert list(table["frame"]) == list(range(6)) and table["success"].all()
    with pytest.raises(FrozenInstanceError):
        result.method = "orb"


def test_a_list_of_images_gives_the_folders_estimate(folder_estimate, sequence):
    from_images = ifmi.estimate(list(sequence.images), config=CONFIG, calib=sequence.model)
    # The folder decides its mirror band from its frames, the list from the calibration: the same
    # rotations within what one registration resolves.
    assert geodesic_angle(folder_estimate.rotations, from_images.rotations).max() < MAX_ATE_RAD


def test_evaluate_in_memory_matches_the_cli(folder_estimate, dataset, sequence, tmp_path, capsys):
    in_memory = ifmi.evaluate(sequence.trajectory, folder_estimate)
    error = geodesic_angle(sequence.rotations, folder_estimate.rotations)
    assert in_memory.ate_rad == pytest.approx(np.sqrt(np.mean(error ** 2)), rel=1e-9)
    assert set(in_memory.rmse_rad) == {"roll", "pitch", "yaw"}
    assert in_memory.summary.failures == 0 and in_memory.summary.frames_associated == 6

    path = folder_estimate.write(tmp_path / "est.txt")
    assert read_tum(path).rotations == pytest.approx(folder_estimate.rotations, abs=1e-6)
    assert main(["evaluate", "--gt", str(dataset / "groundtruth.txt"), "--est", str(path), "--json",
                 "--out", str(tmp_path / "eval")]) == 0
    printed = json.loads(capsys.readouterr().out)
    # TUM files hold quaternions with a fixed number of decimals: the file's ATE is the same to them.
    assert printed["summary"]["geodesic"]["rmse"] == pytest.approx(in_memory.ate_rad, abs=1e-6)

    from_files = ifmi.evaluate(dataset / "groundtruth.txt", path)
    assert from_files.ate_rad == printed["summary"]["geodesic"]["rmse"]
    assert from_files.path is None and not (tmp_path / "est.eval").exists()
    written = ifmi.evaluate(dataset / "groundtruth.txt", path, out=True)
    assert written.path == tmp_path / "est.eval" and (written.path / "evaluation.json").is_file()
    assert written.axis("yaw").rmse == pytest.approx(in_memory.axis("yaw").rmse, abs=1e-6)


def test_written_estimate_matches_the_cli(dataset, folder_estimate, tmp_path):
    api_path = folder_estimate.write(tmp_path / "api.txt")
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "cli.txt"), "--width", "512",
                 "--no-progress"]) == 0
    assert read_tum(api_path).rotations == pytest.approx(read_tum(tmp_path / "cli.txt").rotations, abs=1e-9)
    api_config = json.loads((tmp_path / "api.config.json").read_text())
    cli_config = json.loads((tmp_path / "cli.config.json").read_text())
    assert api_config["config"] == cli_config["config"] and api_config["dataset"] == cli_config["dataset"]


def test_bad_inputs_are_one_clear_error(dataset, sequence, tmp_path):
    with pytest.raises(InputError, match="needs calib"):
        ifmi.estimate(list(sequence.images))
    with pytest.raises(InputError, match="dataset folder not found"):
        ifmi.estimate(tmp_path / "missing")
    with pytest.raises(InputError, match="its own calibration"):
        ifmi.estimate(dataset, calib=dataset / "calib_results.txt")
    with pytest.raises(InputError, match="needs the ground truth and the estimate as files"):
        ifmi.evaluate(sequence.trajectory, sequence.trajectory, out=tmp_path / "e")


def test_read_calibration_reads_the_written_model(dataset):
    model = ifmi.read_calibration(dataset / "calib_results.txt")
    assert model.size == MODEL.size
    assert np.allclose(model.pol, MODEL.pol)


def test_load_scene_applies_overrides():
    omnisim = pytest.importorskip("omnisim")
    scene = omnisim.load_scene(SCENES / "office.toml", resolution=64, frames=3, spp=2)
    assert scene.render.resolution == (64, 64) and scene.render.spp == 2 and scene.trajectory.frames == 3
    with pytest.raises(InputError, match="nope.toml"):
        omnisim.load_scene(SCENES / "nope.toml")
