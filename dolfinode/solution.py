"""The Galerkin solution: exact piecewise polynomials, dense evaluation and samples."""
import math
import weakref
from functools import cache, cached_property

import numpy as np
from numba import njit

from dolfinode.compile.jit import first_use, helper
from dolfinode.compile.lowering import lower
from dolfinode.compile.signatures import address, component_kernel, rhs_kernel
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.methods.method import (
    element_value,
    lagrange_matrices,
    lagrange_slopes,
    lagrange_weights,
    make_method,
)


@helper()
def _locate(ends, t, n):
    """The first element whose end ``ends[e]`` (increasing) is at or after t (the last
    element if none): np.searchsorted(ends, t) capped, searched from the guess ``n``, the
    answer for an earlier time. Sorted times walk forward, galloping (steps 1, 2, 4, ...)
    then bisecting, so m times over M elements cost O(m + M) at most and O(m log M) when
    they are sparse; an earlier time bisects [0, n)."""
    last = ends.shape[0] - 1
    if n > 0 and ends[n - 1] >= t:
        lo, hi = 0, n - 1
    else:
        lo = hi = n
        step = 1
        while hi < last and ends[hi] < t:
            lo = hi + 1
            hi = min(hi + step, last)
            step *= 2
    while lo < hi:
        mid = (lo + hi) // 2
        if ends[mid] >= t:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(cache=True, inline="always")
def _jump(values, e, before, left, theta):
    """before - U(t_{n-1}^+) = -[U], the jump at the start of element e (nodal values
    ``values[e, j]``, U(t_{n-1}^+) = sum_j left[j] values[e, j], U(t_{n-1}^-) = ``before``)
    where it is resolved, |[U]| <= theta max_j |values[e, j] - before| (any jump where
    theta is inf), else NaN."""
    plus = 0.0
    change = 0.0
    for j in range(values.shape[1]):
        plus += left[j] * values[e, j]
        change = max(change, abs(values[e, j] - before))
    # (not "<=": theta = inf takes every jump, a zero change too)
    return before - plus if not abs(plus - before) > theta * change else np.nan


@njit(cache=True, inline="always")
def _correction(values, e, before, dense):
    """The coefficient c of :func:`_dense_value` for element e of one component: -[U]
    (:func:`_jump`) where dense = (left, theta) is dG(q)'s rule (theta >= 0), ``before``
    (the component's value before the element) is known (not NaN) and the jump resolved,
    else 0 (the element polynomial)."""
    left, theta = dense
    c = _jump(values, e, before, left, theta) if theta >= 0.0 else np.nan
    return 0.0 if np.isnan(c) else c


@njit(cache=True, inline="always")  # (as element_value: a call per value, inlined)
def _dense_value(values, e, tau, nodes, bary, c):
    """The dense value at tau of element e (nodal values ``values[e, j]`` at the right Radau
    nodes tau_j) of one component: the collocation polynomial of :func:`_evaluate_dg`,

        P(tau) = U(tau) + c R(tau),  R(tau) = prod_j (tau_j - tau) / tau_j,

    with c = -[U] (:func:`_correction`; R(0) = 1, so P(0) is the value before the element,
    and R(tau_j) = 0), or U where c = 0. R(1) = 0 exactly: element ends are unchanged."""
    value = element_value(values, e, tau, nodes, bary)
    if c != 0.0:  # (the correction apart: in the same loop, U's evaluation cost 8 x)
        r = c
        for j in range(nodes.shape[0]):
            r *= (nodes[j] - tau) / nodes[j]
        value += r
    return value


@helper()
def _before_element(i, e, ptr, t_start, t_end, values, s_end, s_values, t0, u0):
    """U_i just before component i's element e (ptr[i] <= e < ptr[i+1]): the end value of
    what ends at its start (its previous element, a shared slab (s_end, s_values (S, q + 1,
    N)); u0[i] at t0), NaN if nothing does."""
    start = t_start[e]
    if e > ptr[i] and t_end[e - 1] == start:
        return values[e - 1, values.shape[1] - 1]
    if start == t0:
        return u0[i]
    if s_end.shape[0] > 0:
        n = _locate(s_end, start, 0)
        if s_end[n] == start:
            return s_values[n, s_values.shape[1] - 1, i]
    return np.nan


@helper()
def _before_slab(i, n, ptr, t_end, values, s_start, s_end, s_values, t0, u0):
    """U_i just before shared slab n: as :func:`_before_element`, the end value of the
    previous slab or of component i's element ending at its start (u0[i] at t0)."""
    start = s_start[n]
    if n > 0 and s_end[n - 1] == start:
        return s_values[n - 1, s_values.shape[1] - 1, i]
    if start == t0:
        return u0[i]
    ends = t_end[ptr[i]:ptr[i + 1]]
    if ends.shape[0] > 0:
        k = _locate(ends, start, 0)
        if ends[k] == start:
            return values[ptr[i] + k, values.shape[1] - 1]
    return np.nan


@helper()
def _evaluate_component(i, ptr, t_start, t_end, values, s_end, s_values, nodes, bary, dense,
                        t0, u0, times, done, out):
    """out[i, m] = U_i(times[m]) from component i's elements ptr[i]:ptr[i+1] (time-sorted;
    values (E, q + 1)), each from the first element ending at or after the time by
    :func:`_dense_value` (the value before an element from :func:`_before_element`, shared
    slabs (s_end, s_values) included); times with done[m] >= 0 are skipped (``done``
    empty: none)."""
    ends = t_end[ptr[i]:ptr[i + 1]]
    n = 0
    current = -1
    c = 0.0
    for m in range(times.shape[0]):
        if done.shape[0] > 0 and done[m] >= 0:
            continue
        if ends.shape[0] == 0:  # (a mixed history covers every other time by slabs)
            out[i, m] = np.nan
            continue
        n = _locate(ends, times[m], n)
        e = ptr[i] + n
        if e != current:
            current = e
            c = _correction(values, e, _before_element(i, e, ptr, t_start, t_end, values,
                                                       s_end, s_values, t0, u0), dense)
        tau = min(max((times[m] - t_start[e]) / (t_end[e] - t_start[e]), 0.0), 1.0)
        out[i, m] = _dense_value(values, e, tau, nodes, bary, c)


@njit(cache=True)
def _evaluate_components(ptr, t_start, t_end, values, nodes, bary, dense, t0, u0, times, out):
    """out[i, m] = U_i(times[m]) from component i's elements ptr[i]:ptr[i+1] (time-sorted;
    values (E, q + 1)), each from the first element ending at or after the time
    (:func:`_evaluate_component`)."""
    none = np.empty(0, dtype=np.int64)
    s_end = np.empty(0)
    s_values = np.empty((0, values.shape[1], ptr.shape[0] - 1))
    for i in range(ptr.shape[0] - 1):
        _evaluate_component(i, ptr, t_start, t_end, values, s_end, s_values, nodes, bary,
                            dense, t0, u0, times, none, out)


@njit(cache=True)
def _evaluate_shared(t_start, t_end, values, nodes, bary, times, out):
    """out[i, m] = U_i(times[m]) on a partition shared by all components (values
    (M, q + 1, N)), from the first element ending at or after the time; the basis is
    evaluated once per time for all components."""
    weights = np.empty(nodes.shape[0])
    n = 0
    for m in range(times.shape[0]):
        n = _locate(t_end, times[m], n)
        tau = min(max((times[m] - t_start[n]) / (t_end[n] - t_start[n]), 0.0), 1.0)
        lagrange_weights(tau, nodes, bary, weights)
        for i in range(out.shape[0]):
            out[i, m] = 0.0
        for j in range(nodes.shape[0]):  # (components innermost: contiguous in values)
            for i in range(out.shape[0]):
                out[i, m] += weights[j] * values[n, j, i]


@njit(cache=True, inline="always")
def _defect_small(c, defect, star, q_star, theta):
    """Whether |d(tau*)| tau* / 2 <= theta |c Q(tau*)|: a collocation polynomial's defect d,
    integrated from tau = 0 where it vanishes, is at most theta times its correction c Q
    (:func:`_passes_defect_test`; a NaN fails)."""
    return abs(defect) * (0.5 * star) <= theta * abs(c * q_star)


@njit(cache=True, inline="always")
def _passes_defect_test(c, defect, star, q_star, theta):
    """c where P = U + c Q passes :func:`_defect_small`'s test, else 0 (U)."""
    return c if _defect_small(c, defect, star, q_star, theta) else 0.0


@njit(cache=True, inline="always")
def _scaled_max(x, scale):
    """max_i |x_i| / scale_i (0 where x_i = 0; NaN, which fails every test, where x_i is
    or where scale_i = 0 and x_i is not): :func:`_evaluate_cg`'s tests over all
    components, each relative to its size on the element."""
    big = 0.0
    for i in range(x.shape[0]):
        r = 0.0
        if x[i] != 0.0:
            r = abs(x[i]) / scale[i] if scale[i] > 0.0 else np.nan
        if r > big or math.isnan(r):
            big = r
    return big


@njit(cache=True, inline="always")
def _defect_correction(rhs, p, t, k, X, F, g, Y, F2, star, pi_star, s_star, theta, scale):
    """V = P - g S, the collocation polynomial P (of :func:`_evaluate_cg` or
    :func:`_evaluate_dg`) corrected by its defect, one order higher inside the element.

    P's defect d = P' - k f(P, t) vanishes at the collocation nodes tau_j, d(tau) ~ g Pi(tau)
    with Pi(tau) = prod_j (tau - tau_j), and the error u - P ~ -int_0^tau d = -g S(tau),
    S(tau) = int_0^tau Pi (S(0) = S(1) = 0: the element ends are unchanged), so with
    g = d(tau*) / Pi(tau*) V's interior error is O(k^(q+3)) where the element resolves the
    component (cG(q): at most the nodes' O(k^(2q))), against P's O(k^(q+2)). Where
    k |lambda| >> 1 the error follows d / (k lambda), not -int d: V is used where its own
    residual passes :func:`_passes_defect_test`, k |f_i(V(tau*)) -
    f_i(P(tau*))| tau* / 2 <= theta |g S(tau*)| (V' = P' - g Pi, so V's defect at tau* is
    k (f(P) - f(V)) there; along the correction, k |lambda| tau* / 2 <= theta).

    On entry X = P(tau*) at time t, F = f(X), g[i] = d_i(tau*) (0 where P is not formed);
    on return g[i] = d_i(tau*) / Pi(tau*) where V passes, else 0. Y, F2: workspace
    (V(tau*), f there); f the kernel at address ``rhs``, parameters p. With a ``scale``
    (cG(q)) the test is one over all components (:func:`_scaled_max`), and g is returned
    whole; returns whether V passes."""
    f = rhs_kernel(rhs)
    for i in range(X.shape[0]):
        g[i] /= pi_star
        Y[i] = X[i] - g[i] * s_star
    f(address(Y, 0), t, address(p, 0), address(F2, 0))
    for i in range(X.shape[0]):
        F2[i] = k * (F[i] - F2[i])
    if scale.shape[0]:
        return _defect_small(_scaled_max(g, scale), _scaled_max(F2, scale), star, s_star,
                             theta)
    for i in range(X.shape[0]):
        g[i] = _passes_defect_test(g[i], F2[i], star, s_star, theta)
    return True


@njit(cache=True, inline="always")
def _correction_shape(G, tau):
    """S(tau) = int_0^tau Pi = tau (tau - 1) G(tau) (G's monomial coefficients, highest
    first; :func:`_defect_check`)."""
    s = 0.0
    for coefficient in G:
        s = s * tau + coefficient
    return s * tau * (tau - 1.0)


@njit(cache=True, inline="always")
def _cg_defects(values, n, slopes, c, dq_star, k, F, d):
    """d[i] = P_i'(tau*) - k F[i], the defect of :func:`_evaluate_cg`'s P = U + c Q on element
    n at tau* (F = f there; ``slopes`` l_j'(tau*), dq_star Q'(tau*); c = 0: U's defect)."""
    for i in range(d.shape[0]):
        d[i] = c[i] * dq_star - k * F[i]
        for j in range(slopes.shape[0]):
            d[i] += slopes[j] * values[n, j, i]


@njit(cache=True, inline="always")
def _element_value(values, n, basis, out):
    """out[i] = sum_j basis[j] values[n, j, i]: element n's polynomial where its nodal basis
    takes the values ``basis``."""
    for i in range(out.shape[0]):
        out[i] = 0.0
        for j in range(basis.shape[0]):
            out[i] += basis[j] * values[n, j, i]


#: How far inside its element, relative to |t| + k, a cG(q) dense value reads f at an end
#: node: 16 ulp, where a jump in t at the end (the solve ends its pieces there) is on the
#: element's side (f at the jump itself need not be; Heaviside(t - 1) made P 460-1000 x
#: the tolerance), and f is otherwise as at the node to rounding.
NODE_INSET = 16 * np.finfo(float).eps


@helper()
def _node_time(a, k, node):
    """a + node k, the time of a nodal value of the element [a, a + k], moved inside it by
    NODE_INSET (|a| + k) where f reads it at an end."""
    h = min(NODE_INSET * (abs(a) + k), 0.25 * k)
    return min(max(a + node * k, a + h), a + k - h)


#: Up to how many components :func:`_evaluate_cg` forms the quasi-steady value W (a dense
#: 2N x 2N factorization per element read where the collocation values fail); above, U.
QUASI_STEADY_LIMIT = 32


@njit(cache=True, inline="always")
def _quasi_steady(rhs, jacobian, indptr, indices, p, values, n, t_start, k, check, theta, c,
                  g, scale, Y, X, F, F2, J, ab, ipiv):
    """W = U + c Q - g S on element n, U's correction by collocating the equation,
    linearised at U(tau*), at tau* and tau** (:func:`_evaluate_cg`), all components together:

        (Q'(tau) I - Q(tau) k J) c - (Q(tau) I - S(tau) k J) g = -d_U(tau),  tau = tau*, tau**,

    d_U = U' - k f(U, t), J = df/du at U(tau*) (S' = Q). A component stiff on the element
    takes its quasi-steady state, W ~ U + (k J)^-1 d_U at both points, a resolved one
    P's and V's two shapes. Returns whether W's residual is at most theta times U's,
    |W' - k f(W)| <= theta |d_U| (over the components, :func:`_scaled_max` with ``scale``),
    at tau*, tau** (zero for linear f) and tau***, off both; c, g then hold W's
    coefficients.
    ``check`` as :func:`_evaluate_cg`'s; Y, X, F, F2: workspace of N (U, W, d_U, f), J of
    the Jacobian's CSR values (kernel at address ``jacobian``, pattern ``indptr``,
    ``indices``), ab (2N, 6N - 2) and ipiv the dense band storage of :func:`band_lu`."""
    points, bases, slopes, Qs, dQs, Ss = check[7:]
    N = c.shape[0]
    f = rhs_kernel(rhs)
    kv = 2 * (2 * N - 1)  # ab[j, kv + i - j] = A[i, j], kl = ku = 2N - 1
    ab[:] = 0.0
    for point in range(2):
        t = t_start + points[point] * k
        _element_value(values, n, bases[point], Y)
        if point == 0:
            rhs_kernel(jacobian)(address(Y, 0), t, address(p, 0), address(J, 0))
        f(address(Y, 0), t, address(p, 0), address(F2, 0))
        for i in range(N):
            r = point * N + i
            X[i] = 0.0
            ab[i, kv + r - i] = dQs[point]
            ab[N + i, kv + r - N - i] = -Qs[point]
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                ab[j, kv + r - j] -= Qs[point] * k * J[nz]
                ab[N + j, kv + r - N - j] += Ss[point] * k * J[nz]
        _cg_defects(values, n, slopes[point], X, 0.0, k, F2, F)
        for i in range(N):
            (c if point == 0 else g)[i] = -F[i]
    Z = np.empty(2 * N)  # (the right-hand side: c, then g)
    for i in range(N):
        Z[i] = c[i]
        Z[N + i] = g[i]
    if band_lu(ab, 2 * N - 1, 2 * N - 1, ipiv) != 0:
        return False
    band_solve(ab, 2 * N - 1, 2 * N - 1, ipiv, Z)
    for i in range(N):
        c[i] = Z[i]
        g[i] = Z[N + i]
    every = True
    zero = np.zeros(N)
    for point in range(3):
        t = t_start + points[point] * k
        _element_value(values, n, bases[point], Y)
        for i in range(N):
            X[i] = Y[i] + c[i] * Qs[point] - g[i] * Ss[point]
        f(address(Y, 0), t, address(p, 0), address(F2, 0))
        _cg_defects(values, n, slopes[point], zero, 0.0, k, F2, F)
        f(address(X, 0), t, address(p, 0), address(F2, 0))
        _cg_defects(values, n, slopes[point], c, dQs[point], k, F2, Y)
        for i in range(N):
            Y[i] -= g[i] * Qs[point]
        every &= _scaled_max(Y, scale) <= theta * _scaled_max(F, scale)
    return every


@njit(cache=True, error_model="numpy")  # (no zero check on every division)
def _evaluate_cg(t_start, t_end, values, nodes, bary, rhs, jacobian, indptr, indices, p,
                 check, theta, times, out):
    """out[i, m] = the dense value of a mono-adaptive cG(q) solution at times[m].

    On element n, with nodal values U_j at the Lobatto nodes tau_j (tau_0 = 0, tau_q = 1)
    and f_j = f(U_j, t_{n-1} + tau_j k), the collocation polynomial P of degree q + 1 with
    P(0) = U(0) and P'(tau_j) = k f_j (Lobatto IIIA's) is

        P(tau) = U(tau) + c Q(tau),  Q(tau) = prod_j (tau - tau_j),
        c = k / (q + 1) sum_j w_j f_j

    (w_j the barycentric weights: sum_j w_j f_j is the leading coefficient of the
    interpolant of the f_j; the cG(q) equations make P' - U' orthogonal to the polynomials
    of degree q - 1, so it is c Q'), and with its defect d = P' - k f(P, t) at
    tau* = tau_1 / 2 (off the nodes) the corrected value (:func:`_defect_correction`)

        V(tau) = P(tau) - g S(tau),  g = d(tau*) / Q(tau*),  S(tau) = int_0^tau Q

    (S(1) = 0: Lobatto quadrature is exact for Q, q >= 2). U's interior error is
    O(k^(q+1)), P's O(k^(q+2)), V's O(k^(q+3)) up to the nodes' O(k^(2q)) where the element
    resolves the component. Where k |lambda| >> 1 the nodal errors enter k f_j multiplied
    by it and P swings: V is used where its residual test passes, else P where its defect,
    integrated from tau = 0 where it vanishes (about P's error at tau*), is at most theta
    times the correction there (about U's error), |d(tau*)| tau* / 2 <= theta |c Q(tau*)|
    (:func:`_defect_small`; a stiff component: d(tau*) ~ k lambda c Q(tau*)). Each test
    is one over the components, each relative to its largest nodal value on the element
    (:func:`_scaled_max`): per component, one whose correction passes near zero (the
    oscillator's where its third derivative does) failed alone and dropped the element.

    Else (a component stiff on the element, near its quasi-steady state, where U's error
    follows U's defect d_U = U' - k f(U), u - U ~ d_U / (k lambda)) the value
    W = U + c Q - g S, c and g by collocating the linearised equation at two points
    (:func:`_quasi_steady`: one Jacobian, a dense solve, six more f; up to
    QUASI_STEADY_LIMIT components), where its residual at three is at most theta times
    U's, else U.

    One kind per element for every component: P, V and W differ from U by corrections
    linear in f's values (W's through its system's inverse; w^T J = 0 where w^T f = 0), so
    every linear invariant w^T u that the nodes keep holds at every t inside the element
    (a kind chosen per component broke HIRES's y7 + y8: 1.15e-5 against the tolerance's
    1e-5, and ROBER's y1 + y2 + y3: 1.6e-6).

    ``check`` = (tau*, l_j(tau*), l_j'(tau*), Q(tau*), Q'(tau*), S(tau*), G, and the
    points of :func:`_quasi_steady`) (:func:`_defect_check`), l_j U's Lagrange basis;
    ``jacobian`` the Jacobian kernel's
    address (its CSR pattern ``indptr``, ``indices``). Q and S are 0 at the ends: the
    element ends are unchanged bit for bit. f (the kernel at address ``rhs``, parameters
    p) is evaluated at the q + 1 nodes and twice at tau* once per element, when a time
    first falls inside it.
    """
    q1, N = nodes.shape[0], out.shape[0]
    star, basis, slopes, q_star, dq_star, s_star, g_coefficients = check[:7]
    weights = np.empty(q1)
    U = np.empty((q1 + 1, N))  # (contiguous rows for the kernel; the last P(tau*))
    F = np.empty((q1 + 1, N))
    c = np.zeros(N)
    g = np.zeros(N)
    Y = np.empty(N)
    X = np.empty(N)
    F2 = np.empty(N)
    F3 = np.empty(N)
    scale = np.empty(N)
    J = np.empty(max(indices.shape[0], 1))
    dense = N <= QUASI_STEADY_LIMIT
    ab = np.empty((2 * N if dense else 0, 6 * N - 2 if dense else 0))
    ipiv = np.empty(2 * N if dense else 0, dtype=np.int64)
    f = rhs_kernel(rhs)
    current = -1
    ready = False
    n = 0
    for m in range(times.shape[0]):
        n = _locate(t_end, times[m], n)
        if n != current:
            current = n
            ready = False
        k = t_end[n] - t_start[n]
        tau = min(max((times[m] - t_start[n]) / k, 0.0), 1.0)
        lagrange_weights(tau, nodes, bary, weights)
        for i in range(N):
            out[i, m] = 0.0
        for j in range(q1):
            for i in range(N):
                out[i, m] += weights[j] * values[n, j, i]
        if not 0.0 < tau < 1.0:
            continue
        if not ready:
            ready = True
            for j in range(q1):
                for i in range(N):
                    U[j, i] = values[n, j, i]
                f(address(U, j * N), _node_time(t_start[n], k, nodes[j]), address(p, 0),
                  address(F, j * N))
            for i in range(N):
                lead = 0.0
                U[q1, i] = 0.0
                for j in range(q1):
                    lead += bary[j] * F[j, i]
                    U[q1, i] += basis[j] * values[n, j, i]
                c[i] = k * lead / q1
                U[q1, i] += c[i] * q_star
            t_star = t_start[n] + star * k
            f(address(U, q1 * N), t_star, address(p, 0), address(F, q1 * N))
            _cg_defects(values, n, slopes, c, dq_star, k, F[q1], g)
            for i in range(N):
                scale[i] = 0.0
                for j in range(q1):
                    scale[i] = max(scale[i], abs(values[n, j, i]))
            collocated = _defect_small(_scaled_max(c, scale), _scaled_max(g, scale), star,
                                       q_star, theta)
            if not _defect_correction(rhs, p, t_star, k, U[q1], F[q1], g, Y, F2, star,
                                      q_star, s_star, theta, scale):
                g[:] = 0.0
                if not collocated and not (dense and _quasi_steady(
                        rhs, jacobian, indptr, indices, p, values, n, t_start[n], k,
                        check, theta, c, g, scale, Y, X, F2, F3, J, ab, ipiv)):
                    c[:] = 0.0
        r = 1.0
        for j in range(q1):
            r *= tau - nodes[j]
        s_tau = _correction_shape(g_coefficients, tau)
        for i in range(N):
            out[i, m] += c[i] * r - g[i] * s_tau


@njit(cache=True)
def _evaluate_mixed(ptr, t_start, t_end, values, s_start, s_end, s_values, nodes, bary, dense,
                    t0, u0, times, out):
    """out[i, m] = U_i(times[m]) from a mixed history: shared slabs (s_start, s_end,
    s_values (S, q + 1, N), time-sorted) where a time lies in one, (s_start, s_end] (or t0
    at a first slab starting there), else component i's own elements (as
    :func:`_evaluate_components`). A slab's value is each component's :func:`_dense_value`
    (the value before it from :func:`_before_slab`): the same bits as the slab's elements give
    (a history on disk and the samples of dense_output=False read those)."""
    slab = np.full(times.shape[0], -1, dtype=np.int64)
    corrections = np.empty(out.shape[0])
    current = -1
    n = 0
    for m in range(times.shape[0]):
        t = times[m]
        n = _locate(s_end, t, n)
        if not (t <= s_end[n] and (s_start[n] < t or (t == s_start[n] and t == t0))):
            continue
        slab[m] = n
        by_component = s_values[n].T
        if n != current:
            current = n
            for i in range(out.shape[0]):
                corrections[i] = _correction(by_component, i, _before_slab(
                    i, n, ptr, t_end, values, s_start, s_end, s_values, t0, u0), dense)
        tau = min(max((t - s_start[n]) / (s_end[n] - s_start[n]), 0.0), 1.0)
        for i in range(out.shape[0]):
            out[i, m] = _dense_value(by_component, i, tau, nodes, bary, corrections[i])
    for i in range(ptr.shape[0] - 1):
        _evaluate_component(i, ptr, t_start, t_end, values, s_end, s_values, nodes, bary,
                            dense, t0, u0, times, slab, out)


@helper()
def _row(cached, slot):
    """What :func:`_correct_multi` keeps of an element read, by its slot (the element at
    ``where`` of :func:`_element_at`, slab n's at E + n N + d): c, g, V's residual, the
    shared kind, NaN where not yet formed. ``cached`` = (rows, index, slots, count), a
    sparse set over uninitialised arrays (a scalar call reads a few elements: filling an
    array of every element cost it 30-80 us on 26536 elements): slot's row is formed where
    slots[index[slot]] == slot among the first count[0]."""
    rows, index, slots, count = cached
    n = index[slot]
    if not (0 <= n < count[0] and slots[n] == slot):
        n = count[0]
        count[0] += 1
        index[slot], slots[n] = n, slot
        rows[slot, :] = np.nan
    return rows[slot]


@helper()
def _element_at(d, t, history):
    """The element component d is read from at t: the first of the shared slabs and of its
    own elements ending at or after t, as the joined history (:class:`MixedSolution`) reads
    it (``history`` = (ptr, t_start, t_end, values, s_start, s_end, s_values) as
    :func:`_correct_multi` takes it); its own element e as e, slab n as E + n
    (E = t_end.shape[0])."""
    ptr, _, t_end, _, _, s_end, _ = history
    slab, e = -1, -1
    if s_end.shape[0] > 0:
        slab = _locate(s_end, t, 0)
    if ptr[d + 1] > ptr[d]:
        e = ptr[d] + _locate(t_end[ptr[d]:ptr[d + 1]], t, 0)
    use_slab = slab >= 0
    if slab >= 0 and e >= 0:
        slab_after, own_after = s_end[slab] >= t, t_end[e] >= t
        if slab_after and own_after:
            use_slab = s_end[slab] < t_end[e]
        elif slab_after or own_after:
            use_slab = slab_after
        else:  # (past both: the last)
            use_slab = s_end[slab] > t_end[e]
    return t_end.shape[0] + slab if use_slab else e


@helper()
def _nodal_value(d, where, j, history):
    """Component d's nodal value j on its element ``where`` (:func:`_element_at`)."""
    _, _, t_end, values, _, _, s_values = history
    E = t_end.shape[0]
    return s_values[where - E, j, d] if where >= E else values[where, j]


@helper()
def _element_polynomial(d, where, t, history, nodes, bary):
    """(U_d(t), a, b) on component d's element ``where`` (:func:`_element_at`) [a, b]."""
    _, t_start, t_end, values, s_start, s_end, s_values = history
    E = t_end.shape[0]
    if where >= E:
        a, b = s_start[where - E], s_end[where - E]
        tau = min(max((t - a) / (b - a), 0.0), 1.0)
        return element_value(s_values[where - E].T, d, tau, nodes, bary), a, b
    a, b = t_start[where], t_end[where]
    tau = min(max((t - a) / (b - a), 0.0), 1.0)
    return element_value(values, where, tau, nodes, bary), a, b


@helper()
def _collocation_coefficient(d, where, history, method, ode, q_zero, u, F):
    """c of the collocation polynomial P = U_d + c Q (Q = prod_j (tau - tau_j)) on component
    d's element ``where`` [a, a + k] (:func:`_correct_multi`): mcG(q) (tau_0 = 0)
    c = k / (q + 1) sum_j w_j f_d(U(a + tau_j k)) with the other components at their
    polynomials U (as the element's moments read them), mdG(q) c = (U_d(a^-) - U_d(a^+)) /
    Q(0) (P(0) the value before, :func:`_before_element`), NaN where that is unknown.
    u (N), F (1): workspace."""
    ptr, t_start, t_end, values, s_start, s_end, s_values = history
    nodes, bary, left, t0, u0 = method
    rhs, indptr, indices, p = ode[:4]
    E, q1 = t_end.shape[0], nodes.shape[0]
    slab = where - E
    if nodes[0] > 0.0:  # (dG: Radau nodes)
        before = (_before_slab(d, slab, ptr, t_end, values, s_start, s_end, s_values, t0, u0)
                  if slab >= 0 else _before_element(d, where, ptr, t_start, t_end, values,
                                                    s_end, s_values, t0, u0))
        for j in range(q1):
            before -= left[j] * _nodal_value(d, where, j, history)
        return before / q_zero
    a = s_start[slab] if slab >= 0 else t_start[where]
    k = (s_end[slab] if slab >= 0 else t_end[where]) - a
    f = component_kernel(rhs)
    lead = 0.0
    for j in range(q1):
        tj = _node_time(a, k, nodes[j])
        for nz in range(indptr[d], indptr[d + 1]):
            r = indices[nz]
            u[r] = (_nodal_value(d, where, j, history) if r == d else _element_polynomial(
                r, _element_at(r, tj, history), tj, history, nodes, bary)[0])
        f(d, address(u, 0), tj, address(p, 0), address(F, 0))
        lead += bary[j] * F[0]
    return k * lead / q1


@helper()
def _coefficients_at(d, t, history, method, ode, check, cached, u, F):
    """(where, slot, c): component d's element at t (:func:`_element_at`), its row of
    ``cached`` (the element at ``where``, slab n's at E + n N + d) and its collocation
    coefficient (:func:`_collocation_coefficient`, 0 where unknown), formed once per element
    in _row(cached, slot)[0] (NaN: not yet)."""
    where = _element_at(d, t, history)
    E = history[2].shape[0]
    slot = where if where < E else E + (where - E) * u.shape[0] + d
    if np.isnan(_row(cached, slot)[0]):
        c = _collocation_coefficient(d, where, history, method, ode, check[7], u, F)
        _row(cached, slot)[0] = 0.0 if np.isnan(c) else c
    return where, slot, _row(cached, slot)[0]


@helper()
def _collocation_value(d, t, history, method, ode, check, cached, u, F):
    """P_d(t) = U_d(t) + c Q(tau), the collocation polynomial of component d's element at t
    (:func:`_coefficients_at`), untested: what :func:`_correct_multi` reads the other
    components at."""
    nodes, bary = method[0], method[1]
    where, _, c = _coefficients_at(d, t, history, method, ode, check, cached, u, F)
    value, a, b = _element_polynomial(d, where, t, history, nodes, bary)
    tau = min(max((t - a) / (b - a), 0.0), 1.0)
    for j in range(nodes.shape[0]):
        c *= tau - nodes[j]
    return value + c


@helper()
def _star_value(d, where, c, g, history, method, check):
    """(t*, U_d(tau*) + c Q(tau*) - g S(tau*)) on component d's element ``where``: P's
    value at tau* (g = 0), V's (:func:`_correct_multi`)."""
    nodes, bary = method[0], method[1]
    _, a, b = _element_polynomial(d, where, 0.0, history, nodes, bary)
    t_star = a + check[0] * (b - a)
    return t_star, (_element_polynomial(d, where, t_star, history, nodes, bary)[0]
                    + c * check[3] - g * check[5])


@helper()
def _defect_at(d, where, t_star, c, g, history, method, ode, check, u, F):
    """The defect at tau* of U_d + c Q - g S on component d's element ``where``,
    U_d'(tau*) + c Q'(tau*) - g Q(tau*) - k f_d(u, t*) (u: its value and the other
    components' there; S' = Q). F (1): workspace."""
    rhs, p = ode[0], ode[3]
    nodes, bary = method[0], method[1]
    _, a, b = _element_polynomial(d, where, 0.0, history, nodes, bary)
    component_kernel(rhs)(d, address(u, 0), t_star, address(p, 0), address(F, 0))
    defect = c * check[4] - g * check[3] - (b - a) * F[0]
    for j in range(nodes.shape[0]):
        defect += check[2][j] * _nodal_value(d, where, j, history)
    return defect


@helper()
def _defect_coefficient(d, where, slot, history, method, ode, check, cached, u, w, F):
    """g = D / Q(tau*) of V = P - g S on component d's element ``where``, D = P_d'(tau*) -
    k f_d(P(t*), t*) its collocation polynomial's defect, the other components at theirs
    (:func:`_collocation_value`), formed once per element in _row(cached, slot)[1]. u, w (N),
    F (1): workspace."""
    if not np.isnan(_row(cached, slot)[1]):
        return _row(cached, slot)[1]
    indptr, indices = ode[1], ode[2]
    c = _row(cached, slot)[0]
    t_star, X = _star_value(d, where, c, 0.0, history, method, check)
    for nz in range(indptr[d], indptr[d + 1]):
        r = indices[nz]
        u[r] = X if r == d else _collocation_value(r, t_star, history, method, ode, check,
                                                   cached, w, F)
    _row(cached, slot)[1] = _defect_at(d, where, t_star, c, 0.0, history, method, ode, check,
                                       u, F) / check[3]
    return _row(cached, slot)[1]


@helper()
def _corrected_value(d, t, history, method, ode, check, cached, u, w, F):
    """V_d(t) = P_d(t) - g S(tau) (:func:`_defect_coefficient`), untested: where
    :func:`_correct_multi`'s test of V reads the other components (as the mono-adaptive
    test moves every component to V). u, w (N), F (1): workspace."""
    where, slot, _ = _coefficients_at(d, t, history, method, ode, check, cached, w, F)
    g = _defect_coefficient(d, where, slot, history, method, ode, check, cached, u, w, F)
    _, a, b = _element_polynomial(d, where, t, history, method[0], method[1])
    tau = min(max((t - a) / (b - a), 0.0), 1.0)
    return (_collocation_value(d, t, history, method, ode, check, cached, w, F)
            - g * _correction_shape(check[6], tau))


@helper()
def _residual(d, t, history, method, ode, check, cached, u, v, w, F):
    """V's residual at tau* on component d's element at t, V_d' - k f_d(V) there
    (:func:`_defect_at`), the other components at their V
    (:func:`_corrected_value`, as the mono-adaptive test moves every component to V); once
    per element, in _row(cached, slot)[2]. u, v, w (N), F (1): workspace."""
    where, slot, c = _coefficients_at(d, t, history, method, ode, check, cached, w, F)
    if not np.isnan(_row(cached, slot)[2]):
        return _row(cached, slot)[2]
    indptr, indices = ode[1], ode[2]
    g = _defect_coefficient(d, where, slot, history, method, ode, check, cached, u, w, F)
    t_star, X = _star_value(d, where, c, g, history, method, check)
    for nz in range(indptr[d], indptr[d + 1]):
        r = indices[nz]
        u[r] = X if r == d else _corrected_value(r, t_star, history, method, ode, check,
                                                 cached, v, w, F)
    _row(cached, slot)[2] = _defect_at(d, where, t_star, c, g, history, method, ode, check,
                                       u, F)
    return _row(cached, slot)[2]


@helper()
def _shared_kind(i, t, history, method, ode, check, theta, cached, u, v, w, F, members,
                 seen, tests):
    """The kind of component i's dense value on its element at t (:func:`_correct_multi`),
    one for the components that reach i through f's dependencies (either way: ``ode``'s
    pattern and its transpose) over elements of the same interval, so that a linear
    invariant the nodes keep holds inside: 2 (V) where V's residuals
    (:func:`_residual`), integrated from 0, are at most theta times its corrections g S at
    tau*, else 1 (P) where P's defects D = g Q(tau*) are at most theta times its
    corrections c Q, else 0 (the element polynomial as read without f), each test one over
    the set (:func:`_defect_small` of :func:`_scaled_max`, each component relative to its
    largest nodal value: per component, one whose correction passes near zero failed alone
    and dropped the set); once per set, in _row(cached, slot)[3] of each. members, seen
    (N, int; seen zero), tests (5, N): workspace."""
    where, slot, _ = _coefficients_at(i, t, history, method, ode, check, cached, w, F)
    if not np.isnan(_row(cached, slot)[3]):
        return _row(cached, slot)[3]
    nodes, bary = method[0], method[1]
    indptr, indices, tindptr, tindices = ode[1], ode[2], ode[4], ode[5]
    star, q_star, s_star = check[0], check[3], check[5]
    _, a, b = _element_polynomial(i, where, t, history, nodes, bary)
    t_star = a + star * (b - a)
    members[0] = i
    seen[i] = 1
    count = 1
    for n in range(u.shape[0]):  # (breadth first: members[n] is the next to visit)
        if n == count:
            break
        d = members[n]
        for pattern in range(2):
            ptr, idx = (indptr, indices) if pattern == 0 else (tindptr, tindices)
            for nz in range(ptr[d], ptr[d + 1]):
                r = idx[nz]
                if not seen[r]:
                    _, ra, rb = _element_polynomial(r, _element_at(r, t_star, history),
                                                    t_star, history, nodes, bary)
                    if ra == a and rb == b:
                        seen[r] = 1
                        members[count] = r
                        count += 1
    for n in range(count):
        d = members[n]
        residual = _residual(d, t_star, history, method, ode, check, cached, u, v, w, F)
        where, slot, c = _coefficients_at(d, t_star, history, method, ode, check, cached, w,
                                          F)
        g = _row(cached, slot)[1]
        tests[0, n], tests[1, n], tests[2, n], tests[3, n] = residual, g, g * q_star, c
        tests[4, n] = 0.0
        for j in range(nodes.shape[0]):
            tests[4, n] = max(tests[4, n], abs(_nodal_value(d, where, j, history)))
    scale = tests[4, :count]
    kind = 0.0
    if _defect_small(_scaled_max(tests[1, :count], scale),
                     _scaled_max(tests[0, :count], scale), star, s_star, theta):
        kind = 2.0
    elif _defect_small(_scaled_max(tests[3, :count], scale),
                       _scaled_max(tests[2, :count], scale), star, q_star, theta):
        kind = 1.0
    for n in range(count):
        _row(cached, _coefficients_at(members[n], t_star, history, method, ode, check,
                                      cached, w, F)[1])[3] = kind
        seen[members[n]] = 0
    return kind


@njit(cache=True)
def _correct_multi(ptr, t_start, t_end, values, s_start, s_end, s_values, nodes, bary, left,
                   t0, u0, rhs, indptr, indices, p, tindptr, tindices, check, theta, rows,
                   index, slots, count, times, out):
    """out[i, m] = mcG(q)'s or mdG(q)'s dense value at times[m] strictly inside component i's
    element (elsewhere out is left as it is: the nodal values), from component i's elements
    ptr[i]:ptr[i + 1] and the shared slabs (s_start, s_end, s_values (S, q + 1, N)) as
    :func:`_evaluate_mixed` reads them (the slabs empty for a grouped history); the method's
    nodes, barycentric weights and l_j(0) (``left``), t0, u0; f_i the component kernel at
    address ``rhs``, its CSR dependencies (``indptr``, ``indices``) and their transpose
    (``tindptr``, ``tindices``: the components whose f reads each), parameters p. (The
    helpers take them as ``history`` = (ptr, ..., s_values), ``method`` = (nodes, ...,
    u0), ``ode`` = (rhs, ..., tindices); the arguments are arrays: a tuple argument costs
    the call several us to type.)

    On component i's element [a, a + k] with nodal values U_j at the method's nodes tau_j
    (Lobatto, mcG(q); right Radau, mdG(q)), the collocation polynomial of mono cG(q) or
    dG(q) (:func:`_evaluate_cg`, :func:`_evaluate_dg`) is

        P(tau) = U_i(tau) + c Q(tau),  Q(tau) = prod_j (tau - tau_j)

    (:func:`_collocation_coefficient`: mcG(q) P'(tau_j) = k f_i at the nodes, mdG(q) P(0)
    the value before the element), and with its defect D = P' - k f_i(P, t) at tau* (half
    the first node off 0), the other components read at their own collocation polynomials
    there (:func:`_collocation_value`; at their U they put k J times U's O(k^(q+1)) error
    into D), the defect-corrected value

        V(tau) = P(tau) - g S(tau),  g = D(tau*) / Q(tau*),  S(tau) = int_0^tau Q,

    one order higher (:func:`_defect_coefficient`, as :func:`_defect_correction`). Each is
    used under the residual tests of the mono-adaptive values, V, else P (no P for mdG(q)
    where the value before is unknown), one kind and one test for the components coupled
    over elements of the same interval (:func:`_shared_kind`): P, V and U differ by
    corrections linear in f's values, so a linear invariant that the nodes keep holds
    inside such an interval. Where the set fails both, out is left as it is, the element
    polynomial as read without f: U_i for mcG(q); for mdG(q) dG's jump rule
    (:func:`_correction`), P where the jump is resolved, as U_i after its jump is off by
    it near the element's start (a slow component sharing its elements with a stiff one
    stepped over, or with one decayed to 1e-40: 17 x and 64 x the tolerance, against the
    jump rule's 0.012 x and 0.03 x).

    ``check`` = (tau*, l_j(tau*), l_j'(tau*), Q(tau*), Q'(tau*), S(tau*), G, Q(0))
    (:func:`_multi_check`). (rows, index, slots, count) keep per element read c, g, V's
    residual and the shared kind (:func:`_row`, :func:`element_cache`; kept from call to
    call for the same history). f_i is evaluated q + 3 (mcG(q)) or 3 (mdG(q)) times per element
    the times fall inside, and about as many times per element of another component read
    at tau*. Q and S vanish at tau = 1: the ends are unchanged."""
    N, E, S = out.shape[0], t_end.shape[0], s_start.shape[0]
    history = (ptr, t_start, t_end, values, s_start, s_end, s_values)
    method = (nodes, bary, left, t0, u0)
    ode = (rhs, indptr, indices, p, tindptr, tindices)
    cached = (rows, index, slots, count)
    u, v, w = np.zeros(N), np.zeros(N), np.zeros(N)  # (f's arguments, one per depth)
    F = np.zeros(1)
    members = np.empty(N, dtype=np.int64)
    seen = np.zeros(N, dtype=np.int64)
    tests = np.empty((5, N))
    for i in range(N):
        own = t_end[ptr[i]:ptr[i + 1]]
        n, slab, current, kind, c, g = 0, 0, -1, 0.0, 0.0, 0.0
        for m in range(times.shape[0]):
            t = times[m]
            where = -1  # (found as _element_at finds it, walking forward from the last)
            if S > 0:
                slab = _locate(s_end, t, slab)
                if s_start[slab] < t < s_end[slab]:
                    where, a, b = E + slab, s_start[slab], s_end[slab]
            if where < 0 and own.shape[0] > 0:
                n = _locate(own, t, n)
                e = ptr[i] + n
                if t_start[e] < t < t_end[e]:
                    where, a, b = e, t_start[e], t_end[e]
            if where < 0:
                continue
            if where != current:
                current = where
                # (an element read before, in this call or an earlier one, is looked up
                # alone: the helpers' calls pass every array of the history)
                row = _row(cached, where if where < E else E + (where - E) * N + i)
                if np.isnan(row[3]):
                    _shared_kind(i, t, history, method, ode, check, theta, cached, u, v, w, F,
                                 members, seen, tests)
                kind = row[3]
                c, g = row[0], row[1] if kind > 1.0 else 0.0
            if kind == 0.0:  # (out holds the element polynomial as read without f)
                continue
            tau = (t - a) / (b - a)
            value = (element_value(s_values[slab].T, i, tau, nodes, bary) if where >= E
                     else element_value(values, where, tau, nodes, bary))
            r = 1.0
            for j in range(nodes.shape[0]):
                r *= tau - nodes[j]
            out[i, m] = value + c * r - g * _correction_shape(check[6], tau)


#: A solution keeps what its multi-adaptive dense values read per element (c, g, the
#: tests: :func:`element_cache`) from call to call where that takes at most these bytes
#: (1.4 M elements): a loop of scalar calls reads the same elements again.
KEPT_CACHE = 2**26
#: Where dG(q)'s dense value cannot read f: a component's jump [U] at an element's start is
#: taken as resolved, and the collocation polynomial used, when |[U]| <= THETA max_j
#: |xi_j - U(t_{n-1}^-)| (see _evaluate_dg; mdG(q): _correction).
DENSE_THETA = 0.25
#: cG(q)'s and dG(q)'s collocation polynomial P is used for a component where its defect,
#: integrated from the element start, is at most THETA times its correction of U (see
#: _evaluate_cg, _evaluate_dg).
DEFECT_THETA = 1.0


@njit(cache=True, inline="always")
def _entry(J, indptr, indices, i, j):
    """J_ij of the CSR values J (pattern ``indptr``, ``indices``), 0 outside the pattern."""
    for nz in range(indptr[i], indptr[i + 1]):
        if indices[nz] == j:
            return J[nz]
    return 0.0


@njit(cache=True, inline="always")
def _dg_values(values, n, collocated, before, g, weights, weights0, s_tau, out):
    """out[i] = component i's value of :func:`_evaluate_dg` on element n where the bases
    take ``weights`` (U's, on the nodes) and ``weights0`` (P's, on 0 and the nodes), S
    ``s_tau``: P - g S where ``collocated``, else U."""
    q1 = values.shape[1]
    for i in range(out.shape[0]):
        value = 0.0
        if collocated[i]:
            for j in range(q1):
                value += weights0[j + 1] * values[n, j, i]
            out[i] = value + weights0[0] * before[i] - g[i] * s_tau
        else:
            for j in range(q1):
                value += weights[j] * values[n, j, i]
            out[i] = value


@njit(cache=True, inline="always")
def _quasi_steady_dg(rhs, p, values, n, t, tau, k, nodes, nodes0, collocated, before, g,
                     steady, diagonal, slopes, slopes0, D, F, out):
    """out[i] = W_i = Z_i + (Z_i' - k f_i(Z, t)) / (k J_ii) where ``steady`` (one Newton step
    of component i's equation from :func:`_evaluate_dg`'s value Z = ``out`` towards its
    quasi-steady state, lag included; J_ii = ``diagonal[i]``), Z' in tau (P' - g Pi where
    ``collocated``, else U'); on return D[i] = Z_i' where ``steady``, F = k f(Z, t)."""
    q1 = nodes.shape[0]
    lagrange_slopes(tau, nodes, slopes)
    lagrange_slopes(tau, nodes0, slopes0)
    pi_tau = 1.0
    for j in range(q1):
        pi_tau *= tau - nodes[j]
    rhs_kernel(rhs)(address(out, 0), t, address(p, 0), address(F, 0))
    for i in range(out.shape[0]):
        F[i] *= k
        if not steady[i]:
            continue
        D[i] = 0.0
        if collocated[i]:
            D[i] = slopes0[0] * before[i] - g[i] * pi_tau
            for j in range(q1):
                D[i] += slopes0[j + 1] * values[n, j, i]
        else:
            for j in range(q1):
                D[i] += slopes[j] * values[n, j, i]
        out[i] += (D[i] - F[i]) / (k * diagonal[i])


@njit(cache=True, error_model="numpy")  # (no zero check on every division)
def _evaluate_dg(t_start, t_end, values, starts, befores, nodes, bary, nodes0, bary0, left,
                 rhs, jacobian, indptr, indices, p, check, theta, times, out):
    """out[i, m] = the dense value of a mono-adaptive dG(q) solution at times[m].

    On element n, with stage values xi_j at the right Radau nodes tau_j and the previous
    end value U(t_{n-1}^-) (u0 on the first element), the collocation polynomial

        P(tau) = U(tau) - [U] R(tau),  [U] = U(t_{n-1}^+) - U(t_{n-1}^-),

    of degree q + 1 interpolates U(t_{n-1}^-) at tau = 0 and xi_j at tau_j (R the right
    Radau polynomial, R(0) = 1, R(tau_j) = 0): Radau IIA's, P'(tau_j) = k f(xi_j). With its
    defect d = P' - k f(P, t) at tau* = tau_0 / 2 the corrected value
    (:func:`_defect_correction`)

        V(tau) = P(tau) - g S(tau),  g = d(tau*) / Pi(tau*),  S(tau) = int_0^tau Pi

    (Pi(tau) = prod_j (tau - tau_j); S(1) = 0: Radau quadrature is exact for Pi) has
    interior error O(k^(q+3)) where the element resolves the component, against P's
    O(k^(q+2)) and U's O(k^(q+1)) (the nodes: O(k^(2q+1))). Where a stiff transient is
    stepped over, the jump is O(1) and P swings by |[U] R| inside; where k |lambda| >> 1
    the error follows d / (k lambda), not -int d. Each value is used per element and
    component only where its residual passes cG's test (:func:`_passes_defect_test`): P
    where |d(tau*)| tau* / 2 <= theta |[U] R(tau*)| (P's residual, integrated from 0,
    against its correction of U), V where also k |f_i(V(tau*)) - f_i(P(tau*))| tau* / 2
    <= theta |g S(tau*)| (V's residual at tau*, V' = P' - g Pi, against its correction of
    P: k |lambda| tau* / 2 <= theta along it), else P, else U; two f per element.

    A component stiff on the element, -k J_ii tau* > 1 (J = df/du at the value Z chosen
    so, at tau*; the layer at the element's start has decayed by tau*), and a fast mode on
    its own, sum_(j != i) |J_ji| <= |J_ii| / 2 (it feeds the others less than itself: a
    linear invariant w^T u, w^T J = 0, ties it to them, and W moved it alone: HIRES's
    y7 + y8 broke by 1.07e-5 at 1e-6, ROBER's y1 was 61 x the tolerance inside), has its
    nodes on its quasi-steady state, and U, P, V interpolate that state between them, off
    by k^(q+1) times its (q+1)th derivative. It takes

        W_i(tau) = Z_i + r_i / (k J_ii),  r = Z' - k f(Z, t)

    (:func:`_quasi_steady_dg`: one Newton step of its equation towards that state, lag Z_i'
    included; without the lag W was 1250 x the tolerance inside) where W's residual,
    W_i' - k f_i(W) with W_i' = Z_i' + r_i' / (k J_ii) (r' between tau* and tau**), is at
    those two points at most theta times Z's, r_i: one Jacobian and, where a component is
    stiff, four f per element, and one f per time.
    cG(q)'s quasi-steady value (:func:`_quasi_steady`: W = U + c Q - g S, two coefficients
    by collocation at two points) on dG(q)'s shapes was worse than Z where -k J_ii is
    large (u' = -800 (u - sin(v)^3), dG(2) at 1e-6: 42 -> 103 x the tolerance inside): two
    coefficients do not follow the state across the element, and W(0) misses the value
    before. ``jacobian``: the Jacobian kernel's address (CSR pattern ``indptr``,
    ``indices``), 0 for none.
    ``check`` = (tau*, l_j(tau*), l0_j(tau*), l0_j'(tau*) (l, l0 the Lagrange bases of U
    and of P on 0, tau_0, ..., tau_q), R(tau*), Pi(tau*), S(tau*), G) with S(tau) = tau
    (tau - 1) G(tau) (G's monomial coefficients, highest first), f the kernel at address
    ``rhs`` (parameters p). Without f (``rhs`` 0: f jumps, or the elements solve more than one
    model) P is used where |[U]_i| <= ``theta`` max_j |xi_ij - U_i(t_{n-1}^-)|, else U
    (dG(1) near an extremum of a component fails it: jump and change are both O(k^2)).

    An element starting at starts[p] (t0; a model switch) reads befores[p] as its value
    before (u0; the new model's initial value), not the previous element's end; where the
    partition restarts otherwise (t_{n-1} not the previous element's end) U is used. Every
    value equals xi_q at tau = 1 (S(1) = 0 exactly): the nodes are unchanged bit for bit.
    """
    q1, N = nodes.shape[0], out.shape[0]
    star, basis, basis0, slopes0, r_star, pi_star, s_star, g_coefficients, second = check
    # where a component is stiff on the element: J_ii (diagonal[i]), sum_j |J_ji|
    # (spread[i]), whether it takes W (steady[i]); workspace of W: the bases' slopes, Z',
    # k f(Z), J's values
    steady = np.zeros(N, dtype=np.bool_)
    diagonal = np.empty(N)
    spread = np.empty(N)
    slopes = np.empty(q1)
    slopes_p = np.empty(q1 + 1)
    D = np.empty(N)
    Z = np.empty(N)
    test = np.empty((8, N))
    J = np.empty(max(indices.shape[0], 1))
    weights = np.empty(q1)
    weights0 = np.empty(q1 + 1)
    # per element and component, made when the times enter an element: whether P is used
    # (collocated[i]), U(t_{n-1}^-) (before[i]) and V's coefficient g[i]; the bases only
    # where one reads them
    collocated = np.zeros(N, dtype=np.bool_)
    before = np.zeros(N)
    g = np.zeros(N)
    X = np.empty(N)  # P(tau*), V(tau*) and f there
    Y = np.empty(N)
    F = np.empty(N)
    F2 = np.empty(N)
    f = rhs_kernel(rhs)
    some_p = some_u = some_w = False
    current = -1
    n = 0
    for m in range(times.shape[0]):
        n = _locate(t_end, times[m], n)
        k = t_end[n] - t_start[n]
        if n != current:
            current = n
            # (an element cut to end at a piece's T may end a rounding away from the next
            # start)
            first = n == 0 or abs(t_end[n - 1] - t_start[n]) > 4e-16 * abs(t_start[n])
            start = -1
            for s in range(starts.shape[0]):
                if t_start[n] == starts[s]:
                    start = s
            some_p = some_u = False
            by_component = values[n].T
            for i in range(N):
                collocated[i] = False
                g[i] = 0.0
                X[i] = 0.0
                if start >= 0 or not first:
                    before[i] = befores[start, i] if start >= 0 else values[n - 1, q1 - 1, i]
                    if rhs == 0:
                        collocated[i] = not np.isnan(_jump(by_component, i, before[i], left,
                                                           theta))
                    else:
                        collocated[i] = True
                        X[i] = basis0[0] * before[i]
                if collocated[i]:
                    for j in range(q1):
                        X[i] += basis0[j + 1] * values[n, j, i]
                else:
                    for j in range(q1):
                        X[i] += basis[j] * values[n, j, i]
            if rhs != 0:
                f(address(X, 0), t_start[n] + star * k, address(p, 0), address(F, 0))
                for i in range(N):
                    if collocated[i]:
                        g[i] = slopes0[0] * before[i] - k * F[i]
                        for j in range(q1):
                            g[i] += slopes0[j + 1] * values[n, j, i]
                        c = _jump(by_component, i, before[i], left, np.inf)
                        collocated[i] = _passes_defect_test(c, g[i], star, r_star,
                                                            theta) != 0.0
                _defect_correction(rhs, p, t_start[n] + star * k, k, X, F, g, Y, F2, star,
                                   pi_star, s_star, theta, np.empty(0))
                for i in range(N):
                    collocated[i] |= g[i] != 0.0
            some_w = False
            if jacobian != 0:
                t_star = t_start[n] + star * k
                _dg_values(values, n, collocated, before, g, basis, basis0, s_star, X)
                rhs_kernel(jacobian)(address(X, 0), t_star, address(p, 0), address(J, 0))
                for i in range(N):
                    diagonal[i] = _entry(J, indptr, indices, i, i)
                    spread[i] = 0.0
                for nz in range(indices.shape[0]):  # (sum_(j != i) |J_ji| by column)
                    spread[indices[nz]] += abs(J[nz])
                for i in range(N):
                    steady[i] = (-k * diagonal[i] * star > 1.0
                                 and spread[i] - abs(diagonal[i]) <= 0.5 * abs(diagonal[i]))
                    some_w |= steady[i]
            if some_w:
                lagrange_weights(second, nodes, bary, weights)
                lagrange_weights(second, nodes0, bary0, weights0)
                _dg_values(values, n, collocated, before, g, weights, weights0,
                           _correction_shape(g_coefficients, second), Y)
                # rows: W, Z', k f(Z), k f(W) at tau* (0-3), at tau** (4-7)
                for point in range(2):
                    a = 4 * point
                    tau_a = star if point == 0 else second
                    t_a = t_start[n] + tau_a * k
                    test[a, :] = X if point == 0 else Y
                    _quasi_steady_dg(rhs, p, values, n, t_a, tau_a, k, nodes, nodes0,
                                     collocated, before, g, steady, diagonal, slopes, slopes_p,
                                     test[a + 1], test[a + 2], test[a])
                    f(address(test[a], 0), t_a, address(p, 0), address(test[a + 3], 0))
                some_w = False
                for i in range(N):
                    if not steady[i]:
                        continue
                    # W' = Z' + r' / (k J_ii), r = Z' - k f(Z) (r' between the points)
                    lag = ((test[5, i] - test[6, i]) - (test[1, i] - test[2, i])) / (
                        (second - star) * k * diagonal[i])
                    r_w = max(abs(test[1, i] + lag - k * test[3, i]),
                              abs(test[5, i] + lag - k * test[7, i]))
                    r_z = max(abs(test[1, i] - test[2, i]), abs(test[5, i] - test[6, i]))
                    steady[i] = r_w <= theta * r_z
                    some_w |= steady[i]
            for i in range(N):
                some_p |= collocated[i]
                some_u |= not collocated[i]
        tau = min(max((times[m] - t_start[n]) / k, 0.0), 1.0)
        if some_u:
            lagrange_weights(tau, nodes, bary, weights)
        s_tau = 0.0
        if some_p:
            lagrange_weights(tau, nodes0, bary0, weights0)
            s_tau = _correction_shape(g_coefficients, tau)
        _dg_values(values, n, collocated, before, g, weights, weights0, s_tau, Z)
        if some_w and 0.0 < tau < 1.0:  # (W(1) != U(1): the nodes stay)
            _quasi_steady_dg(rhs, p, values, n, times[m], tau, k, nodes, nodes0, collocated,
                             before, g, steady, diagonal, slopes, slopes_p, D, F, Z)
        for i in range(N):
            out[i, m] = Z[i]


@njit(cache=True)
def _first_outside(times, t0, T):
    """The index of the first time outside [t0, T] (or NaN), -1 if none."""
    for m in range(times.shape[0]):
        if not t0 <= times[m] <= T:
            return m
    return -1


@njit(cache=True)
def _set_initial(times, t0, u0, out):
    """out[:, m] = u0 where times[m] == t0: U(t0) is the initial value (for dG the element
    polynomial starts after the jump)."""
    for m in range(times.shape[0]):
        if times[m] == t0:
            for i in range(u0.shape[0]):  # (not out[:, m] = u0: see io.history)
                out[i, m] = u0[i]


@njit(cache=True)
def _grouped(comp, t_start):
    """Whether the elements are sorted by component and, within one, by start time."""
    for e in range(1, comp.shape[0]):
        if comp[e] < comp[e - 1] or (comp[e] == comp[e - 1] and t_start[e] < t_start[e - 1]):
            return False
    return True


def _group(N, comp, t_start, t_end, values):
    """(ptr, t_start, t_end, values) of elements of N components ordered by component and,
    within one, by start time (sorted copies only if they are not), component i owning
    ptr[i]:ptr[i + 1]."""
    if not _grouped(comp, t_start):
        order = np.lexsort((t_start, comp))
        comp, t_start, t_end, values = comp[order], t_start[order], t_end[order], values[order]
    return np.searchsorted(comp, np.arange(N + 1)), t_start, t_end, values


def equispaced(t0, T, n):
    """np.linspace(t0, T, n) (with the last time exactly T), formed without its 14 us of
    argument handling."""
    times = np.arange(n) * ((T - t0) / max(n - 1, 1)) + t0
    if n > 1:
        times[-1] = T
    return times


def join_elements(chunks):
    """np.concatenate of element arrays given in chunks, [[t_start, k, values], ...], per array.

    The list is emptied and each chunk released once copied: the result's pages are
    committed as the chunks' are freed, so the stored elements (gigabytes on a large
    system) are not held twice as with np.concatenate."""
    if len(chunks) == 1:  # the common case: copies of the used part of the buffers
        return [part.copy() for part in chunks.pop()]
    total = sum(len(chunk[0]) for chunk in chunks)
    joined = [np.empty((total, *a.shape[1:]), dtype=a.dtype) for a in chunks[0]]
    chunks.reverse()
    start = 0
    while chunks:
        chunk = chunks.pop()
        for out, part in zip(joined, chunk):
            out[start:start + len(part)] = part
        start += len(chunk[0])
    return joined


@cache
def _collocation_nodes(family, q):
    """The nodes 0, tau_0, ..., tau_q of dG(q)'s collocation polynomial and their
    barycentric weights w_j = 1 / prod_{m != j} (x_j - x_m)."""
    x = np.concatenate([[0.0], make_method(family, q).nodes])
    w = np.array([1.0 / np.prod([x[j] - x[m] for m in range(len(x)) if m != j])
                  for j in range(len(x))])
    return x, w


def dense_rule(method, dense=True):
    """(left, theta) of :func:`_correction`: dG(q)'s rule for dG(q), q >= 1, theta < 0 (the
    element polynomials) for other methods or dense False."""
    if dense and method.family == "dG" and method.q > 0:
        return method.left_value, float(DENSE_THETA)
    return method.nodes, -1.0


def _shapes(nodes):
    """Q = prod_j (tau - tau_j), S(tau) = int_0^tau Q (polynomials) and G, the coefficients
    of S(tau) / (tau (tau - 1)), highest first (:func:`_correction_shape`)."""
    Q = np.polynomial.Polynomial.fromroots(nodes)
    S = Q.integ(lbnd=0.0)
    G, _ = divmod(S, np.polynomial.Polynomial([0.0, -1.0, 1.0]))
    return Q, S, np.ascontiguousarray(G.coef[::-1])


def transposed(indptr, indices):
    """(indptr, indices) of the transposed CSR pattern: the components whose f reads each."""
    counts = np.bincount(indices, minlength=indptr.shape[0] - 1)
    order = np.argsort(indices, kind="stable")
    rows = np.repeat(np.arange(indptr.shape[0] - 1), np.diff(indptr))
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), rows[order].astype(np.int64)


@cache
def _multi_check(family, q):
    """``check`` of :func:`_correct_multi`: (tau*, l_j(tau*), l_j'(tau*), Q(tau*), Q'(tau*),
    S(tau*), G, Q(0)) at the tau* of :func:`_defect_check` (half the first node off 0; l_j
    the Lagrange basis on the method's nodes)."""
    nodes = make_method(family, q).nodes
    Q, S, G = _shapes(nodes)
    star = _defect_check(family, q)[0]
    basis, slopes = lagrange_matrices(nodes, (star,))
    return (star, basis[0], slopes[0], float(Q(star)), float(Q.deriv()(star)), float(S(star)),
            G, float(Q(0.0)))


@cache
def _defect_check(family, q):
    """``check`` of the residual tests at tau*, off the nodes, and of V = P - g S
    (:func:`_defect_correction`; Q = prod_j (tau - tau_j) over the method's nodes,
    S(tau) = int_0^tau Q, G the coefficients, highest first, of S(tau) / (tau (tau - 1))).
    cG(q) (:func:`_evaluate_cg`): (tau*, l_j(tau*), l_j'(tau*), Q(tau*), Q'(tau*), S(tau*),
    G, then points, l_j, l_j', Q, Q', S at the points tau*, tau** = (tau_(q-1) + 1) / 2,
    tau*** = 1/2 (q odd) or (1/2 + tau**) / 2) at tau* = tau_1 / 2 (l_j the Lagrange
    basis on the nodes). dG(q)
    (:func:`_evaluate_dg`): (tau*, l_j(tau*), l0_j(tau*), l0_j'(tau*), R(tau*), Q(tau*),
    S(tau*), G, tau** = (tau_(q-1) + 1) / 2) at tau* = tau_0 / 2 (l0_j the basis on 0 and
    the nodes, R = prod_j (tau_j - tau) / tau_j)."""
    nodes = make_method(family, q).nodes
    Q, S, G = _shapes(nodes)
    if family == "cG":
        second = (nodes[-2] + 1) / 2
        # (off the nodes: U's defect is small at a node, where its nodal value superconverges)
        points = np.array([nodes[1] / 2, second, 0.5 if q % 2 else (0.5 + second) / 2])
        basis, slopes = lagrange_matrices(nodes, points)
        return (float(points[0]), basis[0], slopes[0], float(Q(points[0])),
                float(Q.deriv()(points[0])), float(S(points[0])), G, points, basis, slopes,
                Q(points), Q.deriv()(points), S(points))
    star = nodes[0] / 2
    basis, _ = lagrange_matrices(nodes, (star,))
    basis0, slopes0 = lagrange_matrices(np.concatenate([[0.0], nodes]), (star,))
    return (float(star), basis[0], basis0[0], slopes0[0], float(np.prod(1 - star / nodes)),
            float(Q(star)), float(S(star)), G, float((nodes[-2] + 1) / 2))


@njit(cache=True)
def _inside(times, t0, T):
    """Whether a time lies strictly inside (t0, T): only there can a dense value differ from
    U (the corrections of cG(q) and mcG(q) vanish at element ends, dG(q)'s at right ends,
    and t0 reads u0), so sol(T) reads no f and compiles none of the dense kernels. (A
    compiled loop: numpy's three passes cost 2 us at 100 times.)"""
    for m in range(times.shape[0]):
        if t0 < times[m] < T:
            return True
    return False


def _reads_f(method):
    """Whether ``method``'s dense value reads f: cG(q) and mcG(q), q >= 2, dG(q) and mdG(q),
    q >= 1 (:func:`_evaluate_cg`, :func:`_evaluate_dg`, :func:`_correct_multi`)."""
    return method.q > (0 if method.family == "dG" else 1)


def dense_rhs(method, ode, branches=False):
    """The lowered ``ode`` that :func:`evaluate_mono` and :func:`correct_multi` read for a
    cG(q), mcG(q), q >= 2, or dG(q), mdG(q), q >= 1, dense value (its elements must solve
    it); None for other methods.

    With ``branches`` (the solve recorded the branches of f's switches it took), the smooth
    f of their branch parameters (:func:`dolfinode.events.switched`), to be read on each
    element's branch (:func:`on_branches`): the solve restarts at each crossing of a switch
    of the state, so end nodes sit on it, where the original f takes either branch by
    rounding (cG(q)'s P, which reads f there, was 10-59 x the tolerance inside, Coulomb
    friction at 1e-8). Without, also None for cG(q), mcG(q) where f jumps across a switch
    of the state (their element polynomial is used). A jump in t is read on the element's
    side (:data:`NODE_INSET`; without, cG(3) was 25 x the tolerance inside the elements of
    u' = -u + Heaviside(t - 1), at 1e-8). dG(q)'s reads f only at tau* inside the element
    (and, with J, at the times there), which no jump crosses (the solve ends its pieces
    there)."""
    if not _reads_f(method):
        return None
    if branches:
        from dolfinode import events  # (it imports this module)

        return lower(events.switched(ode)[0])
    if method.family == "cG" and _switches_on_state(ode):
        return None
    return lower(ode)


def on_branches(branches, times, out, rhs, evaluate):
    """evaluate(times, rhs, out), with the branch parameters of ``rhs`` (:func:`dense_rhs`)
    those the solve took at the times: ``branches`` = (starts, sigmas), sigmas[j] from
    starts[j] on (its restarts: t0, the breakpoints, the crossings of switches), None for
    one call as given. Once per distinct branch, on the times of its pieces (s_j, s_j+1]
    (a piece's start is the end of the one before), each time's element solved on it;
    ``out`` holds what ``evaluate`` starts from (multi-adaptive: the element
    polynomials)."""
    if branches is None or rhs is None:
        evaluate(times, rhs, out)
        return
    starts, sigmas = branches
    distinct, which = np.unique(sigmas, axis=0, return_inverse=True)
    piece = which.ravel()[np.maximum(np.searchsorted(starts, times) - 1, 0)]
    for j, sigma in enumerate(distinct):
        at = np.flatnonzero(piece == j)
        if at.size == 0:
            continue
        if at.size == 1:  # (an (N, 1) part is C- and F-contiguous: numba would compile the
            at = np.repeat(at, 2)  # kernels again, as in Solution._values)
        part = np.empty((at.size, out.shape[0])).T
        part[:] = out[:, at]
        values = rhs.p.copy()
        values[values.size - sigma.size:] = sigma
        evaluate(times[at], rhs.again(values), part)
        out[:, at] = part


def branches_taken(restarts):
    """(starts, sigmas) of :func:`on_branches` from the solve's restarts [(t, sigma), ...]."""
    starts, sigmas = zip(*restarts)
    return np.array(starts, dtype=float), np.array(sigmas, dtype=float).reshape(len(starts), -1)


def correct_multi(method, compiled, dependents, declared, history, times, out, cache=None):
    """The multi-adaptive dense value inside the elements of ``history`` = (ptr, t_start,
    t_end, values, s_start, s_end, s_values) at ``times`` in ``out``, which holds the element
    polynomials there (:func:`_correct_multi`): ``compiled`` the lowered ODE
    (:func:`dense_rhs`), ``dependents`` its transposed pattern, ``declared`` its t0, u0,
    ``cache`` what the elements read keep (:func:`element_cache` of this history, made for
    this call if None). Every reader of multi-adaptive elements (a Solution, the samples of
    dense_output=False) corrects through here."""
    if cache is None:
        cache = element_cache(history, declared.N)
    with first_use(_correct_multi, "the multi-adaptive dense values", 7):
        _correct_multi(*history, method.nodes, method.barycentric_weights, method.left_value,
                       float(declared.t0), np.asarray(declared.u0, dtype=float),
                       compiled.rhs_component.address, compiled.indptr, compiled.indices,
                       compiled.p, *dependents, _multi_check(method.family, method.q),
                       DEFECT_THETA, *cache, times, out)


def element_cache(history, N):
    """What :func:`_correct_multi` keeps per element read of ``history`` (rows, index,
    slots, count: :func:`_row`'s sparse set, empty), 48 bytes per element and slab
    component, committed only where an element is read."""
    size = history[2].shape[0] + history[4].shape[0] * N
    return (np.empty((size, 4)), np.empty(size, dtype=np.int64),
            np.empty(size, dtype=np.int64), np.zeros(1, dtype=np.int64))


def _switches_on_state(ode):
    """Whether f of ``ode`` jumps across a switch of the state (a non-smooth function of the
    state other than a kink, :func:`dolfinode.events.switched`; for a template system, a
    term that jumps)."""
    from dolfinode import events  # (it imports this module)

    if hasattr(ode, "templates"):
        return bool(ode._derived("_jumps", ode.templates, lambda: events._template_jumps(ode)))
    states = set(ode.states)
    return any(not s.kink and s.g.free_symbols & states for s in events.switched(ode)[1])


def evaluate_mono(method, t_start, t_end, values, starts, befores, times, out, compiled=None):
    """out = U at ``times`` from elements of a shared partition (values (M, q + 1, N)):
    dG(q), q >= 1, by :func:`_evaluate_dg` (befores[p], the value before an element
    starting at starts[p]: u0 at t0; with ``compiled``, the lowered ODE the elements solve,
    its defect test, else its jump test), cG(q), q >= 2, with ``compiled`` by
    :func:`_evaluate_cg`, other methods by their element polynomials.
    Every reader of a mono-adaptive solution's elements (in memory, stored, streamed in
    chunks) evaluates through here."""
    if method.family == "cG" and _reads_f(method) and compiled is not None:
        with first_use(_evaluate_cg, "cG(q)'s dense values", 6):
            _evaluate_cg(t_start, t_end, values, method.nodes, method.barycentric_weights,
                         compiled.rhs.address, compiled.jacobian.address, compiled.indptr,
                         compiled.indices, compiled.p, _defect_check(method.family, method.q),
                         DEFECT_THETA, times, out)
    elif method.family == "dG" and method.q > 0:
        nodes0, bary0 = _collocation_nodes(method.family, method.q)
        none = np.empty(0, dtype=np.int64)
        rhs, jacobian, indptr, indices, p, theta = (
            (0, 0, none, none, np.empty(0), DENSE_THETA) if compiled is None
            else (compiled.rhs.address, compiled.jacobian.address, compiled.indptr,
                  compiled.indices, compiled.p, DEFECT_THETA))
        with first_use(_evaluate_dg, "dG(q)'s dense values", 2):
            _evaluate_dg(t_start, t_end, values, np.asarray(starts, dtype=float),
                         np.asarray(befores, dtype=float).reshape(len(starts), values.shape[2]),
                         method.nodes, method.barycentric_weights, nodes0, bary0,
                         method.left_value, rhs, jacobian, indptr, indices, p,
                         _defect_check(method.family, method.q), float(theta), times, out)
    else:
        _evaluate_shared(t_start, t_end, values, method.nodes, method.barycentric_weights,
                         times, out)


class Solution:
    """Piecewise polynomial solution U of a Galerkin method on [t0, T].

    Each element covers [t_n, t_n + k_n]; its polynomial of degree q takes the values
    ``values[n, j]`` at the method's nodes t_n + tau_j k_n and is evaluated exactly with the
    method's Lagrange basis. At an element boundary the value of the element to the left is
    returned (for dG the left limit U(t_n^-)). Mono-adaptive solutions share one partition
    (``values`` has shape (M, q+1, N)); multi-adaptive solutions give every component its own
    (see :meth:`multi_adaptive`).

    Attributes
    ----------
    t, y : sample times (M,) and values (N, M), ``number_of_samples`` equispaced points
    stats : dict of counters and timings
    method : the :class:`~dolfinode.methods.Method`
    success, status, message : how the solve ended, with scipy's ``solve_ivp`` conventions:
        status 0 when T was reached, 1 when a terminal event stopped it (a failed solve raises
        :class:`~dolfinode.SolverError`, whose status is -1)
    parameters : dict of the checked parameters the solve used (None for a solution that no
        solve made)
    model : the :class:`~dolfinode.modeling.ReducedModel` of a solve with automatic modeling,
        else None
    error_estimate : the :class:`~dolfinode.ErrorEstimate` of a goal-oriented solve
        (``solve(..., goal=...)``), else None
    """

    status = 0
    message = "The solver successfully reached the end of the integration interval."
    parameters = None
    model = None
    error_estimate = None
    #: Whether the solution holds its history (its elements): False for dense_output=False.
    dense = True
    #: Per event, the crossing times and the states there (arrays, as solve_ivp's); None
    #: without events=.
    t_events = y_events = None
    #: The branches of f's switches the solve took (:meth:`_set_branches`); None without.
    _branches = None

    @cached_property
    def ode(self):
        """The declaration as solved (its values at the solve; made on first read where the
        solve gave its maker: see ``makers``)."""
        return self._makers["ode"]()

    @cached_property
    def stats(self):
        """dict of counters and timings (made on first read where the solve gave its maker)."""
        return self._makers["stats"]()

    def __getstate__(self):
        # a deferred attribute is made now: its maker may hold what does not pickle
        if "_makers" in self.__dict__:
            self.ode, self.stats  # noqa: B018 (made now)
        state = self.__dict__.copy()
        state.pop("_makers", None)
        state.pop("_element_cache", None)
        if state.get("_rhs") is not None:  # (the kernels: lowered again where read; a None
            del state["_rhs"]                # set by the solve, elements of several models, kept)
        return state

    @property
    def _declaration(self):
        """What evaluation reads of the declaration (t0, T, N, u0): ``ode``, or before it is
        made the makers' "declared" (copying it cost a small solve 2-5 us)."""
        ode = self.__dict__.get("ode")
        if ode is None:
            ode = self._makers.get("declared")
        return self.ode if ode is None else ode

    @property
    def success(self):
        """True unless the solve failed (status -1), as ``solve_ivp``'s ``success``."""
        return self.status >= 0

    def __init__(self, ode, method, t_start, k, values, stats, number_of_samples, makers=None):
        """``makers``: {"ode": maker, "stats": maker} (``ode`` and ``stats`` then None), the
        two made by maker() on first read: a loop of many small solves often reads neither;
        with "declared": what evaluation reads of the declaration instead (t0, T, N, u0:
        the declaration the ode maker copies, or an object with these four, never changed)."""
        self.method, self.t_start, self.k, self.values = method, t_start, k, values
        self._component_ptr = None
        if makers is None:
            self.ode, self.stats = ode, stats
        else:
            self._makers = makers
        self._sample(number_of_samples)

    @classmethod
    def multi_adaptive(cls, ode, method, comp, t_start, t_end, values, stats, number_of_samples):
        """A solution whose component i has its own elements (comp == i), in any order
        (already grouped by component and in time, they are not sorted or copied)."""
        return cls.grouped(ode, method, *_group(ode.N, comp, t_start, t_end, values), stats,
                           number_of_samples)

    @classmethod
    def grouped(cls, ode, method, ptr, t_start, t_end, values, stats, number_of_samples):
        """A multi-adaptive solution whose component i owns the elements ptr[i]:ptr[i + 1],
        in time order (the arrays are kept, not copied)."""
        self = cls.__new__(cls)
        self.ode, self.method, self.stats = ode, method, stats
        self.t_start, self._t_end, self.values = t_start, t_end, values
        self.k = t_end - t_start
        self._component_ptr = ptr
        self._sample(number_of_samples)
        return self

    def _sample(self, samples):
        """Take ``samples`` equispaced samples t, y (or samples at the given times), made
        when first read (a small solve often wants only sol(T))."""
        if isinstance(samples, np.ndarray):
            self.__dict__["t"] = samples
        else:
            self._number_of_samples = samples

    @cached_property
    def t(self):
        """Sample times: np.linspace's values (t0 + i (T - t0)/(n - 1), the last T)."""
        declared = self._declaration
        return equispaced(declared.t0, declared.T, self._number_of_samples)

    @cached_property
    def y(self):
        """U at the sample times, shape (N, M)."""
        y = self._evaluate(self.t)
        # U(t0), as in _values, set directly: only the first sample can be t0
        declared = self._declaration
        if self.t[0] == declared.t0:
            y[:, 0] = declared.u0
        return y

    @property
    def multi(self):
        """Whether every component has its own partition."""
        return self._component_ptr is not None

    @property
    def states(self):
        return self.ode.states

    def __call__(self, t):
        """U(t): shape (N,) for a scalar t, (N, len(t)) for a sequence (scipy's convention),
        (N, *t.shape) for an array of any shape."""
        try:
            times = None if t is None else np.asarray(t, dtype=float)  # (None would be nan)
        except (TypeError, ValueError):
            times = None
        if times is None:
            raise TypeError(f"the solution is evaluated at real times t (a number or an array "
                            f"of them), got {t!r}")
        shape = times.shape
        times = times.ravel()
        ode = self._declaration
        outside = _first_outside(times, ode.t0, ode.T)
        if outside >= 0:
            bad = times[outside]
            what = " (not a number)" if math.isnan(bad) else ""
            raise ValueError(f"the solution is defined on [{ode.t0}, {ode.T}], "
                             f"got t = {bad:.17g}{what}")
        return self._values(times).reshape(ode.N, *shape)

    def _values(self, times, dense=True):
        """U at ``times`` in [t0, T], shape (N, len(times)) (the dense value unless ``dense``
        is False: :meth:`_evaluate`)."""
        if times.size == 1:  # (an (N, 1) result is C- as well as F-contiguous: numba would
            return self._values(np.repeat(times, 2), dense)[:, :1]  # compile the kernels again)
        # (solutions whose values are no element polynomials, as a modeling solution's, take
        # no ``dense``: asked for U's polynomials they raise)
        out = self._evaluate(times) if dense else self._evaluate(times, dense)
        declared = self._declaration
        _set_initial(times, declared.t0, declared.u0, out)
        return out

    def _evaluate(self, times, dense=True):
        """U at ``times`` in [t0, T], shape (N, len(times)), from the elements (the dense
        values that read f, of cG(q), mcG(q) and dG(q), unless ``dense`` is False)."""
        declared = self._declaration
        out = np.empty((times.size, declared.N)).T  # components contiguous at each time
        if self.multi:
            _evaluate_components(self._component_ptr, self.t_start, self._t_end, self.values,
                                 self.method.nodes, self.method.barycentric_weights,
                                 dense_rule(self.method), declared.t0, declared.u0, times, out)
            if dense and self._rhs is not None and _inside(times, declared.t0, declared.T):
                none = np.empty(0)
                self._correct(self._component_ptr, self.t_start, self._t_end, self.values,
                              none, none, np.empty((0, self.values.shape[1], declared.N)),
                              times, out)
        elif times.size and times[0] == declared.T and (times == declared.T).all():
            out[:] = self._end_values()[:, None]  # (the solve's own sol(T): no kernel)
        else:
            rhs = self._rhs if dense else None
            if rhs is not None and not _inside(times, declared.t0, declared.T):
                rhs = None
            self._evaluate_mono(times, rhs, out)
        return out

    def _correct(self, ptr, t_start, t_end, values, s_start, s_end, s_values, times, out):
        """mcG(q), q >= 2, mdG(q), q >= 1: the dense value inside the elements at ``times``
        in ``out``, which holds the element polynomials (:func:`_correct_multi`), where the
        solution reads f (``_rhs``, on the branches of :meth:`_set_branches`), with the
        element cache kept for this history."""
        if self._rhs is None:
            return
        history = (ptr, t_start, t_end, values, s_start, s_end, s_values)
        kept = self.__dict__.get("_element_cache")
        # (weak references: a joined or replaced history is not held by its cache)
        if kept is not None and all(r() is a or a.size == 0 and r() is None
                                    for r, a in zip(kept[0], history)):
            cache = kept[1]
        else:  # (a new history: the first call, a join, or a reader's elements around times)
            cache = element_cache(history, self._declaration.N)
            if cache[0].nbytes <= KEPT_CACHE:
                self.__dict__["_element_cache"] = (
                    [weakref.ref(a) if a.size else lambda: None for a in history], cache)
        on_branches(self._branches, times, out, self._rhs, lambda at, rhs, part: correct_multi(
            self.method, rhs, self._dependents, self._declaration, history, at, part, cache))

    def _evaluate_mono(self, times, rhs, out):
        """out = U at ``times`` from the shared partition, cG(q)'s dense value reading the
        lowered ODE ``rhs`` (:func:`evaluate_mono`; on the branches of
        :meth:`_set_branches`)."""
        declared = self._declaration  # (arrays, not lists: converting [u0] cost 1 us)
        starts, befores = self.__dict__.get("_restarts") or (np.array([declared.t0]),
                                                             declared.u0[np.newaxis])
        on_branches(self._branches, times, out, rhs, lambda at, branch, part: evaluate_mono(
            self.method, self.t_start, self.t_start + self.k, self.values, starts, befores,
            at, part, branch))

    def _set_branches(self, branches):
        """Record the branches of f's switches the solve took, (starts, sigmas) of
        :func:`branches_taken`: the dense values then read f on each element's branch
        (:func:`dense_rhs`, :func:`on_branches`)."""
        self._branches = branches
        self.__dict__.pop("_rhs", None)  # (read before by the solve, on the original f)
        self.__dict__.pop("_element_cache", None)

    @cached_property
    def _dependents(self):
        """(indptr, indices) of the components whose f_i reads each component (the
        transposed pattern of ``_rhs``'s), read by :func:`_correct_multi`."""
        return transposed(self._rhs.indptr, self._rhs.indices)

    @cached_property
    def _rhs(self):
        """The lowered ODE whose f the dense values of cG(q), mcG(q) and mono-adaptive dG(q)
        read (:func:`_evaluate_cg`, :func:`_correct_multi`, :func:`_evaluate_dg`; the smooth f
        of the branch parameters where the solve kept its branches, :func:`dense_rhs`), None
        for other methods and where the elements solve more than one model (a restart)."""
        if "_restarts" in self.__dict__ or not _reads_f(self.method):
            return None  # (the ode not read: a solution may make it on first read)
        return dense_rhs(self.method, self.ode, self._branches is not None)

    def _galerkin(self, times):
        """U at ``times`` in [t0, T] by the polynomials the solve solved, not the dense value
        that reads f (dG(q): the collocation polynomial under the jump test of
        :func:`_evaluate_dg`): where the crossings of events are located (a state switch or
        kink restarts the solve there, on U; the estimates read U's residual)."""
        if self._rhs is None:
            return self._evaluate(times)
        return self._evaluate(times, dense=False)

    def _end_values(self):
        """U at the end of the last element of a shared partition: its last nodal values,
        read without an evaluation (and from a file without reading the history)."""
        return self.values[-1, -1]

    def time_steps(self, component=None):
        """Element start times and lengths (t_n, k_n): of the shared partition, or of one
        component (index or state symbol) of a multi-adaptive solution."""
        if not self.multi:
            return self.t_start.copy(), self.k.copy()
        if component is None:
            raise ValueError("a multi-adaptive solution has one partition per component: "
                             "give the component (index or state)")
        if isinstance(component, (int, np.integer)):
            N = self.ode.N
            if not -N <= component < N:
                raise ValueError(f"component index {component} is out of range: {N} components, "
                                 f"indices 0..{N - 1} (or -{N}..-1)")
            i = int(component) % N
        else:
            i = self.ode.index(component)
        span = slice(self._component_ptr[i], self._component_ptr[i + 1])
        return self.t_start[span].copy(), self.k[span].copy()

    def elements(self):
        """Every component's elements in one layout for mono- and multi-adaptive solutions.

        Returns
        -------
        ptr : (N + 1,) int64; component i owns elements ptr[i]:ptr[i + 1], sorted in time
        t_start, t_end : (E,) element end points; consecutive elements of a component share
            their end point exactly
        values : (E, q + 1) nodal values at t_start + tau_j (t_end - t_start)
        """
        if self.multi:
            return (self._component_ptr.copy(), self.t_start.copy(), self._t_end.copy(),
                    self.values.copy())
        M, N = len(self.k), self.ode.N
        t_end = np.append(self.t_start[1:], self.t_start[-1] + self.k[-1])
        ptr = np.arange(N + 1, dtype=np.int64) * M
        values = np.ascontiguousarray(self.values.transpose(2, 0, 1)).reshape(N * M, -1)
        return ptr, np.tile(self.t_start, N), np.tile(t_end, N), values

    def __repr__(self):
        kind = "multi-adaptive" if self.multi else "mono-adaptive"
        return (f"Solution({self.method.name}, {kind}, N={self.ode.N}, elements={len(self.k)}, "
                f"t=[{self.ode.t0}, {self.ode.T}])")


@njit(cache=True)
def _merge_slabs(ptr, t_start, t_end, values, s_start, s_end, s_values, out_ptr, out_start,
                 out_end, out_values):
    """Component i's elements ptr[i]:ptr[i+1] and the shared slabs (both time-sorted), merged
    in time order into out_ptr[i]:out_ptr[i+1]."""
    for i in range(ptr.shape[0] - 1):
        e, n = ptr[i], 0
        for r in range(out_ptr[i], out_ptr[i + 1]):
            # (by entry, not slices: see io.history)
            if n < s_start.shape[0] and (e == ptr[i + 1] or s_start[n] < t_start[e]):
                out_start[r], out_end[r] = s_start[n], s_end[n]
                for j in range(values.shape[1]):
                    out_values[r, j] = s_values[n, j, i]
                n += 1
            else:
                out_start[r], out_end[r] = t_start[e], t_end[e]
                for j in range(values.shape[1]):
                    out_values[r, j] = values[e, j]
                e += 1


class _Made:
    """An element array of a solution that makes its elements on first read or write of one
    (``sol._make_elements()``): a :class:`MixedSolution` joins its parts (a reader that
    shifts them then shifts what U(t) reads), a :class:`PreparedSolution` copies them out of
    its solver's buffers."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, sol, owner=None):
        if sol is None:
            return self
        sol._make_elements()
        return sol.__dict__[self.name]

    def __set__(self, sol, value):
        sol._make_elements()
        sol.__dict__[self.name] = value


class MixedSolution(Solution):
    """A multi-adaptive solution whose synchronised slabs (every component on one interval,
    as the multi-adaptive loop solves them in one mono-adaptive slab) are kept as shared
    slabs, the other elements by component.

    ``sol(t)`` and the samples are evaluated from the two parts; the grouped elements of
    :meth:`Solution.grouped` (``t_start``, ``k``, ``values``, ``elements()``, the dual) are
    joined on first read, which then replaces the two parts. A history that is mostly
    synchronised slabs is stored with (q + 1) doubles per element instead of an element's
    component, end points and values, and joined without a sort by component.
    """

    multi = True
    t_start = _Made()
    k = _Made()
    values = _Made()
    _t_end = _Made()
    _component_ptr = _Made()

    def __init__(self, ode, method, elements, slabs, stats, number_of_samples):
        """``elements`` (ptr, t_start, t_end, values) grouped by component as
        :meth:`Solution.grouped` takes them; ``slabs`` (s_start, s_end, s_values (S, q + 1,
        N)), time-sorted; the two cover each component's [t0, T] without overlap."""
        self.ode, self.method, self.stats = ode, method, stats
        self._parts = (*elements, *slabs)
        self._sample(number_of_samples)

    def _make_elements(self):
        """Join the slabs into every component's elements (once)."""
        parts = self.__dict__.pop("_parts", None)
        if parts is None:
            return
        ptr, values, s_start = parts[0], parts[3], parts[4]
        N, S = self.ode.N, s_start.shape[0]
        merged = np.arange(N + 1) * S + ptr
        t_start, t_end = np.empty(merged[-1]), np.empty(merged[-1])
        joined = np.empty((merged[-1], values.shape[1]))
        _merge_slabs(*parts, merged, t_start, t_end, joined)
        self.__dict__.update(_component_ptr=merged, t_start=t_start, _t_end=t_end,
                             values=joined, k=t_end - t_start)

    def _evaluate(self, times, dense=True):
        parts = self.__dict__.get("_parts")
        if parts is None:  # joined (and maybe shifted by its reader)
            return super()._evaluate(times, dense)
        out = np.empty((times.size, self.ode.N)).T
        declared = self._declaration
        _evaluate_mixed(*parts, self.method.nodes, self.method.barycentric_weights,
                        dense_rule(self.method), declared.t0, declared.u0, times, out)
        if dense and self._rhs is not None and _inside(times, declared.t0, declared.T):
            self._correct(*parts, times, out)
        return out

    def __repr__(self):
        parts = self.__dict__.get("_parts")
        elements = (len(self.k) if parts is None
                    else len(parts[1]) + len(parts[4]) * self.ode.N)
        return (f"Solution({self.method.name}, multi-adaptive, N={self.ode.N}, "
                f"elements={elements}, t=[{self.ode.t0}, {self.ode.T}])")


class PreparedSolution(Solution):
    """The mono-adaptive Solution of a prepared call (:class:`dolfinode.Solver`): its elements
    are the used part of the solver's output buffers until :meth:`_make_elements` copies
    them, which reading ``t_start``, ``k`` or ``values``, pickling, and the solver's next
    call before it writes the buffers do: a loop of small solves that reads only ``sol(t)``
    of each result copies nothing (the copies were about a tenth of a trivial prepared
    solve). ``sol(t)`` reads the buffers while they are shared."""

    t_start = _Made()
    k = _Made()
    values = _Made()

    def __init__(self, method, times, X, n, number_of_samples, makers):
        """``times``: the buffer (2, capacity) of the element starts and lengths, ``X``:
        (capacity, q + 1, N) of the nodal values, of which the first ``n`` are the
        solution's; ``makers`` as :class:`Solution` takes them, with "parameters": the
        solver's checked parameters, copied when ``sol.parameters`` is read."""
        self.method, self._makers, self._shared = method, makers, (times, X, n)
        self._component_ptr = None
        self._sample(number_of_samples)

    def _make_elements(self):
        """Copy the elements out of the solver's buffers (once; before the solver writes
        them again)."""
        shared = self.__dict__.get("_shared")
        if shared is not None:
            times, X, n = shared
            times = times[:, :n].copy()
            self.__dict__.update(t_start=times[0], k=times[1], values=X[:n].copy())
            # (dropped once copied: a KeyboardInterrupt before leaves it to copy again)
            del self.__dict__["_shared"]

    @cached_property
    def _rhs(self):
        """The lowered ODE the dense value reads (:meth:`Solution._rhs`), the solver's for
        every solution of the same declaration solved (``makers["rhs"]``); unpickled, its
        own."""
        makers = self.__dict__.get("_makers")
        if makers is None or not _reads_f(self.method):
            return Solution._rhs.func(self)
        return makers["rhs"]()

    @cached_property
    def parameters(self):
        """The checked parameters of the solve: a copy of the solver's, made when read."""
        return dict(self._makers["parameters"])

    def __getstate__(self):
        self._make_elements()
        self.parameters  # noqa: B018 (made now: its maker does not pickle)
        return super().__getstate__()

    def _end_values(self):
        shared = self.__dict__.get("_shared")
        if shared is None:
            return super()._end_values()
        _, X, n = shared
        return X[n - 1, -1]

    def _evaluate_mono(self, times, rhs, out):
        shared = self.__dict__.get("_shared")
        if shared is None:
            return super()._evaluate_mono(times, rhs, out)
        buffer, X, n = shared  # (no restarts: a prepared call has no switches)
        t_start, declared = buffer[0, :n], self._declaration
        return evaluate_mono(self.method, t_start, t_start + buffer[1, :n], X[:n],
                             np.array([declared.t0]), declared.u0[np.newaxis], times, out, rhs)
