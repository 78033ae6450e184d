"""Newton matrices I - c J in banded and sparse storage: the same solves, and the choice."""
import importlib

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile import lower
from dolfinode.linalg.newton_matrix import (
    band_structure,
    lu_factor,
    lu_solve,
    newton_structure,
    shift,
    sparse_candidate,
    sparse_structure,
    store_jacobian,
)
from dolfinode.methods import parse_method


def grid_ode(n, nonlinear=True, coupled=True):
    """u' = Lap u - u^3 on an n x n grid (mirror boundaries), plus (``coupled``) a one-way
    coupling to the first point (an unsymmetric pattern)."""
    u = sp.symbols(f"u0:{n * n}")

    def at(i, j):
        i = 1 if i < 0 else n - 2 if i > n - 1 else i
        j = 1 if j < 0 else n - 2 if j > n - 1 else j
        return u[i * n + j]

    rhs = {}
    for i in range(n):
        for j in range(n):
            lap = at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1) - 4 * at(i, j)
            rhs[at(i, j)] = (n * n * lap - (at(i, j) ** 3 if nonlinear else 0)
                             + (u[0] / (1 + i) if coupled else 0))
    x = np.linspace(-1, 1, n)
    return dn.ODE(rhs, u0=np.exp(-5 * np.add.outer(x**2, x**2)).ravel(), T=0.1)


def structures(compiled):
    _, position, kl, ku = compiled.ordering
    return {"banded": band_structure(position, kl, ku),
            "sparse": sparse_structure(compiled.indptr, compiled.indices, compiled.N)}


@pytest.mark.parametrize("c", [0.3, 0.02 + 0.01j])
@pytest.mark.parametrize("storage", ["banded", "sparse"])
def test_factor_and_solve_the_shifted_jacobian(storage, c):
    """store_jacobian, shift, lu_factor and lu_solve give (I - c J)^{-1} b, J = df/du, in the
    structure's ordering, real and complex c; the error filter's in-place shift (ab = jb)
    too."""
    ode = grid_ode(5)
    compiled = lower(ode)
    structure = structures(compiled)[storage]
    rng = np.random.default_rng(0)
    u = rng.standard_normal(ode.N)
    J = compiled.jacobian_matrix(u, 0.0).toarray()
    jdata = compiled.jacobian_matrix(u, 0.0).data
    jb = np.zeros(structure.shape)
    store_jacobian(jdata, compiled.indptr, compiled.indices, structure.tuple, jb)
    ab = np.zeros(structure.shape, dtype=type(c))
    shift(jb, c, structure.tuple, ab)
    ipiv = np.zeros(ode.N, dtype=np.int64)
    assert lu_factor(ab, structure.tuple, ipiv) == 0
    b = rng.standard_normal(ode.N)
    x = np.zeros(ode.N, dtype=type(c))
    x[structure.position] = b
    lu_solve(ab, structure.tuple, ipiv, x)
    expected = np.linalg.solve(np.eye(ode.N) - c * J, b)
    np.testing.assert_allclose(x[structure.position], expected, rtol=1e-12, atol=1e-12)
    if isinstance(c, float):
        shift(jb, c, structure.tuple, jb)
        assert lu_factor(jb, structure.tuple, ipiv) == 0
        y = np.zeros(ode.N)
        y[structure.position] = b
        lu_solve(jb, structure.tuple, ipiv, y)
        np.testing.assert_allclose(y[structure.position], expected, rtol=1e-12, atol=1e-12)


def chosen(ode, method):
    """The storage dn.solve takes for ``method`` on ``ode``."""
    compiled = lower(ode)
    return newton_structure(compiled.band_structure, lambda: compiled.sparse_structure,
                            parse_method(method)[1].stage_eigenvalues)


def test_wide_bands_go_sparse_narrow_ones_stay_banded():
    """A 2-D grid (band ~ n) is factored sparse, a chain (tridiagonal) and a small system banded;
    in real arithmetic (cG(1): one real matrix) the band holds out to larger grids than in
    complex (cG(2): one complex pair; measured: real 2-D Brusselators up to N ~ 3000); each
    choice is the one estimated cheaper."""
    grid = chosen(grid_ode(12), "cG(2)")
    assert grid.sparse
    assert grid.description.startswith("sparse LU")
    compiled = lower(grid_ode(12))
    band, sparse = compiled.band_structure, compiled.sparse_structure
    assert sparse is grid
    assert sparse.seconds(True, 4) < band.seconds(True, 4)
    chain_u = sp.symbols("c0:300")
    chain = dn.ODE({chain_u[i]: chain_u[i - 1] - 2 * chain_u[i] + chain_u[(i + 1) % 300]
                    for i in range(300)}, u0=np.ones(300), T=1.0)
    assert not sparse_candidate(lower(chain).band_structure)
    assert chosen(chain, "cG(2)").description.startswith("banded LU, bandwidth")
    assert not sparse_candidate(lower(grid_ode(4)).band_structure)  # N = 16 < SPARSE_MIN_N = 20
    plain = grid_ode(20, coupled=False)  # band 20 + 20
    assert chosen(plain, "cG(2)").sparse
    assert not chosen(plain, "cG(1)").sparse


def test_small_wide_band_goes_sparse(monkeypatch):
    """POLLU (N = 20, band 15 + 15 after reordering, 82 nonzeros): the sparse LU, 136 entries
    in its factors against the band's 920, is chosen for a method with a complex pair, and a
    solve with it takes the banded solve's slabs and iterations to the same answer."""
    from dolfinode.bench.problems import pollu

    newton_matrix = importlib.import_module("dolfinode.linalg.newton_matrix")
    ode = pollu().ode
    assert chosen(ode, "dG(2)").sparse
    compiled = lower(ode)
    band, sparse = compiled.band_structure, compiled.sparse_structure
    assert sparse.entries < band.entries / 5
    solves = {}
    for storage, smallest in (("sparse", newton_matrix.SPARSE_MIN_N), ("banded", ode.N + 1)):
        monkeypatch.setattr(newton_matrix, "SPARSE_MIN_N", smallest)
        compiled.newton_plans.clear()
        solves[storage] = dn.solve(ode, method="dG(2)", tolerance=1e-5)
        assert solves[storage].stats["newton matrices"].startswith(f"{storage} LU")
    compiled.newton_plans.clear()  # (the banded plan is not the default's)
    counts = ("time slabs", "nonlinear iterations", "jacobian evaluations")
    assert [solves["sparse"].stats[c] for c in counts] == [solves["banded"].stats[c]
                                                           for c in counts]
    np.testing.assert_allclose(solves["sparse"](ode.T), solves["banded"](ode.T), rtol=1e-12,
                               atol=1e-300)


def test_sparse_memory_is_far_below_the_band():
    """On a 30 x 30 grid the sparse workspace of cG(3) takes a fraction of the banded one."""
    compiled = lower(grid_ode(30, nonlinear=False))
    both = structures(compiled)
    assert both["sparse"].memory(3) < 0.3 * both["banded"].memory(3)
    rows, columns = both["sparse"].shape
    assert rows == 1 and columns == len(both["sparse"].idx)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "cG(3)"])
def test_solves_with_sparse_newton_matrices(method, monkeypatch):
    """Newton's method with sparse matrices through dn.solve reaches the accuracy of a tight
    scipy Radau solution, on the same slabs and with the same iterations as with banded
    ones (factored on every Newton slab: the band, 99 + 10 wide from the coupling to u_0, would
    be kept over slabs, the sparse factors, cheap, not)."""
    from scipy.integrate import solve_ivp

    from dolfinode.timeslab import mono

    solve_module = importlib.import_module("dolfinode.solve")  # dolfinode.solve is the function

    monkeypatch.setattr(mono, "REUSE_TIME", np.inf)
    ode = grid_ode(10)
    compiled = lower(ode)
    assert chosen(ode, method).sparse
    sol = dn.solve(ode, method, tolerance=1e-6, nonlinear_solver="newton")
    assert sol.stats["newton matrices"].startswith("sparse LU")
    reference = solve_ivp(lambda t, y: compiled.f(y, t), (0.0, ode.T), np.asarray(ode.u0),
                          method="Radau", jac=lambda t, y: compiled.jacobian_matrix(y, t),
                          rtol=1e-11, atol=1e-12).y[:, -1]
    assert np.abs(sol.y[:, -1] - reference).max() < 1e-5
    monkeypatch.setattr(solve_module, "newton_structure",
                        lambda band, make_sparse, eigenvalues: band)
    compiled.newton_plans.clear()  # the first solve's choice is kept per method
    banded = dn.solve(ode, method, tolerance=1e-6, nonlinear_solver="newton")
    assert banded.stats["newton matrices"].startswith("banded LU")
    for key in ("time slabs", "nonlinear iterations", "factorizations"):
        assert sol.stats[key] == banded.stats[key]
    np.testing.assert_allclose(sol.y, banded.y, rtol=0, atol=1e-11)


def test_the_storage_is_decided_once_per_pattern_and_method(monkeypatch):
    """Later solves of the same ODE with the same method reuse the first one's choice of
    storage and cost estimates (they were a quarter of a small solve's time); another method
    decides its own."""
    solve_module = importlib.import_module("dolfinode.solve")
    decided = []
    decide = solve_module.newton_structure
    monkeypatch.setattr(solve_module, "newton_structure",
                        lambda *args: decided.append(1) or decide(*args))
    ode = grid_ode(3)
    first = dn.solve(ode, "cG(2)", tolerance=1e-5)
    again = dn.solve(ode, "cG(2)", tolerance=1e-5)
    assert len(decided) == 1
    np.testing.assert_array_equal(first.y, again.y)
    dn.solve(ode, "dG(1)", tolerance=1e-5)
    assert len(decided) == 2
