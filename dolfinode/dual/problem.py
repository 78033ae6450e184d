"""The dual (adjoint) problem, linearised at a computed solution and solved backward by cG(r).

For a goal M(u) = G(u(T)) + int g(u, t) dt the dual solution phi satisfies

    -phi'(t) = J(U(t), t)^T phi(t) + grad g(U(t), t),   t in [t0, T),
     phi(T)  = grad G(U(T)),

with J = df/du the Jacobian generated from sympy and evaluated at the Galerkin solution U
(the mean value of the seed paper, "Error analysis", taken at U). In the reversed time
s = T - t this is the forward linear problem y' = J^T y + grad g, solved with the
continuous Galerkin method cG(r) of :mod:`dolfinode.methods` on every interval of the union
of all components' element partitions, where U is a polynomial in every component. The
linear stage system of an interval has the sparsity of J^T; it is solved by the banded LU of
:mod:`dolfinode.linalg.banded` in the Jacobian's bandwidth ordering, so that a chain-like
coupling costs O(N) per interval, or, when the band is wide (2-D lattices, see
:func:`dolfinode.linalg.wide_band`), by scipy's sparse LU (SuperLU, fill-reducing ordering).
"""
import numpy as np
import scipy.sparse as sps
from scipy.sparse.linalg import splu

from dolfinode.compile import lower
from dolfinode.compile.jit import helper
from dolfinode.compile.pattern import assemble_pattern
from dolfinode.compile.signatures import rhs_kernel
from dolfinode.errors import SolverError
from dolfinode.linalg import band_lu, band_solve, wide_band
from dolfinode.methods import make_method
from dolfinode.methods.method import monomial_coefficients


@helper()
def horner(c, x):
    """sum_i c[i] x^i."""
    value = 0.0
    for i in range(c.shape[0] - 1, -1, -1):
        value = value * x + c[i]
    return value


@helper()
def horner_derivative(c, x):
    """d/dx sum_i c[i] x^i."""
    value = 0.0
    for i in range(c.shape[0] - 1, 0, -1):
        value = value * x + i * c[i]
    return value


@helper()
def evaluate_primal(coef, t_start, t_end, current, t, out):
    """out[i] = U_i(t) on the element current[i] of component i."""
    for i in range(out.shape[0]):
        e = current[i]
        out[i] = horner(coef[e], (t - t_start[e]) / (t_end[e] - t_start[e]))


@helper()
def advance_forward(ptr, t_end, a, b, current):
    """Move current[i] forward to the element of component i that contains (a, b)."""
    middle = 0.5 * (a + b)
    for i in range(current.shape[0]):
        e = current[i]
        while e < ptr[i + 1] - 1 and t_end[e] <= middle:
            e += 1
        current[i] = e


@helper()
def advance_backward(ptr, t_start, a, b, current):
    """Move current[i] backward to the element of component i that contains (a, b)."""
    middle = 0.5 * (a + b)
    for i in range(current.shape[0]):
        e = current[i]
        while e > ptr[i] and t_start[e] >= middle:
            e -= 1
        current[i] = e


@helper()
def add_transpose_product(indptr, indices, jdata, y, scale, out):
    """out += scale J^T y for J in CSR form (values ``jdata`` of the generated Jacobian)."""
    for c in range(indptr.shape[0] - 1):
        for nz in range(indptr[c], indptr[c + 1]):
            out[indices[nz]] += scale * jdata[nz] * y[c]


@helper()
def assemble_dual_matrix(jdata, indptr, indices, position, A, h, kl, ku, ab):
    """Band storage of I - h (A (x) I) diag(J_m^T), the stage matrix of one dual interval.

    Unknown (stage s, component i) sits at row position[i] r + s; the block (s, m) is
    -h A_sm J_m^T with J_m = jdata[m + 1] (CSR values of J at stage node m). An entry
    J_m[c, i] of the Jacobian lands in row (s, i), column (m, c); kl, ku are the band widths
    of the stage matrix (see :func:`_backward_cg`).
    """
    r = A.shape[0]
    kv = kl + ku
    ab[:, :] = 0.0
    for c in range(indptr.shape[0] - 1):
        column = position[c] * r
        for nz in range(indptr[c], indptr[c + 1]):
            row = position[indices[nz]] * r
            for m in range(r):
                value = -h * jdata[m + 1, nz]
                for s in range(r):
                    ab[column + m, kv + row + s - column - m] += value * A[s, m]
    for n in range(ab.shape[0]):
        ab[n, kv] += 1.0


@helper()
def _interval(jac_address, p, indptr, indices, position, l, grid, ptr, t_start, t_end, coef, A,
              b0, nodes, source, y, current, u, jdata, stages):
    """Set up the stage system of interval l (from the end): J (the kernel at ``jac_address``)
    at its R nodes into jdata (jdata[j] at backward node j), and the right-hand side into
    ``stages``, the unknown (stage s, component i) at position[i] r + s. Returns the interval
    length h."""
    jac = rhs_kernel(jac_address)
    N, r, R = y.shape[0], A.shape[0], nodes.shape[0]
    h = grid[l + 1] - grid[l]
    g = source[l if source.shape[0] > 1 else 0]
    advance_backward(ptr, t_start, grid[l], grid[l + 1], current)
    for j in range(R):  # backward node j is forward node R - 1 - j
        t = grid[l + 1] - nodes[j] * h
        evaluate_primal(coef, t_start, t_end, current, t, u)
        jac(u.ctypes, t, p.ctypes, jdata[j].ctypes)
    slope = h * g[R - 1]  # h (J_0^T y_0 + source_0)
    add_transpose_product(indptr, indices, jdata[0], y, h, slope)
    for s in range(r):
        for i in range(N):
            value = y[i] + b0[s] * slope[i]
            for m in range(r):
                value += h * A[s, m] * g[R - 2 - m, i]
            stages[position[i] * r + s] = value
    return h


@helper()
def _store(phi, l, y, stages, position, r):
    """phi[l] from the interval's start value y and its solved stages."""
    R = phi.shape[1]
    for i in range(y.shape[0]):  # (not phi[l, R - 1, :] = y: see io.history)
        phi[l, R - 1, i] = y[i]
    for s in range(r):
        for i in range(y.shape[0]):
            phi[l, R - 2 - s, i] = stages[position[i] * r + s]


@helper()
def _backward_cg(jac_address, p, indptr, indices, position, kl, ku, grid, ptr, t_start, t_end,
                 coef, A, b0, nodes, source, psi, phi):
    """cG(r) for y' = J(U(T - s))^T y + source in s = T - t, interval by interval from T.

    The stage form of cG(r) with its Lobatto quadrature (see :mod:`dolfinode.methods.method`),

        xi_s = y_0 + h (b0_s F_0 + sum_m A_sm F_m),   F_m = J_m^T xi_m + source_m,

    is linear in the stages: (I - h (A (x) I) diag(J_m^T)) xi = y_0 + h b0 (J_0^T y_0 +
    source_0) + h (A (x) I) source. With the components in the bandwidth ordering
    ``position`` (lower/upper Jacobian band widths kl, ku) and the r stages of a component
    adjacent, the matrix has r (ku + 1) - 1 sub- and r (kl + 1) - 1 super-diagonals; the banded
    LU costs O(r N (r (kl + ku + 2))^2) per interval instead of O((r N)^3) densely.
    phi[l, j] receives the values at the forward nodes t_l + tau_j h (tau_j symmetric); the
    primal elements are tracked by one cursor per component (memory O(N)).
    Returns -1, or the interval l whose stage matrix is singular.
    """
    L, N = grid.shape[0] - 1, psi.shape[0]
    r, R = A.shape[0], nodes.shape[0]
    low, up = r * (ku + 1) - 1, r * (kl + 1) - 1
    u = np.empty(N)
    jdata = np.empty((R, max(indices.shape[0], 1)))
    ab = np.empty((r * N, 2 * low + up + 1))
    ipiv = np.empty(r * N, dtype=np.int64)
    stages = np.empty(r * N)
    current = ptr[1:] - 1
    y = psi.copy()
    for l in range(L - 1, -1, -1):
        h = _interval(jac_address, p, indptr, indices, position, l, grid, ptr, t_start, t_end,
                      coef, A, b0, nodes, source, y, current, u, jdata, stages)
        assemble_dual_matrix(jdata, indptr, indices, position, A, h, low, up, ab)
        if band_lu(ab, low, up, ipiv) != 0:
            return l
        band_solve(ab, low, up, ipiv, stages)
        _store(phi, l, y, stages, position, r)
        y = phi[l, 0].copy()
    return -1


def _stage_pattern(indptr, indices, position, r):
    """CSC pattern of the stage matrix I - h (A (x) I) diag(J_m^T) and the CSC position of
    each of its entries: first the (s, m, nz) products, then the identity."""
    n = len(position)
    c = np.repeat(np.arange(n), np.diff(indptr))  # J[c, i] with i = indices[nz]
    s, m = np.divmod(np.arange(r * r), r)
    rows = (position[indices][None, :] * r + s[:, None]).ravel()   # (s, i)
    columns = (position[c][None, :] * r + m[:, None]).ravel()      # (m, c)
    diagonal = np.arange(r * n)
    pairs = np.column_stack([np.concatenate([columns, diagonal]),
                             np.concatenate([rows, diagonal])])
    # CSR of the transpose = CSC of the matrix
    colptr, row_index, (position_of,) = assemble_pattern(r * n, [(pairs, [0], [1])])
    return colptr, row_index, position_of.ravel()


def _backward_cg_sparse(jac_address, p, indptr, indices, position, grid, ptr, t_start, t_end,
                        coef, A, b0, nodes, source, psi, phi):
    """As :func:`_backward_cg`, with the stage matrix factored by SuperLU (scipy's splu, fill-
    reducing column ordering) instead of the banded LU: for wide bands (2-D lattices)."""
    L, N = grid.shape[0] - 1, psi.shape[0]
    r, R = A.shape[0], nodes.shape[0]
    colptr, row_index, where = _stage_pattern(indptr, indices, position, r)
    u = np.empty(N)
    jdata = np.empty((R, max(indices.shape[0], 1)))
    stages = np.empty(r * N)
    current = ptr[1:] - 1
    values = np.empty(len(where))
    values[r * r * len(indices):] = 1.0
    products = values[:r * r * len(indices)].reshape(r, r, len(indices))
    y = psi.copy()
    for l in range(L - 1, -1, -1):
        h = _interval(jac_address, p, indptr, indices, position, l, grid, ptr, t_start, t_end,
                      coef, A, b0, nodes, source, y, current, u, jdata, stages)
        np.multiply(-h * A[:, :, None], jdata[None, 1:r + 1, :len(indices)], out=products)
        data = np.bincount(where, weights=values, minlength=len(row_index))
        matrix = sps.csc_matrix((data, row_index, colptr), shape=(r * N, r * N))
        try:
            stages = splu(matrix).solve(stages)
        except RuntimeError:  # "Factor is exactly singular"
            return l
        _store(phi, l, y, stages, position, r)
        y = phi[l, 0].copy()
    return -1


class PrimalPolynomials:
    """The stored solution U in the layout the dual needs: per-component elements in time
    order, each a polynomial in tau = (t - t_start) / (t_end - t_start) in monomial form, and
    the union grid of all element end points, refined where the goal's integrand needs it:
    its jumps in t are grid points, and inside its narrow features the intervals are no
    longer than the feature's step (the dual's source is read at the grid's nodes only: a
    window of t between two nodes was read as 0, and the estimate with it)."""

    def __init__(self, sol, integral=None):
        ptr, t_start, t_end, values = sol.elements()
        self.ptr, self.t_start, self.t_end = ptr, t_start, t_end
        self.coef = np.ascontiguousarray(values @ monomial_coefficients(sol.method.nodes))
        points = np.unique(np.concatenate([t_start, t_end]))
        if integral is not None:
            points = _refined(points, integral)
        # end points that differ by rounding only (multi-adaptive sub-slabs) are one point
        keep = np.diff(points, prepend=-np.inf) > 1e-13 * (sol.ode.T - sol.ode.t0)
        self.grid = points[keep]
        self.grid[-1] = sol.ode.T


def _refined(points, integral):
    """``points`` with the integrand's breakpoints, and points a feature's step apart
    across each of its narrow features."""
    features = integral.features
    more = [integral.breakpoints]
    for start, end, step in zip(features.start, features.end, features.step):
        more.append(np.linspace(start, end, int(np.ceil((end - start) / step)) + 1))
    more = np.concatenate(more)
    return np.union1d(points, more[(more > points[0]) & (more < points[-1])])


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


def solve_dual(sol, final, integral, degree, primal=None, linear_solver="auto"):
    """Solve the dual problem linearised at the solution ``sol``.

    Parameters
    ----------
    sol : Solution
    final, integral : the goal's parts from :func:`dolfinode.dual.goal.resolve` (or None)
    degree : int
        r of the cG(r) dual scheme (nodal order 2r on the primal's union grid).
    primal : PrimalPolynomials, optional
        Reused when given.
    linear_solver : {"auto", "banded", "sparse"}
        How the stage system of every interval is solved: the compiled banded LU in the
        Jacobian's bandwidth ordering (O(N b^2), for chains and narrow bands), scipy's splu
        (for wide bands, as on 2-D lattices), or the choice of :func:`dolfinode.linalg.wide_band`.

    Returns
    -------
    DualSolution, PrimalPolynomials

    Raises
    ------
    SolverError
        If the stage matrix of an interval is singular.
    """
    if linear_solver not in ("auto", "banded", "sparse"):
        raise ValueError(f"linear_solver must be 'auto', 'banded' or 'sparse', got "
                         f"{linear_solver!r}")
    ode = sol.ode
    primal = primal or PrimalPolynomials(sol, integral)
    compiled = lower(ode)
    _, position, kl, ku = compiled.ordering
    m = make_method("cG", degree)
    grid = primal.grid
    psi = np.zeros(ode.N)
    if final is not None:
        psi = final.at(sol(ode.T)[:, None], np.array([ode.T]))[:, 0]
    if integral is None:
        source = np.zeros((1, degree + 1, ode.N))
    else:
        times = grid[:-1, None] + np.outer(np.diff(grid), m.nodes)
        # g's t read on each interval's own side of a jump at its ends (a window of t)
        inside = np.clip(times, np.nextafter(grid[:-1], grid[1:])[:, None],
                         np.nextafter(grid[1:], grid[:-1])[:, None]).ravel()
        weights = integral.at(sol(times.ravel()), inside)
        source = np.ascontiguousarray(weights.T.reshape(len(grid) - 1, degree + 1, ode.N))
    phi = np.empty((len(grid) - 1, degree + 1, ode.N))
    arguments = (grid, primal.ptr, primal.t_start, primal.t_end, primal.coef, np.array(m.A),
                 m.b0.copy(), m.nodes.copy(), source, psi, phi)
    r = degree
    if linear_solver == "auto":
        linear_solver = "sparse" if wide_band(r * ode.N, r * (kl + ku + 2)) else "banded"
    if linear_solver == "sparse":
        failed = _backward_cg_sparse(compiled.jacobian.address, compiled.p, compiled.indptr,
                                     compiled.indices, position, *arguments)
    else:
        failed = _backward_cg(compiled.jacobian.address, compiled.p, compiled.indptr,
                              compiled.indices, position, kl, ku, *arguments)
    if failed >= 0:
        raise SolverError(f"the dual's stage matrix is singular on [{grid[failed]:.6g}, "
                          f"{grid[failed + 1]:.6g}]: I - h A (x) J^T has a zero pivot")
    coef = np.einsum("ljn,jc->lcn", phi, monomial_coefficients(m.nodes))
    return DualSolution(grid, coef), primal
