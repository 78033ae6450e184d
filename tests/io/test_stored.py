"""A solution history streamed to HDF5 (dense_output="run.h5") and read back lazily."""
import os
import stat
import textwrap

import numpy as np
import pytest

import dolfinode as dn
from dolfinode.io.atomic import _umask
from dolfinode.problems import mass_spring_chain


@pytest.fixture(scope="module")
def chain():
    ode, _ = mass_spring_chain(20, T=3.0)
    return ode


@pytest.mark.parametrize("method", ["cG(2)", "mcG(1)", "dG(1)", "mcG(2)"])
def test_streamed_history_reads_back_equal_to_the_in_memory_one(chain, tmp_path, method):
    dense = dn.solve(chain, method, tolerance=1e-6)
    path = tmp_path / "out" / "run.h5"
    streamed = dn.solve(chain, method, tolerance=1e-6, dense_output=str(path))
    loaded = dn.load_solution(path)
    times = np.random.default_rng(1).uniform(0.0, 3.0, 50)
    for sol in (streamed, loaded):
        np.testing.assert_array_equal(sol(times), dense(times))  # read lazily
        np.testing.assert_array_equal(sol.y, dense.y)
        np.testing.assert_array_equal(sol.values, dense.values)  # read whole
        assert sol.stats["elements"] == dense.stats["elements"]
        assert sol.ode.states == chain.states and sol.method.name == dense.method.name
    assert os.listdir(path.parent) == ["run.h5"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o644 & ~_umask()
    loaded.close()
    streamed.close()


def test_an_error_estimate_of_a_loaded_solution_equals_the_in_memory_one(chain, tmp_path):
    goal = {chain.states[3]: 1.0}
    dense = dn.solve(chain, "cG(1)", tolerance=1e-4)
    loaded = dn.solve(chain, "cG(1)", tolerance=1e-4, dense_output=str(tmp_path / "run.h5"))
    assert dn.estimate_error(loaded, goal).value == dn.estimate_error(dense, goal).value


def test_a_failed_solve_leaves_no_file(chain, tmp_path):
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(chain, "cG(1)", maximum_steps=5, dense_output=str(tmp_path / "run.h5"))
    assert not os.listdir(tmp_path)


def test_a_file_that_is_not_a_history_is_named(tmp_path):
    import h5py

    with h5py.File(tmp_path / "other.h5", "w") as other:
        other["x"] = 1.0
    with pytest.raises(ValueError, match="other.h5 is not a dolfinode solution history"):
        dn.load_solution(tmp_path / "other.h5")


_LONG = textwrap.dedent("""
    import sys
    from pathlib import Path
    import dolfinode as dn
    from dolfinode.problems import mass_spring_chain

    ode, _ = mass_spring_chain(100, T=1000.0)
    Path(sys.argv[1], "started").touch()
    dn.solve(ode, "cG(1)", fixed_time_step=True, initial_time_step=1e-4,
             dense_output=str(Path(sys.argv[1], "run.h5")))
""")


def test_a_killed_streaming_solve_leaves_no_file(tmp_path, kill_python):
    # streaming by 3 s after the start: 10^7 slabs take minutes
    kill_python(_LONG, tmp_path, started=tmp_path / "started", seconds=3.0)
    assert os.listdir(tmp_path) == ["started"]


def test_a_declaration_with_events_streams_and_pickles(tmp_path):
    """The events' caches on the declaration (lambdified switching functions) are not stored:
    a history written after a solve with events pickles its declaration."""
    import pickle

    import sympy as sp

    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u + sp.Heaviside(dn.t - 1.5)}, u0=[1.0, 0.0], T=3.0)
    dense = dn.solve(ode, "cG(2)", tolerance=1e-8, events=[u])
    path = tmp_path / "run.h5"
    stored = dn.solve(ode, "cG(2)", tolerance=1e-8, events=[u], dense_output=str(path))
    assert np.array_equal(stored.t_events[0], dense.t_events[0])
    assert np.allclose(dn.load_solution(path)(2.7), dense(2.7), rtol=0, atol=1e-14)
    again = pickle.loads(pickle.dumps(ode))
    assert np.allclose(dn.solve(again, "cG(2)", tolerance=1e-8)(3.0), dense(3.0))
    assert sorted(os.listdir(tmp_path)) == ["run.h5"]


@pytest.mark.parametrize("method", ["cG(1)", "dG(1)"])
def test_evaluation_reads_the_element_times_in_blocks(tmp_path, method):
    """sol(t) of a file history longer than a dataset chunk (131072 elements) reads the
    element times of the blocks around t only, not all of them (16 bytes per element, which
    a history too long for memory may not have), and gives the in-memory values bit for bit,
    on block boundaries as well."""
    import sympy as sp

    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=300.0)
    options = {"fixed_time_step": True, "initial_time_step": 1e-3}
    dense = dn.solve(ode, method, **options)
    stored = dn.solve(ode, method, dense_output=str(tmp_path / "run.h5"), **options)
    block = stored._h5["t_start"].chunks[0]
    assert stored.stats["time slabs"] > 2 * block
    edges = dense.t_start[[block - 1, block, 2 * block]]
    times = np.concatenate([edges, edges + 1e-4, np.random.default_rng(2).uniform(0, 300, 20)])
    np.testing.assert_array_equal(stored(times), dense(times))
    np.testing.assert_array_equal(stored.y, dense.y)
    assert "_times" not in stored.__dict__
    np.testing.assert_array_equal(stored.t_start, dense.t_start)  # asked for: read whole
    np.testing.assert_array_equal(stored(times), dense(times))
    stored.close()
