"""Solving one multi-adaptive slab: the Jacobian rows at its start, the initial guess of its
elements, the synchronised path (every component on one step, solved as one mono-adaptive
slab) and the element-wise Gauss-Seidel sweeps (:func:`.sweeps.converge`) with their
stopping test. :mod:`.loop` calls them in that order.
"""
import math

from numba import types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT
from dolfinode.counters import F_EVALUATIONS, ITERATIONS, JACOBIANS
from dolfinode.methods.method import lagrange_weights
from dolfinode.timeslab import ROUNDING
from dolfinode.timeslab.multi.sweeps import converge, synchronised, windows_settled


@helper(**NO_REFCOUNT)
def jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian, jdiag,
                  coupling, jacobian_time, counters):
    """The rows of df/du at (x, t) of the components active[:nactive] not evaluated there
    yet (``jacobian_time``), into the CSR values ``jacobian``, their diagonals ``jdiag`` and
    couplings sum_j!=i |J_ij| (``coupling``)."""
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


@helper(**NO_REFCOUNT)
def _extrapolation_weights(a, b, ea, eb, nodes, bary, weights, far):
    """weights[m, j] = l_j(tau_m), the Lagrange basis of an element on [a, b] at the nodes
    tau_m of [ea, eb] (continued past b), and far[m]: whether the node lies more than two
    element lengths past b (tau > 3: too far to extrapolate)."""
    for m in range(nodes.shape[0]):
        tau = (ea + nodes[m] * (eb - ea) - a) / (b - a)
        far[m] = tau > 3.0
        lagrange_weights(tau, nodes, bary, weights[m])


@helper(inline="always")
def _continued(i, e, a, b, ea, eb, m, x, last_values, nodes, bary, key, weights, far):
    """Node m of element e (on [ea_e, eb_e]) on component i's polynomial of [a, b]
    continued (x_i where that lies too far ahead); the extrapolation weights are made again
    only when (a, b, ea_e, eb_e) differs from ``key``: on a synchronised slab every
    component's guess shares them (the check here, not in a call per element: it took
    about half of such a guess)."""
    if not (key[0] == a and key[1] == b and key[2] == ea[e] and key[3] == eb[e]):
        key[0], key[1], key[2], key[3] = a, b, ea[e], eb[e]
        _extrapolation_weights(a, b, ea[e], eb[e], nodes, bary, weights, far)
    if far[m]:
        return x[i]
    value = 0.0
    for j in range(nodes.shape[0]):
        value += weights[m, j] * last_values[i, j]
    return value


@linked(returns=types.none, what="the multi-adaptive elements' guess", seconds=1)
@helper(**NO_REFCOUNT)
def initial_guess(ne, comp, ea, eb, prev, x, last_a, last_b, last_values, nodes, bary, key,
                  weights, far, values):
    """The nodal values of the slab's elements before the sweeps: each component's first
    element continues the component's last polynomial of the previous slab, on [last_a,
    last_b] (at most two element lengths ahead, else x_i); later elements start at x_i and
    continue their predecessor when the sweep reaches them."""
    nn = nodes.shape[0]
    for e in range(ne):
        i = comp[e]
        a, b = last_a[i], last_b[i]
        for m in range(nn):
            if prev[e] < 0 and b > a:
                values[e, m] = _continued(i, e, a, b, ea, eb, m, x, last_values, nodes, bary,
                                          key, weights, far)
            else:
                values[e, m] = x[i]


@helper(**NO_REFCOUNT)
def guess_stages(N, ea, eb, x, last_a, last_b, last_values, nodes, bary, key, weights, far,
                 X):
    """``initial_guess`` of a synchronised slab (element i: component i) written straight
    into its stage vector, X[s N + i] at the stage nodes (the last S of the element's), as
    :func:`.sweeps.synchronised` solves it: the same values without the elements' copy."""
    nn = nodes.shape[0]
    S = X.shape[0] // N
    for i in range(N):
        a, b = last_a[i], last_b[i]
        for s in range(S):
            m = nn - S + s
            if b > a:
                X[s * N + i] = _continued(i, i, a, b, ea, eb, m, x, last_values, nodes, bary,
                                          key, weights, far)
            else:
                X[s * N + i] = x[i]


@helper(**NO_REFCOUNT)
def solve_synchronised(f, p, x, f0, f0_time, t, b, A, b0, stage_nodes, atol, rtol, dtol, span,
                       fixed, max_iter, guessed, comp, ne, values, fend, X, F, G, w, fvec,
                       counters):
    """Solve the slab [t, b], every component on one element, as one mono-adaptive slab
    (:func:`.sweeps.synchronised`), with f0 = f(x, t) evaluated unless ``f0_time`` == t and
    the mono loop's stopping tolerance dtol min(1, (b - t)/span), not below the rounding
    level (its discrete errors add up over the slabs). Returns whether it converged and the
    time at which f0 holds f."""
    if f0_time != t:  # (NaN: not valid)
        f(x.ctypes, t, p.ctypes, f0.ctypes)
        counters[F_EVALUATIONS] += x.shape[0]
        f0_time = t
    dtol_k = dtol if fixed else max(dtol * min(1.0, (b - t) / span),
                                    min(dtol, ROUNDING / rtol))
    iterations = synchronised(f, p, x, f0, t, b - t, A, b0, stage_nodes, atol, rtol, dtol_k,
                              max_iter, guessed, comp, ne, values, fend, X, F, G, w, fvec,
                              counters)
    return iterations >= 0, f0_time


@linked(returns=types.Tuple((types.boolean, types.int64)),
        what="the multi-adaptive sweeps", seconds=8)
@helper(**NO_REFCOUNT)
def sweep_slab(max_iter, retry, windows, nwin, ne, nroot, top_start, limit, dtol, K, b, fi,
               p, x, indptr, indices, position, jacobian, comp, prev, cptr, celems, ea, eb,
               values, saved, nodes, bary, qweights, Minv, A, stages, sptr, spts, dptr, dcur,
               jdiag, coupling, stiff, atol, rtol, states, out, cur, mom, fend, D, delta,
               local, group_order, elist, newton, factored, factored_k, changed, computed,
               clock, top_change, mark, frozen, uw, counters):
    """Global iterations over the slab, at most ``max_iter``: every window iterated to
    convergence in turn (the fast components advance window by window as in single-rate
    time stepping), then the top-level elements (``converge``). One sweep would leave the
    slow components' own coupling to the next global iteration, which costs a sweep over
    every window. Converged when the largest increment d <= dtol (1 - rho), rho = d / d_prev
    the contraction (the distance to the fixed point is about d / (1 - rho)), when it
    stalls at rounding level, or when the top level's change leaves the windows settled
    (``windows_settled``, on the time left ``K``, with the slab end ``b`` and the work vector
    ``uw``); stops on a non-finite increment or
    three growing ones. Returns (converged, index of the last iteration)."""
    nn = nodes.shape[0]
    d_prev = math.inf
    growth = 0
    last_it = -1
    for it in range(max_iter):
        last_it = it
        predict = it == 0 and not retry
        d, resolved = converge(windows, nwin, ne, predict, True, limit, fi, p, x, indptr,
                               indices, position, jacobian, comp, prev, cptr, celems, ea, eb,
                               values, nodes, bary, qweights, Minv, A, stages, sptr, spts,
                               dptr, dcur, jdiag, coupling, stiff, atol, rtol, states, out,
                               cur, mom, fend, D, delta, local, group_order, elist, newton,
                               factored, factored_k, changed, computed, clock, counters)
        if not resolved:
            d = math.inf
        for e in range(nroot):
            for m in range(nn):
                saved[e, m] = values[e, m]
        top, settled = converge(top_start, 1, nroot, False, nwin > 0, limit, fi, p, x, indptr,
                                indices, position, jacobian, comp, prev, cptr, celems, ea, eb,
                                values, nodes, bary, qweights, Minv, A, stages, sptr, spts,
                                dptr, dcur, jdiag, coupling, stiff, atol, rtol, states, out,
                                cur, mom, fend, D, delta, local, group_order, elist, newton,
                                factored, factored_k, changed, computed, clock, counters)
        d = max(d, top)
        if nwin > 0 and not settled:
            d = math.inf
        counters[ITERATIONS] += 1
        rho = min(d / d_prev, 0.99) if it > 0 else 0.0
        if d <= dtol * (1.0 - rho) or (it >= 2 and d >= 0.5 * d_prev and d <= 1e-10):
            return True, last_it
        if nwin > 0 and resolved and math.isfinite(d) and windows_settled(
                nroot, comp, values, saved, indptr, indices, jacobian, atol, rtol, x, K, dtol,
                top_change, mark, frozen, fi, p, b, cptr, celems, uw, out, counters):
            return True, last_it
        if not math.isfinite(d):
            break
        growth = growth + 1 if d >= d_prev else 0
        if growth >= 3:
            break
        d_prev = d
    return False, last_it
