"""Ensembles: serial, thread pool and a dask LocalCluster give the same results as separate
solves; reduced values; bad variations fail before anything runs."""
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn

u, v, k = sp.symbols("u v k")


def oscillator():
    return dn.ODE({u: v, v: -k * u}, u0=[1.0, 0.0], T=1.0, params={k: 4.0})


def final_value(solution):  # module level: picklable for process pools and clusters
    return solution(solution.ode.T)


VARIATIONS = [{k: 1.0}, {"k": 9.0, "u0": [0.5, 1.0]}, {"T": 2.0}, {k: 2.0, "u0": {u: 0.0, v: 1.0}}]


def expected_final_values():
    return [final_value(dn.solve(dn.vary(oscillator(), var), "cG(2)", tolerance=1e-8))
            for var in VARIATIONS]


def test_serial_ensemble_equals_separate_solves_and_exact_solution():
    values = dn.solve_ensemble(oscillator(), VARIATIONS, reduce=final_value, method="cG(2)",
                               tolerance=1e-8)
    np.testing.assert_array_equal(values, expected_final_values())
    w = 1.0  # first variation: u = cos(t)
    np.testing.assert_allclose(values[0], [np.cos(w), -np.sin(w)], atol=1e-6)


def test_an_auto_ensemble_equals_separate_solves():
    """method="auto" in an ensemble, as in dn.solve (it was refused as unknown)."""
    results = dn.solve_ensemble(oscillator(), VARIATIONS, method="auto", tolerance=1e-8,
                                reduce=final_value)
    for result, variation in zip(results, VARIATIONS):
        single = dn.solve(dn.vary(oscillator(), variation), "auto", tolerance=1e-8)
        np.testing.assert_array_equal(result, final_value(single))


def test_solutions_come_back_in_order_with_their_variation():
    solutions = dn.solve_ensemble(oscillator(), VARIATIONS, method="cG(2)", tolerance=1e-8)
    assert [s.ode.T for s in solutions] == [1.0, 1.0, 2.0, 1.0]
    assert [s.ode.params[k] for s in solutions] == [1.0, 9.0, 4.0, 2.0]
    np.testing.assert_array_equal(solutions[1].ode.u0, [0.5, 1.0])


def test_thread_pool_equals_serial():
    with ThreadPoolExecutor(max_workers=2) as pool:
        values = dn.solve_ensemble(oscillator(), VARIATIONS, executor=pool, reduce=final_value,
                                   method="cG(2)", tolerance=1e-8, progress=True)
    np.testing.assert_array_equal(values, expected_final_values())


def test_dask_local_cluster_equals_serial():
    distributed = pytest.importorskip("distributed")
    chain = dn.systems.lattice(2, m=1.0)  # a template system travels as its declaration
    variations = [{"T": 0.5}, {"T": 1.0}, {"u0": chain.u0 * 1.01}]
    serial = dn.solve_ensemble(chain, variations, reduce=final_value, tolerance=1e-6)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        remote = dn.solve_ensemble(chain, variations, executor=client, reduce=final_value,
                                   tolerance=1e-6)
        solutions = dn.solve_ensemble(oscillator(), VARIATIONS[:2], executor=client,
                                      method="cG(2)", tolerance=1e-8)
    np.testing.assert_array_equal(remote, serial)
    np.testing.assert_array_equal([final_value(s) for s in solutions], expected_final_values()[:2])


@pytest.mark.parametrize("variations, error, match", [
    ({k: 1.0}, TypeError, "sequence"),
    ([{k: 1.0}, [1.0]], TypeError, "must be a dict"),
    ([{sp.Symbol("kk"): 1.0}], ValueError, "neither a parameter .* did you mean 'k'"),
    ([{"u1": [0.0, 1.0]}], ValueError, "did you mean 'u0'"),
    ([{k: "stiff"}], TypeError, "must be a real number"),
    ([{"u0": [1.0]}], ValueError, "has 1 values but the system has 2"),
    ([{"T": -1.0}], ValueError, "larger than t0"),
])
def test_bad_variations_fail_before_running(variations, error, match):
    with pytest.raises(error, match=match):
        dn.solve_ensemble(oscillator(), variations)


def test_a_variation_keeps_the_declared_domain():
    ode = dn.ODE({u: v, v: -k * u}, u0=[1.0, 0.0], T=1.0, params={k: 4.0}, nonnegative=[u])
    assert dn.vary(ode, {k: 1.0}).nonnegative.tolist() == [True, False]
    with pytest.raises(ValueError, match="u0 of u is -1.0, but u is declared nonnegative"):
        dn.solve_ensemble(ode, [{k: 1.0}, {"u0": [-1.0, 0.0]}])


def test_bad_arguments_fail_before_running():
    with pytest.raises(ValueError, match="tolerance"):
        dn.solve_ensemble(oscillator(), [{}], tolerence=1e-3)
    with pytest.raises(TypeError, match="reduce"):
        dn.solve_ensemble(oscillator(), [{}], reduce=3)
    with pytest.raises(TypeError, match="dolfinode.ODE"):
        dn.solve_ensemble("ode", [{}])
    with pytest.raises(TypeError, match="executor must be"):  # was "'str' has no 'submit'"
        dn.solve_ensemble(oscillator(), [{}], executor="threads")


def test_a_failing_run_names_its_variation():
    x = sp.Symbol("x")
    blowup = dn.ODE({x: x**2}, u0=[1.0], T=0.5)
    with pytest.raises(dn.SolverError) as info:
        dn.solve_ensemble(blowup, [{}, {"T": 2.0}])
    notes = "".join(getattr(info.value, "__notes__", []))
    assert "variation 1" in notes and "return_exceptions=True keeps the other runs" in notes


def test_runs_and_solutions_pickle_for_process_pools_and_clusters():
    import pickle
    run = dn.vary(dn.systems.lattice(2, m=1.0), {"T": 0.2})
    solution = dn.solve(run, tolerance=1e-6)
    back = pickle.loads(pickle.dumps(solution))
    np.testing.assert_array_equal(back(0.1), solution(0.1))
    np.testing.assert_array_equal(dn.solve(pickle.loads(pickle.dumps(run)), tolerance=1e-6).y,
                                  solution.y)


def test_progress_bar_counts_the_runs(capsys):
    dn.solve_ensemble(oscillator(), VARIATIONS, reduce=final_value, progress=True,
                      method="cG(2)", tolerance=1e-8)
    assert "4/4" in capsys.readouterr().err


def blowup_ensemble(**options):
    """Runs 0 and 2 reach T; run 1 (T = 2) meets the blow-up of u = 1/(1 - t) at t = 1."""
    x = sp.Symbol("x")
    ode = dn.ODE({x: x**2}, u0=[1.0], T=0.5)
    return dn.solve_ensemble(ode, [{}, {"T": 2.0}, {"T": 0.9}], return_exceptions=True,
                             tolerance=1e-6, **options)


@pytest.mark.parametrize("pool", [None, ThreadPoolExecutor])
def test_return_exceptions_keeps_every_member_in_place(pool):
    if pool is None:
        runs = blowup_ensemble()
    else:
        with pool(max_workers=2) as executor:
            runs = blowup_ensemble(executor=executor)
    assert [type(run).__name__ for run in runs] == ["Solution", "SolverError", "Solution"]
    assert [run.status for run in runs] == [0, -1, 0]
    assert [run.success for run in runs] == [True, False, True]
    assert 0.9 < runs[1].t <= 1.0 and runs[1].message == str(runs[1])
    assert "variation 1" in "".join(runs[1].__notes__)
    # the completed members are the solutions u = 1/(1 - t)
    for run, T in ((runs[0], 0.5), (runs[2], 0.9)):
        assert run(T)[0] == pytest.approx(1.0 / (1.0 - T), rel=1e-4)


def kill_worker_once(solution, marker):
    """The reduce of the killed-worker test: the first run that gets here kills its worker
    process (as an out-of-memory kill would), the others return u(T)."""
    import os
    import signal
    if not os.path.exists(marker):
        open(marker, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return solution(solution.ode.T)


def test_dask_survives_a_killed_worker(tmp_path):
    distributed = pytest.importorskip("distributed")
    import functools
    import sys

    import cloudpickle

    # the workers cannot import this test module: send the reduce function by value
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        reduce = functools.partial(kill_worker_once, marker=str(tmp_path / "killed"))
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                distributed.Client(cluster, timeout=120) as client, \
                ThreadPoolExecutor(max_workers=1) as waiting:
            run = waiting.submit(dn.solve_ensemble, oscillator(), VARIATIONS, executor=client,
                                 reduce=reduce, method="cG(2)", tolerance=1e-8,
                                 return_exceptions=True)
            values = run.result(timeout=300)  # a bound instead of a hang if dask stalls
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert (tmp_path / "killed").exists()  # a worker did die
    np.testing.assert_array_equal(values, expected_final_values())


def test_a_member_out_of_memory_is_a_solver_error_naming_what_to_try(monkeypatch):
    """Members that fit one by one but not together: the first ones' histories take the
    memory, a later member's allocation fails (numpy's or the compiled code's MemoryError,
    often without a message). It comes back as a SolverError naming dense_output, its
    variation and reduce=; the other members complete."""
    from dolfinode.io import history

    add = history.InMemory.add

    def full_from_the_second_run(self, chunk, t):
        if self.ode.T == 2.0:
            raise MemoryError()
        add(self, chunk, t)

    monkeypatch.setattr(history.InMemory, "add", full_from_the_second_run)
    runs = dn.solve_ensemble(oscillator(), [{}, {"T": 2.0}, {"T": 0.5}], method="cG(2)",
                             return_exceptions=True)
    assert [type(run).__name__ for run in runs] == ["Solution", "OutOfMemoryError", "Solution"]
    failed = runs[1]
    assert isinstance(failed, dn.SolverError) and isinstance(failed, MemoryError)
    assert failed.status == -1 and 0.0 < failed.t <= 2.0
    assert "dense_output=False" in failed.message and "ran out of memory" in failed.message
    assert "variation 1" in "".join(failed.__notes__) and "reduce=" in "".join(failed.__notes__)
