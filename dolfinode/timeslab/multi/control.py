"""Acceptance, rejection and step control of a multi-adaptive slab: each component's desired
step at the slab start, the residual-based error indicator of every component, acceptance
and each component's next step, the declared domain (reject a slab that leaves it, project
an accepted one on it), and the rejected attempt kept as the guess of its retry.
"""
import math

import numpy as np
from numba import types

from dolfinode.adaptivity import (
    MAX_FACTOR,
    STIFF_RATIO,
    clamped_step,
    filter_residuals,
    stiff_deviation,
    stiff_factor,
)
from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT
from dolfinode.counters import F_EVALUATIONS
from dolfinode.methods.method import element_value
from dolfinode.timeslab import CONSTRAINT_CUT
from dolfinode.timeslab.multi.steps import inverse_root, power
from dolfinode.timeslab.partition import first_ending_after, grow_float

#: The interior estimate of a component on its quasi-steady state (``interior_indicators``)
#: is held to the tolerance as given, or to INTERIOR_SHARE x the step tolerance where that is
#: looser (tight tolerances, whose calibrated step tolerance is many times the tolerance).
#: Measured on the tolerance record (doc/design/multiadaptive-loose.md): held to the tolerance
#: alone or to 3 x it, HIRES and VDPOL over-delivered at T below the calibration's band
#: (mdG(1) on HIRES at 1e-5 0.093 x, mcG(2) on VDPOL at 1e-6 0.067 x with 3 x).
INTERIOR_SHARE = 1.0 / 3.0
#: A slab holds many elements of a fast component and one indicator above the margin rejects
#: them all; steps are still chosen for indicators of 1 (DOLFIN G1 accepted up to 2 TOL too).
ACCEPTANCE_MARGIN = 2.0


@helper(**NO_REFCOUNT)
def desired_steps(kdes, active, nactive, fixed, kmax, t, T):
    """Cap the active components' desired steps at kmax (unless ``fixed``); returns the
    largest desired step, the smallest within [t, T] and the elements per unit time of the
    partition, sum_i 1 / min(kdes_i, T - t)."""
    kcap = 0.0
    kmin = math.inf
    rate = 0.0
    for r in range(nactive):
        i = active[r]
        if not fixed:
            kdes[i] = min(kdes[i], kmax)
        kcap = max(kcap, kdes[i])
        ki = min(kdes[i], T - t)
        kmin = min(kmin, ki)
        rate += 1.0 / ki
    return kcap, kmin, rate


@helper(**NO_REFCOUNT)
def residual_indicators(ne, comp, ea, eb, values, fend, end_derivative, resid, unfiltered,
                        filtered, loosening, position, indptr, indices, jacobian, jdiag,
                        coupling, gamma, elist, group_order, local, newton, active, nactive,
                        emax, kact, umax, counters):
    """Every element's residual k R(t_e) = k U'(t_e) - k f_i(U(t_e)) at its end (f_i from
    the last sweep, ``fend``), filtered on each sub-slab unless the slab was solved
    synchronised by fixed point (not stiff: unfiltered, as in the mono loop; ``unfiltered``
    keeps the residuals before the filter), and per active component its largest |k R|
    (``emax``), max |U_i| (``umax``) and longest element (``kact``) in the slab: one step
    serves all of a component's elements in the slab, so one scale (an element's own
    |U_i(t_e)| would let the zero crossings of an oscillation dictate the step of every
    period). A filtered residual is scaled by :func:`~dolfinode.adaptivity.stiff_factor`
    (``loosening``), as the mono loop's estimate: the calibrated step tolerance assumes
    superconvergent nodes, which a component stiff on its step has not. Returns whether a
    value or residual is not finite."""
    nn = values.shape[1]
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
        resid[e] = kdu - (eb[e] - ea[e]) * fend[e]
    # (overwrites newton: the loop resets ``factored`` at every slab start)
    if filtered:
        for e in range(ne):
            unfiltered[e] = resid[e]
        filter_residuals(ne, comp, ea, eb, resid, position, indptr, indices, jacobian, jdiag,
                         coupling, gamma, elist, group_order, local, newton, counters)
    for e in range(ne):
        i = comp[e]
        k = eb[e] - ea[e]
        res = abs(resid[e])
        if filtered and loosening > 0.0:
            res *= stiff_factor(res, abs(unfiltered[e]), loosening)
        uend = values[e, nn - 1]
        if not (math.isfinite(uend) and math.isfinite(res)):
            blowup = True
        emax[i] = max(emax[i], res)
        umax[i] = max(umax[i], abs(uend))
        kact[i] = max(kact[i], k)
    return blowup


@helper(**NO_REFCOUNT)
def interior_indicators(ne, comp, ea, eb, values, resid, unfiltered, jdiag, interior, fi, p,
                        x, indptr, indices, cptr, celems, nodes, bary, states, out, delivered,
                        atol, rtol, umax, emax, counters):
    """The interior estimates of the elements of components that follow their quasi-steady
    state g_i (f_i = 0) within their step, into ``emax`` (in units of the step tolerance):

        e_int = max(0, |k R(tau*)| - |k R(1)|) / (1 - k J_ii) / max(delivered, INTERIOR_SHARE),

    the excess of the residual at tau* (``interior[0]``; ``interior[1:]``: l_j'(tau*)) over
    the one at the element's end (``unfiltered``), filtered by the diagonal (k R / (1 - k
    J_ii) tends to U_i - g_i), held to the tolerance as given (1 / ``delivered``, the ratio
    of the step tolerance to it: the interior does not superconverge), or to INTERIOR_SHARE
    of the step tolerance where that is looser. tau* = 0 for mdG(q)
    (right Radau nodes: the node polynomial is largest there), half the first node gap for
    mcG(q); the other components are read at t* from their elements of the slab (a frozen
    one at x_j). One f_i per such element.

    Such a component's nodal values sit on g_i, so its filtered end estimate, the distance
    from g_i at the last node, is small whatever the step, while between the nodes U_i is
    g_i's interpolant, off by k^(q+1) g_i^(q+1) times the node polynomial: on u' = -1000
    (u - cos t), mdG(1) at 1e-2 stepped 2.1 long with its ends within 0.03 x the tolerance
    and its interior 19 x off, and a slow v' = u - v / 10 reading it 8.6 x
    (doc/design/multiadaptive-loose.md). The end's own distance from g_i is the end
    estimate's, hence the excess: mcG(q), not L-stable, carries it from node to node
    (:func:`~dolfinode.adaptivity.undamped_warning`), and held to the tolerance inside as well
    it cut ROBER's mcG(2) steps to |k J_ii| ~ 1 (1e-3: 471 -> 743,814 elements).

    Following g_i takes both conditions: stiff on its own rate, -k J_ii > 1, and an end
    estimate that the sub-slab's filter reduced below STIFF_RATIO x the residual (``resid``,
    as :func:`~dolfinode.adaptivity.stiff_factor`). On the first alone, the components of a
    smooth front along a diffusion chain (the filter leaves their slow mode as it is: their
    interior is accurate) took 3 x the elements (mdG(1), 40 points, 1e-5); on the second
    alone, the stiff springs of a chain (J_ii = 0, the filter acting on the oscillation
    stepped over), 5.4 x (mdG(3), 50 masses, 1e-6). Not on a slab solved synchronised,
    which is unfiltered (not stiff).

    Returns (size, i, t*): the largest interior estimate of the slab in units of the
    tolerance as given, e_int delivered^-1 / (atol_i + rtol max |U_i|) (the step control's
    scale, loosened by the calibration), its component and point (the loop keeps the
    run's largest for :func:`dolfinode.global_error.interior_warning`)."""
    largest, where, at = 0.0, -1, 0.0
    if not delivered > 0.0:  # (fixed steps)
        return largest, where, at
    nn = values.shape[1]
    tau = interior[0]
    for e in range(ne):
        i = comp[e]
        k = eb[e] - ea[e]
        if not (-k * jdiag[i] > 1.0 and abs(resid[e]) < STIFF_RATIO * abs(unfiltered[e])):
            continue
        ts = ea[e] + tau * k
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if j == i:
                states[0, j] = element_value(values, e, tau, nodes, bary)
            elif cptr[j] == cptr[j + 1]:
                states[0, j] = x[j]
            else:  # j's element at ts
                c = celems[first_ending_after(ts, j, cptr, celems, eb)]
                tj = min(max((ts - ea[c]) / (eb[c] - ea[c]), 0.0), 1.0)
                states[0, j] = element_value(values, c, tj, nodes, bary)
        fi(i, states[0].ctypes, ts, p.ctypes, out.ctypes)
        counters[F_EVALUATIONS] += 1
        kdu = 0.0
        for m in range(nn):
            kdu += interior[1 + m] * values[e, m]
        excess = abs(kdu - k * out[0]) - abs(unfiltered[e])
        distance = max(excess, 0.0) / (1.0 - k * jdiag[i])
        emax[i] = max(emax[i], distance / max(delivered, INTERIOR_SHARE))
        size = distance / delivered / (atol[i] + rtol * umax[i])
        if size > largest:
            largest, where, at = size, i, ts
    return largest, where, at


@helper(**NO_REFCOUNT)
def slab_deviation(ne, comp, values, resid, unfiltered, atol, rtol):
    """(d, i, eps): the largest :func:`~dolfinode.adaptivity.stiff_deviation` of a filtered
    slab's elements, its component and its filtered residual in units of atol_i + rtol
    |U_i(t_e)| (the mono loop's record for :func:`~dolfinode.adaptivity.undamped_warning`)."""
    nn = values.shape[1]
    deviation, deviated, deviated_eps = 0.0, -1, 0.0
    for e in range(ne):
        uend = abs(values[e, nn - 1])
        d = stiff_deviation(abs(resid[e]), abs(unfiltered[e]), uend)
        if d > deviation:
            i = comp[e]
            deviation, deviated = d, i
            deviated_eps = abs(resid[e]) / (atol[i] + rtol * uend)
    return deviation, deviated, deviated_eps


@helper(**NO_REFCOUNT)
def scale_indicators(active, nactive, checked, nchecked, emax, atol, rtol, umax):
    """emax_i / (atol_i + rtol umax_i) for the components with elements and the frozen ones
    checked."""
    for r in range(nactive + nchecked):
        i = active[r] if r < nactive else checked[r - nactive]
        emax[i] /= atol[i] + rtol * umax[i]


@helper(**NO_REFCOUNT)
def choose_steps(active, nactive, checked, nchecked, emax, kact, kdes, frozen, solved, order,
                 safety, kmax):
    """Accept the slab when every scaled indicator is <= ACCEPTANCE_MARGIN, and choose each
    active component's next step from its indicator (``next_step``), smoothed by the
    harmonic mean with its last desired step when accepted, below 0.9 times its step when
    it failed. A component held on the synchronised step (``solved``) is judged on its own
    step, its estimate scaled by (kdes / k)^order, so that the synchronised step does not
    cap its growth. Returns the acceptance."""
    efloor = (safety / MAX_FACTOR) ** order
    nseen = nactive + nchecked
    accept = True
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
            eref *= power(kdes[i] / kref, order)
            kref = kdes[i]
        # below efloor the factor is capped at MAX_FACTOR anyway: no root for idle components;
        # above it the controller of ``next_step`` without history, by ``inverse_root``
        knew = kref * MAX_FACTOR
        if not eref <= efloor:
            knew = clamped_step(kref, safety * inverse_root(max(eref, 1e-10), order))
        if accept:
            knew = 2.0 * kdes[i] * knew / (kdes[i] + knew)  # harmonic-mean regulator
        elif emax[i] > ACCEPTANCE_MARGIN:
            knew = min(knew, 0.9 * kact[i])
        else:
            knew = kdes[i]
        kdes[i] = min(knew, kmax)
    return accept


@helper(**NO_REFCOUNT)
def leaves_domain(ne, comp, values, floor, kdes, kact):
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
def project(ne, comp, values, floor, projected):
    """Set the nodal values of the nonnegative components in [floor, 0) to 0, marking those
    components in ``projected``."""
    for e in range(ne):
        i = comp[e]
        if floor[i] > -math.inf:
            for m in range(values.shape[1]):
                if values[e, m] < 0.0:
                    values[e, m] = 0.0
                    projected[i] = True


@helper(**NO_REFCOUNT)
def drives_out(active, nactive, projected, x, fi, p, b, T, floor, out, counters):
    """Of the active components projected on the slab ending at b (``projected``, cleared):
    the first one projected to zero that f drives below its floor by T, or -1 (f does not
    keep it nonnegative, and the projected solution would stay at 0 where the exact one
    turns negative); and whether any was projected."""
    any_projected = False
    for r in range(nactive):
        i = active[r]
        if projected[i]:
            any_projected = True
            projected[i] = False
            if x[i] == 0.0:
                fi(i, x.ctypes, b, p.ctypes, out.ctypes)
                counters[F_EVALUATIONS] += 1
                if out[0] * (T - b) < floor[i]:
                    return i, any_projected
    return -1, any_projected


@linked(returns=types.Tuple((types.float64[::1], types.float64[::1], types.float64[:, ::1])),
        what="the multi-adaptive rejected attempt", seconds=1)
@helper()
def keep_attempt(ne, ea, eb, values, oea, oeb, ovalues):
    """Copy the slab's elements (their intervals and nodal values) into the rejected
    attempt's arrays, grown as needed; returns them (the initial guess of the retry,
    ``sweeps.guess_from``)."""
    nn = values.shape[1]
    oea = grow_float(oea, ne)
    oeb = grow_float(oeb, ne)
    if ovalues.shape[0] < ne:
        ovalues = np.empty((max(ne, 2 * ovalues.shape[0]), nn))
    for e in range(ne):  # (slice copies compile their shape checks and messages)
        oea[e] = ea[e]
        oeb[e] = eb[e]
        for m in range(nn):
            ovalues[e, m] = values[e, m]
    return oea, oeb, ovalues
