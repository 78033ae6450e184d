"""The seed model of automatic modeling, solved in full (no automatic modeling), against its
closed form x2 = cos(w t), x1 = (1 - cos t)/4 + A (cos 2wt - cos t), w = sqrt(kappa)."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench import problems as P

# The error at tolerance 1e-6 used to grow with kappa (2.5e-3 to 0.17 at kappa 1e6) while the
# step indicator k^p |R| ignored the time scale 1/sqrt(kappa); the local error estimate
# (I - gamma k J)^{-1} k R of dolfinode.adaptivity is a change in u at every time scale.


@pytest.mark.parametrize("kappa, T, bound", [
    (1e2, 10.0, 1e-4),
    (1e4, 10.0, 1e-4),
    (1e6, 1.0, 1e-4),
])
@pytest.mark.parametrize("method", ["cG(2)", "dG(2)"])
def test_seed_model_matches_the_closed_form(kappa, T, bound, method, finite):
    p = P.seed_model(kappa, T=T)
    sol = dn.solve(p.ode, method=method, tolerance=1e-6)
    finite(sol)
    err = np.abs(sol.y - p.exact(sol.t))
    assert err[:2].max() <= bound                       # positions
    assert err[2:].max() <= bound * np.sqrt(kappa)      # velocities scale with w


@pytest.mark.parametrize("kappa", [1e2, 1e4, 1e6])
def test_seed_model_converges_with_fixed_steps(kappa, finite):
    """Uniform steps resolving the fast period (k = period / 200) with cG(2): the closed form
    and the discretisation agree, so the reference itself is right at every kappa."""
    p = P.seed_model(kappa, T=1.0)
    k = 2 * np.pi / np.sqrt(kappa) / 200
    sol = dn.solve(p.ode, method="cG(2)", fixed_time_step=True, initial_time_step=k)
    finite(sol)
    assert np.abs(sol.y[:2] - p.exact(sol.t)[:2]).max() < 1e-5
