"""bench_noisy_pairs: both searches run on the same set, and the engine is left as it was."""

from __future__ import annotations

import json
import math

import pytest

from ifmi.spectral.fourier_mellin import FourierMellinConfig
from ifmi.spectral.ifmi_front_end import RegistrationOptions

pytest.importorskip("skimage")
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)
from test_bench_methods import _benchmark_module  # noqa: E402


def test_phase_only_search_is_the_fraction_zero_and_the_engine_is_restored(monkeypatch):
    bench = _benchmark_module("bench_noisy_pairs", monkeypatch)
    original = RegistrationOptions.engine_config
    with bench.search("phase_only"):
        assert RegistrationOptions().engine_config().noisy_pair_fraction == 0.0
    with bench.search("default"):
        assert RegistrationOptions().engine_config().noisy_pair_fraction == FourierMellinConfig.noisy_pair_fraction
    assert RegistrationOptions.engine_config is original


def test_both_searches_are_measured_and_written(tmp_path, monkeypatch, capsys):
    model = example_omni_model(128)
    sequence = synthetic_sequence(model, 4, seed=5, max_step_rad=0.03, band_px=example_band_px(model))
    dataset = write_synthetic_dataset(tmp_path / "office", sequence)
    bench = _benchmark_module("bench_noisy_pairs", monkeypatch)
    out = tmp_path / "bench"
    assert bench.main([str(dataset), "--modes", "frame", "--rounds", "1", "--out", str(out)]) == 0
    (row,) = json.loads((out / "bench_noisy_pairs.json").read_text())["rows"]
    assert row["dataset"] == "office" and row["mode"] == "frame"
    # Steps of up to 0.03 rad on a 128 px synthetic omni image: either search stays far below a step.
    assert row["ate_phase_only"] < 0.01 and row["ate_default"] < 0.01
    assert set(row["cpu_s"]) == {"default", "phase_only"} and all(math.isfinite(v) for v in row["cpu_s"].values())
    assert (out / "default" / "frame").is_dir() and (out / "phase_only" / "frame").is_dir()
    assert "office" in capsys.readouterr().out


def test_goal_table_counts_rough_runs_against_the_better_feature_method(tmp_path, monkeypatch):
    bench = _benchmark_module("bench_noisy_pairs", monkeypatch)
    features_json = tmp_path / "bench_methods.json"
    features_json.write_text(json.dumps({"rows": [
        {"dataset": d, "mode": "frame", "method": m, "geodesic_rmse": v}
        for d, m, v in [("rough", "orb", 0.03), ("rough", "akaze", 0.012), ("other", "orb", 0.01),
                        ("other", "akaze", 0.02), ("clean", "orb", 0.01), ("clean", "akaze", 0.01)]]}))
    features = bench.feature_ates(str(features_json))
    assert features[("rough", "frame")] == (0.03, 0.012)
    rows = [{"dataset": "rough", "mode": "frame", "ate_phase_only": 0.006, "ate_default": 0.003, "same_estimates": False},
            {"dataset": "other", "mode": "frame", "ate_phase_only": 0.02, "ate_default": 0.02, "same_estimates": True},
            {"dataset": "clean", "mode": "frame", "ate_phase_only": 0.001, "ate_default": 0.001, "same_estimates": True}]
    table = bench.goal_table(rows, features, {"clean"})
    # rough: default 0.003 / 0.012 = 0.25 (<= 1/3), phase-only 0.5 (under 1x only); other: 2x; clean: not counted.
    assert "| rough | frame | 0.00600 | 0.00300 | 0.50 | 0.03000 | 0.01200 | 0.50 | 0.25 |" in table
    assert "| clean (clean) | frame |" in table and "(same)" in table
    assert ("Runs counted (not clean): 2. At or under 1/3 of the better feature method: default 1, phase-only 0. "
            "Under 1x: default 1, phase-only 1.") in table
    assert table.index("| other |") < table.index("| clean (clean) |")
