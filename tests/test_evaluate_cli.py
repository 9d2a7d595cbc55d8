"""``ifmi evaluate``: files written, numbers, side files and error paths."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ifmi.cli import main
from ifmi.io.results import read_evaluation
from ifmi.io.tum import Trajectory, write_tum
from ifmi.rotations import matrix_from_rpy


def _write_run(tmp_path, n=20, yaw_offset=0.01, failed=(3, 7)):
    rpy = np.zeros((n, 3))
    rpy[:, 2] = np.linspace(0.0, 0.5, n)
    positions = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)])
    gt = Trajectory(np.arange(n, dtype=float), positions, matrix_from_rpy(rpy))
    rpy_est = rpy.copy()
    rpy_est[1:, 2] += yaw_offset
    est = Trajectory(np.arange(n, dtype=float), positions * 3.0, matrix_from_rpy(rpy_est))
    write_tum(tmp_path / "groundtruth.txt", gt)
    write_tum(tmp_path / "est.txt", est)
    lines = ["frame,reference_frame,success,reason,n_correspondences,n_inliers,seconds"]
    for k in range(n):
        ok = k not in failed
        lines.append(f"{k},{max(k - 1, 0)},{str(ok).lower()},{'ok' if ok else 'too few matches'},"
                     f"50,40,{0.01 * (1 + k % 2)}")
    (tmp_path / "est.frames.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "est.config.json").write_text(json.dumps(
        {"method": "orb", "dataset": str(tmp_path / "office_20"), "config": {"n_features": 2000}}))
    return gt, est


def test_evaluate_writes_files_and_exact_numbers(tmp_path, capsys):
    _write_run(tmp_path)
    out = tmp_path / "eval"
    code = main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                 "--est", str(tmp_path / "est.txt"), "--out", str(out), "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    s = printed["summary"]
    # Yaw is off by 0.01 rad on 19 of 20 frames, roll and pitch are exact.
    assert s["axes"]["yaw"]["rmse"] == pytest.approx(0.01 * np.sqrt(19 / 20), abs=1e-9)
    assert s["axes"]["roll"]["rmse"] == pytest.approx(0.0, abs=1e-9)
    assert s["geodesic"]["max"] == pytest.approx(0.01, abs=1e-9)
    assert s["relative_geodesic"]["max"] == pytest.approx(0.01, abs=1e-9)
    # Positions are the truth scaled by 3; seen from the estimated reference
    # camera (yawed by 0.01 rad from frame 1 on) the direction is off by 0.01
    # rad, except for frame 1 whose reference is frame 0 (exact).
    assert s["translation_direction"]["count"] == 19
    assert s["translation_direction"]["mean"] == pytest.approx(0.01 * 18 / 19, abs=1e-9)
    assert s["failures"] == {"count": 2, "frames": 20}
    assert s["time"]["mean_s"] == pytest.approx(0.015)
    assert printed["method"] == "orb" and printed["dataset"] == "office_20"
    record = read_evaluation(out)
    assert record.config["config"]["n_features"] == 2000
    assert len(record.frames) == 20
    np.testing.assert_allclose(record.arrays["yaw_error"][1:], 0.01, atol=1e-9)
    for name in ("evaluation.json", "per_frame.csv", "per_frame.npz", "config.json", "frames.csv"):
        assert (out / name).is_file()
    header = (out / "per_frame.csv").read_text().splitlines()[0].split(",")
    assert "geodesic_error" in header and "roll_gt" in header


def test_evaluate_table_output_and_default_folder(tmp_path, capsys):
    _write_run(tmp_path)
    assert main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                 "--est", str(tmp_path / "est.txt")]) == 0
    text = capsys.readouterr().out
    assert "yaw" in text and "failed frames: 2 of 20" in text
    assert (tmp_path / "est.eval" / "evaluation.json").is_file()


def test_evaluate_without_side_files(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "est.frames.csv").unlink()
    (tmp_path / "est.config.json").unlink()
    assert main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                 "--est", str(tmp_path / "est.txt"), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["summary"]
    assert s["failures"] is None and s["time"] is None


def _run_error(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


def test_missing_estimate_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "nope.txt")], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "nope.txt" in err and "not found" in err


def test_malformed_groundtruth_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "groundtruth.txt").write_text("0 0 0 0 0 0 0\n")
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "est.txt")], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "expected 8 values" in err


def test_malformed_frames_csv_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "est.frames.csv").write_text("frame,success\n0,true\n")
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "est.txt")], capsys)
    assert code == 2 and "est.frames.csv" in err and "missing column(s) seconds" in err


def test_malformed_config_json_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "est.config.json").write_text("{not json")
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "est.txt")], capsys)
    assert code == 2 and "est.config.json" in err and "invalid JSON" in err


def test_disjoint_timestamps_is_one_line_error(tmp_path, capsys):
    gt, est = _write_run(tmp_path)
    write_tum(tmp_path / "est.txt", Trajectory(est.timestamps + 1000, est.positions, est.rotations))
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "est.txt")], capsys)
    assert code == 2 and "no estimate timestamp" in err and len(err.splitlines()) == 1


def test_ifmi_evaluation_saves_motion_flow_of_real_frames(tmp_path):
    import cv2

    from ifmi.evaluation import evaluate_files
    from ifmi.io.calib import write_calib
    from ifmi.io.results import read_motion_flow, write_estimate_run
    from ifmi.pipeline import estimate_dataset
    pytest.importorskip("skimage")
    from ifmi.synthetic import environment_texture, example_band_px, example_omni_model, omni_from_environment

    # Two frames turned by a pure yaw: on the panorama every tile moves by
    # -yaw * width / (2 pi) columns and 0 rows.
    yaw = 0.05
    data = tmp_path / "data"
    (data / "images").mkdir(parents=True)
    model = example_omni_model(256)
    write_calib(data / "calib_results.txt", model)
    texture = environment_texture(height=512, seed=0)
    rotations = matrix_from_rpy(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, yaw]]))
    for k, R in enumerate(rotations):
        cv2.imwrite(str(data / "images" / f"{k:06d}.png"), omni_from_environment(
            texture, model, R, band_px=example_band_px(model)))
    write_tum(data / "groundtruth.txt", Trajectory(np.arange(2.0), np.zeros((2, 3)), rotations))
    est = write_estimate_run(tmp_path / "ifmi.txt", estimate_dataset(data, method="ifmi"),
                             dataset_dir=data)
    meta = evaluate_files(data / "groundtruth.txt", est, out_dir=tmp_path / "eval")
    assert meta["motion_flow"] == "motion_flow.npz"
    flow = read_motion_flow(tmp_path / "eval" / "motion_flow.npz")
    width = flow["panorama_a"].shape[1]
    assert flow["panorama_a"].shape == flow["panorama_b"].shape
    assert len(flow["points_a"]) >= 3 and len(flow["tile_centers"]) >= len(flow["points_a"])
    d = flow["points_b"] - flow["points_a"]
    d[:, 1] = (d[:, 1] + width / 2) % width - width / 2
    expected = -yaw * width / (2 * np.pi)
    # Tile flow is sub-pixel; the median over tiles is within a quarter pixel.
    assert abs(np.median(d[:, 1]) - expected) < 0.25
    assert abs(np.median(d[:, 0])) < 0.25
