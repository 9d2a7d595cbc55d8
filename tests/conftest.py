"""Shared fixtures: a seeded random generator, the rotation assertion of ifmi.testing, Python's SIGINT handler,
the benchmark scripts as modules."""

from __future__ import annotations

import importlib.util
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from ifmi import testing

# Seed of the ``rng`` fixture: every test that draws random data draws the same data on each run.
RNG_SEED = 20190922


def pytest_collection_modifyitems(config, items):
    """Every render test is slow too: Mitsuba compiles its kernels on the first render of a process."""
    for item in items:
        if item.get_closest_marker("render") is not None:
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def rng() -> np.random.Generator:
    """A NumPy generator seeded with :data:`RNG_SEED` (a fresh one per test)."""
    return np.random.default_rng(RNG_SEED)


@pytest.fixture
def assert_rotation_close():
    """:func:`ifmi.testing.assert_rotation_close`, for tests that prefer a fixture to an import."""
    return testing.assert_rotation_close


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler for the test, whatever the runner was started with (a background
    job of a script starts with SIGINT ignored, and the command lines then leave it so)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


# The benchmark scripts, run as ``python benchmarks/NAME.py`` (their folder then on the path).
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def benchmark_module(monkeypatch):
    """Load ``benchmarks/NAME.py`` as the module ``NAME``: its folder importable (for ``benchlib``)
    and the module in ``sys.modules`` (dataclasses look their module up) for the test's duration."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, name, module)
        spec.loader.exec_module(module)
        return module

    return load
