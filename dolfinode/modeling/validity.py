"""A posteriori validity of a reduced model: the modeling-error estimate and its warning.

The error of the reduced solution U against the average u-bar of the full model, in a goal
M(u) = (psi, u(T)), is (Jansson, Johnson & Logg 2005, "Error analysis")

    M(U) - M(u-bar) = (discretisation residual, phi)  +  int_{t_c}^T (phi, g~ - g-bar) dt,

with phi the dual solution of the reduced problem (-phi' = (df~/du)^T phi, phi(T) = psi). The
defect d = g~ - g-bar of a model is measured at the control points between its build and
its rebuild (the check that rebuilds it measures it last); on that span |d_i| is bounded by the
largest of those measurements (it varies between checks: an explicit time dependence of f
leaves a bias of the kernel, avg cos t = 0.9997 cos t at tau = 1, that the checks sample). A
model built at the last control point, not yet checked, is taken to have the last defect:

    modeling part  ~  int_{t_c}^T sum_i |phi_i(t)| |d_i(t)| dt,

at most the paper's bound S0 max ||g~ - g-bar||. Where the fast oscillation is damped or
excited by itself (its squared amplitudes change at the rate r of
:func:`~dolfinode.modeling.reduced.amplitude_rate`), the checks, restarted with the recorded
fluctuation, cannot see g-bar follow it, and |d_i(t)| is taken to grow by
|g-bar_i| |exp(r (t - t_c)) - 1| (at most |g-bar_i| for a decay), or by r_i (t - t_c) with
the rate r_i measured inside the resolved windows (:func:`unfollowed_rate`: a resonant
forcing, linear in J's eigenvalues, has no such r), the larger of the two. A goal at T misses what a dissipative system
forgets: a model wrong until the first check (then rebuilt) leaves an error on that span
only; ``local`` = max over the spans between checks of max |d| times the span's length is
that error before the dynamics propagate it, and is checked against the tolerance too. The
default goal
is every slow (active) component at T, each on its own (one dual per component, up to
DUAL_COMPONENTS of them; the sum of the active components beyond).

The estimate is against u-bar: pointwise the full solution u differs from it also by the fast
oscillation of the slow components (a slow y' = -y + x^2 forced by x = cos(omega t) carries
y - y-bar = sin(2 omega t) / (4 omega)). Its amplitude, measured in every resolved window, is
checked against the tolerance too (:func:`check_oscillation`).
"""
import warnings
from dataclasses import dataclass

import numpy as np
import sympy as sp

from dolfinode.errors import ModelingWarning, SolverError
from dolfinode.modeling.averaging import kernel_weights

#: Up to this many active components the default goal takes one dual per component (each slow
#: component at T is an output); beyond, one dual for their sum.
DUAL_COMPONENTS = 8
#: Gauss points per dual interval for the integral of |phi| |d|.
GAUSS_POINTS = 4
#: Samples of the half window's kernel in :func:`half_window_response` (the response does
#: not change from 100 to 10^4).
HALF_WINDOW_SAMPLES = 500


@dataclass
class ModelingError:
    """The error estimate of a reduced solution in a goal (:meth:`ReducedModel.modeling_error`).

    Attributes
    ----------
    bound : the modeling part: int sum_i |phi_i| |g~_i - g-bar_i| dt over (t_c, T] (module
        docstring)
    S0 : int ||phi||_l2 dt of the reduced model's dual problem
    largest_defect : max over the control points of ||g~ - g-bar||_l2
    discretization : the dual estimate of the reduced solution's own discretisation error in
        the goal (against the exact reduced solution u~, residual of the model as last built)
    local : max over the spans between the start and the checks of max_i |d_i| (span length):
        the error a defect leaves on its span before the dynamics propagate it
    goal : the output estimated (for the default goal, the slow component of largest total)
    worst_time, worst_state : the control point and the state of the largest relative defect
    """

    bound: float
    S0: float
    largest_defect: float
    discretization: float
    local: float = 0.0
    goal: str = "the goal"
    worst_time: float = np.nan
    worst_state: object = None

    @property
    def total(self):
        """bound + |discretization|: the estimate of |M(U) - M(u-bar)|."""
        return self.bound + abs(self.discretization)


def modeling_error(model, goal=None):
    """:class:`ModelingError` of ``model`` (a solved :class:`ReducedModel`) in ``goal``."""
    from dolfinode.dual.estimate import estimate_linearised

    worst = None
    for name, psi in _goals(model, goal).items():
        estimate = estimate_linearised(model.reduced, psi)
        part = ModelingError(_weighted_defect(estimate.dual, model),
                             estimate.stability_factors["S0"], model.largest_defect,
                             estimate.value, float(_local_defect(model)), name)
        if worst is None or part.total > worst.total:
            worst = part
    point = max(model.control_points, key=lambda c: c.relative_defect)
    worst.worst_time = float(point.time)
    worst.worst_state = model.ode.states[int(np.argmax(np.abs(point.defects)))]
    return worst


def flow_error(model, goal=None):
    """:class:`ModelingError` of a :class:`~dolfinode.modeling.flow.FlowModel` in ``goal``:
    the modeling part FLOW_SAFETY |(psi, D(T))| from the difference D of the averages of the
    flows at the two scale separations (see :mod:`dolfinode.modeling.flow`), ``local`` the
    same at the worst comparison time. No dual is solved (S0 is nan): the dual of the
    oscillating flow cost 20 times the flows; the two flows are solved on their own meshes
    to the tolerance, so D holds their discretisation errors too, and ``discretization``
    is 0."""
    from dolfinode.modeling.flow import FLOW_SAFETY

    worst = None
    for name, psi in _goals(model, goal).items():
        differences = np.abs(_goal_vector(model.ode, psi) @ model.difference)
        part = ModelingError(FLOW_SAFETY * float(differences[-1]), np.nan,
                             model.largest_defect, 0.0, FLOW_SAFETY * float(differences.max()),
                             name)
        if worst is None or part.total > worst.total:
            worst = part
    where = np.abs(model.difference) * model.active[:, None]
    i, j = np.unravel_index(np.argmax(where), where.shape)
    worst.worst_time, worst.worst_state = float(model.times[j]), model.ode.states[int(i)]
    return worst


def _goal_vector(ode, goal):
    """psi of a linear final-time goal (a dict by state or a vector); the flow model's
    difference is known at the output times only for such goals."""
    from dolfinode.dual.goal import Goal, _Functional

    goal = Goal.parse(goal)
    if goal.integral is not None or isinstance(goal.final, sp.Basic):
        raise ValueError("the flow model's modeling error is estimated for linear final-time "
                         "goals (psi, u(T)): a dict by state or a vector of N weights")
    return _Functional(goal.final, ode, "final", False).weights


def _goals(model, goal):
    """{name: psi}: the given goal, or each active (slow) component at T (the sum of them
    beyond DUAL_COMPONENTS)."""
    active = np.flatnonzero(model.active)
    if goal is not None:
        return {"the goal": goal}
    if len(active) <= DUAL_COMPONENTS:
        return {f"{model.ode.states[i]}(T)": np.eye(model.ode.N)[i] for i in active}
    return {"the sum of the slow components at T": model.active.astype(float)}


def _local_defect(model):
    """max over the spans (t_{k-1}, t_k] between the reduced solution's start and the checks
    of max_i |d_{k,i}| (t_k - t_{k-1})."""
    times = [model.reduced.ode.t0] + [c.time for c in model.control_points]
    return max(float(np.max(np.abs(c.defects))) * (b - a)
               for a, b, c in zip(times[:-1], times[1:], model.control_points))


def _weighted_defect(phi, model):
    """int sum_i |phi_i(t)| |d_i(t)| dt over (t_c, T], |d| bounded on the span of each
    model as in the module docstring."""
    checks = model.control_points
    times = [model.reduced.ode.t0] + [c.time for c in checks] + [model.reduced.ode.T]
    # model k is used from the k-th build on, and measured by the checks up to its rebuild
    built = np.cumsum([0] + [c.rebuilt for c in checks])  # the model used up to each check
    largest = {}
    for model_index, check in zip(built, checks):
        largest[model_index] = np.maximum(largest.get(model_index, 0.0), np.abs(check.defects))
    g_bar = np.max([np.abs(c.g_bar) for c in checks], axis=0)
    unfollowed = unfollowed_rate(model)
    x, w = np.polynomial.legendre.leggauss(GAUSS_POINTS)
    total = 0.0
    for a, b, model_index in zip(times[:-1], times[1:], built):
        if b <= a:
            continue
        d = largest.get(model_index, np.abs(checks[-1].defects))
        nodes = np.concatenate([[a], phi.grid[(phi.grid > a) & (phi.grid < b)], [b]])
        mid, half = (nodes[1:] + nodes[:-1]) / 2, (nodes[1:] - nodes[:-1]) / 2
        s = (mid[:, None] + half[:, None] * x).ravel()
        weights = np.abs(phi(s))
        # (a damping that amplitude_rate predicts shows in the windows too: counted once)
        drift = np.maximum(np.abs(np.expm1(model.amplitude_rate * (s - times[0])))
                           * (g_bar @ weights), (s - times[0]) * (unfollowed @ weights))
        total += float((half[:, None] * w).ravel() @ (d @ weights + drift))
    return total


def _remedies(model):
    """What a warning about the reduced ``model`` suggests: subgrid_model='flow' where a
    parameter sets the fast scale (it carries the fast state instead of a model of it: on
    a fast mode driven by slow forcing, or coupled cubically, or with a fast relaxation, it
    met the tolerance where the affine model was 3-316 x off), 'affine' where the model is
    not affine yet."""
    from dolfinode.modeling.flow import stiffness_parameter  # (flow imports this module)

    remedies = ["a longer average_length", "more control_points"]
    if not model.affine:
        remedies.append("subgrid_model='affine'")
    if model._compiled is not None and stiffness_parameter(model.ode, model._compiled):
        remedies.insert(0, "subgrid_model='flow'")
    return ", ".join(remedies)


def unfollowed_rate(model):
    """Per component, |r_i|: the rate at which g-bar moves inside the resolved windows beyond
    what the affine model's slope G gives for the slow state's move there (the median over
    the windows; 0 where r_i (T - t_c) is below ``model_tolerance`` (max |g-bar_i| +
    tolerance), the defect at which a check rebuilds).

    Each window gives g-bar and u-bar on its two halves, so the rate w_k of g-bar there and
    the part of it G (u-bar_2 - u-bar_1) / (their distance) that follows the slow state; the
    rest is what the fast oscillation does by itself (an amplitude that a resonant or
    parametric forcing or a damping makes grow or decay). The checks never see it:
    restarted from the recorded fluctuation, they see the fast amplitude of the build, so
    the defect grows by about r (t - t_c) unmeasured (a fast rotation driving a second at
    its own frequency, whose amplitude grows linearly: the model's error at T = 10 was 0.64
    and its estimate 0.004). The median keeps what all windows share. Less than the
    difference the half windows' kernels let through from the slowest fast oscillation
    (:func:`half_window_response`) counts as no drift."""
    from dolfinode.modeling.reduced import component_frequencies

    windows = [w for w in model.windows if w.halves]
    rate = np.zeros(model.ode.N)
    oscillating = ~model.active & ~model._slaved
    if not windows or model._compiled is None or not oscillating.any():
        return rate
    compiled = model._compiled

    def g(w):
        return w.f_bar - compiled.f(model.state(w.u_bar, w.center), w.center)

    first, second = windows[0].halves
    separation = second.center - first.center
    within = np.array([g(w.halves[1]) - g(w.halves[0]) - model._apply_G(
        model.state(w.halves[1].u_bar) - model.state(w.halves[0].u_bar)) for w in windows])
    scale = np.max([np.abs(g(w)) for w in windows], axis=0)
    omega = np.min(component_frequencies(compiled.jacobian_matrix(
        windows[0].u_bar, windows[0].center))[oscillating])
    noise = 2 * half_window_response(omega, separation / 2) * scale
    rate = np.maximum(np.abs(np.median(within, axis=0)) - noise, 0.0) / separation
    span = model.reduced.ode.T - model.reduced.ode.t0
    rate[rate * span <= model.model_tolerance * (scale + model.tolerance)] = 0.0
    return np.where(model.active, rate, 0.0)


def half_window_response(omega, half_width, samples=HALF_WINDOW_SAMPLES):
    """max over phases of the half window's kernel average of cos(omega t + phase): the
    error by which a half window's g-bar can differ from the other's without any drift
    (the seed model at omega tau = 30: 1.3e-5 of the oscillation at 2 omega, which alone
    gave it a drift of 1.7e-3 per unit time)."""
    s = np.linspace(-1.0, 1.0, 2 * samples + 1)
    return float(abs(kernel_weights(samples) @ np.exp(1j * omega * half_width * s)))


def model_fails(estimate, tolerance):
    """Whether the model itself fails the check, not the discretisation: the modeling part
    of the :class:`ModelingError` or its ``local`` part above ``tolerance``."""
    return estimate is not None and max(estimate.bound, estimate.local) > tolerance


def check_validity(model, tolerance, model_tolerance, strict, stacklevel=5, estimate=None):
    """Warn (``ModelingWarning``), or raise SolverError when ``strict``, when the reduced
    model's error estimate in the default goal, or its ``local`` part, exceeds ``tolerance``;
    the message says too when the last two control points both found a relative defect above
    ``model_tolerance`` (rebuilding did not help). Returns the :class:`ModelingError` (None
    without control points); ``estimate``, where given, is ``model.modeling_error()``."""
    if model.subgrid_model != "flow" and not model.control_points:
        return None
    if estimate is None:
        estimate = model.modeling_error()
    problems = []
    if estimate.total > tolerance:
        problems.append(f"its error estimate {estimate.total:.3g} in {estimate.goal} (modeling "
                        f"{estimate.bound:.3g}, discretisation "
                        f"{abs(estimate.discretization):.3g}) exceeds the tolerance {tolerance:g}")
    flow = model.subgrid_model == "flow"
    if estimate.local > tolerance:
        problems.append(
            f"the averages of the flows at the two scale separations differ, times the "
            f"safety factor, by {estimate.local:.3g} at t = {estimate.worst_time:.4g}, above "
            f"the tolerance {tolerance:g}" if flow else
            f"a defect found at a control point, times the span before it, is "
            f"{estimate.local:.3g}, above the tolerance {tolerance:g} (the solution on that "
            "span may be off by as much)")
    if not problems:
        return estimate
    if flow:
        rates = ", ".join(f"{r:.3g}" for r in model.rates[1:])
        message = (f"the flow-averaged model may not represent the full one: "
                   f"{'; '.join(problems)} (largest in {estimate.worst_state}). The flows "
                   f"slow the fast scale {model.rates[0]:.3g} down to {rates}, too little "
                   "separated from the slow one for this tolerance: solve without "
                   "automatic_modeling, or raise dolfinode.modeling.flow.FLOW_SEPARATION")
        if strict:
            raise SolverError("automatic modeling: " + message, t=estimate.worst_time)
        warnings.warn(message, ModelingWarning, stacklevel=stacklevel)
        return estimate
    message = (f"the reduced model may not represent the full one: {'; '.join(problems)}; "
               f"largest relative defect at t = {estimate.worst_time:.4g} in "
               f"{estimate.worst_state}")
    failed = [c for c in model.control_points[-2:] if c.relative_defect > model_tolerance]
    if len(failed) == 2:
        message += (f"; the last two control points (t = {failed[0].time:.4g}, "
                    f"{failed[1].time:.4g}) found relative defects "
                    f"{failed[0].relative_defect:.3g}, {failed[1].relative_defect:.3g} above "
                    f"model_tolerance = {model_tolerance:g} although the model was rebuilt")
    if model.amplitude_rate:
        message += (f"; the fast oscillation is damped or excited by itself (its squared "
                    f"amplitude grows at the rate {model.amplitude_rate:.3g}), which the "
                    "reduced model does not follow")
    unfollowed = unfollowed_rate(model)
    if unfollowed.any():
        i = int(np.argmax(unfollowed))
        message += (f"; inside the resolved windows g-bar of {model.ode.states[i]} moves at "
                    f"{unfollowed[i]:.3g} per unit time beyond what the slow state explains "
                    "(the fast oscillation changes by itself: a resonant or parametric "
                    "forcing), which the checks, restarted from the recorded fluctuation, "
                    "do not see")
    message += f". Try {_remedies(model)}, or solve without automatic_modeling"
    if strict:
        raise SolverError("automatic modeling: " + message, t=estimate.worst_time)
    warnings.warn(message, ModelingWarning, stacklevel=stacklevel)
    return estimate


#: The words that tell the warning of :func:`check_oscillation` from the model's own.
OSCILLATION = "oscillates about it on the fast scale"


def check_oscillation(model, tolerance, stacklevel=5):
    """Warn (``ModelingWarning``) when a slow (active) component oscillates on the fast scale,
    in a resolved window, with an amplitude above ``tolerance``: the solution, an average,
    then differs from the full one pointwise by about that much whatever its error estimate.
    Returns the largest amplitude (0 for the flow-averaged model, which resolves no window
    of the full model)."""
    if model.subgrid_model == "flow":
        return 0.0
    amplitudes = [np.where(model.active, w.amplitude, 0.0) for w in model.windows]
    window, i = np.unravel_index(np.argmax(amplitudes), (len(amplitudes), model.ode.N))
    largest = float(amplitudes[window][i])
    if largest > tolerance:
        warnings.warn(
            f"the solution is the average of the full one over the averaging kernel "
            f"(average_length {model.average_length:.3g}): its slow component {model.ode.states[i]} "
            f"{OSCILLATION} with amplitude {largest:.3g} (measured in "
            f"the window at t = {model.windows[window].center:.4g}), above the tolerance "
            f"{tolerance:g}, so pointwise the full solution differs from the returned one by "
            "about that much; sol.stats['fast oscillation'] holds it. For pointwise accuracy "
            "solve without automatic_modeling", ModelingWarning, stacklevel=stacklevel)
    return largest
