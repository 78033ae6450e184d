"""The flow-averaged model (``subgrid_model="flow"``): the fast variables are carried, never
reconstructed.

A reduced model that freezes the fast components and restarts them at control points from a
recorded fluctuation rebuilds their slow quantities (amplitudes, energies, adiabatic
invariants) from stale data, and it cannot represent slow variables that are combinations of
components (the centres of stiff springs). The seamless heterogeneous multiscale method (E,
Ren & Vanden-Eijnden, J. Comput. Phys. 228, 2009) evolves the fast variables continuously
with the slow ones, its micro solver carried from macro step to macro step; it is
equivalent to the full model with the fast scale slowed down to a moderate separation from
the slow one (their "boosting"; FLAVORS, Tao, Owhadi & Marsden, Multiscale Model. Simul.
2010, switch the stiff part off and on for the same effect). Here, with sympy's declaration:

1. the stiffness parameter p is the parameter with which the spectral radius rho of df/du(u0)
   scales most, rho ~ p^e with |e| >= MIN_EXPONENT (kappa of x'' = -kappa x: e = 1/2; a
   small mass: e = -1/2; the rate of a relaxation: e = 1), see :func:`stiffness_parameter`;
2. the flow is the full model with p replaced by p (rho_2 / rho)^(1/e), whose fast rate is
   rho_2 = min(rho, 2 FLOW_SEPARATION rho_slow) (rho_slow the |lambda| of df/du(u0) below its
   largest gap, see :func:`slow_rate`), solved from u0 on [t0, T + tau_1] with a conservative
   cG method (dG damps the fast oscillation, whose energy drives the slow variables) of
   degree at least RESOLVING_DEGREE (see :func:`resolving_method`);
3. the output is its average with the modeling kernel K (:mod:`~dolfinode.modeling.averaging`)
   of half-length tau' = max(MINIMUM_PERIODS / rho_2, SLOW_FRACTION / rho_slow), shortened
   to t - t0 near t0:

       U-bar(t) = int K_h(s) U(t + s) ds,   h = min(tau', t - t0);

4. the modeling error is measured: the flow is solved again at rho_1 = rho_2 / 2 (p scaled
   by 2^(-1/e)); the difference D = U-bar_1 - U-bar_2 of the averages (both of half-length
   tau_1, tau' with rho_1) is the error of the finer flow against the limit rho -> inf for
   a convergence of order one in rho (adiabatic corrections are O(1 / rho)), and
   FLOW_SAFETY |D| is the modeling part of the a posteriori check
   (:func:`dolfinode.modeling.validity.flow_error`). Where rho_2 = rho there is nothing
   to slow down: the full model is solved at the tolerance and at FULL_TIGHTER times it
   (returned), and D estimates the discretisation error.

The cost depends on rho_slow and [t0, T], not on rho. The premise is that of any modeling with
a scale separation: the averages of the family of models with p varied and u0 fixed have a
limit as rho -> inf, which the user's rho is close to; the check measures how far the flow
is from it, and warns (:class:`~dolfinode.ModelingWarning`) where that is above the
tolerance.
"""
import math
from dataclasses import dataclass, field

import numpy as np

from dolfinode.compile import lower
from dolfinode.ensemble import vary
from dolfinode.methods import parse_method
from dolfinode.modeling import validity
from dolfinode.modeling.averaging import kernel_weights
from dolfinode.modeling.reduced import (
    MINIMUM_PERIODS,
    SLOW_FRACTION,
    component_frequencies,
    fast_time_scale,
    relaxing_components,
)
from dolfinode.solution import Solution

#: The flow's fast rate over the slow one: rho_1 = FLOW_SEPARATION rho_slow (on the adiabatic
#: class of dolfinode.bench.multiscale, rho_slow = 1.4, the averages at rho = 100 are within
#: 1.7e-5 of those at 1e3, and the error falls like rho^-2). At 75 the check's averages, over
#: MINIMUM_PERIODS radians of rho_1, are 0.4 / rho_slow long: they damp a slow oscillation by
#: 8e-6.
FLOW_SEPARATION = 75.0
#: The check's flow is this much faster: rho_2 = FLOW_REFINEMENT rho_1.
FLOW_REFINEMENT = 2.0
#: The modeling part of the estimate is FLOW_SAFETY |U-bar_1 - U-bar_2|: the error of the finer
#: flow is |D| / (FLOW_REFINEMENT^a - 1) for convergence of order a in rho, at most |D| for
#: a >= 1; the safety covers a down to about 0.6.
FLOW_SAFETY = 2.0
#: Where the full model is no faster than rho_2 it is solved, and checked by a solve at
#: this fraction of the tolerance (returned; D then estimates the discretisation error).
FULL_TIGHTER = 0.1
#: The flows (and the resolved windows) are solved with cG(q) (mcG(q)) of this degree at
#: least: they carry thousands of fast periods, and at the tolerance the steps per period
#: fall with q (the adiabatic class at
#: rho_2 = 212, tolerance 1e-4: cG(2) 199,000 slabs, cG(3) 50,000, cG(4) 26,000, with the
#: slow x1(T) the same to 2e-7).
RESOLVING_DEGREE = 4
#: A parameter p is a stiffness when rho ~ p^e with |e| at least this.
MIN_EXPONENT = 0.25
#: p is multiplied by this to measure e.
PROBE = 4.0
#: ``subgrid_model="auto"`` takes the flow when a fast frequency changes by more than this
#: fraction with the slow state, predicted over [t0, T] from the first window's halves or
#: found at a control point (its adiabatic invariant then moves the fast amplitudes with the
#: slow state, which a frozen fluctuation cannot follow).
FLOW_START = 0.1
#: Output times at which the two flows are compared, and the kernel's points per half
#: window there (tau_1 rho_2 = 2 MINIMUM_PERIODS = 60: 8 points per fast period; the kernel
#: vanishes with five derivatives at the ends, and from 250 points D on the slow components
#: moved by 6e-9 on the adiabatic class, 1e-6 of |D| = 2.5e-3 on Fermi-Pasta-Ulam).
COMPARISON_TIMES = 200
COMPARISON_SAMPLES = 80
#: Bytes of solution values evaluated at once for the averages.
EVALUATION_BYTES = 2**26


def stiffness_parameter(ode, compiled):
    """(p, e): the parameter of ``ode`` with which the spectral radius of df/du(u0, t0)
    scales most, rho(p PROBE) / rho(p) = PROBE^e, with |e| >= MIN_EXPONENT; None without
    one."""
    rho = 1.0 / fast_time_scale(compiled, ode.u0, ode.t0)
    best = None
    if not np.isfinite(rho) or rho == 0:
        return None
    for symbol, value in ode.params.items():
        try:
            value = float(value)
        except (TypeError, ValueError):
            continue
        if value == 0 or not np.isfinite(value):
            continue
        varied = vary(ode, {symbol: value * PROBE})
        probe = 1.0 / fast_time_scale(lower(varied), ode.u0, ode.t0)
        exponent = math.log(probe / rho) / math.log(PROBE)
        if abs(exponent) >= MIN_EXPONENT and (best is None or abs(exponent) > abs(best[1])):
            best = (symbol, exponent)
    return best


def slow_rate(compiled, u, t):
    """The slow rate of df/du at (u, t): the |lambda| below the largest ratio between
    consecutive nonzero |lambda| (0 for one distinct |lambda|, or for more than 500
    components, whose spectrum is not computed in full)."""
    J = compiled.jacobian_matrix(u, t)
    if J.shape[0] > 500:
        return 0.0
    moduli = np.unique(np.abs(np.linalg.eigvals(J.toarray())))
    moduli = moduli[moduli > 0]
    if moduli.size < 2:
        return 0.0
    return float(moduli[np.argmax(moduli[1:] / moduli[:-1])])


def frequency_change(J_a, J_b, tau):
    """max_i |omega_i(b) - omega_i(a)| / omega_i(a) over the fast oscillating components
    (omega_i tau >= 2 pi, not relaxing) of the frequencies
    :func:`~dolfinode.modeling.reduced.component_frequencies` of the Jacobians J_a and J_b
    (0 without such components)."""
    omega_a, omega_b = component_frequencies(J_a), component_frequencies(J_b)
    fast = (omega_a * tau >= 2 * np.pi) & ~relaxing_components(J_a, omega_a > 0)
    if not fast.any():
        return 0.0
    return float(np.max(np.abs(omega_b[fast] - omega_a[fast]) / omega_a[fast]))


@dataclass
class FlowModel:
    """The flow-averaged model of a solve (``sol.model`` for ``subgrid_model="flow"``).

    Attributes
    ----------
    stiffness : the stiffness parameter (a sympy symbol) and its exponent e (rho ~ p^e)
    rates : rho of the full model, rho_1 and rho_2 of the two flows
    average_length : tau', the half-length of the output averages
    reduced : the finer flow (the full model at rho_2) on [t0, T + tau_1], a Solution
    coarse : the flow at rho_1
    times : the comparison times in [t0 + tau_1, T] (T last)
    difference : U-bar_1 - U-bar_2 at ``times``, shape (N, len(times))
    active : bool mask of the outputs the default goal estimates: the components that do
        not oscillate on the flow's fast scale (all of them when every one does)
    estimate : the :class:`~dolfinode.modeling.validity.ModelingError` of the default goal
    reason : why the flow model was chosen
    """

    ode: object
    stiffness: tuple
    rates: tuple
    average_length: float
    reduced: Solution
    coarse: Solution
    times: np.ndarray
    difference: np.ndarray
    active: np.ndarray
    reason: str = "subgrid_model='flow'"
    estimate: object = None
    subgrid_model: str = "flow"
    control_points: list = field(default_factory=list)

    @property
    def built(self):
        return [float(self.ode.t0)]

    @property
    def g(self):
        """No subgrid term: the flow evolves the fast variables."""
        return {}

    @property
    def inactive(self):
        return ()

    @property
    def largest_defect(self):
        """max over the comparison times and outputs of |U-bar_1 - U-bar_2|."""
        return float(np.max(np.abs(self.difference[self.active]), initial=0.0))

    def modeling_error(self, goal=None):
        """The error estimate of the output (the average of the finer flow) against the
        average of the full model in a goal, see :func:`dolfinode.modeling.validity.flow_error`.

        Parameters
        ----------
        goal : any goal form of :func:`dolfinode.estimate_error`, optional
            Default: each output component at T on its own, the largest estimate.

        Returns
        -------
        :class:`~dolfinode.modeling.validity.ModelingError`
        """
        return validity.flow_error(self, goal)

    def __repr__(self):
        return (f"FlowModel({self.stiffness[0]} scaled: rho {self.rates[0]:.3g} -> "
                f"{self.rates[2]:.3g}, tau={self.average_length:.3g})")


class FlowSolution(Solution):
    """The kernel average of a flow (:class:`FlowModel`) on [t0, T]: U-bar(t) with the
    half-length min(tau', t - t0) (the module docstring). Its elements are the flow's
    (``model.reduced``): ``t_start``, ``k``, ``values``, :meth:`time_steps` and
    :meth:`elements` raise AttributeError."""

    def __init__(self, ode, flow, tau, samples, number_of_samples):
        self.ode, self.flow, self.tau, self.stats = ode, flow, tau, {}
        self.method = flow.method
        self._weights = kernel_weights(samples)
        self._offsets = np.linspace(-1.0, 1.0, self._weights.size)
        self._sample(number_of_samples)

    @property
    def multi(self):
        return self.flow.multi

    def _evaluate(self, times):
        return average(self.flow, times, np.minimum(self.tau, times - self.ode.t0),
                       self._weights, self._offsets)

    def _not_stored(self, *args, **kwargs):
        raise AttributeError("a flow-averaged solution is an average of the flow "
                             "sol.model.reduced, which has the elements")

    t_start = k = values = property(_not_stored)
    time_steps = elements = _not_stored

    def __repr__(self):
        return (f"FlowSolution({self.method.name}, N={self.ode.N}, "
                f"t=[{self.ode.t0}, {self.ode.T}], tau={self.tau:.3g})")


def average(solution, times, half, weights, offsets):
    """int K_h(s) U(t + s) ds at ``times`` with half-lengths ``half`` (the modeling kernel
    on the points ``offsets`` of [-1, 1] with ``weights``), shape (N, len(times))."""
    N = solution.ode.N
    out = np.empty((N, times.size))
    chunk = max(1, EVALUATION_BYTES // (8 * N * weights.size))
    for a in range(0, times.size, chunk):
        grid = times[a:a + chunk, None] + half[a:a + chunk, None] * offsets
        values = solution(grid.ravel()).reshape(N, *grid.shape)
        out[:, a:a + chunk] = values @ weights
    return out


def resolving_method(method):
    """The method that resolves the fast scale, in the flows and in the windows of the
    reduced models: cG(max(q, RESOLVING_DEGREE)) for cG(q) or dG(q), mcG(...) for mcG(q)
    or mdG(q) (conservative: dG damps the fast oscillation)."""
    multi, m = parse_method(method)
    return f"{'m' if multi else ''}cG({max(m.q, RESOLVING_DEGREE)})"


def solve_flow(ode, method, tolerance, samples, number_of_samples, run, reason):
    """Solve ``ode`` with the flow-averaged model; ``run(declaration, method, tolerance=)``
    solves a declaration (counted in the stats by the caller), ``method`` the user's (the
    flows take :func:`resolving_method` of it). Returns the :class:`FlowSolution` with
    ``model`` set (its check is the caller's,
    :func:`~dolfinode.modeling.validity.check_validity`).

    Raises ValueError when no parameter sets the fast scale."""
    compiled = lower(ode)
    stiffness = stiffness_parameter(ode, compiled)
    if stiffness is None:
        names = ", ".join(s.name for s in ode.params) or "none"
        raise ValueError("subgrid_model='flow' slows the fast scale down by varying the "
                         "parameter that sets it, and no parameter of the ODE (" + names +
                         ") changes the largest |eigenvalue| of df/du(u0): declare the "
                         "stiffness (a large spring constant, a small mass or time constant) "
                         "as a parameter, or use subgrid_model='auto'")
    symbol, exponent = stiffness
    fastest = fast_time_scale(compiled, ode.u0, ode.t0)
    rho = 1.0 / fastest
    span = ode.T - ode.t0
    slow = max(slow_rate(compiled, ode.u0, ode.t0), 1.0 / span)
    fine = min(rho, FLOW_REFINEMENT * FLOW_SEPARATION * slow)
    rates, tolerances = [fine / FLOW_REFINEMENT, fine], [tolerance] * 2
    if fine == rho:  # the full model: the check is a tighter solve of it
        rates, tolerances = [rho, rho], [tolerance, FULL_TIGHTER * tolerance]
    value = float(ode.params[symbol])
    flows = [vary(ode, {symbol: value * (r / rho) ** (1.0 / exponent)}) for r in rates]
    # the output averages the finer flow, the check both: each over MINIMUM_PERIODS
    # radians of the fast scale at least, and SLOW_FRACTION of the slow one
    tau, tau_check = (max(MINIMUM_PERIODS / r, SLOW_FRACTION / slow) for r in rates[::-1])
    if not 4 * tau_check < span:
        raise ValueError(f"subgrid_model='flow': the flows' averages (average_length "
                         f"{tau_check:.3g}) do not fit in [t0, T] = [{ode.t0}, {ode.T}]: "
                         "the fast and slow scales are not separated enough for a model of "
                         "the slow one (a relaxation has no fast oscillation to carry: "
                         "subgrid_model='auto' puts it on its slow manifold); solve "
                         "without automatic_modeling")
    solutions = [run(vary(flow, {"T": ode.T + tau_check}), resolving_method(method),
                     tolerance=tol) for flow, tol in zip(flows, tolerances)]
    weights = kernel_weights(COMPARISON_SAMPLES)
    offsets = np.linspace(-1.0, 1.0, weights.size)
    times = np.linspace(ode.t0 + tau_check, ode.T, COMPARISON_TIMES)
    half = np.full(times.size, tau_check)
    coarse, fine = (average(s, times, half, weights, offsets) for s in solutions)
    J = lower(flows[1]).jacobian_matrix(ode.u0, ode.t0)
    outputs = component_frequencies(J) * tau < 2 * np.pi
    model = FlowModel(ode, stiffness, (rho, *rates), tau, solutions[1], solutions[0], times,
                      coarse - fine, outputs if outputs.any() else ~outputs, reason)
    sol = FlowSolution(ode, solutions[1], tau, samples, number_of_samples)
    sol.model = model
    return sol
