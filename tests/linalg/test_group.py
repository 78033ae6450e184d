"""Newton matrices of a group of components (dolfinode.linalg.group)."""
import numpy as np
import pytest


@pytest.mark.parametrize("method", ["mcG(1)", "mcG(2)", "mcG(3)", "mdG(0)", "mdG(1)", "mdG(2)"])
def test_group_newton_solves_the_stage_system_through_the_transformation(method):
    """The group Newton step's factors and solve (``factor_group``, ``solve_group``: one
    n x n band system per real eigenvalue of A and one complex one per pair) give the solution
    of the whole stage system (I - k A (x) J_gg) dX = r, stage-major, on a random banded
    group."""
    from dolfinode.counters import NUM_COUNTERS
    from dolfinode.linalg import group
    from dolfinode.methods import parse_method
    from dolfinode.timeslab import multi

    _, m = parse_method(method)
    T, T_inverse, eigenvalues = multi.method_tables(m)[4:7]
    S = T.shape[0]
    rng = np.random.default_rng(7)
    n, k = 9, 0.3
    J = np.where(np.abs(np.subtract.outer(np.arange(n), np.arange(n))) <= 2,
                 rng.standard_normal((n, n)), 0.0)
    J[0, 1] = J[1, 0] = 0.0  # a hole in the band
    indptr = np.concatenate([[0], np.cumsum((J != 0).sum(axis=1))]).astype(np.int64)
    indices = np.concatenate([np.flatnonzero(row) for row in J]).astype(np.int64)
    jacobian = J[J != 0]
    order = np.arange(n, dtype=np.int64)
    local = np.arange(n, dtype=np.int64)
    n_real = int(np.sum(eigenvalues.imag == 0))
    newton = group.group_workspace(max(n_real, 1), len(eigenvalues) - n_real, S, n, 7)
    counters = np.zeros(NUM_COUNTERS, dtype=np.int64)
    kl, ku, info = group.factor_group(order, n, local, indptr, indices, jacobian, k,
                                      eigenvalues, newton, counters)
    assert info == 0 and (kl, ku) == (2, 2)
    r = rng.standard_normal(S * n)
    newton[3][:S * n] = r
    group.solve_group(n, kl, ku, (T, T_inverse, eigenvalues), newton)
    expected = np.linalg.solve(np.eye(S * n) - k * np.kron(m.A, J), r)
    np.testing.assert_allclose(newton[3][:S * n], expected, rtol=1e-12, atol=1e-12)
