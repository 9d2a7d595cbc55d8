"""benchmarks/bench_speed.py: exclusive stage times, stage columns, resized sets and its report."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("skimage")
from ifmi.io.camera_file import calibration_path, read_camera  # noqa: E402
from ifmi.io.tum import read_tum  # noqa: E402
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)

@pytest.fixture
def bench(benchmark_module):
    """``benchmarks/bench_speed.py`` as a module."""
    return benchmark_module("bench_speed")


def _dataset(folder: Path, frames: int = 4) -> Path:
    model = example_omni_model(128)
    sequence = synthetic_sequence(model, frames, seed=3, max_step_rad=0.03, band_px=example_band_px(model))
    return write_synthetic_dataset(folder, sequence)


def test_csv_stages_are_medians_of_the_stage_columns(bench, tmp_path):
    path = tmp_path / "run.frames.csv"
    path.write_text("frame,seconds,t_panorama_ms,t_register_ms\n0,0.1,9,9\n1,0.1,1,4\n2,0.1,3,\n3,0.1,2,6\n")
    # Frame 0 (no pair) is left out; empty cells are skipped.
    assert bench.csv_stages(path) == {"panorama": 2.0, "register": 5.0}
    path.write_text("frame,seconds\n0,0.1\n1,0.2\n")
    assert bench.csv_stages(path) is None


def test_resized_dataset_scales_images_and_calibration(bench, tmp_path):
    source = _dataset(tmp_path / "small")
    out = bench.resized_dataset(source, tmp_path / "big", size=256, frames=2)
    images = sorted((out / "images").iterdir())
    assert len(images) == 2
    assert cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED).shape[:2] == (256, 256)
    model = read_camera(calibration_path(out))
    expected = read_camera(calibration_path(source)).scaled(2.0)
    assert model.size == (256, 256)
    np.testing.assert_allclose(model.center, expected.center)
    # The ground truth of the frames kept: the resized set can be evaluated.
    truth = read_tum(out / "groundtruth.txt")
    np.testing.assert_array_equal(truth.rotations, read_tum(source / "groundtruth.txt").rotations[:2])


def test_one_set_gives_every_method_and_a_report(bench, tmp_path, capsys):
    data = _dataset(tmp_path / "office")
    out, report = tmp_path / "bench", tmp_path / "speed.md"
    assert bench.main([str(data), "--modes", "frame", "--rounds", "1", "--frames", "3", "--rss-size", "0",
                       "--out", str(out), "--report", str(report)]) == 0
    results = json.loads((out / "bench_speed.json").read_text())
    (row,) = results["rows"]
    assert set(row["compute_ms"]) == set(row["wall_ms"]) == set(row["ate_rad"]) == {"ifmi", "orb", "akaze"}
    assert all(v > 0 for v in row["compute_ms"].values())
    # The stage table is the per-pair pipeline's own timing columns: every pair is registered and solved.
    stages = row["stages_ms"]
    assert {"prepare", "register", "solve"} <= set(stages) and all(v >= 0 for v in stages.values())
    assert stages["register"] > 0 and stages["solve"] > 0
    text = report.read_text()
    assert text in capsys.readouterr().out
    for heading in ("## Targets", "## Per set and mode", "## iFMI per stage (ms per frame)"):
        assert heading in text
    assert str(tmp_path) not in text  # paths outside the working directory are shortened
