"""The dual (adjoint) problem, linearised at a computed solution and solved backward by cG(r).

For a goal M(u) = G(u(T)) + int g(u, t) dt the dual solution phi satisfies

    -phi'(t) = J(U(t), t)^T phi(t) + grad g(U(t), t),   t in [t0, T),
     phi(T)  = grad G(U(T)),

with J = df/du the Jacobian generated from sympy and evaluated at the Galerkin solution U
(the mean value of the seed paper, "Error analysis", taken at U). In the reversed time
s = T - t this is the forward linear problem y' = J^T y + grad g, solved with the
continuous Galerkin method cG(r) of :mod:`dolfinode.methods` on every interval of the union
of all components' element partitions, where U is a polynomial in every component.
"""
import numpy as np
from numba import njit

from dolfinode.compile import lower
from dolfinode.methods import make_method


@njit(cache=True)
def horner(c, x):
    """sum_i c[i] x^i."""
    value = 0.0
    for i in range(c.shape[0] - 1, -1, -1):
        value = value * x + c[i]
    return value


@njit(cache=True)
def horner_derivative(c, x):
    """d/dx sum_i c[i] x^i."""
    value = 0.0
    for i in range(c.shape[0] - 1, 0, -1):
        value = value * x + i * c[i]
    return value


@njit(cache=True)
def evaluate_primal(coef, t_start, t_end, elements, t, out):
    """out[i] = U_i(t) on the element elements[i] of component i."""
    for i in range(out.shape[0]):
        e = elements[i]
        out[i] = horner(coef[e], (t - t_start[e]) / (t_end[e] - t_start[e]))


@njit(cache=True)
def locate(ptr, t_end, grid):
    """elements[l, i]: the element of component i that contains the interval l of the grid."""
    L, N = grid.shape[0] - 1, ptr.shape[0] - 1
    elements = np.empty((L, N), dtype=np.int64)
    for i in range(N):
        e = ptr[i]
        for l in range(L):
            middle = 0.5 * (grid[l] + grid[l + 1])
            while e < ptr[i + 1] - 1 and t_end[e] <= middle:
                e += 1
            elements[l, i] = e
    return elements


@njit(cache=True)
def jacobian_transpose(jac, p, indptr, indices, u, t, jdata, out):
    """out = J(u, t)^T as a dense matrix, from the generated CSR Jacobian kernel."""
    jac(u.ctypes, t, p.ctypes, jdata.ctypes)
    out[:, :] = 0.0
    for row in range(indptr.shape[0] - 1):
        for n in range(indptr[row], indptr[row + 1]):
            out[indices[n], row] = jdata[n]


@njit(cache=True)
def _backward_cg(jac, p, indptr, indices, grid, elements, t_start, t_end, coef, A, b0, nodes,
                 source, psi, phi):
    """cG(r) for y' = J(U(T - s))^T y + source in s = T - t, interval by interval from T.

    The stage form of cG(r) with its Lobatto quadrature (see :mod:`dolfinode.methods.method`),

        xi_s = y_0 + h (b0_s F_0 + sum_m A_sm F_m),   F_m = J_m^T xi_m + source_m,

    is linear in the stages; each interval solves this (r N) x (r N) system densely.
    phi[l, j] receives the values at the forward nodes t_l + tau_j h (tau_j symmetric).
    """
    L, N = grid.shape[0] - 1, psi.shape[0]
    r, R = A.shape[0], nodes.shape[0]
    u = np.empty(N)
    jdata = np.empty(max(indices.shape[0], 1))
    JT = np.zeros((R, N, N))
    system = np.empty((r * N, r * N))
    rhs = np.empty(r * N)
    y = psi.copy()
    for l in range(L - 1, -1, -1):
        h = grid[l + 1] - grid[l]
        g = source[l if source.shape[0] > 1 else 0]
        for j in range(R):  # backward node j is forward node R - 1 - j
            t = grid[l + 1] - nodes[j] * h
            evaluate_primal(coef, t_start, t_end, elements[l], t, u)
            jacobian_transpose(jac, p, indptr, indices, u, t, jdata, JT[j])
        system[:, :] = 0.0
        for s in range(r):
            for i in range(N):
                value = y[i] + h * b0[s] * g[R - 1, i]
                for c in range(N):
                    value += h * b0[s] * JT[0, i, c] * y[c]
                for m in range(r):
                    value += h * A[s, m] * g[R - 2 - m, i]
                    for c in range(N):
                        system[s * N + i, m * N + c] -= h * A[s, m] * JT[m + 1, i, c]
                system[s * N + i, s * N + i] += 1.0
                rhs[s * N + i] = value
        stages = np.linalg.solve(system, rhs)
        phi[l, R - 1, :] = y
        for s in range(r):
            phi[l, R - 2 - s, :] = stages[s * N:(s + 1) * N]
        y = stages[(r - 1) * N:].copy()


def monomial_coefficients(nodes):
    """C with c = values @ C: monomial coefficients in tau of the interpolant at the nodes."""
    return np.linalg.inv(np.vander(nodes, increasing=True)).T


class PrimalPolynomials:
    """The stored solution U in the layout the dual needs: per-component elements in time
    order, each a polynomial in tau = (t - t_start) / (t_end - t_start) in monomial form, and
    the union grid of all element end points."""

    def __init__(self, sol):
        ptr, t_start, t_end, values = sol.elements()
        self.ptr, self.t_start, self.t_end = ptr, t_start, t_end
        self.coef = np.ascontiguousarray(values @ monomial_coefficients(sol.method.nodes))
        points = np.unique(np.concatenate([t_start, t_end]))
        # end points that differ by rounding only (multi-adaptive sub-slabs) are one point
        keep = np.diff(points, prepend=-np.inf) > 1e-13 * (sol.ode.T - sol.ode.t0)
        self.grid = points[keep]
        self.grid[-1] = sol.ode.T
        self.elements = locate(ptr, t_end, self.grid)


class DualSolution:
    """The dual solution phi, piecewise polynomial of degree r on the union grid.

    Call it like a :class:`~dolfinode.Solution`: ``phi(t)`` has shape (N,) for a scalar t and
    (N, M) for M times; ``phi.derivative(t)`` gives phi'.

    Attributes
    ----------
    grid : (L + 1,) interval end points
    coef : (L, r + 1, N) monomial coefficients in tau = (t - grid[l]) / (grid[l+1] - grid[l])
    degree : r
    """

    def __init__(self, grid, coef):
        self.grid, self.coef = grid, coef
        self.degree = coef.shape[1] - 1

    def _evaluate(self, t, derivative):
        scalar = np.ndim(t) == 0
        times = np.atleast_1d(np.asarray(t, dtype=float))
        if times.size and (times.min() < self.grid[0] or times.max() > self.grid[-1]):
            raise ValueError(f"the dual solution is defined on [{self.grid[0]}, {self.grid[-1]}]")
        l = np.clip(np.searchsorted(self.grid, times, side="right") - 1, 0, len(self.grid) - 2)
        h = np.diff(self.grid)[l]
        tau = (times - self.grid[l]) / h
        powers = np.arange(self.degree + 1)
        if derivative:
            basis = powers * tau[:, None] ** np.maximum(powers - 1, 0) / h[:, None]
        else:
            basis = tau[:, None] ** powers
        out = np.einsum("mj,mjn->nm", basis, self.coef[l])
        return out[:, 0] if scalar else out

    def __call__(self, t):
        return self._evaluate(t, derivative=False)

    def derivative(self, t):
        """phi'(t)."""
        return self._evaluate(t, derivative=True)


def solve_dual(sol, final, integral, degree, primal=None):
    """Solve the dual problem linearised at the solution ``sol``.

    Parameters
    ----------
    sol : Solution
    final, integral : the goal's parts from :func:`dolfinode.dual.goal.resolve` (or None)
    degree : int
        r of the cG(r) dual scheme (nodal order 2r on the primal's union grid).
    primal : PrimalPolynomials, optional
        Reused when given.

    Returns
    -------
    DualSolution, PrimalPolynomials
    """
    ode = sol.ode
    primal = primal or PrimalPolynomials(sol)
    compiled = lower(ode)
    m = make_method("cG", degree)
    grid = primal.grid
    psi = np.zeros(ode.N)
    if final is not None:
        psi = final.at(sol(ode.T)[:, None], np.array([ode.T]))[:, 0]
    if integral is None:
        source = np.zeros((1, degree + 1, ode.N))
    else:
        times = (grid[:-1, None] + np.outer(np.diff(grid), m.nodes)).ravel()
        weights = integral.at(sol(times), times)
        source = np.ascontiguousarray(weights.T.reshape(len(grid) - 1, degree + 1, ode.N))
    phi = np.empty((len(grid) - 1, degree + 1, ode.N))
    _backward_cg(compiled.jacobian, compiled.p, compiled.indptr, compiled.indices, grid,
                 primal.elements, primal.t_start, primal.t_end, primal.coef, np.array(m.A),
                 m.b0.copy(), m.nodes.copy(), source, psi, phi)
    coef = np.einsum("ljn,jc->lcn", phi, monomial_coefficients(m.nodes))
    return DualSolution(grid, coef), primal
