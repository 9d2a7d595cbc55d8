"""``ifmi evaluate``: files written, numbers, side files and error paths."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest

from ifmi.cli import main
from ifmi.io.results import read_evaluation
from ifmi.io.tum import Trajectory, write_tum
from ifmi.geometry.rotations import matrix_from_rpy


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


def test_out_inside_a_data_folder_of_the_dataset_is_refused(tmp_path, capsys):
    _write_run(tmp_path)  # the ground truth sits in tmp_path: the dataset folder
    (tmp_path / "images").mkdir()
    out = tmp_path / "images" / "ev"
    code, err = _run_error(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"),
                            "--est", str(tmp_path / "est.txt"), "--out", str(out)], capsys)
    assert code == 1 and len(err.splitlines()) == 1
    assert err.endswith(f"{out}: would write into images/ of the input dataset {tmp_path}; "
                        "choose another output path")
    assert list((tmp_path / "images").iterdir()) == []


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


def test_position_out_of_range_in_groundtruth_is_one_line_error(tmp_path, capsys):
    # 1e308 m: the translation-direction errors overflowed (NumPy warnings, then n/a) with exit 0.
    _write_run(tmp_path)
    lines = (tmp_path / "groundtruth.txt").read_text().splitlines()
    fields = lines[3].split()
    lines[3] = " ".join([fields[0], "1e308", *fields[2:]])
    (tmp_path / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and err == (f"ifmi evaluate: error: {tmp_path / 'groundtruth.txt'}: pose at timestamp 2: "
                                 "position coordinate 1e+308 out of range; expected at most 3.352e+153 in "
                                 "magnitude")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_side_file_that_is_a_fifo_is_one_line_error(tmp_path, capsys):
    # The read waited for a writer forever.
    _write_run(tmp_path)
    (tmp_path / "est.frames.csv").unlink()
    os.mkfifo(tmp_path / "est.frames.csv")
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and err == (f"ifmi evaluate: error: {tmp_path / 'est.frames.csv'}: is a FIFO, device or "
                                 "socket, not a frames file; expected a regular file")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_out_folder_whose_evaluation_json_is_a_fifo_is_refused(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "eval").mkdir()
    os.mkfifo(tmp_path / "eval" / "evaluation.json")
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "eval")), capsys)
    assert code == 1 and len(err.splitlines()) == 1
    assert "eval: holds evaluation.json but is not an evaluation folder written by ifmi evaluate" in err


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


def test_motion_flow_sample_of_real_frames_and_evaluation_stays_pure(tmp_path):
    import cv2

    from ifmi.evaluation.trajectory_files import evaluate_files
    from ifmi.io.calib import write_calib
    from ifmi.io.results import write_estimate_run
    from ifmi.experiments.motion_flow import motion_flow_sample
    from ifmi.pipeline import EstimateConfig, estimate_dataset
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
    # The evaluation reads files only: no front end is run, no flow sample written.
    assert "motion_flow" not in meta and not (tmp_path / "eval" / "motion_flow.npz").exists()
    flow = motion_flow_sample(data, config=EstimateConfig(), frames=(0, 1))
    width = flow["panorama_a"].shape[1]
    assert flow["panorama_a"].shape == flow["panorama_b"].shape
    assert len(flow["points_a"]) >= 3 and len(flow["tile_centers"]) >= len(flow["points_a"])
    d = flow["points_b"] - flow["points_a"]
    d[:, 1] = (d[:, 1] + width / 2) % width - width / 2
    expected = -yaw * width / (2 * np.pi)
    # Tile flow is sub-pixel; the median over tiles is within a quarter pixel.
    assert abs(np.median(d[:, 1]) - expected) < 0.25
    assert abs(np.median(d[:, 0])) < 0.25


# JSON nested past Python's recursion limit (the decoder raised RecursionError, printed as a traceback).
DEEP_JSON = '{"a": ' * 100_000 + "1" + "}" * 100_000


@pytest.mark.parametrize("text, problem", [
    (DEEP_JSON, "invalid JSON: nested too deeply"),
    ('{"method": "orb", "n": ' + "9" * 5000 + "}", "invalid JSON: an integer of 5000 digits; expected at most 4300"),
])
def test_config_json_nested_too_deeply_or_of_a_huge_integer_is_one_line_error(tmp_path, capsys, text,
                                                                              problem):
    _write_run(tmp_path)
    (tmp_path / "est.config.json").write_text(text)
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "eval")), capsys)
    assert code == 2 and err == f"ifmi evaluate: error: {tmp_path / 'est.config.json'}: {problem}"
    assert not (tmp_path / "eval").exists()


def test_out_folder_whose_evaluation_json_is_nested_too_deeply_is_refused(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "evaluation.json").write_text(DEEP_JSON)
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "eval")), capsys)
    assert code == 1 and len(err.splitlines()) == 1
    assert "eval: holds evaluation.json but is not an evaluation folder written by ifmi evaluate" in err
    assert (tmp_path / "eval" / "evaluation.json").read_text() == DEEP_JSON


def _gate(tmp_path, *extra):
    return ["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est", str(tmp_path / "est.txt"),
            *extra]


def test_gate_passes_within_bounds(tmp_path, capsys):
    _write_run(tmp_path)  # geodesic error 0.01 rad on 19 of 20 frames, 2 failed frames
    assert main(_gate(tmp_path, "--max-rmse", "0.0100", "--max-failed", "2")) == 0
    out = capsys.readouterr().out.strip()
    assert out == "PASS: geodesic RMSE 0.0097 rad <= 0.0100 rad, 2 failed frames <= 2"


def test_gate_fails_on_rmse_with_one_line_and_exit_1(tmp_path, capsys):
    _write_run(tmp_path, yaw_offset=0.0126)
    assert main(_gate(tmp_path, "--max-rmse", "0.01")) == 1
    out = capsys.readouterr().out.strip()
    assert out == "FAIL: geodesic RMSE 0.0123 rad > 0.0100 rad, 2 failed frames"


def test_gate_fails_on_failed_frames(tmp_path, capsys):
    _write_run(tmp_path, failed=(1, 2, 3))
    assert main(_gate(tmp_path, "--max-rmse", "0.1", "--max-failed", "2")) == 1
    assert capsys.readouterr().out.strip() == ("FAIL: geodesic RMSE 0.0097 rad <= 0.1000 rad, "
                                               "3 failed frames > 2")


def test_gate_max_failed_without_frames_file_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "est.frames.csv").unlink()
    code, err = _run_error(_gate(tmp_path, "--max-rmse", "0.1", "--max-failed", "0"), capsys)
    assert code == 2 and "failed-frame count is unknown" in err and len(err.splitlines()) == 1
    assert "est.frames.csv" in err
    # Refused before anything is written: no evaluation folder beside the estimate.
    assert not (tmp_path / "est.eval").exists()


def test_gate_max_failed_needs_max_rmse(tmp_path, capsys):
    _write_run(tmp_path)
    code, err = _run_error(_gate(tmp_path, "--max-failed", "0"), capsys)
    assert code == 2 and "--max-failed needs --max-rmse" in err


def test_too_few_associated_poses_is_an_error_naming_both_counts(tmp_path, capsys):
    gt, est = _write_run(tmp_path)
    (tmp_path / "est.frames.csv").unlink()
    # Only frames 0..8 of 20 have an estimate: 9 < 10.
    write_tum(tmp_path / "est.txt", Trajectory(est.timestamps[:9], est.positions[:9],
                                               est.rotations[:9]))
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and "only 9 of 20 ground-truth poses" in err and len(err.splitlines()) == 1
    # The bar can be lowered.
    assert main(_gate(tmp_path, "--min-matched", "0.4")) == 0


def test_duplicate_timestamps_are_an_error(tmp_path, capsys):
    gt, est = _write_run(tmp_path)
    stamps = gt.timestamps.copy()
    stamps[5] = 4.0
    write_tum(tmp_path / "groundtruth.txt", Trajectory(stamps, gt.positions, gt.rotations))
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and "groundtruth.txt" in err and "duplicate timestamp 4" in err
    _write_run(tmp_path)
    write_tum(tmp_path / "est.txt", Trajectory(stamps, est.positions, est.rotations))
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and "est.txt" in err and "duplicate timestamp 4" in err


def test_side_files_of_another_run_are_refused(tmp_path, capsys):
    _write_run(tmp_path)
    rows = (tmp_path / "est.frames.csv").read_text().splitlines()
    (tmp_path / "est.frames.csv").write_text("\n".join(rows + rows[1:]) + "\n")
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and "est.frames.csv" in err and "40 frames, but est.txt has 20 poses" in err
    assert len(err.splitlines()) == 1


def test_unwritable_output_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    (tmp_path / "file").write_text("x")
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "file" / "eval")), capsys)
    assert code == 1 and len(err.splitlines()) == 1
    assert "cannot write" in err and str(tmp_path / "file" / "eval") in err and ".tmp" not in err


def test_read_only_output_folder_is_one_line_error(tmp_path, capsys):
    import os

    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    _write_run(tmp_path)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code, err = _run_error(_gate(tmp_path, "--out", str(locked / "eval")), capsys)
    finally:
        locked.chmod(0o700)
    assert code == 1 and len(err.splitlines()) == 1 and "Permission denied" in err


def test_evaluate_options_are_checked():
    from ifmi.evaluation.trajectory_files import EvaluateOptions

    with pytest.raises(ValueError, match="expected min_matched in \\[0, 1\\], got 1.5"):
        EvaluateOptions(min_matched=1.5)
    with pytest.raises(ValueError, match="expected max_time_difference finite and >= 0, got -1"):
        EvaluateOptions(max_time_difference=-1)
    with pytest.raises(ValueError, match="expected origin_tolerance_rad > 0, got 0"):
        EvaluateOptions(origin_tolerance_rad=0)


def test_evaluate_cli_rejects_bad_min_matched(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(_gate(tmp_path, "--min-matched", "1.5"))
    assert exc.value.code == 2 and "expected a fraction in [0, 1], got 1.5" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["inf", "-1"])
def test_evaluate_cli_rejects_an_infinite_or_negative_time_difference(tmp_path, capsys, value):
    # With inf every pose was "within inf" yet the shortfall message said only some were.
    with pytest.raises(SystemExit) as exc:
        main(_gate(tmp_path, "--max-time-difference", value))
    err = capsys.readouterr().err.splitlines()[-1]
    assert exc.value.code == 2 and err == ("ifmi evaluate: error: argument --max-time-difference: "
                                           "expected a finite time difference >= 0 in the timestamps' "
                                           f"unit, got {value}")


def test_gate_fails_on_nan_rmse():
    from ifmi.evaluation.trajectory_files import gate_verdict
    from ifmi.evaluation.metrics import ErrorStats, EvaluationSummary

    nan = ErrorStats(*[float("nan")] * 5, count=0)
    summary = EvaluationSummary(nan, nan, nan, nan, nan, nan, 3, 3, 0)
    verdict = gate_verdict(summary, max_rmse_rad=0.1)
    assert not verdict.passed and verdict.line == "FAIL: geodesic RMSE nan rad > 0.1000 rad"


def test_summary_round_trips_through_its_dict(tmp_path, capsys):
    from ifmi.evaluation.trajectory_files import summary_of
    from ifmi.evaluation.metrics import EvaluationSummary

    _write_run(tmp_path)
    assert main(_gate(tmp_path, "--json")) == 0
    meta = json.loads(capsys.readouterr().out)
    summary = summary_of(meta)
    assert EvaluationSummary.from_dict(summary.to_dict()) == summary
    flat = summary.flat()
    assert flat["rmse_yaw_rad"] == meta["summary"]["axes"]["yaw"]["rmse"]
    assert flat["rmse_mean_rad"] == pytest.approx(meta["summary"]["mean_rmse"])
    assert flat["failures"] == 2 and flat["frames"] == 20


def test_motion_flow_sample_of_frames_outside_the_dataset_is_input_error(tmp_path):
    from ifmi.errors import InputError
    from ifmi.experiments.motion_flow import motion_flow_sample
    from ifmi.pipeline import EstimateConfig
    pytest.importorskip("skimage")
    from ifmi.synthetic import example_omni_model, synthetic_sequence, write_synthetic_dataset

    data = write_synthetic_dataset(tmp_path / "d", synthetic_sequence(example_omni_model(96), 2))
    with pytest.raises(InputError, match=r"frames 0, 5 outside 0..1"):
        motion_flow_sample(data, config=EstimateConfig(), frames=(0, 5))


def test_a_reader_leaving_the_pipe_ends_quietly(tmp_path, monkeypatch, capsys):
    # `ifmi evaluate --json | head -c 10`: the reader closes the pipe while the JSON is printed.
    import io
    import os
    import sys

    _write_run(tmp_path)
    gt, est = tmp_path / "groundtruth.txt", tmp_path / "est.txt"
    read_end, write_end = os.pipe()
    os.close(read_end)
    broken = io.TextIOWrapper(io.FileIO(write_end, "w"), write_through=True)
    monkeypatch.setattr(sys, "stdout", broken)
    assert main(["evaluate", "--gt", str(gt), "--est", str(est), "--json"]) == 1
    broken.write("after the pipe closed\n")  # now bound to the null device: no error
    assert capsys.readouterr().err == ""



def test_gate_line_shows_small_angles_with_significant_digits(tmp_path, capsys):
    # A sharp 1024 px run is off by about 1e-5 rad: four decimals would print 0.0000 <= 0.0001.
    _write_run(tmp_path, yaw_offset=1e-5, failed=())
    code = main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est", str(tmp_path / "est.txt"),
                 "--max-rmse", "1e-4"])
    out = capsys.readouterr().out.strip()
    assert code == 0 and out.startswith("PASS: geodesic RMSE 9.747e-06 rad <= 1.000e-04 rad"), out


def _edit_frames(tmp_path, column, value, rows=None):
    """Set ``column`` of est.frames.csv to ``value`` on ``rows`` (0: frame 0; default all)."""
    lines = (tmp_path / "est.frames.csv").read_text().splitlines()
    j = lines[0].split(",").index(column)
    for k in range(1, len(lines)):
        if rows is None or k - 1 in rows:
            fields = lines[k].split(",")
            fields[j] = value
            lines[k] = ",".join(fields)
    (tmp_path / "est.frames.csv").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("missing", ["", "nan"])
def test_frames_csv_without_times_gives_an_unknown_time(tmp_path, capsys, missing):
    # An estimator that records no time: the time per frame is unknown, and said so.
    _write_run(tmp_path)
    _edit_frames(tmp_path, "seconds", missing)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Mean of empty slice"
        assert main(_gate(tmp_path, "--out", str(tmp_path / "eval"))) == 0
    out = capsys.readouterr().out
    assert "time per frame: unknown (the run's frames.csv records no time)" in out
    doc = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert doc["summary"]["time"] is None and doc["summary"]["failures"]["count"] == 2


def test_frames_csv_with_some_times_missing_times_the_others(tmp_path, capsys):
    _write_run(tmp_path)  # 0.01 s on even frames, 0.02 s on odd ones
    _edit_frames(tmp_path, "seconds", "", rows=range(1, 20, 2))
    assert main(_gate(tmp_path, "--json")) == 0
    time = json.loads(capsys.readouterr().out)["summary"]["time"]
    assert time == {"mean_s": pytest.approx(0.01), "median_s": pytest.approx(0.01),
                    "total_s": pytest.approx(0.1), "frames": 10}
    assert main(_gate(tmp_path)) == 0
    assert ("time per frame: 10.00 ms mean, 10.00 ms median (over the 10 of 20 frames with a "
            "recorded time)") in capsys.readouterr().out


@pytest.mark.parametrize("column, value, expected", [
    ("seconds", "-1", "column seconds: expected a time in seconds >= 0 (empty when not recorded), "
                      "got '-1'"),
    ("seconds", "inf", "column seconds: expected a time in seconds >= 0"),
    # Finite, but past what a time per frame in milliseconds can show (the mean was inf ms).
    ("seconds", "1e308", "column seconds: expected times that add up to at most 1.798e+305 s, got a "
                         "total past it at this line"),
    ("frame", "", "column frame: expected a frame number (a whole number from 0 to 2**63 - 1), got ''"),
    ("frame", "-3", "column frame: expected a frame number (a whole number from 0 to 2**63 - 1), got '-3'"),
    ("frame", "2.5", "column frame: expected a frame number (a whole number from 0 to 2**63 - 1), got '2.5'"),
    ("frame", "1_4", "column frame: expected a frame number (a whole number from 0 to 2**63 - 1), got '1_4'"),
    ("frame", "99999999999999999999999", "column frame: expected a frame number (a whole number from 0 to "
                                         "2**63 - 1), got '99999999999999999999999'"),
    ("reference_frame", "1.5", "column reference_frame: expected a frame number (a whole number; "
                               "empty for none), got '1.5'"),
])
def test_bad_frames_csv_value_is_one_line_error_naming_the_line(tmp_path, capsys, column, value,
                                                                expected):
    _write_run(tmp_path)
    _edit_frames(tmp_path, column, value, rows=[4])
    # A comment line before the header: the line named is the file's (frame 4 is on line 7).
    text = (tmp_path / "est.frames.csv").read_text()
    (tmp_path / "est.frames.csv").write_text("# run of today\n" + text)
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "eval")), capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert f"est.frames.csv: line 7: {expected}" in err
    assert not (tmp_path / "eval").exists()


def test_column_named_twice_in_frames_csv_is_one_line_error(tmp_path, capsys):
    # The later column replaced the earlier one: the times were read from whichever came last.
    _write_run(tmp_path)
    text = (tmp_path / "est.frames.csv").read_text()
    (tmp_path / "est.frames.csv").write_text(text.replace("n_inliers", "seconds", 1))
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and err == (f"ifmi evaluate: error: {tmp_path / 'est.frames.csv'}: line 1: column "
                                 "seconds given twice; expected each column once")


def test_estimate_that_is_the_ground_truth_file_is_refused(tmp_path, capsys):
    # Every error was 0 and the gate said PASS.
    _write_run(tmp_path)
    gt = tmp_path / "groundtruth.txt"
    code, err = _run_error(["evaluate", "--gt", str(gt), "--est", str(gt), "--max-rmse", "0.001"], capsys)
    assert code == 2 and err == (f"ifmi evaluate: error: {gt}: is the ground-truth file {gt} itself (every "
                                 "error would be 0); expected an estimate")
    assert "PASS" not in capsys.readouterr().out


def test_repeated_frame_in_frames_csv_is_one_line_error(tmp_path, capsys):
    _write_run(tmp_path)
    _edit_frames(tmp_path, "frame", "3", rows=[5])
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert ("est.frames.csv: frame 3 on 2 rows; expected one row per frame (reference frames are "
            "found by frame number)") in err


def test_ground_truth_of_one_pose_is_refused(tmp_path, capsys):
    # One ground-truth pose, frame 0: RMSE 0 over it whatever the estimate.
    gt, _ = _write_run(tmp_path, yaw_offset=0.5)
    write_tum(tmp_path / "groundtruth.txt", Trajectory(gt.timestamps[:1], gt.positions[:1],
                                                       gt.rotations[:1]))
    code, err = _run_error(_gate(tmp_path, "--max-rmse", "0.0001"), capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "PASS" not in capsys.readouterr().out
    assert ("groundtruth.txt: only 1 of 20 poses of est.txt have a ground-truth pose within 0.001 "
            "(expected at least 50%; --min-matched lowers the bar)") in err


def test_ground_truth_covering_under_half_of_the_estimate_is_refused(tmp_path, capsys):
    gt, _ = _write_run(tmp_path)
    (tmp_path / "est.frames.csv").unlink()
    write_tum(tmp_path / "groundtruth.txt", Trajectory(gt.timestamps[:9], gt.positions[:9],
                                                       gt.rotations[:9]))
    code, err = _run_error(_gate(tmp_path), capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "groundtruth.txt: only 9 of 20 poses of est.txt have a ground-truth pose" in err
    assert main(_gate(tmp_path, "--min-matched", "0.4")) == 0


def test_one_associated_pose_is_refused_whatever_the_bar(tmp_path, capsys):
    gt, est = _write_run(tmp_path, yaw_offset=0.5)
    (tmp_path / "est.frames.csv").unlink()
    write_tum(tmp_path / "groundtruth.txt", Trajectory(gt.timestamps[:1], gt.positions[:1],
                                                       gt.rotations[:1]))
    code, err = _run_error(_gate(tmp_path, "--min-matched", "0", "--max-rmse", "0.0001"), capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert ("groundtruth.txt: only 1 pose associated with est.txt (within 0.001); expected at "
            "least 2 (an error over one pose measures nothing)") in err


@pytest.mark.parametrize("config, expected", [
    ({"method": "orb", "dataset": 5}, "field dataset: expected a string or null, got a number 5"),
    ({"method": ["orb"]}, 'field method: expected a name (a string without / or \\) or null, got '
                          'an array ["orb"]'),
    ({"method": "../orb"}, 'field method: expected a name (a string without / or \\) or null, got '
                           'a string "../orb"'),
])
def test_config_json_field_of_the_wrong_kind_is_one_line_error(tmp_path, capsys, config, expected):
    _write_run(tmp_path)
    (tmp_path / "est.config.json").write_text(json.dumps(config))
    code, err = _run_error(_gate(tmp_path, "--out", str(tmp_path / "eval")), capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert f"est.config.json: {expected}" in err and not (tmp_path / "eval").exists()


def test_byte_order_marks_of_windows_editors_are_skipped(tmp_path, capsys):
    # Notepad and spreadsheets save UTF-8 with a byte-order mark: the files read as without one
    # (before: "line 1: non-numeric value", "missing column(s) frame; got \ufeffframe, ...").
    _write_run(tmp_path)
    argv = ["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est", str(tmp_path / "est.txt"),
            "--json"]
    assert main(argv) == 0
    plain = json.loads(capsys.readouterr().out)
    for name in ("groundtruth.txt", "est.txt", "est.frames.csv"):
        path = tmp_path / name
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["summary"] == plain["summary"]


def test_estimate_starting_later_than_the_ground_truth_is_rebased_with_a_warning(tmp_path, capsys):
    gt, _ = _write_run(tmp_path, yaw_offset=0.0)
    first = 5  # the estimate's first frames were dropped: it starts at the identity on frame 5
    later = Trajectory(gt.timestamps[first:], gt.positions[first:], gt.rotations[first].T @ gt.rotations[first:])
    write_tum(tmp_path / "later.txt", later)
    assert main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est", str(tmp_path / "later.txt"),
                 "--json", "--out", str(tmp_path / "ev")]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)["summary"]
    assert summary["geodesic"]["rmse"] < 1e-9
    warning_lines = [line for line in captured.err.splitlines() if "warning" in line]
    assert len(warning_lines) == 1
    assert "groundtruth.txt" in warning_lines[0] and "timestamp 5 is 0.1316 rad from the identity" in warning_lines[0]
    origin = json.loads((tmp_path / "ev" / "evaluation.json").read_text())["origin"]
    assert origin["timestamp"] == 5.0 and origin["estimate_angle_rad"] == 0.0


def test_ground_truth_starting_on_the_estimates_first_frame_gives_no_warning(tmp_path, capsys):
    _write_run(tmp_path)
    assert main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est", str(tmp_path / "est.txt"),
                 "--out", str(tmp_path / "ev")]) == 0
    assert "warning" not in capsys.readouterr().err


def test_default_folder_that_cannot_be_written_keeps_the_verdict(tmp_path, capsys):
    """Without --out the folder beside the estimate is a convenience: a file of the user's in its
    place is kept, the result is still printed, and a gate's exit code stays its verdict."""
    _write_run(tmp_path)  # geodesic error 0.01 rad
    blocker = tmp_path / "est.eval"
    blocker.write_text("user notes\n")
    assert main(_gate(tmp_path, "--max-rmse", "0.0100")) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("PASS")
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and str(blocker) in err[0] and "not saved" in err[0]
    assert main(_gate(tmp_path, "--max-rmse", "0.005")) == 1
    assert capsys.readouterr().out.startswith("FAIL")
    assert main(_gate(tmp_path)) == 0
    captured = capsys.readouterr()
    assert "geodesic" in captured.out and "results written" not in captured.out
    assert blocker.read_text() == "user notes\n"


@pytest.mark.parametrize("argv, line", [
    # Before: argparse's three-line usage block came first.
    (["--max-rmse", "-0.01"], "ifmi evaluate: error: argument --max-rmse: expected a number >= 0, got -0.01"),
    (["--max-rmse", "x"], "ifmi evaluate: error: argument --max-rmse: expected a number >= 0, got 'x'"),
])
def test_a_refused_option_value_is_one_line_without_the_usage_block(tmp_path, capsys, argv, line):
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "--gt", str(tmp_path / "gt.txt"), "--est", str(tmp_path / "est.txt"), *argv])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == line + "\n"


def test_a_missing_required_option_keeps_the_usage_block(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "--gt", str(tmp_path / "gt.txt")])
    err = capsys.readouterr().err.splitlines()
    assert exit_info.value.code == 2 and err[0].startswith("usage: ifmi evaluate")
    assert err[-1] == "ifmi evaluate: error: the following arguments are required: --est"
