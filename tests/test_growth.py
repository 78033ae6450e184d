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


@pytest.mark.parametrize("rhs, T", [(sp.Max(1, 3 * u - 2), 1.5),
                                     (1 + 60 * sp.Heaviside(u - 1) * (u - 1), 1.3)])
def test_each_step_is_checked_on_its_own_branch(rhs, T):
    # the Jacobian of the smooth f holds the last piece's branch: rate 3 (60) was warned
    # at t = 0.15, where u < 1 and J = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dn.solve(dn.ODE({u: rhs}, u0=[0.0], T=T), method="dG(2)", tolerance=1e-6)
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


def _coupled(rates, seed=0):
    """u' = A (u - 1), A = S diag(rates) S^-1 with a fixed well-conditioned S: its modes
    coupled in every component, from 1 + 1e-6 (near the equilibrium: one step may span)."""
    names = sp.symbols(f"x0:{len(rates)}")
    S = np.eye(len(rates)) + 0.3 * np.random.default_rng(seed).standard_normal((len(rates),) * 2)
    A = S @ np.diag(rates) @ np.linalg.inv(S)
    rhs = {x: sum(float(a) * (y - 1) for a, y in zip(row, names)) for x, row in zip(names, A)}
    return dn.ODE(rhs, u0=[1 + 1e-6] * len(rates), T=1.0)


@pytest.mark.parametrize("method", ["dG(2)", "cG(1)", "mdG(1)"])
@pytest.mark.parametrize("ode", [
    # a growing mode among stiff decaying ones (8 components, HIRES-like rates)
    _coupled([-1e4, -3e3, -1e3, -300.0, -40.0, -10.0, -1.0, 50.0]),
    # a rotation that grows: z complex (u - 1, v - 1) turns at 30 and grows at 50
    dn.ODE({u: 50 * (u - 1) - 30 * (v - 1), v: 30 * (u - 1) + 50 * (v - 1)},
           u0=[1 + 1e-6, 1.0], T=1.0),
], ids=["stiff-coupled", "rotation"])
def test_growing_mode_among_others_is_warned(method, ode):
    with pytest.warns(dn.ToleranceWarning, match="growing mode .* spans the step"):
        dn.solve(ode, method=method, tolerance=1e-3)


def test_decaying_stiff_steps_are_certified_without_decomposition(monkeypatch):
    # VDPOL at mu = 1e3: Gershgorin's bound of Re z passes SPANNED on most steps (J_21 ~ 1e6)
    # and no mode grows; 8 of those steps were eigen-decomposed at every check
    from dolfinode import growth
    bounds, decomposed = [], []
    gershgorin = growth._gershgorin
    monkeypatch.setattr(growth, "_gershgorin", lambda *a: bounds.append(gershgorin(*a))
                        or bounds[-1])
    monkeypatch.setattr(growth, "_missed", lambda *a: decomposed.append(a) or None)
    y1, y2 = sp.symbols("y1 y2")
    ode = dn.ODE({y1: y2, y2: 1e3 * ((1 - y1**2) * y2 - y1)}, u0=[2.0, 0.0], T=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dn.solve(ode, method="dG(3)", tolerance=1e-6)
    assert np.sum(np.concatenate(bounds) > growth.SPANNED) > 10  # (the check ran)
    assert not decomposed


def test_certificate_passes_no_matrix_with_a_growing_mode():
    # random Z near a decomposed one, stiff rates and complex pairs around Re z = SPANNED: a
    # certified Z (with and without the basis) has no eigenvalue with Re z > SPANNED
    from dolfinode import growth
    rng, N = np.random.default_rng(1), 6
    indptr, indices = np.arange(0, N * N + 1, N), np.tile(np.arange(N), N)
    certified = growing = 0
    for _ in range(400):
        rates = -(10.0 ** rng.uniform(-1, 4, N)) + 1j * rng.choice(2, N) * rng.uniform(0, 5, N)
        rates[0] = rng.uniform(0, 2 * growth.SPANNED)
        rates = np.concatenate([rates[: N // 2], np.conj(rates[: N // 2])])
        S = np.eye(N) + 0.5 * rng.standard_normal((N, N))
        reference = np.real(S @ np.diag(rates) @ np.linalg.inv(S))
        Z = reference * (1 + 10.0 ** rng.uniform(-6, -1) * rng.standard_normal((N, N)))
        V = np.linalg.eig(reference)[1].astype(complex)
        for basis in [(V, np.linalg.inv(V)), growth.NO_BASIS]:
            passed = growth._certified(Z.reshape(1, -1), indptr, indices, np.ones((1, N)),
                                       np.zeros(1, dtype=np.int64), *basis, np.empty((N, N)))
            certified += passed
            exceeds = np.max(np.linalg.eigvals(Z).real) > growth.SPANNED
            growing += exceeds
            assert not (passed and exceeds)
    assert certified > 100 and growing > 100


def _coupled_with_rate(rates, a):
    """:func:`_coupled` with a last rate given by the parameter ``a``: A = A_0 + a s w^T
    (s, w: the last column of S, the last row of S^-1)."""
    S = np.eye(len(rates) + 1) + 0.3 * np.random.default_rng(0).standard_normal(
        (len(rates) + 1,) * 2)
    W = np.linalg.inv(S)
    A = S @ np.diag([*rates, 0.0]) @ W
    names = sp.symbols(f"x0:{len(rates) + 1}")
    mode = sum(float(w) * (y - 1) for w, y in zip(W[-1], names))
    rhs = {x: sum(float(c) * (y - 1) for c, y in zip(row, names)) + a * float(s) * mode
           for x, row, s in zip(names, A, S[:, -1])}
    return dn.ODE(rhs, u0=[1 + 1e-6] * (len(rates) + 1), T=1.0, params={a: -1.0})


def _counting(monkeypatch):
    """Count the growth check's decompositions, its certificates begun from a basis, and
    the steps they certified."""
    from dolfinode import growth
    counts = {"decomposed": 0, "from a basis": 0, "by a basis": 0}
    basis, certified = growth._basis, growth._certified

    def counted_basis(Z):
        counts["decomposed"] += 1
        return basis(Z)

    def counted_certified(*args):
        passed = certified(*args)
        counts["from a basis"] += args[5].size > 0 and args[4].size > 0
        counts["by a basis"] += passed * (args[5].size > 0)
        return passed

    monkeypatch.setattr(growth, "_basis", counted_basis)
    monkeypatch.setattr(growth, "_certified", counted_certified)
    return counts


RATES = [-1e4, -3e3, -1e3, -300.0, -40.0, -10.0, -1.0]


def _solved_once(monkeypatch):
    """(a, a Solver of :func:`_coupled_with_rate` by dG(2), :func:`_counting`'s counts) after
    its first solve, which decomposed a step (one step to T: J constant, Z = J)."""
    a = sp.Symbol("a")
    counts = _counting(monkeypatch)
    solver = dn.Solver(_coupled_with_rate(RATES, a), method="dG(2)", tolerance=1e-3,
                       estimate_global_error=True)
    solver.solve()
    assert counts["decomposed"] >= 1
    return a, solver, counts


def test_second_check_of_a_system_starts_from_its_kept_basis(monkeypatch):
    # the check decomposed the first step its plain bound did not certify in every solve
    _, solver, counts = _solved_once(monkeypatch)
    counts.update({"decomposed": 0, "by a basis": 0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (no growing mode: nothing to warn)
        solver.solve(u0=[1 + 2e-6] * 8)
    assert counts["decomposed"] == 0 and counts["by a basis"] >= 1


def test_kept_basis_of_other_parameters_certifies_no_growing_step(monkeypatch):
    # the basis kept from a = -1 (every mode decaying) meets the steps of a = 50
    a, solver, counts = _solved_once(monkeypatch)
    counts["from a basis"] = 0
    with pytest.warns(dn.ToleranceWarning, match="growing mode .* spans the step"):
        solver.solve(params={a: 50.0})
    assert counts["from a basis"] >= 1


@pytest.mark.parametrize("method", METHODS)
def test_prepared_solve_of_one_step_is_checked(method):
    # Solver.solve of one step skipped the checks at T: u(1) = 1 for 5e15, unwarned
    ode = dn.ODE({u: 50 * (u - 1)}, u0=[1 + 1e-6], T=1.0)
    solver = dn.Solver(ode, method=method, tolerance=1e-3)
    for u0 in ([1 + 1e-6], [1 - 1e-6]):  # (the second call: the prepared path's values)
        with pytest.warns(dn.ToleranceWarning, match="growing mode .* spans the step"):
            sol = solver.solve(u0=u0)
        assert sol.stats["time slabs"] == 1


def test_prepared_solve_unchecked_at_T_is_not_warned():
    # estimate_global_error=False skips the checks at T, as in dn.solve: the prepared call's
    # compiled growth test too
    ode = dn.ODE({u: 50 * (u - 1)}, u0=[1 + 1e-6], T=1.0)
    solver = dn.Solver(ode, method="dG(2)", tolerance=1e-3, estimate_global_error=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for u0 in ([1 + 1e-6], [1 - 1e-6]):
            assert solver.solve(u0=u0).stats["time slabs"] == 1


@pytest.mark.parametrize("method", ["mcG(2)", "mdG(1)"])
def test_multi_adaptive_check_reads_no_dense_value(method, monkeypatch):
    # the check read U between other components' steps by sol(t), whose dense value reads
    # f: its kernels (~6 s with empty caches) compiled with every first mcG(q) solve
    from dolfinode import growth, solution
    states, steps = [], growth._steps

    def recorded(sol):
        states.append(steps(sol))
        return states[-1]

    monkeypatch.setattr(growth, "_steps", recorded)
    monkeypatch.setattr(solution, "correct_multi", lambda *a, **k: pytest.fail("dense value"))
    ode = dn.ODE({u: v, v: -u - 10 * (1 + u**2) * v}, u0=[1.0, 0.0], T=3.0)
    sol = dn.solve(ode, method=method, tolerance=1e-6)
    times, _, state = states[0]
    # (a component's elements hold other components' step starts: its interior is read)
    assert len(times) > min(sol.stats["elements per component"])
    monkeypatch.undo()
    U = state(slice(None))
    assert np.array_equal(U[0], ode.u0)
    assert np.array_equal(U[1:], sol._galerkin(times[1:]).T)  # (U's polynomials)
