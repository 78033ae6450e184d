"""Helpers for the hard cases: a returned solution must be finite everywhere."""
import numpy as np
import pytest


def assert_finite(sol):
    """No NaN or inf anywhere in a returned solution: samples, nodal values, steps."""
    assert np.all(np.isfinite(sol.y)), "NaN/inf in sol.y"
    assert np.all(np.isfinite(sol.values)), "NaN/inf in the nodal values"
    assert np.all(np.isfinite(sol.k)) and np.all(sol.k > 0), "bad time steps"


@pytest.fixture
def finite():
    return assert_finite
