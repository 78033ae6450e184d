"""Mono-adaptive cG(q)/dG(q): convergence orders, adaptivity and stiff problems."""
import importlib
import itertools

import numpy as np
import pytest
import scipy.linalg as sl
import sympy as sp

import dolfinode as dn
from dolfinode import problems

# A weakly damped oscillator coupled to a decaying mode: errors accumulate over T = 20, so the
# asymptotic regime is visible above rounding even for order 11.
A_LINEAR = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.5], [0.0, -0.5, -0.1]])
U0_LINEAR = np.array([1.0, 0.5, -0.2])
# Per method: the largest step and how many halvings keep the error between ~1e-10 and 1e-1.
STEPS = {"cG(1)": (0.25, 4), "cG(2)": (0.5, 4), "cG(3)": (1.0, 4), "cG(4)": (2.0, 3),
         "cG(5)": (2.0, 2), "dG(0)": (1 / 64, 3), "dG(1)": (0.25, 4), "dG(2)": (0.5, 4),
         "dG(3)": (1.0, 3), "dG(4)": (2.0, 2), "dG(5)": (2.0, 2)}


@pytest.fixture(scope="module")
def linear():
    u = sp.symbols("u0:3")
    rhs = {u[i]: sum(A_LINEAR[i, j] * u[j] for j in range(3)) for i in range(3)}
    T = 20.0
    return dn.ODE(rhs, u0=U0_LINEAR, T=T), sl.expm(A_LINEAR * T) @ U0_LINEAR


def observed_order(ode, exact, method, ks):
    """Least-squares slope of log(error) against log(k), errors above rounding level only."""
    errors = np.array([np.abs(dn.solve(ode, method=method, fixed_time_step=True,
                                       initial_time_step=k)(ode.T) - exact).max() for k in ks])
    assert errors.min() > 1e-11, f"{method}: errors {errors} reach rounding level"
    return np.polyfit(np.log(ks), np.log(errors), 1)[0]


@pytest.mark.parametrize("method", STEPS)
def test_nodal_convergence_order(linear, method):
    """cG(q): nodal order 2q; dG(q): 2q + 1, against expm, with fixed uniform steps."""
    ode, exact = linear
    order = dn.parse_method(method)[1].order
    k0, count = STEPS[method]
    ks = [k0 / 2**j for j in range(count)]
    assert abs(observed_order(ode, exact, method, ks) - order) < 0.3


#: Rounding error accumulated over thousands of steps on [0, 10] for |u| ~ 1.
ROUNDING_AT_T = 1e-11


@pytest.mark.parametrize("method", ["cG(1)", "cG(2)", "dG(1)", "dG(2)"])
def test_error_decreases_with_tolerance_harmonic(method):
    ode, exact = problems.harmonic(T=10.0)
    errors = [np.abs(dn.solve(ode, method=method, tolerance=tol)(ode.T) - exact(ode.T)).max()
              for tol in (1e-3, 1e-5, 1e-7, 1e-9)]
    # until rounding: dG(2) measured 5.6e-7, 2.9e-9, 1.5e-12, 1.7e-12 (over ~5000 steps)
    assert all(a > b or max(a, b) < ROUNDING_AT_T for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < 1e-6


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)", "cG(3)"])
def test_error_decreases_with_tolerance_lorenz(method):
    ode = problems.lorenz(T=5.0)
    reference = dn.solve(ode, method="cG(5)", tolerance=1e-13)(5.0)
    errors = [np.abs(dn.solve(ode, method=method, tolerance=tol)(5.0) - reference).max()
              for tol in (1e-3, 1e-5, 1e-7, 1e-9)]
    assert all(a > b for a, b in itertools.pairwise(errors)), errors


def test_hires_five_significant_digits():
    sol = dn.solve(problems.hires(), method="dG(2)", tolerance=1e-6)
    assert problems.mescd(sol(sol.ode.T), problems.HIRES_REFERENCE) >= 5
    assert sol.stats["newton"], "HIRES is stiff: the default solver should have switched to Newton"


@pytest.mark.parametrize("method", ["dG(0)", "dG(1)", "cG(1)", "cG(2)"])
def test_stiff_decay_switches_to_newton(method):
    ode, exact = problems.stiff_decay(lam=1000.0, T=10.0)
    sol = dn.solve(ode, method=method, tolerance=1e-5)
    assert sol.stats["newton"]
    times = np.array([0.001, 0.01, 1.0, 10.0])
    assert np.abs(sol(times)[0] - exact(times)[0]).max() < 1e-3
    # once the transient has decayed the step grows far beyond the explicit limit 2/1000
    assert sol.k[-1] > 0.1


@pytest.mark.parametrize("method, iterations", [("cG(3)", 4.0), ("dG(3)", 4.5)])
def test_fixed_point_starts_from_the_last_element_extrapolated(method, iterations):
    """On a smooth solution the last element's polynomial, continued, predicts the stages to
    O(k^(q+1)): measured on u'' = -u over T = 20 at tolerance 1e-8, cG(3) 3.3 and dG(3) 4.0
    iterations per slab (from explicit Euler: 5.0 and 5.0), at the same steps and accuracy."""
    ode, exact = problems.harmonic(T=20.0)
    sol = dn.solve(ode, method=method, tolerance=1e-8, nonlinear_solver="fixed-point",
                   calibrate_tolerance=False)  # the steps of the measurement
    assert sol.stats["nonlinear iterations"] / sol.stats["time slabs"] < iterations
    assert np.abs(sol(ode.T) - exact(ode.T)).max() < 1e-9


@pytest.mark.parametrize("method, tol", [("cG(1)", 1e-2), ("cG(2)", 1e-2), ("cG(2)", 1e-3)])
def test_rober_at_loose_tolerance_is_right_or_raises(method, tol):
    """ROBER with atol 1e-6 (where scipy's BDF returns y1 = -3e6) at loose tolerances.

    cG(q) is not L-stable: on ROBER the error of the stiff y2 is not damped but carried
    from slab to slab, and through 1e4 y2 y3 it drives y1 below zero, into the branch where
    y1 = -y3 grows without bound. Letting Newton's second increment exceed its first (cG(2)
    at t ~ 6e10: 0.14, 0.19, 0.014, ...) completed these runs with y1 = -4e7 at T; as
    Newton is now, they end in SolverError."""
    from dolfinode.bench import problems as bench

    p = bench.rober()
    try:
        sol = dn.solve(p.ode, method=method, tolerance=tol, absolute_tolerance=1e-6,
                       maximum_steps=20_000)
    except dn.SolverError:
        return
    assert np.all(np.abs(sol(p.T) - p.final) <= 1e-6 + tol * np.abs(p.final))
    assert sol.values.min() >= -1e-6


def test_explicit_newton_matches_fixed_point():
    ode = problems.lorenz(T=2.0)
    a = dn.solve(ode, method="cG(2)", tolerance=1e-8, nonlinear_solver="fixed-point")
    b = dn.solve(ode, method="cG(2)", tolerance=1e-8, nonlinear_solver="newton")
    assert not a.stats["newton"] and b.stats["jacobian evaluations"] > 0
    assert np.abs(a(2.0) - b(2.0)).max() < 1e-5


@pytest.mark.parametrize("method", ["cG(3)", "cG(5)", "dG(3)", "dG(5)"])
def test_oscillation_stays_with_fixed_point(method):
    # A chain with two springs 1e4 times stiffer (omega ~ 140) is not stiff at the steps its
    # accuracy needs, but k A (x) J is far from normal for q >= 3: an increment of a
    # converging iteration may grow once. Taken for divergence, that switched every solve to
    # Newton, 3-6x slower on the 50-mass chain.
    from dolfinode.bench.problems import mass_spring_chain

    p = mass_spring_chain(n=4, T=1.0)
    for tol in (1e-3, 1e-5):  # at the steps of the local estimate bounded by tol
        sol = dn.solve(p.ode, method=method, tolerance=tol, calibrate_tolerance=False)
        assert not sol.stats["newton"], (method, tol)
        assert np.abs(sol(p.T) - p.final).max() <= 10 * tol


def test_maximum_time_step_is_respected():
    ode, _ = problems.harmonic(T=10.0)
    sol = dn.solve(ode, method="cG(3)", tolerance=1e-3, maximum_time_step=0.1)
    assert sol.k.max() <= 0.1 * (1 + 1e-12)


def test_fixed_time_step_gives_uniform_partition():
    ode, _ = problems.harmonic(T=1.0)
    sol = dn.solve(ode, method="dG(1)", fixed_time_step=True, initial_time_step=0.1)
    assert len(sol.k) == 10 and np.allclose(sol.k, 0.1)
    assert sol.stats["rejected steps"] == 0


@pytest.mark.parametrize("n", [100_000, 1_234_567])
def test_fixed_steps_of_T_over_n_take_n_steps(n):
    # the running sum t0 + k + k + ... rounds: 1e5 steps of 1e-5 left a sliver of 1e-11,
    # one step past maximum_steps = n
    u = sp.Symbol("u")
    ode = dn.ODE({u: -u}, u0=[1.0], T=1.0)
    sol = dn.solve(ode, "dG(0)", fixed_time_step=True, initial_time_step=1.0 / n,
                   maximum_steps=n, estimate_global_error=False, dense_output=False)
    assert sol.stats["time slabs"] == n


def test_time_dependent_rhs_and_parameters():
    u, a = sp.symbols("u a")
    ode = dn.ODE({u: -a * u + dn.t}, u0=[1.0], T=3.0, params={a: 2.0})
    sol = dn.solve(ode, method="cG(2)", tolerance=1e-9)
    exact = 3.0 / 2 - 0.25 + 1.25 * np.exp(-6.0)  # u = t/a - 1/a^2 + (1 + 1/a^2) e^{-a t}
    assert abs(sol(3.0)[0] - exact) < 1e-7


def test_nonzero_initial_time():
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[2.0], T=5.0, t0=3.0), method="dG(2)", tolerance=1e-9)
    assert sol.t[0] == 3.0 and abs(sol(5.0)[0] - 2 * np.exp(-2.0)) < 1e-7



@pytest.mark.parametrize("method", ["cG(2)", "dG(1)"])
def test_a_pulse_near_t_one_is_integrated_over_the_slabs_it_spans(method):
    """A pulse 2^-44 wide (256 ulp of t = 1) of area 1 in f(t): each slab is the step t + k
    represents near t = 0 too, so the quadrature of the pulse spans its float width (a slab
    of nominal length 0.70369 w spanned 0.703125 w: u(2) was 2.1e-4 off at 1e-6)."""
    u = sp.Symbol("u")
    w = 2.0**-44
    pulse = (sp.Heaviside(dn.t - 1) - sp.Heaviside(dn.t - 1 - w)) / w
    sol = dn.solve(dn.ODE({u: -u + pulse}, u0=[0.5], T=2.0), method, tolerance=1e-6)
    exact = (0.5 * np.exp(-1.0) + 1.0) * np.exp(-1.0)
    assert abs(sol(2.0)[0] - exact) < 1e-6
    t_start, k = sol.time_steps()
    np.testing.assert_array_equal((t_start + k) - t_start, k)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)"])
def test_a_large_initial_time_keeps_the_tolerance(method):
    """At t0 = 1e9 double precision resolves t to 1.2e-7: the slabs are the steps t + k
    represents, so that they tile [t0, T] (taking k as given drifted by up to ulp(t) per
    slab: 53 x, 186 x the tolerance here)."""
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=1e9 + 10.0, t0=1e9)
    sol = dn.solve(ode, method=method, tolerance=1e-8)
    assert np.max(np.abs(sol(ode.T) - [np.cos(10.0), -np.sin(10.0)])) < 3e-8
    t_start, k = sol.time_steps()
    np.testing.assert_array_equal((t_start + k) - t_start, k)  # each slab is its own length


def test_fixed_steps_far_from_t_zero_are_as_accurate_as_near_it():
    # 0.01 at t = 1e9 is 0.01 +- 6e-8: taken as 0.01 the end was 8e-6 off, 70,000 x the error
    # of the same steps from t0 = 0
    u, v = sp.symbols("u v")
    errors = []
    for t0 in (0.0, 1e9):
        ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=t0 + 10.0, t0=t0)
        sol = dn.solve(ode, "cG(2)", fixed_time_step=True, initial_time_step=0.01)
        errors.append(np.max(np.abs(sol(ode.T) - [np.cos(10.0), -np.sin(10.0)])))
    assert errors[1] < 2 * errors[0]

def test_stats_are_counted():
    sol = dn.solve(problems.hires(), method="dG(1)", tolerance=1e-4)
    stats = sol.stats
    for key in ("time slabs", "elements", "f evaluations", "jacobian evaluations",
                "factorizations", "rejected steps", "nonlinear iterations", "compile time",
                "solve time"):
        assert key in stats
    assert stats["elements"] == stats["time slabs"] * 8
    assert stats["f evaluations"] >= stats["nonlinear iterations"]
    assert stats["factorizations"] >= stats["jacobian evaluations"] > 0
    assert stats["solve time"] > 0


def test_newton_matrix_is_allocated_only_when_needed(monkeypatch):
    """With no memory for the Newton matrix, fixed point still solves; a stiff solve stops."""
    driver = importlib.import_module("dolfinode.solve")  # the module, not dn.solve
    monkeypatch.setattr(driver, "_NEWTON_MEMORY_FRACTION", 0.0)
    monkeypatch.setattr(driver, "SMALL_BYTES", 0)
    harmonic, _ = problems.harmonic(T=1.0)
    sol = dn.solve(harmonic, method="dG(1)", tolerance=1e-6)
    assert not sol.stats["newton"] and sol.stats["time slabs"] > 1
    ode, _ = problems.stiff_decay(lam=1000.0, T=10.0)
    for solver in ("default", "newton"):
        with pytest.raises(dn.SolverError, match="Newton matrices .* banded LU") as info:
            dn.solve(ode, method="cG(1)", tolerance=1e-5, nonlinear_solver=solver)
        assert info.value.t < 10.0
        assert "fixed-point" in str(info.value)


def test_newton_memory_formula():
    """NewtonStructure.memory bounds what the Newton solver allocates, for every method: J
    (later the filter's matrix), one band matrix (2 kl + ku + 1 columns) per real eigenvalue of
    A and a complex one per pair, the pivots and the work vectors; within 25% of it."""
    from dolfinode.linalg.newton_matrix import band_structure
    from dolfinode.methods import make_method

    N, kl, ku = 1000, 3, 2
    columns = 2 * kl + ku + 1
    structure = band_structure(np.arange(N), kl, ku)
    for family, q in [("cG", 1), ("cG", 2), ("cG", 5), ("dG", 0), ("dG", 1), ("dG", 6)]:
        method = make_method(family, q)
        S = len(method.A)
        real = int(np.sum(method.stage_eigenvalues.imag == 0))
        pairs = len(method.stage_eigenvalues) - real
        allocated = (8 * N * columns * (1 + real + 2 * pairs)  # J (filter), matrices
                     + 8 * N * (real + pairs + 1)                  # pivots
                     + 8 * N * S + 8 * N + 16 * N)                 # Z, z_real, z_complex
        bound = structure.memory(S)
        assert allocated <= bound <= 1.25 * allocated, (family, q)


def grid_reaction_diffusion(n):
    """u' = 2 Lap u + u (1 - u) on an n x n grid (mirror boundaries): a band of about n after
    reordering, so that a factorization costs ~ n^4 against ~ n^3 for a solve."""
    u = sp.symbols(f"u0:{n * n}")
    D = sp.Symbol("D")

    def at(i, j):
        i = 1 if i < 0 else n - 2 if i > n - 1 else i
        j = 1 if j < 0 else n - 2 if j > n - 1 else j
        return u[i * n + j]

    rhs = {at(i, j): D * (at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1)
                          - 4 * at(i, j)) + at(i, j) * (1 - at(i, j))
           for i in range(n) for j in range(n)}
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    return dn.ODE(rhs, u0=np.exp(-20 * (x**2 + y**2)).ravel(), T=1.0,
                  params={D: 2.0 * (n - 1) ** 2})


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)"])
def test_newton_keeps_costly_factors_over_slabs(method, monkeypatch):
    """With a factorization estimated at REUSE_TIME or more, Newton's J and factors serve
    several slabs: a fraction of the factorizations for the same accuracy."""
    from dolfinode.compile import lower
    from dolfinode.timeslab import mono

    ode = grid_reaction_diffusion(20)
    assert lower(ode).sparse_structure.seconds(complex_values=True) >= mono.REUSE_TIME
    reference = dn.solve(ode, "dG(3)", tolerance=1e-10, nonlinear_solver="newton").y[:, -1]
    # the step estimate bounded by 1e-5, so that both runs reach 1e-5 at T
    kept = dn.solve(ode, method, tolerance=1e-5, nonlinear_solver="newton",
                    calibrate_tolerance=False)
    monkeypatch.setattr(mono, "REUSE_TIME", np.inf)
    monkeypatch.setattr(mono, "KEEP_FACTORS", False)
    every = dn.solve(ode, method, tolerance=1e-5, nonlinear_solver="newton",
                     calibrate_tolerance=False)
    assert every.stats["jacobian evaluations"] == every.stats["time slabs"] + every.stats[
        "rejected steps"] + every.stats["failed nonlinear solves"]
    assert kept.stats["factorizations"] < every.stats["factorizations"] / 4
    assert kept.stats["jacobian evaluations"] < every.stats["time slabs"] / 4
    for sol in (kept, every):
        assert np.abs(sol.y[:, -1] - reference).max() < 1e-5


def test_sparse_analysis_waits_for_newton(monkeypatch):
    """The sparse structure (a minimum degree ordering and the filled pattern, seconds for a
    large lattice) is made only when a solve first needs Newton's method: not for fixed-point
    solves; a default solve that turns stiff decides it then and goes on."""
    from dolfinode.compile import lower, lowering

    made = []
    make = lowering.sparse_structure
    monkeypatch.setattr(lowering, "sparse_structure",
                        lambda *args: made.append(1) or make(*args))
    monkeypatch.setattr(lowering, "_structures", {})
    ode = grid_reaction_diffusion(12)
    assert dn.solve(ode, "cG(2)", tolerance=1e-4, nonlinear_solver="fixed-point").stats[
        "newton matrices"] is None
    assert not made
    sol = dn.solve(ode, "cG(2)", tolerance=1e-4)
    assert sol.stats["newton"] and sol.stats["newton matrices"].startswith("sparse LU")
    assert made == [1]
    assert lower(ode).sparse_structure is not None and made == [1]  # remembered


def brusselator_2d(n=12, T=10.0):
    """The 2-D Brusselator of demos/brusselator.py (mirror boundaries): mildly stiff, its
    fixed-point iteration needs steps a little shorter than the error control's."""
    u = sp.symbols(f"u0:{n * n}")
    v = sp.symbols(f"v0:{n * n}")
    alpha = 0.02 * (n - 1) ** 2

    def lap(w, i, j):
        def at(a, b):
            a = 1 if a < 0 else n - 2 if a > n - 1 else a
            b = 1 if b < 0 else n - 2 if b > n - 1 else b
            return w[a * n + b]
        return at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1) - 4 * w[i * n + j]

    cells = [(i, j) for i in range(n) for j in range(n)]
    rhs = {u[i * n + j]: 1 + u[i * n + j] ** 2 * v[i * n + j] - 4.4 * u[i * n + j]
           + alpha * lap(u, i, j) for i, j in cells}
    rhs.update({v[i * n + j]: 3.4 * u[i * n + j] - u[i * n + j] ** 2 * v[i * n + j]
                + alpha * lap(v, i, j) for i, j in cells})
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    return dn.ODE(rhs, u0=np.concatenate([0.5 + y.ravel(), 1 + 5 * x.ravel()]), T=T)


def test_newton_gives_way_to_cheaper_fixed_point_iteration():
    """The default solver turns to Newton where fixed-point iteration fails, and back when
    fixed-point iteration on its own (shorter) steps is estimated much cheaper than Newton on
    the error control's: on a mildly stiff 2-D Brusselator two Jacobians instead of one per
    few slabs, and the accuracy of Newton throughout."""
    ode = brusselator_2d()
    reference = dn.solve(ode, "cG(3)", tolerance=1e-9).y[:, -1]
    default = dn.solve(ode, "cG(2)", tolerance=1e-3)
    newton = dn.solve(ode, "cG(2)", tolerance=1e-3, nonlinear_solver="newton")
    assert default.stats["newton"] and default.stats["jacobian evaluations"] <= 3
    assert newton.stats["jacobian evaluations"] > 10 * default.stats["jacobian evaluations"]
    for sol in (default, newton):
        assert np.abs(sol.y[:, -1] - reference).max() < 1e-3


def test_a_newton_failure_on_the_start_does_not_hold_the_growth():
    """ROBER from a first step that overshoots its start: Newton fails early, and once
    it contracts fast again the step grows as the error control asks, not by NEWTON_PROBE
    per slab over the eleven decades to T (measured from a first step 6.25e-4 and one
    failure: 166 slabs held, 69 free)."""
    from dolfinode.bench.problems import mescd, rober
    from dolfinode.timeslab import mono

    problem = rober()
    sol = dn.solve(problem.ode, method="dG(3)", tolerance=1e-2,
                   absolute_tolerance=problem.atol_ratio * 1e-2, initial_time_step=1e-2)
    assert sol.stats["failed nonlinear solves"] >= 1
    _, k = sol.time_steps()
    probing = np.isclose(k[1:-1] / k[:-2], mono.NEWTON_PROBE, rtol=1e-9)
    assert probing.sum() < 10
    assert len(k) < 100
    assert mescd(sol(problem.T), problem.final, problem.atol_ratio) > 3


def test_a_newton_failure_after_contracting_is_not_retried_from_x():
    """HIRES, dG(2) at 1e-6 with the peers bench's absolute tolerance: Newton fails twice from
    the extrapolated start after contracting. A retry from the constant x (mono.RETRY_AFTER
    raised in a scratch copy) converged in one of them but took more iterations than the
    smaller step it saves: 51 slabs in 320 iterations against 52 in 307 without it, with
    5.6 and 5.4 digits (mescd)."""
    from dolfinode.bench.problems import hires_problem, mescd

    problem = hires_problem()
    sol = dn.solve(problem.ode, method="dG(2)", tolerance=1e-6,
                   absolute_tolerance=problem.atol_ratio * 1e-6)
    assert sol.stats["failed nonlinear solves"] == 2
    assert sol.stats["time slabs"] == 52
    assert sol.stats["nonlinear iterations"] <= 310
    assert mescd(sol(problem.T), problem.final, problem.atol_ratio) > 5


@pytest.mark.parametrize("problem, method", [("springs", "cG(1)"), ("springs", "dG(1)"),
                                             ("HIRES", "cG(2)"), ("HIRES", "dG(1)")])
def test_a_run_cut_into_many_loop_calls_steps_as_one(stiff_springs, problem, method,
                                                     monkeypatch):
    """The loop carries its state (the predictor's last slab, the step controller's and the
    nonlinear solver's limits, Newton's factors, their step, age and contraction rate) from
    one call to the next: output buffers of 7 slabs cut the run into many calls, and it takes
    the same slabs, f evaluations, Jacobians and values, bitwise."""
    ode = stiff_springs if problem == "springs" else problems.hires()
    whole = dn.solve(ode, method=method, tolerance=1e-6, dense_output=False)
    monkeypatch.setattr(importlib.import_module("dolfinode.solve"), "_CHUNK_LIMIT", 7)
    cut = dn.solve(ode, method=method, tolerance=1e-6, dense_output=False)
    assert whole.stats["time slabs"] > 10 * 7  # (many calls)
    assert problem == "springs" or whole.stats["jacobian evaluations"] > 0
    for key in ("time slabs", "f evaluations", "jacobian evaluations", "factorizations",
                "rejected steps", "nonlinear iterations"):
        assert cut.stats[key] == whole.stats[key], key
    np.testing.assert_array_equal(cut.y, whole.y)
