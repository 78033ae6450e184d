"""method="auto": the mono- or multi-adaptive variant, switched between in stretches.

The decisions rest on measured CPU rates; the tests that assert them measure "CPU time" with
a cost model instead (elements x 1 for cG(q), x COST_RATIO = 7 for mcG(q), the prior of
family.py), so that they do not depend on the machine's load.
"""
import importlib
import itertools

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode import family, global_error
from dolfinode.bench.multirate import oscillator_bank
from dolfinode.bench.problems import mass_spring_chain as chain_problem
from dolfinode.family import auto_base
from dolfinode.problems import mass_spring_chain
from dolfinode.solution import MixedSolution

TOL = 1e-5
driver = importlib.import_module("dolfinode.solve")  # (dn.solve is the function)


def _model_costs(monkeypatch, per_call):
    """CPU time = per_call + elements x (COST_RATIO multi-adaptive, 1 mono-adaptive) x 1e-7 s
    per solve."""
    spent = [0.0]
    solve = driver.solve

    def counted(ode, method, **parameters):
        sol = solve(ode, method, **parameters)
        elements = sol.stats["elements"] * (family.COST_RATIO if sol.multi else 1)
        spent[0] += per_call + elements * 1e-7
        return sol

    monkeypatch.setattr(driver, "solve", counted)
    monkeypatch.setattr(family, "_clock", lambda: spent[0])


@pytest.fixture
def cost_model(monkeypatch):
    """The CPU time of a solve from its elements alone."""
    _model_costs(monkeypatch, 0.0)


def _ramped_bank(ramp_at, sign, T=6.0):
    """60 oscillators of frequency 1..2 and one whose frequency ramps between 1 and 100
    around t = ramp_at: up for sign = 1, down for sign = -1."""
    n = 60
    x, v = sp.symbols(f"x:{n + 1}"), sp.symbols(f"v:{n + 1}")
    omega = list(np.linspace(1.0, 2.0, n)) + [1 + 99 * (1 + sign * sp.tanh(5 * (dn.t - ramp_at)))
                                              / 2]
    rhs = {}
    for i in range(n + 1):
        rhs[x[i]] = v[i]
        rhs[v[i]] = -omega[i] ** 2 * x[i]
    return dn.ODE(rhs, u0={**dict.fromkeys(x, 1.0), **dict.fromkeys(v, 0.0)}, T=T)


@pytest.fixture(scope="module")
def late_fast():
    """One time scale until t = 2, two after it."""
    return _ramped_bank(2.0, 1)


@pytest.mark.parametrize("name, base", [("auto", "cG(2)"), ("auto:dG(1)", "dG(1)"),
                                        (" AUTO : cg( 3 ) ", "cG(3)"), ("cG(2)", None),
                                        ("auto:mcG(2)", None), ("autocG(2)", None), (2, None)])
def test_auto_base(name, base):
    assert auto_base(name) == base


def test_unknown_method_names_auto():
    with pytest.raises(ValueError, match="'auto'"):
        dn.solve(mass_spring_chain(4, T=1.0)[0], "auto:mcG(2)")


def test_late_fast_scale_switches(cost_model, late_fast):
    """cG(2) while all oscillators are slow, mcG(2) once one is 100x faster; the switched
    solution is as accurate as either variant's."""
    sol = dn.solve(late_fast, "auto", tolerance=TOL)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2) -> mcG(2)", choice
    switch = [check for check in choice["checks"] if check["switched"]]
    # seen in the second half of the stretch the ramp ends in, not a stretch later
    assert len(switch) == 1 and 2.0 < switch[0]["t"] < 3.0, choice
    assert switch[0]["measured"] < switch[0]["rate"]
    # the trial that switched is kept: the stretch from the check's time is mcG(2)'s
    after = next(s for s in choice["stretches"] if s["interval"][0] == switch[0]["t"])
    assert after["method"] == "mcG(2)" and after["trial"]
    assert choice["method"] == "mcG(2)" and sol.multi
    stretches = choice["stretches"]
    assert stretches[0]["interval"][0] == 0.0 and stretches[-1]["interval"][1] == 6.0
    assert all(a["interval"][1] == b["interval"][0] for a, b in itertools.pairwise(stretches))
    reference = dn.solve(late_fast, "cG(3)", tolerance=1e-10)(6.0)
    error = np.abs(sol(6.0) - reference).max()
    errors = [np.abs(dn.solve(late_fast, m, tolerance=TOL)(6.0) - reference).max()
              for m in ("cG(2)", "mcG(2)")]
    assert error < 10 * max(errors), (error, errors)


def test_switched_solution_is_one_solution(cost_model, late_fast):
    """Evaluable and continuous across the switch, every component covering [t0, T], the
    counters summed, and estimate_error works on it."""
    sol = dn.solve(late_fast, "auto", tolerance=TOL, number_of_samples=11)
    ts = next(c["t"] for c in sol.stats["family choice"]["checks"] if c["switched"])
    across = sol([ts - 1e-12, ts, ts + 1e-12])  # (|U'| < 1e4: 1e-8 apart at most)
    assert np.abs(across[:, 0] - across[:, 2]).max() < 1e-7
    np.testing.assert_array_equal(sol.t, np.linspace(0.0, 6.0, 11))
    np.testing.assert_array_equal(sol.y[:, -1], sol(6.0))
    for i in (0, late_fast.N - 1):
        t_start, k = sol.time_steps(i)
        assert t_start[0] == 0.0 and np.isclose(t_start[-1] + k[-1], 6.0)
        np.testing.assert_allclose(t_start[1:], (t_start + k)[:-1], rtol=0, atol=1e-12)
    assert sol.stats["elements"] == len(sol.k) == sol.stats["elements per component"].sum()
    assert sol.parameters["tolerance"] == TOL
    estimate = dn.estimate_error(sol, {"x60": 1.0})
    assert np.isfinite(estimate.value) and estimate.bound >= abs(estimate.value)


def test_uniform_chain_does_not_switch(cost_model):
    """Without scale separation every component takes the same step: cG(2) throughout,
    the other variant never even measured."""
    ode = mass_spring_chain(40, T=200.0)[0]
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2)" and not sol.multi, choice
    assert choice["checks"] == [] and len(choice["stretches"]) >= 4
    direct = dn.solve(ode, "cG(2)", tolerance=1e-6)
    assert np.abs(sol(200.0) - direct(200.0)).max() < 1e-4


def test_fast_scale_ending_switches_back(cost_model):
    """A fast oscillator that slows to the others' frequency at t = 3 of T = 12: mcG(2)
    while it is fast, cG(2) again once the second half of a stretch shows one scale only.
    (With T = 6 what is left after the trial is too short to pay an mcG(2) restart under
    the cost model, whose start of every component active is dear: mcG(2) to T.)"""
    ode = _ramped_bank(3.0, -1, T=12.0)
    sol = dn.solve(ode, "auto", tolerance=TOL)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2) -> mcG(2) -> cG(2)", choice
    back = choice["checks"][-1]
    assert back["from"] == "mcG(2)" and back["switched"] and 3.0 < back["t"] < 12.0, choice
    # the cost ratio of the predictions: the prior until both variants ran stretches, then
    # the measured one, which recovers the cost model's
    ratios = [s["cost ratio"] for s in choice["stretches"] if s.get("cost ratio")]
    assert ratios[0] == (family.COST_RATIO, "prior") and ratios[-1][1] == "measured"
    assert ratios[-1][0] == pytest.approx(family.COST_RATIO)
    # the joined solution (mono, multi, mono) is as accurate as either variant's at T, and
    # its dual estimate works
    reference = dn.solve(ode, "cG(3)", tolerance=1e-10)(12.0)
    errors = [np.abs(dn.solve(ode, m, tolerance=TOL)(12.0) - reference).max()
              for m in ("cG(2)", "mcG(2)")]
    error = np.abs(sol(12.0) - reference).max()
    assert error < 10 * max(errors), (error, errors)
    estimate = dn.estimate_error(sol, {"x0": 1.0})
    assert np.isfinite(estimate.value) and estimate.bound >= abs(estimate.value)


def test_late_rate_and_prediction_see_the_second_half(late_fast):
    """A cG(2) stretch over [1, 3] is slow until the ramp at 2: its rate is that of its
    second half, and mcG(2) is predicted from the spread there (one component of 122
    fast), not from the single scale before."""
    parameters = {"tolerance": TOL, "number_of_samples": 2, "calibrate_tolerance": False}
    sol, _ = family._solve_on(driver.solve, late_fast, 1.0, 3.0, late_fast.u0, "cG(2)",
                              parameters)
    late = family._late(sol)
    assert family._steady_rate(sol, 1.0) == pytest.approx(late.sum() / len(sol.k) / 1.0)
    share = family._multi_elements_late(sol, np.full(late_fast.N, TOL), TOL)
    assert share < 0.25, share
    before, _ = family._solve_on(driver.solve, late_fast, 0.0, 1.0, late_fast.u0, "cG(2)",
                                 parameters)
    assert family._multi_elements_late(before, np.full(late_fast.N, TOL), TOL) > 2 * share


def test_small_system_is_solved_once(cost_model):
    """N < COST_RATIO x MULTI_ELEMENTS x SWITCH_MARGIN: mcG(2) cannot be predicted cheaper,
    so no stretches: the mono-adaptive solve itself, goal and all."""
    ode = mass_spring_chain(10, T=20.0)[0]
    assert ode.N < family.COST_RATIO * family.MULTI_ELEMENTS * family.SWITCH_MARGIN
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert "20 components" in choice["decided once"] and choice["stretches"] == []
    assert choice["method"] == sol.stats["method"] == "cG(2)"
    direct = dn.solve(ode, "cG(2)", tolerance=1e-6)
    np.testing.assert_array_equal(sol.values, direct.values)


def test_scale_separation_switches_once(cost_model):
    """One oscillator 1000x faster than 200 others from the start: mcG(2) after the first
    stretch, and no switch back."""
    ode = oscillator_bank(n=200, w=1000.0, T=0.5).ode
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2) -> mcG(2)", choice
    assert [c["switched"] for c in choice["checks"]] == [True]
    assert choice["checks"][0]["t"] == pytest.approx(0.005)
    # the trial (4 % of T) found every component active again at its start: the stretch
    # after it is longer than the 16 % of the schedule, so that restarts stay cheap
    trial, after = choice["stretches"][1:3]
    assert trial["trial"] and trial["interval"] == pytest.approx([0.005, 0.025])
    assert after["interval"][1] - after["interval"][0] > 0.16 * 0.5


def test_decided_once_for_output_parameters(cost_model):
    """Sample times and a history kept as samples refer to [t0, T]: decided after the first
    stretch, then that variant's own solve."""
    ode = mass_spring_chain(20, T=20.0)[0]
    sol = dn.solve(ode, "auto", sample_times=[5.0, 20.0], dense_output=False)
    choice = sol.stats["family choice"]
    assert "decided once" in choice and len(choice["stretches"]) == 1
    np.testing.assert_array_equal(sol.t, [5.0, 20.0])
    direct = dn.solve(ode, choice["method"], sample_times=[5.0, 20.0], dense_output=False)
    np.testing.assert_array_equal(sol.y, direct.y)


def test_error_at_T_of_stretches_is_estimated(cost_model):
    """A run in stretches is estimated on the joined solution, as its base method's run
    is: a 30-mass chain with 2 springs 1e6 stiffer at 1e-6 was 371 x the tolerance off,
    and silent, where cG(2) alone warned."""
    problem = chain_problem(n=30, stiffness=1e6, stiff_springs=2, T=0.1)
    with pytest.warns(dn.ToleranceWarning, match="error at T"):
        sol = dn.solve(problem.ode, "auto", tolerance=1e-6)
    assert "decided once" not in sol.stats["family choice"]
    U = sol(0.1)
    error, _ = global_error.scaled(U - problem.final, U, 1e-6, 1e-6)
    assert error > 10e-6
    assert sol.stats["global error estimate"] == pytest.approx(error, rel=0.5)


def test_failing_stretch_is_not_silent():
    """A stretch that fails raises what went wrong."""
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(mass_spring_chain(4, T=100.0)[0], "auto", maximum_steps=3)


def test_maximum_steps_bounds_the_whole_solve():
    """maximum_steps counts the time slabs of every kept stretch, not of each one."""
    ode = mass_spring_chain(20, T=100.0)[0]  # (N = 40: solved in stretches)
    slabs = dn.solve(ode, "cG(2)", tolerance=TOL).stats["time slabs"]
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(ode, "auto", tolerance=TOL, maximum_steps=slabs // 2)
    sol = dn.solve(ode, "auto", tolerance=TOL, maximum_steps=3 * slabs)
    assert sol.t[-1] == ode.T


def test_losing_trial_among_mono_stretches_is_discarded(cost_model, monkeypatch):
    """A multi-adaptive trial predicted cheap but measured dearer does not continue, and
    among mono-adaptive stretches it is solved again by cG(2): the solution stays
    mono-adaptive, its stretches contiguous, every check recorded."""
    monkeypatch.setattr(family, "MULTI_ELEMENTS", 1e-3)  # mcG(2) predicted ~free
    ode = mass_spring_chain(20, T=50.0)[0]
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2)" and not sol.multi, choice
    assert choice["checks"] and not any(c["switched"] for c in choice["checks"])
    assert all(c["measured"] >= c["rate"] for c in choice["checks"])
    stretches = choice["stretches"]
    assert all(s["method"] == "cG(2)" for s in stretches)
    assert all(a["interval"][1] == b["interval"][0] for a, b in itertools.pairwise(stretches))
    direct = dn.solve(ode, "cG(2)", tolerance=1e-6)
    assert np.abs(sol(50.0) - direct(50.0)).max() < 1e-4


def test_joined_stretches_evaluate_as_the_stretches(late_fast):
    """A cG(2) stretch and an mcG(2) stretch joined in the multi-adaptive form: at any time
    the joined solution is the stretch's own polynomial (U: the multi-adaptive form reads
    the element polynomial, not cG(q)'s dense value)."""
    parameters = {"tolerance": TOL, "number_of_samples": 2, "calibrate_tolerance": False}
    first, _ = family._solve_on(driver.solve, late_fast, 0.0, 2.5, late_fast.u0, "cG(2)",
                                parameters)
    second, _ = family._solve_on(driver.solve, late_fast, 2.5, 3.0, first(2.5), "mcG(2)",
                                 parameters)
    joined = family._joined(late_fast, [first, second], 5)
    assert joined.multi and joined.stats["method"] == "cG(2) -> mcG(2)"
    assert joined.stats["elements"] == first.stats["elements"] + second.stats["elements"]
    # the cG(2) slabs stay shared slabs until the elements are read, then every
    # component owns them: the same polynomials either way
    assert isinstance(joined, MixedSolution)
    times = np.random.default_rng(1).uniform(0.0, 3.0, 50)
    for merged in (False, True):
        if merged:
            assert len(joined.t_start) == joined.stats["elements per component"].sum()
        for t in times:
            piece = first if t <= 2.5 else second
            own = piece._galerkin(np.array([t]))[:, 0]
            np.testing.assert_allclose(joined(t), own, rtol=0, atol=1e-13)


def test_carried_steps_follow_the_components_errors():
    """Entering mcG(2) after cG(2), a component gets the common step over its share of the
    largest local error, at most MAX_STEP_GROWTH x: the fast oscillator keeps the common
    step, slow ones get larger ones."""
    bank = oscillator_bank(n=20, w=1000.0, T=0.02).ode
    sol = dn.solve(bank, "cG(2)", tolerance=1e-6, calibrate_tolerance=False)
    atol = np.full(bank.N, 1e-6)
    steps = family._component_steps(sol, atol, 1e-6)
    common = sol.stats["next time step"]
    assert np.all(steps >= common) and np.all(steps <= family.MAX_STEP_GROWTH * common)
    fast = [bank.N - 2, bank.N - 1]  # x_f, v_f: the last two states
    assert steps[fast].max() < 2 * common and np.median(steps) > 3 * common


def test_restart_cost_from_two_stretches():
    """c_j = F + r L_j: F from two stretches, and never negative (timing noise)."""
    assert family._restart_cost([(1.0, 3.0), (4.0, 6.0)]) == pytest.approx(2.0)
    assert family._restart_cost([(1.0, 1.0), (4.0, 8.0)]) == 0.0


def test_shortest_stretch_bounds_the_restart_share():
    """A stretch of 2 that took 3 at a steady rate 1 had a start of 1: the next is 1 /
    (RESTART_SHARE x 1) long at least; a larger fixed cost per call, or restart measured
    before, counts instead."""
    share = family.RESTART_SHARE
    assert family._shortest_stretch(3.0, 1.0, 2.0, 0.0) == pytest.approx((1.0 / share, 1.0))
    assert family._shortest_stretch(3.0, 1.0, 2.0, 2.0) == pytest.approx(
        (2.0 / (share * 0.5), 2.0))
    assert family._shortest_stretch(3.0, 1.5, 2.0, 0.0) == (0.0, 0.0)


def test_mono_stretches_follow_the_schedule(monkeypatch):
    """A solve's fixed cost (a small problem's) does not lengthen mono-adaptive stretches:
    a restart costs only it, and a long stretch would see a change of scales late (1, 4, 16,
    20, 20, 20, 19 % of [t0, T]); the same solution as without a fixed cost."""
    ode = mass_spring_chain(20, T=50.0)[0]
    _model_costs(monkeypatch, 0.0)
    cut = dn.solve(ode, "auto", tolerance=1e-6)
    monkeypatch.undo()
    _model_costs(monkeypatch, 1e-3)
    dear = dn.solve(ode, "auto", tolerance=1e-6)
    for sol in (cut, dear):
        lengths = [s["interval"][1] - s["interval"][0]
                   for s in sol.stats["family choice"]["stretches"]]
        np.testing.assert_allclose(lengths, np.array([1, 4, 16, 20, 20, 20, 19]) * 0.5)
    assert dear.stats["method"] == "cG(2)"
    assert np.abs(dear(50.0) - cut(50.0)).max() < 1e-5


def test_stretch_end_leaves_no_stretch_too_short_to_pay():
    """No sliver: T when less than half a stretch, or less than the least length that pays
    a restart, would be left after it."""
    assert family._stretch_end(0.0, 4.0, 10.0) == 4.0
    assert family._stretch_end(0.0, 4.0, 10.0, rest=7.0) == 10.0
    assert family._stretch_end(0.0, 4.0, 5.9) == 5.9
    assert family._stretch_end(1.0, 4.0, 10.0, rest=5.0) == 5.0

