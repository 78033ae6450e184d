"""The multi-adaptive loop: slab after slab, build (:mod:`dolfinode.timeslab.partition`),
solve (:mod:`.sweeps`), estimate the error of every element (:mod:`dolfinode.adaptivity`),
accept or reject, choose each component's next step (:mod:`.steps`), freeze and wake
components (:mod:`.freezing`), store the accepted elements. See :mod:`dolfinode.timeslab.multi`.
"""
import math
from functools import cache

import numpy as np
from numba import types

from dolfinode.adaptivity import MAX_FACTOR, filter_residuals, next_step
from dolfinode.compile.jit import Loop, helper
from dolfinode.compile.signatures import NO_REFCOUNT, component_kernel, rhs_kernel
from dolfinode.counters import (
    ELEMENTS,
    F_EVALUATIONS,
    FAILED_SOLVES,
    ITERATIONS,
    JACOBIANS,
    OUTSIDE,
    REJECTED,
    SLABS,
    STIFF,
    STORED,
    SUBSLABS,
    SYNCHRONISED,
)
from dolfinode.linalg.group import group_workspace
from dolfinode.methods.method import lagrange_weights, real_eigenvalues
from dolfinode.timeslab import (
    BLOWUP,
    CONSTRAINT,
    CONSTRAINT_CUT,
    DEFAULT,
    DONE,
    FULL,
    NEWTON,
    NONCONVERGENCE,
    ROUNDING,
    UNDERFLOW,
    smallest_step,
)
from dolfinode.timeslab.contract import OPTIONS_TYPE, STATE_TYPE
from dolfinode.timeslab.multi.freezing import (
    QUIET,
    drift_bound,
    freeze,
    store_constant,
    transpose_pattern,
)
from dolfinode.timeslab.multi.steps import grade, power, propagate, slab_limit
from dolfinode.timeslab.multi.sweeps import (
    converge,
    guess_from,
    synchronised,
    windows_settled,
)
from dolfinode.timeslab.partition import (
    build_slab,
    component_elements,
    dependency_structure,
    grow_float,
)

#: A slab holds many elements of a fast component and one indicator above the margin rejects
#: them all; steps are still chosen for indicators of 1 (DOLFIN G1 accepted up to 2 TOL too).
ACCEPTANCE_MARGIN = 2.0
#: Accepted slabs after a rejection during which the slab length limit does not grow.
REJECTION_HOLD = 4
#: A slab is synchronised, every active component on the smallest desired step, when that
#: takes at most SYNCHRONISE times the elements of the multi-adaptive partition: it is then
#: solved as one mono-adaptive slab (``sweeps.synchronised``), whose elements cost a fraction
#: of a multi-adaptive one (a component kernel call per node, dependencies gathered, sweeps).
#: After a synchronised slab the next one is synchronised up to twice that gain. (8 to enter:
#: the suite's stiff-spring chain took 2-3x the elements and 1.4-1.9x the time of its
#: partition.)
SYNCHRONISE = 4.0
#: After the synchronised fixed-point iteration failed on a slab of length k, slabs are
#: synchronised only below k, which grows by SYNCHRONISE_PROBE per synchronised slab.
SYNCHRONISE_PROBE = 1.2
#: Synchronised slabs over which the Jacobian rows of an earlier slab start serve the steps.
JACOBIAN_AGE = 8


_f8 = types.float64[::1]
_i8 = types.int64[::1]
_SIGNATURE = types.int64(
    types.intp, types.intp, types.intp, _f8,       # addresses of f, f_i and J_i, p
    _i8, _i8, _i8,                                 # indptr, indices, bandwidth position
    types.float64[:, ::1], types.float64[:, ::1],  # M^{-1}, A
    _f8, _f8,                                      # b0, tau (the mono form, ``synchronised``)
    types.float64[:, ::1], types.float64[:, ::1],  # A = T B T^-1
    types.complex128[::1],                         # the eigenvalues of B
    _f8, _f8, _f8,                                 # nodes, quadrature weights, bary
    _f8,                                           # end_derivative
    OPTIONS_TYPE, _f8, _f8,                        # options, atol, floor
    _f8, _f8, _f8, STATE_TYPE, _i8,                # x, kdes, frozen, state, counters
    _i8, _f8, _f8, types.float64[:, ::1],          # out_comp, out_a, out_b, out_values
)


@helper(**NO_REFCOUNT)
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


@helper(**NO_REFCOUNT)
def _jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian, jdiag,
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
def _extrapolation_weights(a, b, ea, eb, nodes, bary, key, weights, far):
    """weights[m, j] = l_j(tau_m), the Lagrange basis of an element on [a, b] at the nodes
    tau_m of [ea, eb] (continued past b), and far[m]: whether the node lies more than two
    element lengths past b (tau > 3: too far to extrapolate). Recomputed only when
    (a, b, ea, eb) differs from ``key``: on a synchronised slab every component's guess
    shares them."""
    if key[0] == a and key[1] == b and key[2] == ea and key[3] == eb:
        return
    key[0], key[1], key[2], key[3] = a, b, ea, eb
    for m in range(nodes.shape[0]):
        tau = (ea + nodes[m] * (eb - ea) - a) / (b - a)
        far[m] = tau > 3.0
        lagrange_weights(tau, nodes, bary, weights[m])


@helper(**NO_REFCOUNT)
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
    """The method's tables in the order :func:`advance` takes them (M^{-1}, A, b0, the stage
    nodes tau, T, T^{-1}, eigenvalues, nodes, quadrature weights, barycentric weights, end
    derivative), as writable copies (numba types read-only arrays apart); made once per
    method, as advance only reads them."""
    m = method
    tables = (m.moment_inverse, m.A, m.b0, m.nodes[m.stages], m.stage_transform,
              m.stage_transform_inverse, m.stage_eigenvalues, m.nodes, m.quadrature_weights,
              m.barycentric_weights, m.end_derivative)
    return tuple(np.array(table) for table in tables)


def _advance(f_address, fi_address, ji_address, p, indptr, indices, position, Minv, A, b0,
             stage_nodes, transform, transform_inverse, eigenvalues, nodes, qweights, bary,
             end_derivative, options, atol, floor, x, kdes, frozen, state, counters, out_comp,
             out_a, out_b, out_values):
    """Advance (x, t) slab by slab towards T, storing accepted elements; returns a status.
    ``frozen[i]`` is the time since which component i is frozen (NaN: active). A slab on
    which a value leaves the declared domain is rejected (``_leaves_domain``); an accepted
    one is projected on it."""
    f = rhs_kernel(f_address)
    fi = component_kernel(fi_address)
    ji = component_kernel(ji_address)
    N = x.shape[0]
    S = Minv.shape[0]
    nn = nodes.shape[0]
    o = options[0]
    st = state[0]
    fixed = o.fixed
    autonomous = o.autonomous
    mode = o.solver
    max_iter = o.max_iter
    rtol, T, kmax, safety, dtol = o.rtol, o.T, o.kmax, o.safety, o.dtol
    order, theta, beta = o.order, o.theta, o.beta
    gamma = np.full(1, o.gamma + 0j)  # the error filter's stage eigenvalue
    stages = (transform, transform_inverse, eigenvalues)
    efloor = (safety / MAX_FACTOR) ** order
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
    changed = np.zeros(N, dtype=np.int64)  # clock stamps of the lazy sweeps (see converge)
    computed = np.empty(4 * N, dtype=np.int64)
    clock = np.zeros(1, dtype=np.int64)
    last_a = np.zeros(N)  # each component's last element of the previous slab
    last_b = np.zeros(N)
    last_values = np.empty((N, nn))
    # Newton workspace for sub-slab groups (group_newton), grown to the largest group (band:
    # the global one); at least one real matrix, which the error filter uses
    band_width = 2 * o.band_lower + o.band_upper + 1
    n_real = real_eigenvalues(eigenvalues)
    newton = group_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S, 1, band_width)
    factored = np.zeros(N + 3, dtype=np.int64)  # the factors in ``newton`` (group_newton)
    factored_k = np.zeros(1)
    uw = x.copy()
    states = np.empty((nn, N))  # the states at an interval's nodes (``moments``)
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
    rptr, readers = transpose_pattern(indptr, indices, N)
    drift = np.empty(N)  # change on the slab and bound of the drift until T (``drift_bound``)
    quiet = np.ones(N, dtype=np.bool_)  # (stays True for a frozen component until it wakes)
    kslab = kmax  # slab length limit, adapted to the cost per unit time (``slab_limit``)
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
    # the synchronised slabs' workspace: f(x, t) (valid at f0_time), stages, f at the end
    f0 = np.empty(N)
    f0_time = math.nan
    fvec = np.empty(N)
    X = np.empty(S * N)
    F = np.empty(S * N)
    G = np.empty(S * N)
    w = np.empty(S * N)
    sync_fail = math.inf  # (see SYNCHRONISE_PROBE)
    # synchronised slabs since the Jacobian rows were evaluated (at the start and after the
    # active set changed: JACOBIAN_AGE, so that every active row is evaluated)
    jacobian_age = JACOBIAN_AGE
    solved = False  # the last slab was solved synchronised
    guess_weights = np.empty((nn, nn))  # (``_extrapolation_weights``)
    guess_key = np.full(4, np.nan)
    guess_far = np.zeros(nn, dtype=np.bool_)
    sptr = np.zeros(1, dtype=np.int64)  # (``dependency_structure``, for the sweeps)
    spts = np.zeros(1)
    dptr = np.zeros(1, dtype=np.int64)
    dcur = np.zeros(1, dtype=np.int64)
    counters[STORED] = 0
    capacity = out_a.shape[0]
    t = st.t
    while True:
        if regroup:
            nactive = 0
            for i in range(N):
                if math.isnan(frozen[i]):
                    active[nactive] = i
                    nactive += 1
            regroup = False
            jacobian_age = JACOBIAN_AGE
        nfrozen = N - nactive
        if t >= T:
            if nfrozen > capacity - counters[STORED]:
                return FULL
            for i in range(N):
                if not math.isnan(frozen[i]):
                    store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b,
                                   out_values)
                    frozen[i] = math.nan
            return DONE
        factored[0] = 0
        kcap = 0.0  # the largest desired step
        kmin = math.inf  # the smallest, and the elements per unit time of the partition
        rate = 0.0
        for r in range(nactive):
            i = active[r]
            if not fixed:
                kdes[i] = min(kdes[i], kmax)
            kcap = max(kcap, kdes[i])
            ki = min(kdes[i], T - t)
            kmin = min(kmin, ki)
            rate += 1.0 / ki
        stiff = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        # (twice the gain to leave it: a slab that flips back and forth pays both)
        sync = (not fixed and not stiff and nfrozen == 0 and kmin < sync_fail
                and nactive <= (2.0 if solved else 1.0) * SYNCHRONISE * kmin * rate)
        # (threshold 0: one group, on the smallest step)
        b, ne, nsub, nwin, comp, ea, eb, windows = build_slab(t, T, kdes, active[:nactive],
                                                              0.0 if sync else theta, beta,
                                                              kslab, comp, ea, eb, windows)
        # the Jacobian at the slab start: its diagonal damps the element updates, its
        # couplings propagate small steps, and it is the Newton matrix of coupled sub-slabs.
        # A slab solved synchronised needs it only for the steps (ties, grading, drift):
        # one up to JACOBIAN_AGE synchronised slabs old serves them.
        try_sync = nsub == 1 and nfrozen == 0 and not stiff and b - t < sync_fail
        if not (try_sync and jacobian_age < JACOBIAN_AGE):
            _jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian, jdiag,
                           coupling, jacobian_time, counters)
            jacobian_age = 0
        if ne + nfrozen > capacity - counters[STORED]:
            # (room for the frozen components' elements too, stored when they wake up)
            return FULL  # with nothing stored: the driver grows the buffers
        if b - t < smallest_step(t, o.span) and b < T:
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
        largest = 1
        run = 1
        for e in range(1, ne):
            run = run + 1 if ea[e] == ea[e - 1] and eb[e] == eb[e - 1] else 1
            largest = max(largest, run)
        if largest > newton[4].shape[0]:  # (its real vector has a row per component)
            newton = group_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S,
                                     largest, band_width)
        # initial guess: each component's first element continues its last polynomial of the
        # previous slab (at most two element lengths ahead); later elements continue their
        # predecessor when the sweep reaches them
        # (after a rejection: the rejected attempt)
        if retry:
            guess_from(x, comp, ea, eb, values, cptr, celems, ocptr, ocelems, oea, oeb, ovalues,
                       nodes, bary)
        else:
            for e in range(ne):
                i = comp[e]
                if prev[e] < 0 and last_b[i] > last_a[i]:
                    _extrapolation_weights(last_a[i], last_b[i], ea[e], eb[e], nodes, bary,
                                           guess_key, guess_weights, guess_far)
                    for m in range(nn):
                        value = 0.0
                        for j in range(nn):
                            value += guess_weights[m, j] * last_values[i, j]
                        values[e, m] = x[i] if guess_far[m] else value
                else:
                    for m in range(nn):
                        values[e, m] = x[i]
        nroot = windows[0] if nwin > 0 else ne
        if saved.shape[0] < nroot:
            saved = np.empty((max(nroot, 2 * saved.shape[0]), nn))
        converged = False
        d_prev = math.inf
        growth = 0
        f_attempt = counters[F_EVALUATIONS]
        solved = False  # as one mono-adaptive slab (every component on [t, b])
        if try_sync:
            if f0_time != t:  # (NaN: not valid)
                f(x.ctypes, t, p.ctypes, f0.ctypes)
                counters[F_EVALUATIONS] += N
                f0_time = t
            # the mono loop's stopping tolerance: its discrete errors add up over the slabs
            dtol_k = dtol if fixed else max(dtol * min(1.0, (b - t) / o.span),
                                            min(dtol, ROUNDING / rtol))
            solved = synchronised(f, p, x, f0, t, b - t, A, b0, stage_nodes, atol, rtol, dtol_k,
                                  max_iter, comp, ne, values, fend, X, F, G, w, fvec,
                                  counters) >= 0
            if solved:
                converged = True
                sync_fail *= SYNCHRONISE_PROBE
                jacobian_age += 1
            else:
                sync_fail = b - t
                _jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian,
                               jdiag, coupling, jacobian_time, counters)
                jacobian_age = 0
        if not solved:  # the moments' breakpoints and dependency cursors
            sptr, spts, dptr, dcur = dependency_structure(ne, comp, indptr, indices, cptr,
                                                          celems, ea, eb)
        last_it = -1
        for it in range(0 if solved else max_iter):
            last_it = it
            # every window iterated to convergence in turn (the fast components advance window
            # by window as in single-rate time stepping), then the top-level elements: one
            # sweep would leave the slow components' own coupling to the next global
            # iteration, which costs a sweep over every window
            predict = it == 0 and not retry
            d, resolved = converge(windows, nwin, ne, predict, True, sweep_limit, fi, p, x,
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
            top, settled = converge(top_start, 1, nroot, False, nwin > 0, sweep_limit, fi, p,
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
            if nwin > 0 and resolved and math.isfinite(d) and windows_settled(
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
        if converged and mode == DEFAULT and last_it >= 7:
            counters[STIFF] = 1  # Gauss-Seidel converges too slowly: Newton from here on
        # (a synchronised slab shorter than the limit says nothing about the windows' cost)
        if not fixed and not (solved and b - t < kslab):
            limit = slab_limit(min(kslab, kcap), kmax, b - t, converged, nwin,
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
            if (b - t) * 0.25 < smallest_step(t, o.span):
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
        # (overwrites newton: ``factored`` is reset at every slab start; a synchronised slab
        # converged by fixed point is not stiff: unfiltered, as in the mono loop)
        if not solved:
            filter_residuals(ne, comp, ea, eb, resid, position, indptr, indices, jacobian,
                             jdiag, coupling, gamma, elist, group_order, local, newton, counters)
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
                drift[i] = drift_bound(0.0, out[0], T - b, jdiag[i] + coupling[i],
                                       QUIET * (atol[i] + rtol * umax[i]))
        # (the components with elements, then the frozen ones checked)
        nseen = nactive + nchecked
        for r in range(nseen):
            i = active[r] if r < nactive else checked[r - nactive]
            emax[i] /= atol[i] + rtol * umax[i]
        for c in range(nchecked):  # frozen components that fail the slab take part in its retry
            i = checked[c]
            if not emax[i] <= ACCEPTANCE_MARGIN:
                store_constant(i, frozen[i], t, x, counters, out_comp, out_a, out_b,
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
            if (b - t) * 0.25 < smallest_step(t, o.span):
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
                kref, eref = kact[i], emax[i]
                if solved and kdes[i] > kref:
                    # held on the synchronised step: its estimate scaled to its own step
                    # (eps = O(k^order)), so that the synchronised step does not cap its
                    # growth and the partition can show what it saves again
                    eref *= power(kdes[i] / kref, order)
                    kref = kdes[i]
                # below efloor the factor is capped at MAX_FACTOR anyway: no pow() for idle
                # components
                knew = (kref * MAX_FACTOR if eref <= efloor else
                        next_step(kref, eref, 1.0, order, safety, False))
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
            propagate(kdes, active[:nactive], frozen, indptr, indices, jacobian)
            grade(kdes, active[:nactive], frozen, indptr, indices, jacobian)
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
            for e in range(ne):  # (slice copies compile their shape checks and messages)
                oea[e] = ea[e]
                oeb[e] = eb[e]
                for m in range(nn):
                    ovalues[e, m] = values[e, m]
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
        st.mono_elements += (b - t) / kmin * N
        counters[SLABS] += 1
        counters[SYNCHRONISED] += solved
        hold = max(0, hold - 1)
        counters[SUBSLABS] += nsub
        for r in range(nactive):
            i = active[r]
            last = celems[cptr[i + 1] - 1]
            change = values[last, nn - 1] - x[i]
            drift[i] = drift_bound(change, fend[last], T - b, jdiag[i] + coupling[i],
                                   QUIET * (atol[i] + rtol * umax[i]))
            x[i] = values[last, nn - 1]
            last_a[i], last_b[i] = ea[last], eb[last]
            for m in range(nn):
                last_values[i, m] = values[last, m]
        # a component projected to zero that f drives below its floor by T: f does not keep
        # it nonnegative, and the projected solution would stay at 0 where the exact one
        # turns negative
        if solved:  # f(x, b), unless a value was projected
            f0_time = b
            for i in range(N):
                f0[i] = fvec[i]
        for r in range(nactive):
            i = active[r]
            if projected[i]:
                f0_time = math.nan
                projected[i] = False
                if x[i] == 0.0:
                    fi(i, x.ctypes, b, p.ctypes, out.ctypes)
                    counters[F_EVALUATIONS] += 1
                    if out[0] * (T - b) < floor[i]:
                        counters[OUTSIDE] = i + 1
                        st.t = b
                        return CONSTRAINT
        if not fixed and b < T and freeze(b, b - t, active[:nactive], checked[:nchecked],
                                          indptr, indices, drift, atol, rtol, umax, x, frozen,
                                          kdes, last_a, last_b, quiet, uw, counters, out_comp,
                                          out_a, out_b, out_values):
            regroup = True
        t = b
        st.t = t


advance = Loop(_advance, _SIGNATURE, "the multi-adaptive loop (mcG(q), mdG(q))", 25,
               error_model="numpy")
