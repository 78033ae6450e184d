"""dn.Solver: validated once, then solves as dn.solve does, with the values of each call."""
import sys

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile.jit import Loop
from dolfinode.solution import PreparedSolution

u, v, k = sp.symbols("u v k")


@pytest.fixture(autouse=True)
def checked_loops(monkeypatch):
    """Type-check every call of a compiled loop: the drivers must pass the loops' exact
    argument types, which their unchecked calls assume."""
    monkeypatch.setattr(Loop, "checked", True)


@pytest.fixture
def oscillator():
    return dn.ODE({u: v, v: -k * u}, u0={u: 1.0, v: 0.0}, T=2.0, params={k: 4.0})


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)", "mcG(1)"])
def test_solver_is_bitwise_dn_solve_of_the_varied_ode(oscillator, method):
    solver = dn.Solver(oscillator, method=method, tolerance=1e-6)
    sol = solver.solve(u0=[0.5, 0.0], params={k: 9.0}, T=1.5)
    reference = dn.solve(dn.vary(oscillator, {"u0": [0.5, 0.0], k: 9.0, "T": 1.5}),
                         method=method, tolerance=1e-6)
    np.testing.assert_array_equal(sol.values, reference.values)
    np.testing.assert_array_equal(sol.t_start, reference.t_start)
    assert sol.stats["f evaluations"] == reference.stats["f evaluations"]


@pytest.mark.parametrize("method", ["auto", "auto:dG(1)"])
def test_an_auto_solver_solves_as_dn_solve_of_the_varied_ode(oscillator, method):
    """method="auto" chooses mono or multi-adaptive on every call, as dn.solve does (it
    raised "unknown method 'auto': use ... or 'auto'")."""
    solver = dn.Solver(oscillator, method=method, tolerance=1e-6)
    times = np.linspace(0.0, 1.5, 7)
    for omega in (3.0, 1.0):
        sol = solver.solve(u0=[0.5, 0.0], params={k: omega**2}, T=1.5)
        reference = dn.solve(dn.vary(oscillator, {"u0": [0.5, 0.0], k: omega**2, "T": 1.5}),
                             method=method, tolerance=1e-6)
        np.testing.assert_array_equal(sol(times), reference(times))


def test_solver_follows_the_parameters_of_each_call(oscillator):
    solver = dn.Solver(oscillator, method="dG(2)", tolerance=1e-8)
    for omega in (3.0, 1.0, 2.0):  # u = u0 cos(omega t) for k = omega^2
        sol = solver.solve(u0=[0.5, 0.0], params={k: omega**2})
        assert sol.ode.params[k] == omega**2
        assert sol(2.0)[0] == pytest.approx(0.5 * np.cos(2.0 * omega), abs=1e-6)
    # the declaration itself is left as it was; by name works as by symbol
    assert oscillator.params[k] == 4.0 and oscillator.T == 2.0
    by_name = solver.solve(params={"k": 4.0})
    np.testing.assert_array_equal(by_name.values, dn.solve(oscillator, method="dG(2)",
                                                           tolerance=1e-8).values)


def test_solver_times_and_estimate_error_use_the_call_values(oscillator):
    solver = dn.Solver(oscillator, method="cG(2)", tolerance=1e-8)
    sol = solver.solve(t0=1.0, T=3.0, params={k: 1.0}, u0=[1.0, 0.0])
    assert sol.t[0] == 1.0 and sol.t[-1] == 3.0
    assert sol(3.0)[0] == pytest.approx(np.cos(2.0), abs=1e-6)
    est = dn.estimate_error(sol, goal={u: 1.0})
    assert abs(est.value) < 1e-6


def test_solver_rejects_bad_input_up_front_and_per_call(oscillator):
    with pytest.raises(TypeError):
        dn.Solver("not an ode")
    with pytest.raises(ValueError, match="tolerance"):
        dn.Solver(oscillator, tolrance=1e-6)
    with pytest.raises(ValueError):
        dn.Solver(oscillator, method="xG(2)")
    solver = dn.Solver(oscillator, method="cG(1)")
    with pytest.raises(ValueError):
        solver.solve(params={sp.Symbol("q"): 1.0})
    with pytest.raises(ValueError):
        solver.solve(u0=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        solver.solve(T=-1.0)


def _assert_same_solution(sol, reference):
    """Bitwise the same elements, samples and counters, and a declaration with the same
    values."""
    np.testing.assert_array_equal(sol.t_start, reference.t_start)
    np.testing.assert_array_equal(sol.k, reference.k)
    np.testing.assert_array_equal(sol.values, reference.values)
    np.testing.assert_array_equal(sol.y, reference.y)
    for name in ("time slabs", "f evaluations", "rejected steps", "nonlinear iterations"):
        assert sol.stats[name] == reference.stats[name]
    assert (sol.ode.t0, sol.ode.T, dict(sol.ode.params)) == (
        reference.ode.t0, reference.ode.T, dict(reference.ode.params))
    np.testing.assert_array_equal(sol.ode.u0, reference.ode.u0)


@pytest.mark.parametrize("method", ["cG(1)", "dG(0)", "mdG(0)"])
def test_successive_calls_are_bitwise_dn_solve_and_keep_their_own_arrays(oscillator, method):
    solver = dn.Solver(oscillator, method=method, tolerance=1e-5)
    calls = [{"u0": {u: 0.5, "v": 0.1}, "params": {"k": 9.0}},
             {"u0": np.array([1.0, -1.0]), "t0": 0.5, "T": 1.0},
             {"params": {k: 1.0}, "T": 3.0}]
    solutions = [solver.solve(**call) for call in calls]
    for call, sol in zip(calls, solutions):  # the later calls left the earlier results alone
        variation = {**call.get("params", {}),
                     **{name: call[name] for name in ("u0", "T", "t0") if name in call}}
        reference = dn.solve(dn.vary(oscillator, variation), method=method, tolerance=1e-5)
        _assert_same_solution(sol, reference)


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)"])
def test_a_solution_sharing_the_buffers_is_its_copy_until_the_next_call(oscillator, method):
    """A prepared solution reads the solver's buffers until it is read or the next call
    writes them (PreparedSolution): evaluated before and after it copies them, bitwise
    dn.solve's; its arrays, pickled or read, are its own."""
    import pickle

    times = np.linspace(0.0, 2.0, 41)
    options = {"tolerance": 1e-6, "estimate_global_error": False}  # (the estimate reads them)
    reference = dn.solve(oscillator, method=method, **options)
    solver = dn.Solver(oscillator, method=method, **options)
    sol, held = solver.solve(), solver.solve()
    assert "_shared" in held.__dict__  # (sol copied its elements when held was solved)
    np.testing.assert_array_equal(held(times), reference(times))
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(held))(times), reference(times))
    assert "_shared" not in held.__dict__  # (pickling copied them)
    shared = solver.solve()
    values = shared.values  # (a read copies)
    solver.solve(u0=[0.3, 0.2], params={k: 1.0})
    for solution in (sol, held, shared):
        _assert_same_solution(solution, reference)
        np.testing.assert_array_equal(solution(times), reference(times))
    np.testing.assert_array_equal(values, reference.values)


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)"])
def test_the_lowered_f_of_dense_values_is_made_once_per_declaration_solved(oscillator,
                                                                            method):
    """The solutions of repeated calls share the lowered f their dense values read
    (_Solved.dense_rhs); new parameter values make another; a solution first evaluated
    after a later call with other values reads its own, bitwise dn.solve's."""
    times = np.linspace(0.0, 2.0, 41)
    options = {"tolerance": 1e-6, "estimate_global_error": False}
    solver = dn.Solver(oscillator, method=method, **options)
    first, second = solver.solve(), solver.solve()
    first(times)
    second(times)
    assert first._rhs is not None and first._rhs is second._rhs
    late = solver.solve()
    stiffer = solver.solve(params={k: 9.0})
    stiffer(times)
    assert stiffer._rhs is not first._rhs
    for sol, values in ((late, {k: 4.0}), (stiffer, {k: 9.0}), (first, {k: 4.0})):
        reference = dn.solve(dn.vary(oscillator, values), method=method, **options)
        np.testing.assert_array_equal(sol(times), reference(times))


@pytest.mark.parametrize("method", ["dG(2)", "mcG(1)"])
def test_a_solution_s_parameters_are_its_own(oscillator, method):
    """sol.parameters is a copy: changing it leaves the solver and its later solutions alone
    (they shared the solver's dict)."""
    solver = dn.Solver(oscillator, method=method, tolerance=1e-6)
    sol = solver.solve()
    sol.parameters["tolerance"] = 1.0
    later = solver.solve(params={k: 2.0})
    assert later.parameters["tolerance"] == 1e-6 and solver._params["tolerance"] == 1e-6
    later.parameters["maximum_steps"] = 1
    _assert_same_solution(solver.solve(), dn.solve(oscillator, method=method, tolerance=1e-6))


def test_a_solver_s_own_parameters_cannot_be_changed(oscillator):
    """A Solver checked and lowered its method and parameters once: changing them after was
    silently ignored (solver.parameters["tolerance"] = 1e-3 solved at 1e-8 still)."""
    solver = dn.Solver(oscillator, method="cG(2)", tolerance=1e-8)
    with pytest.raises(TypeError):
        solver.parameters["tolerance"] = 1e-3
    for name, value in [("parameters", {"tolerance": 1e-3}), ("method", "dG(1)"),
                        ("ode", oscillator)]:
        with pytest.raises(AttributeError):
            setattr(solver, name, value)
    assert solver.solve().parameters["tolerance"] == 1e-8 and solver.method == "cG(2)"


def test_kept_solvers_sharing_buffers_leave_an_earlier_solution_alone(oscillator):
    """dn.solve's kept solvers of one declaration share their buffers: a solution of one
    option set, still shared, copies them before a call with other options writes them."""
    first = {"tolerance": 1e-6, "estimate_global_error": False}  # (the estimate reads them)
    other = {"tolerance": 1e-4, "estimate_global_error": False}
    reference = dn.solve(dn.vary(oscillator, {}), "dG(2)", **first)
    for options in (first, other):
        dn.solve(oscillator, "dG(2)", **options)  # (the second call of each is kept)
    sol = dn.solve(oscillator, "dG(2)", **first)
    assert "_shared" in sol.__dict__
    dn.solve(oscillator, "dG(2)", **other)
    _assert_same_solution(sol, reference)


@pytest.mark.parametrize("method", ["dG(2)", "mcG(1)"])
def test_a_call_from_another_thread_leaves_a_running_call_alone(oscillator, method,
                                                                monkeypatch):
    """A Solver used by two threads at once: the second thread's call came while the first
    one's was in the prepared path, replaced the values of the solver's copy of the
    declaration and wrote its buffers, and the first call returned the second's solution,
    silently. Calls from a thread other than the first caller's solve a copy."""
    import threading

    solver = dn.Solver(oscillator, method=method, tolerance=1e-6)
    inside, other_done, results = threading.Event(), threading.Event(), {}
    original = dn.Solver._solve_prepared

    def paused(self, work):  # the first caller's call waits inside for the other's
        if threading.current_thread() is threading.main_thread():
            inside.set()
            assert other_done.wait(60)
        return original(self, work)

    def other():
        assert inside.wait(60)
        try:
            results["other"] = solver.solve(params={k: 9.0})
        finally:
            other_done.set()

    monkeypatch.setattr(dn.Solver, "_solve_prepared", paused)
    thread = threading.Thread(target=other)
    thread.start()
    results["first"] = solver.solve(params={k: 1.0})
    thread.join()
    for name, value in (("first", 1.0), ("other", 9.0)):
        reference = dn.solve(dn.vary(oscillator, {k: value}), method=method, tolerance=1e-6)
        _assert_same_solution(results[name], reference)


def _stopped_at(code, line):
    """A trace function raising KeyboardInterrupt (as Ctrl-C's handler does) when ``code``
    reaches ``line``."""
    def local(frame, event, arg):
        if event == "line" and frame.f_lineno == line:
            raise KeyboardInterrupt
        return local
    return lambda frame, event, arg: local if frame.f_code is code else None


@pytest.mark.parametrize("method", ["dG(2)", "mcG(1)"])
def test_a_call_stopped_at_any_line_leaves_the_solver_right(method):
    """A KeyboardInterrupt at any line of the code that writes a call's values and interval
    into the work space, or copies the last solution out of the buffers: the solution held
    from before and the next calls are bitwise dn.solve's. A stop there left the values or
    the interval marked as taken (the next call solved with the step bound of other values
    or the arrays of another interval) or a solution without its elements (KeyError)."""
    import inspect

    w = sp.Symbol("w")
    ode = dn.ODE({u: v, v: -k * u + sp.sin(w * dn.t)}, u0=[1.0, 0.0], T=2.0,
                 params={k: 4.0, w: 3.0})
    options = {"tolerance": 1e-6, "estimate_global_error": False}
    times = np.linspace(0.0, 1.5, 7)
    first, other = {"params": {k: 1.0, w: 3.0}}, {"params": {k: 9.0, w: 40.0}, "T": 1.5}
    references = [dn.solve(dn.vary(ode, {**call["params"], "T": call.get("T", 2.0)}),
                           method=method, **options) for call in (first, other)]
    solver = dn.Solver(ode, method=method, **options)
    stopped = 0
    for function in (dn.Solver._take_values, dn.Solver._workspace,
                     PreparedSolution._make_elements):
        lines, start = inspect.getsourcelines(function)
        for line in range(start + 1, start + len(lines)):
            held = solver.solve(**first)
            tracer = sys.gettrace()
            sys.settrace(_stopped_at(function.__code__, line))
            try:
                solver.solve(**other)
            except KeyboardInterrupt:
                stopped += 1
            finally:
                sys.settrace(tracer)
            np.testing.assert_array_equal(held(times), references[0](times))
            for call, reference in ((other, references[1]), (first, references[0])):
                np.testing.assert_array_equal(solver.solve(**call).y, reference.y)
    assert stopped > 20


def test_solver_takes_the_prepared_path_where_it_can(oscillator, monkeypatch):
    """A solve in memory takes one loop call into the kept buffers; events, breakpoints,
    samples only and modeling take the general path, with the same answers."""
    prepared = dn.Solver(oscillator, method="dG(1)")
    assert prepared._buffers is not None
    assert dn.Solver(oscillator, method="mcG(1)")._buffers is not None
    for parameters in ({"events": [u]}, {"dense_output": False}, {"breakpoints": [1.0]},
                       {"automatic_modeling": True}):
        assert dn.Solver(oscillator, method="dG(1)", **parameters)._buffers is None
    events = dn.Solver(oscillator, method="dG(1)", events=[u]).solve(params={k: 1.0})
    reference = dn.solve(dn.vary(oscillator, {k: 1.0}), method="dG(1)", events=[u])
    np.testing.assert_array_equal(events.t_events[0], reference.t_events[0])
    assert events.t_events[0][0] == pytest.approx(np.pi / 2, rel=1e-5)
    samples = dn.Solver(oscillator, method="dG(1)", dense_output=False).solve(u0=[2.0, 0.0])
    np.testing.assert_array_equal(samples.y, dn.solve(dn.vary(oscillator, {"u0": [2.0, 0.0]}),
                                                      method="dG(1)", dense_output=False).y)


def test_a_sparse_candidate_takes_the_prepared_path_once_its_storage_is_decided():
    """POLLU (20 components, a band of 15 + 15: its Newton storage is analysed by the first
    solve that needs Newton's method) on a fresh declaration: the first call takes the
    general path, the later ones the prepared path, bitwise the same solution."""
    from dolfinode.bench import problems

    ode = problems.pollu().ode
    options = {"tolerance": 1e-6, "estimate_global_error": False}
    solver = dn.Solver(ode, method="dG(3)", **options)
    assert solver._buffers is None
    first = solver.solve()
    assert solver._buffers is not None
    second = solver.solve()
    assert isinstance(second, PreparedSolution) and not isinstance(first, PreparedSolution)
    _assert_same_solution(second, first)


@pytest.mark.parametrize("method", ["cG(1)", "mcG(1)"])
def test_a_solve_longer_than_the_kept_buffers_goes_on_from_them(oscillator, method,
                                                                monkeypatch):
    """Kept buffers of 3 slabs (elements): the prepared solve goes on into new buffers as
    dn.solve does, to the same Solution, without solving again."""
    monkeypatch.setattr(sys.modules["dolfinode.solve"], "_CHUNK_LIMIT", 3)
    monkeypatch.setattr(sys.modules["dolfinode.solver"], "solve_lowered", None)
    solver = dn.Solver(oscillator, method=method, tolerance=1e-3, maximum_steps=400)
    sol = solver.solve(T=1.0)
    assert solver._continued == 1
    _assert_same_solution(sol, dn.solve(dn.vary(oscillator, {"T": 1.0}), method=method,
                                        tolerance=1e-3, maximum_steps=400))
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        solver.solve(T=50.0)


def test_solver_follows_the_declaration_as_it_is_at_each_call(oscillator):
    solver = dn.Solver(oscillator, method="dG(1)")
    oscillator.params[k] = 1.0
    oscillator.T = 1.0
    sol = solver.solve()
    assert sol.ode.params[k] == 1.0 and sol.ode.T == 1.0
    _assert_same_solution(sol, dn.solve(oscillator, method="dG(1)"))


@pytest.mark.parametrize("call, error, match", [
    ({"u0": [1.0, np.nan]}, ValueError, "u0 is not finite for v"),
    ({"u0": {u: 1.0}}, ValueError, "missing values for v"),
    ({"params": {"kk": 1.0}}, ValueError, "did you mean 'k'"),
    ({"params": {k: np.inf}}, ValueError, "parameter k must be finite"),
    ({"params": {k: "x"}}, TypeError, "parameter k must be a real number"),
    ({"params": [(k, 1.0)]}, TypeError, "params must be a dict"),
    ({"t0": 3.0}, ValueError, "larger than t0"),
    ({"T": np.inf}, ValueError, "T must be finite"),
])
def test_solver_names_the_bad_entry_of_a_call(oscillator, call, error, match):
    with pytest.raises(error, match=match):
        dn.Solver(oscillator, method="dG(1)").solve(**call)


def test_solver_of_a_template_system_is_bitwise_dn_solve():
    x, rate = sp.symbols("x rate")
    decay = dn.Template(slots=(x,), terms={x: -rate * x}, indices=[[0], [1]])
    ode = dn.TemplateODE(decay, u0=[1.0, 2.0], T=1.0, params={rate: 1.0})
    solver = dn.Solver(ode, method="cG(2)", tolerance=1e-8)
    sol = solver.solve(params={"rate": 2.0}, u0=[1.0, 1.0])
    _assert_same_solution(sol, dn.solve(dn.vary(ode, {rate: 2.0, "u0": [1.0, 1.0]}),
                                        method="cG(2)", tolerance=1e-8))
    np.testing.assert_allclose(sol(1.0), np.exp(-2.0), rtol=1e-6)


def test_the_prepared_work_space_is_kept_and_follows_each_call(monkeypatch):
    """The loop's arguments are made once per interval; the values of each call (the
    parameters, whose signs decide the floor of the values, u0, T) reach them: every call
    takes the prepared path and is bitwise dn.solve of the varied declaration."""
    x, rate = sp.symbols("x rate")
    ode = dn.ODE({x: rate - x}, u0=[0.5], T=1.0, params={rate: 1.0})  # x >= 0 iff rate >= 0
    solver = dn.Solver(ode, method="dG(1)", tolerance=1e-4)

    def general_path(*args):
        raise AssertionError("the prepared path gave way to the general one")

    monkeypatch.setattr("dolfinode.solver.solve_lowered", general_path)
    calls = [{}, {"params": {rate: -1.0}}, {"params": {rate: -1.0}, "u0": [-0.5]}, {},
             {"T": 2.0}, {"T": 2.0, "params": {rate: 2.0}}, {}]
    loops = []
    for call in calls:
        sol = solver.solve(**call)
        loops.append(solver._loop)
        variation = {**call.get("params", {}),
                     **{name: call[name] for name in ("u0", "T") if name in call}}
        _assert_same_solution(sol, dn.solve(dn.vary(ode, variation), method="dG(1)",
                                            tolerance=1e-4))
    assert loops[0] is loops[3] and loops[4] is loops[5]  # kept over calls of one interval
    assert loops[3] is not loops[4] and loops[5] is not loops[6]  # made again for another


@pytest.mark.parametrize("method, parameters", [
    ("cG(2)", {"fixed_time_step": True, "initial_time_step": 0.01}),
    ("mcG(1)", {"initial_time_step": {u: 1e-3, v: 2e-3}, "tolerance": 1e-5}),
    ("dG(1)", {"absolute_tolerance": {u: 1e-8, v: 1e-6}, "tolerance": 1e-5,
               "maximum_time_step": 0.05}),
])
def test_the_prepared_path_keeps_the_given_steps_and_tolerances(oscillator, monkeypatch,
                                                                method, parameters):
    """Steps and tolerances given to the Solver hold in every call of its kept work space
    (fixed steps, first steps per state, absolute tolerances per state, a largest step),
    bitwise as dn.solve, also after a new interval."""
    solver = dn.Solver(oscillator, method=method, **parameters)

    def general_path(*args):
        raise AssertionError("the prepared path gave way to the general one")

    monkeypatch.setattr("dolfinode.solver.solve_lowered", general_path)
    for call in ({}, {"params": {k: 9.0}, "u0": [0.5, 0.1]}, {"T": 1.0}):
        variation = {**call.get("params", {}),
                     **{name: call[name] for name in ("u0", "T") if name in call}}
        _assert_same_solution(solver.solve(**call), dn.solve(dn.vary(oscillator, variation),
                                                             method=method, **parameters))


def test_values_equal_to_the_last_calls_are_reused_and_bad_ones_still_refused(oscillator):
    """A call whose u0 and parameter values equal the last call's (in new objects, by name,
    as a tuple) solves bitwise as it did; a value that is not finite or not a number after
    it is refused as on a fresh solver, and a zero keeps its sign (0.0 == -0.0)."""
    solver = dn.Solver(oscillator, method="dG(1)")
    first = solver.solve(u0=[0.5, 0.1], params={k: 9.0})
    _assert_same_solution(solver.solve(u0=(0.5, 0.1), params={"k": 9.0}), first)
    for call, error, match in [
            ({"u0": [0.5, np.nan], "params": {k: 9.0}}, ValueError, "u0 is not finite for v"),
            ({"u0": [0.5, 0.1], "params": {k: np.nan}}, ValueError, "k must be finite"),
            ({"params": {k: np.array([9.0, 1.0])}}, TypeError, "k must be a real number")]:
        with pytest.raises(error, match=match):
            solver.solve(**call)
        _assert_same_solution(solver.solve(u0=[0.5, 0.1], params={k: 9.0}), first)
    for zero in (0.0, -0.0, -0.0, 0.0):
        sol = solver.solve(u0=[zero, 0.1], params={k: zero})
        assert np.signbit(sol.ode.u0[0]) == np.signbit(sol.ode.params[k]) == np.signbit(zero)
        _assert_same_solution(sol, dn.solve(dn.vary(oscillator, {"u0": [zero, 0.1], k: zero}),
                                            method="dG(1)"))


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "mcG(1)"])
def test_an_oscillating_forcing_keeps_the_prepared_path(monkeypatch, method):
    """u' = -u + sin(w t): the step bound of the oscillation (1 / w where w t spans many
    periods, none for w = 1) follows the values of each call on the prepared path, bitwise
    dn.solve of the varied declaration, with the same stats (the bound and the estimate of
    the error at T among them)."""
    w = sp.Symbol("w")
    ode = dn.ODE({u: -u + sp.sin(w * dn.t)}, u0=[1.0], T=0.5, params={w: 1.0})
    solver = dn.Solver(ode, method=method, tolerance=1e-3)

    def general_path(*args):
        raise AssertionError("the prepared path gave way to the general one")

    monkeypatch.setattr("dolfinode.solver.solve_lowered", general_path)
    for call in ({}, {"params": {w: 300.0}}, {"params": {w: 300.0}, "u0": [2.0]},
                 {"params": {w: 1.0}}, {"params": {w: 300.0}, "T": 0.25}):
        sol = solver.solve(**call)
        variation = {**call["params"], **{name: call[name] for name in ("u0", "T")
                                          if name in call}} if call else {}
        reference = dn.solve(dn.vary(ode, variation), method=method, tolerance=1e-3)
        _assert_same_solution(sol, reference)
        bound = sol.stats.get("oscillation step bound")
        assert bound == reference.stats.get("oscillation step bound")
        assert bound == (None if variation.get(w, 1.0) == 1.0 else pytest.approx(1 / 300, rel=1e-3))
        assert {name: value for name, value in sol.stats.items() if "time" not in name} == {
            name: value for name, value in reference.stats.items() if "time" not in name}


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "mcG(1)"])
def test_what_a_solution_makes_on_first_read_equals_dn_solve(oscillator, method):
    """The prepared path makes sol.ode and sol.stats when first read: the same declaration
    values and counters as dn.solve's; each solution makes its own, and a later call or a
    change of the declaration does not reach them."""
    # (the estimate of the error at T, on by default for this long run, reads both at once)
    solver = dn.Solver(oscillator, method=method, tolerance=1e-6, estimate_global_error=False)
    first, second = solver.solve(), solver.solve()
    reference = dn.solve(oscillator, method=method, tolerance=1e-6, estimate_global_error=False)
    if method.startswith("m"):
        assert "stats" in vars(first)  # multi-adaptive: made with the solution
    else:
        assert "ode" not in vars(first) and "stats" not in vars(first)
    oscillator.params[k] = 9.0  # after the solves: their declarations keep k = 4
    for sol in (first, second):
        assert list(sol.stats) == list(reference.stats)
        for name, value in reference.stats.items():
            if name not in ("solve time", "compile time"):
                np.testing.assert_array_equal(sol.stats[name], value)
        assert dict(sol.ode.params) == {k: 4.0} and sol.ode.T == 2.0
        np.testing.assert_array_equal(sol.ode.u0, reference.ode.u0)
    assert first.ode is not second.ode and first.stats is not second.stats
    first.ode.params[k] = 1.0
    assert second.ode.params[k] == 4.0
    for name in ("t_start", "k", "values"):
        assert not np.shares_memory(getattr(first, name), getattr(second, name))
    np.testing.assert_array_equal(first.values, second.values)


@pytest.mark.parametrize("method", ["dG(1)", "mcG(1)"])
def test_a_prepared_solution_pickles_with_what_it_makes_on_first_read(oscillator, method):
    import pickle

    sol = dn.Solver(oscillator, method=method).solve(params={k: 9.0})
    copy = pickle.loads(pickle.dumps(sol))
    np.testing.assert_array_equal(copy(1.5), sol(1.5))
    assert copy.stats["f evaluations"] == sol.stats["f evaluations"]
    assert copy.ode.params[k] == 9.0 and "_makers" not in vars(copy)


@pytest.mark.parametrize("u0", [[0.5, 0.1], (0.5, 0.1), np.array([0.5, 0.1]), {u: 0.5, "v": 0.1},
                                [1, 0.1], np.array([0.5, 0.1], dtype=np.float32)])
def test_every_form_of_u0_and_params_solves_as_the_varied_declaration(oscillator, u0):
    """Floats in a list, tuple or vector take the direct check; ints, other dtypes, dicts
    the declaration's: the same solution either way."""
    solver = dn.Solver(oscillator, method="dG(1)", tolerance=1e-5)
    for params in ({k: 9.0}, {"k": np.float64(9.0)}, {k: 9}):
        sol = solver.solve(u0=u0, params=params)
        expected = [0.5, 0.1] if isinstance(u0, dict) else np.asarray(u0).astype(float)
        _assert_same_solution(sol, dn.solve(dn.vary(oscillator, {k: 9.0, "u0": expected}),
                                            method="dG(1)", tolerance=1e-5))
        assert not sol.ode.u0.flags.writeable


@pytest.mark.parametrize("call, error, match", [
    ({"u0": [1.0, np.inf]}, ValueError, "u0 is not finite for v"),
    ({"u0": np.array([np.nan, 1.0])}, ValueError, "u0 is not finite for u"),
    ({"u0": [1.0]}, ValueError, "has 1 values but the system has 2"),
    ({"u0": [1.0, "x"]}, TypeError, "u0 must hold real numbers"),
    ({"u0": [1.0, 1j]}, TypeError, "complex"),
    ({"params": {k: -np.inf}}, ValueError, "parameter k must be finite"),
    ({"params": {sp.Symbol("k", positive=True): 1.0}}, ValueError, "neither a parameter"),
    ({"params": {k: 1j}}, TypeError, "complex"),
])
def test_the_direct_checks_give_the_declaration_errors(oscillator, call, error, match):
    solver = dn.Solver(oscillator, method="dG(1)")
    solver.solve()  # (a prepared work space: the checks of a call come first all the same)
    with pytest.raises(error, match=match):
        solver.solve(**call)
    np.testing.assert_array_equal(solver.solve().values, dn.solve(oscillator,
                                                                  method="dG(1)").values)


def test_a_negative_u0_in_a_nonnegative_declaration_is_refused_directly():
    x, rate = sp.symbols("x rate")
    ode = dn.ODE({x: -rate * x}, u0=[1.0], T=1.0, params={rate: 1.0}, nonnegative=True)
    with pytest.raises(ValueError, match="declared nonnegative"):
        dn.Solver(ode, method="dG(1)").solve(u0=[-0.5])


def test_the_floor_follows_the_sign_of_u0():
    """x' = -rate x keeps x >= 0 from x(0) >= 0 (the values are then kept >= -atol), not
    from x(0) < 0: each call's floor is dn.solve's, in any order of the signs."""
    x, rate = sp.symbols("x rate")
    ode = dn.ODE({x: -rate * x}, u0=[0.5], T=3.0, params={rate: 2.0})
    solver = dn.Solver(ode, method="dG(1)", tolerance=1e-3)
    for u0 in ([0.5], [-1e-4], [-0.25], [1e-4], np.array([0.0]), [-1e-4]):
        _assert_same_solution(solver.solve(u0=u0), dn.solve(dn.vary(ode, {"u0": u0}),
                                                            method="dG(1)", tolerance=1e-3))


def test_the_kept_compiled_calls_are_type_checked_in_the_tests(oscillator):
    """The solver keeps the loops' entry points (Loop.entry); while Loop.checked (this
    module's fixture) they are numba's type-checking dispatchers, so these tests check the
    argument types of every prepared call."""
    from dolfinode.timeslab import mono, prepared
    from dolfinode.timeslab.start import start

    solver = dn.Solver(oscillator, method="dG(1)")
    solver.solve()
    assert solver._loop[0] is mono.advance.compile()
    assert solver._start[0] is start.compile()
    assert solver._prepared[0] is prepared.run.compile()


def test_a_start_failing_in_the_one_compiled_call_is_named_and_the_next_call_is_fresh(
        monkeypatch):
    """The prepared mono-adaptive call runs the start and the loop in one compiled call
    (:mod:`dolfinode.timeslab.prepared`): a start that fails there (f(u0, t0) not finite, an
    interval too short to resolve) raises dn.solve's error, and a later call of the same
    work space is bitwise dn.solve."""
    x, rate = sp.symbols("x rate")
    ode = dn.ODE({x: -rate * x}, u0=[1e10], T=1e6 + 1.0, t0=1e6, params={rate: 1.0})
    solver = dn.Solver(ode, method="dG(2)", tolerance=1e-6)

    def general_path(*args):
        raise AssertionError("the prepared path gave way to the general one")

    monkeypatch.setattr("dolfinode.solver.solve_lowered", general_path)
    solver.solve()
    with pytest.raises(ValueError, match=r"f\(u0, t0\) is not finite in the right-hand side "
                                         "of x"):
        solver.solve(params={rate: 1e308})
    with pytest.raises(ValueError, match="shorter than the smallest step"):
        solver.solve(T=1e6 + 1e-9)
    for call in ({"params": {rate: 2.0}}, {}):
        _assert_same_solution(solver.solve(**call), dn.solve(
            dn.vary(ode, call.get("params", {})), method="dG(2)", tolerance=1e-6))
