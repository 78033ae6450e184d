"""method="auto": the mono- or multi-adaptive variant, switched between in stretches.

The decisions rest on measured CPU rates; the tests that assert them measure "CPU time" with
a cost model instead (elements x 1 for cG(q), x COST_RATIO = 12 for mcG(q): the ratio is
11-22 on the benchmark problems), so that they do not depend on the machine's load.
"""
import importlib
import itertools

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode import family
from dolfinode.bench.multirate import oscillator_bank
from dolfinode.family import auto_base
from dolfinode.problems import mass_spring_chain

TOL = 1e-5
driver = importlib.import_module("dolfinode.solve")  # (dn.solve is the function)


@pytest.fixture
def cost_model(monkeypatch):
    """CPU time = elements x (COST_RATIO multi-adaptive, 1 mono-adaptive) x 1e-7 s."""
    spent = [0.0]
    solve = driver.solve

    def counted(ode, method, **parameters):
        sol = solve(ode, method, **parameters)
        spent[0] += sol.stats["elements"] * (family.COST_RATIO if sol.multi else 1) * 1e-7
        return sol

    monkeypatch.setattr(driver, "solve", counted)
    monkeypatch.setattr(family, "_clock", lambda: spent[0])


@pytest.fixture(scope="module")
def late_fast():
    """60 oscillators of frequency 1..2 and one whose frequency ramps from 1 to 100 around
    t = 2 (of T = 6): one time scale until the ramp, two after it."""
    n, T = 60, 6.0
    x, v = sp.symbols(f"x:{n + 1}"), sp.symbols(f"v:{n + 1}")
    omega = list(np.linspace(1.0, 2.0, n)) + [1 + 99 * (1 + sp.tanh(5 * (dn.t - 2))) / 2]
    rhs = {}
    for i in range(n + 1):
        rhs[x[i]] = v[i]
        rhs[v[i]] = -omega[i] ** 2 * x[i]
    return dn.ODE(rhs, u0={**dict.fromkeys(x, 1.0), **dict.fromkeys(v, 0.0)}, T=T)


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
    assert len(switch) == 1 and 2.0 < switch[0]["t"] < 6.0, choice
    assert switch[0]["measured"] * family.SWITCH_MARGIN < switch[0]["rate"]
    assert choice["method"] == "mcG(2)" and sol.multi
    stretches = choice["stretches"]
    assert stretches[0]["interval"][0] == 0.0 and stretches[-1]["interval"][1] == 6.0
    assert all(a["interval"][1] == b["interval"][0] for a, b in itertools.pairwise(stretches))
    reference = dn.solve(late_fast, "cG(3)", tolerance=1e-10)(6.0)
    error = np.abs(sol(6.0) - reference).max()
    errors = [np.abs(dn.solve(late_fast, m, tolerance=TOL, calibrate_tolerance=False)(6.0)
                     - reference).max() for m in ("cG(2)", "mcG(2)")]
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
    direct = dn.solve(ode, "cG(2)", tolerance=1e-6, calibrate_tolerance=False)
    assert np.abs(sol(200.0) - direct(200.0)).max() < 1e-4


def test_scale_separation_switches_once(cost_model):
    """One oscillator 1000x faster than 200 others from the start: mcG(2) after the first
    stretch, and no switch back."""
    ode = oscillator_bank(n=200, w=1000.0, T=0.5).ode
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert sol.stats["method"] == "cG(2) -> mcG(2)", choice
    assert [c["switched"] for c in choice["checks"]] == [True]
    assert choice["checks"][0]["t"] == pytest.approx(0.005)


def test_decided_once_for_output_parameters(cost_model):
    """Sample times and a history kept as samples refer to [t0, T]: decided after the first
    stretch, then that variant's own solve."""
    ode = mass_spring_chain(10, T=20.0)[0]
    sol = dn.solve(ode, "auto", sample_times=[5.0, 20.0], dense_output=False)
    choice = sol.stats["family choice"]
    assert "decided once" in choice and len(choice["stretches"]) == 1
    np.testing.assert_array_equal(sol.t, [5.0, 20.0])
    direct = dn.solve(ode, choice["method"], sample_times=[5.0, 20.0], dense_output=False,
                      calibrate_tolerance=False)  # as "auto" solves
    np.testing.assert_array_equal(sol.y, direct.y)


def test_failing_stretch_is_not_silent():
    """A stretch that fails raises what went wrong."""
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(mass_spring_chain(4, T=100.0)[0], "auto", maximum_steps=3)


def test_maximum_steps_bounds_the_whole_solve():
    """maximum_steps counts the time slabs of every kept stretch, not of each one."""
    ode = mass_spring_chain(4, T=100.0)[0]
    slabs = dn.solve(ode, "cG(2)", tolerance=TOL, calibrate_tolerance=False).stats["time slabs"]
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(ode, "auto", tolerance=TOL, maximum_steps=slabs // 2)
    sol = dn.solve(ode, "auto", tolerance=TOL, maximum_steps=3 * slabs)
    assert sol.t[-1] == ode.T
