"""Frozen components of the multi-adaptive loop: components at rest get no elements, the
constant x_i for the others, until they drift; then their constant element over the whole span
is stored."""
import math

import numpy as np
from numba import types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT
from dolfinode.counters import ELEMENTS, F_EVALUATIONS, JACOBIANS, STORED

#: A component whose change on a slab and drift over the rest of the interval stay below QUIET
#: times its error scale is frozen: a constant, with no elements, until it drifts (``freeze``).
QUIET = 1e-3


@helper(**NO_REFCOUNT)
def store_constant(i, a, b, x, counters, out_comp, out_a, out_b, out_values):
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


@helper(**NO_REFCOUNT)
def wake(i, t, x, frozen, last_a, last_b, counters, out_comp, out_a, out_b, out_values):
    """Make frozen component i active at t: its constant element [frozen since, t] is stored
    and it has no polynomial to continue."""
    store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b, out_values)
    frozen[i] = math.nan
    last_b[i] = last_a[i]


@helper(inline="always")
def drift_bound(change, rate, tau, mu, quiet):
    """|change| + |rate| tau (e^(mu tau) - 1) / (mu tau): a component's change on a slab and a
    bound of its drift over the time tau left, if it moves at ``rate`` now and its row of
    df/du has mu = J_ii + sum_j!=i |J_ij| (the row's bound of the logarithmic max-norm:
    rates of size r grow at most like e^(mu t) r). Without the growth factor u' = u from
    u = 1e-12 would be frozen for good. Where |change| + |rate| tau already exceeds
    ``quiet`` (the level of ``freeze``), that is returned: the growth factor (an expm1 per
    component and slab) cannot change the decision."""
    if rate == 0.0:
        return abs(change)
    drift = abs(change) + abs(rate) * tau
    if drift > quiet:
        return drift
    z = max(mu, 0.0) * tau
    growth = 1.0 if z < 1e-8 else (math.expm1(z) / z if z < 700.0 else math.inf)
    return abs(change) + abs(rate) * tau * growth


@linked(returns=types.boolean, what="the multi-adaptive freezing", seconds=1)
@helper(**NO_REFCOUNT)
def freeze(b, k, active, checked, indptr, indices, drift, atol, rtol, umax, x, frozen, kdes,
           last_a, last_b, quiet, uw, counters, out_comp, out_a, out_b, out_values):
    """Freeze and wake components at the end b of an accepted slab of length k, from the
    ``active`` ones and the frozen ones ``checked`` on it; returns whether any changed.

    Component i is quiet when its drift (``drift_bound``: its change on the slab, and a bound of
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
            wake(i, b, x, frozen, last_a, last_b, counters, out_comp, out_a, out_b, out_values)
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


@linked(returns=types.boolean, what="the multi-adaptive frozen components' wake-up",
        seconds=1)
@helper(**NO_REFCOUNT)
def wake_readers(b, k, checked, nchecked, frozen, quiet, drift, rptr, readers, indptr, indices,
                 ji, x, p, jrow, atol, rtol, kdes, last_a, last_b, stack, depth, counters,
                 out_comp, out_a, out_b, out_values):
    """Wake, at the end b of an accepted slab of length k, the frozen readers of the
    components that woke there (``freeze``) which would drift within the next slab; returns
    whether any woke.

    A frozen component is checked only after a slab in which a component it reads was
    active, so without this a front moving along a chain of frozen components woke one
    coupling per slab and fell behind the solution's leading edge wherever that moves
    faster (a 1000-stage linear chain: components woke at 45 x the tolerance). A woken
    component i with drift bound d_i moves by about its rate times k over the next slab, and
    its reader r, at depth m of the couplings from a component woken by ``freeze``, then
    drifts by about (the m-th Taylor term of the chain u_r' = J_ri u_i)

        d_r = |J_ri| k d_i / m,

    J_ri from r's row of df/du at (x, b). r wakes when d_r exceeds QUIET times
    atol_r + rtol |x_r|, and its readers are tried in turn."""
    n = 0
    for c in range(nchecked):
        i = checked[c]
        if math.isnan(frozen[i]) and not quiet[i]:
            stack[n] = i
            depth[n] = 1
            n += 1
    woke = False
    while n > 0:
        n -= 1
        i, m = stack[n], depth[n]
        for q in range(rptr[i], rptr[i + 1]):
            r = readers[q]
            if math.isnan(frozen[r]):
                continue
            ji(r, x.ctypes, b, p.ctypes, jrow.ctypes)
            counters[JACOBIANS] += 1
            jri = 0.0
            for nz in range(indptr[r], indptr[r + 1]):
                if indices[nz] == i:
                    jri = abs(jrow[nz - indptr[r]])
            d = jri * k * drift[i] / m
            if not d > QUIET * (atol[r] + rtol * abs(x[r])):
                continue
            wake(r, b, x, frozen, last_a, last_b, counters, out_comp, out_a, out_b, out_values)
            quiet[r] = False
            drift[r] = d
            kdes[r] = k
            stack[n] = r
            depth[n] = m + 1
            n += 1
            woke = True
    return woke


@linked(returns=types.UniTuple(types.int64[::1], 2),
        what="the multi-adaptive dependency pattern's transpose", seconds=1)
@helper()
def transpose_pattern(indptr, indices, N):
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


@helper(**NO_REFCOUNT)
def active_components(frozen, active):
    """The components not frozen (``frozen[i]`` NaN) into active[:n], in order; returns n."""
    n = 0
    for i in range(frozen.shape[0]):
        if math.isnan(frozen[i]):
            active[n] = i
            n += 1
    return n


@linked(returns=types.none, what="the multi-adaptive frozen components' storage",
        seconds=1)
@helper(**NO_REFCOUNT)
def store_frozen(frozen, t, x, counters, out_comp, out_a, out_b, out_values):
    """At the end t of the run: the constant element of every frozen component since it
    froze, which makes it active again."""
    for i in range(frozen.shape[0]):
        if not math.isnan(frozen[i]):
            store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b, out_values)
            frozen[i] = math.nan


@linked(returns=types.Tuple((types.int64, types.boolean)),
        what="the multi-adaptive frozen components' check", seconds=1)
@helper(**NO_REFCOUNT)
def check_frozen(stamp, active, nactive, autonomous, rptr, readers, check_stamp, frozen,
                 checked, uw, values, cptr, celems, fi, p, t, b, T, x, out, jdiag, coupling,
                 emax, umax, kact, drift, atol, rtol, counters):
    """Check the frozen components after a slab [t, b]: a frozen component is a constant on
    the slab, its residual -f_i(U(b)) with every other component at its end value (uw
    holds x_j for the frozen ones). For autonomous f only the frozen components that read
    an active one (``readers``, marked with ``stamp`` in ``check_stamp``) can have changed;
    for the others all are checked. Writes their indicator (k |f_i|, unscaled), scale and
    step for :mod:`.control` and their drift bound; returns the number checked, listed in
    ``checked``, and whether an f_i is not finite."""
    nn = values.shape[1]
    nchecked = 0
    blowup = False
    for r in range(nactive):
        j = active[r]
        uw[j] = values[celems[cptr[j + 1] - 1], nn - 1]
        if not autonomous:
            continue
        for q in range(rptr[j], rptr[j + 1]):
            i = readers[q]
            if check_stamp[i] != stamp and not math.isnan(frozen[i]):
                check_stamp[i] = stamp
                checked[nchecked] = i
                nchecked += 1
    if not autonomous:
        for i in range(frozen.shape[0]):
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
        drift[i] = drift_bound(0.0, out[0], T - b, jdiag[i] + coupling[i],
                               QUIET * (atol[i] + rtol * umax[i]))
    return nchecked, blowup


@linked(returns=types.boolean, what="the multi-adaptive frozen components' wake-up",
        seconds=1)
@helper(**NO_REFCOUNT)
def wake_failed(checked, nchecked, emax, margin, t, x, frozen, quiet, last_a, last_b,
                counters, out_comp, out_a, out_b, out_values):
    """Wake the checked frozen components whose scaled indicator exceeds ``margin`` (or is
    NaN): their constant element up to the slab start t is stored and they take part in the
    slab's retry. Returns whether any woke."""
    woke = False
    for c in range(nchecked):
        i = checked[c]
        if not emax[i] <= margin:
            wake(i, t, x, frozen, last_a, last_b, counters, out_comp, out_a, out_b, out_values)
            quiet[i] = False
            woke = True
    return woke
