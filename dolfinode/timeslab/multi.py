"""Multi-adaptive time slabs: mcG(q) and mdG(q) with individual time steps per component.

Slabs are built by :mod:`dolfinode.timeslab.partition`. The Galerkin equations of every element, xi = x_left + k M^{-1} m with the moments
m_l = int f_i(U) tau^l, are solved by Gauss-Seidel sweeps over the elements in creation order.
The moments are integrated exactly (for linear f) by the method's quadrature on every interval
between the element ends of the dependencies, each dependency read from its own element
polynomial (interpolated from larger elements, the exact small elements inside a larger one):
sampling a large element only at its own nodes would alias the fast forcing of small ones and
lose the 2q / 2q + 1 nodal order. When plain sweeps do not converge the problem is treated as
stiff, and the elements of each sub-slab (one interval, several components) are updated
together by a simplified Newton step with the sparse sympy Jacobian restricted to them.

After a slab, every element's residual gives an indicator as in :mod:`dolfinode.adaptivity`;
the slab is accepted when all are <= ACCEPTANCE_MARGIN, and each component gets its own next
step.
"""
import math

import numpy as np
from numba import njit, types

from dolfinode.compile.signatures import COMPONENT_TYPE
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.timeslab import (
    BLOWUP,
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
    REJECTED,
    SLABS,
    STIFF,
    STORED,
    SUBSLABS,
    UNDERFLOW,
)
from dolfinode.timeslab.partition import build_slab, component_elements, subintervals

# Indices into the float state: current time, and the elements a mono-adaptive method with
# each slab's smallest step would have needed (for the multi-adaptive efficiency index).
T_NOW, MONO_ELEMENTS = range(2)
# Integer and float options.
SOLVER, FIXED, MAX_ITER, IS_DG, BAND_LOWER, BAND_UPPER = range(6)
RTOL, T_END, KMAX, SAFETY, DTOL, ORDER, RESIDUAL_POWER, THETA, BETA = range(9)
_KMIN_RELATIVE = 1e-14
#: A slab holds many elements of a fast component and one indicator above the margin rejects
#: them all; steps are still chosen for indicators of 1 (DOLFIN G1 accepted up to 2 TOL too).
ACCEPTANCE_MARGIN = 2.0


@njit(cache=True)
def _evaluate(values, e, tau, nodes, bary):
    """The element polynomial of e at tau in [0, 1] (barycentric Lagrange formula)."""
    num = 0.0
    den = 0.0
    for j in range(nodes.shape[0]):
        d = tau - nodes[j]
        if d == 0.0:
            return values[e, j]
        w = bary[j] / d
        num += w * values[e, j]
        den += w
    return num / den


@njit(cache=True)
def _value_at(j, t, a, x0, cptr, celems, ea, eb, values, nodes, bary):
    """u_j(t) inside the slab [a, ...]: x0 at the slab start, else from j's covering element."""
    lo = cptr[j]
    hi = cptr[j + 1] - 1
    if t <= a:
        return x0[j]
    # first element of j with end >= t
    while lo < hi:
        mid = (lo + hi) // 2
        if eb[celems[mid]] >= t:
            hi = mid
        else:
            lo = mid + 1
    e = celems[lo]
    tau = (t - ea[e]) / (eb[e] - ea[e])
    return _evaluate(values, e, min(max(tau, 0.0), 1.0), nodes, bary)


@njit(cache=True)
def _node_rhs(fi, p, i, e, m, t, a, x0, indptr, indices, cptr, celems, ea, eb, values, nodes,
              bary, uw, out):
    """f_i at node m of element e (component i), dependencies read from their elements."""
    for nz in range(indptr[i], indptr[i + 1]):
        j = indices[nz]
        if j == i:
            uw[j] = values[e, m]
        else:
            uw[j] = _value_at(j, t, a, x0, cptr, celems, ea, eb, values, nodes, bary)
    fi(i, uw.ctypes, t, p.ctypes, out.ctypes)
    return out[0]


@njit(cache=True)
def _basis(tau, nodes, bary, lam):
    """Lagrange basis values l_j(tau) into lam."""
    hit = -1
    den = 0.0
    for j in range(nodes.shape[0]):
        d = tau - nodes[j]
        if d == 0.0:
            hit = j
            break
        lam[j] = bary[j] / d
        den += lam[j]
    for j in range(nodes.shape[0]):
        if hit >= 0:
            lam[j] = 1.0 if j == hit else 0.0
        else:
            lam[j] /= den


@njit(cache=True)
def _moments(fi, p, i, e, slab_start, x0, indptr, indices, cptr, celems, ea, eb, values, nodes,
             bary, qweights, sptr, spts, uw, out, lam, mom):
    """Moments m_l = int_0^1 f_i(U(tau)) tau^l dtau of element e by quadrature on every
    interval between breakpoints (exact for linear f). Returns the f evaluations."""
    S = mom.shape[0]
    nn = nodes.shape[0]
    k = eb[e] - ea[e]
    mom[:] = 0.0
    evaluations = 0
    for sub in range(sptr[e], sptr[e + 1] - 1):
        s0 = spts[sub]
        h = spts[sub + 1] - s0
        for m in range(nn):
            tq = s0 + nodes[m] * h
            tau = min(max((tq - ea[e]) / k, 0.0), 1.0)
            _basis(tau, nodes, bary, lam)
            own = 0.0
            for n in range(nn):
                own += lam[n] * values[e, n]
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                uw[j] = own if j == i else _value_at(j, tq, slab_start, x0, cptr, celems, ea, eb,
                                                     values, nodes, bary)
            fi(i, uw.ctypes, tq, p.ctypes, out.ctypes)
            evaluations += 1
            w = qweights[m] * h / k
            power = 1.0
            for lm in range(S):
                mom[lm] += w * power * out[0]
                power *= tau
    return evaluations


@njit(cache=True)
def _group_newton(e0, e1, fi, ji, p, t, x, indptr, indices, position, comp, prev, cptr, celems,
                  ea, eb, values, nodes, bary, qweights, Minv, A, sptr, spts, atol, rtol, uw, out,
                  jrow, lam, mom, local, order, ab_ws, rhs, ipiv, counters):
    """One simplified Newton step for the elements e0..e1-1 of one sub-slab (same interval):
    (I - k A (x) J_gg) dX = r, with r the exact Galerkin residuals and J_gg the sparse Jacobian
    restricted to the group's components at the sub-slab start, in band storage (components
    in the global bandwidth ordering). Returns the largest scaled increment (inf on failure)."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S
    n = e1 - e0
    k = eb[e0] - ea[e0]
    ta = ea[e0]
    # the group's components in bandwidth order: local[i] = their row block
    for r_ in range(n):
        order[r_] = comp[e0 + r_]
    for a_ in range(1, n):  # insertion sort by global position (groups are small or sorted)
        c = order[a_]
        b_ = a_ - 1
        while b_ >= 0 and position[order[b_]] > position[c]:
            order[b_ + 1] = order[b_]
            b_ -= 1
        order[b_ + 1] = c
    for r_ in range(n):
        local[order[r_]] = r_
    kl = 0
    ku = 0
    for e in range(e0, e1):
        i = comp[e]
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] >= 0:
                kl = max(kl, local[i] - local[j])
                ku = max(ku, local[j] - local[i])
    klS = kl * S + S - 1
    kuS = ku * S + S - 1
    kv = klS + kuS
    ab = ab_ws[:n * S, :2 * klS + kuS + 1]  # the workspace fits: local bands <= global ones
    ab[:, :] = 0.0
    for e in range(e0, e1):
        i = comp[e]
        xl = x[i] if prev[e] < 0 else values[prev[e], nn - 1]
        if first_stage == 1:
            values[e, 0] = xl
        counters[F_EVALUATIONS] += _moments(fi, p, i, e, t, x, indptr, indices, cptr, celems, ea,
                                            eb, values, nodes, bary, qweights, sptr, spts, uw,
                                            out, lam, mom)
        row = local[i] * S
        for s_ in range(S):
            acc = 0.0
            for lm in range(S):
                acc += Minv[s_, lm] * mom[lm]
            rhs[row + s_] = xl + k * acc - values[e, first_stage + s_]
        # row i of df/du at the sub-slab start, restricted to the group
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            uw[j] = xl if j == i else _value_at(j, ta, t, x, cptr, celems, ea, eb, values, nodes,
                                                bary)
        ji(i, uw.ctypes, ta, p.ctypes, jrow.ctypes)
        counters[JACOBIANS] += 1
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] < 0:
                continue
            col = local[j] * S
            value = -k * jrow[nz - indptr[i]]
            for s_ in range(S):
                for m_ in range(S):
                    ab[col + m_, kv + row + s_ - col - m_] += value * A[s_, m_]
    for r_ in range(n * S):
        ab[r_, kv] += 1.0
    counters[FACTORIZATIONS] += 1
    d = math.inf
    if band_lu(ab, klS, kuS, ipiv) == 0:
        band_solve(ab, klS, kuS, ipiv, rhs)
        d = 0.0
        for e in range(e0, e1):
            i = comp[e]
            for s_ in range(S):
                delta = rhs[local[i] * S + s_]
                values[e, first_stage + s_] += delta
                scaled = abs(delta) / (atol[i] + rtol * abs(values[e, first_stage + s_]))
                if not scaled <= d:
                    d = scaled if math.isfinite(scaled) else math.inf
    for r_ in range(n):
        local[order[r_]] = -1
    return d


@njit(cache=True)
def _sweep(lo, hi, fi, ji, p, t, x, indptr, indices, position, comp, prev, cptr, celems, ea, eb,
           values, nodes, bary, qweights, Minv, A, sptr, spts, stiff, atol, rtol, uw, out, jrow,
           lam, mom, local, order, ab_ws, rhs, ipiv, counters):
    """One Gauss-Seidel sweep over elements lo..hi-1: each element's stage values from the
    fixed point xi = x_left + k M^{-1} m(xi) or, when stiff, each sub-slab's elements together
    by a simplified Newton step (see ``_group_newton``). Returns the largest scaled increment
    (inf on failure)."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S  # 1 for cG (node 0 is the left value), 0 for dG
    d = 0.0
    e = lo
    while e < hi:
        if stiff:
            e1 = e + 1
            while e1 < hi and ea[e1] == ea[e] and eb[e1] == eb[e]:
                e1 += 1
            d = max(d, _group_newton(e, e1, fi, ji, p, t, x, indptr, indices, position, comp,
                                     prev, cptr, celems, ea, eb, values, nodes, bary, qweights,
                                     Minv, A, sptr, spts, atol, rtol, uw, out, jrow, lam, mom,
                                     local, order, ab_ws, rhs, ipiv, counters))
            e = e1
            continue
        i = comp[e]
        k = eb[e] - ea[e]
        xl = x[i] if prev[e] < 0 else values[prev[e], nn - 1]  # the left value
        if first_stage == 1:
            values[e, 0] = xl
        counters[F_EVALUATIONS] += _moments(fi, p, i, e, t, x, indptr, indices, cptr, celems, ea,
                                            eb, values, nodes, bary, qweights, sptr, spts, uw,
                                            out, lam, mom)
        for s in range(S):
            acc = 0.0
            for lm in range(S):
                acc += Minv[s, lm] * mom[lm]
            delta = xl + k * acc - values[e, first_stage + s]
            values[e, first_stage + s] += delta
            scaled = abs(delta) / (atol[i] + rtol * abs(values[e, first_stage + s]))
            if not scaled <= d:
                d = scaled if math.isfinite(scaled) else math.inf
        e += 1
    return d


_f8 = types.float64[::1]
_i8 = types.int64[::1]
_SIGNATURE = types.int64(
    COMPONENT_TYPE, COMPONENT_TYPE, _f8,           # f_i, J_i, p
    _i8, _i8, _i8,                                 # indptr, indices, bandwidth position
    types.float64[:, ::1], types.float64[:, ::1],  # M^{-1}, A
    _f8, _f8, _f8,                                 # nodes, quadrature weights, bary
    _f8, _f8,                                      # end_derivative, left_value
    _i8, _f8, _f8,                                 # iopts, fopts, atol
    _f8, _f8, _f8, _i8,                            # x, kdes, state, counters
    _i8, _f8, _f8, types.float64[:, ::1],          # out_comp, out_a, out_b, out_values
)


@njit(_SIGNATURE, cache=True, error_model="numpy")
def advance(fi, ji, p, indptr, indices, position, Minv, A, nodes, qweights, bary, end_derivative,
            left_value, iopts, fopts, atol, x, kdes, state, counters, out_comp, out_a, out_b,
            out_values):
    """Advance (x, t) slab by slab towards T, storing accepted elements; returns a status."""
    N = x.shape[0]
    S = Minv.shape[0]
    nn = nodes.shape[0]
    is_dg = iopts[IS_DG] == 1
    fixed = iopts[FIXED] == 1
    mode = iopts[SOLVER]
    max_iter = iopts[MAX_ITER]
    rtol, T, kmax, safety, dtol = fopts[RTOL], fopts[T_END], fopts[KMAX], fopts[SAFETY], fopts[DTOL]
    order, rpow, theta, beta = fopts[ORDER], fopts[RESIDUAL_POWER], fopts[THETA], fopts[BETA]

    comp = np.empty(4 * N, dtype=np.int64)
    ea = np.empty(4 * N)
    eb = np.empty(4 * N)
    windows = np.empty(16, dtype=np.int64)
    values = np.empty((4 * N, nn))
    mom = np.empty(S)
    lam = np.empty(nn)
    local = np.full(N, -1, dtype=np.int64)
    group_order = np.empty(N, dtype=np.int64)
    last_a = np.zeros(N)  # each component's last element of the previous slab
    last_b = np.zeros(N)
    last_values = np.empty((N, nn))
    # Newton workspace for sub-slab groups, grown to the largest group (band: the global one)
    band_width = 2 * (iopts[BAND_LOWER] + 1) * S + (iopts[BAND_UPPER] + 1) * S
    ab_ws = np.zeros((S, band_width))
    newton_rhs = np.empty(S)
    newton_ipiv = np.empty(S, dtype=np.int64)
    uw = x.copy()
    out = np.empty(1)
    jrow = np.empty(max(1, indices.shape[0]))
    emax = np.empty(N)
    kact = np.empty(N)
    counters[STORED] = 0
    capacity = out_a.shape[0]
    t = state[T_NOW]
    while True:
        if t >= T:
            return DONE
        for i in range(N):
            if not fixed:
                kdes[i] = min(kdes[i], kmax)
        b, ne, nsub, nwin, comp, ea, eb, windows = build_slab(t, T, kdes, theta, beta, comp, ea,
                                                              eb, windows)
        if ne > capacity - counters[STORED]:
            return FULL  # with nothing stored: the driver grows the buffers
        if b - t < _KMIN_RELATIVE * max(abs(t), abs(T) * 1e-6) and b < T:
            return UNDERFLOW
        if values.shape[0] < ne:
            values = np.empty((max(ne, 2 * values.shape[0]), nn))
        cptr, celems, prev = component_elements(comp, ne, N)
        sptr, spts = subintervals(ne, comp, indptr, indices, cptr, celems, ea, eb)
        largest = 1
        run = 1
        for e in range(1, ne):
            run = run + 1 if ea[e] == ea[e - 1] and eb[e] == eb[e - 1] else 1
            largest = max(largest, run)
        if largest * S > ab_ws.shape[0]:
            ab_ws = np.zeros((largest * S, band_width))
            newton_rhs = np.empty(largest * S)
            newton_ipiv = np.empty(largest * S, dtype=np.int64)
        # initial guess: the top-level elements continue each component's last polynomial of
        # the previous slab (smooth, slow components), the windows start constant (they are
        # solved forward in time)
        for e in range(ne):
            i = comp[e]
            for m in range(nn):
                values[e, m] = x[i]
                if e < (windows[0] if nwin > 0 else ne) and last_b[i] > last_a[i]:
                    tau = (ea[e] + nodes[m] * (eb[e] - ea[e]) - last_a[i]) / (last_b[i] - last_a[i])
                    if tau <= 3.0:  # extrapolate at most two element lengths ahead
                        values[e, m] = _evaluate(last_values, i, tau, nodes, bary)
        stiff = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        nroot = windows[0] if nwin > 0 else ne
        converged = False
        d_prev = math.inf
        growth = 0
        for it in range(max_iter):
            # every window iterated to convergence in turn (the fast components advance window
            # by window as in single-rate time stepping), then the top-level elements once
            d = 0.0
            for w in range(nwin):
                hi = windows[w + 1] if w + 1 < nwin else ne
                for sweeps in range(max_iter):
                    dl = _sweep(windows[w], hi, fi, ji, p, t, x, indptr, indices, position,
                                comp, prev, cptr, celems, ea, eb, values, nodes, bary, qweights,
                                Minv, A, sptr, spts, stiff, atol, rtol, uw, out, jrow, lam, mom,
                                local, group_order, ab_ws, newton_rhs, newton_ipiv,
                                counters)
                    if sweeps == 0:
                        d = max(d, dl)
                    # converge windows well below dtol, so that what the next global
                    # iteration measures is the top level's influence, not leftover error
                    if dl <= 0.1 * dtol or not math.isfinite(dl):
                        break
                if not dl <= 0.1 * dtol:
                    d = math.inf
            d = max(d, _sweep(0, nroot, fi, ji, p, t, x, indptr, indices, position, comp, prev,
                              cptr, celems, ea, eb, values, nodes, bary, qweights, Minv, A, sptr,
                              spts, stiff, atol, rtol, uw, out, jrow, lam, mom, local,
                              group_order, ab_ws, newton_rhs, newton_ipiv, counters))
            counters[ITERATIONS] += 1
            if d <= dtol or (it >= 2 and d >= 0.5 * d_prev and d <= 1e-10):
                converged = True
                break
            if not math.isfinite(d):
                break
            growth = growth + 1 if d >= d_prev else 0
            if growth >= 3:
                break
            d_prev = d
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
            if (b - t) * 0.25 < _KMIN_RELATIVE * max(abs(t), abs(T) * 1e-6):
                return NONCONVERGENCE
            continue
        # residual-based indicator of every element, per component maximum
        for i in range(N):
            emax[i] = 0.0
            kact[i] = 0.0
        blowup = False
        for e in range(ne):
            i = comp[e]
            k = eb[e] - ea[e]
            fend = _node_rhs(fi, p, i, e, nn - 1, eb[e], t, x, indptr, indices, cptr, celems, ea,
                             eb, values, nodes, bary, uw, out)
            counters[F_EVALUATIONS] += 1
            kdu = 0.0
            ul = 0.0
            for j in range(nn):
                kdu += end_derivative[j] * values[e, j]
                ul += left_value[j] * values[e, j]
            res = abs(kdu / k - fend)
            if is_dg:
                xl = x[i] if prev[e] < 0 else values[prev[e], nn - 1]
                res += abs(ul - xl) / k
            uend = values[e, nn - 1]
            if not (math.isfinite(uend) and math.isfinite(res)):
                blowup = True
            ind = k ** rpow * res / (atol[i] + rtol * abs(uend))
            emax[i] = max(emax[i], ind)
            kact[i] = max(kact[i], k)
        if blowup:
            if fixed:
                return BLOWUP
            for i in range(N):
                kdes[i] *= 0.25
            counters[REJECTED] += 1
            if (b - t) * 0.25 < _KMIN_RELATIVE * max(abs(t), abs(T) * 1e-6):
                return BLOWUP
            continue
        accept = True
        if not fixed:
            for i in range(N):
                if emax[i] > ACCEPTANCE_MARGIN:
                    accept = False
            for i in range(N):
                factor = safety * max(emax[i], 1e-10) ** (-1.0 / order)
                knew = kact[i] * min(5.0, max(0.2, factor))
                if accept:
                    knew = 2.0 * kdes[i] * knew / (kdes[i] + knew)  # harmonic-mean regulator
                elif emax[i] > ACCEPTANCE_MARGIN:
                    knew = min(knew, 0.9 * kact[i])
                else:
                    knew = kdes[i]
                kdes[i] = min(knew, kmax)
            # propagate small steps along strong dependencies: when f_i reacts to u_j within
            # one step of i (|df_i/du_j| k_i > 1), u_j must be resolved on i's scale. This is
            # DOLFIN's "poor man's dual weighting", restricted to the couplings that matter.
            for i in range(N):
                ji(i, x.ctypes, t, p.ctypes, jrow.ctypes)
                for nz in range(indptr[i], indptr[i + 1]):
                    j = indices[nz]
                    if j != i and abs(jrow[nz - indptr[i]]) * kdes[i] > 1.0:
                        kdes[j] = min(kdes[j], kdes[i])
        if not accept:
            counters[REJECTED] += 1
            continue
        # store the slab's elements and move to its end
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
        counters[SUBSLABS] += nsub
        for i in range(N):
            last = celems[cptr[i + 1] - 1]
            x[i] = values[last, nn - 1]
            last_a[i], last_b[i] = ea[last], eb[last]
            for m in range(nn):
                last_values[i, m] = values[last, m]
        t = b
        state[T_NOW] = t
