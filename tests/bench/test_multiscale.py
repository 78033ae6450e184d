import numpy as np

from dolfinode.bench.multiscale import kernel_grid
from dolfinode.modeling.averaging import kernel_weights


def test_kernel_grid_averages_polynomials_of_degree_one_exactly():
    times = np.array([1.0, 1.5, 2.0])
    grid, average = kernel_grid(times, 0.25, samples=50)
    assert np.all(np.diff(grid) > 0) and grid[0] == 0.75 and grid[-1] == 2.25
    values = np.vstack([np.full(grid.size, 3.0), 2 * grid - 1])
    np.testing.assert_allclose(average(values), np.vstack([np.full(3, 3.0), 2 * times - 1]),
                               rtol=1e-12)


def test_kernel_grid_uses_the_modeling_kernel():
    grid, average = kernel_grid([0.0], 1.0, samples=40)
    w = kernel_weights(40)
    np.testing.assert_allclose(average(np.cos(3 * grid)[None]), [[np.cos(3 * grid) @ w]])
