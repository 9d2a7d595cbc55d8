"""Shared fixtures: a seeded random generator and the rotation assertion of ifmi.testing."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi import testing

# Seed of the ``rng`` fixture: every test that draws random data draws the same data on each run.
RNG_SEED = 20190922


@pytest.fixture
def rng() -> np.random.Generator:
    """A NumPy generator seeded with :data:`RNG_SEED` (a fresh one per test)."""
    return np.random.default_rng(RNG_SEED)


@pytest.fixture
def assert_rotation_close():
    """:func:`ifmi.testing.assert_rotation_close`, for tests that prefer a fixture to an import."""
    return testing.assert_rotation_close
