"""Construction of multi-adaptive time slabs in flat arrays.

A time slab [a, b] is built recursively from the components' desired steps k_i (DOLFIN's
``createTimeSlab`` and ``Partition``): the remaining components whose
k_i >= theta min(max k_i, L) (L: the interval's length, at the top the slab length limit)
form a group that takes one element of the group's smallest step K (stretched to the end of
the enclosing interval when K >= beta times its length, so slabs end synchronised); the other
components fill [a, a + K] with sub-slabs built the same way. Elements live in flat arrays
(component, interval), in creation order, with per-component index arrays.
"""

import math

import numpy as np
from numba import types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT


@helper()
def grow_float(array, size):
    """``array`` (1-D), or a copy of it at least ``size`` long (twice as long at least)."""
    if size <= array.shape[0]:
        return array
    bigger = np.empty(max(size, 2 * array.shape[0]))
    for i in range(array.shape[0]):  # (a slice copy compiles its shape check and message)
        bigger[i] = array[i]
    return bigger


@helper()
def grow_int(array, size):
    """``array`` (1-D int64), or a copy of it at least ``size`` long (twice as long at
    least)."""
    if size <= array.shape[0]:
        return array
    bigger = np.empty(max(size, 2 * array.shape[0]), dtype=np.int64)
    for i in range(array.shape[0]):
        bigger[i] = array[i]
    return bigger


@helper()
def _partition(perm, offset, kdes, theta, length):
    """Move the components of perm[offset:] with k >= theta min(max k, length) to the front;
    return the group's end and its step: the group's smallest k, at most ``length`` (DOLFIN's
    ``Partition::update``, with the interval's length as a cap: every component that could
    step over most of the interval joins the group instead of taking sub-slabs of its own)."""
    n = perm.shape[0]
    kmax = 0.0
    for r in range(offset, n):
        kmax = max(kmax, kdes[perm[r]])
    kmax = min(kmax, length)
    pivot = theta * kmax
    end = offset
    for r in range(offset, n):
        if kdes[perm[r]] >= pivot:
            tmp = perm[end]
            perm[end] = perm[r]
            perm[r] = tmp
            end += 1
    K = kmax
    for r in range(offset, end):
        K = min(K, kdes[perm[r]])
    return end, K


@linked(returns=types.Tuple((types.float64, types.int64, types.int64, types.int64,
                             types.int64[::1], types.float64[::1], types.float64[::1],
                             types.int64[::1])),
        what="the multi-adaptive partition", seconds=1)
@helper()
def build_slab(a, T, kdes, active, theta, beta, kslab, comp, ea, eb, windows):
    """Build the time slab starting at a, at most kslab long, for the components ``active``
    (the others are frozen and get no element); returns (b, number of elements, number of
    sub-slabs, number of windows, comp, ea, eb, windows), the arrays grown as needed.

    Elements come in creation order (depth first), so the sub-slabs nested in each sub-slab of
    the top level form a contiguous range, a *window*, starting at ``windows[w]``."""
    n = active.shape[0]
    perm = active.copy()
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
        end, K = _partition(perm, offset, kdes, theta, min(hi - lo, kslab) if depth == 0
                            else hi - lo)
        b1 = lo + K if K < beta * (hi - lo) else hi
        if depth == 1:
            windows = grow_int(windows, nwin + 1)
            windows[nwin] = ne
            nwin += 1
        comp = grow_int(comp, ne + end - offset)
        ea = grow_float(ea, ne + end - offset)
        eb = grow_float(eb, ne + end - offset)
        for r in range(offset, end):
            comp[ne] = perm[r]
            ea[ne] = lo
            eb[ne] = b1
            ne += 1
        nsub += 1
        if depth == fb.shape[0]:
            fb = grow_float(fb, 2 * depth)
            fend = grow_int(fend, 2 * depth)
            ft = grow_float(ft, 2 * depth)
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


@helper(**NO_REFCOUNT)
def one_group_end(a, T, kcap, kmin, theta, beta, kslab):
    """The end b of the slab :func:`build_slab` makes when all components form one group,
    from the largest desired step ``kcap`` and the smallest ``kmin`` of min(k_i, T - a),
    without a pass over the components; NaN when they do not (then build it). The group is
    every component with k_i >= theta min(kcap, L), L = min(T - a, kslab): all of them iff
    kmin reaches it (if kmin = T - a, every k_i >= T - a >= L does), and its step is
    min(kcap, L, min k_i) = min(min(kcap, L), kmin), as ``_partition`` finds it."""
    kmax = min(kcap, min(T - a, kslab))
    if kmin < theta * kmax:
        return math.nan
    K = min(kmax, kmin)
    return a + K if K < beta * (T - a) else T


@linked(returns=types.UniTuple(types.int64[::1], 3),
        what="the multi-adaptive partition's elements", seconds=1)
@helper()
def component_elements(comp, ne, n):
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


@helper()
def _sort(buf, count):
    """Sort buf[:count] in place: insertion sort (the lists are short and nearly sorted),
    as the last pass of a Shell sort (gaps 3 g + 1) for lists longer than 64."""
    gap = 1
    if count > 64:
        while gap < count // 3:
            gap = 3 * gap + 1
    while gap >= 1:
        for r in range(gap, count):
            v = buf[r]
            s = r
            while s >= gap and buf[s - gap] > v:
                buf[s] = buf[s - gap]
                s -= gap
            buf[s] = v
        gap //= 3


@helper()
def first_ending_after(t, j, cptr, celems, eb):
    """The position in ``celems`` of component j's first element ending after t (its last
    where none does), by bisection of its elements cptr[j] .. cptr[j + 1] - 1."""
    lo, hi = cptr[j], cptr[j + 1] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if eb[celems[mid]] > t:
            hi = mid
        else:
            lo = mid + 1
    return lo


@linked(returns=types.Tuple((types.int64[::1], types.float64[::1], types.int64[::1],
                             types.int64[::1])),
        what="the multi-adaptive dependency structure", seconds=1)
@helper()
def dependency_structure(ne, comp, indptr, indices, cptr, celems, ea, eb):
    """Per element e of component i: the breakpoints that split it into intervals where the
    integrand f_i(U) is one polynomial (its ends and the element ends of its dependencies
    inside it), as CSR (sptr, spts); and for every dependency j of i (the nonzeros of row i,
    at dptr[e] + nz - indptr[i]) the position in ``celems`` of j's first element ending
    after the start of e, a cursor from which dependency values are read in time order."""
    sptr = np.zeros(ne + 1, dtype=np.int64)
    spts = np.empty(2 * ne + 16)
    dptr = np.zeros(ne + 1, dtype=np.int64)
    for e in range(ne):
        i = comp[e]
        dptr[e + 1] = dptr[e] + indptr[i + 1] - indptr[i]
    dcur = np.empty(dptr[ne], dtype=np.int64)
    buf = np.empty(16)
    for e in range(ne):
        i = comp[e]
        a, b = ea[e], eb[e]
        count = 0
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            lo = first_ending_after(a, j, cptr, celems, eb)
            dcur[dptr[e] + nz - indptr[i]] = lo
            if j == i:
                continue
            for c in range(lo, cptr[j + 1]):
                tb = eb[celems[c]]
                if tb >= b:
                    break
                if count == buf.shape[0]:
                    buf = grow_float(buf, 2 * count)
                buf[count] = tb
                count += 1
        if count > 1:
            _sort(buf, count)
        if sptr[e] + count + 2 > spts.shape[0]:
            spts = grow_float(spts, sptr[e] + count + 2)
        base = sptr[e]
        spts[base] = a
        n = 1
        for r in range(count):
            tb = buf[r]
            if tb - spts[base + n - 1] > 1e-12 * (b - a) and b - tb > 1e-12 * (b - a):
                spts[base + n] = tb
                n += 1
        spts[base + n] = b
        sptr[e + 1] = base + n + 1
    return sptr, spts, dptr, dcur
