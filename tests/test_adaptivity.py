"""The tolerance means the error at T: calibrated step tolerances (dolfinode.adaptivity)."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.adaptivity import DELIVERED, MAX_STEP_TOLERANCE, step_tolerance
from dolfinode.bench import problems
from dolfinode.methods import make_method

PROBLEMS = {"HIRES": problems.hires_problem, "VDPOL": problems.vdpol,
            "harmonic": problems.harmonic_problem}


def scaled_error(problem, method, tolerance):
    """The Test Set's scaled error at T, max |U(T) - u(T)| / (atol_ratio + |u(T)|)."""
    sol = dn.solve(problem.ode, method=method, tolerance=tolerance, calibrate_tolerance=True,
                   absolute_tolerance=problem.atol_ratio * tolerance)
    return np.max(np.abs(sol(problem.T) - problem.final)
                  / (problem.atol_ratio + np.abs(problem.final)))


@pytest.mark.parametrize("name", PROBLEMS)
@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "dG(2)"])
def test_delivered_error_within_ten_times_the_tolerance_and_monotone(name, method):
    problem = PROBLEMS[name]()
    errors = [scaled_error(problem, method, tolerance) for tolerance in (1e-3, 1e-5)]
    for error, tolerance in zip(errors, (1e-3, 1e-5)):
        assert 0.1 * tolerance <= error <= 10 * tolerance
    assert errors[1] < errors[0]


def test_step_tolerance_is_monotone_bounded_and_identity_where_not_calibrated():
    tolerances = 10.0 ** -np.arange(2, 13)
    for family, q in DELIVERED:
        step = [step_tolerance(make_method(family, q), tol) for tol in tolerances]
        assert np.all(np.diff(step) <= 0) and step[-1] < step[-2]
        assert np.all(np.asarray(step) >= tolerances)
        assert max(step) <= MAX_STEP_TOLERANCE
    for family, q in (("cG", 1), ("dG", 0), ("cG", 5)):
        assert step_tolerance(make_method(family, q), 1e-6) == 1e-6
