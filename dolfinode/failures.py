"""Why a solve stopped: the SolverError messages of the driver (:mod:`dolfinode.solve`).

Each names the time reached and only what would help: a blow-up only where max |u| grew, a
function outside its domain with whether it depends on t alone or on components.
"""
import numpy as np
import sympy as sp

from dolfinode import timeslab as ts
from dolfinode.errors import OutOfMemoryError
from dolfinode.memory import available_memory
from dolfinode.ode import t as dn_t

#: The status of a solve stopped by maximum_steps (the loops' codes are >= 0).
STEP_LIMIT = -1

#: A solve stopped by maximum_steps is said to approach a blow-up when its last step is below
#: _BLOWUP_STEP (T - t0) and max |u| grew _BLOWUP_GROWTH-fold since t0 (dG(0) on u' = u^2,
#: u(0) = 1: 10^7 steps, down to 3.1e-10, with |u| = 2.3e3 at t = 0.99956), and the last
#: step is below _STEADY times the mean step; steps near their mean resolve a fast time
#: scale instead (the seed model at kappa = 1e12: 3e-8 steps, |u| = 1e6 the amplitude of
#: the fast velocity).
_BLOWUP_STEP, _BLOWUP_GROWTH, _STEADY = 1e-6, 100.0, 0.1

#: Where f may stop being defined (see ``ODE(nonnegative=...)``).
_DOMAIN = ("a square root or other non-integer power of a component that reaches 0 is nan "
           "below it: declare the component nonnegative=, and f reads it there as max(u, 0)")
#: The same hint when components are declared nonnegative already.
_DOMAIN_DECLARED = ("the components declared nonnegative are read as max(u, 0) in non-integer "
                    "powers, but sqrt(u) and the like have no bounded derivative where u reaches "
                    "0 (Newton's Jacobian is infinite there): cG(1) and mcG(1) step through such "
                    "a point")


#: Functions not defined on the whole real line, with their domain as a test on the argument.
_PARTIAL = {sp.log: ("log", lambda a: a > 0), sp.asin: ("asin", lambda a: abs(a) <= 1),
            sp.acos: ("acos", lambda a: abs(a) <= 1), sp.acosh: ("acosh", lambda a: a >= 1),
            sp.atanh: ("atanh", lambda a: abs(a) < 1)}


def undefined(ode, compiled, x, t, k):
    """Why f is not finite a little past the time t where a step from the state x failed
    (after the last step k, up to 10^4 k, with x moved along f(x, t)), if it is not (else
    None): the argument outside its function's domain and whether it depends on t alone
    (then no method or step helps) or on components."""
    if hasattr(ode, "templates"):  # a template system's rhs takes O(N) to build
        return None
    with np.errstate(all="ignore"):
        slope = np.nan_to_num(compiled.f(x, t), nan=0.0, posinf=0.0, neginf=0.0)
        for step in k * np.logspace(0, 4, 5):
            step = min(step, ode.T - t)
            moved = x + step * slope
            bad = np.flatnonzero(~np.isfinite(compiled.f(moved, t + step)))
            if bad.size:
                break
        else:
            return None
    i, t = int(bad[0]), float(t + step)
    values = {**dict(zip(ode.states, moved.tolist())), **ode.params, dn_t: t}
    for part in sp.preorder_traversal(ode.rhs[i]):
        if part.is_Pow and not part.exp.is_integer:
            name, argument, inside = "a non-integer power", part.base, lambda a: a >= 0
        elif type(part) in _PARTIAL:
            (name, inside), argument = _PARTIAL[type(part)], part.args[0]
        else:
            continue
        try:
            value = float(argument.subs(values))
        except (TypeError, ValueError):
            continue
        if inside(value):
            continue
        where = f"{name} in the right-hand side of {ode.states[i].name} gets {argument} = {value:.3g}"
        if not argument.free_symbols & set(ode.states):
            return (f"f is not defined past t = {t:.6g}: {where}, which depends on t alone, so "
                    "no method or step size can continue; end the interval there (smaller T) "
                    "or change the expression")
        components = ", ".join(sorted(s.name for s in argument.free_symbols & set(ode.states)))
        return (f"f is not defined at t = {t:.6g}: {where} from the values of {components}; "
                + (_DOMAIN_DECLARED if ode.nonnegative.any() else _DOMAIN))
    return None


def out_of_memory(ode, params, t, error):
    """The OutOfMemoryError (a SolverError) for an allocation that failed at the time ``t``
    of a run (``error``: numpy's or the compiled code's MemoryError, often without a
    message), saying what holds memory and what to change."""
    done = 100 * (t - ode.t0) / (ode.T - ode.t0)
    what = str(error) or "an allocation failed"
    if params["dense_output"] is True:
        hint = ("solve with dense_output=False to keep only the samples (choose them with "
                "sample_times=) and the final state, or dense_output='run.h5' to stream the "
                "history to a file")
    else:
        hint = "ask for fewer samples (number_of_samples, sample_times)"
    return OutOfMemoryError(
        f"the solve ran out of memory at t = {t:.6g} ({done:.3g}% of [t0, T]): {what}; the "
        f"memory left to this process is {available_memory() / 2**30:.3g} GB (the least of the "
        "machine's available memory, its cgroup limit and RLIMIT_AS). Free what the process "
        f"holds (the solutions of earlier solves it keeps), or {hint}", t=t)


def undamped_message(method, t, failed, slabs, tolerance):
    """The SolverError message for a cG(q) loop stopped by ``timeslab.mono.undamped``."""
    return (f"{method.name} stopped at t = {t:.6g}: {failed} of its nonlinear solves failed in "
            f"{slabs} time slabs. cG(q) does not damp a stiff component's deviation from its "
            f"quasi-steady state (it is not L-stable), so Newton fails on long steps once the "
            f"state decays below it; use dG({method.q}) (method='dG({method.q})'), which damps "
            f"it, or a tolerance well below {tolerance:g}")


def failure_message(status, state, fixed, x, outside, kmax, newton, ode, slabs, dg=False):
    """The SolverError message for a loop that stopped with ``status`` (state: t and the
    last step) with the solution x after ``slabs`` time slabs; ``newton``: whether Newton's
    method was used, ``dg``: whether the method is a dG(q) one (then not advised)."""
    t, k = state
    grew, growth = _growth(ode, x)
    size = f"max |u| = {np.max(np.abs(x)):.3g} there"
    domain = _DOMAIN_DECLARED if ode.nonnegative.any() else _DOMAIN
    solver = "Newton's method" if newton else "the nonlinear solver"
    if status == STEP_LIMIT:
        raise_ = ("maximum_steps" if kmax is None else
                  f"maximum_steps or maximum_time_step (the steps are capped at {kmax:.3g})")
        grew, growth = _growth(ode, x)
        mean = (t - ode.t0) / max(slabs, 1)
        hint = ""
        if fixed:
            # (the user's step: neither the tolerance nor the order sets it)
            return (f"maximum_steps was reached at t = {t:.6g} ({size}) with fixed_time_step: "
                    f"the step {k:.3g} takes {(ode.T - ode.t0) / k:.6g} steps over [t0, T], "
                    f"{slabs} taken (the steps' sum rounds, so a count equal to maximum_steps "
                    "may need one more); raise maximum_steps or give a longer "
                    "initial_time_step")
        if k < _BLOWUP_STEP * (ode.T - ode.t0) and k < _STEADY * mean and grew:
            hint = (f"; the steps shrank to {k:.3g} while max |u| grew {growth}: the solution "
                    "may blow up near this time")
        elif k < _BLOWUP_STEP * (ode.T - ode.t0) and k >= _STEADY * mean:
            hint = (f"; the steps stayed near {k:.3g} (their mean since t0: {mean:.3g}), a time "
                    "scale far shorter than T - t0: for a fast oscillation automatic_modeling="
                    "True averages it, for a fast decay (stiff) a dG(q) method with "
                    "nonlinear_solver='newton' steps over it")
        return (f"maximum_steps was reached at t = {t:.6g} ({size}){hint}; raise {raise_}, "
                "loosen the tolerance, or use a higher-order method")
    if status == ts.NONCONVERGENCE:
        if fixed:
            return (f"{solver} did not converge at t = {t:.6g} with the fixed time step "
                    f"{k:.3g}; use a smaller initial_time_step"
                    + ("" if newton else " or nonlinear_solver='newton'"))
        if grew:
            return (f"{solver} did not converge at t = {t:.6g}, even after reducing the time "
                    f"step to {k:.3g}, while max |u| grew {growth} ({size}): the solution may "
                    "blow up near this time (a finite-time singularity, or growth past what "
                    f"double precision holds); {domain}")
        tries = [*([] if newton else ["nonlinear_solver='newton'"]),
                 *([] if dg else ["a dG(q) method"])]
        return (f"{solver} did not converge at t = {t:.6g}, even after reducing the time step "
                f"to {k:.3g}; " + (f"try {', '.join(tries)}, or " if tries else "")
                + f"check the right-hand side for a singularity near this time ({size}); "
                f"{domain}")
    if status == ts.CONSTRAINT:
        name = outside.name
        how = "" if fixed else (", or it falls below -absolute_tolerance on every step down to "
                                f"{k:.3g}")
        declared = "declared" if ode.nonnegative.any() else "kept by f (u0 >= 0)"
        return (f"{name}, {declared} nonnegative, leaves [0, inf) at t = {t:.6g} (the right-hand "
                f"side drives it below zero from {name} = 0{how}). Check that f keeps {name} >= 0 "
                f"(f >= 0 where {name} = 0), or drop {name} from nonnegative="
                + ("; with fixed_time_step, a smaller initial_time_step may help" if fixed else ""))
    if status == ts.BLOWUP:
        return (f"the solution is not finite or blows up near t = {t:.6g} (time step reduced to "
                f"{k:.3g}; {size}): the exact solution may have a finite-time singularity there, "
                f"or f is not defined past it; {domain}")
    if grew:
        return (f"the time step fell to {k:.3g} at t = {t:.6g}, below what double precision "
                f"resolves, while max |u| grew {growth} ({size}): the solution may blow up "
                "near this time, or the tolerance is too tight for double precision")
    advice = ("for a stiff problem use a dG(q) method (L-stable) with nonlinear_solver="
              "'newton'; else " if not (dg and newton) else
              "the solution changes faster than double precision resolves a step there (a "
              "rate above about 1 / that step); ")
    return (f"the time step fell to {k:.3g} at t = {t:.6g}, below what double precision "
            f"resolves, but max |u| did not grow ({size}): not a blow-up of u by a power. f "
            "may be singular near this time (a pole of f in t, or u growing like a logarithm: f "
            f"~ 1 / (t* - t)); else the error control or {solver} kept cutting the step: "
            f"{advice}loosen tolerance or absolute_tolerance"
            + _far_origin(ode))


def _far_origin(ode):
    """The hint for an interval far from t = 0 against its length, where the rounding of t
    (not the problem) sets the smallest step; '' elsewhere."""
    span = ode.T - ode.t0
    if abs(ode.t0) < span:
        return ""
    return (f". t0 = {ode.t0:.6g} lies far from t = 0 against the interval's length "
            f"{span:.6g}, so double precision resolves its steps only down to about "
            f"{ts.smallest_step(ode.T, span):.2g}: solve on t0 = 0 and T = {span:.6g} "
            "(dn.t + t0 for dn.t in f) to resolve shorter ones")


def _growth(ode, x):
    """(whether max |u| grew _BLOWUP_GROWTH-fold since t0, how much, in words without a ratio
    to zero)."""
    start, now = np.max(np.abs(ode.u0)), np.max(np.abs(x))
    grew = now > _BLOWUP_GROWTH * (start if start > 0 else 1.0)
    return grew, (f"{now / start:.3g}-fold since t0" if start > 0
                  else f"from 0 at t0 to {now:.3g}")

