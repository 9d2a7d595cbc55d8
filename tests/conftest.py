"""Shared fixtures: a seeded random generator, the rotation assertion of ifmi.testing, Python's SIGINT handler."""

from __future__ import annotations

import signal

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
