"""Solving a multi-adaptive slab: Gauss-Seidel sweeps over its elements, each update damped by
the element's own Newton matrix, and a simplified Newton step over the elements of a sub-slab
whose components are stiff or strongly coupled on its step (``group_newton``, with the band
matrices of :mod:`dolfinode.linalg.group`); the check that the windows stay converged after
the top level moved; the initial values of a slab rebuilt after a rejection; a synchronised
slab (every component on one step) solved as one mono-adaptive slab (``synchronised``)."""
import math

from numba import types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT, address
from dolfinode.counters import F_EVALUATIONS
from dolfinode.linalg.group import factor_group, group_order, solve_group
from dolfinode.methods.method import element_value
from dolfinode.solvers.slab import fixed_point
from dolfinode.timeslab.multi.moments import moments

#: Most Gauss-Seidel sweeps of one window per global iteration.
MAX_SWEEPS = 30
#: Sub-slabs coupled more strongly than this on their step are solved by Newton together.
COUPLING_LIMIT = 0.5


@helper(inline="always")
def damping(k, jii, A, D):
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


@linked(returns=types.float64, what="the multi-adaptive group Newton step", seconds=4)
@helper(**NO_REFCOUNT)
def group_newton(elist, n, fi, p, x, indptr, indices, position, jacobian, comp, prev, cptr,
                 celems, ea, eb, values, nodes, bary, qweights, Minv, stages, sptr, spts, dptr,
                 dcur, atol, rtol, states, out, cur, mom, fend, local, order, newton, factored,
                 factored_k, changed, computed, clock, small, counters):
    """One simplified Newton step for the elements elist[:n] of one sub-slab (same interval):
    (I - k A (x) J_gg) dX = r, with r the exact Galerkin residuals and J_gg the Jacobian at
    the slab start restricted to the group's components (in the global bandwidth ordering),
    solved by the stage transformation (``solve_group``); the other components of the
    sub-slab keep their values. ``newton`` = (real and complex band matrices, pivots, rhs,
    real and complex vectors, Z): the workspace, sized for the largest group.

    The factors stay in ``newton`` and serve the next groups with the same components and
    step (the sub-slabs of a window, and every sweep over them): ``factored`` holds their
    n, band widths and components, ``factored_k`` their step (n = 0: none; reset at every
    slab start). Records the update in ``computed`` and ``changed`` (see ``converge``).
    Returns the largest scaled increment (inf on failure)."""
    S = Minv.shape[0]
    nn = nodes.shape[0]
    first_stage = nn - S
    k = eb[elist[0]] - ea[elist[0]]
    group_order(elist, n, comp, position, order, local)
    reuse = factored[0] == n and factored_k[0] == k
    for r_ in range(n):
        if not reuse:
            break
        reuse = factored[3 + r_] == order[r_]
    if not reuse:
        factored[0] = 0
        kl, ku, info = factor_group(order, n, local, indptr, indices, jacobian, k, stages[2],
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
        counters[F_EVALUATIONS] += moments(fi, p, x, i, e, indptr, indices, cptr, celems, ea,
                                           eb, values, nodes, bary, qweights, sptr, spts, dptr,
                                           dcur, cur, states, out, mom, fend)
        for s_ in range(S):
            acc = 0.0
            for lm in range(S):
                acc += Minv[s_, lm] * mom[lm]
            rhs[s_ * n + local[i]] = xl + k * acc - values[e, first_stage + s_]
    solve_group(n, factored[1], factored[2], stages, newton)
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


@helper(inline="always")
def stale(e, i, indptr, indices, changed, computed):
    """Whether element e of component i must be recomputed: never computed, or i (its left
    value) or a component it reads changed since."""
    if computed[e] < 0 or changed[i] > computed[e]:
        return True
    for nz in range(indptr[i], indptr[i + 1]):
        if changed[indices[nz]] > computed[e]:
            return True
    return False


@linked
@helper(**NO_REFCOUNT)
def converge(starts, nranges, end, predict_first, iterate, limit, fi, p, x, indptr, indices,
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
    problem is stiff, is updated together by a simplified Newton step (``group_newton``).
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
                        if stale(ep, comp[ep], indptr, indices, changed, computed):
                            elist[n] = ep
                            n += 1
                    if n > 0:
                        d = max(d, group_newton(elist, n, fi, p, x, indptr, indices,
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
                    if not stale(ep, i, indptr, indices, changed, computed):
                        continue
                    xl = x[i] if prev[ep] < 0 else values[prev[ep], nn - 1]  # the left value
                    if first_stage == 1:
                        values[ep, 0] = xl
                    counters[F_EVALUATIONS] += moments(fi, p, x, i, ep, indptr, indices, cptr,
                                                       celems, ea, eb, values, nodes, bary,
                                                       qweights, sptr, spts, dptr, dcur, cur,
                                                       states, out, mom, fend)
                    for s in range(S):
                        acc = 0.0
                        for lm in range(S):
                            acc += Minv[s, lm] * mom[lm]
                        delta[s] = xl + k * acc - values[ep, first_stage + s]
                    if abs(k * jdiag[i]) > 1e-3:
                        damping(k, jdiag[i], A, D)
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


@linked
@helper(**NO_REFCOUNT)
def windows_settled(nroot, comp, values, saved, indptr, indices, jacobian, atol, rtol, x, K,
                    dtol, change, mark, frozen, fi, p, b, cptr, celems, uw, out, counters):
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
    x for the converged Galerkin solution on the same steps).

    The Jacobian at the slab start does not see a coupling that switches on inside the slab
    (a pulse 200 exp(-((a - 0.1) / 0.01)^2) in u_i' as a slow a nears 0.1: the windows read
    a's prediction, J_ia = 1e-12 at the start, and the slab was accepted with u_i missing
    the pulse, 10^4 x the tolerance). So where the estimate passes, the change is also
    measured at the slab end b: |f_i(U(b)) - f_i(U*(b))|, U* with the top level's values
    before its last sweeps (``saved``; ``uw``, a work vector of N, holds the state), for every
    window component reading a top-level one (two f_i evaluations each). (Against f_i at the
    end of i's last element when it was computed, the test also caught the top level's changes
    below the lazy sweeps' threshold, and on the stiff heat equation mcG(1) at 1e-6 took 1.9 x
    the slabs.)"""
    N = x.shape[0]
    nn = values.shape[1]
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
    for j in range(N):  # U(b): a component without elements (frozen) is x_j
        uw[j] = values[celems[cptr[j + 1] - 1], nn - 1] if cptr[j + 1] > cptr[j] else x[j]
    for i in range(N):
        if mark[i] == 1 or cptr[i + 1] == cptr[i]:
            continue
        reads = False
        for nz in range(indptr[i], indptr[i + 1]):
            if mark[indices[nz]] == 1 and change[indices[nz]] > 0.0:
                reads = True
                break
        if reads:
            fi(i, uw.ctypes, b, p.ctypes, out.ctypes)
            after = out[0]
            for nz in range(indptr[i], indptr[i + 1]):  # the top level before its sweeps
                j = indices[nz]
                if mark[j] == 1 and celems[cptr[j + 1] - 1] < nroot:
                    uw[j] = saved[celems[cptr[j + 1] - 1], nn - 1]
            fi(i, uw.ctypes, b, p.ctypes, out.ctypes)
            counters[F_EVALUATIONS] += 2
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                if mark[j] == 1:
                    uw[j] = values[celems[cptr[j + 1] - 1], nn - 1]
            if not K * abs(after - out[0]) <= dtol * (atol[i] + rtol * abs(x[i])):
                return False
    return True


@linked(returns=types.none, what="the multi-adaptive retry's guess", seconds=1)
@helper(**NO_REFCOUNT)
def guess_from(x, comp, ea, eb, values, cptr, celems, ocptr, ocelems, oea, oeb, ovalues, nodes,
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


@helper(**NO_REFCOUNT)
def synchronised(f, p, x, f0, t, k, A, b0, tau, atol, rtol, dtol, max_iter, guessed, comp, ne,
                 values, fend, X, F, G, w, fvec, counters):
    """Solve a slab whose ne = N elements all lie on [t, t + k] as one mono-adaptive slab:
    the stages X_s = x + k (b0_s f(x, t) + sum_m A_sm f(X_m, t + tau_m k)) by the mono loop's
    fixed-point iteration (:func:`dolfinode.solvers.slab.fixed_point`) with the whole
    system's f, from the elements' initial values (from X itself when ``guessed``:
    ``slab.guess_stages``); with every step equal the element
    equations xi = x_left + k M^{-1} m(xi) are these equations, so the solution is cG(q)'s
    or dG(q)'s, at the cost of the mono loop's f evaluations instead of one component
    kernel call, with its dependencies gathered, per component and node. ``f0`` = f(x, t),
    fvec, X, F, G, w work space. Writes the converged values and f_i at the end (``fend``)
    of every element; returns the iterations, or -1 when the iteration did not converge
    (the slab is then stiff for it). f evaluations are counted per component."""
    N = x.shape[0]
    S = A.shape[0]
    first_stage = values.shape[1] - S
    for e in range(ne if not guessed else 0):
        i = comp[e]
        for s in range(S):
            X[s * N + i] = values[e, first_stage + s]
    before = counters[F_EVALUATIONS]
    iters = fixed_point(f, p, x, f0, t, k, A, b0, tau, atol, rtol, dtol, max_iter, X, F, G, w,
                        counters)
    if iters >= 0:
        f(address(X, (S - 1) * N), t + k, address(p, 0), address(fvec, 0))
        counters[F_EVALUATIONS] += 1
        for e in range(ne):
            i = comp[e]
            if first_stage == 1:
                values[e, 0] = x[i]
            for s in range(S):
                values[e, first_stage + s] = X[s * N + i]
            fend[e] = fvec[i]
    counters[F_EVALUATIONS] = before + N * (counters[F_EVALUATIONS] - before)
    return iters
