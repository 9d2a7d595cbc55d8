"""benchmarks/bench_blas_threads.py: both limits timed, the limit restored, its table and its errors."""

from __future__ import annotations

import pytest

import ifmi.pipeline as pipeline

pytest.importorskip("skimage")
from ifmi.synthetic import example_omni_model, synthetic_sequence, write_synthetic_dataset  # noqa: E402

@pytest.fixture
def bench(benchmark_module):
    """``benchmarks/bench_blas_threads.py`` as a module."""
    return benchmark_module("bench_blas_threads")


def test_every_method_is_timed_with_both_limits_and_the_limit_comes_back(bench, tmp_path, capsys):
    model = example_omni_model(256)
    dataset = write_synthetic_dataset(tmp_path / "set", synthetic_sequence(model, 3, seed=2))
    assert bench.main([str(dataset), "--modes", "frame", "--rounds", "1", "--frames", "3"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| set | frame |")]
    assert len(rows) == len(bench.METHODS)
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        wall_default, wall_one, ratio = map(float, cells[3:6])
        assert wall_default > 0 and wall_one > 0 and ratio == pytest.approx(wall_default / wall_one, abs=0.01)
    assert pipeline.single_blas_thread is bench.LIMITS["one"]


def test_a_folder_that_is_no_dataset_is_one_error_line(bench, tmp_path, capsys):
    assert bench.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err


def test_rounds_below_one_are_refused(bench, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main([str(tmp_path), "--rounds", "0"])
    assert exc.value.code == 2 and "expected --rounds >= 1" in capsys.readouterr().err
