"""Multi-adaptive time slabs: mcG(q) and mdG(q) with individual time steps per component.

A time slab [a, b] is built recursively from the components' desired steps k_i (DOLFIN's
``createTimeSlab``, Logg's MAG papers): the remaining components whose k_i >= theta max k_i
form a group that takes one element of the group's smallest step K (stretched to the end of
the enclosing interval when K >= beta times its length, so slabs end synchronised); the other
components fill [a, a + K] with sub-slabs built the same way. Elements live in flat arrays
(component, interval, previous element, nodal values), in creation order.

The Galerkin equations of every element, xi = x_left + k M^{-1} m with the moments
m_l = int f_i(U) tau^l, are solved by Gauss-Seidel sweeps over the elements in creation order.
The moments are integrated exactly (for linear f) by the method's quadrature on every interval
between the element ends of the dependencies, each dependency read from its own element
polynomial (interpolated from larger elements, the exact small elements inside a larger one):
sampling a large element only at its own nodes would alias the fast forcing of small ones and
lose the 2q / 2q + 1 nodal order. When plain sweeps do not converge the problem is treated
as stiff and each element update becomes one Newton step in its own stage values, with the
exact diagonal df_i/du_i from the sympy Jacobian (DOLFIN's diagonal damping, made exact).

After a slab, every element's residual gives an indicator as in :mod:`dolfinode.adaptivity`;
the slab is accepted when all are <= 1, and each component gets its own next step.
"""
import math

import numpy as np
from numba import njit, types

from dolfinode.compile.signatures import COMPONENT_TYPE
from dolfinode.timeslab.mono import BLOWUP, DEFAULT, DONE, FULL, NEWTON, NONCONVERGENCE, UNDERFLOW

# Indices into the integer counters (kept across calls by the driver).
SLABS, REJECTED, F_EVALUATIONS, JACOBIANS, ELEMENTS, ITERATIONS, STORED, FAILED_SOLVES, STIFF, \
    SUBSLABS = range(10)
NUM_COUNTERS = 10
# Indices into the float state: current time, and the elements a mono-adaptive method with
# each slab's smallest step would have needed (for the multi-adaptive efficiency index).
T_NOW, MONO_ELEMENTS = range(2)
# Integer and float options.
SOLVER, FIXED, MAX_ITER, IS_DG = range(4)
RTOL, T_END, KMAX, SAFETY, DTOL, ORDER, RESIDUAL_POWER, THETA, BETA = range(9)
_KMIN_RELATIVE = 1e-14


@njit(cache=True)
def _grow_float(array, size):
    if size <= array.shape[0]:
        return array
    bigger = np.empty((max(size, 2 * array.shape[0]),) + array.shape[1:])
    bigger[:array.shape[0]] = array
    return bigger


@njit(cache=True)
def _grow_int(array, size):
    if size <= array.shape[0]:
        return array
    bigger = np.empty(max(size, 2 * array.shape[0]), dtype=np.int64)
    bigger[:array.shape[0]] = array
    return bigger


@njit(cache=True)
def _partition(perm, offset, kdes, theta):
    """Move the components of perm[offset:] with k >= theta max k to the front; return the
    group's end and its smallest step (DOLFIN's ``Partition::update``)."""
    n = perm.shape[0]
    kmax = 0.0
    for r in range(offset, n):
        kmax = max(kmax, kdes[perm[r]])
    pivot = theta * kmax
    end = offset
    for r in range(offset, n):
        if kdes[perm[r]] >= pivot:
            tmp = perm[end]
            perm[end] = perm[r]
            perm[r] = tmp
            end += 1
    K = math.inf
    for r in range(offset, end):
        K = min(K, kdes[perm[r]])
    return end, K


@njit(cache=True)
def build_slab(a, T, kdes, theta, beta, comp, ea, eb, windows):
    """Build the time slab starting at a; returns (b, number of elements, number of sub-slabs,
    number of windows, comp, ea, eb, windows), the arrays grown as needed.

    Elements come in creation order (depth first), so the sub-slabs nested in each sub-slab of
    the top level form a contiguous range, a *window*, starting at ``windows[w]``."""
    n = kdes.shape[0]
    perm = np.arange(n)
    # frame stack: (end of its interval b1, end of its group, current time t)
    fb = np.empty(64)
    fend = np.empty(64, dtype=np.int64)
    ft = np.empty(64)
    ne = 0
    nsub = 0
    nwin = 0
    depth = 0
    offset, lo, hi = 0, a, T
    while True:
        # create a sub-slab on [lo, hi] for the components perm[offset:]
        end, K = _partition(perm, offset, kdes, theta)
        b1 = lo + K if K < beta * (hi - lo) else hi
        if depth == 1:
            windows = _grow_int(windows, nwin + 1)
            windows[nwin] = ne
            nwin += 1
        comp = _grow_int(comp, ne + end - offset)
        ea = _grow_float(ea, ne + end - offset)
        eb = _grow_float(eb, ne + end - offset)
        for r in range(offset, end):
            comp[ne] = perm[r]
            ea[ne] = lo
            eb[ne] = b1
            ne += 1
        nsub += 1
        if depth == fb.shape[0]:
            fb = _grow_float(fb, 2 * depth)
            fend = _grow_int(fend, 2 * depth)
            ft = _grow_float(ft, 2 * depth)
        fb[depth], fend[depth], ft[depth] = b1, end, lo
        depth += 1
        # find the innermost frame with components left to fill, popping finished frames
        while depth > 0:
            f = depth - 1
            if ft[f] < fb[f] and fend[f] < n:
                break
            depth -= 1
            if depth > 0:
                ft[depth - 1] = fb[f]
        if depth == 0:
            return fb[0], ne, nsub, nwin, comp, ea, eb, windows
        f = depth - 1
        offset, lo, hi = fend[f], ft[f], fb[f]


@njit(cache=True)
def _component_elements(comp, ne, n):
    """CSR (ptr, elements) of each component's elements in creation (= time) order, and each
    element's predecessor of the same component (-1 at the slab start)."""
    ptr = np.zeros(n + 1, dtype=np.int64)
    for e in range(ne):
        ptr[comp[e] + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    fill = ptr[:-1].copy()
    elements = np.empty(ne, dtype=np.int64)
    prev = np.empty(ne, dtype=np.int64)
    for e in range(ne):
        c = fill[comp[e]]
        elements[c] = e
        prev[e] = elements[c - 1] if c > ptr[comp[e]] else -1
        fill[comp[e]] += 1
    return ptr, elements, prev


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
def subintervals(ne, comp, indptr, indices, cptr, celems, ea, eb):
    """For every element, the breakpoints (its ends and the element ends of its dependencies
    inside it) that split it into intervals where the integrand is one polynomial; CSR."""
    ptr = np.zeros(ne + 1, dtype=np.int64)
    points = np.empty(2 * ne)
    buf = np.empty(16)
    for e in range(ne):
        i = comp[e]
        a, b = ea[e], eb[e]
        count = 0
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if j == i:
                continue
            for c in range(cptr[j], cptr[j + 1]):
                tb = eb[celems[c]]
                if a < tb < b:
                    if count == buf.shape[0]:
                        buf = _grow_float(buf, 2 * count)
                    buf[count] = tb
                    count += 1
        inner = np.unique(buf[:count])
        need = ptr[e] + inner.shape[0] + 2
        points = _grow_float(points, need)
        points[ptr[e]] = a
        n = 1
        for tb in inner:
            if tb - points[ptr[e] + n - 1] > 1e-12 * (b - a) and b - tb > 1e-12 * (b - a):
                points[ptr[e] + n] = tb
                n += 1
        points[ptr[e] + n] = b
        ptr[e + 1] = ptr[e] + n + 1
    return ptr, points


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
def _moments(fi, ji, p, i, e, slab_start, x0, indptr, indices, diag, cptr, celems, ea, eb,
             values, nodes, bary, qweights, sptr, spts, stiff, first_stage, uw, out, jrow, lam,
             mom, dmom):
    """Moments m_l = int_0^1 f_i(U(tau)) tau^l dtau of element e by quadrature on every
    interval between breakpoints (exact for linear f), and with ``stiff`` their derivatives
    dmom[l, s] with respect to the element's own stage values. Returns the f evaluations."""
    S = mom.shape[0]
    nn = nodes.shape[0]
    k = eb[e] - ea[e]
    mom[:] = 0.0
    if stiff:
        dmom[:, :] = 0.0
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
            if stiff and diag[i] >= 0:
                ji(i, uw.ctypes, tq, p.ctypes, jrow.ctypes)
                jii = jrow[diag[i]]
                power = 1.0
                for lm in range(S):
                    for s in range(S):
                        dmom[lm, s] += w * power * jii * lam[first_stage + s]
                    power *= tau
    return evaluations


@njit(cache=True)
def _solve_small(M, r):
    """Solve the small dense system M x = r in place (Gaussian elimination, partial pivoting)."""
    n = r.shape[0]
    for c in range(n):
        piv = c
        for row in range(c + 1, n):
            if abs(M[row, c]) > abs(M[piv, c]):
                piv = row
        if M[piv, c] == 0.0:
            return False
        if piv != c:
            for col in range(n):
                tmp = M[c, col]
                M[c, col] = M[piv, col]
                M[piv, col] = tmp
            tmp = r[c]
            r[c] = r[piv]
            r[piv] = tmp
        for row in range(c + 1, n):
            factor = M[row, c] / M[c, c]
            for col in range(c, n):
                M[row, col] -= factor * M[c, col]
            r[row] -= factor * r[c]
    for c in range(n - 1, -1, -1):
        acc = r[c]
        for col in range(c + 1, n):
            acc -= M[c, col] * r[col]
        r[c] = acc / M[c, c]
    return True


@njit(cache=True)
def _sweep(lo, hi, fi, ji, p, t, x, indptr, indices, diag, comp, prev, cptr, celems, ea, eb,
           values, nodes, bary, qweights, Minv, sptr, spts, stiff, atol, rtol, uw, out, jrow,
           lam, mom, dmom, M, r, counters):
    """One Gauss-Seidel sweep over elements lo..hi-1: each element's stage values from
    xi = x_left + k M^{-1} m(xi), with stiffness by one Newton step in its own stages
    (I - k M^{-1} dm/dxi) dxi = r. Returns the largest scaled increment (inf on failure)."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S  # 1 for cG (node 0 is the left value), 0 for dG
    d = 0.0
    for e in range(lo, hi):
        i = comp[e]
        k = eb[e] - ea[e]
        xl = x[i] if prev[e] < 0 else values[prev[e], nn - 1]  # the left value
        if first_stage == 1:
            values[e, 0] = xl
        counters[F_EVALUATIONS] += _moments(
            fi, ji, p, i, e, t, x, indptr, indices, diag, cptr, celems, ea, eb, values, nodes,
            bary, qweights, sptr, spts, stiff, first_stage, uw, out, jrow, lam, mom, dmom)
        for s in range(S):
            acc = 0.0
            for lm in range(S):
                acc += Minv[s, lm] * mom[lm]
            r[s] = xl + k * acc - values[e, first_stage + s]
        if stiff and diag[i] >= 0:
            for row in range(S):
                for col in range(S):
                    acc = 0.0
                    for lm in range(S):
                        acc += Minv[row, lm] * dmom[lm, col]
                    M[row, col] = (1.0 if row == col else 0.0) - k * acc
            counters[JACOBIANS] += 1
            if not _solve_small(M, r):
                return math.inf
        for s in range(S):
            values[e, first_stage + s] += r[s]
            scaled = abs(r[s]) / (atol[i] + rtol * abs(values[e, first_stage + s]))
            if not scaled <= d:
                d = scaled if math.isfinite(scaled) else math.inf
    return d


_f8 = types.float64[::1]
_i8 = types.int64[::1]
_SIGNATURE = types.int64(
    COMPONENT_TYPE, COMPONENT_TYPE, _f8,           # f_i, J_i, p
    _i8, _i8, _i8,                                 # indptr, indices, diagonal position in row
    types.float64[:, ::1], _f8, _f8, _f8,          # M^{-1}, nodes, quadrature weights, bary
    _f8, _f8,                                      # end_derivative, left_value
    _i8, _f8, _f8,                                 # iopts, fopts, atol
    _f8, _f8, _f8, _i8,                            # x, kdes, state, counters
    _i8, _f8, _f8, types.float64[:, ::1],          # out_comp, out_a, out_b, out_values
)


@njit(_SIGNATURE, cache=True, error_model="numpy")
def advance(fi, ji, p, indptr, indices, diag, Minv, nodes, qweights, bary, end_derivative,
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
    dmom = np.empty((S, S))
    lam = np.empty(nn)
    M = np.empty((S, S))
    r = np.empty(S)
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
        cptr, celems, prev = _component_elements(comp, ne, N)
        sptr, spts = subintervals(ne, comp, indptr, indices, cptr, celems, ea, eb)
        # initial guess: constant continuation of each component's left value
        for e in range(ne):
            for m in range(nn):
                values[e, m] = x[comp[e]]
        stiff = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        nroot = windows[0] if nwin > 0 else ne
        converged = False
        d_prev = math.inf
        growth = 0
        for it in range(max_iter):
            # the top-level elements once, then every window iterated to convergence in turn:
            # the fast components advance window by window as in single-rate time stepping
            d = _sweep(0, nroot, fi, ji, p, t, x, indptr, indices, diag, comp, prev, cptr, celems,
                       ea, eb, values, nodes, bary, qweights, Minv, sptr, spts, stiff, atol, rtol,
                       uw, out, jrow, lam, mom, dmom, M, r, counters)
            for w in range(nwin):
                hi = windows[w + 1] if w + 1 < nwin else ne
                for local in range(max_iter):
                    dl = _sweep(windows[w], hi, fi, ji, p, t, x, indptr, indices, diag, comp,
                                prev, cptr, celems, ea, eb, values, nodes, bary, qweights, Minv,
                                sptr, spts, stiff, atol, rtol, uw, out, jrow, lam, mom, dmom, M,
                                r, counters)
                    if local == 0:
                        d = max(d, dl)
                    # converge windows well below dtol, so that what the next global
                    # iteration measures is the top level's influence, not leftover error
                    if dl <= 0.1 * dtol or not math.isfinite(dl):
                        break
                if not dl <= 0.1 * dtol:
                    d = math.inf
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
                if emax[i] > 1.0:
                    accept = False
            for i in range(N):
                factor = safety * max(emax[i], 1e-10) ** (-1.0 / order)
                knew = kact[i] * min(5.0, max(0.2, factor))
                if accept:
                    knew = 2.0 * kdes[i] * knew / (kdes[i] + knew)  # harmonic-mean regulator
                elif emax[i] > 1.0:
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
            x[i] = values[celems[cptr[i + 1] - 1], nn - 1]
        t = b
        state[T_NOW] = t
