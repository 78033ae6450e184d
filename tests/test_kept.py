"""dn.solve's kept solvers (dolfinode.kept): a repeated call with the same options takes
a prepared Solver's path, bitwise as a first call, and never a stale state."""
import gc
import pickle
import sys
import threading
import weakref

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn

u, v, k, c = sp.symbols("u v k c")


def declare(u0=(1.0, 0.0), T=2.0, t0=0.0, **params):
    """A damped oscillator, a fresh declaration (its first dn.solve takes the general path)."""
    values = {k: 4.0, c: 0.5, **{sp.Symbol(name): value for name, value in params.items()}}
    return dn.ODE({u: v, v: -k * u - c * v}, u0=list(u0), T=T, t0=t0, params=values)


def assert_same(sol, reference):
    """Bitwise the same solution: element ends, values, samples, counts."""
    np.testing.assert_array_equal(sol.t_start, reference.t_start)
    np.testing.assert_array_equal(sol.values, reference.values)
    np.testing.assert_array_equal(sol.y, reference.y)
    np.testing.assert_array_equal(sol(np.linspace(sol.t[0], sol.t[-1], 37)),
                                  reference(np.linspace(sol.t[0], sol.t[-1], 37)))
    timeless = ("solve time", "compile time")
    np.testing.assert_equal({key: value for key, value in sol.stats.items()
                             if key not in timeless},
                            {key: value for key, value in reference.stats.items()
                             if key not in timeless})
    np.testing.assert_equal(sol.parameters, reference.parameters)


@pytest.fixture
def no_general_path(monkeypatch):
    """Make dn.solve's general path fail: a call that passes takes a kept solver."""
    def general_path(*args, **kwargs):
        raise AssertionError("dn.solve took the general path")

    driver = sys.modules["dolfinode.solve"]  # (dn.solve is the function)
    return lambda: monkeypatch.setattr(driver, "solve_lowered", general_path)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "mcG(1)"])
def test_repeated_calls_are_kept_and_bitwise_a_first_call(method, no_general_path):
    ode = declare()
    first = dn.solve(ode, method, tolerance=1e-5)
    second = dn.solve(ode, method, tolerance=1e-5)
    no_general_path()
    third = dn.solve(ode, method, tolerance=1e-5)
    for sol in (second, third):
        assert_same(sol, first)
    assert third.values is not second.values and third.parameters is not second.parameters
    assert third.ode.params[k] == 4.0


@pytest.mark.parametrize("method", ["cG(1)", "mcG(1)"])
def test_a_repeated_long_solve_goes_on_from_the_kept_buffers(method, no_general_path,
                                                             monkeypatch):
    """A kept solve longer than its buffers (5 slabs or elements here) goes on into new
    ones as the first call did: bitwise the first call, and not solved again."""
    monkeypatch.setattr(sys.modules["dolfinode.solve"], "_CHUNK_LIMIT", 5)
    ode = declare()
    first = dn.solve(ode, method, tolerance=1e-5)
    assert first.stats["time slabs"] > 10
    second = dn.solve(ode, method, tolerance=1e-5)
    no_general_path()
    monkeypatch.setattr(sys.modules["dolfinode.solver"], "solve_lowered", None)
    third = dn.solve(ode, method, tolerance=1e-5)
    solver, = [s for s in ode._kept_solvers.solvers.values() if s]
    assert solver._continued == 2
    for sol in (second, third):
        assert_same(sol, first)


def test_kept_solves_follow_every_value_of_the_declaration(no_general_path):
    references = [dn.solve(declare(**values), "dG(2)", tolerance=1e-6) for values in (
        {"k": 9.0}, {"k": 1.0, "c": 0.0}, {"u0": (0.5, -1.0), "k": 1.0, "c": 0.0},
        {"u0": (0.5, -1.0), "t0": 0.5, "T": 3.0, "k": 1.0, "c": 0.0}, {})]
    ode = declare()
    for _ in range(2):
        before = dn.solve(ode, "dG(2)", tolerance=1e-6)
    kept = before.values.copy()
    no_general_path()
    ode.params[k] = 9.0  # set in place
    assert_same(dn.solve(ode, "dG(2)", tolerance=1e-6), references[0])
    ode.params = {k: 1.0, c: 0.0}  # a new mapping
    assert_same(dn.solve(ode, "dG(2)", tolerance=1e-6), references[1])
    ode.u0 = [0.5, -1.0]
    assert_same(dn.solve(ode, "dG(2)", tolerance=1e-6), references[2])
    ode.T = 3.0
    ode.t0 = 0.5
    sol = dn.solve(ode, "dG(2)", tolerance=1e-6)
    assert_same(sol, references[3])
    assert sol.ode.T == 3.0 and sol.ode.params[k] == 1.0
    # earlier solutions are left alone: their values, and the declaration they evaluate on
    np.testing.assert_array_equal(before.values, kept)
    np.testing.assert_array_equal(before([0.0, 0.2]), references[4]([0.0, 0.2]))
    assert before.ode.t0 == 0.0 and before.ode.params[k] == 4.0


def test_other_options_are_never_served_by_a_kept_solver():
    ode = declare()
    for _ in range(3):
        dn.solve(ode, "cG(2)", tolerance=1e-6, maximum_steps=1000)
    for options in ({"method": "dG(2)", "tolerance": 1e-6, "maximum_steps": 1000},
                    {"method": "cG(2)", "tolerance": 1e-4, "maximum_steps": 1000},
                    {"method": "cG(2)", "tolerance": 1e-6, "maximum_steps": 1000,
                     "sample_times": (0.0, 0.5, 2.0)},
                    {"method": "cG(2)", "tolerance": 1e-6, "maximum_steps": 1000,
                     "maximum_time_step": 0.01}):
        for _ in range(3):
            assert_same(dn.solve(ode, **options), dn.solve(declare(), **options))
    for _ in range(3):  # (a kept solver's run that stops early is solved again and fails)
        with pytest.raises(dn.SolverError, match="maximum_steps was reached"):
            dn.solve(ode, "cG(2)", tolerance=1e-6, maximum_steps=3)
    with pytest.raises(ValueError, match="maximum_steps"):  # equal to 1000, not an integer
        dn.solve(ode, "cG(2)", tolerance=1e-6, maximum_steps=1000.0)


def test_an_absolute_tolerance_per_state_is_kept_by_its_values(no_general_path):
    def reference(atol):  # (a fresh declaration: the general path)
        return dn.solve(declare(), "dG(2)", tolerance=1e-4, absolute_tolerance=np.array(atol))

    loose, tight = reference([1e-7, 1e-6]), reference([1e-7, 1e-9])
    ode = declare()
    atol = np.array([1e-7, 1e-6])

    def solve(atol):
        return dn.solve(ode, "dG(2)", tolerance=1e-4, absolute_tolerance=atol)

    seen = [solve(atol), solve(atol), solve([1e-7, 1e-6]), solve([1e-7, 1e-6])]
    atol[1] = 1e-9  # changed in place: the solver kept for the old values is not taken
    seen += [solve(atol), solve(atol)]
    no_general_path()
    seen += [solve(atol), solve([1e-7, 1e-6])]
    for sol, expected in zip(seen[1:], [loose, loose, loose, tight, tight, tight, loose]):
        assert_same(sol, expected)
    assert tight.stats["time slabs"] > loose.stats["time slabs"]


def test_events_and_invalid_options_take_the_general_path():
    ode = declare()
    for _ in range(3):
        sol = dn.solve(ode, "cG(2)", tolerance=1e-6, events=(u,))
        assert len(sol.t_events[0]) == 1  # u = 0 at t ~ pi / (2 x 1.98) on [0, 2]
        with pytest.raises(ValueError, match="tolerance"):
            dn.solve(ode, "cG(2)", tolerance=-1.0)


def test_a_busy_kept_solver_is_not_shared_between_threads():
    ode = declare()
    reference = dn.solve(ode, "cG(2)", tolerance=1e-6)
    dn.solve(ode, "cG(2)", tolerance=1e-6)  # a kept solver from here on
    kept = ode.__dict__["_kept_solvers"]
    with kept.lock:  # another thread solving: this one takes the general path
        results = []
        worker = threading.Thread(
            target=lambda: results.append(dn.solve(ode, "cG(2)", tolerance=1e-6)))
        worker.start()
        worker.join(timeout=60)
        assert results, "a solve waited for another thread's kept solver"
    assert_same(results[0], reference)


def test_copies_of_the_declaration_keep_their_own_solvers():
    ode = declare()
    for _ in range(3):
        sol = dn.solve(ode, "cG(2)", tolerance=1e-6)
    ode.params[k] = 9.0
    # the solved snapshot and a pickled copy carry k = 4 and no solver of ode's
    again = dn.solve(sol.ode, "cG(2)", tolerance=1e-6)
    copy = pickle.loads(pickle.dumps(sol.ode))
    for other in (again, dn.solve(copy, "cG(2)", tolerance=1e-6),
                  dn.solve(copy, "cG(2)", tolerance=1e-6)):
        assert_same(other, sol)


def test_a_declaration_solved_once_is_freed_without_the_cycle_collector():
    ode = declare()
    dn.solve(ode, "cG(2)", tolerance=1e-6)
    gone = weakref.ref(ode)
    gc.disable()
    try:
        del ode
        assert gone() is None
    finally:
        gc.enable()
