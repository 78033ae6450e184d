"""The subgrid models: the pattern of the affine model and its least-squares fit."""
import numpy as np
from scipy import sparse

from dolfinode.modeling.reduced import affine_pattern, fit_affine


def test_affine_pattern_reaches_through_the_inactive_components():
    # 0, 1 active; 2 -> 3 -> 4 inactive chain: f_0 depends on u_2, u_4 on u_1
    J = sparse.csr_matrix(np.array([[1, 0, 1, 0, 0],
                                    [0, 1, 0, 0, 0],
                                    [0, 0, 0, 1, 0],
                                    [0, 0, 0, 0, 1],
                                    [0, 1, 0, 0, 0]], dtype=float))
    rows, cols = affine_pattern(J, np.array([True, True, False, False, False]))
    assert list(zip(rows, cols)) == [(0, 1)]  # J_AA's own entries are not in it


def test_fit_affine_recovers_a_linear_dependence_along_the_windows():
    pattern = (np.array([0, 0]), np.array([1, 2]))
    G = np.array([2.0, -1.0])
    u = [np.array([5.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 1.0, 1.0]),
         np.array([0.0, 0.0, 0.0])]
    g = [np.array([G @ uk[1:], 0.0, 0.0]) for uk in u]
    np.testing.assert_allclose(fit_affine(pattern, u, g), G, rtol=1e-10)
    assert not fit_affine(pattern, u[:1], g[:1]).any()  # one window: constant model
    # windows along one direction (1, 1) up to noise below AFFINE_RCOND: the minimum-norm
    # slope along it, G (1, 1)/2 on both entries, not a noise-driven second direction
    u = [np.array([0.0, 1.0, 1.0 + 1e-3]), np.array([0.0, 2.0, 2.0]), np.zeros(3)]
    g = [np.array([G @ uk[1:], 0.0, 0.0]) for uk in u]
    np.testing.assert_allclose(fit_affine(pattern, u, g), [0.5, 0.5], atol=1e-3)
