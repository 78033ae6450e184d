"""The steps of the multi-adaptive loop: each component's next step from its error estimate,
the ties and grading of steps along strong couplings, and the slab length limit."""
import math

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT

#: Largest step ratio between strongly coupled components (see ``grade``), and sweeps.
GRADING = 2.0
GRADING_SWEEPS = 4
#: Most visits per row of ``propagate`` (ties passed on along chains of strong couplings).
PROPAGATION_SWEEPS = 8
#: A mutual coupling with |J_ij| >= ASYMMETRY^2 |J_ji| ties u_j's step to u_i's (``propagate``).
ASYMMETRY = 10.0
#: Factor by which the slab length limit climbs on the cost per unit time (``slab_limit``).
SLAB_CLIMB = 1.5


@linked
@helper(**NO_REFCOUNT)
def propagate(kdes, rows, frozen, indptr, indices, strength, jdiag, lowered, stack):
    """Small steps travel along strong dependencies: k_j <= k_i when f_i reacts to u_j within
    one step of i (|J_ij| k_i > 1; DOLFIN's "poor man's dual weighting", restricted to the
    couplings that matter), or when the coupling is mutual and lopsided,
    |J_ij| >= ASYMMETRY^2 |J_ji| > 0: then an error d in u_j becomes sqrt(|J_ij / J_ji|) d in
    u_i over i's time scale (the scaling that makes the pair symmetric; omega for x' = v,
    v' = -omega^2 x), so u_j must be as resolved as u_i although its own indicator allows
    longer steps (mcG(1) on the stiff chain at tolerance 1e-7: positions 40x longer than
    their velocities, 2 10^4 x tolerance). Both tests are one, strength_ij k_i > 1, with the
    couplings' ``strength`` of :func:`tie_reach` (|J_ij|, infinite where lopsided). Only the
    components ``rows`` and the active ones they read take part (frozen components have no
    step). A step lowered by a tie is passed on along the next one (on POLLU, y4 -> y3 -> the
    species with J_ii = -4.4e11) to a fixed point, by a work list: the ``rows`` in order, and
    a row whose step fell is visited again next (``stack``, N integers; ``lowered``, N flags,
    False on entry and on return, marks the rows on it), at most PROPAGATION_SWEEPS visits
    per row. Steps only decrease and a tie depends on k_i alone, so a row whose step did not
    fall since its last visit would change nothing. (Passes over the rows in order move a tie
    one coupling per pass where the coupled rows come in the other order: 6-8 passes per
    slab on the uniform mass-spring chain, x_1..x_n, v_1..v_n.)

    Where i also follows u_j within its step, stiff on it (-J_ii k_i > 1, ``jdiag``), the
    tie goes both ways, k_i <= k_j too: the two take one step in one group. A longer
    element of i spans element ends of j, where j's polynomial has a kink, and i, relaxing
    to u_j within its element, cannot follow it; a shorter one reads j's interior, which
    does not superconverge: on a front along u_i' = r (u_{i-1} - u_i) (200 stages, r =
    1000, tolerance 1e-6) the end of such an element was 26 x the tolerance off (mcG(3);
    mdG(2) 15 x), its estimate within it, against 1.0 x with the two-way tie
    (doc/design/multi-adaptive.md). Lowering k_i may break a two-way tie of a reader of i
    already visited, so the work list runs again over the ``rows`` while a pass that met a
    two-way tie lowered a step, at most PROPAGATION_SWEEPS times."""
    for _ in range(PROPAGATION_SWEEPS):
        if not _propagate_pass(kdes, rows, frozen, indptr, indices, strength, jdiag,
                               lowered, stack):
            return


@helper(**NO_REFCOUNT)
def _propagate_pass(kdes, rows, frozen, indptr, indices, strength, jdiag, lowered, stack):
    """One run of :func:`propagate`'s work list over the ``rows``; returns whether it met a
    two-way tie and lowered a step (so that another run may lower more)."""
    two_way = False
    moved = False
    n = 0
    for r in range(rows.shape[0] - 1, -1, -1):
        stack[n] = rows[r]
        lowered[rows[r]] = True
        n += 1
    visits = 0
    while n > 0 and visits < PROPAGATION_SWEEPS * rows.shape[0]:
        n -= 1
        i = stack[n]
        lowered[i] = False
        visits += 1
        follows = -jdiag[i] * kdes[i] > 1.0
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if not (strength[nz] * kdes[i] > 1.0 and math.isnan(frozen[j])):
                continue
            two_way = two_way or follows
            if kdes[j] > kdes[i]:
                kdes[j] = kdes[i]
                moved = True
                if not lowered[j]:
                    lowered[j] = True
                    stack[n] = j
                    n += 1
            elif follows and kdes[j] < kdes[i]:
                kdes[i] = kdes[j]
                follows = -jdiag[i] * kdes[i] > 1.0
                moved = True
                if not lowered[i]:
                    lowered[i] = True
                    stack[n] = i
                    n += 1
    for r in range(n):  # (left by the cap: no stale flag for the next call)
        lowered[stack[r]] = False
    return two_way and moved


@linked
@helper(**NO_REFCOUNT)
def grade(kdes, rows, frozen, indptr, indices, reaction):
    """Grade the steps along strong couplings, k_i <= max(GRADING k_j, 1 / |df_i/du_j|):
    a component that reacts to u_j within its own step may not step far beyond j, so that
    activity moving along the couplings (a front) meets steps that shrink towards it instead
    of one long step that the next slab rejects. ``reaction`` holds 1 / |J_ij| per coupling
    (:func:`tie_reach`; infinite for j = i and J_ij = 0, which constrain nothing).
    Alternating sweeps over the components ``rows``, to a fixed point or GRADING_SWEEPS of
    them; frozen components constrain nothing."""
    n = rows.shape[0]
    for sweep in range(GRADING_SWEEPS):
        moved = False
        for r in range(n):
            i = rows[r] if sweep % 2 == 0 else rows[n - 1 - r]
            for nz in range(indptr[i], indptr[i + 1]):
                j = indices[nz]
                # (k_i > max(a, b) iff k_i > a and k_i > b)
                if kdes[i] > GRADING * kdes[j] and math.isnan(frozen[j]):
                    cap = max(GRADING * kdes[j], reaction[nz])
                    if kdes[i] > cap:
                        kdes[i] = cap
                        moved = True
        if not moved:
            return


@helper(**NO_REFCOUNT)
def tie_reach(rows, indptr, indices, jacobian, reach, lopsided, strength, reaction):
    """For the ``rows``: reach[i], the largest |J_ij| over j != i (NaN if one is), and
    lopsided[i], whether a coupling of row i is mutual and lopsided,
    |J_ij| >= ASYMMETRY^2 |J_ji| > 0; per coupling (CSR position nz of J_ij) the
    ``strength`` that ``propagate`` ties by, |J_ij| (0 for j = i, infinite where lopsided),
    and the ``reaction`` time that ``grade`` caps by, 1 / |J_ij| (infinite for j = i and
    J_ij = 0). They depend on the Jacobian alone (made once for the slabs that share one)
    and tell which rows ``propagate`` and ``grade`` can act on (``tying_rows``,
    ``grading_rows``)."""
    for i in rows:
        largest = 0.0
        lopsided[i] = False
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            jij = abs(jacobian[nz])
            strength[nz] = 0.0
            reaction[nz] = math.inf
            if j == i or jij == 0.0:
                continue
            strength[nz] = jij
            reaction[nz] = 1.0 / jij
            if not jij <= largest:
                largest = jij
            for nz2 in range(indptr[j], indptr[j + 1]):
                if indices[nz2] == i:
                    jji = abs(jacobian[nz2])
                    if 0.0 < jji and jij >= ASYMMETRY**2 * jji:
                        lopsided[i] = True
                        strength[nz] = math.inf
                    break
        reach[i] = largest


@helper(**NO_REFCOUNT)
def tying_rows(kdes, rows, reach, lopsided, acting):
    """The ``rows`` on which ``propagate`` can tie a step, in order, into acting[:n];
    returns n. Row i ties only on a lopsided coupling or where |J_ij| k_i > 1, so not while
    k_i reach_i <= 1 (``tie_reach``); steps only decrease there, so such a row stays idle,
    and propagate over the others changes the same steps in the same order (floating-point
    products are monotone)."""
    n = 0
    for i in rows:
        if lopsided[i] or not kdes[i] * reach[i] <= 1.0:
            acting[n] = i
            n += 1
    return n


@helper(**NO_REFCOUNT)
def grading_rows(kdes, rows, reach, acting):
    """The ``rows`` (the active components) on which ``grade`` can lower a step, in order,
    into acting[:n]; returns n. Grading lowers k_i only above max(GRADING k_j, 1 / |J_ij|)
    for an active j, never below GRADING min_j k_j, so a row with k_i <= GRADING min_j k_j
    or k_i <= 1 / reach_i (``tie_reach``) stays idle, and grade over the others changes the
    same steps in the same order (floating-point products and quotients are monotone)."""
    kmin = math.inf
    for i in rows:
        kmin = min(kmin, kdes[i])
    n = 0
    for i in rows:
        if not (kdes[i] <= GRADING * kmin or kdes[i] <= 1.0 / reach[i]):
            acting[n] = i
            n += 1
    return n


@helper(**NO_REFCOUNT)
def tie_and_grade(current, kdes, rows, frozen, indptr, indices, jacobian, reach, lopsided,
                  strength, reaction, jdiag, lowered, stack, acting):
    """:func:`propagate`, then :func:`grade`, each over the ``rows`` that can act on their
    steps (:func:`tying_rows`, :func:`grading_rows`), with the weights of
    :func:`tie_reach`, made first unless ``current`` (made for this ``jacobian``). Returns
    True: the weights are current. The smallest step of the ``rows`` stays: a tie copies one
    active step to another, grading caps at GRADING times one."""
    if not current:
        tie_reach(rows, indptr, indices, jacobian, reach, lopsided, strength, reaction)
    n = tying_rows(kdes, rows, reach, lopsided, acting)
    propagate(kdes, acting[:n], frozen, indptr, indices, strength, jdiag, lowered, stack)
    n = grading_rows(kdes, rows, reach, acting)
    grade(kdes, acting[:n], frozen, indptr, indices, reaction)
    return True


@helper(inline="always")
def power(x, order):
    """x^order, by products for the integer orders 1..4 (the local orders q + 1 of q <= 3):
    it runs per component and slab, where a pow call is a visible share of an element."""
    if order == 2.0:
        return x * x
    if order == 3.0:
        return x * x * x
    if order == 4.0:
        return (x * x) * (x * x)
    if order == 1.0:
        return x
    return x**order


@helper(inline="always")
def inverse_root(x, order):
    """x^(-1/order), by a square root for the order 2 (mcG(1), mdG(1)): the step control's
    root runs per component and slab, where a pow call took about 55 of an adaptive mcG(1)
    element's 300 cycles. (1 / sqrt(x) may differ from x**-0.5 in the last bit.)"""
    if order == 2.0:
        return 1.0 / math.sqrt(x)
    return x ** (-1.0 / order)


@helper(**NO_REFCOUNT)
def slab_limit(kslab, kmax, K, converged, nwin, cost, climb):
    """The next slab length limit. A slab with windows costs its top-level elements about
    once (lazy sweeps) and its window elements once per global iteration: a longer slab
    takes fewer top-level elements per unit time, but more global iterations and longer
    windows, whose sweeps converge more slowly. Without windows the limit grows. With them
    it climbs on the measured cost per unit time, ``cost`` (f evaluations of the slab's
    solve / K): by SLAB_CLIMB in the direction ``climb[1]`` (+1 longer, -1 shorter),
    turning when the cost rose above the last slab's, ``climb[0]``. (The former rule, grow
    at two global iterations or fewer and halve at four, let the windows of the
    multi-adaptive problems of the benchmark suite take 2-3 times the f evaluations.)
    Growth starts from the limit itself, not from K, which the top level's smallest desired
    step may keep below it."""
    if not converged:
        return 0.5 * K
    if nwin == 0:
        return min(kmax, 2.0 * max(kslab, K))
    if cost > climb[0]:
        climb[1] = -climb[1]
    climb[0] = cost
    if climb[1] > 0:
        return min(kmax, SLAB_CLIMB * max(kslab, K))
    return K / SLAB_CLIMB
