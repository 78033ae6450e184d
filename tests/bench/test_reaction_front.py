"""The NumPy right-hand side and Jacobian of benchmarks/run_reaction_front.py (scipy's input)."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.compile import lower


@pytest.fixture(scope="module")
def rf(benchmark_script):
    return benchmark_script("run_reaction_front")


def test_numpy_f_and_jacobian_match_the_compiled_kernels(rf):
    """f, the sparse J and its band storage agree with dolfinode's compiled f and df/du of the
    template system at a random state."""
    n, t = 50, 0.03
    compiled = lower(rf.front(n, 0.1))
    fun, bands, jac = rf.front_numpy(n)
    u = np.random.default_rng(1).random(n)
    f = compiled.f(u, t)
    np.testing.assert_allclose(fun(t, u), f, rtol=1e-12, atol=1e-12 * np.abs(f).max())
    J = compiled.jacobian_matrix(u, t).toarray()
    np.testing.assert_allclose(jac(t, u).toarray(), J, rtol=1e-12, atol=1e-12 * np.abs(J).max())
    i, j = np.nonzero(J)
    np.testing.assert_allclose(bands(t, u)[1 + i - j, j], J[i, j], rtol=1e-12)   # LSODA's layout


def test_scipy_sweep_against_dolfinode_and_the_time_limit(rf):
    """run_scipy's errors against dolfinode's dG(3) solution fall with the tolerance; past its
    time limit a run is abandoned and the tighter tolerances are skipped."""
    ode = rf.front(400, 0.01)   # L = 2: the front at x = 1 is inside
    ref = dn.solve(ode, method="dG(3)", tolerance=1e-10)(ode.T)
    coarse, fine = rf.run_scipy(ode, "Radau", [1e-4, 1e-8], ref, 60.0)
    assert fine[3] > 0 and fine[7] < 1e-7 and fine[7] < coarse[7] / 100
    rows = rf.run_scipy(ode, "DOP853", [1e-4, 1e-6], ref, 0.0)
    assert len(rows) == 1 and rows[0][3] is None and "abandoned" in rows[0][8]


def test_equal_error_picks_the_fastest_bracketing_method_per_side(rf):
    """At each level the fastest dolfinode method and scipy solver whose runs bracket it are
    paired, with the scipy solvers that do not bracket it; levels either side does not bracket
    are left out."""
    curves = {1000: {"mcG(2)": [(1e-4, 1.0), (1e-8, 3.0)], "mcG(3)": [(1e-6, 0.5), (1e-8, 0.8)],
                     "DOP853": [(1e-3, 0.1), (1e-6, 0.2)], "Radau": [(1e-4, 0.5), (1e-9, 4.0)]}}
    rows = rf.equal_error(curves, [1e-3, 1e-5, 1e-7, 1e-10])
    assert [(level, dm, sm, missing) for n, level, (dm, dt), (sm, st), missing in rows] == [
        (1e-5, "mcG(2)", "DOP853", ["LSODA", "BDF"]),
        (1e-7, "mcG(3)", "Radau", ["LSODA", "DOP853", "BDF"])]
    assert rows[0][2][1] == pytest.approx(1.0 * 3.0**0.25)   # log-log, a quarter of the way
    assert rows[1][2][1] == pytest.approx(0.5 * 1.6**0.5)
