"""DOLFIN's stiff test problems complete with dG(1), mdG(1) and mcG(1), errors checked against
the exact solution (linear problems) or a tight dG(3) solve."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode import problems

SUITE = {name: (ode, exact) for name, ode, exact in problems.stiff_suite()}
_references = {}


def reference(name):
    if name not in _references:
        ode, exact = SUITE[name]
        _references[name] = exact(ode.T) if exact else dn.solve(ode, method="dG(3)",
                                                                tolerance=1e-11)(ode.T)
    return _references[name]


@pytest.mark.parametrize("method", ["dG(1)", "mdG(1)", "mcG(1)"])
@pytest.mark.parametrize("name", list(SUITE))
def test_stiff_problem(name, method):
    ode, _ = SUITE[name]
    sol = dn.solve(ode, method=method, tolerance=1e-4)
    assert np.all(np.isfinite(sol.values))
    expected = reference(name)
    error = np.abs(sol(ode.T) - expected).max() / max(1.0, np.abs(expected).max())
    assert error < 5e-3, error
