"""The mono-adaptive time-slab loop: cG(q) and dG(q) with one time step for all components.

One compiled function advances the solution slab by slab (build, solve, check, accept or
reject, as DOLFIN's TimeStepper) and stores every accepted element's nodal values; it returns
when it reaches T, when its output buffer is full (the driver then calls it again, which is
also where progress is reported), or when it cannot continue.
"""
import math
from functools import cache

import numpy as np
from numba import njit, types

from dolfinode.adaptivity import (
    accepted_step,
    filter_estimate,
    next_step,
    stiff_deviation,
    stiff_factor,
)
from dolfinode.compile.jit import Loop, helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT, address, rhs_kernel
from dolfinode.linalg.newton_matrix import shift, store_jacobian
from dolfinode.methods.method import lagrange_weights
from dolfinode.solvers.slab import (
    GIVE_UP,
    TRANSFORMED,
    factor,
    factor_stages,
    fixed_point,
    near_step,
    newton,
    newton_tolerance,
    transformed_tables,
)
from dolfinode.timeslab import (
    BLOWUP,
    CONSTRAINT,
    CONSTRAINT_CUT,
    DEFAULT,
    DONE,
    F_EVALUATIONS,
    FAILED_SOLVES,
    FULL,
    ITERATIONS,
    JACOBIANS,
    NEWTON,
    NEWTON_NEEDED,
    NONCONVERGENCE,
    OUTSIDE,
    REJECTED,
    ROUNDING,
    SLABS,
    STIFF,
    STORED,
    UNDERFLOW,
    smallest_step,
)
from dolfinode.timeslab.contract import OPTIONS_TYPE, STATE_TYPE

#: A fixed step's running sum t0 + k + k + ... rounds by up to this x |t| a step.
SUM_ROUNDING = np.finfo(float).eps

#: After a failed nonlinear solve of length k_fail, steps stay below SOLVER_MARGIN x k_fail,
#: and k_fail grows by NEWTON_PROBE per accepted step.
SOLVER_MARGIN = 0.8
NEWTON_PROBE = 1.2
#: ... and, for dG(q), the limit is lifted once Newton contracts at rate theta <= SOLVER_FREE:
#: else one failure early in a run holds every later step to 1.2x growth (ROBER dG(3) from a first
#: step of 6.25e-4: 166 slabs, 69 without the hold; VDPOL at 1e-1: 194 and 129). cG(q) keeps
#: the limit: its failures come back with the undamped deviation (ROBER cG(2) at 1e-4 fails).
SOLVER_FREE = 0.1
#: Fixed-point iteration, and Newton's on dG(q), start from the last element extrapolated
#: (see :func:`extrapolate`) when the step is at most EXTRAPOLATE times the last one, else
#: from explicit Euler, whose first increment on stiff slabs is 5-70 x the tolerance (HIRES,
#: ROBER, VDPOL): with the stop relative to the delivered error (slab.newton_tolerance) the
#: extrapolated start saves 8-27 % of dG(3)'s iterations there (doc/design/newton.md).
#: Newton on cG(q) starts from Euler: extrapolated, cG(3) on HIRES at 1e-2 and 1e-3
#: delivered 0.02-0.08 x the tolerance (0.6 and 1.3 from Euler), outside the calibration.
EXTRAPOLATE = 2.0
#: From an extrapolated start, Newton's J (and the error filter's) is evaluated at the
#: predicted stage nearest the slab's middle (:func:`middle_stage`), not at its start: the
#: simplified iteration contracts at a rate set by how far J at the stages is from the one J
#: used, and from the middle that distance is about half the slab. dG(3) on HIRES, ROBER, VDPOL
#: at 1e-3..3e-10 takes 7-25 % fewer iterations (doc/design/newton.md). An Euler start (cG(q),
#: a step more than EXTRAPOLATE x the last) keeps J at the start: its stages overshoot; so
#: does a J not finite at the prediction.
#: A fresh Newton solve that fails is tried once more from the constant x, except after an
#: extrapolated start whose iteration contracted (took more than RETRY_AFTER iterations)
#: before it failed: there J or the step failed, not the start, and the retry from x
#: converged in 5 of 131 such failures (dG(1..5) on HIRES, ROBER, VDPOL, POLLU, VDPOLM at
#: 1e-2..1e-10; 8 iterations each on HIRES dG(3) at 1e-6); after a first increment that grew,
#: in 50 of 541 (doc/design/newton.md).
RETRY_AFTER = 2
#: cG(q) is not L-stable (|R(-inf)| = 1): a stiff component's deviation from its
#: quasi-steady state is never damped, and once the state decays below it, Newton fails on
#: most steps and the steps collapse (ROBER, cG(2), tolerance 1e-3: 322,000 slabs, 45 % failed
#: solves). A cG loop stops when Newton fails after UNDAMPED_FAILURES failed solves, once they
#: are at least UNDAMPED_SHARE of the accepted slabs, and the driver says why (dG(q) damps it).
UNDAMPED_FAILURES = 1000
UNDAMPED_SHARE = 0.25
#: The factors of one Jacobian (stage matrices, error filter) are kept over slabs, as RADAU5
#: and CVODE keep theirs, when a factorization is estimated to take at least REUSE_TIME seconds
#: (``NewtonStructure.seconds``, complex; 2e5 multiply-adds of the banded LU): while the step
#: stays within a factor REUSE_RATIO of the factors' step, for at most REUSE_AGE slabs, and
#: until a Newton iteration with them fails (then they are made afresh and the slab is solved
#: again). On wide bands a factorization costs ten or more solves, so keeping it pays; on
#: narrow ones only over slabs of the same step (THETA_KEEP).
REUSE_TIME = 1.3e-4
REUSE_RATIO = 1.25
REUSE_AGE = 20
#: Every system also keeps its factors over slabs of the same step (fixed steps, or a step
#: the controller repeats) while the last Newton iteration with them contracted fast (rate
#: theta <= THETA_KEEP, see slab.newton), for at most REUSE_AGE slabs; with kept factors Newton
#: gives up when an increment shrinks by less than THETA_KEPT, and the slab is solved again
#: with a fresh J and factors. Factors of another step leave an iteration error at the
#: stopping tolerance that fresh ones do not (a linear system: none), which breaks the energy
#: conservation of cG on the harmonic oscillator (4e-10 against 1e-12); RADAU5's freeze of a
#: step that would grow by at most 1.2x, to keep its factors exact, costs 50-60% more slabs
#: with dG(1) (doc/design/newton.md).
THETA_KEEP = 0.03
THETA_KEPT = 0.25
#: False: factor every Newton slab afresh unless REUSE_TIME says otherwise (for comparisons).
KEEP_FACTORS = True
#: With the default solver, Newton's method (taken when fixed-point iteration fails) gives way
#: to fixed-point iteration again when that is estimated SWITCH_BACK times cheaper per unit
#: time: its iterations per slab times the stages over the step it last converged on, against
#: Newton's measured cost per slab (iterations, solves and factorizations in f evaluations, see
#: newton_costs) over the step the error control asks for. A fixed-point failure then shortens
#: the step (to the last one it converged on, at most half), as with
#: nonlinear_solver="fixed-point", while that is still the cheaper. Mildly stiff systems
#: (diffusion) converge by fixed-point iteration on steps a few times shorter than Newton's at
#: a fraction of the cost per step (the 2-D Brusselator: doc/design/methods.md).
SWITCH_BACK = 0.5
#: ... only where Newton's steps have settled (the error control asks for at most
#: SETTLED x the last step: in a transient Newton's steps grow far beyond fixed point's), and
#: back to Newton when the error control of fixed point asks for steps below RETURN x
#: k_newton (state; without Newton's error filter a stiff component's estimate is far larger).
SETTLED = 1.25
RETURN = 0.25
#: Seconds of one f evaluation per Jacobian nonzero and component, and per call (a model,
#: fitted to the chain and reaction-front kernels).
F_ENTRY, F_CALL = 0.6e-9, 30e-9

_f8 = types.float64[::1]
_i8 = types.int64[::1]
#: (position, kl, ku, ptr, idx, diag, jmap): see :mod:`dolfinode.linalg.newton_matrix`
_STRUCTURE = types.Tuple((_i8, types.int64, types.int64, _i8, _i8, _i8, _i8))
_SIGNATURE = types.int64(
    types.intp, types.intp, _f8,            # addresses of f and J, p
    _i8, _i8, _STRUCTURE,                   # indptr, indices, Newton matrix structure
    types.float64[:, ::1], _f8, _f8,       # A, b0, tau
    types.float64[:, ::1], types.float64[:, ::1], types.complex128[::1],  # A = T B T^-1, eig B
    _f8, _f8, _f8,                           # nodes, barycentric weights, end_derivative
    OPTIONS_TYPE, _f8, _f8,                  # options, atol, floor
    _f8, _f8, STATE_TYPE, _i8,               # x, f0, state, counters
    types.Tuple((types.float64[:, :, ::1], types.float64[:, ::1],  # carried (see ``carry``)
                 types.float64[:, :, ::1], types.complex128[:, :, ::1],
                 types.int64[:, ::1], _i8)),
    _f8, _f8, types.float64[:, :, ::1],      # out_t, out_k, out_X
)


@cache
def method_tables(method):
    """The method's tables in the order :func:`advance` takes them (A, b0, tau, T, T^{-1},
    eigenvalues, nodes, barycentric weights, end derivative), as the writable arrays of its
    signature (numba types read-only arrays apart); made once per method, as advance only
    reads them."""
    m = method
    tables = (m.A, m.b0, m.nodes[m.stages], m.stage_transform, m.stage_transform_inverse,
              m.stage_eigenvalues, m.nodes, m.barycentric_weights, m.end_derivative)
    return tuple(np.array(table) for table in tables)


def carry(N, method, structure, ready, last=None):
    """The arrays the loop carries from one call to the next (with the state's fields, see
    :mod:`dolfinode.timeslab.contract`): the last slab's nodal values (1, q + 1, N), which
    predict the next slab's stages (``last``: those of an earlier carry, kept), and the
    Newton workspace for the matrices' ``structure`` (:class:`~dolfinode.linalg.
    newton_matrix.NewtonStructure`) once their storage is decided (``ready``; else empty):
    J, then the error filter's factors, in the structure's storage, the factors of one
    matrix I - k lambda J per real eigenvalue lambda of A and per complex pair, and their
    pivots."""
    if last is None:
        last = np.empty((1, method.q + 1, N))
    n_real = n_complex = rows = columns = n = 0  # (no workspace before it is decided)
    if ready:
        _, kl, ku, ptr, idx, _, _ = structure.tuple
        rows, columns = (1, idx.shape[0]) if ptr.shape[0] > 0 else (N, 2 * kl + ku + 1)
        n_real, n_complex = _stage_systems(method)
        n = N
    return (last, np.zeros((rows, columns)), np.zeros((n_real, rows, columns)),
            np.zeros((n_complex, rows, columns), dtype=np.complex128),
            np.zeros((n_real + n_complex, n), dtype=np.int64), np.zeros(n, dtype=np.int64))


def holds_workspace(carried):
    """Whether ``carried`` (a :func:`carry`) holds the Newton workspace, made once the
    storage was decided (its pivots are then not empty)."""
    return carried[4].size > 0


@cache
def _stage_systems(method):
    """The real and complex systems of a Newton step of ``method``: one per real eigenvalue
    of its stage matrix, one per complex pair (made once: numpy's count costs 3 us)."""
    real = sum(1 for lam in method.stage_eigenvalues if lam.imag == 0.0)
    return real, len(method.stage_eigenvalues) - real


@helper(**NO_REFCOUNT)
def _suspend(out_k, out_X, counters, last_X, rate, st):
    """Keep what the next call goes on from: the last slab stored by this call (if any) in
    the carried ``last_X``, Newton's last contraction rate in the state."""
    st.newton_rate = rate[0]
    n = counters[STORED] - 1
    if n >= 0:
        st.k_last = out_k[n]
        for j in range(out_X.shape[1]):
            for i in range(out_X.shape[2]):
                last_X[0, j, i] = out_X[n, j, i]


@helper(**NO_REFCOUNT)
def extrapolate(out_X, n, nodes, bary, k_prev, k, tau, X, weights):
    """Predict the stages from the polynomial of stored element n (nodal values out_X[n]),
    continued past its end: X_s = U_n(1 + tau_s k / k_prev). Its error is O(k^(q+1)) on a
    smooth solution, against O(k^2) for explicit Euler. ``weights``: work space, one entry
    per node (the basis at each stage's time, :func:`lagrange_weights`)."""
    N = out_X.shape[2]
    for s in range(tau.shape[0]):
        lagrange_weights(1.0 + tau[s] * k / k_prev, nodes, bary, weights)
        for i in range(N):
            value = 0.0
            for j in range(nodes.shape[0]):
                value += weights[j] * out_X[n, j, i]
            X[s * N + i] = value


@helper()
def middle_stage(tau):
    """The stage whose time t + tau_s k is nearest the slab's middle (the first of a tie)."""
    middle = 0
    for s in range(tau.shape[0]):
        if abs(tau[s] - 0.5) < abs(tau[middle] - 0.5):
            middle = s
    return middle


@njit(cache=True, inline="always")
def euler_stages(x, f0, k, tau, X):
    """X_s = x + tau_s k f0 for every stage: explicit Euler (k = 0: the constant x)."""
    N = x.shape[0]
    for s in range(tau.shape[0]):
        for i in range(N):
            X[s * N + i] = x[i] + tau[s] * k * f0[i]


@helper()
def undamped(failed, slabs):
    """Whether a cG loop's failed nonlinear solves show a stiff deviation cG(q) cannot damp."""
    return failed > UNDAMPED_FAILURES and failed >= UNDAMPED_SHARE * slabs


@linked(returns=types.int64, what="the declared domain's check", seconds=1)
@helper()
def leaves_domain(X, floor):
    """The first component with a stage value X_(s N + i) below its floor (-atol_i for a
    component declared nonnegative, -inf for the others), or -1."""
    N = floor.shape[0]
    for s in range(X.shape[0] // N):
        for i in range(N):
            if X[s * N + i] < floor[i]:
                return i
    return -1


@linked(returns=types.boolean, what="the declared domain's projection", seconds=1)
@helper()
def project(X, floor):
    """Set the stage values of the nonnegative components in [floor, 0) to 0; returns whether
    any changed."""
    N = floor.shape[0]
    changed = False
    for s in range(X.shape[0] // N):
        for i in range(N):
            if X[s * N + i] < 0.0 and floor[i] > -math.inf:
                X[s * N + i] = 0.0
                changed = True
    return changed


@linked(returns=types.int64, what="the declared domain's projection", seconds=1)
@helper()
def drives_out(u, fu, floor, remaining):
    """The first nonnegative component at zero that f drives below its floor by the end,
    f_i(u) (T - t) < -atol_i, or -1. For a right-hand side that keeps the nonnegative
    components so (f_i >= 0 where u_i = 0) there is none: without this check a projected
    solution would stay at 0 where the exact one turns negative."""
    for i in range(u.shape[0]):
        if u[i] == 0.0 and floor[i] > -math.inf and fu[i] * remaining < floor[i]:
            return i
    return -1


def newton_costs(structure, eigenvalues, N, nnz, stages):
    """(NEWTON_UNITS, FACTOR_UNITS): a Newton iteration (f at the S stages, one solve per real
    eigenvalue of the stage matrix and one complex one per pair) and a Jacobian with its
    factorizations (the stage matrices and the error filter's), in f evaluations (estimated:
    F_ENTRY, F_CALL and the structure's estimates)."""
    f_seconds = F_ENTRY * (nnz + N) + F_CALL
    real = int(np.sum(np.imag(eigenvalues) == 0))
    pairs = len(eigenvalues) - real
    solves = (real * structure.solve_seconds(False) + pairs * structure.solve_seconds(True))
    factors = ((real + 1) * structure.factor_seconds(False)
               + pairs * structure.factor_seconds(True))
    return stages + solves / f_seconds, 1.0 + (nnz * F_ENTRY + factors) / f_seconds


@helper()
def fixed_point_cheaper(k_fp, k_newton, S, st):
    """Whether fixed-point iteration on steps k_fp is estimated SWITCH_BACK times cheaper per
    unit time than Newton's method on steps k_newton (False before Newton was measured)."""
    return (st.newton_cost > 0.0 and k_fp > 0.0 and st.fp_iterations * S / k_fp
            < SWITCH_BACK * st.newton_cost / k_newton)


def _advance(f_address, jac_address, p, indptr, indices, structure, A, b0, tau,
            transform, transform_inverse, eigenvalues, nodes, bary, end_derivative, options,
            atol, floor, x, f0, state, counters, carried, out_t, out_k, out_X):
    """Advance (x, t) towards T, storing accepted elements in out_*; returns a status code.
    It carries its state from one call to the next in ``state`` and ``carried``
    (:func:`carry`), unless ``state[0].carried`` is False (a fresh start).

    A step on which a stage value leaves the declared domain (``leaves_domain``) is
    shortened by CONSTRAINT_CUT and retried; an accepted one is projected on it."""
    f = rhs_kernel(f_address)
    jac = rhs_kernel(jac_address)
    N = x.shape[0]
    S = A.shape[0]
    n_nodes = nodes.shape[0]
    o = options[0]
    st = state[0]
    is_dg = o.is_dg
    fixed = o.fixed
    mode = o.solver
    max_iter = o.max_iter
    rtol, T, kmax, safety, dtol = o.rtol, o.T, o.kmax, o.safety, o.dtol
    # the estimate is O(k^(q+1)) for cG(q) and dG(q) (see dolfinode.adaptivity)
    order = o.order
    gamma = o.gamma
    loosening = o.loosening

    X = np.empty(S * N)
    F = np.empty(S * N)
    G = np.empty(S * N)
    filter_rhs = np.empty(N)
    unfiltered = np.empty(N)  # k R(t_n) before the filter
    fend = np.empty(N)
    jdata = np.empty(indices.shape[0])
    # the last slab's values, the Newton workspace (its factors are used over slabs), in
    # the structure's storage: J, once the stage matrices are factored the error filter's
    # I - gamma k J and its factors (the filter is applied with Newton only)
    last_X, jb, ab_real, ab_complex, ipiv, ipiv_filter = carried
    if not st.carried:
        st.k_solver, st.k_last, st.k_factored, st.theta = math.inf, 0.0, 0.0, math.inf
        st.k_accuracy = st.k_next
        st.age, st.filter_ok, st.newton_rate, st.carried = 0, False, 0.0, True
    # Newton's work space, twice the stages: dG(q)'s residual keeps V in the second half and
    # reads the transformed tables (slab.newton)
    Z = np.empty(2 * S * N)
    A_newton, b0_newton = A, b0
    newton_flags = 0
    if is_dg:
        A_newton, b0_newton = np.empty((S, S)), np.empty(S)
        transformed_tables(A, b0, transform_inverse, A_newton, b0_newton)
        newton_flags = GIVE_UP | TRANSFORMED
    z_real = np.empty(N)
    middle = middle_stage(tau)
    x_middle = np.empty(N)  # the predicted stage there
    z_complex = np.empty(N, dtype=np.complex128)
    reuse = o.reuse
    keep = o.keep_factors
    rate = np.empty(1)  # Newton's contraction rate on the last slab (newton)
    rate[0] = st.newton_rate
    # Newton stops relative to the delivered error (newton_tolerance), dG(q) only: cG(q) is
    # not L-stable and keeps a stiff component's iteration error (ROBER cG(2), 1e-2)
    delivered = o.delivered if is_dg else 0.0
    rounding = ROUNDING / rtol  # the rounding level of the scaled norm
    est = np.empty(N)
    w = np.empty(S * N)  # weights of the scaled norm (solvers' work space)
    weights = np.empty(n_nodes)  # extrapolate's work space
    counters[STORED] = 0
    # whether a component is declared nonnegative (floor > -inf): else no domain checks
    bounded = False
    for i in range(N):
        bounded = bounded or floor[i] > -math.inf

    t = st.t
    k = st.k_next
    if not st.have_f0:
        f(address(x, 0), t, address(p, 0), address(f0, 0))
        counters[F_EVALUATIONS] += 1
        st.have_f0 = True
    capacity = out_t.shape[0]
    while counters[STORED] < capacity:
        if t >= T:
            _suspend(out_k, out_X, counters, last_X, rate, st)  # (a piece of events goes on)
            return DONE
        remaining = T - t
        if not fixed:
            k = min(k, kmax)
        nominal = k  # a fixed step shortened to end at T (a jump of f) resumes after it
        # a fixed step also absorbs the running sum's rounding, up to an ulp of |t| a step
        # over the (T - t0) / k steps (1e5 steps of 1e-5 left a sliver of 1e-11 to T)
        if (k >= remaining * (1.0 - 1e-9) or (not fixed and 1.1 * k >= remaining)
                or (fixed and remaining - k <= o.span / nominal * SUM_ROUNDING
                    * max(abs(t), abs(T)))):
            k = remaining
        # The slab is [t, fl(t + k)]: its length is the step t + k represents, or the
        # quadrature of f(t) over it (a pulse) and the solution's grid disagree by up to
        # ulp(t). The chosen step decides whether kept factors serve (a repeated step
        # varies by ulps once rounded).
        chosen = k
        if k < remaining:
            k = (t + k) - t
        kmin = smallest_step(t, o.span)
        if k < kmin and k < remaining:
            return UNDERFLOW
        # Each slab's discrete (iteration) error adds up over the (T - t0)/k slabs, and for
        # oscillations it does so with one sign (a systematic energy drift), so the stopping
        # tolerance is dtol x k/(T - t0): the sum stays below dtol x tolerance. It is not
        # taken below the rounding level ROUNDING/rtol of the scaled norm (nor above dtol).
        dtol_k = dtol
        if not fixed:
            dtol_k = max(dtol * min(1.0, k / o.span), min(dtol, rounding))
        use_newton = mode == NEWTON or (mode == DEFAULT and counters[STIFF] == 1)
        n_prev = counters[STORED] - 1
        extrapolated = True
        if (is_dg or not use_newton) and n_prev >= 0 and k <= EXTRAPOLATE * out_k[n_prev]:
            extrapolate(out_X, n_prev, nodes, bary, out_k[n_prev], k, tau, X, weights)
        elif (is_dg or not use_newton) and n_prev < 0 and 0.0 < k <= EXTRAPOLATE * st.k_last:
            extrapolate(last_X, 0, nodes, bary, st.k_last, k, tau, X, weights)  # (last call's)
        else:
            extrapolated = False
            euler_stages(x, f0, k, tau, X)
        iters = -1
        iterations_before, jacobians_before = counters[ITERATIONS], counters[JACOBIANS]
        if not use_newton:
            iters = fixed_point(f, p, x, f0, t, k, A, b0, tau, atol, rtol, dtol_k, max_iter,
                                X, F, G, w, counters)
            if iters >= 0:
                st.fp_iterations = 0.7 * st.fp_iterations + 0.3 * iters
                st.fp_step = k
            elif mode == DEFAULT:
                if st.fp_step >= k:  # it converged on this step before, not now
                    st.fp_step = 0.5 * k
                k_fp = min(st.fp_step, 0.5 * k)
                if fixed_point_cheaper(k_fp, st.k_accuracy, S, st) and k_fp >= kmin:
                    counters[FAILED_SOLVES] += 1  # on the shorter step, as with "fixed-point"
                    st.k_solver = k
                    k = k_fp
                    continue
                counters[STIFF] = 1  # treat the problem as stiff
                use_newton = True
                extrapolated = False
                euler_stages(x, f0, k, tau, X)
        if use_newton and not o.newton_ready:  # (the driver carries its workspace then)
            st.t = t
            st.k_next = k
            _suspend(out_k, out_X, counters, last_X, rate, st)
            return NEWTON_NEEDED
        if use_newton:
            iterations_before = counters[ITERATIONS]  # not the failed fixed point's
            st.age += 1
            kept = st.age <= REUSE_AGE and (
                (keep and st.theta <= THETA_KEEP and chosen == st.k_factored)
                or (reuse and near_step(chosen, st.k_factored, REUSE_RATIO)))
            for fresh in range(0 if kept else 1, 2):
                if fresh == 1:
                    if kept:  # the kept factors did not converge: afresh, from the start
                        euler_stages(x, f0, k, tau, X)
                    at_start = not extrapolated or kept
                    if not at_start:
                        for i in range(N):
                            x_middle[i] = X[middle * N + i]
                        jac(address(x_middle, 0), t + tau[middle] * k, address(p, 0),
                            address(jdata, 0))
                        for value in jdata:  # (a prediction outside f's domain)
                            at_start = at_start or not math.isfinite(value)
                    if at_start:
                        jac(address(x, 0), t, address(p, 0), address(jdata, 0))
                    counters[JACOBIANS] += 1
                    store_jacobian(jdata, indptr, indices, structure, jb)
                    factored = factor_stages(jb, k, eigenvalues, structure, ab_real,
                                             ab_complex, ipiv, counters)
                    st.k_factored = chosen if factored else 0.0
                    st.age = 0
                    if not factored:
                        break
                    # J is not needed once factored: jb takes the error filter's factors
                    shift(jb, gamma * k, structure, jb)
                    st.filter_ok = factor(jb, structure, ipiv_filter, counters)
                # Computed before the call: a conditional among its arguments splits the
                # call over branches, and numba then increfs and decrefs (atomically) every
                # array argument passed before it, on every solve (3 % of ROBER's solve).
                theta_max = 1.0 if fresh == 1 else THETA_KEPT
                tol = newton_tolerance(dtol_k, min(dtol, rounding), dtol, delivered,
                                       k / o.span, counters[SLABS])
                attempt_start = counters[ITERATIONS]
                for attempt in range(2 if fresh == 1 else 1):  # kept factors: one try
                    if attempt == 1:
                        # On stiff components the Euler predictor overshoots by |k lambda|
                        # (ROBER at k ~ t: 1e6-1e11); start once more from the constant x
                        # before reducing k. Not where an extrapolated start contracted
                        # before it failed (RETRY_AFTER): the start was not what failed.
                        if (extrapolated and not kept
                                and counters[ITERATIONS] - attempt_start > RETRY_AFTER):
                            break
                        euler_stages(x, f0, 0.0, tau, X)
                    iters = newton(f, p, x, f0, t, k, A_newton, b0_newton, tau, transform,
                                   transform_inverse, atol, rtol, tol, max_iter, theta_max,
                                   newton_flags, X, F, G, Z, ab_real, ab_complex, structure,
                                   ipiv, z_real, z_complex, w, counters, rate)
                    if iters >= 0:
                        break
                if iters >= 0:
                    st.theta = rate[0]
                    break
        if iters < 0:
            counters[FAILED_SOLVES] += 1
            if fixed or (use_newton and not is_dg
                         and undamped(counters[FAILED_SOLVES], counters[SLABS])):
                st.k_next = k
                return NONCONVERGENCE
            st.k_solver = k
            k *= 0.25
            if k < kmin:
                return NONCONVERGENCE
            continue
        # end-point value and residual
        end = (S - 1) * N  # X[end:] is the end-point value
        f(address(X, end), t + k, address(p, 0), address(fend, 0))
        counters[F_EVALUATIONS] += 1
        blowup = False
        for i in range(N):
            if not (math.isfinite(X[end + i]) and math.isfinite(fend[i])):
                blowup = True
                break
            kdu = 0.0
            for j in range(n_nodes):
                if is_dg:
                    xi = X[j * N + i]
                else:
                    xi = x[i] if j == 0 else X[(j - 1) * N + i]
                kdu += end_derivative[j] * xi
            est[i] = kdu - k * fend[i]  # k R(t_n)
        filtered = False
        if use_newton and not blowup:
            # (I - gamma k J)^-1 with the J and the step of the stage factors
            blowup = not st.filter_ok
            if not blowup:
                filtered = loosening > 0.0
                if filtered:
                    # by element: a slice assigned from an array compiles numba's long
                    # shape-error message
                    for i in range(N):
                        unfiltered[i] = est[i]
                filter_estimate(jb, structure, ipiv_filter, est, filter_rhs)
        eps = 0.0
        deviation, deviated, deviated_eps = 0.0, -1, 0.0
        for i in range(N):
            eps_i = abs(est[i]) / (atol[i] + rtol * abs(X[end + i]))
            if filtered and eps_i > 0.0:
                d = stiff_deviation(abs(est[i]), abs(unfiltered[i]), abs(X[end + i]))
                if d > deviation:
                    deviation, deviated, deviated_eps = d, i, eps_i
                eps_i *= stiff_factor(abs(est[i]), abs(unfiltered[i]), loosening)
            eps = max(eps, eps_i)
        if blowup or not math.isfinite(eps):
            if fixed:
                return BLOWUP
            k *= 0.25
            counters[REJECTED] += 1
            if k < kmin:
                return BLOWUP
            continue
        accepted = fixed or eps <= 1.0
        if accepted:
            outside = leaves_domain(X, floor) if bounded else -1
            if outside >= 0 and not fixed and CONSTRAINT_CUT * k >= kmin:
                counters[REJECTED] += 1
                k *= CONSTRAINT_CUT
                continue
            if outside < 0 and bounded and project(X, floor):
                f(address(X, end), t + k, address(p, 0), address(fend, 0))
                counters[F_EVALUATIONS] += 1
                outside = drives_out(X[end:], fend, floor, T - t - k)
            if outside >= 0:
                counters[OUTSIDE] = outside + 1
                st.t = t
                st.k_next = k
                return CONSTRAINT
            n = counters[STORED]
            out_t[n] = t
            out_k[n] = k
            for j in range(n_nodes):
                for i in range(N):
                    if is_dg:
                        out_X[n, j, i] = X[j * N + i]
                    else:
                        out_X[n, j, i] = x[i] if j == 0 else X[(j - 1) * N + i]
            counters[STORED] += 1
            counters[SLABS] += 1
            st.deviation = max(st.deviation, deviation)  # (adaptivity.undamped_warning)
            st.last_deviation, st.deviated, st.deviation_error = (deviation, deviated,
                                                                  deviated_eps)
            t = t + k if k < remaining else T
            for i in range(N):
                x[i] = X[end + i]
                f0[i] = fend[i]
            if fixed:
                k_new = nominal
            elif is_dg:
                k_new = accepted_step(k, eps, st.k_accepted, st.eps_prev, order, safety,
                                      st.theta if use_newton else 1.0)
            else:
                k_new = next_step(k, eps, st.eps_prev, order, safety, True)
            st.k_accepted = k
            st.k_accuracy = k_new
            if use_newton and mode == DEFAULT:
                cost = ((counters[ITERATIONS] - iterations_before) * o.newton_units
                        + (counters[JACOBIANS] - jacobians_before) * o.factor_units)
                st.newton_cost = (cost if st.newton_cost == 0.0
                                  else 0.7 * st.newton_cost + 0.3 * cost)
                k_fp = min(st.fp_step, k_new)
                if k_new <= SETTLED * k and fixed_point_cheaper(k_fp, k_new, S, st):
                    counters[STIFF] = 0  # back to fixed point, on steps up to k_fp
                    st.k_solver = k_fp / SOLVER_MARGIN
                    st.k_newton = k_new
            elif mode == DEFAULT and k_new < RETURN * st.k_newton:
                counters[STIFF] = 1  # fixed point's error control throttles: Newton again
                st.k_newton = 0.0
            k_new = min(k_new, SOLVER_MARGIN * st.k_solver)
            # a fast contraction says dG's failure is behind; cG's recurs (undamped)
            st.k_solver = math.inf if use_newton and is_dg and st.theta <= SOLVER_FREE else (
                st.k_solver * NEWTON_PROBE)
            st.eps_prev = eps
            k = k_new
        else:
            counters[REJECTED] += 1
            k = next_step(k, eps, 1.0, order, safety, False)
            st.k_accuracy = k
        st.t = t
        st.k_next = k
    st.t = t
    st.k_next = k
    _suspend(out_k, out_X, counters, last_X, rate, st)
    return DONE if t >= T else FULL


advance = Loop(_advance, _SIGNATURE, "the mono-adaptive loop (cG(q), dG(q))", 8,
               error_model="numpy")
