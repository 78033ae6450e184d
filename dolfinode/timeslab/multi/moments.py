"""The moments of an element of the multi-adaptive loop: the integrals of f_i(U) against the
powers of the element's normalised time, by quadrature on every interval between the element
ends of the dependencies (exact for linear f), each dependency read from its own element
polynomial."""

from dolfinode.compile.jit import helper
from dolfinode.methods.method import element_value


@helper(inline="always")
def moments(fi, p, x, i, e, indptr, indices, cptr, celems, ea, eb, values, nodes, bary,
            qweights, sptr, spts, dptr, dcur, cur, states, out, mom, fend):
    """Moments m_l = int_0^1 f_i(U(tau)) tau^l dtau of element e by quadrature on every
    interval between breakpoints (exact for linear f); f_i at the end of e into fend[e] (the
    last node of the last interval is the element's end). Every dependency is one polynomial
    on each interval: its element there is found by a cursor from dcur that walks its
    elements in time order, and an element that is exactly the interval is read at its nodes;
    a frozen dependency (no element in the slab) is its constant value x_j. The values at all
    nodes of an interval go to the rows of ``states`` (row m: the state f_i reads at node m)
    before f_i is evaluated: written just before each evaluation, as the evaluation loads
    them, they stalled the pipeline at every node. (The reads are written out here, not in a
    helper: numba's reference counting of each array argument of a call cost more than the
    reads.) Returns the f evaluations."""
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
