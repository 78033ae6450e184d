"""An a posteriori estimate of the error at T of a mono-adaptive cG(q)/dG(q) solution.

The error e_n = U(t_n) - u(t_n) at the slabs' ends obeys

    e_{n+1} = Phi_n e_n + d_n,   e_0 = 0,

with Phi_n the linearised exact flow over I_n = (t_n, t_{n+1}] and d_n the slab's local error,
the solution U_{n+1} against the exact flow from U_n (the dual problem with the goal e(T)
sums the same terms). Both are one linear problem on the slab, the error equation

    e' = J(t) e + R(t),   e(t_n^+) = e_n + [U]_n,

with the residual R = U' - f(t, U) of the slab polynomial, the jump [U]_n (zero for cG) and
J = df/du along U. It is solved by the (q + 2)-stage Radau IIA collocation, J_j at its stage
points: exact on the degree-(2q + 2) moments of R that Galerkin orthogonality leaves (the
leading term of d_n, O(k^{2q+1}) for cG(q) and O(k^{2q+2}) for dG(q)), and L-stable, so that
it stays bounded where k |lambda| >> 1 (d_n -> -J^{-1} R, Phi_n -> 0, as the exact flow).
The estimate is signed: errors that cancel over periods cancel in it, and errors that grow
(a period drifting with the energy) grow in it.

The method's own slab map (the Pade function of k J of cG(q) or dG(q)) is not the propagator
here: it pairs with the local error of a slab started from the exact solution, which is not
computable; with the residual's d_n, cG(q)'s undamped stiff modes would be counted twice
(measured: POLLU cG(2), cG(3) over-estimated 13-300 x at 1e-8 and 1e-9).

It holds while the error stays small enough for the linearised equation: the measure of
that is the nonlinearity nu = max_n |f(U_n - e_n) - f(U_n) + J_n e_n| / |J_n e_n| at the
slabs' ends (0 for linear systems); where nu > NONLINEAR_LIMIT the estimate is not trusted
(above 10 x the tolerance :func:`dolfinode.solve` then measures the error against a tighter
solve, and says that it could not be estimated where that fails). A small nu does not make
the estimate at T right: the remainder r = f(U - e) - f(U) + J e the linearised equation
leaves out is a forcing like R (the error obeys e' = J e + R - r), and where the run does not
damp it (an oscillation whose frequency depends on its amplitude, over many periods) it adds
up as R does. The second-order part g, the solution of g' = J g - r(e), g(t_0) = 0, is
propagated signed with e, by the same stage systems (:func:`_recursion`: r at the stage
points, one more back-substitution per slab), so that what the run damps does not add up
and what it carries does; scaled as the tolerance means it,

    delta = max_i |g_i(T)| / (w_i + |U_i(T) - e_i|),   w = atol / rtol,

it says how far the remainder moves the estimate at T. :func:`slab_estimate` has no values
of e inside its slabs to propagate r by and bounds it by the neutral sum, delta = max_i
sum_n k_n |r_{n,i}| / (w_i + |U_{n,i} - e_{n,i}|) at the slabs' ends (on a damped run it
over-counts). :func:`dolfinode.solve` measures the error where delta leaves the estimate on
either side of 10 x the tolerance.
"""
import itertools
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import sympy as sp
from numba import njit

from dolfinode.compile import lower
from dolfinode.compile.signatures import address, call_rhs_rows, component_kernel, rhs_kernel
from dolfinode.family import _parts as family_parts
from dolfinode.features import narrow_features
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.memory import SMALL_BYTES, available_memory
from dolfinode.methods.method import lagrange_matrices, monomial_coefficients, pade
from dolfinode.methods.quadrature import radau
from dolfinode.ode import t as time_symbol
from dolfinode.solution import _evaluate_components, _set_initial, dense_rule


def collocation_matrix(nodes):
    """The Butcher matrix of the collocation method on ``nodes`` in [0, 1]:
    a_ij = int_0^{c_i} l_j, with l_j the Lagrange basis on the nodes."""
    nodes = np.asarray(nodes, dtype=float)
    C = monomial_coefficients(nodes).T  # l_j(x) = sum_p C[p, j] x^p
    powers = np.arange(1, len(nodes) + 1)
    return (nodes[:, None] ** powers[None, :] / powers[None, :]) @ C


def radau_nodes(s):
    """The s right Radau points on [0, 1] (the last is 1), as floats."""
    return np.array(radau(s)[0], dtype=float)


@lru_cache(maxsize=32)
def _collocation(s):
    """(c, a): the nodes and Butcher matrix of the s-stage Radau IIA collocation (made once;
    shared, never written)."""
    c = radau_nodes(s)
    return c, collocation_matrix(c)


def _basis(method, x):
    """:func:`lagrange_matrices` (B, D) of ``method``'s basis at the points ``x``, made once
    per method and points (shared, never written)."""
    return _lagrange_matrices(tuple(float(c) for c in method.nodes), tuple(x))


@lru_cache(maxsize=64)
def _lagrange_matrices(nodes, x):
    return lagrange_matrices(nodes, x)


@lru_cache(maxsize=32)
def _stability(s):
    """(numerator, denominator): the coefficients, lowest degree first, of the s-stage Radau
    IIA stability function P(z), the (s - 1, s) Pade approximant of exp(z): the flow the
    collocation applies to its initial value for a constant J."""
    return pade(s - 1, s)


@lru_cache(maxsize=32)
def _flow_radius(s):
    """The largest r (in steps of 0.05, below P's poles) with |exp(z) - P(z)| <= FLOW_GAP / 10
    on |z| = r, hence on |z| <= r (the maximum principle): 0.4, 1.1, 1.85, 2.65 for s = 2..5."""
    edge = np.min(np.abs(np.roots(_stability(s)[1][::-1])))
    circle = np.exp(2j * np.pi * np.arange(720) / 720)
    radius = 0.0
    for r in np.arange(1, int(edge / 0.05)) * 0.05:
        if _largest_gap(s, r * circle) > FLOW_GAP / 10:
            break
        radius = r
    return radius


def _largest_gap(s, z):
    """max |exp(z) - P(z)| over the points ``z``, P the s-stage Radau IIA stability function."""
    num, den = _stability(s)
    return np.max(np.abs(np.exp(z) - np.polyval(num[::-1], z) / np.polyval(den[::-1], z)))


@lru_cache(maxsize=32)
def _flow_box(s):
    """The largest h (in steps of 0.05; 0 if none) with |exp(z) - P(z)| <= FLOW_GAP / 2 on
    the boundary of the box log(FLOW_GAP) <= Re z <= 0, |Im z| <= h, hence inside it (P's
    poles lie in Re z > 0): 0, 0, 2.95, 4.55 for s = 2..5. With the damped half-plane Re z <
    log(FLOW_GAP) it covers the moderately damped modes that :func:`_flow_radius` does not."""
    x = np.linspace(np.log(FLOW_GAP), 0.0, 500)
    h = 0.0
    for top in np.arange(1, 200) * 0.05:
        y = np.linspace(-top, top, 200)
        z = np.concatenate([x + 1j * top, x - 1j * top, x[0] + 1j * y, 1j * y])
        if _largest_gap(s, z) > FLOW_GAP / 2:
            break
        h = top
    return h


@lru_cache(maxsize=32)
def _stage_modes(s):
    """(mu, T, forcing) of :func:`_modal`: a = T diag(mu) T^-1 for the s-stage collocation
    matrix a, and forcing = T^-1 a."""
    a = _collocation(s)[1]
    mu, T = np.linalg.eig(a)
    return mu, T, np.linalg.inv(T) @ a


def _evaluators(compiled):
    """f(t, U) and J(t, U) (dense) for U of shape (P, N), through the compiled kernels."""
    N = compiled.N
    rows = np.repeat(np.arange(N), np.diff(compiled.indptr))

    def f(t, U):
        out = np.empty(U.shape)
        call_rhs_rows(compiled.rhs.address, np.ascontiguousarray(U), t, compiled.p, out)
        return out

    def J(t, U):
        data = np.empty((len(t), max(compiled.nnz, 1)))
        call_rhs_rows(compiled.jacobian.address, np.ascontiguousarray(U), t, compiled.p, data)
        out = np.zeros((len(t), N, N))
        out[:, rows, compiled.indices] = data[:, :compiled.nnz]
        return out

    return f, J


def _constant_jacobian(ode, compiled):
    """Whether df/du is constant (a linear system with coefficients free of t): from the
    declaration's expressions on the Jacobian's pattern (False for template systems)."""
    rhs = getattr(ode, "rhs", None)
    if rhs is None or hasattr(ode, "templates"):
        return False
    variables = set(ode.states) | {time_symbol}
    rows = np.repeat(np.arange(compiled.N), np.diff(compiled.indptr))
    return not any(sp.diff(rhs[i], ode.states[j]).free_symbols & variables
                   for i, j in zip(rows, compiled.indices))


def _residual(sol, f, nodes_at, part, before=None):
    """R = U' - f(t, U) of the slabs ``part`` (a slice) at the relative points ``nodes_at``:
    (M, len, N); and their jumps U(t_n^+) - U(t_n^-): (M, N), U(t_0^-) = ``before`` (default
    u0) before ``sol``'s first slab."""
    vals, k, t0 = sol.values[part], sol.k[part], sol.t_start[part]
    M, _, N = vals.shape
    B, D = _basis(sol.method, nodes_at)
    U = np.einsum("ij,mjn->min", B, vals)
    dU = np.einsum("ij,mjn->min", D, vals) / k[:, None, None]
    t = (t0[:, None] + nodes_at[None, :] * k[:, None]).ravel()
    R = dU - f(t, U.reshape(-1, N)).reshape(M, len(nodes_at), N)
    start = _basis(sol.method, (0.0,))[0][0] @ vals  # (M, N)
    first = part.start or 0
    if first:
        previous = sol.values[first - 1, -1, :]
    else:
        previous = np.asarray(sol.ode.u0 if before is None else before, dtype=float)
    before = np.concatenate([previous[None, :], vals[:-1, -1, :]])
    return R, start - before


#: Pieces of the composite 3-point Gauss rule that integrates R over each slab of a run whose
#: f has narrow features (:func:`_feature_shifts`): FEATURE_PIECES across a feature,
#: TAIL_PIECES elsewhere (f's tails: atan(k (t - 3)) ~ 1 / (k (3 - t)) outside the feature).
FEATURE_PIECES = 256
TAIL_PIECES = 64


def _composite(pieces):
    """(x, w): the composite 3-point Gauss rule on ``pieces`` equal pieces of [0, 1]."""
    g, w = np.polynomial.legendre.leggauss(3)
    x = ((np.arange(pieces)[:, None] + (g[None, :] + 1) / 2) / pieces).ravel()
    return x, np.tile(w / 2, pieces) / pieces


def _feature_shifts(sol, compiled, c, a, chunk=256):
    """(slabs, shifts): for a run whose f has narrow features in its state-free terms
    (:func:`dolfinode.features.narrow_features`; none for others), its slabs and per slab
    the constant added to R at the stages so that the collocation's quadrature
    sum_j a_sj R_j of R's mean over the slab becomes that of the composite rule
    (:data:`FEATURE_PIECES`). The collocation integrates R exactly up to degree 2s - 2; a
    steep f(t) is far from a polynomial over a slab, across its feature and in its tails,
    and that quadrature's error is the slab's error the estimate mis-counted (u' = atan(k
    (t - 3)) at 1e-7, errors from the slabs [2.88, 2.99] and [2.9999, 3.0001]: k = 1e6
    dG(3) 2.7 x the tolerance, estimated 74 x; k = 1e5 cG(2) 36 x, estimated 105 x)."""
    features = narrow_features(sol.ode)
    if not len(features):
        return np.empty(0, dtype=np.int64), np.empty((0, len(sol.ode.u0)))
    f = _evaluators(compiled)[0]
    coarse = a[-1]
    x, w = _composite(TAIL_PIECES)
    shifts = np.empty((len(sol.k), len(sol.ode.u0)))
    for lo in range(0, len(sol.k), chunk):
        part = slice(lo, min(lo + chunk, len(sol.k)))
        shifts[part] = (np.einsum("i,min->mn", w, _residual(sol, f, x, part)[0])
                        - np.einsum("i,min->mn", coarse, _residual(sol, f, c, part)[0]))
    ends = sol.t_start + sol.k
    x, w = _composite(FEATURE_PIECES)
    for start, end in zip(features.start, features.end):
        inside = np.flatnonzero((sol.t_start < end) & (ends > start))
        for lo in range(inside[0], inside[-1] + 1, chunk) if inside.size else ():
            part = slice(lo, min(lo + chunk, inside[-1] + 1))
            shifts[part] = (np.einsum("i,min->mn", w, _residual(sol, f, x, part)[0])
                            - np.einsum("i,min->mn", coarse, _residual(sol, f, c, part)[0]))
    return np.arange(len(sol.k), dtype=np.int64), shifts


def _modal(sol, compiled, lam, V, c, slabs, shifts, chunk=4096, e=None, before=None,
           own_ends=None, weight=None, peak=None):
    """The recursion in the eigenbasis (lam, V) of a constant J, where each slab's stage
    system is scalar per mode z = k lambda: with a = T diag(mu) T^{-1}, the last stage of
    (I - z a)^{-1} x is T[-1] diag(1 / (1 - z mu)) T^{-1} x, for ``chunk`` slabs at once;
    from the error ``e`` (default 0) and the value ``before`` (default u0) at the start of
    ``sol``'s first slab. ``peak`` (in place, as :func:`_recursion`'s) keeps the largest
    |e_{n,i}| / (weight_i + |U_i(t_n) - e_{n,i}|) where ``own_ends[n, i]`` (None: nowhere).

    The error at the slab's start (e_n + [U]_n) is carried by the exact flow exp(z), not by
    the collocation's: where a step spans many periods of a weakly damped oscillation
    (|z| >> 1, Re z small) the collocation, L-stable, damps it as dG(q) itself does, and
    the estimate would miss the amplitude dG(q) removed (a mode of frequency 1000 and
    decay rate 0.05 stepped over by dG(2) at 1e-3: 251 x the tolerance, estimated 2 x)."""
    f = _evaluators(compiled)[0]
    Vi = np.linalg.inv(V)
    mu, T, forcing = _stage_modes(len(c))
    e = np.zeros(len(lam), dtype=complex) if e is None else Vi @ e
    for lo in range(0, len(sol.k), chunk):
        part = slice(lo, min(lo + chunk, len(sol.k)))
        R, jump = _residual(sol, f, c, part, before)
        inside = (slabs >= part.start) & (slabs < part.stop)
        R[slabs[inside] - part.start] += shifts[inside][:, None, :]
        k = sol.k[part]
        z = (k[:, None] * lam[None, :])[..., None]  # (M, N, 1)
        # the stage right-hand sides k a R in the stage eigenbasis: (M, N, s)
        w = (forcing @ (R @ Vi.T) * k[:, None, None]).transpose(0, 2, 1)
        flow = np.exp(z[..., 0])  # the slab's map of e_n + [U]_n, per mode
        d = w / (1 - z * mu) @ T[-1] + flow * (jump @ Vi.T)
        if own_ends is not None:
            _modal_ends(sol, part, V, flow, d, e, own_ends, weight, peak)
        # e after the chunk: prod flow e + sum_n (prod_{m > n} flow_m) d_n
        after = np.cumprod(flow[::-1], axis=0)[::-1]
        e = after[0] * e + np.sum(np.concatenate([after[1:], np.ones((1, len(lam)))]) * d, axis=0)
    return (V @ e).real


def _modal_ends(sol, part, V, flow, d, e, own_ends, weight, peak):
    """peak (value, time, component) = the largest scaled error so far (:func:`_modal`) at
    the ends of the slabs ``part``, e_n = flow_n e_{n-1} + d_n from ``e`` in the eigenbasis
    (a scan beside the chunk's product, which e at T keeps)."""
    own = own_ends[part]
    error = (_modal_scan(flow, d, e) @ V.T).real  # (M, N)
    values = _basis(sol.method, (1.0,))[0][0] @ sol.values[part]  # U(t_n), (M, N)
    ratio = np.where(own, np.abs(error) / (weight + np.abs(values - error)), 0.0)
    n, i = np.unravel_index(np.argmax(ratio), ratio.shape)
    if ratio[n, i] > peak[0]:
        peak[:] = ratio[n, i], sol.t_start[part][n] + sol.k[part][n], i


@njit(cache=True)
def _modal_scan(flow, d, e):
    """E_n = flow_n E_{n-1} + d_n, E_{-1} = ``e``: a chunk's errors at its slab ends by mode."""
    E = np.empty_like(d)
    for n in range(d.shape[0]):
        for i in range(d.shape[1]):
            E[n, i] = flow[n, i] * (E[n - 1, i] if n else e[i]) + d[n, i]
    return E


#: Stage systems without a narrow band are solved by LAPACK above LAPACK_SIZE rows, and by
#: the band LU over their band below (measured, the estimate's time against a dense
#: elimination: HIRES cG(1), 24 rows, 0.73 x; against LAPACK: POLLU cG(1), 60 rows, 0.63 x;
#: VDPOL, ROBER, 8-15 rows, 1.1-1.2 x, 0.1 ms in all; over the band of HIRES dG(3), 14 of its
#: 39 sub- and super-diagonals, against the full band: 0.8 x, the same factors).
LAPACK_SIZE = 64


def stage_band(compiled, s):
    """(position, kl, ku) of the stage system (I - k a (x) J) of ``s`` stages with its
    unknowns ordered component-major, stage (i, r) at row s position[r] + i (``position``:
    the components' reverse Cuthill-McKee order when it narrows J's band): a J of
    bandwidths (b_l, b_u) gives kl = s b_l + s - 1, ku = s b_u + s - 1."""
    _, position, kl, ku = compiled.ordering
    return position, s * kl + s - 1, s * ku + s - 1


def banded(rows, kl, ku):
    """Whether a stage system of ``rows`` rows and bandwidths (kl, ku) is solved banded: its
    band LU (rows kl (kl + ku) flops) costs less than half the dense one (rows^3 / 3)."""
    return 6 * kl * (kl + ku) < rows * rows


#: A mode z = k lambda of a slab's mean Jacobian whose exact flow exp(z) and collocated one
#: P(z) (:func:`_stability`) differ by more than FLOW_GAP is carried exactly by the compiled
#: pass: a weakly damped oscillation stepped over (|z| >> 1, Re z small), where P(z) ~ 1 / z
#: and exp(z) keeps the amplitude. No eigenproblem is solved while k ||J||_1 stays below
#: :func:`_flow_radius` (where |exp(z) - P(z)| <= FLOW_GAP / 10), no eigenvectors where no
#: mode qualifies. Damped modes, |exp(z)| <= FLOW_GAP, stay with the collocation:
#: its stage Jacobians follow J's variation, which the exact flow of the mean does not, and
#: that broke the cancellation of dG(q)'s jump against its residual (HIRES dG(q) at 1e-4:
#: estimated 0.23 x the error, 1.0 x with the collocation's flow).
FLOW_GAP = 1e-2


@njit(cache=True)
def _gaps(lam, num, den):
    """exp(z) - P(z) at z = ``lam`` where it and |exp(z)| exceed FLOW_GAP, 0 elsewhere."""
    g = np.zeros(lam.size, dtype=np.complex128)
    for i in range(lam.size):
        z, top, bottom = lam[i], 0j, 0j
        for j in range(num.size - 1, -1, -1):
            top = top * z + num[j]
        for j in range(den.size - 1, -1, -1):
            bottom = bottom * z + den[j]
        gap = np.exp(z) - top / bottom
        if abs(gap) > FLOW_GAP and np.exp(z.real) > FLOW_GAP:
            g[i] = gap
    return g


#: The eigenbasis V of a slab's Z (:func:`_flow_gap`) is kept for the next slabs while its
#: condition ||V||_1 ||V^-1||_1 is below BASIS_CONDITION (:func:`_flows_agree`).
BASIS_CONDITION = 1e6


@njit(cache=True)
def _flow_gap(Z, x, num, den, basis):
    """((exp(Z) - P(Z)) x restricted to the modes z of Z where |exp(z) - P(z)| and |exp(z)|
    exceed FLOW_GAP (:func:`_gaps`), in Z's eigenbasis (zero where there is none, or where
    that basis is near-defective: condition above MODAL_CONDITION), for the columns of ``x``
    (N, m); whether that basis V and V^-1 were kept in basis[0], basis[1] for
    :func:`_flows_agree` (BASIS_CONDITION))."""
    out = np.zeros(x.shape)
    if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(x))):
        return out, False  # (J or e not finite: the stage solve's e is not either, and says so)
    lam, V = np.linalg.eig(Z.astype(np.complex128))
    try:
        inverse = np.linalg.inv(V)
    except Exception:  # noqa: BLE001 - (numba: V singular, LinAlgError) a defective Z
        inverse = np.full(V.shape, np.inf + 0j)
    kept = _norm1(V) * _norm1(inverse) < BASIS_CONDITION
    if kept:
        basis[0], basis[1] = V, inverse
    gaps = _gaps(lam, num, den)
    if np.all(gaps == 0) or np.linalg.cond(V) > MODAL_CONDITION:
        return out, kept
    y = gaps.reshape((gaps.size, 1)) * np.linalg.solve(V, x.astype(np.complex128))
    return (V @ y).real, kept


@njit(cache=True)
def _norm1(A):
    """||A||_1, the largest column sum of |A|."""
    largest = 0.0
    for j in range(A.shape[1]):
        column = 0.0
        for i in range(A.shape[0]):
            column += abs(A[i, j])
        largest = max(largest, column)
    return largest


@njit(cache=True)
def _product(A, B, out):
    """out = A B (square matrices), returned."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0j
            for m in range(A.shape[1]):
                acc += A[i, m] * B[m, j]
            out[i, j] = acc
    return out


@njit(cache=True)
def _flows_agree(Z, V, inverse, radius, box, work):
    """Whether no mode of Z is one that :func:`_gaps` carries, without its eigenvalues: the
    Gershgorin discs (rows, or columns) of W = V^-1 Z V, similar to Z and near diagonal
    where V is the eigenbasis of an earlier slab's Z and J changed little since, or of
    S^-1 W S, S = diag(|W_ii|^(-1/2)) (a stiff mode's row then weighs little on the slow
    ones'), each lie where exp(z) <= FLOW_GAP (Re z <= log FLOW_GAP) or |exp(z) - P(z)| <=
    FLOW_GAP / 10 (|z| <= ``radius``, :func:`_flow_radius`), or within Re z <= 0, |Im z|
    <= ``box`` (:func:`_flow_box`); each entry of W widened by its rounding (N eps
    ||V^-1||_1 ||Z||_1 ||V||_1). ``work``: room for Z V and W, (2, N, N) complex (a slab's
    test allocated nothing: it ran on most slabs of ROBER and VDPOL)."""
    N = Z.shape[0]
    W = _product(inverse, _product(Z, V, work[0]), work[1])
    rounding = N * 2.2e-16 * _norm1(inverse) * _norm1(Z) * _norm1(V)
    damped = np.log(FLOW_GAP)
    rows = columns = scaled_rows = scaled_columns = True  # of W, of S^-1 W S
    for i in range(N):
        row = column = scaled_row = scaled_column = rounding
        scale_i = 1.0 / np.sqrt(max(1.0, abs(W[i, i])))
        for j in range(N):
            if j != i:
                scale_j = 1.0 / np.sqrt(max(1.0, abs(W[j, j])))
                row += abs(W[i, j]) + rounding
                column += abs(W[j, i]) + rounding
                scaled_row += (abs(W[i, j]) + rounding) * scale_j / scale_i
                scaled_column += (abs(W[j, i]) + rounding) * scale_i / scale_j
        z = W[i, i]
        rows = rows and _in_flow_region(z, row, damped, radius, box)
        columns = columns and _in_flow_region(z, column, damped, radius, box)
        scaled_rows = scaled_rows and _in_flow_region(z, scaled_row, damped, radius, box)
        scaled_columns = scaled_columns and _in_flow_region(z, scaled_column, damped, radius,
                                                            box)
        if not (rows or columns or scaled_rows or scaled_columns):
            return False
    return True


@njit(cache=True)
def _in_flow_region(z, rho, damped, radius, box):
    """Whether the disc |w - z| <= rho lies where no mode is carried (:func:`_flows_agree`)."""
    return (z.real + rho < damped or abs(z) + rho <= radius
            or (z.real + rho <= 0 and abs(z.imag) + rho <= box))


@njit(cache=True)
def _recursion(rhs, jacobian, p, indptr, indices, values, k, t_start, e0, before, g,
               nodes, B, D, a, position, kl, ku, num, den, radius, box, slabs, shifts,
               weight, own_ends, peak):
    """(e_M, nu): e_{n+1} = the last stage of (I - k a (x) J_j) E = 1 (x) (e_n + [U]_n)
    + k (a (x) I) R, one slab after the other from e_0 = ``e0`` (U(t_0^-) = ``before``, the
    previous slab's end value or u0), (J_j, R_j at the Radau points ``nodes``; ``B``,
    ``D``: the slab polynomial and its derivative at 0 and at the nodes), and nu as in the
    module docstring, from the last stage's J and f at the slab's end. The second-order
    part ``g`` (in place, from its value at t_0) is carried by the same stage system, with
    the remainder r_j = f(U_j - E_j) - f(U_j) + J_j E_j at the stages as its forcing:
    g_{n+1} = the last stage of (I - k a (x) J_j) G = 1 (x) g_n - k (a (x) I) r (one more
    back-substitution). The stage (i, r) is
    unknown s position[r] + i (:func:`stage_band`); kl >= 0: the system is solved by its
    band LU with bandwidths (kl, ku), kl < 0: by LAPACK. On the modes of the slab's mean
    Jacobian Z = k sum_j a_sj J_j where the collocation's flow P(z) (coefficients ``num``,
    ``den``; none while k ||J||_1 <= ``radius``, nor while the eigenbasis of an earlier
    slab's Z shows none, :func:`_flows_agree`) departs from exp(z) (:data:`FLOW_GAP`),
    e_n + [U]_n and g_n are carried by exp(z), as in :func:`_modal`: e_{n+1} += (exp(Z) -
    P(Z)) (e_n + [U]_n) on those modes, and g_{n+1} likewise. ``shifts[i]``
    is added to R at every stage of the slab ``slabs[i]`` (increasing;
    :func:`_feature_shifts`). ``peak`` (in place: value, time, component) keeps the
    largest |e_{n,i}| / (weight_i + |U_i(t_n) - e_{n,i}|) over the slabs' ends t_n, scaled
    as :func:`scaled` (the error mid-run), where ``own_ends[n, i]``."""
    f, jac = rhs_kernel(rhs), rhs_kernel(jacobian)
    M, s, N, nnz = k.size, nodes.size, e0.size, indices.size
    U, R, F = np.empty((s + 1, N)), np.empty((s, N)), np.empty((s, N))
    fU, data = np.empty(N), np.empty((s, max(nnz, 1)))
    band = kl >= 0
    A = np.empty((0, 0)) if band else np.empty((s * N, s * N))
    ab = np.zeros((s * N, 2 * kl + ku + 1) if band else (0, 0))  # (band_storage)
    pivots = np.empty(s * N if band else 0, dtype=np.int64)
    b, c = np.empty(s * N), np.empty(s * N)
    x, e, shifted = np.empty(N), e0.copy(), np.empty(N)
    starts = np.empty((N, 2))  # e_n + [U]_n and g_n, for the exact flow's part
    exact = N <= MAX_DENSE  # (Z is dense: large banded systems keep the collocation's flow)
    Z = np.empty((N, N) if exact else (0, 0))
    # an earlier slab's eigenbasis of Z and its inverse, where kept (:func:`_flows_agree`)
    basis, kept = np.empty((2, N, N) if exact else (2, 0, 0), dtype=np.complex128), False
    work = np.empty_like(basis)  # (:func:`_flows_agree`)
    next_shift = 0
    nu = 0.0
    for n in range(M):
        U[:] = 0.0
        R[:] = 0.0
        for i in range(s + 1):
            for j in range(values.shape[1]):
                for col in range(N):
                    U[i, col] += B[i, j] * values[n, j, col]
                    if i:
                        R[i - 1, col] += D[i, j] * values[n, j, col] / k[n]
        for i in range(s):
            t = t_start[n] + nodes[i] * k[n]
            f(address(U, (i + 1) * N), t, address(p, 0), address(F, i * N))
            jac(address(U, (i + 1) * N), t, address(p, 0), address(data, i * data.shape[1]))
            for col in range(N):
                R[i, col] -= F[i, col]
        if next_shift < slabs.size and slabs[next_shift] == n:
            for i in range(s):
                for col in range(N):
                    R[i, col] += shifts[next_shift, col]
            next_shift += 1
        for col in range(N):  # x = e_n + [U]_n
            x[col] = e[col] + U[0, col] - (before[col] if n == 0 else values[n - 1, -1, col])
        if band:
            ab[:] = 0.0
        else:
            A[:] = 0.0
        for r in range(N):
            for i in range(s):
                row = s * position[r] + i
                b[row] = x[r]
                for j in range(s):
                    b[row] += k[n] * a[i, j] * R[j, r]
                if band:
                    ab[row, kl + ku] += 1.0
                else:
                    A[row, row] += 1.0
                for m in range(indptr[r], indptr[r + 1]):
                    for j in range(s):
                        col = s * position[indices[m]] + j
                        if band:
                            ab[col, kl + ku + row - col] -= k[n] * a[i, j] * data[j, m]
                        else:
                            A[row, col] -= k[n] * a[i, j] * data[j, m]
        factored = True
        if band:
            factored = band_lu(ab, kl, ku, pivots) == 0
            if factored:
                band_solve(ab, kl, ku, pivots, b)
            else:
                b[:] = np.nan  # (a singular stage system: the estimate says so)
        else:
            b = np.linalg.solve(A, b)
        # the remainder at the stages, R holding it in turn: r_j = f(U_j - E_j) - f(U_j) + J_j E_j
        for i in range(s):
            for col in range(N):
                shifted[col] = U[i + 1, col] - b[s * position[col] + i]
            t = t_start[n] + nodes[i] * k[n]
            f(address(shifted, 0), t, address(p, 0), address(fU, 0))
            for col in range(N):
                linear = 0.0
                for m in range(indptr[col], indptr[col + 1]):
                    linear += data[i, m] * b[s * position[indices[m]] + i]
                R[i, col] = fU[col] - F[i, col] + linear
        for r in range(N):
            for i in range(s):
                row = s * position[r] + i
                c[row] = g[r]
                for j in range(s):
                    c[row] -= k[n] * a[i, j] * R[j, r]
        if not factored:
            c[:] = np.nan
        elif band:
            band_solve(ab, kl, ku, pivots, c)
        else:
            c = np.linalg.solve(A, c)
        for r in range(N):
            e[r] = b[s * position[r] + s - 1]
            starts[r, 0], starts[r, 1] = x[r], g[r]
            g[r] = c[s * position[r] + s - 1]
        Z[:] = 0.0
        for r in range(N if exact else 0):
            for m in range(indptr[r], indptr[r + 1]):
                for j in range(s):
                    Z[r, indices[m]] += k[n] * a[s - 1, j] * data[j, m]
        if (exact and _norm1(Z) > radius
                and not (kept and _flows_agree(Z, basis[0], basis[1], radius, box, work))):
            gap, kept = _flow_gap(Z, starts, num, den, basis)
            e += gap[:, 0]
            g += gap[:, 1]
        for r in range(N):
            if own_ends[n, r]:
                _keep_peak(peak, e[r], weight[r], U[s, r], t_start[n] + k[n], r)
        # nu: |f(U - e) - f(U) + J e| / |J e| at the slab's end, its last stage point
        for col in range(N):
            shifted[col] = U[s, col] - e[col]
        f(address(shifted, 0), t_start[n] + k[n], address(p, 0), address(fU, 0))
        size = remainder = 0.0
        for r in range(N):
            linear = 0.0
            for m in range(indptr[r], indptr[r + 1]):
                linear += data[s - 1, m] * e[indices[m]]
            size = max(size, abs(linear))
            remainder = max(remainder, abs(fU[r] - F[s - 1, r] + linear))
        if size > 0:
            nu = max(nu, remainder / size)
    return e, nu


#: The share of the available memory the values of a multi-adaptive solution's common slabs
#: may take (every component at every common slab: a 200-mass chain's mcG(1), 10 GB and more).
COMMON_MEMORY_FRACTION = 0.25


def _common_slabs(sol):
    """A multi-adaptive solution as slabs: the intervals between consecutive element ends of
    all components, on each of which every component is one polynomial of degree q, with
    their values at the method's nodes (each from the element ending at or after the node:
    left limits at the ends, as the mono-adaptive values)."""
    ends = np.unique(np.concatenate([sol.t_start, sol._t_end]))
    # (ends that differ by rounding only would make intervals of no length; a few ulps of
    # each end's own size, not of the largest: far from t = 0 the elements are short of it)
    ends = ends[np.concatenate([[True], np.diff(ends) > 16 * np.spacing(np.abs(ends[1:]))])]
    t_start, k = ends[:-1], np.diff(ends)
    nodes = np.asarray(sol.method.nodes, dtype=float)
    # (sol(times) holds them twice, transposed and in place)
    size = 2 * 8 * len(k) * len(nodes) * len(sol.ode.u0)
    if size > COMMON_MEMORY_FRACTION * available_memory():
        raise ValueError(f"the global error estimate of this multi-adaptive solution needs its "
                         f"{len(k)} common slabs' values, {size / 2**30:.3g} GB, more than "
                         f"{COMMON_MEMORY_FRACTION:g} x the memory available: estimate a "
                         "cG(q)/dG(q) solve at the same tolerance, or use dn.estimate_error "
                         "with a goal")
    # (the Galerkin polynomials, not the dense value sol(t) reads: the residual is U's)
    times = (t_start[:, None] + nodes[None, :] * k[:, None]).ravel()
    values = np.empty((times.size, sol.ode.N)).T
    _evaluate_components(sol._component_ptr, sol.t_start, sol._t_end, sol.values, nodes,
                         sol.method.barycentric_weights, dense_rule(sol.method, dense=False),
                         sol.ode.t0, sol.ode.u0, times, values)
    _set_initial(times, sol.ode.t0, sol.ode.u0, values)
    values = np.ascontiguousarray(values.T.reshape(len(k), len(nodes), -1))
    # (each component's element ends among the slabs' ends)
    own_ends = np.zeros((len(k), sol.ode.N), dtype=np.bool_)
    ptr = sol._component_ptr
    for i in range(sol.ode.N):
        slab = np.searchsorted(ends, sol._t_end[ptr[i]:ptr[i + 1]], side="right") - 2
        own_ends[np.clip(slab, 0, len(k) - 1), i] = True
    return SimpleNamespace(method=sol.method, ode=sol.ode, t_start=t_start, k=k, values=values,
                           own_ends=own_ends)


#: Systems whose stage matrices ((q + 2) N rows per slab) have no narrow band, a non-constant
#: Jacobian or a constant one whose eigenvectors have a condition number above
#: MODAL_CONDITION (a Jordan block: x' = v, v' = c) are estimated with dense stage
#: matrices: at most MAX_DENSE components.
MAX_DENSE = 200
MODAL_CONDITION = 1e8


#: The linearised error equation is taken not to describe the error where the propagated
#: error makes f's remainder exceed NONLINEAR_LIMIT times its linear part. Measured
#: (benchmarks/probe_global_error_signed.py): at most 1.7 on HIRES, ROBER, POLLU and the
#: unseen problems (Kepler's orbit at 1e-3, 1000 x its tolerance, included); VDPOL 0.07-1.7e4
#: at 1e-5 and 1e-7 (estimate 0.1-4 x the error) and 8e3-3e9 at 1e-3 across its folds (the
#: runs whose estimate is 118-4200 x the error: 6e6 and above).
NONLINEAR_LIMIT = 100.0


def second_order(g, U, e, weight):
    """delta = max_i |g_i| / (w_i + |U_i - e_i|): the second-order part ``g`` of the error at
    T (see the module docstring) scaled as the tolerance means it, by the exact solution's
    estimate U(T) - e (``weight``: w = atol / rtol per component)."""
    return float(np.max(np.abs(g) / (weight + np.abs(U - e)), initial=0.0))


def estimate(sol, compiled=None, weight=None):
    """(e, nu, delta): the signed estimate e ~ U(T) - u(T), shape (N,), of a cG(q)/dG(q)
    solution, the nonlinearity nu of the error equation along the run and its second-order
    part delta (see the module docstring; ``weight``: atol / rtol per component, default 1);
    ``compiled``: the kernels it was solved with (default: those of ``sol.ode``). A
    multi-adaptive solution is taken on the common refinement of its elements. Stage systems
    with a narrow band (:func:`banded`) are solved banded, others densely, or mode by mode
    for a constant J with a well-conditioned eigenbasis (:class:`Running`, over the whole
    history at once).

    Raises
    ------
    ValueError
        For more than MAX_DENSE components with dense stage systems and a Jacobian that is
        not constant, or a multi-adaptive solution whose common slabs do not fit in memory.
    """
    run = carried(sol, compiled, weight)
    return run.e, run.nu, run.delta


def carried(sol, compiled=None, weight=None):
    """The :class:`Running` recursion of :func:`estimate` carried over the whole of ``sol``
    (its e, nu, delta and the error mid-run ``peak``, at every element end of every
    component: a mono-adaptive solution's slab ends)."""
    compiled = lower(sol.ode) if compiled is None else compiled
    run = Running(sol.ode, compiled, sol.method, weight)
    if sol._component_ptr is None:
        run.add(sol.t_start, sol.k, sol.values)
    else:
        sol = _common_slabs(sol)
        run.add(sol.t_start, sol.k, sol.values, sol.own_ends)
    return run


def along(sol, chunks=64, compiled=None):
    """(times, e): the estimate e ~ U - u, shape (N, M), at t0 and at the ends of ``chunks``
    equal runs of slabs (M <= chunks + 1), carried as :func:`carried` carries it to T (a
    multi-adaptive solution on the common refinement of its elements)."""
    compiled = lower(sol.ode) if compiled is None else compiled
    run = Running(sol.ode, compiled, sol.method)
    if sol._component_ptr is not None:
        sol = _common_slabs(sol)
    n = len(sol.k)
    cuts = np.unique(np.linspace(0, n, min(chunks, n) + 1).astype(int))
    times, errors = [sol.ode.t0], [run.e.copy()]
    for a, b in itertools.pairwise(cuts):
        run.add(sol.t_start[a:b], sol.k[a:b], sol.values[a:b])
        times.append(sol.t_start[b - 1] + sol.k[b - 1])
        errors.append(run.e.copy())
    return np.array(times), np.array(errors).T


class Running:
    """The recursion of :func:`estimate` for a mono-adaptive run of ``ode`` by ``method``
    (with the kernels ``compiled``), carried chunk by chunk as the run's slabs arrive
    (:meth:`add`), so that a solve without history (``dense_output=False`` or a file) is
    estimated as one with it: it keeps e_n, U(t_n^-), nu and the second-order part g
    (``weight``: atol / rtol per component, default 1), not the slabs, and each chunk
    continues the arithmetic of the one pass over the whole history. ``peak`` (value, time,
    component) is the largest error mid-run at the ends :meth:`add` is given (:func:`carried`).

    Raises
    ------
    ValueError
        For more than MAX_DENSE components with dense stage systems and a Jacobian that is
        not constant.
    """

    def __init__(self, ode, compiled, method, weight=None):
        c, a = _collocation(method.q + 2)
        position, kl, ku = stage_band(compiled, len(c))
        rows = len(c) * compiled.N
        self.modes = None  # (lam, V): a constant J estimated mode by mode (:func:`_modal`)
        if not banded(rows, kl, ku):
            if rows > LAPACK_SIZE:  # (below, the band LU over the band: kl, ku < rows)
                kl = ku = -1
            self.modes = _constant_modes(ode, compiled)
            if self.modes is None and compiled.N > MAX_DENSE:
                raise ValueError(f"the global error estimate of a system whose Jacobian has no "
                                 f"narrow band is dense (unless linear with a well-conditioned "
                                 f"eigenbasis): at most {MAX_DENSE} components, got "
                                 f"{compiled.N}")
        self.ode, self.compiled, self.method, self.c, self.a = ode, compiled, method, c, a
        B, D, flows = _stage_tables(tuple(float(node) for node in method.nodes))
        self.stages = (c, B, D, a, position, kl, ku, *flows)
        self.e, self.nu, self.g = np.zeros(compiled.N), 0.0, np.zeros(compiled.N)
        self.weight = np.ones(compiled.N) if weight is None else np.asarray(weight, dtype=float)
        self.peak = np.zeros(3)
        self.before = np.array(ode.u0, dtype=float)  # U(t_n^-) of the next slab

    @property
    def delta(self):
        """The second-order part of the estimate so far (see the module docstring)."""
        return second_order(self.g, self.before, self.e, self.weight)

    def add(self, t_start, k, values, own_ends=None):
        """Carry e over the next slabs of the run, (t_start (n,), k (n,), values (n, q + 1,
        N)), as a mono-adaptive loop's chunk holds them (``own_ends`` (n, N): where the
        error mid-run is compared, :attr:`peak`; None: at every slab end, where every
        component of a mono-adaptive run ends)."""
        if not len(k):
            return
        if own_ends is None:
            own_ends = np.ones((len(k), self.ode.N), dtype=np.bool_)
        part = SimpleNamespace(method=self.method, ode=self.ode, t_start=t_start, k=k,
                               values=values)
        shifts = _feature_shifts(part, self.compiled, self.c, self.a)
        if self.modes is not None:
            self.e = _modal(part, self.compiled, *self.modes, self.c, *shifts, e=self.e,
                            before=self.before, own_ends=own_ends, weight=self.weight,
                            peak=self.peak)
        else:
            compiled = self.compiled
            self.e, nu = _recursion(compiled.rhs.address, compiled.jacobian.address,
                                    compiled.p, compiled.indptr, compiled.indices,
                                    np.ascontiguousarray(values), k, t_start, self.e,
                                    self.before, self.g, *self.stages,
                                    *shifts, self.weight, own_ends, self.peak)
            self.nu = max(self.nu, nu)
        self.before = values[-1, -1].copy()


@lru_cache(maxsize=32)
def _stage_tables(nodes):
    """(B, D, (num, den, radius, box)) of :func:`_recursion` for a method's ``nodes``, made
    once (shared, never written): its basis and derivative at 0 and at the Radau points of
    len(nodes) + 1 stages, and that collocation's stability function, flow radius and box."""
    s = len(nodes) + 1
    B, D = _lagrange_matrices(nodes, (0.0, *(float(x) for x in _collocation(s)[0])))
    return B, D, (*_stability(s), _flow_radius(s), _flow_box(s))


def _constant_modes(ode, compiled):
    """(lam, V): the eigenvalues and eigenvectors of ``ode``'s J where it is constant with an
    eigenbasis of condition number below MODAL_CONDITION; None otherwise."""
    if not compiled._derived("constant jacobian", lambda: _constant_jacobian(ode, compiled)):
        return None
    u0 = np.array(ode.u0, dtype=float)  # (writeable: the type f's evaluations take)
    lam, V = np.linalg.eig(_evaluators(compiled)[1](np.array([float(ode.t0)]), u0[None, :])[0])
    return None if np.linalg.cond(V) >= MODAL_CONDITION else (lam, V)


def modal_estimate(sol, compiled, weight=None, peak=None):
    """(e, 0.0, 0.0) as :func:`estimate` (linear: no remainder), mode by mode
    (:func:`_modal`), for a solution on shared
    slabs of a linear system with a constant J whose eigenbasis has a condition number below
    MODAL_CONDITION; None for any other. Each mode is carried by its exact flow
    exp(k lambda), also where a step spans many periods of a weakly damped oscillation (a
    stiff spring stepped over), where the slab estimate's series gives up. ``peak`` (in
    place, as :attr:`Running.peak`; none given: not kept) keeps the largest error at a slab
    end (``weight``: atol / rtol per component, default 1)."""
    modes = _constant_modes(sol.ode, compiled)
    if modes is None:
        return None
    c, a = _collocation(sol.method.q + 2)
    ends = None if peak is None else np.ones((len(sol.k), compiled.N), dtype=np.bool_)
    weight = np.ones(compiled.N) if weight is None else np.asarray(weight, dtype=float)
    return (_modal(sol, compiled, *modes, c, *_feature_shifts(sol, compiled, c, a),
                   own_ends=ends, weight=weight, peak=peak), 0.0, 0.0)


def measured_warning(size, linearised, nu, rtol, state, factor):
    """The ToleranceWarning's message for an error at T ``size`` (as :func:`scaled`)
    measured against a solve at ``factor`` x the tolerance ``rtol`` where the linearised
    estimate (``linearised``) did not hold (nonlinearity ``nu``); None within WARN_FACTOR x
    the tolerance."""
    if size <= WARN_FACTOR * rtol:
        return None
    return (f"the error at T is {size / rtol:.3g} x the tolerance (largest in {state}; "
            f"sol.stats['global error estimate'] = {size:.3g}), measured against a solve at "
            f"{factor:g} x the tolerance (the linearised estimate, {linearised / rtol:.3g} x, "
            f"does not hold along this run: sol.stats['global error nonlinearity'] = "
            f"{nu:.3g}). Try a tighter tolerance, or dn.estimate_error with a goal")


#: Why a run's error at T is measured against a reference solve (:func:`reference_warning`),
#: and what to try where it is large.
STIFF_SLABS = (("the run is stiff on its slabs (steps long against the period or decay time "
                "of some of its modes), where the slab estimate cannot follow the error"),
               ("a step spanning many periods of a weakly damped oscillation leaves its error "
                "undamped. Try a tighter tolerance, a maximum_time_step below that period, or "
                "dn.estimate_error with a goal"))
SECOND_ORDER = (("the error grew along the run to where f's nonlinearity moves the linearised "
                 "estimate across 10 x the tolerance (sol.stats['global error second order']: "
                 "a phase error of a nonlinear oscillation over many periods)"),
                "Try a tighter tolerance, a higher order, or dn.estimate_error with a goal")
NONLINEAR = (("the error equation is far from linear along this run (sol.stats['global error "
              "nonlinearity'] > NONLINEAR_LIMIT), so that the linearised estimate neither "
              "confirms nor excludes an error above the tolerance"),
             "Try a tighter tolerance, or dn.estimate_error with a goal")
NOT_SMOOTH = (("f jumps, switches or an event ends the run, where the linearised estimate, "
               "made for one smooth f, does not apply"),
              "Try a tighter tolerance or a higher order")


def measured_midrun_warning(peak, time, size, rtol, state, factor, reason, shift=np.inf):
    """The ToleranceWarning's message for an error mid-run ``peak`` (as :func:`scaled`, of
    ``state`` at ``time``) measured against a solve at ``factor`` x the tolerance ``rtol``
    for ``reason`` (as :func:`reference_warning`'s), where the error at T, ``size``, is
    within WARN_FACTOR x the tolerance; None where ``peak`` is within it too. ``shift`` as
    :func:`midrun_warning`'s."""
    if peak <= WARN_FACTOR * rtol:
        return None
    why, advice = reason
    return (f"the measured error mid-run is {peak / rtol:.3g} x the tolerance at t = "
            f"{time:.6g} (in {state}; sol.stats['global error mid-run'] = {peak:.3g}), though "
            f"{size / rtol:.3g} x at T, against a solve at {factor:g} x the tolerance: {why}. "
            f"Values read before T may be that far off. {advice}.{_phase(state, shift)}")


def reference_warning(size, rtol, state, factor, reason):
    """The ToleranceWarning's message for a run whose error at T ``size`` (as :func:`scaled`)
    was measured against a solve at ``factor`` x the tolerance ``rtol`` for ``reason``
    (STIFF_SLABS, SECOND_ORDER or NOT_SMOOTH: why, what to try): None within WARN_FACTOR x the tolerance;
    ``size`` None: that solve failed, the error could not be estimated."""
    why, advice = reason
    if size is None:
        return (f"the error at T could not be estimated: {why}, and the solve at {factor:g} x "
                "the tolerance to measure it against failed. Compare with a solve at a "
                "tighter tolerance or with a maximum_time_step, or use dn.estimate_error "
                "with a goal")
    if size <= WARN_FACTOR * rtol:
        return None
    return (f"the error at T is {size / rtol:.3g} x the tolerance (largest in {state}; "
            f"sol.stats['global error estimate'] = {size:.3g}), measured against a solve at "
            f"{factor:g} x the tolerance: {why}; {advice}")


#: The slab estimate (:func:`slab_estimate`) takes the moments of each component's residual
#: over a sub-step up to the degree M <= 2q + SLAB_MOMENTS, the fewest whose first term left
#: out of the moment series, relative to the first, (h rho)^M / (M + 1)!, is below
#: SLAB_MOMENT_CUT (h rho as the sub-step, or the one before it, saw it), ...
SLAB_MOMENTS = 4
SLAB_MOMENT_CUT = 1e-3
#: ... over sub-steps of the slab short enough that the Taylor series of exp(h J) settles
#: (a term below SLAB_SETTLED x the sum) within SLAB_TERMS terms without growing past
#: SLAB_CANCELLATION x the vector it is applied to: then h rho(J) is below about 2, and the
#: moment series, cut at 2q + SLAB_MOMENTS, is accurate too.
SLAB_TERMS = 18
SLAB_SETTLED = 1e-10
SLAB_CANCELLATION = 1e8
#: A sub-step on which the series does not settle halves the sub-steps' length h, up to
#: SLAB_SUBSTEPS sub-steps per element of the slab (a shared slab, a mono-adaptive step or a
#: multi-adaptive slab solved as one: q + 1, the work of its q + 1 values per component; as
#: N elements a multi-adaptive one let the Brusselator's (N = 2000) mcG(2) at 1e-4 grind 4,000
#: sub-steps a slab, 65 x its solve, before giving up): beyond, the run is stiff on the slab
#: (the common refinement of :func:`estimate`, L-stable, then costs less) and it gives up.
SLAB_SUBSTEPS = 2


def slab_estimate(sol, compiled=None, weight=None, peak=None):
    """(e, nu, delta) as :func:`estimate` for a multi-adaptive solution (or a mono-adaptive one, as
    one whose every slab is shared), at a cost of the order of its elements (times the
    sub-steps below), not of its common refinement, without stage systems; None where a
    slab would need more than SLAB_SUBSTEPS sub-steps per element (a stiff run; a shared
    slab counts as q + 1 elements); a ValueError where its copy of the elements
    would take more than COMMON_MEMORY_FRACTION x the available memory (asked only for a
    copy larger than memory.SMALL_BYTES).

    A slab (t_n, t_{n+1}], between two times where every component's elements end, is cut
    into sub-steps I = (a, a + K] no longer than a length h carried from sub-step to sub-step
    (halved, and the sub-step redone, where the series below does not settle; doubled after
    one where it settled in at most SLAB_TERMS // 2 terms), on each of which the error
    equation e' = J e + R with J frozen at the sub-step's midpoint gives

        e(a + K) = exp(K J) e(a) + int_I exp(J (a + K - s)) R(s) ds
                 = exp(K J) w_0 + sum_{m >= 1} (K J)^m (mu_m - mu_0) / m!,

    mu_m = int_I ((a + K - s) / K)^m R(s) ds and w_0 = e(a) + mu_0: the residual enters
    through its moments, integrated on the parts in I of each component's own elements
    (mdG(q)'s jumps at their starts as point masses), split at the element ends of the
    components f_i reads, by Gauss quadrature exact for the degree of U_i' - f_i(U) times
    the weight where f is linear (on a shared slab, every component on the one element,
    by f at once). exp(K J) w_0 is summed by its Taylor series until a term is below
    SLAB_SETTLED x the sum, the moment terms up to m = M <= 2q + SLAB_MOMENTS (Horner; M
    by K rho(J), SLAB_MOMENT_CUT); both hold for K rho(J) below about 2, which the
    sub-steps keep. With one sub-step and one element
    per slab it is the series of the collocation of :func:`estimate`. nu as there and delta
    by the neutral sum of the module docstring (``weight``: atol / rtol per component,
    default 1), at the slabs' ends. A :class:`~dolfinode.solution.MixedSolution` keeps its parts.

    At every element end, ``peak`` (in place, as :attr:`Running.peak`: value, time,
    component; none given: not kept) keeps the largest |e_i| / (w_i + |U_i - e_i|) of the
    components whose element ends there (the error mid-run; every component at a shared
    slab's end). An end inside a sub-step gets e carried to it from the sub-step's start by
    the same series; the sub-steps do not end there (cut at every end, mdG(2)'s estimate of
    an undamped 50-mass chain at 1e-8 fell from 17.0 x, the error 17.2 x, to 8.1 x)."""
    compiled = lower(sol.ode) if compiled is None else compiled
    method = sol.method
    N = compiled.N
    (ptr, t_start, t_end, values), (s_start, s_end, s_values) = family_parts(sol)
    # the elements' monomial coefficients, and the sort of their ends
    size = 8 * len(t_end) * (method.q + 6)
    if size > SMALL_BYTES and size > COMMON_MEMORY_FRACTION * available_memory():
        raise ValueError(f"the slab estimate's copy of the {len(t_end)} elements takes "
                         f"{size / 2**30:.3g} GB, more than {COMMON_MEMORY_FRACTION:g} x the "
                         "memory available")
    ends, counts = np.unique(t_end, return_counts=True)
    declared = sol._declaration  # (t0, u0; a prepared solution's ode is made when read)
    sync = np.unique(np.concatenate([[declared.t0], ends[counts == N], s_start, s_end]))
    peak = np.zeros(3) if peak is None else peak
    to_monomial, gx, gw, points = _slab_rules(tuple(float(c) for c in method.nodes))
    coef = np.ascontiguousarray(values @ to_monomial)
    weight = np.ones(N) if weight is None else np.asarray(weight, dtype=float)
    second = np.zeros(N)
    e, nu, settled = _slab_recursion(
        compiled.rhs_component.address, compiled.rhs.address, compiled.jacobian.address,
        compiled.p, compiled.indptr, compiled.indices, np.asarray(ptr, dtype=np.int64),
        t_start, t_end, coef, np.asarray(s_start, dtype=float),
        np.ascontiguousarray(s_values, dtype=float), to_monomial, sync,
        np.asarray(declared.u0, dtype=float), weight, second, method.family == "cG", gx, gw,
        points, ends, np.concatenate(([0], np.cumsum(counts))),
        np.argsort(t_end, kind="stable"), np.repeat(np.arange(N), np.diff(ptr)), peak)
    return (e, nu, float(np.max(second))) if settled else None


@lru_cache(maxsize=32)
def _slab_rules(nodes):
    """(to_monomial, gx, gw, points) of :func:`slab_estimate` for a method's ``nodes`` (made
    once; shared, never written): the matrix from the values at the nodes to the monomial
    coefficients in tau = (t - a) / k, and for the moments M = 0..2q + SLAB_MOMENTS the
    n_M = (q + M + 2) // 2 point Gauss rules on [0, 1] (rows of gx, gw), exact to the degree
    2 n_M - 1 >= q + M."""
    nodes = np.asarray(nodes)
    q = len(nodes) - 1
    to_monomial = np.ascontiguousarray(
        np.linalg.inv(nodes[:, None] ** np.arange(len(nodes))[None, :]).T)
    points = (q + np.arange(2 * q + SLAB_MOMENTS + 1) + 2) // 2
    gx, gw = np.zeros((points.size, points[-1])), np.zeros((points.size, points[-1]))
    for M, n in enumerate(points):
        x, w = np.polynomial.legendre.leggauss(n)
        gx[M, :n], gw[M, :n] = (x + 1) / 2, w / 2
    return to_monomial, gx, gw, points


@njit(cache=True)
def _value(coef, el, tau):
    """U(tau) of the element ``el`` (monomial coefficients in tau)."""
    v = 0.0
    for r in range(coef.shape[1] - 1, -1, -1):
        v = v * tau + coef[el, r]
    return v


@njit(cache=True)
def _add_residual(mu, i, coef, row, tau, k, f_i, weight, length, wt):
    """mu[m, i] += (U_i' - f_i) weight length wt^m at tau of an element of length k whose
    monomial coefficients in tau are coef[row] (a quadrature point of a moment sum)."""
    du = 0.0
    for r in range(coef.shape[1] - 1, 0, -1):
        du = du * tau + r * coef[row, r]
    value = (du / k - f_i) * weight * length
    for m in range(mu.shape[0]):
        mu[m, i] += value
        value *= wt


@njit(cache=True)
def _element_at(t_end, lo, hi, t):
    """The first element in lo..hi - 1 (time-sorted) ending at or after t (hi - 1 if none)."""
    hi -= 1
    while lo < hi:
        mid = (lo + hi) // 2
        if t_end[mid] < t:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _state(first, last, t_start, t_end, coef, t, x):
    """x_j = U_j(t) for every component j, from its elements first[j]..last[j] - 1."""
    for j in range(x.size):
        el = _element_at(t_end, first[j], last[j], t)
        x[j] = _value(coef, el, (t - t_start[el]) / (t_end[el] - t_start[el]))


@njit(cache=True)
def _times_jacobian(indptr, indices, data, scale, v, out):
    """out = scale J v (J's values ``data`` in CSR order)."""
    for r in range(v.size):
        acc = 0.0
        for m in range(indptr[r], indptr[r + 1]):
            acc += data[m] * v[indices[m]]
        out[r] = scale * acc


@njit(cache=True)
def _slab_moments(fi, p, indptr, indices, first, last, t_start, t_end, coef, before,
                  continuous, gx, gw, sa, sb, mu, x, out, cursor):
    """mu[m, i] = int_{sa}^{sb} ((sb - s) / h)^m R_i(s) ds over the sub-step (sa, sb] of a
    slab (see :func:`slab_estimate`), each component on the parts inside it of its elements
    first[i]..last[i] - 1 (U_i(t_n-) = before[i]), each part split where an element of a
    component f_i reads ends (``cursor``: room for J's nonzeros)."""
    h = sb - sa
    mu[:] = 0.0
    for i in range(x.size):
        el = _element_at(t_end, first[i], last[i], sa)
        if t_end[el] <= sa:
            el += 1
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            cursor[nz] = _element_at(t_end, first[j], last[j], sa)
        while el < last[i] and t_start[el] < sb:
            a, b = t_start[el], t_end[el]
            k = b - a
            if not continuous and a >= sa:  # the jump U_i(a+) - U_i(a-), a point mass at a
                jump = coef[el, 0] - (before[i] if el == first[i] else _value(coef, el - 1, 1.0))
                wt = (sb - a) / h
                for m in range(mu.shape[0]):
                    mu[m, i] += jump
                    jump *= wt
            lo, hi = max(a, sa), min(b, sb)
            s0 = lo
            while s0 < hi:
                # the neighbours' elements on (s0, s1]: the first of each ending after s0
                s1 = hi
                for nz in range(indptr[i], indptr[i + 1]):
                    j = indices[nz]
                    c = cursor[nz]
                    while c < last[j] - 1 and t_end[c] <= s0:
                        c += 1
                    cursor[nz] = c
                    if j != i and t_end[c] < s1:
                        s1 = t_end[c]
                for g in range(gx.size):
                    t = s0 + gx[g] * (s1 - s0)
                    for nz in range(indptr[i], indptr[i + 1]):
                        c = cursor[nz]
                        x[indices[nz]] = _value(coef, c, (t - t_start[c]) / (t_end[c] - t_start[c]))
                    tau = (t - a) / k
                    x[i] = _value(coef, el, tau)
                    fi(i, address(x, 0), t, address(p, 0), address(out, 0))
                    _add_residual(mu, i, coef, el, tau, k, out[0], gw[g], s1 - s0,
                                  (sb - t) / h)
                s0 = s1
            el += 1


@njit(cache=True)
def _end_errors(ending, owner, coef, e, weight, t, peak):
    """peak (value, time, component) = the largest |e_i| / (w_i + |U_i(t) - e_i|) so far,
    over the components i = owner[el] of the elements ``ending`` at t."""
    for el in ending:
        i = owner[el]
        _keep_peak(peak, e[i], weight[i], _value(coef, el, 1.0), t, i)


@njit(cache=True, inline="always")
def _keep_peak(peak, e, w, U, t, i):
    """peak (value, time, component) = (|e| / (w + |U - e|), t, i) where that exceeds it:
    the error e of component i at an element end at t, scaled as :func:`scaled` (u ~ U - e)."""
    ratio = abs(e) / (w + abs(U - e))
    if ratio > peak[0]:
        peak[0], peak[1], peak[2] = ratio, t, i


@njit(cache=True)
def _shared_state(sc, tau, x):
    """x_i = U_i at tau on a shared slab (monomial coefficients sc[i] in tau)."""
    for i in range(x.size):
        v = 0.0
        for r in range(sc.shape[1] - 1, -1, -1):
            v = v * tau + sc[i, r]
        x[i] = v


@njit(cache=True)
def _shared_moments(f, p, sc, before, continuous, gx, gw, ta, tb, sa, sb, mu, x, fx):
    """mu as :func:`_slab_moments` on a shared slab (ta, tb]: every component on one element,
    monomial coefficients sc[i] in tau = (t - ta) / (tb - ta), its residual by f at once."""
    K, h = tb - ta, sb - sa
    mu[:] = 0.0
    if not continuous and sa == ta:  # the jumps at ta, weight 1
        for i in range(x.size):
            for m in range(mu.shape[0]):
                mu[m, i] += sc[i, 0] - before[i]
    for g in range(gx.size):
        t = sa + gx[g] * h
        tau = (t - ta) / K
        _shared_state(sc, tau, x)
        f(address(x, 0), t, address(p, 0), address(fx, 0))
        wt = (sb - t) / h
        for i in range(x.size):
            _add_residual(mu, i, sc, i, tau, K, fx[i], gw[g], h, wt)


@njit(cache=True)
def _piece_moments(f, p, current, first, t_start, t_end, coef, before, continuous, gx, gw,
                   sa, sb, mu, x, fx):
    """mu as :func:`_slab_moments` on a piece (sa, sb] of a slab inside which no element
    ends, each component i on its element current[i]: the residual of all by f at once
    (no split at the neighbours' ends, none inside)."""
    h = sb - sa
    mu[:] = 0.0
    for i in range(x.size):
        el = current[i]
        if not continuous and t_start[el] >= sa:  # the jump at sa, weight 1
            jump = coef[el, 0] - (before[i] if el == first[i] else _value(coef, el - 1, 1.0))
            for m in range(mu.shape[0]):
                mu[m, i] += jump
    for g in range(gx.size):
        t = sa + gx[g] * h
        for i in range(x.size):
            el = current[i]
            x[i] = _value(coef, el, (t - t_start[el]) / (t_end[el] - t_start[el]))
        f(address(x, 0), t, address(p, 0), address(fx, 0))
        wt = (sb - t) / h
        for i in range(x.size):
            el = current[i]
            k = t_end[el] - t_start[el]
            _add_residual(mu, i, coef, el, (t - t_start[el]) / k, k, fx[i], gw[g], h, wt)


@njit(cache=True)
def _propagate(indptr, indices, data, h, mu, e, nxt, term, total, v, jv):
    """nxt = exp(h J) (e + mu_0) + sum_{m >= 1} (h J)^m (mu_m - mu_0) / m! (see
    :func:`slab_estimate`; J's values ``data``); returns (the number of terms in which the
    Taylor series of exp(h J) settled, or -1 where it does not settle in SLAB_TERMS terms;
    h rho(J) as the series saw it, (m! |t_m| / |t_0|)^(1 / m) at its last term t_m)."""
    N = e.size
    seen = 0.0
    size = 0.0
    for r in range(N):
        term[r] = e[r] + mu[0, r]
        total[r] = term[r]
        size = max(size, abs(term[r]))
    settled = size == 0.0
    terms = 0
    factorial = 1.0
    for m in range(1, SLAB_TERMS + 1):
        if settled:
            break
        terms = m
        _times_jacobian(indptr, indices, data, h / m, term, jv)
        big = biggest = 0.0
        for r in range(N):
            term[r] = jv[r]
            total[r] += jv[r]
            big = max(big, abs(jv[r]))
            biggest = max(biggest, abs(total[r]))
        factorial *= m
        seen = (factorial * big / size) ** (1.0 / m)
        if big > SLAB_CANCELLATION * size:
            break
        settled = big <= SLAB_SETTLED * biggest
    if not settled:
        return -1, seen
    for r in range(N):  # the moment terms by Horner
        v[r] = 0.0
    for m in range(mu.shape[0] - 1, 0, -1):
        for r in range(N):
            v[r] += mu[m, r] - mu[0, r]
        _times_jacobian(indptr, indices, data, h / m, v, jv)
        for r in range(N):
            v[r] = jv[r]
    for r in range(N):
        nxt[r] = total[r] + v[r]
    return terms, seen


@njit(cache=True)
def _moments_for(x, top):
    """The fewest moments M (1..top) for h rho(J) = x: (x^M / (M + 1)! <= SLAB_MOMENT_CUT)."""
    M, left_out = 1, x / 2
    while left_out > SLAB_MOMENT_CUT and M < top:
        M += 1
        left_out *= x / (M + 1)
    return M


@njit(cache=True)
def _slab_recursion(fi_address, rhs, jacobian, p, indptr, indices, ptr, t_start, t_end,
                    coef, s_start, s_values, to_monomial, sync, u0, weight, second,
                    continuous, gx, gw, points, cuts, cut_ptr, ending, owner, peak):
    """(e at T, nu, settled) of :func:`slab_estimate` (delta's sums added to ``second``), slab after slab between the times
    ``sync`` (a slab starting at s_start[n] is the shared slab n, nodal values s_values[n],
    the others are each component's elements ptr[i]:ptr[i + 1]; a shared slab counts as
    q + 1 elements, its values per component), each in sub-steps no longer
    than a length h: halved (and the sub-step redone) where exp(h J)'s series does not
    settle, doubled after a sub-step where it settled in at most SLAB_TERMS // 2 terms;
    settled False: a slab that would need more than SLAB_SUBSTEPS sub-steps per element of
    the slab. ``peak`` (in place) keeps the largest scaled error of the components ending
    at the element ends ``cuts`` (increasing; :func:`slab_estimate`; the elements
    ending[cut_ptr[c]:cut_ptr[c + 1]] end at cuts[c], of the components ``owner``), those
    inside a sub-step carried to them from its start (not into the sub-steps), and of every
    component at a shared slab's end."""
    fi, f, jac = component_kernel(fi_address), rhs_kernel(rhs), rhs_kernel(jacobian)
    N, nnz = u0.size, indices.size
    first, last = ptr[:-1].copy(), ptr[:-1].copy()
    top = points.size - 1
    mu = np.empty((top + 1, N))
    e, nxt, branch, x, out = np.zeros(N), np.empty(N), np.empty(N), np.empty(N), np.empty(1)
    data = np.empty(max(nnz, 1))
    term, total, v, jv = np.empty(N), np.empty(N), np.empty(N), np.empty(N)
    fU, fS, before = np.empty(N), np.empty(N), u0.copy()
    sc = np.empty((N, to_monomial.shape[1]))
    cursor = np.empty(max(nnz, 1), dtype=np.int64)
    current = np.empty(N, dtype=np.int64)  # each component's element on the branch's piece
    fx = np.empty(N)
    nu = 0.0
    h = rho = np.inf  # rho: rho(J) as the last sub-step saw it
    shared_next = 0
    cut = 0  # the first of ``cuts`` after the sub-step's start
    for n in range(sync.size - 1):
        ta, tb = sync[n], sync[n + 1]
        shared = shared_next < s_start.size and s_start[shared_next] == ta
        if shared:
            for i in range(N):
                for r in range(sc.shape[1]):
                    acc = 0.0
                    for node in range(s_values.shape[1]):
                        acc += s_values[shared_next, node, i] * to_monomial[node, r]
                    sc[i, r] = acc
            shared_next += 1
            elements = sc.shape[1]
        else:
            for j in range(N):
                first[j] = last[j]
                while last[j] < ptr[j + 1] and t_end[last[j]] <= tb:
                    last[j] += 1
            elements = np.sum(last - first)
        sa, done = ta, 0
        while sa < tb:
            # the rest of the slab in equal sub-steps no longer than h: take the first
            parts = 1 if h >= tb - sa else int(np.ceil((tb - sa) / h))
            if done + parts > SLAB_SUBSTEPS * elements:
                return e, nu, False
            sb = tb if parts == 1 else sa + (tb - sa) / parts
            tm = sa + 0.5 * (sb - sa)
            M = _moments_for(1.5 * rho * (sb - sa), top)  # a margin: few sub-steps redone
            n = points[M]
            if shared:
                _shared_moments(f, p, sc, before, continuous, gx[M, :n], gw[M, :n], ta, tb,
                                sa, sb, mu[:M + 1], x, fU)
                _shared_state(sc, (tm - ta) / (tb - ta), x)
            else:
                _slab_moments(fi, p, indptr, indices, first, last, t_start, t_end, coef,
                              before, continuous, gx[M, :n], gw[M, :n], sa, sb, mu[:M + 1], x,
                              out, cursor)
                _state(first, last, t_start, t_end, coef, tm, x)
            jac(address(x, 0), tm, address(p, 0), address(data, 0))
            terms, seen = _propagate(indptr, indices, data, sb - sa, mu[:M + 1], e, nxt, term,
                                     total, v, jv)
            if terms < 0:  # redo this sub-step halved
                h, rho = 0.5 * (sb - sa), np.inf
                continue
            rho = seen / (sb - sa)
            if _moments_for(seen, top) > M:  # redo it with the moments its h rho(J) needs
                continue
            while cut < cuts.size and cuts[cut] <= sa:
                cut += 1
            if not shared:
                # the element ends in (sa, sb], the inner ones on a branch from e(sa) that
                # the sub-steps do not take (more sub-steps move e at T on undamped runs)
                branch[:] = e
                at = sa
                for j in range(N):  # each component's element on the first piece
                    current[j] = _element_at(t_end, first[j], last[j], sa)
                    if t_end[current[j]] <= sa:
                        current[j] += 1
                while cut < cuts.size and cuts[cut] < sb:
                    # (the moments a piece's own length needs: short pieces take fewer)
                    Mp = _moments_for(1.5 * rho * (cuts[cut] - at), M)
                    n = points[Mp]
                    _piece_moments(f, p, current, first, t_start, t_end, coef, before,
                                   continuous, gx[Mp, :n], gw[Mp, :n], at, cuts[cut],
                                   mu[:Mp + 1], x, fx)
                    if _propagate(indptr, indices, data, cuts[cut] - at, mu[:Mp + 1], branch,
                                  branch, term, total, v, jv)[0] < 0:
                        break  # (shorter than the sub-step: its series settles as well)
                    at = cuts[cut]
                    _end_errors(ending[cut_ptr[cut]:cut_ptr[cut + 1]], owner, coef, branch,
                                weight, at, peak)
                    for j in range(N):
                        if t_end[current[j]] <= at:
                            current[j] += 1
                    cut += 1
                if cut < cuts.size and cuts[cut] == sb:
                    _end_errors(ending[cut_ptr[cut]:cut_ptr[cut + 1]], owner, coef, nxt,
                                weight, sb, peak)
            e[:] = nxt
            if terms <= SLAB_TERMS // 2 and h < np.inf:
                h = max(h, 2 * (sb - sa))
            sa = sb
            done += 1
        # nu: |f(U - e) - f(U) + J e| / |J e| at the slab's end, U(tb) the next slab's before
        if shared:
            _shared_state(sc, 1.0, x)
            for r in range(N):  # (every component ends here)
                _keep_peak(peak, e[r], weight[r], x[r], tb, r)
        else:
            _state(first, last, t_start, t_end, coef, tb, x)
        before[:] = x
        jac(address(x, 0), tb, address(p, 0), address(data, 0))
        f(address(x, 0), tb, address(p, 0), address(fU, 0))
        for r in range(N):
            term[r] = x[r] - e[r]
        f(address(term, 0), tb, address(p, 0), address(fS, 0))
        _times_jacobian(indptr, indices, data, 1.0, e, jv)
        size = remainder = 0.0
        for r in range(N):
            rest = abs(fS[r] - fU[r] + jv[r])
            size = max(size, abs(jv[r]))
            remainder = max(remainder, rest)
            second[r] += (tb - ta) * rest / (weight[r] + abs(term[r]))
        if size > 0:
            nu = max(nu, remainder / size)
    return e, nu, True


#: A solve with ``estimate_global_error=True`` warns when the estimate exceeds WARN_FACTOR
#: times the tolerance (the tolerance record's band is 0.1-10 x).
WARN_FACTOR = 10.0


def scaled(e, U, atol, rtol):
    """(max_i |e_i| / (atol_i / rtol + |U_i|), i at the maximum): the error ``e`` at T scaled
    as the tolerance means it (comparable with rtol)."""
    ratio = np.abs(e) / (atol / rtol + np.abs(U))
    i = int(np.argmax(ratio))
    return float(ratio[i]), i


def midrun_warning(peak, time, size, nu, rtol, state, shift=np.inf, multi=True):
    """The ToleranceWarning's message for an error mid-run, ``peak`` (as :func:`scaled`, at
    an element end of ``state`` at ``time``: :attr:`Running.peak`) above WARN_FACTOR x the
    tolerance ``rtol`` where the estimate at T, ``size``, is within it; None otherwise, and
    where the nonlinearity ``nu`` exceeds NONLINEAR_LIMIT (the estimate does not hold).

    The step control bounds each element's local error estimate; errors that the run damps
    or cancels before T do not reach the estimate at T: mdG(2) on a' = -1e4 (a - b^2), b, c a
    unit rotation, d' = a - d at 1e-8 left d 20 x off at its element ends inside a's long
    elements (a's Galerkin polynomial 139 x off there, right at a's own ends), 0.06 x at
    T; mcG(3) and mdG(2) on a front along a 200-stage linear chain at 1e-6 17 x and 20 x,
    0.05 x and 0.09 x at T. The recursion's e_n matched the error at every end (ratio
    0.999-1.000). ``shift``: the time over which ``state`` changes by that error at its
    rate there (a fast transition's phase, if one is that near). ``multi``: a
    multi-adaptive run's (False: a mono-adaptive one's, whose elements end together).

    A mono-adaptive run is off mid-run where the errors of its slabs add up over a stretch
    and the run damps them later (HIRES, cG(3) at 1e-9: 21.0 x estimated, 21.7 x measured,
    2.2 x at T), where a drifting phase meets a component's zero (the harmonic oscillator,
    cG(1): 11.6 x at a zero of v, 6.7 x at T), or at a fast transition's phase (Van der
    Pol at eps = 1e-6: 6e4-2e6 x measured at 1e-5..1e-10, the transition's time off by
    1e-12 to 2e-5)."""
    if peak <= WARN_FACTOR * rtol or size > WARN_FACTOR * rtol or nu > NONLINEAR_LIMIT:
        return None
    advice = (", or the mono-adaptive method (cG(q)/dG(q)) for a stiff component read by "
              "others or a front along a chain" if multi else "")
    return (f"the estimated error mid-run is {peak / rtol:.3g} x the tolerance at t = "
            f"{time:.6g} (in {state}, at its element end; sol.stats['global error mid-run'] = "
            f"{peak:.3g}), though {size / rtol:.3g} x at T: the run damps or cancels it before "
            "T, or the solution is larger there against it. Values read before T may be that "
            f"far off: try a tighter tolerance{advice}.{_phase(state, shift)}")


#: The interior estimate (:func:`interior_warning`) was 0.5-2.2 x the error measured inside
#: the elements on 12 mcG(q) runs above 10 x (HIRES, three stiff followers of a slow state;
#: one at 0.15 x: 20.5 x for 134 x, a follower of a follower); it warns above
#: INTERIOR_SPREAD x WARN_FACTOR, so that a warned interior is off by about WARN_FACTOR or
#: more: HIRES by mcG(2) at 1e-6 was estimated 13.1 x where it was 7.0 x.
INTERIOR_SPREAD = 2.0


def interior_warning(method, size, time, state):
    """The ToleranceWarning's message for a multi-adaptive run of ``method`` whose largest
    interior estimate (:func:`dolfinode.timeslab.multi.control.interior_indicators`, in
    units of the tolerance) was ``size``, inside an element of ``state`` at ``time``; None
    within INTERIOR_SPREAD x WARN_FACTOR, and for mdG(q).

    The step control holds that estimate to a third of the step tolerance at tight
    tolerances, many times the tolerance. mcG(q)'s value inside a component stiff on its
    step is its element's polynomial, whose error the estimate measures, to the residual's
    reading of the other components inside theirs: mcG(2) on u' = -800 (u - sin(v)^3),
    v' = 1 - v / 5 + u / 10 at 1e-6 26.1 x for 31.8 x measured (scaled by 1 + |u|); on
    HIRES (absolute_tolerance = tolerance) mcG(2) at 1e-7 23.8 x for 13.7 x, mcG(3) at 1e-8
    270 x for 160 x, all silent before. mdG(q)'s dense value corrects the element's polynomial (on that pair
    mdG(2)'s estimate was 132-227 x where sol(t) was 0.7-7 x off), so it is not warned of."""
    if method.family != "cG" or not size > INTERIOR_SPREAD * WARN_FACTOR:
        return None
    return (f"the estimated error mid-run is {size:.3g} x the tolerance inside the elements of "
            f"{state} near t = {time:.6g}, or of the components its rate reads there: it "
            "follows its quasi-steady state on steps long against its own time scale, and its "
            "value between the element ends is that state's interpolant. Values read inside "
            "elements may be that far off; the "
            "element ends (t + k of sol.time_steps()) are not. A tighter tolerance does not "
            "help (the interior is held to a share of the step tolerance); try "
            f"maximum_time_step near 1 / |df/d{state}|, or the mono-adaptive cG({method.q}), "
            "whose dense value takes the quasi-steady state")


def _phase(state, shift):
    """The mid-run warnings' sentence on a fast transition's phase: ``shift``, the time over
    which ``state`` changes by the error at its rate there ("" where not finite)."""
    if not np.isfinite(shift):
        return ""
    return (f" At {state}'s rate there, that is its change over {shift:.2g} of time: if a "
            "fast transition is that near, the error is its phase, the transition's time off "
            "by about that much.")


def warning(size, nu, rtol, state):
    """The ToleranceWarning's message for an estimate ``size`` (as :func:`scaled`) above
    WARN_FACTOR x the tolerance ``rtol``, largest in ``state``; None otherwise. Where the
    nonlinearity ``nu`` exceeds NONLINEAR_LIMIT the estimate cannot certify the error either
    way (it over-estimates across VDPOL's folds, and Lorenz's error at 1e-3 is of the size of
    the solution): the message says that it is not reliable, not that the error is large."""
    if size <= WARN_FACTOR * rtol:
        return None
    if not np.isfinite(size):  # a singular stage system (k mu lambda = 1 for a growing mode)
        return ("the error at T could not be estimated: the linearised error equation's "
                "stage system was singular on a step. Compare with a solve at a tighter "
                "tolerance, or use dn.estimate_error with a goal")
    if nu > NONLINEAR_LIMIT:
        return (f"the error at T could not be estimated: the linearised estimate is "
                f"{size / rtol:.3g} x the tolerance (largest in {state}), but the error "
                f"equation is far from linear along this run (sol.stats['global error "
                f"nonlinearity'] = {nu:.3g} > {NONLINEAR_LIMIT:g}), so it neither confirms nor "
                "excludes an error above the tolerance. Compare with a solve at a tighter "
                "tolerance, or use dn.estimate_error with a goal")
    return (f"the estimated error at T is {size / rtol:.3g} x the tolerance (largest in {state}; "
            f"sol.stats['global error estimate'] = {size:.3g}): the slabs' errors add up over "
            "this run (a long oscillatory or drifting solution); the tolerance bounds each "
            "slab's error, not their sum. Try a tighter tolerance, a higher order or dG(q), "
            "or dn.estimate_error with a goal for a bound on an output")
