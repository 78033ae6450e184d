"""Multi-adaptive time slabs: mcG(q) and mdG(q) with individual time steps per component.

Slabs are built by :mod:`dolfinode.timeslab.partition`. The Galerkin equations of every
element, xi = x_left + k M^{-1} m with the moments m_l = int f_i(U) tau^l, are solved by
Gauss-Seidel sweeps, each element update damped by its own Newton matrix
(I - k J_ii A)^{-1} so that components stiff on their own step converge. The moments are
integrated exactly (for linear f) by the method's quadrature on every interval between the
element ends of the dependencies, each dependency read from its own element polynomial
(interpolated from larger elements, the exact small elements inside a larger one) through
cursors that walk its elements in time order: sampling a large element only at its own nodes
would alias the fast forcing of small ones and lose the 2q / 2q + 1 nodal order.

A slab is solved window by window (the sub-slabs nested in each top-level sub-slab, in time
order), then the top level, each to convergence; the global iteration stops when the
windows' response to the top level's change is below the discrete tolerance. The slab length
limit climbs on the measured cost per unit time (``_slab_limit``). When Gauss-Seidel fails
or converges too slowly the problem is treated as stiff, and the elements of each sub-slab
(one interval, several components) are updated together by a simplified Newton step with the
sparse sympy Jacobian at the slab start restricted to them, split by the eigenstructure of
the stage matrix into n x n band systems as in the mono-adaptive loop, and factored once for
all the sub-slabs and sweeps with the same components and step.

Components at rest are frozen (``_freeze``): no elements, the constant x_i for the others,
until they drift; then their constant element over the whole span is stored. After a slab the
frozen components that read an active one (all of them for non-autonomous f) are checked by
one evaluation of f_i at the slab end.

After a slab, every element's residual R = U' - f_i(U) at its end gives the local error
estimate of :mod:`dolfinode.adaptivity` (order q + 1 for mcG(q) and mdG(q)), filtered on each
sub-slab, (I - gamma k J_gg)^{-1} k R (``_filter_residuals``), and scaled by
atol + rtol max |U_i| over the slab; the slab is accepted when all are <= ACCEPTANCE_MARGIN,
and each component gets its own next step. Unfiltered, k |R| of a stiff component is
k |lambda| times its distance from the quasi-steady state: mcG(2) needs millions of slabs on
ROBER to 1e11 without the filter, about a thousand with it. DOLFIN's indicators k^q |R| (mcG) and
k^(q+1) |R| (mdG) depend on the unit of time: for q >= 2 and k < 1 they let fast components
step over their oscillation (mcG(3) on the stiff chain: 15x too long steps, errors
10^3-10^5 x tolerance), and mdG(1) reached 2600x the error of dG(1) on the template lattice.
"""
import math
from functools import cache

import numpy as np
from numba import njit, types

from dolfinode.compile.signatures import NO_REFCOUNT, component_kernel
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.methods.method import element_value, real_eigenvalues
from dolfinode.timeslab import (
    BLOWUP,
    CONSTRAINT,
    CONSTRAINT_CUT,
    DEFAULT,
    DONE,
    ELEMENTS,
    F_EVALUATIONS,
    FACTORIZATIONS,
    FAILED_SOLVES,
    FULL,
    ITERATIONS,
    JACOBIANS,
    NEWTON,
    NONCONVERGENCE,
    OUTSIDE,
    REJECTED,
    ROUNDING,
    SLABS,
    STIFF,
    STORED,
    SUBSLABS,
    UNDERFLOW,
    smallest_step,
)
from dolfinode.timeslab.partition import (
    build_slab,
    component_elements,
    dependency_structure,
    grow_float,
)

# Indices into the float state: current time, and the elements a mono-adaptive method with
# each slab's smallest step would have needed (for the multi-adaptive efficiency index).
T_NOW, MONO_ELEMENTS = range(2)
# Integer and float options.
SOLVER, FIXED, MAX_ITER, IS_DG, BAND_LOWER, BAND_UPPER, AUTONOMOUS = range(7)
RTOL, T_END, KMAX, SAFETY, DTOL, ORDER, THETA, BETA, GAMMA, SPAN = range(10)
#: A slab holds many elements of a fast component and one indicator above the margin rejects
#: them all; steps are still chosen for indicators of 1 (DOLFIN G1 accepted up to 2 TOL too).
ACCEPTANCE_MARGIN = 2.0
#: Most Gauss-Seidel sweeps of one window per global iteration.
MAX_SWEEPS = 30
#: Accepted slabs after a rejection during which the slab length limit does not grow.
REJECTION_HOLD = 4
#: Sub-slabs coupled more strongly than this on their step are solved by Newton together.
COUPLING_LIMIT = 0.5
#: Largest step ratio between strongly coupled components (see ``_grade``), and sweeps.
GRADING = 2.0
GRADING_SWEEPS = 4
#: Most passes of ``_propagate`` (ties passed on along chains of strong couplings).
PROPAGATION_SWEEPS = 8
#: A mutual coupling with |J_ij| >= ASYMMETRY^2 |J_ji| ties u_j's step to u_i's (``_propagate``).
ASYMMETRY = 10.0
#: A component whose change on a slab and drift over the rest of the interval stay below QUIET
#: times its error scale is frozen: a constant, with no elements, until it drifts (``_freeze``).
QUIET = 1e-3
#: The error filter of a sub-slab is skipped when it would change the estimates by at most
#: this fraction (gamma k ||J_gg||_inf).
FILTER_NEGLIGIBLE = 0.1
#: Factor by which the slab length limit climbs on the cost per unit time (``_slab_limit``).
SLAB_CLIMB = 1.5


@njit(cache=True, inline="always")
def _moments(fi, p, x, i, e, indptr, indices, cptr, celems, ea, eb, values, nodes, bary,
             qweights, sptr, spts, dptr, dcur, cur, states, out, mom, fend):
    """Moments m_l = int_0^1 f_i(U(tau)) tau^l dtau of element e by quadrature on every
    interval between breakpoints (exact for linear f); f_i at the end of e into fend[e] (the
    last node of the last interval is the element's end). Every dependency is one polynomial
    on each interval: its element there is found by a cursor from dcur that walks its
    elements in time order, and an element that is exactly the interval is read at its nodes;
    a frozen dependency (no element in the slab) is its constant value x_j. The values at all
    nodes of an interval go to the rows of ``states`` (row m: the state f_i reads at node m)
    before f_i is evaluated: written just before each evaluation, as the evaluation loads
    them, they stalled the pipeline at every node. (The reads are written out here, not in a helper: numba's
    reference counting of each array argument of a call cost more than the reads.) Returns
    the f evaluations."""
    S = mom.shape[0]
    nn = nodes.shape[0]
    k = eb[e] - ea[e]
    pp, op = p.ctypes, out.ctypes
    for lm in range(S):
        mom[lm] = 0.0
    row0 = indptr[i]
    degree = indptr[i + 1] - row0
    for r in range(degree):
        cur[r] = dcur[dptr[e] + r]
    whole = sptr[e + 1] - sptr[e] == 2  # no dependency breaks inside e
    for sub in range(sptr[e], sptr[e + 1] - 1):
        s0 = spts[sub]
        s1 = spts[sub + 1]
        h = s1 - s0
        mid = 0.5 * (s0 + s1)
        for r in range(degree):
            j = indices[row0 + r]
            if j == i:
                ej = e
            elif cptr[j] == cptr[j + 1]:
                for m in range(nn):
                    states[m, j] = x[j]
                continue
            else:
                c = cur[r]
                last = cptr[j + 1] - 1
                while c < last and eb[celems[c]] < mid:
                    c += 1
                cur[r] = c
                ej = celems[c]
            if ea[ej] == s0 and eb[ej] == s1:
                for m in range(nn):
                    states[m, j] = values[ej, m]
            else:
                for m in range(nn):
                    tj = (s0 + nodes[m] * h - ea[ej]) / (eb[ej] - ea[ej])
                    states[m, j] = element_value(values, ej, min(max(tj, 0.0), 1.0), nodes, bary)
        for m in range(nn):
            tq = s0 + nodes[m] * h
            tau = nodes[m] if whole else min(max((tq - ea[e]) / k, 0.0), 1.0)
            fi(i, states[m].ctypes, tq, pp, op)
            w = qweights[m] * h / k
            power = 1.0
            for lm in range(S):
                mom[lm] += w * power * out[0]
                power *= tau
    fend[e] = out[0]
    return (sptr[e + 1] - sptr[e] - 1) * nn


@njit(cache=True, inline="always")
def _damping(k, jii, A, D):
    """D = (I - k J_ii A)^{-1}: the element's own (diagonal) Newton matrix, which turns the
    Gauss-Seidel update into a local Newton step for components stiff on their own step."""
    S = A.shape[0]
    for r in range(S):
        for c in range(S):
            D[r, c] = (1.0 if r == c else 0.0) - k * jii * A[r, c]
    if S == 1:
        D[0, 0] = 1.0 / D[0, 0]
        return
    # Gauss-Jordan in place (small, diagonally dominant for k J_ii <= 0)
    for c in range(S):
        piv = D[c, c]
        D[c, c] = 1.0
        for cc in range(S):
            D[c, cc] /= piv
        for r in range(S):
            if r != c:
                factor = D[r, c]
                D[r, c] = 0.0
                for cc in range(S):
                    D[r, cc] -= factor * D[c, cc]


@njit(cache=True, inline="always")
def _group_order(elist, n, comp, position, order, local):
    """The components of the elements elist[:n] in the global bandwidth ordering into
    order[:n], and local[i] = their row block (the others stay -1)."""
    for r_ in range(n):
        order[r_] = comp[elist[r_]]
    for a_ in range(1, n):  # insertion sort by global position (groups are small or sorted)
        c = order[a_]
        b_ = a_ - 1
        while b_ >= 0 and position[order[b_]] > position[c]:
            order[b_ + 1] = order[b_]
            b_ -= 1
        order[b_ + 1] = c
    for r_ in range(n):
        local[order[r_]] = r_


@njit(cache=True, inline="always")
def _group_band(order, n, local, indptr, indices):
    """The band widths (kl, ku) of J_gg, the rows of the components order[:n] restricted to
    them, in their order (``local``, see ``_group_order``)."""
    kl = 0
    ku = 0
    for r_ in range(n):
        i = order[r_]
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] >= 0:
                kl = max(kl, local[i] - local[j])
                ku = max(ku, local[j] - local[i])
    return kl, ku


@njit(cache=True)
def _assemble_group(order, n, local, indptr, indices, jacobian, c, kl, ku, ab):
    """I - c J_gg into the band storage ab (n rows, real or complex c), J_gg as in
    ``_group_band``."""
    kv = kl + ku
    ab[:, :] = 0.0
    for r_ in range(n):
        i = order[r_]
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] >= 0:
                ab[local[j], kv + r_ - local[j]] -= c * jacobian[nz]
    for r_ in range(n):
        ab[r_, kv] += 1.0


@njit(cache=True)
def _factor_group(order, n, local, indptr, indices, jacobian, k, eigenvalues, newton,
                  counters):
    """Factor I - k lambda J_gg (``_group_band``) in band storage for every eigenvalue lambda
    of the stage matrix: the real ones into the real matrices of the workspace ``newton``,
    one complex matrix per complex pair (see ``_group_newton``). Returns the band widths and
    0, or band_lu's info of a singular matrix."""
    ab_real, ab_complex, ipiv = newton[0], newton[1], newton[2]
    kl, ku = _group_band(order, n, local, indptr, indices)
    width = 2 * kl + ku + 1  # the workspace fits: local bands <= global ones
    real = real_eigenvalues(eigenvalues)
    for j in range(real):
        counters[FACTORIZATIONS] += 1
        _assemble_group(order, n, local, indptr, indices, jacobian, k * eigenvalues[j].real,
                        kl, ku, ab_real[j, :n, :width])
        info = band_lu(ab_real[j, :n, :width], kl, ku, ipiv[j])
        if info != 0:
            return kl, ku, info
    for j in range(real, eigenvalues.shape[0]):
        counters[FACTORIZATIONS] += 1
        _assemble_group(order, n, local, indptr, indices, jacobian, k * eigenvalues[j], kl, ku,
                        ab_complex[j - real, :n, :width])
        info = band_lu(ab_complex[j - real, :n, :width], kl, ku, ipiv[j])
        if info != 0:
            return kl, ku, info
    return kl, ku, 0


@njit(cache=True, inline="always")
def _solve_group(n, kl, ku, stages, newton):
    """(I - k A (x) J_gg) dX = r for the stage-major residuals r = rhs[s n + r_] (in place),
    with the factors of ``_factor_group``: A = T B T^{-1} (``stages`` = (T, T^{-1}, the
    eigenvalues)) turns it into (I - k B (x) J_gg) Z = (T^{-1} (x) I) r, one n x n system per
    real eigenvalue and one complex per pair (whose two real blocks are the real and imaginary
    parts of one complex vector), and dX = (T (x) I) Z: RADAU5's transformation, as in the
    mono-adaptive loop. A group of n components with band b costs ~S/2 n x n band
    factorizations of O(n b^2) instead of one S n x S n of O(n (S b)^2)."""
    T, T_inverse, eigenvalues = stages
    ab_real, ab_complex, ipiv, rhs, z_real, z_complex, Z = newton
    S = T.shape[0]
    width = 2 * kl + ku + 1
    for j in range(S):  # Z = (T^{-1} (x) I) r
        for r_ in range(n):
            acc = 0.0
            for s_ in range(S):
                acc += T_inverse[j, s_] * rhs[s_ * n + r_]
            Z[j, r_] = acc
    real = real_eigenvalues(eigenvalues)
    for j in range(real):
        for r_ in range(n):
            z_real[r_] = Z[j, r_]
        band_solve(ab_real[j, :n, :width], kl, ku, ipiv[j], z_real[:n])
        for r_ in range(n):
            Z[j, r_] = z_real[r_]
    for c in range(eigenvalues.shape[0] - real):
        re = real + 2 * c
        for r_ in range(n):
            z_complex[r_] = complex(Z[re, r_], Z[re + 1, r_])
        band_solve(ab_complex[c, :n, :width], kl, ku, ipiv[real + c], z_complex[:n])
        for r_ in range(n):
            Z[re, r_] = z_complex[r_].real
            Z[re + 1, r_] = z_complex[r_].imag
    for s_ in range(S):  # dX = (T (x) I) Z
        for r_ in range(n):
            acc = 0.0
            for j in range(S):
                acc += T[s_, j] * Z[j, r_]
            rhs[s_ * n + r_] = acc


@njit(cache=True)
def _newton_workspace(real, pairs, S, rows, width):
    """The workspace of ``_group_newton`` for groups of up to ``rows`` components: (real band
    matrices, complex ones, pivots, rhs, real vector, complex vector, Z)."""
    return (np.zeros((real, rows, width)), np.zeros((pairs, rows, width), dtype=np.complex128),
            np.zeros((max(real, S), rows), dtype=np.int64), np.empty(S * rows), np.empty(rows),
            np.empty(rows, dtype=np.complex128), np.empty((S, rows)))


@njit(cache=True, **NO_REFCOUNT)
def _group_newton(elist, n, fi, p, x, indptr, indices, position, jacobian, comp, prev, cptr,
                  celems, ea, eb, values, nodes, bary, qweights, Minv, stages, sptr, spts, dptr,
                  dcur, atol, rtol, states, out, cur, mom, fend, local, order, newton, factored,
                  factored_k, changed, computed, clock, small, counters):
    """One simplified Newton step for the elements elist[:n] of one sub-slab (same interval):
    (I - k A (x) J_gg) dX = r, with r the exact Galerkin residuals and J_gg the Jacobian at
    the slab start restricted to the group's components (in the global bandwidth ordering),
    solved by the stage transformation (``_solve_group``); the other components of the
    sub-slab keep their values. ``newton`` = (real and complex band matrices, pivots, rhs,
    real and complex vectors, Z): the workspace, sized for the largest group.

    The factors stay in ``newton`` and serve the next groups with the same components and
    step (the sub-slabs of a window, and every sweep over them): ``factored`` holds their
    n, band widths and components, ``factored_k`` their step (n = 0: none; reset at every
    slab start). Records the update in ``computed`` and ``changed`` (see ``_converge``).
    Returns the largest scaled increment (inf on failure)."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S
    k = eb[elist[0]] - ea[elist[0]]
    _group_order(elist, n, comp, position, order, local)
    reuse = factored[0] == n and factored_k[0] == k
    for r_ in range(n):
        if not reuse:
            break
        reuse = factored[3 + r_] == order[r_]
    if not reuse:
        factored[0] = 0
        kl, ku, info = _factor_group(order, n, local, indptr, indices, jacobian, k, stages[2],
                                     newton, counters)
        if info != 0:
            for r_ in range(n):
                local[order[r_]] = -1
            return math.inf
        factored[0], factored[1], factored[2] = n, kl, ku
        factored_k[0] = k
        for r_ in range(n):
            factored[3 + r_] = order[r_]
    rhs = newton[3]
    for r_ in range(n):
        e = elist[r_]
        i = comp[e]
        xl = x[i] if prev[e] < 0 else values[prev[e], nn - 1]
        if first_stage == 1:
            values[e, 0] = xl
        counters[F_EVALUATIONS] += _moments(fi, p, x, i, e, indptr, indices, cptr, celems, ea,
                                            eb, values, nodes, bary, qweights, sptr, spts, dptr,
                                            dcur, cur, states, out, mom, fend)
        for s_ in range(S):
            acc = 0.0
            for lm in range(S):
                acc += Minv[s_, lm] * mom[lm]
            rhs[s_ * n + local[i]] = xl + k * acc - values[e, first_stage + s_]
    _solve_group(n, factored[1], factored[2], stages, newton)
    d = 0.0
    stamp = clock[0]
    clock[0] += 1  # changes after the step: a significant one makes its readers stale
    for r_ in range(n):
        e = elist[r_]
        i = comp[e]
        di = 0.0
        for s_ in range(S):
            delta = rhs[s_ * n + local[i]]
            values[e, first_stage + s_] += delta
            scaled = abs(delta) / (atol[i] + rtol * abs(values[e, first_stage + s_]))
            if not scaled <= di:
                di = scaled if math.isfinite(scaled) else math.inf
        computed[e] = stamp
        if di > small:
            changed[i] = clock[0]
        d = max(d, di)
    for r_ in range(n):
        local[order[r_]] = -1
    return d


@njit(cache=True, **NO_REFCOUNT)
def _filter_residuals(ne, comp, ea, eb, res, position, indptr, indices, jacobian, jdiag,
                      coupling, gamma, elist, order, local, newton, counters):
    """The local error estimates of the elements from their residuals k R(t_e) (``res``, in
    place): (I - gamma k J_gg)^{-1} k R on every sub-slab, its elements together (J_gg the
    Jacobian at the slab start restricted to their components), as in the
    mono-adaptive loop (:mod:`dolfinode.adaptivity`): k R on components that are not stiff
    on their step, the distance from the quasi-steady state on those that are. A sub-slab
    with gamma k max_i sum_j |J_ij| <= FILTER_NEGLIGIBLE (the filter would change its
    estimates by at most that fraction) or a singular matrix keeps its residuals. ``gamma``:
    [gamma] (the filter's one real eigenvalue, see ``_factor_group``)."""
    ab_real, ipiv, rhs = newton[0], newton[2], newton[3]
    g = gamma[0].real
    e = 0
    while e < ne:
        e1 = e + 1
        while e1 < ne and ea[e1] == ea[e] and eb[e1] == eb[e]:
            e1 += 1
        n = e1 - e
        k = eb[e] - ea[e]
        if n == 1:
            i = comp[e]
            if 1.0 - g * k * jdiag[i] != 0.0:
                res[e] /= 1.0 - g * k * jdiag[i]
            e = e1
            continue
        row_sum = 0.0
        for r in range(n):
            i = comp[e + r]
            row_sum = max(row_sum, abs(jdiag[i]) + coupling[i])
        if g * k * row_sum <= FILTER_NEGLIGIBLE:
            e = e1
            continue
        for r in range(n):
            elist[r] = e + r
        _group_order(elist, n, comp, position, order, local)
        kl, ku, info = _factor_group(order, n, local, indptr, indices, jacobian, k, gamma,
                                     newton, counters)
        if info == 0:
            for r in range(n):
                rhs[local[comp[e + r]]] = res[e + r]
            band_solve(ab_real[0, :n, :2 * kl + ku + 1], kl, ku, ipiv[0], rhs[:n])
            for r in range(n):
                res[e + r] = rhs[local[comp[e + r]]]
        for r in range(n):
            local[order[r]] = -1
        e = e1


@njit(cache=True, inline="always")
def _stale(e, i, indptr, indices, changed, computed):
    """Whether element e of component i must be recomputed: never computed, or i (its left
    value) or a component it reads changed since."""
    if computed[e] < 0 or changed[i] > computed[e]:
        return True
    for nz in range(indptr[i], indptr[i + 1]):
        if changed[indices[nz]] > computed[e]:
            return True
    return False


@njit(cache=True, **NO_REFCOUNT)
def _converge(starts, nranges, end, predict_first, iterate, limit, fi, p, x, indptr, indices,
              position, jacobian, comp, prev, cptr, celems, ea, eb, values, nodes, bary,
              qweights, Minv, A, stages, sptr, spts, dptr, dcur, jdiag, coupling, stiff, atol,
              rtol, states, out, cur, mom, fend, D, delta, local, order, elist, newton,
              factored, factored_k, changed, computed, clock, counters):
    """Gauss-Seidel sweeps over the element ranges starts[r]..starts[r+1] (the last up to
    end), one range after the other, each swept until its largest scaled increment is below
    ``limit`` (``iterate``) or once. A sweep goes sub-slab by sub-slab (elements on one
    interval): each element's stage values xi from the fixed point
    xi = x_left + k M^{-1} m(xi), damped by the element's own Newton matrix,
    xi <- xi + (I - k J_ii A)^{-1} (x_left + k M^{-1} m(xi) - xi); a sub-slab whose
    components are strongly coupled on its step (k sum_j!=i |J_ij| > COUPLING_LIMIT, where
    Gauss-Seidel would crawl, as for diffusion on long steps), or every sub-slab when the
    problem is stiff, is updated together by a simplified Newton step (``_group_newton``).
    With ``predict_first``, an element first continues its predecessor's polynomial.

    Sweeps are lazy: an element is recomputed only when its own last update, or a component
    it reads, changed by more than limit / 10 (scaled) since then (clock stamps: ``changed``
    per component, ``computed`` per element), so components far from any activity, most of
    a large slab's top level, cost one evaluation per slab. Returns the largest increment of
    the ranges' first sweeps and whether every range got below the limit."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S  # 1 for cG (node 0 is the left value), 0 for dG
    small = 0.1 * limit
    first = 0.0
    settled = True
    for r in range(nranges):
        lo = starts[r]
        hi = starts[r + 1] if r + 1 < nranges else end
        for sweep in range(MAX_SWEEPS if iterate else 1):
            predict = predict_first and sweep == 0
            d = 0.0
            e = lo
            while e < hi:
                e1 = e + 1
                while e1 < hi and ea[e1] == ea[e] and eb[e1] == eb[e]:
                    e1 += 1
                if predict:
                    for ep in range(e, e1):
                        pe = prev[ep]
                        if pe < 0:
                            continue
                        computed[ep] = -1
                        for m in range(nn):
                            tau = ((ea[ep] + nodes[m] * (eb[ep] - ea[ep]) - ea[pe])
                                   / (eb[pe] - ea[pe]))
                            values[ep, m] = element_value(values, pe, min(tau, 3.0), nodes, bary)
                k = eb[e] - ea[e]
                together = stiff
                if not stiff and e1 - e > 1:
                    for ep in range(e, e1):
                        if k * coupling[comp[ep]] > COUPLING_LIMIT:
                            together = True
                            break
                if together:
                    n = 0
                    for ep in range(e, e1):
                        if _stale(ep, comp[ep], indptr, indices, changed, computed):
                            elist[n] = ep
                            n += 1
                    if n > 0:
                        d = max(d, _group_newton(elist, n, fi, p, x, indptr, indices,
                                                 position, jacobian, comp, prev, cptr, celems,
                                                 ea, eb, values, nodes, bary, qweights, Minv,
                                                 stages, sptr, spts, dptr, dcur, atol, rtol,
                                                 states, out, cur, mom, fend, local, order,
                                                 newton, factored, factored_k, changed,
                                                 computed, clock, small, counters))
                    e = e1
                    continue
                for ep in range(e, e1):
                    i = comp[ep]
                    if not _stale(ep, i, indptr, indices, changed, computed):
                        continue
                    xl = x[i] if prev[ep] < 0 else values[prev[ep], nn - 1]  # the left value
                    if first_stage == 1:
                        values[ep, 0] = xl
                    counters[F_EVALUATIONS] += _moments(fi, p, x, i, ep, indptr, indices, cptr,
                                                        celems, ea, eb, values, nodes, bary,
                                                        qweights, sptr, spts, dptr, dcur, cur,
                                                        states, out, mom, fend)
                    for s in range(S):
                        acc = 0.0
                        for lm in range(S):
                            acc += Minv[s, lm] * mom[lm]
                        delta[s] = xl + k * acc - values[ep, first_stage + s]
                    if abs(k * jdiag[i]) > 1e-3:
                        _damping(k, jdiag[i], A, D)
                        for s in range(S):
                            acc = 0.0
                            for c in range(S):
                                acc += D[s, c] * delta[c]
                            mom[s] = acc
                        for s in range(S):
                            delta[s] = mom[s]
                    di = 0.0
                    for s in range(S):
                        values[ep, first_stage + s] += delta[s]
                        scaled = abs(delta[s]) / (atol[i] + rtol * abs(values[ep, first_stage + s]))
                        if not scaled <= di:
                            di = scaled if math.isfinite(scaled) else math.inf
                    # a significant change makes e itself (f_i may read u_i) and its readers
                    # stale
                    computed[ep] = clock[0]
                    if di > small:
                        clock[0] += 1
                        changed[i] = clock[0]
                    d = max(d, di)
                e = e1
            if sweep == 0:
                first = max(first, d)
            if d <= limit or not math.isfinite(d):
                break
        if not d <= limit:
            settled = False
    return first, settled


@njit(cache=True, **NO_REFCOUNT)
def _windows_settled(nroot, comp, values, saved, indptr, indices, jacobian, atol, rtol, x, K,
                     dtol, change, mark, frozen):
    """Whether the windows, converged against the top-level values before its last sweeps,
    stay within dtol of what the changed top level implies: a change du_j of a top-level
    component leaves the Galerkin residual sum_j |df_i/du_j| du_j per unit time in a window
    component u_i (Jacobian at the slab start). Saves the confirming sweeps over every
    window when the couplings are weak or the prediction of the top level was good.

    K is the remaining time T - t, not the slab's length: the top level's prediction lags
    the same way on every slab (by k u' for dG(0)'s constants), so these residuals add up
    over the slabs, and the computational error is bounded by the residual times the
    stability factor, about T - t for an undamped dual (mdG(0), non-normal stiff 2 x 2 of
    tests/stability: |df_i/du_j| = 270 against a slow rate 1, 66 x tolerance at T against 0.3
    x for the converged Galerkin solution on the same steps)."""
    N = x.shape[0]
    for i in range(N):
        mark[i] = 0
    for e in range(nroot):
        j = comp[e]
        mark[j] = 1
        change[j] = 0.0
        for m in range(values.shape[1]):
            change[j] = max(change[j], abs(values[e, m] - saved[e, m]))
    for i in range(N):
        if mark[i] == 1 or not math.isnan(frozen[i]):
            continue
        moved = 0.0
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if mark[j] == 1:
                moved += abs(jacobian[nz]) * change[j]
        if K * moved > dtol * (atol[i] + rtol * abs(x[i])):
            return False
    return True


@njit(cache=True, **NO_REFCOUNT)
def _guess_from(x, comp, ea, eb, values, cptr, celems, ocptr, ocelems, oea, oeb, ovalues, nodes,
                bary):
    """Initial values of a slab rebuilt after a rejection: every element of component i
    reads the rejected attempt's polynomials of i at its nodes (the same values where the
    element is unchanged, interpolation where it was refined; x_i where i was frozen)."""
    nn = nodes.shape[0]
    for i in range(cptr.shape[0] - 1):
        if ocptr[i] == ocptr[i + 1]:
            for r in range(cptr[i], cptr[i + 1]):
                values[celems[r], :] = x[i]
            continue
        c = ocptr[i]
        last = ocptr[i + 1] - 1
        for r in range(cptr[i], cptr[i + 1]):
            e = celems[r]
            for m in range(nn):
                tq = ea[e] + nodes[m] * (eb[e] - ea[e])
                while c < last and oeb[ocelems[c]] < tq:
                    c += 1
                eo = ocelems[c]
                tau = min(max((tq - oea[eo]) / (oeb[eo] - oea[eo]), 0.0), 1.0)
                values[e, m] = element_value(ovalues, eo, tau, nodes, bary)


@njit(cache=True, **NO_REFCOUNT)
def _propagate(kdes, rows, frozen, indptr, indices, jacobian):
    """Small steps travel along strong dependencies: k_j <= k_i when f_i reacts to u_j within
    one step of i (|J_ij| k_i > 1; DOLFIN's "poor man's dual weighting", restricted to the
    couplings that matter), or when the coupling is mutual and lopsided,
    |J_ij| >= ASYMMETRY^2 |J_ji| > 0: then an error d in u_j becomes sqrt(|J_ij / J_ji|) d in
    u_i over i's time scale (the scaling that makes the pair symmetric; omega for x' = v,
    v' = -omega^2 x), so u_j must be as resolved as u_i although its own indicator allows
    longer steps (mcG(1) on the stiff chain at tolerance 1e-7: positions 40x longer than
    their velocities, 2 10^4 x tolerance). Only the components ``rows`` and the active ones
    they read take part (frozen components have no step). Passes repeat until no step
    changes (at most PROPAGATION_SWEEPS): a step lowered by a tie is passed on along the
    next one (on POLLU, y4 -> y3 -> the species with J_ii = -4.4e11)."""
    for sweep in range(PROPAGATION_SWEEPS):
        moved = False
        for i in rows:
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                jij = abs(jacobian[nz])
                if j == i or jij == 0.0 or kdes[j] <= kdes[i] or not math.isnan(frozen[j]):
                    continue
                tie = jij * kdes[i] > 1.0
                if not tie:
                    for nz2 in range(indptr[j], indptr[j + 1]):
                        if indices[nz2] == i:
                            jji = abs(jacobian[nz2])
                            tie = 0.0 < jji and jij >= ASYMMETRY**2 * jji
                            break
                if tie:
                    kdes[j] = kdes[i]
                    moved = True
        if not moved:
            return


@njit(cache=True, **NO_REFCOUNT)
def _grade(kdes, rows, frozen, indptr, indices, jacobian):
    """Grade the steps along strong couplings, k_i <= max(GRADING k_j, 1 / |df_i/du_j|):
    a component that reacts to u_j within its own step may not step far beyond j, so that
    activity moving along the couplings (a front) meets steps that shrink towards it instead
    of one long step that the next slab rejects. Alternating sweeps over the components
    ``rows``, to a fixed point or GRADING_SWEEPS of them; frozen components constrain
    nothing."""
    n = rows.shape[0]
    for sweep in range(GRADING_SWEEPS):
        moved = False
        for r in range(n):
            i = rows[r] if sweep % 2 == 0 else rows[n - 1 - r]
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                if j == i or jacobian[nz] == 0.0 or not math.isnan(frozen[j]):
                    continue
                cap = max(GRADING * kdes[j], 1.0 / abs(jacobian[nz]))
                if kdes[i] > cap:
                    kdes[i] = cap
                    moved = True
        if not moved:
            return


@njit(cache=True, **NO_REFCOUNT)
def _store_constant(i, a, b, x, counters, out_comp, out_a, out_b, out_values):
    """Store the constant element U_i = x_i on [a, b]: component i was frozen there."""
    if b <= a:
        return
    n = counters[STORED]
    out_comp[n] = i
    out_a[n] = a
    out_b[n] = b
    out_values[n, :] = x[i]
    counters[STORED] += 1
    counters[ELEMENTS] += 1


@njit(cache=True, inline="always")
def _drift(change, rate, tau, mu):
    """|change| + |rate| tau (e^(mu tau) - 1) / (mu tau): a component's change on a slab and a
    bound of its drift over the time tau left, if it moves at ``rate`` now and its row of
    df/du has mu = J_ii + sum_j!=i |J_ij| (the row's bound of the logarithmic max-norm:
    rates of size r grow at most like e^(mu t) r). Without the growth factor u' = u from
    u = 1e-12 would be frozen for good."""
    if rate == 0.0:
        return abs(change)
    z = max(mu, 0.0) * tau
    growth = 1.0 if z < 1e-8 else (math.expm1(z) / z if z < 700.0 else math.inf)
    return abs(change) + abs(rate) * tau * growth


@njit(cache=True, **NO_REFCOUNT)
def _freeze(b, k, active, checked, indptr, indices, drift, atol, rtol, umax, x, frozen, kdes,
            last_a, last_b, quiet, uw, counters, out_comp, out_a, out_b, out_values):
    """Freeze and wake components at the end b of an accepted slab of length k, from the
    ``active`` ones and the frozen ones ``checked`` on it; returns whether any changed.

    Component i is quiet when its drift (``_drift``: its change on the slab, and a bound of
    its change on the rest of the interval from its present rate f_i(U(b))) is at most QUIET
    times atol + rtol max |U_i|. A frozen component that is no longer quiet wakes up (its
    constant element on [frozen since, b] is stored); an active one freezes when it and every
    component it reads are quiet, unless no component would be left active. (A frozen
    component that was not checked stays quiet: none of its inputs changed.)"""
    for lst in (active, checked):
        for i in lst:
            quiet[i] = drift[i] <= QUIET * (atol[i] + rtol * umax[i])
    changed = False
    awake = active.shape[0]
    for i in checked:
        if not quiet[i]:
            _store_constant(i, frozen[i], b, x, counters, out_comp, out_a, out_b, out_values)
            frozen[i] = math.nan
            last_b[i] = last_a[i]  # no polynomial to continue
            kdes[i] = k  # (graded against its active neighbours)
            awake += 1
            changed = True
    for sweep in range(2):  # count, then freeze when some component stays active
        count = 0
        for i in active:
            if not quiet[i]:
                continue
            reads_quiet = True
            for nz in range(indptr[i], indptr[i + 1]):
                if not quiet[indices[nz]]:
                    reads_quiet = False
                    break
            if reads_quiet:
                count += 1
                if sweep == 1:
                    frozen[i] = b
                    uw[i] = x[i]  # the value the others read (see ``advance``)
                    changed = True
        if count >= awake:
            break
    return changed


@njit(cache=True)
def _readers(indptr, indices, N):
    """The transpose of the dependency pattern, as CSR (rptr, readers): the components whose
    f_i reads u_j are readers[rptr[j]:rptr[j + 1]]."""
    rptr = np.zeros(N + 1, dtype=np.int64)
    for nz in range(indices.shape[0]):
        rptr[indices[nz] + 1] += 1
    for j in range(N):
        rptr[j + 1] += rptr[j]
    fill = rptr[:-1].copy()
    readers = np.empty(indices.shape[0], dtype=np.int64)
    for i in range(N):
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            readers[fill[j]] = i
            fill[j] += 1
    return rptr, readers


@njit(cache=True, **NO_REFCOUNT)
def _slab_limit(kslab, kmax, K, converged, nwin, cost, climb):
    """The next slab length limit. A slab with windows costs its top-level elements about
    once (lazy sweeps) and its window elements once per global iteration: a longer slab
    takes fewer top-level elements per unit time, but more global iterations and longer
    windows, whose sweeps converge more slowly. Without windows the limit grows. With them
    it climbs on the measured cost per unit time, ``cost`` (f evaluations of the slab's
    solve / K): by SLAB_CLIMB in the direction ``climb[1]`` (+1 longer, -1 shorter),
    turning when the cost rose above the last slab's, ``climb[0]``. (The former rule, grow
    at two global iterations or fewer and halve at four, let the windows of the
    multi-adaptive problems of the benchmark suite take 2-3 times the f evaluations.)
    Growth starts from the limit itself, not from K, which the top level's smallest desired
    step may keep below it."""
    if not converged:
        return 0.5 * K
    if nwin == 0:
        return min(kmax, 2.0 * max(kslab, K))
    if cost > climb[0]:
        climb[1] = -climb[1]
    climb[0] = cost
    if climb[1] > 0:
        return min(kmax, SLAB_CLIMB * max(kslab, K))
    return K / SLAB_CLIMB


_f8 = types.float64[::1]
_i8 = types.int64[::1]
_SIGNATURE = types.int64(
    types.intp, types.intp, _f8,                   # addresses of f_i and J_i, p
    _i8, _i8, _i8,                                 # indptr, indices, bandwidth position
    types.float64[:, ::1], types.float64[:, ::1],  # M^{-1}, A
    types.float64[:, ::1], types.float64[:, ::1],  # A = T B T^-1
    types.complex128[::1],                         # the eigenvalues of B
    _f8, _f8, _f8,                                 # nodes, quadrature weights, bary
    _f8,                                           # end_derivative
    _i8, _f8, _f8, _f8,                            # iopts, fopts, atol, floor
    _f8, _f8, _f8, _f8, _i8,                       # x, kdes, frozen, state, counters
    _i8, _f8, _f8, types.float64[:, ::1],          # out_comp, out_a, out_b, out_values
)


@njit(cache=True, **NO_REFCOUNT)
def _leaves_domain(ne, comp, values, floor, kdes, kact):
    """The first component with a nodal value below its floor (-atol_i for a component
    declared nonnegative, -inf for the others), or -1; the steps of all such components are
    cut to CONSTRAINT_CUT times their longest element of the slab."""
    first = -1
    for e in range(ne):
        i = comp[e]
        for m in range(values.shape[1]):
            if values[e, m] < floor[i]:
                kdes[i] = min(kdes[i], CONSTRAINT_CUT * kact[i])
                first = i if first < 0 else first
                break
    return first


@njit(cache=True, **NO_REFCOUNT)
def _project(ne, comp, values, floor, projected):
    """Set the nodal values of the nonnegative components in [floor, 0) to 0, marking those
    components in ``projected``."""
    for e in range(ne):
        i = comp[e]
        if floor[i] > -math.inf:
            for m in range(values.shape[1]):
                if values[e, m] < 0.0:
                    values[e, m] = 0.0
                    projected[i] = True


@cache
def method_tables(method):
    """The method's tables in the order :func:`advance` takes them (M^{-1}, A, T, T^{-1},
    eigenvalues, nodes, quadrature weights, barycentric weights, end derivative), as writable
    copies (numba types read-only arrays apart); made once per method, as advance only reads
    them."""
    m = method
    tables = (m.moment_inverse, m.A, m.stage_transform, m.stage_transform_inverse,
              m.stage_eigenvalues, m.nodes, m.quadrature_weights, m.barycentric_weights,
              m.end_derivative)
    return tuple(np.array(table) for table in tables)


@njit(_SIGNATURE, cache=True, error_model="numpy")
def advance(fi_address, ji_address, p, indptr, indices, position, Minv, A, transform,
            transform_inverse, eigenvalues, nodes, qweights, bary, end_derivative, iopts, fopts,
            atol, floor, x, kdes, frozen, state, counters, out_comp, out_a, out_b, out_values):
    """Advance (x, t) slab by slab towards T, storing accepted elements; returns a status.
    ``frozen[i]`` is the time since which component i is frozen (NaN: active). A slab on
    which a value leaves the declared domain is rejected (``_leaves_domain``); an accepted
    one is projected on it."""
    fi = component_kernel(fi_address)
    ji = component_kernel(ji_address)
    N = x.shape[0]
    S = Minv.shape[0]
    nn = nodes.shape[0]
    fixed = iopts[FIXED] == 1
    autonomous = iopts[AUTONOMOUS] == 1
    mode = iopts[SOLVER]
    max_iter = iopts[MAX_ITER]
    rtol, T, kmax, safety, dtol = fopts[RTOL], fopts[T_END], fopts[KMAX], fopts[SAFETY], fopts[DTOL]
    order, theta, beta = fopts[ORDER], fopts[THETA], fopts[BETA]
    gamma = np.full(1, fopts[GAMMA] + 0j)  # the error filter's stage eigenvalue
    stages = (transform, transform_inverse, eigenvalues)
    efloor = (safety / 5.0) ** order
    # sweeps stop a tenth below the discrete tolerance, but not below the rounding level
    # (fixed steps iterate to dtol = 1e-15 of |U| + 1: Gauss-Seidel stalls above 1e-16)
    sweep_limit = max(0.1 * dtol, ROUNDING / rtol)

    comp = np.empty(4 * N, dtype=np.int64)
    ea = np.empty(4 * N)
    eb = np.empty(4 * N)
    windows = np.empty(16, dtype=np.int64)
    values = np.empty((4 * N, nn))
    fend = np.empty(4 * N)  # f_i at each element's end
    resid = np.empty(4 * N)  # k R at each element's end, filtered
    mom = np.empty(S)
    delta = np.empty(S)
    D = np.empty((S, S))
    degree = 1
    for i in range(N):
        degree = max(degree, indptr[i + 1] - indptr[i])
    cur = np.empty(degree, dtype=np.int64)
    local = np.full(N, -1, dtype=np.int64)
    group_order = np.empty(N, dtype=np.int64)
    elist = np.empty(N, dtype=np.int64)
    changed = np.zeros(N, dtype=np.int64)  # clock stamps of the lazy sweeps (see _converge)
    computed = np.empty(4 * N, dtype=np.int64)
    clock = np.zeros(1, dtype=np.int64)
    last_a = np.zeros(N)  # each component's last element of the previous slab
    last_b = np.zeros(N)
    last_values = np.empty((N, nn))
    # Newton workspace for sub-slab groups (_group_newton), grown to the largest group (band:
    # the global one); at least one real matrix, which the error filter uses
    band_width = 2 * iopts[BAND_LOWER] + iopts[BAND_UPPER] + 1
    n_real = real_eigenvalues(eigenvalues)
    newton = _newton_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S, 1, band_width)
    factored = np.zeros(N + 3, dtype=np.int64)  # the factors in ``newton`` (_group_newton)
    factored_k = np.zeros(1)
    uw = x.copy()
    states = np.empty((nn, N))  # the states at an interval's nodes (``_moments``)
    out = np.empty(1)
    jrow = np.empty(max(1, indices.shape[0]))
    jacobian = np.empty(max(1, indices.shape[0]))  # df/du at the slab start (CSR values)
    jdiag = np.zeros(N)
    coupling = np.zeros(N)  # sum_j!=i |J_ij|
    jacobian_time = np.full(N, np.nan)  # when each row of ``jacobian`` was evaluated
    # the active (not frozen) components, rebuilt when that set changes (``regroup``), and
    # the frozen ones checked after a slab: per slab, the work stays proportional to the
    # active components and their frozen readers, not to N
    active = np.empty(N, dtype=np.int64)
    nactive = 0
    regroup = True
    checked = np.empty(N, dtype=np.int64)
    check_stamp = np.zeros(N, dtype=np.int64)
    check_round = 0
    rptr, readers = _readers(indptr, indices, N)
    drift = np.empty(N)  # change on the slab and bound of the drift until T (``_drift``)
    quiet = np.ones(N, dtype=np.bool_)  # (stays True for a frozen component until it wakes)
    kslab = kmax  # slab length limit, adapted to the cost per unit time (``_slab_limit``)
    hold = 0  # accepted slabs to go before the limit may grow again after a rejection
    climb = np.array([math.inf, 1.0])  # the last slab's cost per unit time, the direction
    emax = np.empty(N)
    kact = np.empty(N)
    umax = np.empty(N)
    saved = np.empty((N, nn))  # the top level's values before its sweeps
    top_start = np.zeros(1, dtype=np.int64)
    top_change = np.zeros(N)
    mark = np.zeros(N, dtype=np.int64)
    # the last rejected attempt, the initial guess of its retry
    retry = False
    oea = np.empty(0)
    oeb = np.empty(0)
    ovalues = np.empty((0, nn))
    ocptr = np.zeros(N + 1, dtype=np.int64)
    ocelems = np.empty(0, dtype=np.int64)
    outside = -1  # the component that left its domain on the last slab (rejected), or -1
    projected = np.zeros(N, dtype=np.bool_)
    counters[STORED] = 0
    capacity = out_a.shape[0]
    t = state[T_NOW]
    while True:
        if regroup:
            nactive = 0
            for i in range(N):
                if math.isnan(frozen[i]):
                    active[nactive] = i
                    nactive += 1
            regroup = False
        nfrozen = N - nactive
        if t >= T:
            if nfrozen > capacity - counters[STORED]:
                return FULL
            for i in range(N):
                if not math.isnan(frozen[i]):
                    _store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b,
                                    out_values)
                    frozen[i] = math.nan
            return DONE
        # the Jacobian at the slab start: its diagonal damps the element updates, its
        # couplings propagate small steps, and it is the Newton matrix of coupled sub-slabs
        factored[0] = 0
        for r in range(nactive):
            i = active[r]
            if jacobian_time[i] != t:
                ji(i, x.ctypes, t, p.ctypes, jrow.ctypes)
                jdiag[i] = 0.0
                coupling[i] = 0.0
                for nz in range(indptr[i], indptr[i + 1]):
                    jacobian[nz] = jrow[nz - indptr[i]]
                    if indices[nz] == i:
                        jdiag[i] = jrow[nz - indptr[i]]
                    else:
                        coupling[i] += abs(jrow[nz - indptr[i]])
                counters[JACOBIANS] += 1
                jacobian_time[i] = t
        kcap = 0.0  # the largest desired step
        for r in range(nactive):
            i = active[r]
            if not fixed:
                kdes[i] = min(kdes[i], kmax)
            kcap = max(kcap, kdes[i])
        b, ne, nsub, nwin, comp, ea, eb, windows = build_slab(t, T, kdes, active[:nactive], theta,
                                                              beta, kslab, comp, ea, eb, windows)
        if ne + nfrozen > capacity - counters[STORED]:
            # (room for the frozen components' elements too, stored when they wake up)
            return FULL  # with nothing stored: the driver grows the buffers
        if b - t < smallest_step(t, fopts[SPAN]) and b < T:
            return CONSTRAINT if outside >= 0 else UNDERFLOW
        if values.shape[0] < ne:
            values = np.empty((max(ne, 2 * values.shape[0]), nn))
            fend = np.empty(values.shape[0])
            resid = np.empty(values.shape[0])
            computed = np.empty(values.shape[0], dtype=np.int64)
        computed[:ne] = -1
        changed[:] = 0
        clock[0] = 0
        cptr, celems, prev = component_elements(comp, ne, N)
        sptr, spts, dptr, dcur = dependency_structure(ne, comp, indptr, indices, cptr, celems,
                                                      ea, eb)
        largest = 1
        run = 1
        for e in range(1, ne):
            run = run + 1 if ea[e] == ea[e - 1] and eb[e] == eb[e - 1] else 1
            largest = max(largest, run)
        if largest > newton[0].shape[1]:
            newton = _newton_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S,
                                       largest, band_width)
        # initial guess: each component's first element continues its last polynomial of the
        # previous slab (at most two element lengths ahead); later elements continue their
        # predecessor when the sweep reaches them
        # (after a rejection: the rejected attempt)
        if retry:
            _guess_from(x, comp, ea, eb, values, cptr, celems, ocptr, ocelems, oea, oeb, ovalues,
                        nodes, bary)
        else:
            for e in range(ne):
                i = comp[e]
                for m in range(nn):
                    values[e, m] = x[i]
                    if prev[e] < 0 and last_b[i] > last_a[i]:
                        tau = ((ea[e] + nodes[m] * (eb[e] - ea[e]) - last_a[i])
                               / (last_b[i] - last_a[i]))
                        if tau <= 3.0:
                            values[e, m] = element_value(last_values, i, tau, nodes, bary)
        stiff = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        nroot = windows[0] if nwin > 0 else ne
        if saved.shape[0] < nroot:
            saved = np.empty((max(nroot, 2 * saved.shape[0]), nn))
        converged = False
        d_prev = math.inf
        growth = 0
        f_attempt = counters[F_EVALUATIONS]
        for it in range(max_iter):
            # every window iterated to convergence in turn (the fast components advance window
            # by window as in single-rate time stepping), then the top-level elements: one
            # sweep would leave the slow components' own coupling to the next global
            # iteration, which costs a sweep over every window
            predict = it == 0 and not retry
            d, resolved = _converge(windows, nwin, ne, predict, True, sweep_limit, fi, p, x,
                                    indptr, indices, position, jacobian, comp, prev, cptr, celems,
                                    ea, eb, values, nodes, bary, qweights, Minv, A, stages, sptr,
                                    spts, dptr, dcur, jdiag, coupling, stiff, atol, rtol, states,
                                    out, cur, mom, fend, D, delta, local, group_order, elist,
                                    newton, factored, factored_k, changed, computed, clock,
                                    counters)
            if not resolved:
                d = math.inf
            for e in range(nroot):
                for m in range(nn):
                    saved[e, m] = values[e, m]
            top, settled = _converge(top_start, 1, nroot, False, nwin > 0, sweep_limit, fi, p,
                                     x, indptr, indices, position, jacobian, comp, prev, cptr,
                                     celems, ea, eb, values, nodes, bary, qweights, Minv, A,
                                     stages, sptr, spts, dptr, dcur, jdiag, coupling, stiff, atol,
                                     rtol, states, out, cur, mom, fend, D, delta, local,
                                     group_order, elist, newton, factored, factored_k, changed,
                                     computed, clock, counters)
            d = max(d, top)
            if nwin > 0 and not settled:
                d = math.inf
            counters[ITERATIONS] += 1
            # the distance to the fixed point is about d / (1 - rho) for the contraction
            # rho = d / d_prev: slowly contracting sweeps must get further below dtol
            rho = min(d / d_prev, 0.99) if it > 0 else 0.0
            if d <= dtol * (1.0 - rho) or (it >= 2 and d >= 0.5 * d_prev and d <= 1e-10):
                converged = True
                break
            if nwin > 0 and resolved and math.isfinite(d) and _windows_settled(
                    nroot, comp, values, saved, indptr, indices, jacobian, atol, rtol, x,
                    T - t, dtol, top_change, mark, frozen):
                converged = True
                break
            if not math.isfinite(d):
                break
            growth = growth + 1 if d >= d_prev else 0
            if growth >= 3:
                break
            d_prev = d
        if converged and mode == DEFAULT and it >= 7:
            counters[STIFF] = 1  # Gauss-Seidel converges too slowly: Newton from here on
        if not fixed:
            limit = _slab_limit(min(kslab, kcap), kmax, b - t, converged, nwin,
                                (counters[F_EVALUATIONS] - f_attempt) / (b - t), climb)
            # no growth for REJECTION_HOLD slabs after a rejection: growing straight back
            # into the length that was rejected costs another whole slab
            kslab = limit if hold == 0 else min(limit, max(kslab, b - t))
        if not converged:
            counters[FAILED_SOLVES] += 1
            if mode == DEFAULT and counters[STIFF] == 0:
                counters[STIFF] = 1  # Gauss-Seidel failed: treat the problem as stiff from here on
                continue
            if fixed:
                return NONCONVERGENCE
            # a shorter slab: only the steps longer than a quarter of it change
            for i in range(N):
                kdes[i] = min(kdes[i], 0.25 * (b - t))
            if (b - t) * 0.25 < smallest_step(t, fopts[SPAN]):
                return NONCONVERGENCE
            continue
        # residual-based indicator of every component: its largest local error estimate in
        # the slab, relative to atol + rtol max |U_i| over the slab (one step serves all of
        # the component's elements in the slab, so one scale: an element's own |U_i(t_e)|
        # would let the zero crossings of an oscillation dictate the step of every period)
        for r in range(nactive):
            i = active[r]
            emax[i] = 0.0
            kact[i] = 0.0
            umax[i] = 0.0
        blowup = False
        for e in range(ne):
            kdu = 0.0
            for j in range(nn):
                kdu += end_derivative[j] * values[e, j]
            resid[e] = kdu - (eb[e] - ea[e]) * fend[e]  # k R(t_e), f_i(U(t_e)) from the last sweep
        _filter_residuals(ne, comp, ea, eb, resid, position, indptr, indices, jacobian, jdiag,
                          coupling, gamma, elist, group_order, local, newton,
                          counters)  # (overwrites newton: ``factored`` is reset at every slab start)
        for e in range(ne):
            i = comp[e]
            k = eb[e] - ea[e]
            res = abs(resid[e])
            uend = values[e, nn - 1]
            if not (math.isfinite(uend) and math.isfinite(res)):
                blowup = True
            emax[i] = max(emax[i], res)
            umax[i] = max(umax[i], abs(uend))
            kact[i] = max(kact[i], k)
        # a frozen component is a constant on the slab: its residual is -f_i(U(b)), every
        # other component at its end value (uw holds x_j for the frozen ones). For autonomous
        # f only the frozen components that read an active one can have changed.
        nchecked = 0
        if nfrozen > 0:
            check_round += 1
            for r in range(nactive):
                j = active[r]
                uw[j] = values[celems[cptr[j + 1] - 1], nn - 1]
                if not autonomous:
                    continue
                for q in range(rptr[j], rptr[j + 1]):
                    i = readers[q]
                    if check_stamp[i] != check_round and not math.isnan(frozen[i]):
                        check_stamp[i] = check_round
                        checked[nchecked] = i
                        nchecked += 1
            if not autonomous:
                for i in range(N):
                    if not math.isnan(frozen[i]):
                        checked[nchecked] = i
                        nchecked += 1
            for c in range(nchecked):
                i = checked[c]
                fi(i, uw.ctypes, b, p.ctypes, out.ctypes)
                counters[F_EVALUATIONS] += 1
                if not math.isfinite(out[0]):
                    blowup = True
                emax[i] = (b - t) * abs(out[0])
                umax[i] = abs(x[i])
                kact[i] = b - t
                drift[i] = _drift(0.0, out[0], T - b, jdiag[i] + coupling[i])
        # (the components with elements, then the frozen ones checked)
        nseen = nactive + nchecked
        for r in range(nseen):
            i = active[r] if r < nactive else checked[r - nactive]
            emax[i] /= atol[i] + rtol * umax[i]
        for c in range(nchecked):  # frozen components that fail the slab take part in its retry
            i = checked[c]
            if not emax[i] <= ACCEPTANCE_MARGIN:
                _store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b,
                                out_values)
                frozen[i] = math.nan
                quiet[i] = False
                last_b[i] = last_a[i]
                regroup = True
        if blowup:
            retry = False
            if fixed:
                return BLOWUP
            for i in range(N):
                kdes[i] *= 0.25
            counters[REJECTED] += 1
            if (b - t) * 0.25 < smallest_step(t, fopts[SPAN]):
                return BLOWUP
            continue
        accept = True
        if not fixed:
            for r in range(nseen):
                i = active[r] if r < nactive else checked[r - nactive]
                if emax[i] > ACCEPTANCE_MARGIN:
                    accept = False
            for r in range(nseen):
                i = active[r] if r < nactive else checked[r - nactive]
                if not math.isnan(frozen[i]):
                    continue  # keeps its step until it wakes up
                # below efloor the factor is capped at 5 anyway: no pow() for idle components
                factor = (5.0 if emax[i] <= efloor else
                          safety * max(emax[i], 1e-10) ** (-1.0 / order))
                knew = kact[i] * min(5.0, max(0.2, factor))
                if accept:
                    knew = 2.0 * kdes[i] * knew / (kdes[i] + knew)  # harmonic-mean regulator
                elif emax[i] > ACCEPTANCE_MARGIN:
                    knew = min(knew, 0.9 * kact[i])
                else:
                    knew = kdes[i]
                kdes[i] = min(knew, kmax)
        outside = _leaves_domain(ne, comp, values, floor, kdes, kact)
        if outside >= 0:
            counters[OUTSIDE] = outside + 1
            if fixed:
                return CONSTRAINT
            accept = False
        if not fixed:
            _propagate(kdes, active[:nactive], frozen, indptr, indices, jacobian)
            _grade(kdes, active[:nactive], frozen, indptr, indices, jacobian)
        if not accept:
            counters[REJECTED] += 1
            # the steps chosen at the slab's start no longer fit its end (a front arrives):
            # retry the same slab with the failed components refined, from the rejected
            # values; a second rejection in a row shortens the slab
            hold = REJECTION_HOLD
            if retry:
                kslab = min(kslab, 0.5 * (b - t))
                retry = False
                continue
            kslab = min(kslab, b - t)
            oea = grow_float(oea, ne)
            oeb = grow_float(oeb, ne)
            if ovalues.shape[0] < ne:
                ovalues = np.empty((max(ne, 2 * ovalues.shape[0]), nn))
            oea[:ne] = ea[:ne]
            oeb[:ne] = eb[:ne]
            ovalues[:ne] = values[:ne]
            ocptr, ocelems = cptr, celems
            retry = True
            continue
        retry = False
        # store the slab's elements and move to its end
        _project(ne, comp, values, floor, projected)
        n0 = counters[STORED]
        for e in range(ne):
            out_comp[n0 + e] = comp[e]
            out_a[n0 + e] = ea[e]
            out_b[n0 + e] = eb[e]
            for m in range(nn):
                out_values[n0 + e, m] = values[e, m]
        counters[STORED] += ne
        counters[ELEMENTS] += ne
        kmin = math.inf
        for e in range(ne):
            kmin = min(kmin, eb[e] - ea[e])
        state[MONO_ELEMENTS] += (b - t) / kmin * N
        counters[SLABS] += 1
        hold = max(0, hold - 1)
        counters[SUBSLABS] += nsub
        for r in range(nactive):
            i = active[r]
            last = celems[cptr[i + 1] - 1]
            drift[i] = _drift(values[last, nn - 1] - x[i], fend[last], T - b,
                              jdiag[i] + coupling[i])
            x[i] = values[last, nn - 1]
            last_a[i], last_b[i] = ea[last], eb[last]
            for m in range(nn):
                last_values[i, m] = values[last, m]
        # a component projected to zero that f drives below its floor by T: f does not keep
        # it nonnegative, and the projected solution would stay at 0 where the exact one
        # turns negative
        for r in range(nactive):
            i = active[r]
            if projected[i]:
                projected[i] = False
                if x[i] == 0.0:
                    fi(i, x.ctypes, b, p.ctypes, out.ctypes)
                    counters[F_EVALUATIONS] += 1
                    if out[0] * (T - b) < floor[i]:
                        counters[OUTSIDE] = i + 1
                        state[T_NOW] = b
                        return CONSTRAINT
        if not fixed and b < T and _freeze(b, b - t, active[:nactive], checked[:nchecked],
                                           indptr, indices, drift, atol, rtol, umax, x, frozen,
                                           kdes, last_a, last_b, quiet, uw, counters, out_comp,
                                           out_a, out_b, out_values):
            regroup = True
        t = b
        state[T_NOW] = t
