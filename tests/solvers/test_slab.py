"""Nonlinear solvers of one slab: the transformed simplified Newton iteration."""
import importlib
import math

import numpy as np
import pytest
import scipy.linalg as sl
import sympy as sp
from numba import njit

import dolfinode as dn
from dolfinode.compile import lower
from dolfinode.compile.signatures import rhs_kernel
from dolfinode.linalg.newton_matrix import band_structure, sparse_structure, store_jacobian
from dolfinode.methods import make_method
from dolfinode.solvers import slab
from dolfinode.timeslab import NUM_COUNTERS, mono

METHODS = [("cG", q) for q in range(1, 7)] + [("dG", q) for q in range(7)]


def permuted_band_system(N=7, seed=0):
    """u' = M u with M tridiagonal in a shuffled component order (the solver reorders it back
    to a band), non-normal and stiff (eigenvalues from -1 to about -2000)."""
    rng = np.random.default_rng(seed)
    band = np.diag(-np.geomspace(1.0, 2000.0, N)) + np.diag(rng.uniform(-30, 30, N - 1), 1)
    band += np.diag(rng.uniform(-3, 3, N - 1), -1)
    perm = rng.permutation(N)
    M = band[np.ix_(perm, perm)]
    u = sp.symbols(f"u0:{N}")
    rhs = {u[i]: sum(M[i, j] * u[j] for j in range(N) if M[i, j]) for i in range(N)}
    return dn.ODE(rhs, u0=rng.uniform(-1, 1, N), T=1.0), M


@njit
def _newton_steps(f_address, p, x0, f0, k, A, b0, tau, T, T_inverse, atol, transformed, X, F,
                  G, Z, ab_real, ab_complex, structure, ipiv, z_real, z_complex, w, counters,
                  steps):
    f = rhs_kernel(f_address)
    return slab.newton(f, p, x0, f0, 0.0, k, A, b0, tau, T, T_inverse, atol, 1e-6, 0.0, steps,
                       1.0, slab.GIVE_UP | (slab.TRANSFORMED if transformed else 0), X, F, G,
                       Z, ab_real, ab_complex, structure, ipiv, z_real, z_complex, w, counters,
                       np.zeros(1))


@pytest.mark.parametrize("transformed", [False, True], ids=["residual", "transformed"])
@pytest.mark.parametrize("storage", ["banded", "sparse"])
@pytest.mark.parametrize("family, q", METHODS, ids=[f"{f}({q})" for f, q in METHODS])
def test_one_newton_step_solves_a_linear_stage_system(family, q, storage, transformed):
    """On u' = M u, one simplified Newton step with J = M gives the stage values exactly,
    whatever the start, in either storage of the Newton matrices and with the residual formed
    in either variables (transformed: from T^-1 A and T^-1 b0): the block-diagonalized
    solves equal the direct solve of (I - k A (x) M) X = 1 (x) x0 + k b0 (x) M x0."""
    ode, M = permuted_band_system()
    compiled = lower(ode)
    _, position, kl, ku = compiled.ordering
    assert kl == ku == 1  # the shuffled tridiagonal was ordered back into a band
    if storage == "banded":
        structure = band_structure(position, kl, ku)
    else:
        structure = sparse_structure(compiled.indptr, compiled.indices, ode.N)
    m = make_method(family, q)
    A, b0 = np.array(m.A), m.b0.copy()
    S, N, k = A.shape[0], ode.N, 0.05
    x0 = np.asarray(ode.u0, dtype=float)
    f0 = M @ x0
    jdata = np.empty(len(compiled.indices))
    compiled.jacobian(x0.ctypes.data, 0.0, compiled.p.ctypes.data, jdata.ctypes.data)
    eigenvalues = m.stage_eigenvalues.copy()
    real = int(np.sum(eigenvalues.imag == 0))
    jb = np.zeros(structure.shape)
    ab_real = np.zeros((real, *structure.shape))
    ab_complex = np.zeros((len(eigenvalues) - real, *structure.shape), dtype=complex)
    ipiv = np.zeros((len(eigenvalues), N), dtype=np.int64)
    counters = np.zeros(NUM_COUNTERS, dtype=np.int64)
    store_jacobian(jdata, compiled.indptr, compiled.indices, structure.tuple, jb)
    assert slab.factor_stages(jb, k, eigenvalues, structure.tuple, ab_real, ab_complex, ipiv,
                              counters)
    X = np.random.default_rng(1).standard_normal(S * N)  # any start
    work = [np.empty(S * N), np.empty(S * N), np.empty(2 * S * N), np.empty(S * N)]
    T_inverse = m.stage_transform_inverse.copy()
    A_newton, b0_newton = A, b0
    if transformed:
        A_newton, b0_newton = np.empty((S, S)), np.empty(S)
        slab.transformed_tables(A, b0, T_inverse, A_newton, b0_newton)
    _newton_steps(compiled.rhs.address, compiled.p, x0, f0, k, A_newton, b0_newton,
                  m.nodes[m.stages].copy(), m.stage_transform.copy(), T_inverse,
                  np.full(N, 1e-6), transformed, X, work[0], work[1], work[2], ab_real,
                  ab_complex, structure.tuple, ipiv, np.empty(N), np.empty(N, dtype=complex),
                  work[3], counters, 1)
    expected = np.linalg.solve(np.eye(S * N) - k * np.kron(A, M),
                               np.tile(x0, S) + k * np.kron(b0, f0))
    scale = np.linalg.cond(m.stage_transform) * np.abs(expected).max()  # 1 to 800
    np.testing.assert_allclose(X, expected, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("method", ["cG(1)", "cG(3)", "cG(4)", "dG(1)", "dG(2)", "dG(5)"])
def test_newton_converges_in_one_step_on_a_linear_system(method):
    """Through dn.solve: every slab of a linear stiff system takes two Newton iterations (the
    second confirms the first), and the solution matches the matrix exponential."""
    ode, M = permuted_band_system()
    sol = dn.solve(ode, method=method, tolerance=1e-8, nonlinear_solver="newton")
    stats = sol.stats
    assert stats["nonlinear iterations"] <= 2 * (stats["time slabs"] + stats["rejected steps"])
    exact = sl.expm(M * ode.T) @ np.asarray(ode.u0)
    assert np.abs(sol(ode.T) - exact).max() < 1e-6


def _newton_solve(ode, keep, monkeypatch, **parameters):
    monkeypatch.setattr(mono, "KEEP_FACTORS", keep)
    return dn.solve(ode, nonlinear_solver="newton", **parameters)


def test_factors_are_kept_on_a_linear_system(monkeypatch):
    """u' = M u on fixed steps: J and the factors are exact for every slab, so they are kept
    for REUSE_AGE slabs at a time, and the solution and iterations are those of factoring
    every slab afresh."""
    ode, _ = permuted_band_system()
    steps = {"method": "dG(2)", "fixed_time_step": True, "initial_time_step": 0.01}
    kept = _newton_solve(ode, True, monkeypatch, **steps)
    fresh = _newton_solve(ode, False, monkeypatch, **steps)
    slabs = kept.stats["time slabs"]
    assert slabs == fresh.stats["time slabs"] == fresh.stats["jacobian evaluations"] == 100
    # + 1: the last step, which absorbs the rounding of t0 + n k, is not exactly theirs
    assert kept.stats["jacobian evaluations"] <= math.ceil(slabs / (mono.REUSE_AGE + 1)) + 1
    assert kept.stats["nonlinear iterations"] == fresh.stats["nonlinear iterations"]
    np.testing.assert_allclose(kept(ode.T), fresh(ode.T), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)"])
def test_kept_factors_are_refreshed_as_the_jacobian_changes(method, monkeypatch):
    """Van der Pol, eps = 0.01, on fixed steps (J changes along the limit cycle): the factors
    serve several slabs, yet are made afresh more often than the age limit REUSE_AGE asks,
    when Newton on them contracts slowly or fails; the answer is that of fresh factors on
    every slab."""
    y1, y2 = sp.symbols("y1 y2")
    ode = dn.ODE({y1: y2, y2: 100 * ((1 - y1**2) * y2 - y1)}, u0=[2.0, 0.0], T=2.0)
    steps = {"method": method, "fixed_time_step": True, "initial_time_step": 2e-3}
    kept = _newton_solve(ode, True, monkeypatch, **steps)
    fresh = _newton_solve(ode, False, monkeypatch, **steps)
    slabs = kept.stats["time slabs"]
    assert slabs == fresh.stats["jacobian evaluations"] == 1000
    assert slabs / (mono.REUSE_AGE + 1) + 10 < kept.stats["jacobian evaluations"] < slabs / 10
    np.testing.assert_allclose(kept(ode.T), fresh(ode.T), rtol=1e-10)


@pytest.mark.parametrize("method, most", [("dG(2)", 4.7), ("dG(3)", 3.6)])
def test_newton_takes_j_in_the_middle_of_an_extrapolated_slab(method, most, monkeypatch):
    """u' = -lambda(t) (u - cos t), lambda = 1000 (1 + 5 t), on fixed steps k = 0.01 with
    fresh factors on every slab: linear, so the simplified iteration contracts at the rate
    |lambda(t_s) - lambda(t_J)| / lambda that J at t_J leaves at the stages; from the middle
    stage (mono.middle_stage) that is about half of what J at the slab's start leaves
    (dG(2) 5.2, dG(3) 3.9 iterations a slab), and the answer is the same."""
    u = sp.Symbol("u")
    ode = dn.ODE({u: -1000 * (1 + 5 * dn.t) * (u - sp.cos(dn.t))}, u0=[2.0], T=1.0,
                 nonnegative=[])
    sol = _newton_solve(ode, False, monkeypatch, method=method, fixed_time_step=True,
                        initial_time_step=0.01)
    assert sol.stats["time slabs"] == sol.stats["jacobian evaluations"] == 100
    assert sol.stats["nonlinear iterations"] <= most * 100
    # u = cos t - u'/lambda + ... : the quasi-steady state to O(1 / lambda^2)
    assert sol(1.0)[0] == pytest.approx(math.cos(1.0) + math.sin(1.0) / 6000, rel=1e-6)


def test_newton_stops_relative_to_the_delivered_error():
    """Newton's stopping tolerance on slab n is KAPPA x the delivered error x max(k/(T - t0),
    1/(n + 1)), between the rounding floor and dtol: the shares of n slabs sum to at most
    2 + ln n; a tighter tolerance (a smaller delivered error) stops tighter; without a
    delivered error (cG(q), fixed steps) the loop's tolerance stands."""
    dtol_k, floor, dtol, delivered = 1e-9, 1e-12, 1e-3, 1e-3
    assert slab.newton_tolerance(dtol_k, floor, dtol, delivered, 0.5, 9) == (
        slab.KAPPA * delivered * 0.5)
    assert slab.newton_tolerance(dtol_k, floor, dtol, delivered, 1e-9, 9) == pytest.approx(
        slab.KAPPA * delivered / 10)
    assert slab.newton_tolerance(dtol_k, floor, dtol, 0.0, 0.5, 9) == dtol_k
    assert slab.newton_tolerance(dtol_k, floor, dtol, 1e3, 0.5, 9) == dtol
    assert slab.newton_tolerance(dtol_k, floor, dtol, 1e-12, 1e-9, 9) == floor
    assert (slab.newton_tolerance(dtol_k, floor, dtol, delivered / 10, 1e-9, 9)
            < slab.newton_tolerance(dtol_k, floor, dtol, delivered, 1e-9, 9))
    n = 10_000
    steps = np.full(n, 1.0 / n)
    total = sum(slab.newton_tolerance(dtol_k, floor, dtol, delivered, k, i)
                for i, k in enumerate(steps))
    assert total <= slab.KAPPA * delivered * (2 + math.log(n))


def test_a_carried_rate_keeps_newton_iterating():
    """After an increment that shrank 1000-fold (the start's error removed at once), the
    estimate theta/(1 - theta) |dX| says converged; with the last solve's rate of 0.5 carried,
    the same increment is 1/(1 - 0.5) = 2x the remaining error, above the tolerance: iterate
    further."""
    d, d_prev, dtol = 1e-4, 1e-1, 1e-5
    assert slab._converged(d, d_prev, 1, dtol, 0.0)
    assert not slab._converged(d, d_prev, 1, dtol, 0.5)
    assert slab._converged(d / 20, d, 2, dtol, 0.5)


def test_a_hopeless_iteration_gives_up_early():
    """RADAU5's prediction: contracting at 0.7 from an increment of 2.3 (HIRES, dG(3) at
    1e-6, t = 284), 28 iterations more leave 0.7^28 x 2.3 / 0.3 = 4e-4, above the tolerance
    1.4e-5: give up now, not after 30 iterations; at 0.2 two suffice. At rounding level,
    stagnation is the test, not this."""
    assert slab._hopeless(0.7, 2.3, 1.4e-5, 28)
    assert not slab._hopeless(0.2, 2.3, 1.4e-5, 28)
    assert not slab._hopeless(0.7, 1e-11, 1e-14, 1)


def _with_stop(monkeypatch, relative, ode, **parameters):
    """dn.solve with Newton's stop relative to the delivered error on or off (the loop option
    ``delivered`` zeroed: the loop's share dtol k/(T - t0), on ROBER the rounding floor)."""
    solve_module = importlib.import_module("dolfinode.solve")  # (dolfinode.solve: the function)
    if not relative:
        options = solve_module._options

        def without_delivered(*args):
            atol, record = options(*args)
            record["delivered"] = 0.0
            return atol, record

        monkeypatch.setattr(solve_module, "_options", without_delivered)
    sol = dn.solve(ode, **parameters)
    monkeypatch.undo()
    return sol


def _rober_dg3(monkeypatch, relative):
    """ROBER (T = 1e11: every step below 1e-8 (T - t0)) with dG(3) at 1e-6; (Newton
    iterations, scaled error at T)."""
    from dolfinode.bench.problems import rober

    problem = rober()
    sol = _with_stop(monkeypatch, relative, problem.ode, method="dG(3)", tolerance=1e-6,
                     absolute_tolerance=problem.atol_ratio * 1e-6)
    error = np.max(np.abs(sol(problem.T) - problem.final)
                   / (problem.atol_ratio + np.abs(problem.final)))
    return sol.stats["nonlinear iterations"], error


def test_the_tolerance_relative_stop_saves_iterations_at_equal_accuracy(monkeypatch):
    """On steps graded over decades (ROBER, dG(3) at 1e-6) the iteration stops at its share
    of KAPPA x the delivered error instead of rounding level: at least 20 % fewer iterations
    (measured 680 against 916), at the same digits: the error at T moves by less than 0.1 x
    the tolerance (measured 4e-4 x) and stays below half of it (0.011 x)."""
    iterations, error = _rober_dg3(monkeypatch, True)
    iterations_floor, error_floor = _rober_dg3(monkeypatch, False)
    assert iterations < 0.8 * iterations_floor
    assert abs(error - error_floor) < 0.1 * 1e-6
    assert error < 0.5 * 1e-6


@pytest.mark.parametrize("solver", ["newton", "default"])
def test_the_tolerance_relative_stop_leaves_a_linear_answer_unchanged(solver, monkeypatch):
    """u' = M u, M symmetric with eigenvalues -1e-9..-1e3, over T = 1e10 (steps graded over
    decades: the share k/(T - t0) below rounding) with dG(2): one Newton iteration with J is
    exact, so Newton's looser stopping test changes the answer by rounding only; the default
    solver's fixed-point slabs (the first, short ones) keep their tolerance."""
    N = 5
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.standard_normal((N, N)))
    M = -(Q * np.geomspace(1e-9, 1e3, N)) @ Q.T
    u = sp.symbols(f"u0:{N}")
    ode = dn.ODE({u[i]: sum(M[i, j] * u[j] for j in range(N)) for i in range(N)},
                 u0=rng.uniform(-1, 1, N), T=1e10)
    parameters = {"method": "dG(2)", "tolerance": 1e-6, "nonlinear_solver": solver}
    relative = _with_stop(monkeypatch, True, ode, **parameters)
    floor = _with_stop(monkeypatch, False, ode, **parameters)
    assert relative.stats["time slabs"] == floor.stats["time slabs"]
    np.testing.assert_allclose(relative.values, floor.values, rtol=1e-12, atol=1e-15)
    exact = sl.expm(M * ode.T) @ np.asarray(ode.u0)
    assert np.abs(relative(ode.T) - exact).max() < 1e-4


@pytest.mark.parametrize("N", range(1, 12))
def test_stage_sums_are_summed_in_order_for_every_block_size(N):
    """_stage_sum keeps components in register blocks of 8, 4, 2 and 1: each sum is still
    c f0_i + A_s0 F_0i + A_s1 F_1i + ..., in that order, so that it equals the plain loop bit
    for bit whatever N mod 8 is."""
    rng = np.random.default_rng(N)
    for S in (1, 2, 4, 5):
        A = rng.standard_normal((S, S))
        f0 = rng.standard_normal(N)
        F = rng.standard_normal(S * N) * 10.0 ** rng.integers(-8, 8, S * N)
        for s in range(S):
            c = float(rng.standard_normal())
            out = np.empty(N)
            slab._stage_sum(c, f0, F, A, s, out)
            expected = []
            for i in range(N):
                acc = c * f0[i]
                for m in range(S):
                    acc += A[s, m] * F[m * N + i]
                expected.append(acc)
            assert out.tolist() == expected
