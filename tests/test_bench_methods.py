"""The benchmarks: bench_methods keeps datasets of one name apart; bench_versions compares two source trees."""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("skimage")
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)

BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_methods.py"


def _benchmark_module(name="bench_methods", monkeypatch=None):
    """Load ``benchmarks/NAME.py`` with its folder importable (for :mod:`benchlib`)."""
    if monkeypatch is not None:
        monkeypatch.syspath_prepend(str(BENCHMARK.parent))
    elif str(BENCHMARK.parent) not in sys.path:
        sys.path.append(str(BENCHMARK.parent))
    spec = importlib.util.spec_from_file_location(name, BENCHMARK.parent / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    if monkeypatch is not None:  # dataclasses look their module up in sys.modules
        monkeypatch.setitem(sys.modules, name, module)
    spec.loader.exec_module(module)
    return module


def _write_dataset(folder, *, seed, max_step_rad):
    model = example_omni_model(128)
    sequence = synthetic_sequence(model, 4, seed=seed, max_step_rad=max_step_rad,
                                  band_px=example_band_px(model))
    return write_synthetic_dataset(folder, sequence)


@pytest.mark.slow
def test_two_datasets_of_one_name_get_their_own_rows_and_folders(tmp_path, capsys):
    a = _write_dataset(tmp_path / "site_a" / "office", seed=5, max_step_rad=0.03)
    b = _write_dataset(tmp_path / "site_b" / "office", seed=6, max_step_rad=0.06)
    out = tmp_path / "bench"
    bench = _benchmark_module()
    # The first folder twice (once through a "..") is measured once.
    again = a.parent / ".." / "site_a" / "office"
    assert bench.main([str(a), str(b), str(again), "--methods", "ifmi", "--modes", "frame",
                       "--timing-rounds", "0", "--out", str(out)]) == 0
    rows = json.loads((out / "bench_methods.json").read_text())["rows"]
    assert [r["dataset"] for r in rows] == ["site_a/office", "site_b/office"]
    assert [r["dataset_path"] for r in rows] == [str(a.resolve()), str(b.resolve())]
    folders = [out / "frame" / r["dataset_id"] for r in rows]
    assert folders[0] != folders[1]
    assert all(f.name.startswith("office-") for f in folders)
    for folder, dataset in zip(folders, (a, b)):
        evaluation = json.loads((folder / "ifmi.eval" / "evaluation.json").read_text())
        assert Path(evaluation["groundtruth_path"]) == (dataset / "groundtruth.txt").resolve()
    # Each row holds its own dataset's numbers: the second sequence turns twice as fast.
    assert rows[0]["geodesic_rmse"] != rows[1]["geodesic_rmse"]
    printed = capsys.readouterr().out
    assert "site_a/office" in printed and "site_b/office" in printed


@pytest.mark.slow
@pytest.mark.parametrize("short", ["images", "groundtruth"])
def test_a_set_too_short_to_evaluate_is_refused_before_any_set_is_measured(tmp_path, capsys, short):
    # One frame or one ground-truth pose measures nothing: refused before the other sets' (possibly
    # long) runs, not at that set's evaluation.
    good = _write_dataset(tmp_path / "good", seed=5, max_step_rad=0.03)
    bad = _write_dataset(tmp_path / "bad", seed=6, max_step_rad=0.03)
    if short == "images":
        for image in sorted((bad / "images").iterdir())[1:]:
            image.unlink()
    else:
        lines = (bad / "groundtruth.txt").read_text().splitlines(keepends=True)
        (bad / "groundtruth.txt").write_text("".join(line for line in lines if line.startswith("#"))
                                             + next(line for line in lines if not line.startswith("#")))
    out = tmp_path / "bench"
    assert _benchmark_module().main([str(good), str(bad), "--methods", "ifmi", "--modes", "frame",
                                     "--timing-rounds", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs at least 2" in err and str(bad) in err
    assert not out.exists()


def test_a_file_instead_of_a_dataset_folder_is_a_one_line_error(tmp_path, capsys):
    not_a_folder = tmp_path / "groundtruth.txt"
    not_a_folder.write_text("0 0 0 0 0 0 0 1\n")
    out = tmp_path / "bench"
    assert _benchmark_module().main([str(not_a_folder), "--methods", "ifmi", "--modes", "frame",
                                     "--timing-rounds", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert str(not_a_folder) in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow
def test_a_kalibr_camera_dataset_is_benchmarked(tmp_path):
    """A camera.yaml dataset (a fisheye sequence from omnisim warp) runs through the benchmark."""
    import cv2
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import write_kalibr
    from ifmi.synthetic import environment_texture, omni_from_environment
    from omnisim.warp import WarpSettings, warp_dataset

    model = EXAMPLES["kb"].scaled(0.5)
    grid = np.stack(np.mgrid[0:model.height, 0:model.width], axis=-1).astype(np.float64)
    image = omni_from_environment(environment_texture(height=256, seed=4), model, np.eye(3))
    image[~model.valid_pixels(grid)] = 0
    cv2.imwrite(str(tmp_path / "fisheye.png"), image)
    write_kalibr(tmp_path / "camera.yaml", model)
    dataset = tmp_path / "fisheye_warp"
    warp_dataset(tmp_path / "fisheye.png", tmp_path / "camera.yaml", dataset, progress=False,
                 settings=WarpSettings(frames=5, seed=2, max_step_deg=4.0, max_tilt_deg=3.0))
    out = tmp_path / "bench"
    assert _benchmark_module().main([str(dataset), "--methods", "ifmi", "--modes", "frame",
                                     "--timing-rounds", "0", "--out", str(out)]) == 0
    (row,) = json.loads((out / "bench_methods.json").read_text())["rows"]
    # Steps of up to 4 degrees on a 256 px fisheye: measured 1.5e-4 rad; a failed or wrong
    # pair would leave an error of the order of the step (0.07 rad).
    assert row["failures"] == 0 and row["geodesic_rmse"] < 2e-3, row


@pytest.mark.slow
def test_options_benchmark_names_same_named_sets_apart_and_compares_a_variant(tmp_path, monkeypatch):
    options = _benchmark_module("bench_ifmi_options", monkeypatch)
    a = _write_dataset(tmp_path / "site_a" / "office", seed=5, max_step_rad=0.03)
    b = _write_dataset(tmp_path / "site_b" / "office", seed=6, max_step_rad=0.06)
    out = tmp_path / "options"
    assert options.main([str(a), str(b), "--variant", "affine:tracking.use_prior=false", "--rounds", "1",
                         "--out", str(out)]) == 0
    rows = json.loads((out / "bench_ifmi_options.json").read_text())["rows"]
    assert [(r["dataset"], r["variant"]) for r in rows] == [("site_a/office", "affine"),
                                                            ("site_b/office", "affine")]
    assert all(r["cpu_default_s"] > 0 and r["cpu_variant_s"] > 0 for r in rows)
    assert rows[0]["ate_default"] != rows[1]["ate_default"]


@pytest.mark.slow
def test_versions_benchmark_finds_one_tree_bit_identical_to_itself(tmp_path, capsys):
    versions = _benchmark_module("bench_versions")
    data = _write_dataset(tmp_path / "office", seed=7, max_step_rad=0.03)
    tree = str(BENCHMARK.parents[1])
    out = tmp_path / "versions.json"
    assert versions.main([tree, tree, "--sets", str(data), "--frames", "3", "--rounds", "1", "--out", str(out)]) == 0
    row = json.loads(out.read_text())["sets"][str(data)]
    assert row["max_rotation_difference"] == 0.0
    assert 0 < row[tree]["ate"] < 0.05 and row[tree]["thread_ms"] > 0
    assert "office" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        versions.main([tree, "--sets", str(data)])
    assert versions._largest_difference([np.eye(3)], [np.eye(3) * 0.5]) == 0.5


@pytest.mark.slow
def test_versions_benchmark_missing_set_is_a_one_line_error(tmp_path, capsys):
    missing = tmp_path / "no_such_set"
    versions = _benchmark_module("bench_versions")
    tree = str(BENCHMARK.parents[1])
    assert versions.main([tree, tree, "--sets", str(missing), "--rounds", "1"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {missing}: dataset folder not found\n"


def test_options_benchmark_summary_over_the_sets_with_a_retry(monkeypatch):
    options = _benchmark_module("bench_ifmi_options", monkeypatch)

    def row(variant, ate_default, ate_variant, retries, failures=(0, 0), cpu=(1.0, 1.0)):
        return {"variant": variant, "ate_default": ate_default, "ate_variant": ate_variant,
                "retry_frames_default": retries[0], "retry_frames_variant": retries[1],
                "failures_default": failures[0], "failures_variant": failures[1],
                "cpu_default_s": cpu[0], "cpu_variant_s": cpu[1]}

    rows = [row("few", 0.01, 0.02, (2, 2), cpu=(1.0, 0.8)), row("few", 0.04, 0.01, (1, 3), (0, 1), (2.0, 1.0)),
            row("few", 0.02, 0.0201, (0, 1)), row("few", 0.5, 0.1, (0, 0)),  # no retry: left out
            row("none", 0.01, 0.02, (0, 0))]
    summary = options.variant_summary(rows)
    assert list(summary) == ["few"]
    few = summary["few"]
    assert few["sets"] == 3 and few["worse"] == 1 and few["better"] == 1
    assert np.isclose(few["ate_ratio_geomean"], (2.0 * 0.25 * 1.005) ** (1 / 3))
    assert np.isclose(few["ate_median_default"], 0.02) and np.isclose(few["ate_median_variant"], 0.02)
    assert (few["failures_default"], few["failures_variant"]) == (0, 1)
    assert np.isclose(few["cpu_ratio_median"], 0.8)


def test_options_benchmark_variant_sets_back_end_options_and_names_unknown_ones(monkeypatch):
    options = _benchmark_module("bench_ifmi_options", monkeypatch)
    from ifmi.pipeline import EstimateConfig
    base = EstimateConfig()
    changed = options.estimate_variant(base, {"relative_pose.robust_scale": 2.0,
                                              "recovery.dense_retry_fraction": 0.0})
    assert changed.relative_pose.robust_scale == 2.0
    assert changed.ifmi.recovery.dense_retry_fraction == 0.0
    assert changed.relative_pose.seed == base.relative_pose.seed
    with pytest.raises(ValueError, match="relative_pose"):
        options.estimate_variant(base, {"relative_pose.no_such_option": 1})


def test_config_file_reaches_every_method_and_a_bad_one_is_a_one_line_error(tmp_path, capsys):
    dataset = _write_dataset(tmp_path / "office", seed=5, max_step_rad=0.03)
    config = tmp_path / "akaze300.json"
    config.write_text(json.dumps({"features": {"akaze_min_keypoints": 300}}))
    out = tmp_path / "bench"
    bench = _benchmark_module()
    assert bench.main([str(dataset), "--methods", "ifmi", "akaze", "--modes", "frame", "--timing-rounds", "0",
                       "--config", str(config), "--out", str(out)]) == 0
    (folder,) = (out / "frame").iterdir()
    for method in ("ifmi", "akaze"):
        saved = json.loads((folder / f"{method}.config.json").read_text())["config"]
        assert saved["features"]["akaze_min_keypoints"] == 300
    config.write_text(json.dumps({"features": {"akaze_min_keypoints": -1}}))
    capsys.readouterr()
    assert bench.main([str(dataset), "--methods", "akaze", "--timing-rounds", "0", "--config", str(config),
                       "--out", str(tmp_path / "bench2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(config) in err and "akaze_min_keypoints must be >= 0, got -1" in err


def test_bench_seeds_runs_each_seed_and_summarises_over_them(tmp_path, capsys, monkeypatch):
    dataset = _write_dataset(tmp_path / "office", seed=5, max_step_rad=0.03)
    out = tmp_path / "seeds"
    bench = _benchmark_module("bench_seeds", monkeypatch)
    assert bench.main([str(dataset), "--seeds", "0", "3", "--methods", "ifmi", "orb", "--modes", "frame",
                       "--out", str(out)]) == 0
    result = json.loads((out / "bench_seeds.json").read_text())
    rows = result["rows"]
    assert [(r["seed"], r["method"]) for r in rows] == [(0, "ifmi"), (0, "orb"), (3, "ifmi"), (3, "orb")]
    # Each seed's runs reached the back end with that seed.
    for seed in (0, 3):
        saved = json.loads((out / f"seed{seed}" / "frame" / rows[0]["dataset_id"] / "ifmi.config.json").read_text())
        assert saved["config"]["relative_pose"]["seed"] == seed
    for entry in result["summary"]:
        ates = [r["geodesic_rmse"] for r in rows if r["method"] == entry["method"]]
        assert entry["ates"] == ates and entry["seeds"] == [0, 3]
        assert entry["median"] == pytest.approx(np.median(ates))
        assert entry["spread"] == pytest.approx(max(ates) / min(ates))
    assert "1 sets with seed 3" in capsys.readouterr().out


def test_bench_seeds_counts_misses_per_seed_and_on_medians(monkeypatch):
    bench = _benchmark_module("bench_seeds", monkeypatch)
    spread = bench.SeedSpread
    spreads = [spread("frame", "lawn", "ifmi", (0, 1), (1.0, 3.0), (0, 0)),
               spread("frame", "lawn", "orb", (0, 1), (2.0, 2.0), (0, 0)),
               spread("frame", "lawn", "akaze", (0, 1), (4.0, 1.0), (0, 0)),
               # A failed frame is a miss whatever the ATE.
               spread("frame", "urban", "ifmi", (0, 1), (1.0, 1.0), (1, 0)),
               spread("frame", "urban", "orb", (0, 1), (5.0, 5.0), (0, 0))]
    per_seed, on_medians, compared = bench.ifmi_misses(spreads, "frame")
    # lawn: seed 0 1 <= 2, seed 1 3 > 1; medians 2 <= min(2, 2.5). urban: seed 0 failed a frame.
    assert (per_seed, on_medians, compared) == ([1, 1], 0, 2)


@pytest.mark.parametrize("seeds", [["-1"], ["2", "2"]])
def test_bench_seeds_refuses_negative_or_repeated_seeds(tmp_path, capsys, monkeypatch, seeds):
    bench = _benchmark_module("bench_seeds", monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        bench.main([str(tmp_path), "--seeds", *seeds, "--out", str(tmp_path / "out")])
    assert exit_info.value.code == 2
    assert "--seeds: expected distinct integers >= 0" in capsys.readouterr().err


def test_bench_uncertainty_takes_each_pairs_error_from_its_own_reference_frame(tmp_path, monkeypatch):
    from scipy.spatial.transform import Rotation

    from ifmi.io.tum import write_tum
    from ifmi.geometry.trajectory import Trajectory

    module = _benchmark_module("bench_uncertainty", monkeypatch)
    stamps = np.arange(4.0)
    gt_rot = Rotation.from_rotvec([[0, 0, 0], [0, 0, 0.1], [0, 0, 0.2], [0, 0, 0.3]]).as_matrix()
    # Estimate: frame 1 off by 0.01 rad about x; frames 2 and 3 estimated against frame 1 (a
    # keyframe) and each 0.002 rad off about y from it; frame 3 failed (pose held, not counted).
    off_1 = Rotation.from_rotvec([0.01, 0, 0]).as_matrix()
    est_rot = gt_rot.copy()
    est_rot[1] = gt_rot[1] @ off_1
    est_rot[2] = est_rot[1] @ gt_rot[1].T @ gt_rot[2] @ Rotation.from_rotvec([0, 0.002, 0]).as_matrix()
    est_rot[3] = est_rot[2]
    zeros = np.zeros((4, 3))
    write_tum(tmp_path / "gt.txt", Trajectory(stamps, zeros, gt_rot))
    write_tum(tmp_path / "est.txt", Trajectory(stamps, zeros, est_rot))
    (tmp_path / "est.frames.csv").write_text(
        "frame,reference_frame,success,seconds,model,rotation_sigma_rad\n0,0,true,0.1,,\n"
        "1,0,true,0.1,rotation,0.005\n2,1,true,0.1,5pt,0.004\n3,1,false,0.1,,\n")
    pairs = module.pair_errors_of_run(tmp_path / "est.txt", tmp_path / "est.frames.csv", tmp_path / "gt.txt",
                                      method="ifmi", mode="keyframe")
    assert pairs.models == ("rotation", "5pt")
    assert np.allclose(pairs.true_rad, [0.01, 0.002], atol=1e-9)
    assert np.allclose(pairs.predicted_rad, [0.005, 0.004])
    by_model = {s.model: s for s in module.calibration_summaries([pairs])}
    assert by_model["all"].pairs == 2 and np.isclose(by_model["all"].z_median, (2.0 + 0.5) / 2)
    assert by_model["rotation"].share_far == 0.0 and np.isclose(by_model["5pt"].z_p99, 0.5)


def test_bundle_window_comparison_counts_ratios_and_misses(tmp_path, monkeypatch):
    module = _benchmark_module("bench_bundle_window", monkeypatch)

    def runs(path, ates):
        rows = [{"mode": "frame", "dataset": dataset, "method": method, "seed": seed, "geodesic_rmse": ate}
                for (dataset, method), per_seed in ates.items() for seed, ate in enumerate(per_seed)]
        path.write_text(json.dumps({"rows": rows}))
        return str(path)

    # lawn_trans_x3: iFMI halves and stays above AKAZE before, falls below it after;
    # office_x5: iFMI doubles, still the best.
    before = runs(tmp_path / "a.json", {("lawn_trans_x3", "ifmi"): [0.02, 0.04, 0.03],
                                        ("lawn_trans_x3", "orb"): [0.05] * 3, ("lawn_trans_x3", "akaze"): [0.02] * 3,
                                        ("office_x5", "ifmi"): [0.001] * 3, ("office_x5", "orb"): [0.01] * 3,
                                        ("office_x5", "akaze"): [0.01] * 3})
    after = runs(tmp_path / "b.json", {("lawn_trans_x3", "ifmi"): [0.015, 0.01, 0.02],
                                       ("lawn_trans_x3", "orb"): [0.05] * 3, ("lawn_trans_x3", "akaze"): [0.02] * 3,
                                       ("office_x5", "ifmi"): [0.002] * 3, ("office_x5", "orb"): [0.01] * 3,
                                       ("office_x5", "akaze"): [0.01] * 3})
    result = module.compare(before, after)
    translated = result["changes"][("frame", "translated", "designed")]["ifmi"]
    assert translated.geometric_mean_ratio == pytest.approx(0.5) and (translated.lower, translated.higher) == (1, 0)
    rotation = result["changes"][("frame", "rotation only", "designed")]["ifmi"]
    assert rotation.geometric_mean_ratio == pytest.approx(2.0) and rotation.higher == 1
    assert result["misses"][("frame", "translated", "designed")] == [1, 1, 0]
    assert result["misses"][("frame", "rotation only", "designed")] == [1, 0, 0]


def test_perturbed_copy_moves_each_sample_by_at_most_one_level_and_repeats_with_its_seed(tmp_path, capsys):
    from ifmi.io.dataset import read_dataset
    from ifmi.io.images import read_image

    perturb = _benchmark_module("perturb_dataset")
    source = _write_dataset(tmp_path / "source", seed=3, max_step_rad=0.05)
    assert perturb.main([str(source), str(tmp_path / "a"), "--seed", "1"]) == 0
    assert perturb.main([str(source), str(tmp_path / "b"), "--seed", "1"]) == 0
    originals, copies = read_dataset(source), read_dataset(tmp_path / "a")
    assert copies.frame_indices == originals.frame_indices
    assert (tmp_path / "a" / "groundtruth.txt").read_bytes() == originals.groundtruth_path.read_bytes()
    steps = np.concatenate([(read_image(c, gray=False).astype(int) - read_image(o, gray=False)).ravel()
                            for c, o in zip(copies.image_paths, originals.image_paths)])
    assert set(np.unique(steps)) <= {-1, 0, 1} and np.count_nonzero(steps) > steps.size // 2
    # The same seed, the same copy.
    assert [p.read_bytes() for p in sorted((tmp_path / "b" / "images").iterdir())] == \
        [p.read_bytes() for p in sorted((tmp_path / "a" / "images").iterdir())]
    capsys.readouterr()
    assert perturb.main([str(source), str(tmp_path / "a"), "--seed", "1"]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path / 'a'}: output folder exists; choose a new one\n"


