"""The driver: ``solve(ode, method, tolerance=..., **parameters) -> Solution``."""
import functools
import os
import sys
import time
import warnings
from itertools import pairwise

import numpy as np
import sympy as sp

from dolfinode import events as ev
from dolfinode import global_error, growth
from dolfinode import timeslab as ts
from dolfinode.adaptivity import (
    UNDAMPED_DEVIATION,
    filter_constant,
    step_absolute_tolerance,
    step_tolerance,
    stiff_loosening,
    undamped_warning,
)
from dolfinode.compile import lower
from dolfinode.errors import SolverError, ToleranceWarning
from dolfinode.failures import (
    STEP_LIMIT,
    failure_message,
    out_of_memory,
    undamped_message,
    undefined,
)
from dolfinode.family import auto_base, solve_auto
from dolfinode.features import narrow_features
from dolfinode.io import history
from dolfinode.kept import solve_kept
from dolfinode.linalg.newton_matrix import newton_structure, sparse_candidate
from dolfinode.memory import SMALL_BYTES, available_memory
from dolfinode.methods import parse_method
from dolfinode.ode import ODE, _vector_by_state
from dolfinode.parameters import DEFAULTS, NONLINEAR_SOLVERS, check_parameters
from dolfinode.timeslab import contract, mono
from dolfinode.timeslab.start import F0_NOT_FINITE, INTERVAL_UNRESOLVED, first_step, start

#: The package's folder (warnings name the first caller outside it).
_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep

#: New solves with a smaller maximum_time_step when a switch was crossed inside an element.
_SWITCH_RETRIES = 3
#: Slabs (elements: multi-adaptive) per loop call of a solve with events or switches: what a
#: terminal event or a switch in the chunk makes the loop redo.
_EVENT_CHUNK = 1024
#: Slabs of the first loop call after a (re)start with events or switches, doubled per call
#: up to _EVENT_CHUNK: where switches come every few slabs (a kink crossed each period) a
#: full chunk per restart redid up to 26 x the slabs kept.
_RESTART_CHUNK = 16
#: Elements per component of the multi-adaptive loop's first call after a (re)start: a
#: multi-adaptive chunk costs about 0.2 ms of Python per call (its view as a Solution, the
#: roots), so starting at _RESTART_CHUNK took up to 1.35 x the CPU on two-component kinks.
_MULTI_RESTART_CHUNK = 4 * _RESTART_CHUNK
#: When set, the most slabs (mono-adaptive) or elements (multi-adaptive) a loop call
#: stores: tests cut a run into many calls with it, which must not change the run.
_CHUNK_LIMIT = None
#: The smallest tolerance without an absolute_tolerance (scipy's solve_ivp bound, 100 machine
#: epsilons): below it the step error estimate is rounding (tolerance=1e-300 failed with
#: "Newton's method did not converge at t = 0 ... check the right-hand side for a
#: singularity"). With absolute_tolerance given, a smaller one means absolute error control.
MIN_TOLERANCE = 100 * np.finfo(float).eps
#: Fraction of the available memory the Newton matrices of a mono-adaptive slab may take;
#: a matrix of at most memory.SMALL_BYTES is taken to fit without asking the system.
_NEWTON_MEMORY_FRACTION = 0.5
#: Largest system whose quasi-positivity is checked (see _keeps_nonnegative).
_QUASI_POSITIVE_N = 200


def _absolute_tolerance(ode, value, rtol):
    """atol per component from the parameter: None (rtol), a number (checked by
    check_parameters) or values per state."""
    if value is None:  # (before np.isscalar, whose call outweighs a small solve's setup)
        return _filled(ode.N, rtol)
    if np.isscalar(value):
        return _filled(ode.N, value)
    atol = _vector_by_state(value, ode.states, "absolute_tolerance")
    if not ((atol > 0.0).all() and np.isfinite(atol).all()):  # (np.all: 4-5 us a call)
        raise ValueError(f"absolute_tolerance must be positive and finite, got {value!r}")
    return atol


def _check_resolvable_tolerance(ode, atol, rtol):
    """Raise ValueError if the tolerance atol_i + rtol |u0_i| of a component is below
    MIN_TOLERANCE |u0_i|, what double precision resolves at its initial size: the step error
    estimate is rounding there, and the steps shrink until maximum_steps or memory runs out
    (tolerance = absolute_tolerance = 1e-20: 10^7 cG(2) slabs). Components starting at 0
    have no scale yet and are not judged."""
    scale = np.abs(ode.u0)
    below = np.flatnonzero(atol + rtol * scale < MIN_TOLERANCE * scale)
    if below.size:
        i = int(below[np.argmax(scale[below])])
        raise ValueError(
            f"the tolerance of {ode.states[i].name} (absolute_tolerance {atol[i]:.3g} + tolerance "
            f"{rtol:.3g} x |u0| = {scale[i]:.3g}) is below what double precision resolves at "
            f"that size ({MIN_TOLERANCE:.2g} |u0| = {MIN_TOLERANCE * scale[i]:.3g}): the error "
            "estimate would be rounding; give a tolerance of at least "
            f"{MIN_TOLERANCE:.2g} or an absolute_tolerance of at least "
            f"{MIN_TOLERANCE * scale[i]:.3g} for it")


def warn_growth_below_tolerance(ode, compiled, atol):
    """A ToleranceWarning for a component that starts below its absolute tolerance,
    0 < |u0_i| < atol_i, and grows past it by T at its initial rate
    r_i = df_i/du_i(u0, t0) > 0: |u0_i| exp(r_i (T - t0)) > atol_i.

    The step control measures errors against atol_i + rtol |U_i|, so while |U_i| < atol_i
    its relative error is free, and so is when it grows: u' = u (1 - u) from u0 = 1e-12 ended
    at u(35) = 0 instead of 1 with every method at tolerance 1e-3 and 1e-6 (10 steps), as did
    an infection seeded at 1e-8 (SIR, T = 120), the error estimate at T included (it
    linearises about the wrong solution). An atol_i below |u0_i| resolves them.
    """
    small = below_tolerance(ode.u0, atol)
    if small:
        warn_growth(ode, compiled, atol, small)


def below_tolerance(u0, atol):
    """The components i with 0 < |u0_i| < atol_i (a list: empty where none, as mostly)."""
    if u0.size <= 64:  # (in Python: a numpy pass costs a small solve 2 us a call)
        return [i for i, (u, a) in enumerate(zip(u0.tolist(), atol.tolist())) if 0 < abs(u) < a]
    return np.flatnonzero((np.abs(u0) < atol) & (u0 != 0.0)).tolist()


def warn_growth(ode, compiled, atol, small):
    """:func:`warn_growth_below_tolerance` for the components ``small`` that start below
    their absolute tolerance (:func:`below_tolerance`, not empty): a Solver calls it when
    the parameter values are new and u0 is not."""
    u0, small = ode.u0, np.array(small)
    rate = compiled.jacobian_matrix(u0, ode.t0).diagonal()[small]
    exponent = np.minimum(rate * (ode.T - ode.t0), 700.0)  # (exp overflows past 709)
    grows = np.abs(u0[small]) * np.exp(exponent) > atol[small]
    if grows.any():
        i = int(small[grows][np.argmax(exponent[grows])])
        _warn(f"u0 of {ode.states[i].name} ({u0[i]:.3g}) is below its absolute tolerance "
              f"({atol[i]:.3g}), where the step control does not see its relative error, and "
              f"it grows at the rate df/d{ode.states[i].name} = {rate[small == i][0]:.3g} "
              f"(x {np.exp(exponent[small == i][0]):.3g} by T): when it grows is not "
              f"controlled, and the solution may be wrong at any tolerance. Give "
              f"absolute_tolerance below |u0| (e.g. {abs(u0[i]) * 1e-3:.1g}) for it")


def starts_below_tolerance(u0, atol):
    """Whether every |u0_i| < atol_i (:func:`warn_below_tolerance_throughout` reads the
    solution only then; a Solver asks when u0 is new)."""
    if u0.size == 1:  # (a repeated small solve: 0.3 us, where numpy's pass costs 2)
        return abs(float(u0[0])) < float(atol[0])
    return bool((np.abs(u0) < atol).all())


def warn_below_tolerance_throughout(ode, atol, sol):
    """A ToleranceWarning for a solution whose every component stays below its absolute
    tolerance, max_t |U_i(t)| < atol_i for all i, and is not identically 0.

    The step control measures errors against atol_i + rtol |U_i|: where |U_i| < atol_i
    throughout, any relative error passes. u'' = -u from u(0) = 1e-12 ended 85-180 x its
    size off at T with cG(2), dG(1), mcG(2) (tolerance 1e-3 and 1e-6, atol by default equal
    to it), and u' = -u + 1e-9 sin 5t from 1e-9 with the wrong sign, all as a success. Read
    only when every |u0_i| < atol_i (a component above atol at t0 has its error measured);
    the history's nodal values, or the samples without it, give max_t |U_i|. Called where
    atol is the default one (an atol the user gave says what size is noise)."""
    u0 = ode.u0
    if not starts_below_tolerance(u0, atol):
        return
    if sol.dense:
        ptr, _, _, values = sol.elements()
        peaks = np.abs(values).max(axis=1)
        peak = np.array([peaks[a:b].max(initial=0.0) for a, b in pairwise(ptr)])
    else:
        peak = np.abs(sol.y).max(axis=1)
    peak = np.maximum(peak, np.abs(sol(sol.ode.T)))
    if (peak < atol).all() and peak.any():
        i = int(np.argmax(peak / atol))
        # the computed peak may itself be the error: the size of u0, where there is one
        size = np.abs(u0).max() or peak.max()
        _warn(f"every component stays below its absolute tolerance (largest: max |"
              f"{ode.states[i].name}| = {peak[i]:.3g} against absolute_tolerance {atol[i]:.3g}): "
              f"the step control accepts any relative error there, and the solution may be "
              f"wrong in all its digits. Give an absolute_tolerance below the solution's size "
              f"(e.g. {size * 1e-6:.1g}), or scale the states to order 1")


#: A component the step control projected to 0 is reported lost when a perturbation of it
#: there would grow by more than LOST_GROWTH by T (an error atol_i becomes LOST_GROWTH atol_i,
#: the run's own bound of 10 x the tolerance); its growth is integrated over LOST_SAMPLES
#: points of the computed solution.
LOST_GROWTH, LOST_SAMPLES = 10.0, 257


def lost_components(ode, compiled, sol):
    """[(i, t_i, G_i)]: the components of ``sol`` that start nonzero, end at exactly 0 and
    stay there from t_i on, with G_i = int_{t_i}^T df_i/du_i(U(t), t) dt > log(LOST_GROWTH).

    The step control keeps the values of a nonnegative (or quasi-positive) system >= -atol
    and projects those in [-atol, 0) to 0. Where f_i = u_i g_i(u), u_i = 0 is invariant: a
    component projected there never comes back, although the exact one, positive, grows
    again at the rate g_i = df_i/du_i (Lotka-Volterra from (3, 40) at tolerance 1e-3: y
    dips to 8e-8, is set to 0, and x grows to 4e4 instead of 1e-3, unwarned). A component
    that decays, g_i < 0 (a species consumed), is lost harmlessly: G_i < 0. Only systems
    whose values the step control bounds below (``ode.nonnegative``, or quasi-positive)
    are projected; the end values are read first (a repeated small solve pays ~1 us)."""
    if not sol.dense:
        return []
    # U at the end (T, or a terminal event's time), without an evaluation where it can
    U = sol(sol.ode.T) if sol.multi else sol._end_values()
    if not _has_zero(U):
        return []
    zero = U == 0.0
    candidates = np.flatnonzero(zero & (ode.u0 != 0.0))
    if not candidates.size or not (ode._constrained or _keeps_nonnegative(ode)):
        return []
    ptr, _, t_end, values = sol.elements()
    end, lost = sol.ode.T, []
    for i in candidates.tolist():
        nonzero = np.flatnonzero((values[ptr[i]:ptr[i + 1]] != 0.0).any(axis=1))
        t_i = float(t_end[ptr[i] + nonzero[-1]]) if nonzero.size else ode.t0
        if t_i >= end:
            continue
        times = np.linspace(t_i, end, LOST_SAMPLES)
        states = sol(times).T
        rates = np.array([compiled.jacobian_matrix(u, t)[i, i] for u, t in zip(states, times)])
        growth = float(np.sum((rates[1:] + rates[:-1]) * np.diff(times))) / 2
        if growth > np.log(LOST_GROWTH):
            lost.append((i, t_i, growth))
    return lost


def warn_lost_components(ode, compiled, params, sol):
    """A ToleranceWarning naming the first of :func:`lost_components`."""
    if not sol.success:
        return
    lost = lost_components(ode, compiled, sol)
    if lost:
        i, t_i, growth = lost[0]
        name = ode.states[i].name
        atol = _absolute_tolerance(ode, params["absolute_tolerance"], params["tolerance"])
        _warn(f"{name} was set to 0 at t = {t_i:.6g}, where it fell below its absolute "
              f"tolerance ({atol[i]:.3g}), and stays there (f keeps 0), but a perturbation "
              f"of {name} there grows by a factor exp({growth:.3g}) along the solution by T: "
              f"the exact {name} comes back and the solution from t = {t_i:.6g} on may be "
              f"wrong at any tolerance. Give an absolute_tolerance below the smallest value "
              f"of {name} (e.g. {atol[i] * 1e-6:.1g})")


def _keeps_nonnegative(ode):
    """Whether f keeps every component >= 0 from u0 >= 0 (the exact solution stays in the
    nonnegative orthant): f_i >= 0 where u_i = 0 and the other components are >= 0, for every
    i (quasi-positivity, decided by sympy's sign assumptions for parameters of the signs of
    their values; t-dependent or undecidable terms count as no). Then the step control keeps
    the values >= -atol as for components declared nonnegative: ROBER to 1e11 at tolerance
    1e-3 (absolute tolerance 1e-3 by default) let y2 dip below -3e-4, where
    y2' = -3e7 y2^2 - 1e4 y2 y3 + ... diverges, and returned y1 ~ -4e7 as a success. Checked
    for systems of at most _QUASI_POSITIVE_N components (sympy's work grows with N), once per
    declaration and signs of the parameters (a parameter fit varies the values at every
    solve: a sympy check per value took ~3 ms a solve)."""
    if hasattr(ode, "templates") or ode.N > _QUASI_POSITIVE_N or _has_negative(ode.u0):
        return False
    signs = _signs(ode.params.values())
    return ode._derived("_keeps_nonnegative", (ode.rhs, signs),
                        lambda: _quasi_positive(ode, signs))


def _has_negative(u0):
    """Whether u0 has an entry < 0 (in Python for a short vector, where a numpy reduction's
    call overhead exceeds the work)."""
    return min(u0.tolist()) < 0 if u0.size <= 64 else bool(u0.min() < 0)


def _has_zero(values):
    """Whether ``values`` has an entry == 0 (in Python for a short vector, as
    :func:`_has_negative`: 0.3 us against numpy's 1.3 us on HIRES)."""
    return 0.0 in values.tolist() if values.size <= 64 else bool((values == 0.0).any())


def _filled(n, value):
    """np.full(n, value) without its argument handling (a small solve pays it per call)."""
    array = np.empty(n)
    array.fill(value)
    return array


def _signs(values):
    """The signs (+1, -1, 0) of parameter values: all that :func:`_keeps_nonnegative` reads
    of them."""
    return tuple((value > 0) - (value < 0) for value in values)


def _quasi_positive(ode, signs):
    """f_i >= 0 where u_i = 0 and the others are >= 0, for every i, by sympy's sign
    assumptions, the parameters of the given ``signs`` (+1, -1, 0) (a jump at u_i = 0, as
    sign(u), counts as no)."""
    if any(f.has(*ev.NON_SMOOTH) for f in ode.rhs):
        return False
    values = {p: sp.Dummy(p.name, positive=True) if sign > 0 else
              sp.Dummy(p.name, negative=True) if sign < 0 else sp.S.Zero
              for p, sign in zip(ode.params, signs)}
    nonnegative = {s: sp.Symbol(s.name, nonnegative=True) for s in ode.states}
    at_zero = (sp.sympify(f).xreplace(values).xreplace(nonnegative)
               .xreplace({nonnegative[s]: sp.S.Zero}) for s, f in zip(ode.states, ode.rhs))
    return all(bool(f.is_nonnegative) for f in at_zero)


def _check_resolvable(ode, name, k, t):
    """Raise ValueError if the step ``k`` (a number or per state) is below
    the smallest step double precision resolves at the time ``t`` (the loops' bound)."""
    kmin = ts.smallest_step(t, ode.T - ode.t0)
    if np.min(k) < kmin:
        raise ValueError(f"{name} = {np.min(k):.3g} is below what double precision resolves at "
                         f"t = {t:.6g} ({kmin:.3g}); give a larger {name}")


def _initial_steps(ode, given, multi_adaptive):
    """The first steps: per state, from ``initial_time_step`` (a number, or per state as a
    dict/sequence for multi-adaptive methods); None: to be guessed by the start."""
    if given is None:
        return np.empty(ode.N)
    if np.isscalar(given):
        return _filled(ode.N, float(given))
    if not multi_adaptive:
        raise ValueError("initial_time_step per state needs a multi-adaptive method "
                         "(mcG(q) or mdG(q)); cG/dG share one step")
    steps = _vector_by_state(given, ode.states, "initial_time_step")
    if np.any(steps <= 0):
        raise ValueError(f"initial_time_step must be positive, got {given!r}")
    return steps


def solve(ode, method="cG(1)", *, tolerance=DEFAULTS["tolerance"], goal=None, **parameters):
    """Solve the ODE u' = f(u, t) on [t0, T], u(t0) = u0, with a Galerkin method.

    The time steps are chosen so that the Galerkin residual R = U' - f(U, t), scaled to a
    local error estimate, stays below ``absolute_tolerance + tolerance |U|`` componentwise
    (the weighted norm of scipy's solve_ivp).

    Parameters
    ----------
    ode : ODE
        The declaration (:class:`dolfinode.ODE` or a template system).
    method : str, default "cG(1)"
        "cG(q)" (q >= 1, nodal order 2q, A-stable) or "dG(q)" (q >= 0, order 2q + 1,
        L-stable): one time step shared by all components; "mcG(q)" or "mdG(q)": individual
        time steps per component (multi-adaptive); "auto" (or "auto:cG(q)", "auto:dG(q)";
        "auto" is "auto:cG(2)"): the mono- or multi-adaptive variant, switched between in
        stretches of [t0, T] when the other is measured to be faster (see
        :mod:`dolfinode.family`); the evidence is in ``sol.stats["family choice"]``.
    tolerance : float, default 1e-6
        Relative tolerance (rtol) of the local error estimate. With ``goal``: the bound on
        the estimated error in that output.
    goal : optional
        An output of the solution (see :class:`dolfinode.Goal`, e.g. ``{u: 1.0}`` for u(T)):
        primal and dual problems are then solved in turn until the estimated error in it is
        below ``tolerance``; the solution carries ``sol.error_estimate``.
    absolute_tolerance : float, dict or sequence, optional
        atol, a number or one per state; default: equal to ``tolerance``.
    initial_time_step : float, dict or sequence, optional
        The first step (per state for mcG/mdG); default: chosen from f(u0, t0).
    maximum_time_step : float, optional
        Upper bound on every step; default T - t0, or 1 / omega where a term of f oscillates
        in t over the whole interval (sin(omega t), unless its range times T - t0 is below
        the absolute tolerance), whose period a longer step aliases
        (:mod:`dolfinode.features`, ``sol.stats["oscillation step bound"]``).
    fixed_time_step : bool, default False
        True: uniform steps equal to ``initial_time_step``, no error control; not checked
        at T unless ``estimate_global_error=True``, which then estimates the error at T
        and warns above 10 x ``tolerance`` (the run's only check: set the tolerance the
        steps are meant to meet).
    nonlinear_solver : {"default", "fixed-point", "newton"}, default "default"
        "default" starts with fixed-point iteration and switches to Newton's method with the
        exact sparse Jacobian when the problem turns out stiff.
    discrete_tolerance_factor : float, default 1e-3
        Tolerance of the nonlinear solver relative to the step error indicator.
    maximum_iterations : int, default 30
        Nonlinear iterations per time slab before the step is reduced.
    safety_factor : float, default 0.9
        Factor in (0, 1] on each new step size.
    maximum_steps : int, default 10000000
        Time slabs before the solve stops with :class:`~dolfinode.SolverError`.
    number_of_samples : int, default 101
        Equispaced output samples ``sol.t``, ``sol.y`` (``sol(t)`` is exact at any t, and
        ``sol.time_steps()`` the elements' starts and lengths).
    sample_times : array_like, optional
        Explicit increasing sample times in [t0, T] for ``sol.t``, ``sol.y`` (solve_ivp's
        ``t_eval``); default: ``number_of_samples`` equispaced ones.
    dense_output : bool or str, default True
        True: the whole history (every element) is kept in memory, so ``sol(t)`` and
        :func:`~dolfinode.estimate_error` work anywhere; False: only the samples and the final
        state (memory independent of the number of steps); a path ``"run.h5"``: the history is
        streamed to that HDF5 file (:func:`dolfinode.load_solution` opens it). A dense solve
        whose history would outgrow the memory left stops with SolverError naming this.
    progress : bool, default False
        Show a tqdm progress bar over [t0, T].
    partitioning_threshold : float, default 0.5
        mcG/mdG: components whose step is at least this fraction of the largest share a
        sub-slab.
    interval_threshold : float, default 0.9
        mcG/mdG: a step at least this fraction of what is left of the interval is stretched
        to its end.
    automatic_modeling : bool, default False
        Replace fast time scales that need not be resolved by a subgrid model g~ built
        from averages over resolved windows (see :mod:`dolfinode.modeling`).
    average_length : float, optional
        tau, the length of the averaging window; default ``100 / max |lambda|`` over the
        eigenvalues of df/du(u0).
    average_samples : int, default 1000
        Samples per half averaging window.
    average_tolerance : float, default 0.1
        Components whose average drifts less than this over a window are inactivated.
    control_points : int, default 10
        Checks of the reduced model against the full model over (t_c, T].
    model_tolerance : float, default 0.02
        Rebuild the model where ``|g~ - g-bar| > model_tolerance max |g-bar|``.
    rebuild_model : bool, default True
        False: build the model once and only measure its defect at the control points.
    subgrid_model : {"auto", "constant", "affine", "flow"}, default "auto"
        g~ constant, affine in the slow state, or "flow": no g~, the fast variables evolve
        with the slow ones in the full model with its stiffness parameter scaled to a
        moderate separation, averaged (:mod:`dolfinode.modeling.flow`). "auto": "flow" when
        the first window shows a fast frequency moving with the slow state or no component
        can be inactivated, else constant, affine when the first window or a rebuild shows
        g-bar moving with the slow state.
    calibrate_tolerance : bool, default True
        cG(q)/dG(q) and mcG(q)/mdG(q), q <= 3, and "auto": aim the steps at the error at
        T, about ``tolerance`` (see Notes);
        False: bound each step's local error estimate by ``tolerance`` instead (the error
        at T then lands 1e-7..10 x below it). Automatic modeling's inner solves use False.
    strict : bool, default False
        Automatic modeling: raise :class:`~dolfinode.SolverError` where the a posteriori
        check of the reduced model would issue a :class:`~dolfinode.ModelingWarning` (its
        estimate exceeds the tolerance).
    events : list, optional
        Zero crossings g(u, t) = 0 to locate: sympy expressions in the states and t, or
        :class:`dolfinode.Event` (terminal, direction); found in ``sol.t_events`` and
        ``sol.y_events``. See :mod:`dolfinode.events`.
    breakpoints : sequence of float, optional
        Times where f jumps that the declaration does not show; jumps of f in t and
        switches on the state written in f are found from the declaration. When f keeps
        every component >= 0 from u0 >= 0 (f_i >= 0 where u_i = 0: mass-action kinetics),
        the values are kept >= -atol as for components declared nonnegative.
    estimate_global_error : bool or "auto", default "auto"
        After the solve, estimate the error at T (:mod:`dolfinode.global_error`: each
        slab's local error propagated to T by the linearised flow) into
        ``sol.stats["global error estimate"]``,
        scaled as the tolerance (see Notes), with ``sol.stats["global error nonlinearity"]``,
        and warn when it exceeds 10 x the tolerance (where the error equation leaves its
        linear range, ``sol.stats["global error nonlinearity"]`` > 100, the error is
        measured instead against a dG(3) solve at 1/100 of the tolerance,
        ``sol.stats["global error reference"]``, and the warning says so; the same where
        the estimate is within 10 x but its second-order part, the remainder f(U - e) -
        f(U) + J e the linearisation leaves out propagated along the run as the estimate
        is, ``sol.stats["global error second order"]``, could lift it above: a nonlinear
        oscillator's phase error over many periods). The run also gets
        ``sol.stats["global error mid-run"]``, the largest error at every element end of
        every component (a mono-adaptive run's slab ends; by the same estimate, stage
        systems, slab estimate or mode by mode), with a warning above 10 x the tolerance
        where the error at T is within (:func:`dolfinode.global_error.midrun_warning`).
        Measured within 0.74-1.6 x the error on HIRES, ROBER, POLLU, a heat equation, a stiff-spring chain
        and the harmonic oscillator, also multi-adaptive (doc/design/global_error.md); it
        costs 0.4-8 x a small solve (a compiled pass over the slabs, one stage solve of
        (q + 2) N rows each, banded where J's band is narrow: 6-15 x a non-stiff chain's
        solve). "auto" estimates runs of more than one step of one component (slabs, or a
        multi-adaptive component's elements) whose stage system has at most ``AUTO_ROWS``
        (64) rows: the steps' errors add up on undamped or drifting runs (Kepler's orbit at
        eccentricity 0.9 over one period, 22 slabs of dG(3) at 1e-3: 35 x the tolerance);
        larger runs (mono- and multi-adaptive) by the slab estimate
        (:func:`dolfinode.global_error.slab_estimate`: the error equation on the slabs by
        Taylor series, no stage systems; 0.3-2.4 x the solve of runs of 0.05 s and more, a
        50-mass chain at 1e-4, 1e-6 within 0.97-1.03 x the error), except where a run is
        stiff on its slabs (a linear system of at most 200 components is then estimated mode
        by mode, :func:`dolfinode.global_error.modal_estimate`; the error of others is
        measured against a dG(3) solve at 1/100 of the tolerance, as above, and warned
        above 10 x the tolerance, or where that solve fails). With events,
        breakpoints or switches in f, where the linearised estimate, made for one smooth f,
        does not apply, the error at T of a run of more than one step is measured against
        a dG(3) solve at 1/100 of the tolerance with the same events and jumps (1.4-2.5 x
        the solve), and warned as above. method="auto" where it solves in stretches is
        estimated on the joined solution as a run of its base method. Automatic modeling is
        not estimated and has no such key. Without the history
        (``dense_output`` False or a file) cG(q)/dG(q) runs are estimated chunk by chunk of
        stored slabs as they are stored (the estimate of the whole history); runs whose
        estimate needs the elements (mcG(q), mdG(q), the slab estimate's) are not, and
        ``sol.stats["global error note"]`` says so (True raises for mcG(q), mdG(q)). True
        estimates every run (a ValueError where it cannot), False none. Runs with
        ``fixed_time_step=True`` are estimated with True only (and warned as above: the
        estimate is their only check); "auto" leaves them unchecked at T, as cheap as
        their steps, and ``sol.stats["global error note"]`` says so.

    Returns
    -------
    Solution
        Callable at any t in [t0, T]; ``sol.success``, ``sol.status`` and ``sol.message`` say
        how the solve ended, ``sol.stats`` counts its work, ``sol.parameters`` holds the
        parameters it used; with ``automatic_modeling=True`` also ``sol.model``, the
        :class:`~dolfinode.modeling.ReducedModel`.
        With events, ``sol.t_events`` and ``sol.y_events``; ``sol.status`` is 1 after a
        terminal event (the solution then ends there: ``sol.ode.T``).

    Raises
    ------
    ValueError, TypeError
        For invalid parameters (an unknown name is answered with the closest valid one, and
        scipy's names such as ``atol`` with dolfinode's).
    SolverError
        When the solver cannot continue; the message names the time reached and what to try.

    Warns
    -----
    ToleranceWarning
        When the run reached a regime where the calibrated tolerance was measured not to
        hold (:func:`dolfinode.adaptivity.undamped_warning`); the message names the
        component and what to try. With ``estimate_global_error=True`` also when the
        estimated error at T exceeds 10 x the tolerance (the local errors of a long run
        adding up).

    Notes
    -----
    ``tolerance`` (rtol) and ``absolute_tolerance`` (atol) aim at the error at T, scaled as
    scipy's and the Test Set's: ``max_i |U_i(T) - u_i(T)| / (atol_i + rtol |u_i(T)|) ~ 1``.
    Each step's local error estimate (:mod:`dolfinode.adaptivity`) is held below a step
    tolerance (rtol / C)^(1/alpha) (atol scaled alike), C and alpha fitted per method
    (:func:`dolfinode.adaptivity.step_tolerance`), since the nodal values of cG(q) and dG(q)
    superconverge; stiff components, whose nodes do not, are held to a few times the
    tolerance (:func:`dolfinode.adaptivity.stiff_factor`). Measured on HIRES, VDPOL and the
    harmonic oscillator over 1e-2..1e-10 (doc/design/tolerance.md): 125 of 144 runs within
    0.1-10 x the tolerance, none above (at most 8.7 x), down to 0.0015 x (dG(3) on VDPOL);
    with q = 4, 5: 65 of 108 within, none above, down to 1e-4 x (VDPOL, which damps).
    It is a calibration of the local error, not a bound: a long non-dissipative run adds
    its errors up (an oscillator bank: 29 x), which ``estimate_error`` measures for a goal
    and ``estimate_global_error`` estimates at T (by default on long runs of small systems),
    with a warning above 10 x. On problems
    it was not fitted on (ROBER, POLLU, VDPOLM, a stiff heat equation; 1e-3..1e-9) one run
    lands above 10 x, with a warning (cG(2) on ROBER at 1e-7, 26 x: a
    :class:`~dolfinode.ToleranceWarning` is raised where cG(q), q even, carries a stiff deviation it
    cannot damp into T). Values inside
    elements (``sol(t)`` between element ends, samples, events) are less accurate than at
    the nodes: dG(q), q >= 1, and cG(q), q >= 2, mono- or multi-adaptive, evaluate their
    collocation polynomial there, O(k^(q+2)) (harmonic oscillator, dG(2): 1.2 / 1.5 / 1.9 x
    at 1e-4 / 1e-6 / 1e-8, dG(3): 1.0 / 2.3 / 3.5 x, cG(3): 1.5 / 3.0 / 3.7 x; dG(1) 7 / 28 /
    48 x), the Galerkin polynomial, O(k^(q+1)), on stiff components and where f jumps,
    against 0.2-2 x at the nodes (doc/benchmarks/dense_output.md), and more where the steps
    are long for
    the solution's curvature (1,300 x measured: mdG(1) at 1e-4 on a component that turns
    stiff mid-run); ``calibrate_tolerance=False`` bounds each step's
    estimate by the tolerance instead, as scipy's rtol and atol do (the error at T then
    lands 1e-7..10 x below it).
    mcG(q) and mdG(q) have their own C (they deliver 1.3-3.5 x cG(q)'s error at one step
    tolerance; 126 of 144 runs within 0.1-10 x, doc/design/tolerance.md), and
    ``method="auto"`` calibrates each variant alike, so that its choice compares runs of
    equal accuracy. dG(0), q > 5 (mcG(q), mdG(q): q > 3) and automatic modeling's inner
    solves use the step tolerance as given. For a bound on an output, pass ``goal``
    (dual-based estimate).

    The defaults are ``dolfinode.default_parameters`` (DOLFIN's names).

    A declaration keeps, for options (method, tolerance, parameters) it was solved with
    twice, a :class:`~dolfinode.Solver` whose prepared path later calls with them take
    (:mod:`dolfinode.kept`): the options are checked once, the values (``ode.params``,
    ``u0``, ``t0``, ``T``) are read at every call, and the result is bitwise that of a first
    call.
    """
    if goal is None:
        sol = solve_kept(ode, method, tolerance, parameters)
        if sol is not None:
            return sol
    parameters["tolerance"] = tolerance
    if not isinstance(ode, ODE):
        raise TypeError(f"solve expects a dolfinode.ODE, got {type(ode).__name__}")
    params = check_parameters(parameters)
    base = auto_base(method)
    if params["estimate_global_error"] is True and params["automatic_modeling"]:
        raise ValueError("estimate_global_error is for cG(q), dG(q), mcG(q), mdG(q) and "
                         "method='auto', not for automatic_modeling")
    if base is not None:
        sol = solve_auto(solve, ode, base, goal, parameters, params)
        if "decided once" not in sol.stats["family choice"]:  # (stretches: not estimated)
            compiled, plan = lowered(ode, params)
            check_error_at_T(ode, compiled, plan, sol.multi, parse_method(base)[1], params,
                             sol)
        return sol
    if goal is not None:
        from dolfinode.dual.adaptivity import solve_for_goal

        if params["dense_output"] is not True:
            raise ValueError("a solve for a goal estimates its error from the dual problem, "
                             "which needs the history: drop dense_output (or set it True)")
        if params["automatic_modeling"]:
            raise ValueError("goal= cannot be combined with automatic_modeling=True: the error "
                             "estimate of a reduced solution is not available (see "
                             "sol.model.modeling_error()); solve for the goal without "
                             "automatic_modeling, or with automatic_modeling and no goal")

        others = {name: value for name, value in parameters.items() if name != "tolerance"}
        if params["estimate_global_error"] == "auto":
            # (the dual estimate checks a goal's solve, whose steps leave the components
            # outside the goal less accurate on purpose)
            others["estimate_global_error"] = False
        return solve_for_goal(solve, ode, method, goal, params["tolerance"], others)
    check_tolerance(params)
    multi_adaptive, m = parse_method(method)
    if params["automatic_modeling"]:
        if params["events"] is not None or params["breakpoints"] is not None:
            raise ValueError("events and breakpoints are not supported with automatic_modeling")
        from dolfinode.modeling import solve_with_modeling

        sol = solve_with_modeling(ode, method, params, solve)
        sol.parameters = params
        return sol
    compiled, plan = lowered(ode, params)
    return solve_lowered(ode, compiled, plan, multi_adaptive, m, params)


def _check_switch_retry(ode, params, step, where, what):
    """Raise SolverError when the new solve of :func:`solve_lowered` with the step bound
    params["maximum_time_step"] would need more than maximum_steps slabs over [t0, T]: a
    switch that changes sign and back faster than any feasible step (a threshold of 1e-12
    on a velocity that passes through zero) would otherwise cost a full solve at that
    bound before maximum_steps stops it with a message about fast time scales."""
    slabs = (ode.T - ode.t0) / params["maximum_time_step"]
    if slabs <= params["maximum_steps"]:
        return
    near = "" if where is None else f" ({what} twice in a short time near t = {where:.9g})"
    raise SolverError(
        f"a switch on the state (Piecewise/Heaviside/sign/floor of a state in f) changes sign "
        f"inside elements that were not split there{near}: locating its crossings would need "
        f"maximum_time_step = {params['maximum_time_step']:.3g}, {slabs:.3g} steps over "
        f"[t0, T], more than maximum_steps = {params['maximum_steps']}, and f was evaluated on "
        "the wrong branch between them. Smooth the switch (e.g. tanh(g / eps)), or make its "
        "two crossings farther apart (a threshold on a state well above its error)",
        t=float(ode.t0 if where is None else where))


def lowered(ode, params):
    """The kernels of ``ode`` with its jumps in t and switches on the state made branch
    parameters (:func:`dolfinode.events.switched`), and the plan of the pieces, events and
    switches (:class:`dolfinode.events.Plan`; None without any)."""
    smooth, switches = ev.switched(ode)
    return lower(smooth), ev.Plan.make(ode, switches, params["breakpoints"], params["events"])


def check_tolerance(params):
    """Raise ValueError for a tolerance below MIN_TOLERANCE without an absolute_tolerance."""
    if params["tolerance"] < MIN_TOLERANCE and params["absolute_tolerance"] is None:
        raise ValueError(f"tolerance must be at least {MIN_TOLERANCE:.2g} (100 machine epsilons, "
                         f"as in scipy's solve_ivp), got {params['tolerance']:g}: below it the "
                         "error estimate is rounding (a smaller one with absolute_tolerance given "
                         "controls the absolute error alone)")


def solve_lowered(ode, compiled, plan, multi_adaptive, m, params):
    """:func:`solve` of ``ode`` with its kernels ``compiled`` (whose ``p`` holds the parameter
    values) and ``plan`` (:func:`lowered`), the parsed method and the checked parameters
    (:func:`check_parameters`, :func:`check_tolerance`): the part of a solve that
    :class:`dolfinode.Solver` repeats.

    A switch on the state crossed inside an element, found a posteriori on the solution
    (:meth:`dolfinode.events.Plan.unresolved_switch_step`), is solved again with a step
    bound from the crossings seen, at most _SWITCH_RETRIES times, else SolverError."""
    given = params["maximum_time_step"]
    atol = _absolute_tolerance(ode, params["absolute_tolerance"], params["tolerance"])
    for _ in range(_SWITCH_RETRIES + 1):
        sol = _solve_once(ode, compiled, plan, multi_adaptive, m, params)
        missed = None if plan is None else plan.unresolved_switch_step(sol)
        if missed is None:
            if plan is not None:
                plan.check_events(sol, params["tolerance"])
            if params["maximum_time_step"] != given:
                sol.stats["switch step bound"] = params["maximum_time_step"]
            elif given is None and not ode.autonomous:
                note_step_bound(sol.stats, _largest_step(ode, params["fixed_time_step"], atol),
                                ode.T - ode.t0)
            check_error_at_T(ode, compiled, plan, multi_adaptive, m, params, sol)
            warn_lost_components(ode, compiled, params, sol)
            if not params["fixed_time_step"] and params["absolute_tolerance"] is None:
                warn_below_tolerance_throughout(ode, atol, sol)
            return sol
        # (without a maximum_time_step, the bound of an oscillating f(t) stays: the smaller)
        bound = params["maximum_time_step"] or _largest_step(ode, params["fixed_time_step"], atol)
        params = {**params, "maximum_time_step": min(bound, missed[0])}
        _check_switch_retry(ode, params, *missed)
        plan = ev.Plan.make(ode, plan.switches, params["breakpoints"], params["events"])
    raise SolverError(
        f"a switch on the state (Piecewise/Heaviside/sign/floor of a state in f) changes sign "
        f"inside elements that were not split there, even with maximum_time_step = "
        f"{params['maximum_time_step']:.3g}: f was evaluated on the wrong branch. Give a "
        "smaller maximum_time_step, or smooth the switch", t=float(ode.t0))


def _solve_once(ode, compiled, plan, multi_adaptive, m, params):
    """One solve of :func:`solve_lowered`."""
    start = time.perf_counter()
    started = _start(ode, compiled, plan, multi_adaptive, m, params)
    if plan is not None and plan.events and params["dense_output"] is False:
        raise ValueError("events are located on the solution's history: give "
                         "dense_output=True or a file name with events=")
    return run_started(ode, compiled, plan, multi_adaptive, m, params, started, start)


def run_started(ode, compiled, plan, multi_adaptive, m, params, started, start, kept=None):
    """The run of a solve started by :func:`_start` (its arrays ``started``; at the time
    ``start``) to its Solution; ``kept``: a :class:`dolfinode.Solver`'s prepared call that
    did not finish (:func:`_run_mono`), which the run continues."""
    atol, floor, x, f0, steps, options, state, counters = started
    reached = state["t"]  # (the loop's time, written in place as it runs)
    try:
        sink = _estimating(ode, compiled, plan, multi_adaptive, m, params,
                           history.sink(ode, m, multi_adaptive, params,
                                        plan.restarts if plan and plan.switches else None))
        run = _run_multi if multi_adaptive else _run_mono
        status, counters, state, elements, stats = run(ode, compiled, m, params, options,
                                                       atol, floor, x, f0, steps, state,
                                                       counters, plan, sink, kept)
        sol = _finish(ode, compiled, plan, multi_adaptive, m, params, status, counters, state,
                      x, stats, start,
                      lambda solved: sink.solution(solved, m, elements, stats, x))
    except MemoryError as error:  # (numpy's, or the compiled code's without a message)
        if isinstance(error, SolverError):
            raise
        raise out_of_memory(ode, params, float(reached[0]), error) from error
    if plan is not None:
        plan.report(sol)
    return sol


def _start(ode, compiled, plan, multi_adaptive, m, params):
    """The start of a solve of ``ode`` from u0 at t0 with the kernels ``compiled`` (whose
    ``p`` holds its parameter values; the branches of ``plan``'s switches at t0 are set in
    it): (atol, floor, x, f0, steps, options, state, counters), the loops' tolerances, lower
    bounds of the values, the state x = u0 (a copy), f0 = f(u0, t0), the first steps, the
    options of both loops (:func:`_options`; the workspace functions add what only their
    loop reads), the loop's state at t0 and zero counters; the checks of the start.

    Raises
    ------
    ValueError
        For f(u0, t0) not finite, an interval or step double precision does not resolve, a
        tolerance below what it resolves at |u0|.
    """
    rtol = params["tolerance"]
    atol = _absolute_tolerance(ode, params["absolute_tolerance"], rtol)
    if rtol < MIN_TOLERANCE and not params["fixed_time_step"]:  # (else atol + rtol |u0| is)
        _check_resolvable_tolerance(ode, atol, rtol)
    if not params["fixed_time_step"]:
        warn_growth_below_tolerance(ode, compiled, atol)
    x = ode.u0.copy()
    if plan is not None:
        sigma = compiled.p[len(ode.params):]  # (a view: the branches at t0 set in place)
        plan.initial_branches(sigma, x, ode.t0, ode.T)
    steps = _initial_steps(ode, params["initial_time_step"], multi_adaptive)
    loop_atol, options = _options(ode, m, params, multi_adaptive, atol)
    f0, state = np.empty(ode.N), contract.state()
    counters = np.zeros(ts.NUM_COUNTERS, dtype=np.int64)
    _started(ode, compiled, params, multi_adaptive, atol, x, f0, steps, options, state,
             counters)
    return loop_atol, _floor(ode, atol), x, f0, steps, options, state, counters


def _options(ode, m, params, multi_adaptive, atol):
    """The loops' absolute tolerances and options (:func:`contract.options`) for the
    tolerances ``atol`` and ``params["tolerance"]``: as given, or calibrated to the error at T
    (:func:`step_tolerance`); with fixed steps, iteration to rounding level relative to the
    solution size."""
    rtol = params["tolerance"]
    fixed = bool(params["fixed_time_step"])
    kmax = params["maximum_time_step"] or _largest_step(ode, fixed, atol)
    loosening = 0.0
    delivered = 0.0 if fixed else 1.0  # the error at T in units of rtol
    if fixed:
        atol, rtol, dtol = np.ones(ode.N), 1.0, 1e-15
    else:
        dtol = params["discrete_tolerance_factor"]
        if params["calibrate_tolerance"] and rtol >= MIN_TOLERANCE:
            step = step_tolerance(m, rtol, multi_adaptive)
            loosening = stiff_loosening(m, rtol, step, multi_adaptive)
            delivered = rtol / step
            atol = step_absolute_tolerance(m, atol, rtol, step, multi_adaptive)
            rtol = step
    return atol, contract.options(
        solver=NONLINEAR_SOLVERS.index(params["nonlinear_solver"]), fixed=fixed,
        max_iter=params["maximum_iterations"], is_dg=m.family == "dG", rtol=rtol, T=ode.T,
        kmax=kmax, safety=params["safety_factor"],
        dtol=dtol, order=m.local_order, span=ode.T - ode.t0, gamma=filter_constant(m),
        loosening=loosening, delivered=delivered)


def _largest_step(ode, fixed, atol):
    """The largest step without a maximum_time_step: T - t0, or less where f oscillates
    in t faster than a step would see (:meth:`dolfinode.features.Features.step_cap`)."""
    span = ode.T - ode.t0
    if fixed or ode.autonomous:
        return span
    return min(span, narrow_features(ode).step_cap(atol, span))


def note_step_bound(stats, bound, span):
    """``stats`` with the largest step an oscillating f(t) allows (:func:`_largest_step`),
    where there is one (None: none) below the ``span`` T - t0."""
    if bound is not None and bound < span:
        stats["oscillation step bound"] = bound
    return stats


def _floor(ode, atol):
    """The lower bounds of the values: -atol where declared nonnegative, or everywhere when
    f keeps the values nonnegative (:func:`_keeps_nonnegative`: with a loose absolute
    tolerance a small concentration dips below 0 and polynomial kinetics diverge from
    there); -inf elsewhere."""
    if _keeps_nonnegative(ode):
        return -atol
    return np.where(ode.nonnegative, -atol, -np.inf) if ode._constrained else _filled(ode.N,
                                                                                    -np.inf)


def _started(ode, compiled, params, multi_adaptive, atol, x, f0, steps, options, state,
             counters):
    """Run the compiled start (:func:`dolfinode.timeslab.start.start`) from x at t0 with
    the tolerances ``atol`` and ``params["tolerance"]`` (the first step's), into f0, the
    steps (guessed unless given), the state and the counters; raise ValueError for a check
    that fails, in words."""
    status = start.unchecked(compiled.rhs.address, compiled.p, ode.t0, atol,
                             params["tolerance"], params["initial_time_step"] is None, x, f0,
                             steps, options, state, counters, not multi_adaptive)
    _check_start(ode, params, status, f0, steps)


def _check_start(ode, params, status, f0, steps):
    """Raise ValueError, in words, for what the start returned ``status`` (f0 not finite, an
    interval too short) or the given steps (``steps``) that double precision does not resolve.
    """
    if status == F0_NOT_FINITE:
        bad = ode.states[int(np.flatnonzero(~np.isfinite(f0))[0])]
        raise ValueError(f"f(u0, t0) is not finite in the right-hand side of {bad}: check u0 "
                         "and the parameters")
    if status == INTERVAL_UNRESOLVED:
        raise ValueError(f"[t0, T] = [{ode.t0:.17g}, {ode.T:.17g}] is shorter than the smallest "
                         f"step double precision resolves there ({ts.ROUNDING:g} |t|): shift "
                         f"the time origin, e.g. t0 = 0 and T = {ode.T - ode.t0:.17g}")
    if params["initial_time_step"] is not None:
        _check_resolvable(ode, "initial_time_step", steps, ode.t0)
    if params["maximum_time_step"] is not None:
        _check_resolvable(ode, "maximum_time_step", params["maximum_time_step"],
                          max(abs(ode.t0), abs(ode.T)))


def _finish(ode, compiled, plan, multi_adaptive, m, params, status, counters, state, x, stats,
            start, solution):
    """The Solution ``solution(solved declaration)`` of a loop run that ended with
    ``status``, its ``stats`` completed from the loop's ``counters``; SolverError (naming
    the time ``state[0]`` and what to try) for a run that did not reach T."""
    if status != ts.DONE:
        newton = _uses_newton(counters, params, stats)
        fixed = bool(params["fixed_time_step"])
        outside = ode.states[counters[ts.OUTSIDE] - 1] if counters[ts.OUTSIDE] else None
        why = (undefined(ode, compiled, x, float(state[0]), float(state[1]))
               if status in (ts.NONCONVERGENCE, ts.BLOWUP) else None)
        if (status == ts.NONCONVERGENCE and not (fixed or multi_adaptive or m.family == "dG")
                and mono.undamped(counters[ts.FAILED_SOLVES], counters[ts.SLABS])):
            why = undamped_message(m, float(state[0]), counters[ts.FAILED_SOLVES],
                                   counters[ts.SLABS], params["tolerance"])
        raise SolverError(why or failure_message(
            status, state, fixed, x, outside, params["maximum_time_step"], newton, ode,
            counters[ts.SLABS], dg=m.family == "dG"), t=float(state[0]))
    _completed_stats(stats, counters.tolist(), multi_adaptive, m, params, compiled.compile_time,
                     time.perf_counter() - start)
    # the declaration as solved: later changes to ode do not reach sol
    solved = ode._snapshot() if plan is None else plan.solved_ode(ode._snapshot())
    sol = solution(solved)
    sol.parameters = params
    return sol


def _uses_newton(counts, params, stats):
    """Whether a run used Newton's method (mono-adaptive solves may return from Newton to
    fixed-point iteration: STIFF is then 0, but the matrices were made)."""
    return (bool(counts[ts.STIFF]) or params["nonlinear_solver"] == "newton"
            or stats.get("newton matrices") is not None)


def _completed_stats(stats, counts, multi_adaptive, m, params, compile_time, seconds):
    """The ``stats`` of a run (:func:`_mono_stats`, :func:`_multi_stats`) completed with the
    counts every solve reports (``counts``: its loop's counters as a list) and its times;
    returns ``stats``."""
    stats.update({
        "method": ("m" if multi_adaptive else "") + m.name,
        "rejected steps": counts[ts.REJECTED],
        "f evaluations": counts[ts.F_EVALUATIONS],
        "jacobian evaluations": counts[ts.JACOBIANS],
        "nonlinear iterations": counts[ts.ITERATIONS],
        "failed nonlinear solves": counts[ts.FAILED_SOLVES],
        "newton": _uses_newton(counts, params, stats),
        "compile time": compile_time,
        "solve time": seconds,
    })
    if params["fixed_time_step"] and params["estimate_global_error"] == "auto":
        stats["global error note"] = FIXED_NOTE
    return stats


def _chunks(advance, make_buffers, capacity, counters, params, state, bar, newton_ready=None,
            first=None, smallest=None):
    """Call a compiled time-slab loop until it reaches T, yielding (status, stored elements)
    after each call; ``first``: (status, buffers) of a first call made already (the kept
    buffers of :class:`dolfinode.Solver`), of ``capacity``; ``smallest``: the first call's
    capacity, doubled after each full chunk up to ``capacity`` (a switch or terminal event
    redoes the rest of its chunk, so chunks after a restart start short).

    The loop returns FULL when its output buffers are full (so results arrive in chunks, and
    progress can be shown); a FULL with nothing stored means one slab needs larger buffers.
    It returns NEWTON_NEEDED when Newton's matrices are not ready: it goes on if
    ``newton_ready()`` makes them so. More than ``maximum_steps`` slabs stop it with
    STEP_LIMIT: the mono-adaptive buffers hold no more slabs than are left, the
    multi-adaptive loop (whose buffers count elements) is checked after each chunk.
    """
    size = capacity if smallest is None else min(smallest, capacity)
    while True:
        if first is None:
            buffers = make_buffers(size)
            status = advance(*buffers)
        else:
            (status, buffers), first = first, None
        chunk = history.filled(buffers, counters)
        del buffers
        if bar is not None:
            bar.update(state["t"][0] - bar.n)
        if counters[ts.SLABS] > params["maximum_steps"]:
            status = STEP_LIMIT
        elif status == ts.NEWTON_NEEDED and newton_ready is not None and newton_ready():
            status = ts.FULL
        elif status == ts.FULL:
            if counters[ts.STORED] == 0 and counters[ts.STORED_BLOCKS] == 0:
                capacity *= 2
            size = min(2 * size, capacity)
            if counters[ts.SLABS] >= params["maximum_steps"]:
                status = STEP_LIMIT
        yield status, chunk
        if status != ts.FULL:
            return


def _integrate(chunks, plan, pieces, ode, state, sink):
    """Run the loop's ``chunks()`` to T, or piece by piece with ``plan`` (events,
    breakpoints, switches: :func:`dolfinode.events.march` through ``pieces``), handing the
    stored elements to ``sink`` (:mod:`dolfinode.io.history`); (status, what
    ``sink.finish(completed)`` returns)."""
    if plan is None:
        for status, chunk in chunks():
            sink.add(chunk, float(state["t"][0]))
    else:  # a terminal event or a switch may redo a chunk: the sink takes the final ones
        status, stored, plan.end = ev.march(plan, pieces, ode.t0, ode.T)
        plan.terminated = status == ev.TERMINATED
        if plan.terminated:
            status = ts.DONE
        for chunk in stored:
            sink.add(chunk, plan.end)
    return status, sink.finish(status == ts.DONE)


def _newton_plan(compiled, m):
    """(structure, bytes, costs, seconds) of the Newton matrices of method ``m`` on the
    pattern of ``compiled``: their storage (:func:`newton_structure`; a sparse one is analysed
    only now), its memory, the cost units of :func:`mono.newton_costs` and the estimated time
    of a factorization. Made once per pattern and method: a small solve would otherwise spend
    a fifth of its time on them."""
    plan = compiled.newton_plans.get(m.name)
    if plan is None:
        structure = newton_structure(compiled.band_structure,
                                     lambda: compiled.sparse_structure, m.stage_eigenvalues)
        plan = (structure, structure.memory(m.num_stages),
                mono.newton_costs(structure, m.stage_eigenvalues, compiled.N, compiled.nnz,
                                  m.num_stages),
                structure.seconds(complex_values=True))
        compiled.newton_plans[m.name] = plan
    return plan


def _step_guess(ode, compiled, atol, rtol):
    """The first step of a fresh start at (x, t) (after a jump of f, the last step says
    nothing about the next)."""
    return lambda x, t: first_step(compiled.f(x, t), x, t, atol, rtol, ode.T - ode.t0)


def _newton_options(compiled, m, options):
    """Decide the storage of the Newton matrices (a sparse one is analysed only now) and set
    the loop's options for it; (structure, bytes, whether they fit in memory)."""
    structure, newton_bytes, costs, seconds = _newton_plan(compiled, m)
    reuse = seconds >= mono.REUSE_TIME
    fits = (newton_bytes <= SMALL_BYTES
            or newton_bytes <= _NEWTON_MEMORY_FRACTION * available_memory())
    options["newton_ready"] = fits
    options["reuse"] = reuse
    options["keep_factors"] = reuse or mono.KEEP_FACTORS
    options["newton_units"], options["factor_units"] = costs
    return structure, newton_bytes, fits


def _mono_arguments(compiled, structure, tables, options, atol, floor, x, f0, state,
                    counters, carried):
    """The mono-adaptive loop's arguments but its output buffers, with the arrays it carries
    over calls (:func:`dolfinode.timeslab.mono.carry`): a call
    ``mono.advance.unchecked(*arguments, out_t, out_k, out_X)`` runs slabs until T or until
    the buffers are full, and returns its status."""
    return (compiled.rhs.address, compiled.jacobian.address, compiled.p, compiled.indptr,
            compiled.indices, structure.tuple, *tables, options, atol, floor, x, f0, state,
            counters, carried)


def _mono_capacity(ode, m):
    """Slabs per loop call: the stored values at most 2^21 doubles."""
    return _limited(int(max(64, min(20000, 2 ** 21 // ((m.q + 1) * ode.N)))))


def _limited(capacity):
    """``capacity``, at most _CHUNK_LIMIT when that is set."""
    return capacity if _CHUNK_LIMIT is None else min(capacity, _CHUNK_LIMIT)


def _mono_buffers(ode, m, params, counters):
    """The mono-adaptive loop's output buffers of a call (t, k, values) for at most
    ``capacity`` slabs, and no more than ``maximum_steps`` allows, as a function of it."""
    def buffers(capacity):
        size = min(capacity, params["maximum_steps"] - counters[ts.SLABS])
        return np.empty(size), np.empty(size), np.empty((size, m.q + 1, ode.N))
    return buffers


#: The largest carried workspace (bytes) a solve leaves for the next solve of its system.
_LEFT_BYTES = 2**20


def _carried(compiled, m, structure, ready, carried):
    """The arrays the mono-adaptive loop carries over its calls (:func:`mono.carry`; the
    last slab's values of ``carried``, an earlier carry, kept): those an earlier solve of
    ``compiled`` by ``m`` left (:func:`_leave_carried`), when the Newton storage is decided
    (``ready``) and theirs is ``structure``, else new ones. A fresh start does not read what
    they hold (the loop factors anew), and a solve takes them out of the pool: none shares
    them (threads, a solve inside an event's callback). Making them costs a small solve 3-6
    us, as many Python arrays alive at once."""
    left = compiled.workspaces.get(m.name) if ready and carried is None else None
    if left:
        try:
            kept_structure, kept = left.pop()
        except IndexError:  # (another thread took it)
            kept_structure = None
        if kept_structure is structure:
            return kept
    return mono.carry(compiled.N, m, structure, ready, None if carried is None else carried[0])


def _leave_carried(compiled, m, structure, carried):
    """Leave a finished solve's ``carried`` arrays (:func:`_carried`) for the next solve of
    ``compiled`` by ``m``, if they hold the decided Newton storage and are small."""
    if carried is None or not mono.holds_workspace(carried) or (
            sum(array.nbytes for array in carried) > _LEFT_BYTES):
        return
    left = compiled.workspaces.setdefault(m.name, [])
    if len(left) < 2:
        left.append((structure, carried))


def _run_mono(ode, compiled, m, params, options, atol, floor, x, f0, steps, state, counters,
              plan, sink, kept=None):
    """The mono-adaptive loop's chunks to T into ``sink``; (status, counters, (t, k), the
    elements, stats). ``kept``: (call, arguments, first) of a :class:`dolfinode.Solver`'s
    prepared solve, its loop's entry and arguments but the buffers, and its first call's
    (status, buffers), which the run goes on from as this one would have."""
    tables = mono.method_tables(m)
    structure = compiled.band_structure  # until Newton is needed: see newton_ready
    newton_bytes = 0

    def newton_ready():
        nonlocal structure, newton_bytes
        structure, newton_bytes, fits = _newton_options(compiled, m, options)
        return fits

    if not sparse_candidate(structure) or m.name in compiled.newton_plans:
        # nothing (left) to analyse: decided up front, no return to the driver (which cost
        # a small sparse system such as POLLU a second loop call and its buffers)
        newton_ready()

    buffers = _mono_buffers(ode, m, params, counters)

    carried, first = None, None

    def advance(*buffers):
        nonlocal carried
        ready = bool(options["newton_ready"][0])
        if carried is None or (ready and not mono.holds_workspace(carried)):  # (decided since)
            carried = _carried(compiled, m, structure, ready, carried)
        return mono.advance.unchecked(*_mono_arguments(
            compiled, structure, tables, options, atol, floor, x, f0, state, counters,
            carried), *buffers)

    if kept is not None:  # (its arguments hold its structure and carried arrays)
        call, arguments, first = kept
        advance = functools.partial(call, *arguments)

    capacity, smallest = _mono_capacity(ode, m), None
    if plan is not None and plan.truncates:  # a terminal event or a switch redoes the rest
        capacity, smallest = min(capacity, _EVENT_CHUNK), _RESTART_CHUNK
    with _progress(ode, params) as bar:
        def chunks():
            return _chunks(advance, buffers, capacity, counters, params, state, bar,
                           newton_ready, first, smallest)

        pieces = plan and ev.MonoPieces(
            ode, m, chunks, options, state, x, compiled.p, len(ode.params),
            _step_guess(ode, compiled, atol, options["rtol"][0]), f0=f0, f=compiled.f)
        status, elements = _integrate(chunks, plan, pieces, ode, state, sink)
    if kept is None:
        _leave_carried(compiled, m, structure, carried)
    if status == ts.NEWTON_NEEDED:
        available = available_memory()
        why = ("was not selected" if params["nonlinear_solver"] == "newton" else "failed")
        raise SolverError(
            f"{m.name} needs Newton's method at t = {state['t'][0]:.6g} (fixed-point "
            f"iteration {why}), but its Newton matrices ({ode.N} unknowns each, "
            f"{structure.description}) take {newton_bytes / 2**30:.3g} GB, more "
            f"than {_NEWTON_MEMORY_FRACTION:g} x the {available / 2**30:.3g} GB available. "
            "Use smaller steps with fixed_time_step=True and nonlinear_solver='fixed-point', "
            "or a smaller system", t=float(state["t"][0]))
    if status == ts.DONE:
        _warn_undamped(ode, compiled, m, params, options, state)
    return status, counters, _time_and_step(state, state["k_next"][0]), elements, _mono_stats(
        ode.N, structure, counters, float(state["k_next"][0]))


def _warn_undamped(ode, compiled, m, params, options, state, multi_adaptive=False):
    """A ToleranceWarning where a run's ``state`` shows a regime the calibration does not
    hold in (:func:`dolfinode.adaptivity.undamped_warning`); uncalibrated runs bound each
    step's error and are not warned (ROBER mcG(2) at 1e-6 then lands 100 x below it)."""
    if params["calibrate_tolerance"] and state["last_deviation"][0] > UNDAMPED_DEVIATION:
        i = int(state["deviated"][0])
        # the loop's scale is the step tolerance: options["rtol"] / tolerance x the given
        size = float(state["deviation_error"][0] * options["rtol"][0] / params["tolerance"])
        rows = np.repeat(np.arange(ode.N), np.diff(compiled.indptr))
        drives = bool(np.any((compiled.indices == i) & (rows != i)))
        why = undamped_warning(m, float(state["deviation"][0]),
                               float(state["last_deviation"][0]), size, drives, ode.states[i],
                               multi_adaptive)
        if why:
            _warn(why)


def _warn_interior(ode, m, state):
    """A ToleranceWarning where a multi-adaptive run's largest interior estimate exceeds
    the tolerance many times (:func:`dolfinode.global_error.interior_warning`)."""
    why = global_error.interior_warning(m, float(state["interior"][0]),
                                        float(state["interior_at"][0]),
                                        ode.states[int(state["interior_of"][0])])
    if why:
        _warn(why)


#: With ``estimate_global_error="auto"`` (the default) the error at T is estimated for runs
#: of at least SHORTEST_RUN steps of one component (a run of one step is its step's local
#: error, which the step control bounds), where the steps' errors can add up past the
#: tolerance (undamped and drifting solutions: Kepler's orbit, a pendulum, 12-25,000 x
#: unwarned without it, from 13 steps on), of systems whose stage system has at most
#: AUTO_ROWS rows ((q + 2) N; its dense solve per slab then costs about what the slab's
#: own solve does); True: every run, False: none.
SHORTEST_RUN = 2
AUTO_ROWS = 64


def fewest_checked_steps(choice):
    """The fewest steps of a run whose error at T ``estimate_global_error=choice`` checks:
    every run (True), none (False), SHORTEST_RUN ("auto")."""
    return {False: np.inf, "auto": SHORTEST_RUN}.get(choice, 0)


#: sol.stats["global error note"] of a fixed-step run under "auto": its steps have no
#: step control, and no tolerance the user meant for them; it is not checked at T, so that
#: it costs its steps alone (the estimate was 35 s of a 40 s mcG(1) run of 1e6 steps).
FIXED_NOTE = ("not estimated: fixed steps; estimate_global_error=True estimates the error at T "
              "and warns above 10 x the tolerance, as for adaptive steps")


def checks_at_T(params):
    """Whether a run with ``params`` is checked at T (:func:`check_error_at_T`): not with
    estimate_global_error=False, nor "auto" with fixed steps (FIXED_NOTE)."""
    choice = params["estimate_global_error"]
    return choice is True or (choice == "auto" and not params["fixed_time_step"])


def check_error_at_T(ode, compiled, plan, multi_adaptive, m, params, sol, steps=None):
    """The check of the error at T of ``sol`` (by the method ``m``) that
    ``params["estimate_global_error"]`` asks for (:func:`checks_at_T`): the growing modes
    its steps span (:func:`warn_spanned_growth`), and the linearised estimate where f is
    smooth (:func:`estimate_global_error`), else measured (:func:`measure_piecewise_error`).
    ``steps``: the :func:`longest_run` of ``sol`` where the caller has it (a prepared
    call's counters: reading sol.stats would make them)."""
    if not checks_at_T(params):
        return
    # each step's Jacobian on its own branch: the declared f, not the smooth one holding the
    # last piece's branches (Max(1, 3 x - 2) was warned of rate 3 where x < 1 and J = 0)
    warn_spanned_growth(ode, compiled if plan is None or not plan.switches else lower(ode), m,
                        params, sol)
    smooth = plan is None or not plan.watched
    check = estimate_global_error if smooth else measure_piecewise_error
    check(ode, compiled, m, params, sol,
          longest_run(sol, multi_adaptive) if steps is None else steps)


def warn_spanned_growth(ode, compiled, m, params, sol):
    """A ToleranceWarning where a step of ``sol`` spans a growing mode whose error the
    step control does not see (:func:`dolfinode.growth.spanned_growth`), for a history
    held in memory (a file's is not read back: it may not fit)."""
    if params["dense_output"] is not True:
        return
    rtol = params["tolerance"]
    found = growth.spanned_growth(
        sol, compiled, m, _absolute_tolerance(ode, params["absolute_tolerance"], rtol), rtol)
    if found is not None:
        _warn(growth.message(ode, m, found))


def longest_run(sol, multi_adaptive):
    """The most steps one component took in ``sol``: its time slabs (cG(q), dG(q)), or the
    elements of the busiest component (mcG(q), mdG(q): few slabs may hold long runs)."""
    if multi_adaptive:
        return int(np.max(sol.stats["elements per component"]))
    return sol.stats["time slabs"]


def _estimating(ode, compiled, plan, multi_adaptive, m, params, sink):
    """``sink`` (:mod:`dolfinode.io.history`), which for a mono-adaptive run without history
    (``dense_output`` False or a file) whose error at T :func:`estimate_global_error` may
    estimate also carries the estimate chunk by chunk (:class:`history.Estimating`)."""
    choice = params["estimate_global_error"]
    if (params["dense_output"] is True or multi_adaptive or not checks_at_T(params)
            or (plan is not None and plan.watched)
            or (choice == "auto" and (m.q + 2) * ode.N > AUTO_ROWS)):
        return sink
    atol = _absolute_tolerance(ode, params["absolute_tolerance"], params["tolerance"])
    return history.Estimating(sink, global_error.Running(ode, compiled, m,
                                                         atol / params["tolerance"]))


def estimate_global_error(ode, compiled, m, params, sol, steps):
    """Estimate the error at T of ``sol`` (a solve of ``ode`` by the method ``m`` with
    ``params``, without events or switches, whose busiest component took ``steps`` steps,
    :func:`longest_run`) when ``params["estimate_global_error"]`` asks for it (True, or "auto"
    for a run of more than one step of a small system: SHORTEST_RUN, AUTO_ROWS), with its
    warning (:func:`_warn_global_error`); a run without history, from the estimate its sink
    carried (:func:`_estimating`), and where there is none sol.stats["global error note"]
    says so."""
    choice = params["estimate_global_error"]
    if steps < fewest_checked_steps(choice) or (choice == "auto" and not sol.success):
        return  # (a run of one step: its step's error, which the step control bounds)
    running = getattr(sol, "_running_estimate", None)
    slabs = False
    if choice == "auto":
        kept = params["dense_output"] is True
        small = (m.q + 2) * ode.N <= AUTO_ROWS
        choice = small and (kept or running is not None)
        # larger runs: the slab estimate (no stage systems, no common refinement)
        slabs = kept and not small
        if not (choice or slabs):
            sol.stats["global error note"] = NO_HISTORY_NOTE
    if choice or slabs:
        _warn_global_error(ode, compiled, params, sol, slabs, running)


def _warn_global_error(ode, compiled, params, sol, slabs=False, running=None):
    """sol.stats["global error estimate"] (:mod:`dolfinode.global_error`, scaled as the
    tolerance means it), "global error nonlinearity" and "global error second order", and
    a ToleranceWarning when the estimate exceeds 10 x the tolerance where it holds (with
    fixed steps too: estimate_global_error=True compares them with the tolerance); where it
    is within 10 x but not with its second-order part added, the error is measured
    (:func:`_measure`, global_error.SECOND_ORDER). ``slabs``: by
    :func:`~dolfinode.global_error.slab_estimate`; where the run is stiff on a slab it gives
    up (:func:`_stiff_on_slabs`), and where its elements' copy exceeds the memory
    sol.stats["global error note"] says that the error at T was not estimated. ``running``:
    the estimate carried chunk by chunk (:class:`global_error.Running`). The estimates
    also give the largest error at an element end mid-run (every component's, a
    mono-adaptive run's at every slab end; :func:`global_error.carried`,
    :func:`global_error.slab_estimate`, :func:`global_error.modal_estimate`), "global error
    mid-run", with a ToleranceWarning where it exceeds 10 x the tolerance and the error at
    T does not (:func:`_midrun_warning`). Where the nonlinearity exceeds NONLINEAR_LIMIT,
    so that the estimate certifies nothing, and it or its remainder reaches 10 x at T or
    its mid-run value does, both are measured against a reference solve (:func:`_measure`)."""
    rtol = params["tolerance"]
    atol = _absolute_tolerance(ode, params["absolute_tolerance"], rtol)
    peak = np.zeros(3)  # the error mid-run: value, time, component
    if slabs:
        try:
            found = global_error.slab_estimate(sol, compiled, atol / rtol, peak)
        except ValueError as error:
            sol.stats["global error note"] = f"not estimated: {error}"
            return
        if found is None and not sol.multi and ode.N <= global_error.MAX_DENSE:
            peak[:] = 0.0  # (linear: exact flows, every slab end again)
            found = global_error.modal_estimate(sol, compiled, atol / rtol, peak)
        if found is None:
            _stiff_on_slabs(ode, params, sol, atol)
            return
    else:
        if running is None:
            running = global_error.carried(sol, compiled, atol / rtol)
        found, peak = (running.e, running.nu, running.delta), running.peak
    e, nu, delta = found
    # scaled by u(T) ~ U(T) - e, as the tolerance means: where the run damped |U| below |u|
    # (a stiff spring stepped over) U's own scale overstates the error (mdG(3) on the
    # 50-mass chain at 1e-2: 10.3 x against 9.33 x, the estimate within 1e-4 of the error)
    U = sol(ode.T)
    size, i = global_error.scaled(e, U - np.where(np.isfinite(e), e, 0.0), atol, rtol)
    sol.stats["global error estimate"] = size
    sol.stats["global error nonlinearity"] = nu
    sol.stats["global error second order"] = delta
    if peak[0] > 0.0:
        sol.stats["global error mid-run"] = float(peak[0])
    if (size <= global_error.WARN_FACTOR * rtol < size + delta
            and nu <= global_error.NONLINEAR_LIMIT):
        # the remainder the linearisation leaves out could lift the error above the
        # warning's threshold (a nonlinear oscillator's phase error at a node of its swing);
        # above NONLINEAR_LIMIT the estimate is not trusted either way (VDPOL's folds)
        _measure(ode, params, sol, atol, global_error.SECOND_ORDER)
        why = _midrun_warning(ode, compiled, sol, peak, nu, rtol, atol)
        if why:
            _warn(why)
        return
    if (nu > global_error.NONLINEAR_LIMIT and size <= global_error.WARN_FACTOR * rtol
            < max(size + delta, peak[0])):
        # not certified either way (far from linear), and near 10 x at T or past it mid-run:
        # measured (Van der Pol, mu = 10, dG(0) at 1e-2: 584 x mid-run, estimated 1184 x)
        _measure(ode, params, sol, atol, global_error.NONLINEAR, midrun=True)
        return
    why = global_error.warning(size, nu, rtol, ode.states[i])
    why = why or _midrun_warning(ode, compiled, sol, peak, nu, rtol, atol)
    if why and nu > global_error.NONLINEAR_LIMIT and np.isfinite(size):
        reference = _reference(ode, params, sol, atol)
        if reference is not None:
            measured, i, _ = _reference_error(sol, reference, atol, rtol)
            sol.stats["global error estimate"] = measured
            sol.stats["global error reference"] = rtol * REFERENCE_FACTOR
            why = global_error.measured_warning(measured, size, nu, rtol, ode.states[i],
                                                REFERENCE_FACTOR)
    if why:
        _warn(why)


def _midrun_warning(ode, compiled, sol, peak, nu, rtol, atol):
    """The ToleranceWarning's message (:func:`global_error.midrun_warning`) for the error
    mid-run ``peak`` (value, time, component; value 0: none compared) of ``sol``, whose error
    at T is sol.stats["global error estimate"] (estimated or measured); None where it is
    within WARN_FACTOR x the tolerance (or none was compared). It
    gives the time over which U_j changes by that error at its rate there,
    |e_j| / |f_j(U, t)|, |e_j| ~ peak (atol_j / rtol + |U_j|): where a fast transition is
    that near, the error is its phase (Van der Pol: 1.5e-7 of time at a rate of 1e6)."""
    largest, time, j = peak
    if largest <= global_error.WARN_FACTOR * rtol:  # (no warning: skip the f evaluation)
        return None
    j = int(j)
    shift = _time_shift(compiled, sol, largest, time, j, atol, rtol)
    return global_error.midrun_warning(largest, time, sol.stats["global error estimate"], nu,
                                       rtol, ode.states[j], shift, sol.multi)


def _time_shift(compiled, sol, error, time, j, atol, rtol):
    """|e_j| / |f_j(U, t)|: the time over which U_j changes by its error at ``time`` at its
    rate there, |e_j| = ``error`` (atol_j / rtol + |U_j|) (scaled as global_error.scaled);
    inf where U_j does not change."""
    U = sol(time)
    rate = abs(compiled.f_component(j, U, time))
    return error * (atol[j] / rtol + abs(U[j])) / rate if rate > 0.0 else np.inf


def _stiff_on_slabs(ode, params, sol, atol):
    """The error at T of a larger run stiff on its slabs, where the slab estimate gives up
    (and it is not linear of at most MAX_DENSE components: global_error.modal_estimate):
    measured against a REFERENCE_METHOD solve at REFERENCE_FACTOR x the tolerance
    (:func:`_reference`), with a ToleranceWarning above 10 x the tolerance, or where
    that solve fails, one that says the error could not be estimated. The stage-system
    estimate, L-stable, would follow the stiff modes, but damps a weakly damped oscillation
    the steps span (a stiff spring) as dG(q) does, and costs many times such a run (a
    nonlinear 50-mass chain's dG(1) at 1e-2: minutes against 0.2 s)."""
    _measure(ode, params, sol, atol, global_error.STIFF_SLABS)


def _measure(ode, params, sol, atol, reason, midrun=False):
    """sol.stats["global error estimate"] measured against a reference solve
    (:func:`_reference`, at REFERENCE_FACTOR x the tolerance: "global error reference"), and
    the ToleranceWarning of :func:`global_error.reference_warning` for ``reason`` above
    WARN_FACTOR x the tolerance, or where the reference solve failed. ``midrun``: also
    "global error mid-run", measured at the run's element ends (:func:`_reference_midrun`),
    with a ToleranceWarning where it exceeds WARN_FACTOR x the tolerance and the error at T
    does not."""
    rtol = params["tolerance"]
    reference = _reference(ode, params, sol, atol)
    if reference is None:
        _warn(global_error.reference_warning(None, rtol, None, REFERENCE_FACTOR, reason))
        return
    size, i, end = _reference_error(sol, reference, atol, rtol)
    sol.stats["global error estimate"] = size
    sol.stats["global error reference"] = rtol * REFERENCE_FACTOR
    why = global_error.reference_warning(size, rtol, ode.states[i], REFERENCE_FACTOR, reason)
    if midrun:
        peak, time, j = _reference_midrun(sol, reference, end, atol, rtol)
        sol.stats["global error mid-run"] = peak
        if not why and peak > global_error.WARN_FACTOR * rtol:
            why = global_error.measured_midrun_warning(
                peak, time, size, rtol, ode.states[j], REFERENCE_FACTOR, reason,
                _time_shift(lower(ode), sol, peak, time, j, atol, rtol))
    if why:
        _warn(why)


#: Element ends compared at once by :func:`_reference_midrun` (bounds its (N, M) arrays).
MIDRUN_CHUNK = 2**16


def _reference_midrun(sol, reference, end, atol, rtol):
    """(peak, t, j): the largest error of ``sol`` against ``reference`` at the element ends
    before ``end`` (every component's, at the union of the ends), scaled as
    :func:`global_error.scaled`, its time and component."""
    if sol.multi:
        ends = np.unique(np.concatenate([np.add(*sol.time_steps(i)) for i in range(sol.ode.N)]))
    else:
        ends = np.add(*sol.time_steps())
    ends = ends[ends < end]
    peak, time, j = 0.0, float(end), 0
    for first in range(0, ends.size, MIDRUN_CHUNK):
        times = ends[first:first + MIDRUN_CHUNK]
        V = reference(times)
        ratio = np.abs(sol(times) - V) / (atol[:, None] / rtol + np.abs(V))
        r, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[r, c] > peak:
            peak, time, j = float(ratio[r, c]), float(times[c]), int(r)
    return peak, time, j


#: sol.stats["global error note"] of a run without history "auto" did not estimate: a
#: multi-adaptive run or a larger system, whose estimates need the elements.
NO_HISTORY_NOTE = ("not estimated: without the history (dense_output=False or a file) the error "
                   f"at T is estimated by default for cG(q)/dG(q) runs with (q + 2) N <= "
                   f"{AUTO_ROWS}; estimate_global_error=True estimates any cG(q)/dG(q) run, "
                   "dense_output=True any run")


#: Where the linearised estimate exceeds 10 x the tolerance but does not hold (its
#: nonlinearity above global_error.NONLINEAR_LIMIT, as across VDPOL's folds), where it does
#: not apply (f jumps or switches, events: :func:`measure_piecewise_error`) and where the slab
#: estimate gives up (:func:`_stiff_on_slabs`), the error at T
#: is measured against a solve at REFERENCE_FACTOR x the tolerance (and atol) by
#: REFERENCE_METHOD (high order and L-stable: a few times the run's cost whatever its
#: method), of at most REFERENCE_STEPS x the run's slabs (at least 100).
REFERENCE_FACTOR, REFERENCE_METHOD, REFERENCE_STEPS = 1e-2, "dG(3)", 20


def measure_piecewise_error(ode, compiled, m, params, sol, steps):
    """The error at T of ``sol``, a solve of ``ode`` with events, breakpoints or switches in
    f (where the linearised estimate, made for one smooth f, does not apply), measured
    against a reference solve (:func:`_reference`) when
    ``params["estimate_global_error"]`` asks for it (as :func:`estimate_global_error`), into
    sol.stats["global error estimate"], with a ToleranceWarning above WARN_FACTOR x the
    tolerance or where the reference solve failed (:func:`_measure`)."""
    choice = params["estimate_global_error"]
    if choice == "auto":
        choice = sol.success and steps >= SHORTEST_RUN
    if choice:
        _measure(ode, params, sol,
                 _absolute_tolerance(ode, params["absolute_tolerance"], params["tolerance"]),
                 global_error.NOT_SMOOTH)


def _reference(ode, params, sol, atol):
    """The solve of ``ode`` by REFERENCE_METHOD at REFERENCE_FACTOR x the tolerance that
    ``sol``'s error is measured against; None where it fails or loses a component
    (:func:`lost_components`)."""
    rtol = params["tolerance"]
    tighter = {**params, "tolerance": rtol * REFERENCE_FACTOR,
               "absolute_tolerance": atol * REFERENCE_FACTOR, "estimate_global_error": False,
               "fixed_time_step": False,  # (a fixed-step run's: its steps would be the run's)
               "progress": False, "dense_output": True,  # (never the user's file)
               "maximum_steps": REFERENCE_STEPS * max(sol.stats["time slabs"], 100)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ToleranceWarning)
            reference = solve(ode, REFERENCE_METHOD, **tighter)
    except (SolverError, ValueError):
        return None
    if lost_components(ode, lower(ode), reference):  # (it lost what the run kept)
        return None
    return reference


def _reference_error(sol, reference, atol, rtol):
    """(size, i, end): U(end) - V(end) scaled as the tolerance means it
    (:func:`global_error.scaled`, by V, the closer to u), V the ``reference`` solve
    (:func:`_reference`); end: T, or where a terminal event ended either run first."""
    # (what evaluation reads: a prepared solution's declaration is made when read)
    end = min(sol._declaration.T, reference._declaration.T)
    V = reference(end)
    return (*global_error.scaled(sol(end) - V, V, atol, rtol), end)


def _warn(why):
    """A ToleranceWarning named at the first caller outside the package, however deep the
    call."""
    frame, level = sys._getframe(), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    warnings.warn(why, ToleranceWarning, stacklevel=level)


def _time_and_step(state, k):
    """(t, k): where a loop stopped (its ``state``) and its next step, for :func:`_finish`."""
    return float(state["t"][0]), float(k)


def _mono_stats(N, structure, counters, k_next):
    """The stats of a mono-adaptive run of N components from its loop's counters (an array
    or a list) and its next step."""
    slabs = int(counters[ts.SLABS])
    return {"time slabs": slabs, "elements": slabs * N,
            "factorizations": int(counters[ts.FACTORIZATIONS]),
            "newton matrices": structure.description if counters[ts.FACTORIZATIONS] else None,
            "next time step": k_next}


def _multi_workspace(ode, compiled, m, params, options, steps):
    """The multi-adaptive loop's arrays for a start with ``steps`` (and its fields of the
    ``options`` of :func:`_start`): (tables, kdes, frozen)."""
    from dolfinode.timeslab import multi  # (its loop is the longest compile of the package)

    _, _, kl, ku = compiled.ordering
    options[["theta", "beta", "band_lower", "band_upper", "autonomous"]] = (
        params["partitioning_threshold"], params["interval_threshold"], kl, ku, ode.autonomous)
    kdes = steps.copy()
    frozen = _filled(ode.N, np.nan)  # since when each component is frozen (NaN: active)
    return multi.method_tables(m), kdes, frozen


def _multi_arguments(compiled, tables, options, atol, floor, x, kdes, frozen, state,
                     counters, capacity):
    """The multi-adaptive loop's arguments but its output buffers, with the arrays it
    carries over calls (:func:`dolfinode.timeslab.multi.carry`) for buffers of ``capacity``
    elements: a call ``multi.advance.unchecked(*arguments, *buffers)`` (``_multi_buffers``)
    runs elements until T or until the buffers are full, and returns its status."""
    from dolfinode.timeslab import multi

    nn = tables[7].shape[0]  # (the nodes, in multi.method_tables' order)
    return (compiled.rhs.address, compiled.rhs_component.address,
            compiled.jacobian_row.address, compiled.p, compiled.indptr, compiled.indices,
            compiled.ordering[1], *tables, options, atol, floor, x, kdes, frozen, state,
            counters, multi.carry(x.size, nn, compiled.indices.size, capacity))


def _multi_calls(ode, m, call, arguments):
    """(buffers, advance) of :func:`_chunks` for the multi-adaptive loop: buffers(capacity)
    makes the output buffers and grows the carried arrays (the last of ``arguments``) with
    them (:func:`dolfinode.timeslab.multi.grown`); advance(*buffers) is ``call(*arguments,
    *buffers)``."""
    from dolfinode.timeslab import multi

    arguments = list(arguments)

    def buffers(capacity):
        arguments[-1] = multi.grown(arguments[-1], capacity)
        return tuple(np.empty(shape, dtype) for shape, dtype in _multi_buffers(ode, m, capacity))

    def advance(*buffers):
        return call(*arguments, *buffers)

    return buffers, advance


def _multi_buffers(ode, m, capacity):
    """The (shape, dtype)s of the multi-adaptive loop's output buffers for ``capacity``
    elements: component, start, end and values of each element, and start, end and values
    (q + 1, N) of the slabs stored as blocks, as many as fill as much memory."""
    blocks = max(1, capacity // ode.N)
    return ((capacity, np.int64), (capacity, float), (capacity, float),
            ((capacity, m.q + 1), float), (blocks, float), (blocks, float),
            ((blocks, (m.q + 1) * ode.N), float))


def _multi_capacity(ode, m):
    """Elements per loop call: values at most 2^21 doubles, as mono's (from 32 MB on, each
    solve would map fresh pages)."""
    return _limited(int(max(64 * ode.N, min(2 ** 20, 2 ** 21 // (m.q + 1)))))


def _multi_stats(counters, mono_elements, per_component, kdes):
    """The stats of a multi-adaptive run from its loop's counters (an array or a list) and
    the mono-adaptive elements its slabs stand for (``state["mono_elements"]``)."""

    total = int(counters[ts.ELEMENTS])
    return {"time slabs": int(counters[ts.SLABS]),
            "sub-slabs": int(counters[ts.SUBSLABS]),
            "elements": total,
            "elements per component": per_component,
            "factorizations": int(counters[ts.FACTORIZATIONS]),
            "efficiency index": mono_elements / max(total, 1),
            "synchronised slabs": int(counters[ts.SYNCHRONISED]),
            "next time step": kdes.copy()}


def _run_multi(ode, compiled, m, params, options, atol, floor, x, f0, steps, state, counters,
               plan, sink, kept=None):
    """:func:`_run_mono` for the multi-adaptive loop (``kept``: its ``steps`` are the
    loop's desired steps)."""
    from dolfinode.timeslab import multi

    capacity, smallest = _multi_capacity(ode, m), None
    if plan is not None and plan.truncates:
        capacity = min(capacity, max(4 * ode.N, _EVENT_CHUNK))
        smallest = _MULTI_RESTART_CHUNK * ode.N
    if kept is None:
        tables, kdes, frozen = _multi_workspace(ode, compiled, m, params, options, steps)
        call, arguments, first = multi.advance.unchecked, _multi_arguments(
            compiled, tables, options, atol, floor, x, kdes, frozen, state, counters,
            capacity), None
    else:
        (call, arguments, first), kdes, frozen = kept, steps, None
    buffers, advance = _multi_calls(ode, m, call, arguments)
    with _progress(ode, params) as bar:
        def chunks():
            return _chunks(advance, buffers, capacity, counters, params, state, bar,
                           first=first, smallest=smallest)

        pieces = plan and ev.MultiPieces(
            ode, m, chunks, options, state, x, compiled.p, len(ode.params),
            _step_guess(ode, compiled, atol, options["rtol"][0]), kdes=kdes, frozen=frozen,
            components=plan.detector.components)
        status, elements = _integrate(chunks, plan, pieces, ode, state, sink)
    if status == ts.DONE:
        _warn_undamped(ode, compiled, m, params, options, state, multi_adaptive=True)
        _warn_interior(ode, m, state)
    return (status, counters, _time_and_step(state, np.min(kdes)), elements,
            _multi_stats(counters, float(state["mono_elements"][0]), sink.per_component, kdes))


class _NoProgress:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def _progress(ode, params):
    """A tqdm bar over [t0, T] when ``progress=True``."""
    if not params["progress"]:
        return _NoProgress()
    from tqdm.auto import tqdm

    return tqdm(total=ode.T - ode.t0, unit="t", desc="dolfinode",
                bar_format="{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}]")
