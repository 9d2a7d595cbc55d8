"""The translation sweep's summary counts each criterion from the runs' ATEs."""

from __future__ import annotations

import pytest


@pytest.fixture
def bench(benchmark_module):
    """``benchmarks/bench_translation.py`` as a module."""
    return benchmark_module("bench_translation")


def _runs(auto, rotation, five_point):
    return {"auto": {"ate_rad": auto}, "rotation": {"ate_rad": rotation}, "5pt": {"ate_rad": five_point}}


def _sweep(cells):
    """``{set: {(method, selection): run}}`` from ``{set: {method: (auto, rotation, 5pt)}}``."""
    return {name: {(m, s): run for m, ates in methods.items() for s, run in _runs(*ates).items()}
            for name, methods in cells.items()}


def test_summary_counts_each_criterion(bench):
    sweep = _sweep({
        # iFMI 1.6x its better forced run (counted), ORB exactly 1.5x (not: at most 1.5x passes; the
        # values are exact in binary); ORB 1.5x the reference (counted), AKAZE 1.2x (not); iFMI
        # 0.004 rad, below 0.005 and a third of the best other method's 0.25: kept.
        "floor-kb-2cm": {"ifmi": (0.004, 0.0025, 0.01), "orb": (0.375, 0.25, 0.5),
                         "akaze": (0.3, 0.3, 0.5), "reference": (0.25, 0.25, 0.5)},
        # iFMI below a third of every other method but not below 0.005 rad: not kept.
        "room-ds-5cm": {"ifmi": (0.006, 0.006, 0.007), "orb": (0.03, 0.03, 0.04),
                        "akaze": (0.03, 0.03, 0.04), "reference": (0.03, 0.03, 0.04)},
        # Not a fisheye: not counted for iFMI's margin.
        "street-ocamcalib-0cm": {"ifmi": (0.001, 0.001, 0.002), "orb": (0.01, 0.01, 0.02),
                                 "akaze": (0.01, 0.01, 0.02), "reference": (0.01, 0.01, 0.02)},
    })
    lines = bench.summary_lines(sweep, ("ifmi", "orb", "akaze", "reference"))
    assert "ifmi 1, orb 0, akaze 0, reference 0 of 3 sets each" in lines[0]
    assert "orb 1, akaze 0 of 3 sets each" in lines[1]
    assert lines[2].endswith("1 of 2 sets (floor-kb-2cm).")


def test_runs_over_ransac_seeds_combine_to_the_median(bench):
    runs = [{"ate_rad": ate, "pairs": 11, "rotation": rot, "5pt": 11 - rot, "failed": 0}
            for ate, rot in ((0.004, 2), (0.001, 0), (0.009, 5))]
    combined = bench.combined_runs(runs)
    assert combined["ate_rad"] == 0.004 and combined["ate_runs"] == [0.004, 0.001, 0.009]
    assert (combined["pairs"], combined["rotation"], combined["5pt"], combined["failed"]) == (33, 7, 26, 0)
    sweep = {"room-kb-5cm": {("orb", s): combined for s in bench.SELECTIONS}}
    line, = bench.seed_spread_line(sweep, ("orb",))
    assert "median 9.00" in line and "over 3 runs" in line  # 0.009 / 0.001 for each of the 3 selections
    one_seed = {"room-kb-5cm": {("orb", s): bench.combined_runs(runs[:1]) for s in bench.SELECTIONS}}
    assert bench.seed_spread_line(one_seed, ("orb",)) == []


def test_seed_zero_keeps_the_file_name_of_a_one_seed_sweep(bench, tmp_path):
    assert bench.run_path(tmp_path, "orb", "auto", 0).name == "result-orb-auto.json"
    assert bench.run_path(tmp_path, "orb", "5pt", 3).name == "result-orb-5pt-seed3.json"
