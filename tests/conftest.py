"""Shared test set-up: importing brdffit turns on JAX's float64 mode before any test builds an array."""

import numpy as np
import pytest

import brdffit  # noqa: F401  (enables jax_enable_x64)


@pytest.fixture
def rng():
    """A seeded NumPy generator, so that random test inputs are the same on every run."""
    return np.random.default_rng(20240607)
