"""Growing modes that a step spans (:mod:`dolfinode.growth`): warned, and only where the
step control misses them."""
import warnings

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.methods.method import make_method, stability_function

u, v = sp.symbols("u v")
METHODS = ["cG(1)", "dG(0)", "dG(2)", "mcG(1)", "mdG(1)"]


@pytest.mark.parametrize("method", METHODS)
def test_unstable_equilibrium_spanned_by_a_step_is_warned(method):
    # one step to T = 1 returned u = 1 where u(1) = 1 + 1e-6 exp(50) = 5e15, unwarned
    ode = dn.ODE({u: 50 * (u - 1)}, u0=[1 + 1e-6], T=1.0)
    with pytest.warns(dn.ToleranceWarning, match="growing mode .* spans the step"):
        sol = dn.solve(ode, method=method, tolerance=1e-3)
    assert abs(sol(1.0)[0] - (1 + 1e-6 * np.exp(50))) > 1e12  # (the answer is wrong)


@pytest.mark.parametrize("method", ["dG(2)", "mdG(1)"])
def test_growth_past_double_precision_says_no_step_resolves_it(method):
    # u' = 1e100 u returned u(T) = 0 with status 0
    ode = dn.ODE({u: 1e100 * u}, u0=[1.0], T=1.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dn.solve(ode, method=method, tolerance=1e-3)
    messages = [str(w.message) for w in caught if w.category is dn.ToleranceWarning]
    assert any("growing mode" in m and "no step resolves it" in m for m in messages), messages


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("rhs, u0, T", [
    ({u: 50 * u}, [1.0], 1.0),                       # the growth is the solution: resolved
    ({u: 1e100 * u}, [0.0], 1.0),                    # nothing to grow
    ({u: 1e3 * v, v: 1e3 * u}, [1.0, -0.999], 0.02),  # a saddle, resolved
    ({u: v, v: -u}, [1.0, 0.0], 20.0),               # no growing mode
])
def test_resolved_or_absent_growth_is_not_warned(method, rhs, u0, T):
    ode = dn.ODE(rhs, u0=u0, T=T)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dn.solve(ode, method=method, tolerance=1e-3)
    assert not [w for w in caught if "growing mode" in str(w.message)]


@pytest.mark.parametrize("family, q", [("cG", 1), ("cG", 3), ("dG", 0), ("dG", 2)])
@pytest.mark.parametrize("z", [-4.0, 0.5])
def test_stability_function_is_the_methods_step_map(family, q, z):
    # one fixed step of u' = z u to T = 1: U(1) = R(z) u0 (u0 < 0: R(z) may be negative,
    # which a quasi-positive system from u0 > 0 would not let U be)
    ode = dn.ODE({u: z * u}, u0=[-1.0], T=1.0)
    sol = dn.solve(ode, method=f"{family}({q})", fixed_time_step=True, initial_time_step=1.0,
                   estimate_global_error=False)
    num, den = stability_function(make_method(family, q))
    R = np.polyval(num[::-1], z) / np.polyval(den[::-1], z)
    assert sol(1.0)[0] == pytest.approx(-R, rel=1e-12)
