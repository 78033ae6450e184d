"""The multi-adaptive loop: slab after slab, build (:mod:`dolfinode.timeslab.partition`),
solve (:mod:`.slab`), estimate the error of every element, accept or reject and choose each
component's next step (:mod:`.control`), tie and grade the steps (:mod:`.steps`), freeze and
wake components (:mod:`.freezing`), store the accepted elements. See
:mod:`dolfinode.timeslab.multi`.
"""
import math
from functools import cache

import numpy as np
from numba import types

from dolfinode.compile.jit import Loop, helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT, component_kernel, rhs_kernel
from dolfinode.counters import (
    ELEMENTS,
    F_EVALUATIONS,
    FAILED_SOLVES,
    OUTSIDE,
    REJECTED,
    SLABS,
    STIFF,
    STORED,
    STORED_BLOCKS,
    SUBSLABS,
    SYNCHRONISED,
)
from dolfinode.linalg.group import group_workspace
from dolfinode.methods.method import lagrange_matrices, real_eigenvalues
from dolfinode.timeslab import (
    BLOWUP,
    CONSTRAINT,
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
from dolfinode.timeslab.multi.control import (
    ACCEPTANCE_MARGIN,
    choose_steps,
    desired_steps,
    drives_out,
    interior_indicators,
    keep_attempt,
    leaves_domain,
    project,
    residual_indicators,
    scale_indicators,
    slab_deviation,
)
from dolfinode.timeslab.multi.freezing import (
    QUIET,
    active_components,
    check_frozen,
    drift_bound,
    freeze,
    store_frozen,
    transpose_pattern,
    wake_failed,
    wake_readers,
)
from dolfinode.timeslab.multi.slab import (
    guess_stages,
    initial_guess,
    jacobian_rows,
    solve_synchronised,
    sweep_slab,
)
from dolfinode.timeslab.multi.steps import (
    slab_limit,
    tie_and_grade,
)
from dolfinode.timeslab.multi.sweeps import guess_from
from dolfinode.timeslab.partition import (
    build_slab,
    component_elements,
    dependency_structure,
    one_group_end,
)

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
#: The first synchronised slab on new rows ties and grades the steps; the others leave them
#: untied, and a slab that leaves synchronisation ties them first.
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
    _f8, _f8,                                      # end_derivative, interior
    OPTIONS_TYPE, _f8, _f8,                        # options, atol, floor
    _f8, _f8, _f8, STATE_TYPE, _i8,                # x, kdes, frozen, state, counters
    types.Tuple((_f8, _f8, types.float64[:, ::1],  # carry (see ``carry``)
                 _f8, _f8, _f8, _f8, _f8,
                 _f8, _f8, types.float64[:, ::1], _i8, _i8)),
    _i8, _f8, _f8, types.float64[:, ::1],          # out_comp, out_a, out_b, out_values
    _f8, _f8, types.float64[:, ::1],               # out_block_a, out_block_b, out_blocks
)


@cache
def method_tables(method):
    """The method's tables in the order :func:`advance` takes them (M^{-1}, A, b0, the stage
    nodes tau, T, T^{-1}, eigenvalues, nodes, quadrature weights, barycentric weights, end
    derivative, the interior point and derivative weights of ``interior_indicators``), as
    writable copies (numba types read-only arrays apart); made once per
    method, as advance only reads them."""
    m = method
    tables = (m.moment_inverse, m.A, m.b0, m.nodes[m.stages], m.stage_transform,
              m.stage_transform_inverse, m.stage_eigenvalues, m.nodes, m.quadrature_weights,
              m.barycentric_weights, m.end_derivative, _interior(m))
    return tuple(np.array(table) for table in tables)


def _interior(method):
    """[tau*, l_0'(tau*), ..., l_q'(tau*)] of :func:`.control.interior_indicators`: tau* = 0
    for dG(q) (right Radau nodes), half the first node gap for cG(q) (Lobatto nodes)."""
    nodes = np.asarray(method.nodes, dtype=float)
    tau = 0.0 if method.family == "dG" else 0.5 * nodes[1]
    return np.concatenate(([tau], lagrange_matrices(nodes, (tau,))[1][0]))


def carry(N, nn, nnz, capacity):
    """The arrays the loop carries from one call to the next (with the state's fields, see
    :mod:`dolfinode.timeslab.contract`), for N components of nn nodal values, nnz entries
    in df/du and output buffers of ``capacity`` elements: each component's last element
    (start, end, nodal values), the Jacobian rows (CSR values, diagonal, sum of the
    off-diagonal |J_ij|, when each was evaluated), f(x, t) of the synchronised slabs, and
    the rejected attempt that guesses its retry (starts, ends, nodal values, CSR of each
    component's elements). An attempt is solved only when it fits in the buffers' room
    (or is one block of N), so it fits in these: :func:`grown` keeps them as large as the
    buffers."""
    room = max(capacity, N)
    return (np.zeros(N), np.zeros(N), np.empty((N, nn)),
            np.empty(max(1, nnz)), np.zeros(N), np.zeros(N), np.full(N, np.nan), np.empty(N),
            np.empty(room), np.empty(room), np.empty((room, nn)),
            np.zeros(N + 1, dtype=np.int64), np.empty(room, dtype=np.int64))


def grown(carried, capacity):
    """``carried`` (:func:`carry`) with room for an attempt of ``capacity`` elements, its
    contents kept."""
    if carried[8].shape[0] >= capacity:
        return carried
    attempt = [np.empty((capacity, *a.shape[1:]), a.dtype) for a in carried[8:11]]
    attempt.append(np.empty(capacity, dtype=np.int64))
    for new, old in zip(attempt, carried[8:11] + carried[12:]):
        new[:old.shape[0]] = old
    return carried[:8] + tuple(attempt[:3]) + (carried[11], attempt[3])


@linked(returns=types.none, what="the multi-adaptive rejected attempt's partition", seconds=1)
@helper(**NO_REFCOUNT)
def _keep_partition(N, ne, cptr, celems, ocptr, ocelems):
    """Copy the CSR of each component's elements of a rejected attempt."""
    for i in range(N + 1):
        ocptr[i] = cptr[i]
    for e in range(ne):
        ocelems[e] = celems[e]


@linked(returns=types.int64, what="the multi-adaptive partition's sub-slabs", seconds=1)
@helper(**NO_REFCOUNT)
def _largest_sub_slab(ne, ea, eb):
    """The most elements on one interval (the slab's elements are ordered by interval)."""
    largest = 1
    run = 1
    for e in range(1, ne):
        run = run + 1 if ea[e] == ea[e - 1] and eb[e] == eb[e - 1] else 1
        largest = max(largest, run)
    return largest


@linked(returns=types.float64, what="the multi-adaptive slab's storage", seconds=1)
@helper(**NO_REFCOUNT)
def _store_slab(ne, comp, ea, eb, values, counters, out_comp, out_a, out_b, out_values):
    """Append the accepted slab's elements to the output; returns its shortest element."""
    n0 = counters[STORED]
    for e in range(ne):
        out_comp[n0 + e] = comp[e]
        out_a[n0 + e] = ea[e]
        out_b[n0 + e] = eb[e]
        for m in range(values.shape[1]):
            out_values[n0 + e, m] = values[e, m]
    counters[STORED] += ne
    counters[ELEMENTS] += ne
    kmin = math.inf
    for e in range(ne):
        kmin = min(kmin, eb[e] - ea[e])
    return kmin


@helper(**NO_REFCOUNT)
def _store_block(N, t, b, values, counters, out_block_a, out_block_b, out_blocks):
    """Append a synchronised slab (element i < N: component i on [t, b]) to the block
    buffers: [t, b] and the values as a block (q + 1, N), row-major, the layout of a
    mono-adaptive slab."""
    nn = values.shape[1]
    n = counters[STORED_BLOCKS]
    out_block_a[n] = t
    out_block_b[n] = b
    for m in range(nn):
        for i in range(N):
            out_blocks[n, m * N + i] = values[i, m]
    counters[STORED_BLOCKS] += 1
    counters[ELEMENTS] += N


@helper(**NO_REFCOUNT)
def _move_to_end(active, nactive, cptr, celems, ea, eb, values, fend, x, fixed, drift, atol,
                 rtol, umax, tau, jdiag, coupling, last_a, last_b, last_values):
    """Move every active component to the end of its last element of the accepted slab
    (x_i, and that element, which the next slab's guess continues), with its drift bound
    over the time ``tau`` left (``freeze``; not with ``fixed`` steps, which never freeze).
    Returns whether a component is quiet by that bound (without one ``freeze`` changes
    nothing unless a frozen component was checked)."""
    nn = values.shape[1]
    any_quiet = False
    for r in range(nactive):
        i = active[r]
        last = celems[cptr[i + 1] - 1]
        if not fixed:
            level = QUIET * (atol[i] + rtol * umax[i])
            drift[i] = drift_bound(values[last, nn - 1] - x[i], fend[last], tau,
                                   jdiag[i] + coupling[i], level)
            any_quiet = any_quiet or drift[i] <= level
        x[i] = values[last, nn - 1]
        last_a[i], last_b[i] = ea[last], eb[last]
        for m in range(nn):
            last_values[i, m] = values[last, m]
    return any_quiet


@helper(**NO_REFCOUNT)
def _fresh(st, kmax, last_a, last_b, jdiag, coupling, jacobian_time):
    """The carried state of a fresh start: no last elements, no Jacobian rows, the slab
    length limit at kmax, no synchronisation failure, no rejected attempt."""
    for i in range(last_a.shape[0]):
        last_a[i] = last_b[i] = jdiag[i] = coupling[i] = 0.0
        jacobian_time[i] = math.nan
    st.k_slab, st.hold, st.climb_cost, st.climb_direction = kmax, 0, math.inf, 1.0
    st.sync_fail, st.f0_time, st.outside = math.inf, math.nan, -1
    st.regroup, st.synchronised, st.retry = True, False, False
    st.carried = True


def _advance(f_address, fi_address, ji_address, p, indptr, indices, position, Minv, A, b0,
             stage_nodes, transform, transform_inverse, eigenvalues, nodes, qweights, bary,
             end_derivative, interior, options, atol, floor, x, kdes, frozen, state, counters, carried,
             out_comp, out_a, out_b, out_values, out_block_a, out_block_b, out_blocks):
    """Advance (x, t) slab by slab towards T, storing accepted elements; returns a status.
    ``frozen[i]`` is the time since which component i is frozen (NaN: active). A slab on
    which a value leaves the declared domain is rejected (``leaves_domain``); an accepted
    one is projected on it. The slab's phases live in :mod:`.slab` (solve), :mod:`.control`
    (indicators, acceptance, steps), :mod:`.steps` and :mod:`.freezing`; this function holds
    the work space and the state carried from slab to slab, and from one call to the next
    (``state`` and ``carried``: :func:`carry`) unless ``state[0].carried`` is False."""
    f = rhs_kernel(f_address)
    fi = component_kernel(fi_address)
    ji = component_kernel(ji_address)
    N = x.shape[0]
    S = Minv.shape[0]
    nn = nodes.shape[0]
    o = options[0]
    st = state[0]
    (last_a, last_b, last_values, jacobian, jdiag, coupling, jacobian_time, f0,
     oea, oeb, ovalues, ocptr, ocelems) = carried
    if not st.carried:
        _fresh(st, o.kmax, last_a, last_b, jdiag, coupling, jacobian_time)
    fixed = o.fixed
    mode = o.solver
    max_iter = o.max_iter
    rtol, T, kmax, dtol = o.rtol, o.T, o.kmax, o.dtol
    theta, beta = o.theta, o.beta
    # (np.empty and a fill throughout: numba compiles np.zeros, np.ones, np.full and
    # np.arange apart for each dtype, ~0.1 s each of the first compile)
    gamma = np.empty(1, dtype=np.complex128)  # the error filter's stage eigenvalue
    gamma[0] = o.gamma
    stages = (transform, transform_inverse, eigenvalues)
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
    unfiltered = np.empty(4 * N)  # ... and before the filter
    mom = np.empty(S)
    delta = np.empty(S)
    D = np.empty((S, S))
    degree = 1
    for i in range(N):
        degree = max(degree, indptr[i + 1] - indptr[i])
    cur = np.empty(degree, dtype=np.int64)
    local = np.empty(N, dtype=np.int64)
    local[:] = -1
    group_order = np.empty(N, dtype=np.int64)
    elist = np.empty(N, dtype=np.int64)
    changed = np.empty(N, dtype=np.int64)  # clock stamps of the lazy sweeps (see converge)
    changed[:] = 0
    computed = np.empty(4 * N, dtype=np.int64)
    clock = np.empty(1, dtype=np.int64)
    clock[0] = 0
    # Newton workspace for sub-slab groups (group_newton), grown to the largest group (band:
    # the global one); at least one real matrix, which the error filter uses
    band_width = 2 * o.band_lower + o.band_upper + 1
    n_real = real_eigenvalues(eigenvalues)
    newton = group_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S, 1, band_width)
    factored = np.empty(N + 3, dtype=np.int64)  # the factors in ``newton`` (group_newton)
    factored[:] = 0
    factored_k = np.empty(1)
    factored_k[0] = 0.0
    uw = x.copy()
    states = np.empty((nn, N))  # the states at an interval's nodes (``moments``)
    out = np.empty(1)
    jrow = np.empty(max(1, indices.shape[0]))
    # the active (not frozen) components, rebuilt when that set changes (``regroup``), and
    # the frozen ones checked after a slab: per slab, the work stays proportional to the
    # active components and their frozen readers, not to N
    active = np.empty(N, dtype=np.int64)
    checked = np.empty(N, dtype=np.int64)
    check_stamp = np.empty(N, dtype=np.int64)
    check_stamp[:] = 0
    check_round = 0
    rptr = readers = np.empty(0, dtype=np.int64)  # (``transpose_pattern``, once one froze)
    wake_stack = np.empty(N, dtype=np.int64)  # (``wake_readers``)
    wake_depth = np.empty(N, dtype=np.int64)
    drift = np.empty(N)  # change on the slab and bound of the drift until T (``drift_bound``)
    quiet = np.empty(N, dtype=np.bool_)  # (stays True for a frozen component until it wakes)
    quiet[:] = True
    climb = np.empty(2)  # (``slab_limit``)
    climb[0], climb[1] = st.climb_cost, st.climb_direction
    emax = np.empty(N)
    kact = np.empty(N)
    umax = np.empty(N)
    saved = np.empty((N, nn))  # the top level's values before its sweeps
    top_start = np.empty(1, dtype=np.int64)
    top_start[0] = 0
    top_change = np.empty(N)
    top_change[:] = 0.0
    mark = np.empty(N, dtype=np.int64)
    mark[:] = 0
    lowered = np.empty(N, dtype=np.bool_)  # (``propagate``)
    lowered[:] = False
    stack = np.empty(N, dtype=np.int64)
    # each row's reach and each coupling's weights (``tie_reach``) for the Jacobian rows
    # since their last evaluation: the slabs that share them pass only the rows that can
    # act to the ties and grading (``acting``)
    reach = np.empty(N)
    lopsided = np.empty(N, dtype=np.bool_)
    lopsided[:] = False
    strength = np.empty(max(1, indices.shape[0]))
    reaction = np.empty(max(1, indices.shape[0]))
    reach_valid = False
    acting = np.empty(N, dtype=np.int64)
    projected = np.empty(N, dtype=np.bool_)
    projected[:] = False
    # the synchronised slabs' workspace: stages, f at the end
    fvec = np.empty(N)
    X = np.empty(S * N)
    F = np.empty(S * N)
    G = np.empty(S * N)
    w = np.empty(S * N)
    guess_weights = np.empty((nn, nn))  # (``initial_guess``)
    guess_key = np.empty(4)
    guess_key[:] = np.nan
    guess_far = np.empty(nn, dtype=np.bool_)
    guess_far[:] = False
    sptr = np.empty(1, dtype=np.int64)  # (``dependency_structure``, for the sweeps)
    sptr[0] = 0
    spts = np.empty(1)
    spts[0] = 0.0
    dptr = np.empty(1, dtype=np.int64)
    dptr[0] = 0
    dcur = np.empty(1, dtype=np.int64)
    dcur[0] = 0
    # the per-component index arrays of a synchronised slab (``component_elements`` of
    # comp[e] = e): element i is component i's only one
    ident = np.empty(N + 1, dtype=np.int64)
    for i in range(N + 1):
        ident[i] = i
    no_prev = np.empty(N, dtype=np.int64)
    no_prev[:] = -1
    # whether a component is declared nonnegative (floor > -inf): else no domain checks
    bounded = False
    for i in range(N):
        bounded = bounded or floor[i] > -math.inf
    counters[STORED] = 0
    counters[STORED_BLOCKS] = 0
    capacity = out_a.shape[0]
    t = st.t
    nactive = active_components(frozen, active)
    while True:
        # the last slab's steps not tied and graded (a synchronised slab on Jacobian rows
        # already used, below; read before a regroup resets the age, and from the carried
        # state, so that a run cut into loop calls steps as one)
        untied = not fixed and st.synchronised and st.jacobian_age > 1
        if st.regroup:  # (JACOBIAN_AGE: every active row is evaluated anew)
            nactive = active_components(frozen, active)
            st.regroup = False
            st.jacobian_age = JACOBIAN_AGE
        nfrozen = N - nactive
        if t >= T:
            if nfrozen > capacity - counters[STORED]:
                return FULL
            if nfrozen > 0:
                store_frozen(frozen, t, x, counters, out_comp, out_a, out_b, out_values)
                st.regroup = True
            return DONE
        factored[0] = 0
        stiff = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        while True:
            kcap, kmin, rate = desired_steps(kdes, active, nactive, fixed, kmax, t, T)
            # (twice the gain to leave it: a slab that flips back and forth pays both)
            sync = (not fixed and not stiff and nfrozen == 0 and kmin < st.sync_fail
                    and nactive <= (2.0 if st.synchronised else 1.0) * SYNCHRONISE * kmin * rate)
            if sync or not untied:
                break
            # a partition next (the spread, a component frozen): tie and grade first
            reach_valid = tie_and_grade(reach_valid, kdes, active[:nactive], frozen, indptr,
                                        indices, jacobian, reach, lopsided, strength, reaction,
                                        jdiag, lowered, stack, acting)
            untied = False
        # (threshold 0: one group, on the smallest step)
        threshold = 0.0 if sync else theta
        # every component on one element of [t, b], in order (comp[e] = e): the fused path,
        # whose slab is known from kcap and kmin
        b = math.nan
        if nfrozen == 0 and not o.unfused:
            b = one_group_end(t, T, kcap, kmin, threshold, beta, st.k_slab)
        fused = not math.isnan(b)
        if fused:
            ne, nsub, nwin = N, 1, 0
            for e in range(N):  # component e on [t, b] (as ``build_slab``)
                comp[e] = e
                ea[e] = t
                eb[e] = b
        else:
            b, ne, nsub, nwin, comp, ea, eb, windows = build_slab(t, T, kdes, active[:nactive],
                                                                  threshold, beta, st.k_slab,
                                                                  comp, ea, eb, windows)
            # (a partition may still put every component on one step)
            fused = nsub == 1 and nfrozen == 0 and not o.unfused
        block = fused and N > 1  # stored as a block (one component: its elements)
        if (counters[STORED_BLOCKS] == out_block_a.shape[0] if block
                else ne + nfrozen > capacity - counters[STORED]):
            # (room for the frozen components' elements too, stored when they wake up; the
            # next call builds this slab again from the carried state)
            return FULL  # with nothing stored: the driver grows the buffers
        # the Jacobian at the slab start: its diagonal damps the element updates, its
        # couplings propagate small steps, and it is the Newton matrix of coupled sub-slabs.
        # A slab solved synchronised needs it only for the steps (ties, grading, drift):
        # one up to JACOBIAN_AGE synchronised slabs old serves them.
        try_sync = nsub == 1 and nfrozen == 0 and not stiff and b - t < st.sync_fail
        if not (try_sync and st.jacobian_age < JACOBIAN_AGE):
            jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian, jdiag,
                          coupling, jacobian_time, counters)
            st.jacobian_age = 0
            reach_valid = False
        if b - t < smallest_step(t, o.span) and b < T:
            return CONSTRAINT if st.outside >= 0 else UNDERFLOW
        if values.shape[0] < ne:
            values = np.empty((max(ne, 2 * values.shape[0]), nn))
            fend = np.empty(values.shape[0])
            resid = np.empty(values.shape[0])
            unfiltered = np.empty(values.shape[0])
            computed = np.empty(values.shape[0], dtype=np.int64)
        if fused:
            cptr, celems, prev, largest = ident, ident[:N], no_prev, N
        else:
            cptr, celems, prev = component_elements(comp, ne, N)
            largest = _largest_sub_slab(ne, ea, eb)
        if largest > newton[4].shape[0]:  # (its real vector has a row per component)
            newton = group_workspace(max(n_real, 1), eigenvalues.shape[0] - n_real, S,
                                     largest, band_width)
        # a fused slab tried synchronised is guessed in its stage vector (the elements only if
        # that fails, for the sweeps)
        guessed = fused and try_sync and not st.retry
        if st.retry:  # the rejected attempt
            guess_from(x, comp, ea, eb, values, cptr, celems, ocptr, ocelems, oea, oeb, ovalues,
                       nodes, bary)
        elif guessed:
            guess_stages(N, ea, eb, x, last_a, last_b, last_values, nodes, bary, guess_key,
                         guess_weights, guess_far, X)
        else:
            initial_guess(ne, comp, ea, eb, prev, x, last_a, last_b, last_values, nodes, bary,
                          guess_key, guess_weights, guess_far, values)
        nroot = windows[0] if nwin > 0 else ne
        if saved.shape[0] < nroot:
            saved = np.empty((max(nroot, 2 * saved.shape[0]), nn))
        f_attempt = counters[F_EVALUATIONS]
        solved = False  # as one mono-adaptive slab (every component on [t, b])
        if try_sync:
            solved, st.f0_time = solve_synchronised(f, p, x, f0, st.f0_time, t, b, A, b0,
                                                    stage_nodes, atol, rtol, dtol, o.span,
                                                    fixed, max_iter, guessed, comp, ne, values,
                                                    fend, X, F, G, w, fvec, counters)
            if solved:
                st.sync_fail *= SYNCHRONISE_PROBE
                st.jacobian_age += 1
            else:
                st.sync_fail = b - t
                if guessed:
                    initial_guess(ne, comp, ea, eb, prev, x, last_a, last_b, last_values, nodes,
                                  bary, guess_key, guess_weights, guess_far, values)
                jacobian_rows(ji, active, nactive, x, t, p, indptr, indices, jrow, jacobian,
                              jdiag, coupling, jacobian_time, counters)
                st.jacobian_age = 0
                reach_valid = False
        st.synchronised = solved
        converged = solved
        last_it = -1
        if not solved:
            computed[:ne] = -1
            changed[:] = 0
            clock[0] = 0
            # the moments' breakpoints and dependency cursors
            sptr, spts, dptr, dcur = dependency_structure(ne, comp, indptr, indices, cptr,
                                                          celems, ea, eb)
            converged, last_it = sweep_slab(
                max_iter, st.retry, windows, nwin, ne, nroot, top_start, sweep_limit, dtol, T - t,
                b, fi, p, x, indptr, indices, position, jacobian, comp, prev, cptr, celems, ea, eb,
                values, saved, nodes, bary, qweights, Minv, A, stages, sptr, spts, dptr, dcur,
                jdiag, coupling, stiff, atol, rtol, states, out, cur, mom, fend, D, delta,
                local, group_order, elist, newton, factored, factored_k, changed, computed,
                clock, top_change, mark, frozen, uw, counters)
        if converged and mode == DEFAULT and last_it >= 7:
            counters[STIFF] = 1  # Gauss-Seidel converges too slowly: Newton from here on
        # (a synchronised slab shorter than the limit says nothing about the windows' cost)
        if not fixed and not (solved and b - t < st.k_slab):
            limit = slab_limit(min(st.k_slab, kcap), kmax, b - t, converged, nwin,
                               (counters[F_EVALUATIONS] - f_attempt) / (b - t), climb)
            st.climb_cost, st.climb_direction = climb[0], climb[1]
            # no growth for REJECTION_HOLD slabs after a rejection: growing straight back
            # into the length that was rejected costs another whole slab
            st.k_slab = limit if st.hold == 0 else min(limit, max(st.k_slab, b - t))
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
        blowup = residual_indicators(ne, comp, ea, eb, values, fend, end_derivative, resid,
                                     unfiltered, not solved, o.loosening, position, indptr,
                                     indices, jacobian, jdiag, coupling, gamma, elist,
                                     group_order, local, newton, active, nactive, emax, kact,
                                     umax, counters)
        inside, inside_of, inside_at = 0.0, -1, 0.0
        if not (fixed or solved):
            inside, inside_of, inside_at = interior_indicators(
                ne, comp, ea, eb, values, resid, unfiltered, jdiag, interior, fi, p, x, indptr,
                indices, cptr, celems, nodes, bary, states, out, o.delivered, atol, rtol,
                umax, emax, counters)
        deviation, deviated, deviated_eps = 0.0, -1, 0.0
        if not solved:
            deviation, deviated, deviated_eps = slab_deviation(ne, comp, values, resid,
                                                               unfiltered, atol, rtol)
        nchecked = 0
        if nfrozen > 0:
            if rptr.shape[0] == 0:
                rptr, readers = transpose_pattern(indptr, indices, N)
            check_round += 1
            nchecked, frozen_blowup = check_frozen(
                check_round, active, nactive, o.autonomous, rptr, readers, check_stamp, frozen,
                checked, uw, values, cptr, celems, fi, p, t, b, T, x, out, jdiag, coupling,
                emax, umax, kact, drift, atol, rtol, counters)
            blowup = blowup or frozen_blowup
        scale_indicators(active, nactive, checked, nchecked, emax, atol, rtol, umax)
        if nchecked > 0 and wake_failed(checked, nchecked, emax, ACCEPTANCE_MARGIN, t, x, frozen,
                                        quiet, last_a, last_b, counters, out_comp, out_a,
                                        out_b, out_values):
            st.regroup = True
        if blowup:
            st.retry = False
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
            accept = choose_steps(active, nactive, checked, nchecked, emax, kact, kdes, frozen,
                                  solved, o.order, o.safety, kmax)
        st.outside = leaves_domain(ne, comp, values, floor, kdes, kact) if bounded else -1
        if st.outside >= 0:
            counters[OUTSIDE] = st.outside + 1
            if fixed:
                return CONSTRAINT
            accept = False
        # a synchronised slab on Jacobian rows already used (see JACOBIAN_AGE) leaves its
        # steps untied: the next synchronised slab takes the smallest, which the ties and
        # grading never change (``tie_and_grade``), and a slab that leaves synchronisation
        # ties them first (``untied`` above)
        if not fixed and not (solved and st.jacobian_age > 1):
            reach_valid = tie_and_grade(reach_valid, kdes, active[:nactive], frozen, indptr,
                                        indices, jacobian, reach, lopsided, strength, reaction,
                                        jdiag, lowered, stack, acting)
        if not accept:
            counters[REJECTED] += 1
            # the steps chosen at the slab's start no longer fit its end (a front arrives):
            # retry the same slab with the failed components refined, from the rejected
            # values; a second rejection in a row shortens the slab
            st.hold = REJECTION_HOLD
            if st.retry or ne > oea.shape[0]:  # (no room: never with the driver's carry)
                st.k_slab = min(st.k_slab, 0.5 * (b - t))
                st.retry = False
                continue
            st.k_slab = min(st.k_slab, b - t)
            # (into the carried arrays: the output buffers' room bounds ne, see carry)
            keep_attempt(ne, ea, eb, values, oea, oeb, ovalues)
            _keep_partition(N, ne, cptr, celems, ocptr, ocelems)
            st.retry = True
            continue
        st.retry = False
        if bounded:
            project(ne, comp, values, floor, projected)
        if block:
            _store_block(N, t, b, values, counters, out_block_a, out_block_b, out_blocks)
            kmin = b - t
        else:
            kmin = _store_slab(ne, comp, ea, eb, values, counters, out_comp, out_a, out_b,
                               out_values)
        st.mono_elements += (b - t) / kmin * N
        st.deviation = max(st.deviation, deviation)  # (adaptivity.undamped_warning)
        st.last_deviation, st.deviated, st.deviation_error = deviation, deviated, deviated_eps
        if inside > st.interior:  # (global_error.interior_warning)
            st.interior, st.interior_of, st.interior_at = inside, inside_of, inside_at
        counters[SLABS] += 1
        counters[SYNCHRONISED] += solved
        st.hold = max(0, st.hold - 1)
        counters[SUBSLABS] += nsub
        any_quiet = _move_to_end(active, nactive, cptr, celems, ea, eb, values, fend, x, fixed,
                                 drift, atol, rtol, umax, T - b, jdiag, coupling, last_a,
                                 last_b, last_values)
        if solved:  # f(x, b), unless a value was projected
            st.f0_time = b
            for i in range(N):
                f0[i] = fvec[i]
        leaving, any_projected = -1, False
        if bounded:
            leaving, any_projected = drives_out(active, nactive, projected, x, fi, p, b, T,
                                                floor, out, counters)
        if any_projected:
            st.f0_time = math.nan
        if leaving >= 0:
            counters[OUTSIDE] = leaving + 1
            st.t = b
            return CONSTRAINT
        # (nothing quiet, nothing checked: freeze would change nothing)
        if not fixed and b < T and (any_quiet or nchecked > 0) and freeze(
                b, b - t, active[:nactive], checked[:nchecked], indptr, indices, drift, atol,
                rtol, umax, x, frozen, kdes, last_a, last_b, quiet, uw, counters, out_comp,
                out_a, out_b, out_values):
            st.regroup = True
            if nchecked > 0:
                wake_readers(b, b - t, checked, nchecked, frozen, quiet, drift, rptr, readers,
                             indptr, indices, ji, x, p, jrow, atol, rtol, kdes, last_a, last_b,
                             wake_stack, wake_depth, counters, out_comp, out_a, out_b,
                             out_values)
        t = b
        st.t = t


advance = Loop(_advance, _SIGNATURE, "the multi-adaptive loop (mcG(q), mdG(q))", 13,
               error_model="numpy")
