"""A posteriori error estimate of a goal: the error representation with the dual weights.

With e = U - u, the dual phi of :mod:`dolfinode.dual.problem` and integration by parts over
every component's own elements I_in = (t_{i,n-1}, t_{i,n}] (Eriksson, Estep, Hansbo, Johnson;
the seed paper, "Error analysis"),

    M(U) - M(u) ~ (e(T), psi) + int (e, grad g) dt
               = sum_i sum_n [ int_{I_in} R_i(U, t) phi_i dt + [U_i]_{n-1} phi_i(t_{i,n-1}) ],

with the residual R_i = U_i' - f_i(U, t) and the jumps [U_i]_{n-1} = U_i(t_{n-1}^+) -
U_i(t_{n-1}^-) (zero for cG; U(t0^-) = u0). Galerkin orthogonality makes the same sum vanish
for test functions pi phi_i that are polynomials of degree q - 1 (cG) or q (dG) on each element;
pi is the L2 projection on the element. Hence the estimate and the bound

    value = sum_{i,n} eta_in,                 eta_in = int R_i phi_i + [U_i] phi_i,
    |value| <= sum_{i,n} ( int |R_i| |phi_i - pi phi_i| + |[U_i]| |(phi_i - pi phi_i)(t^+)| )
               + |sum_{i,n} ( int R_i pi phi_i + [U_i] pi phi_i(t^+) )|,

where the last term (the orthogonality defect) is zero up to the primal's quadrature and
nonlinear-solver tolerance. ``bound`` adds to this the difference between the values computed
with the dual of degree r and r - 1, which covers the dual's discretisation error; it does not
cover the error of linearising at U instead of the mean value over [U, u], which is of second
order in the error. Where that error is not small, the nonlinearity nu of the error equation
along U (:mod:`dolfinode.global_error`) exceeds NONLINEAR_GOAL and a ToleranceWarning says that
neither value nor bound can be trusted. The stability factors are S0 = int ||phi|| dt and
S1 = int ||phi'|| dt (Euclidean norm). All integrals use Gauss quadrature on the union grid, on
whose intervals every component of U and of phi is a polynomial.
"""
import warnings
from dataclasses import dataclass

import numpy as np

from dolfinode.compile import lower
from dolfinode.compile.jit import first_use, helper
from dolfinode.compile.signatures import rhs_kernel
from dolfinode.dual.goal import resolve
from dolfinode.dual.problem import (
    DualSolution,
    advance_forward,
    evaluate_primal,
    horner,
    horner_derivative,
    solve_dual,
)
from dolfinode.errors import ToleranceWarning
from dolfinode.solution import Solution


@dataclass
class ErrorEstimate:
    """The estimated error of a goal M and what it is made of.

    Attributes
    ----------
    value : float
        Estimate of M(U) - M(u) (for a linear final-time goal, (psi, U(T) - u(T))).
    bound : float
        Upper bound of ``|value|`` from ``|R| |phi - pi phi|`` (see the module docstring).
    contributions : ndarray (N,)
        Share of each component (state order) in ``value``: sum over its elements of eta_in.
    bound_contributions : ndarray (N,)
        Share of each component in ``bound`` (without the orthogonality defect).
    orthogonality_defect : float
        ``|sum (R, pi phi) + [U] pi phi|``: zero for an exact Galerkin solution.
    defect_contributions : ndarray (N,)
        Share of each component in the signed sum of ``orthogonality_defect``.
    dual_error : float
        ``|value - value with the dual of one degree lower|``: a (pessimistic) measure of the dual's
        discretisation error in ``value``.
    stability_factors : dict
        "S0" = int ||phi|| dt and "S1" = int ||phi'|| dt.
    dual : DualSolution
        phi, callable.
    states : tuple of the state symbols, in the order of ``contributions``
    nonlinearity : float or None
        nu of the error equation along U (:func:`dolfinode.global_error.estimate`), None
        where it is not computed (more than MAX_DENSE components without a narrow band).
        Above NONLINEAR_GOAL the linearisation at U, and so value and bound, are not reliable.
    """

    value: float
    bound: float
    contributions: np.ndarray
    bound_contributions: np.ndarray
    orthogonality_defect: float
    defect_contributions: np.ndarray
    dual_error: float
    stability_factors: dict
    dual: DualSolution
    states: tuple
    nonlinearity: float | None = None

    def contribution(self, state):
        """Share of one state (symbol or name) in ``value``."""
        names = [s.name for s in self.states]
        key = state if isinstance(state, str) else getattr(state, "name", None)
        if key not in names:
            raise ValueError(f"{state!r} is not a state; states are {', '.join(names)}")
        return float(self.contributions[names.index(key)])


@helper()
def _legendre(x, degree, out):
    """out[m] = P_m(x), m = 0..degree (three-term recurrence)."""
    out[0] = 1.0
    if degree >= 1:
        out[1] = x
    for m in range(1, degree):
        out[m + 1] = ((2 * m + 1) * x * out[m] - m * out[m - 1]) / (m + 1)


@helper()
def _weighted_residuals(rhs_address, p, grid, ptr, t_start, t_end, coef, phi, x, w, projection,
                        first_pass, phi_start, r_phi, phi_moments, r_moments, abs_weighted,
                        norms):
    """Gauss quadrature of the residual R = U' - f(U, t) against the dual, interval by interval.

    First pass: r_phi[e] = int R phi, phi_moments[e, m] = int phi P_m, r_moments[e, m] =
    int R P_m (P_m: Legendre on element e), phi_start[e] = phi at the element's start, and
    norms = (S0, S1). Second pass (with the projections pi phi known):
    abs_weighted[e] = int |R| |phi - pi phi|. The primal elements are tracked by one cursor
    per component (memory O(N)); f is the kernel at ``rhs_address``.
    """
    rhs = rhs_kernel(rhs_address)
    L, N = grid.shape[0] - 1, ptr.shape[0] - 1
    d = projection.shape[1] - 1
    u = np.empty(N)
    f = np.empty(N)
    P = np.empty(d + 1)
    current = ptr[:-1].copy()
    previous = current.copy()
    for l in range(L):
        h = grid[l + 1] - grid[l]
        for i in range(N):  # (not previous[:] = current: see io.history)
            previous[i] = current[i]
        advance_forward(ptr, t_end, grid[l], grid[l + 1], current)
        if first_pass:
            for i in range(N):
                e = current[i]
                if l == 0 or e != previous[i]:
                    phi_start[e] = horner(phi[l, :, i], (t_start[e] - grid[l]) / h)
        for g in range(x.shape[0]):
            t = grid[l] + x[g] * h
            wh = w[g] * h
            evaluate_primal(coef, t_start, t_end, current, t, u)
            rhs(u.ctypes, t, p.ctypes, f.ctypes)
            size0 = 0.0
            size1 = 0.0
            for i in range(N):
                e = current[i]
                k = t_end[e] - t_start[e]
                tau = (t - t_start[e]) / k
                residual = horner_derivative(coef[e], tau) / k - f[i]
                weight = horner(phi[l, :, i], x[g])
                _legendre(2.0 * tau - 1.0, d, P)
                if first_pass:
                    r_phi[e] += wh * residual * weight
                    for m in range(d + 1):
                        phi_moments[e, m] += wh * weight * P[m]
                        r_moments[e, m] += wh * residual * P[m]
                    size0 += weight * weight
                    slope = horner_derivative(phi[l, :, i], x[g]) / h
                    size1 += slope * slope
                else:
                    interpolant = 0.0
                    for m in range(d + 1):
                        interpolant += projection[e, m] * P[m]
                    abs_weighted[e] += wh * abs(residual) * abs(weight - interpolant)
            if first_pass:
                norms[0] += wh * np.sqrt(size0)
                norms[1] += wh * np.sqrt(size1)


def estimate_error(sol, goal, dual_degree=None, quadrature_points=None,
                   linear_solver="auto"):
    """A posteriori estimate of the error in a goal, from the dual problem, with a
    ToleranceWarning where its linearisation at U does not hold (nonlinearity above
    NONLINEAR_GOAL, ``nonlinearity`` of the result).

    Parameters
    ----------
    sol : Solution
        A mono- or multi-adaptive Galerkin solution from :func:`dolfinode.solve`.
    goal : dict, sequence, sympy expression, ("integral", psi) or Goal
        The output M(u): see :class:`dolfinode.Goal`. A dict by state symbol or name or a
        vector psi gives the final-time output (psi, u(T)).
    dual_degree : int, optional
        r >= 2 of the cG(r) dual scheme on the union grid; default max(q + 2, 2), so that the
        dual's discretisation error is small against phi - pi phi. A second dual of degree
        r - 1 measures that error (``dual_error``).
    quadrature_points : int, optional
        Gauss points per union-grid interval; default q + r + 2.
    linear_solver : {"auto", "banded", "sparse"}
        How the dual's stage systems are solved: the compiled banded LU, scipy's splu, or
        (default) splu when the Jacobian's band is wide (see
        :func:`dolfinode.linalg.wide_band`).

    Returns
    -------
    ErrorEstimate

    Warns
    -----
    ToleranceWarning
        Where the nonlinearity of the error equation along U exceeds NONLINEAR_GOAL: the
        linearised value and bound may then be far below the error. And where a goal given
        as an expression is far from linear over the error itself (:func:`_goal_curvature`):
        1 / u(T), log u(T) or int 1/u dt with an error of U above u.

    Raises
    ------
    TypeError, ValueError
        For a solution that is not a :class:`~dolfinode.Solution` or an invalid goal, a
        solution without history (``dense_output=False``), one of automatic modeling,
        and one that crossed a switch on the state (see :mod:`dolfinode.events`; jumps
        of f in t are accounted for: the elements end at them).
    SolverError
        If the dual's stage matrix is singular on an interval (h J with an eigenvalue that
        cG(r) cannot step over).
    """
    estimate = estimate_linearised(sol, goal, dual_degree, quadrature_points, linear_solver)
    estimate.nonlinearity = nu = _nonlinearity(sol)
    if nu is not None and nu > NONLINEAR_GOAL:
        warnings.warn(
            f"the error estimate linearises f at the solution, and along this one the error "
            f"equation is far from linear (nonlinearity {nu:.3g} > {NONLINEAR_GOAL:g}): the "
            f"error can be several times the estimate {estimate.value:.3g} and its bound. "
            "Solve at a tighter tolerance and estimate that solution", ToleranceWarning,
            stacklevel=2)
    why = _goal_curvature(sol, goal, estimate.value)
    if why:
        warnings.warn(why, ToleranceWarning, stacklevel=2)
    return estimate


def estimate_linearised(sol, goal, dual_degree=None, quadrature_points=None,
                        linear_solver="auto"):
    """:func:`estimate_error` without the check of its linearisation (``nonlinearity``
    None), for the drivers that estimate solution after solution (goal adaptivity, the
    modeling check)."""
    if not isinstance(sol, Solution):
        raise TypeError(f"estimate_error expects a dolfinode Solution, got {type(sol).__name__}")
    if not sol.dense:
        raise ValueError("estimate_error needs the history of the solution (the dual problem "
                         "is integrated against its elements), and this one kept only its "
                         "samples: solve with dense_output=True")
    if sol.model is not None:
        # the dual of the full model against the reduced solution reads the subgrid
        # model's defect as a residual, and bounds nothing
        raise ValueError("estimate_error cannot estimate the error of an automatic-modeling "
                         "solution: its residual in the full model is the subgrid model's "
                         "defect, not a discretisation error. Use sol.model.modeling_error() "
                         "for the error the reduced model adds, and solve without "
                         "automatic_modeling for an estimate of the discretisation error")
    if sol.stats.get("state switches"):
        raise ValueError(f"the solution crossed {sol.stats['state switches']} switches on the "
                         "state (Piecewise/Heaviside/sign/floor of a state in f): the "
                         "dual linearised at U misses the jump of the sensitivity where the "
                         "switching time moves with the solution, so the estimate could fall "
                         "below the error. Estimate on a smooth (regularised) model instead")
    ode, method = sol.ode, sol.method
    final, integral = resolve(goal, ode)
    q = method.q
    r = _positive_int(dual_degree, "dual_degree", max(q + 2, 2), minimum=2)
    gauss = _positive_int(quadrature_points, "quadrature_points", q + r + 2)
    # (a kernel called from Python: one called only from compiled code keeps no signatures,
    # and the notice's timer thread then started on every estimate)
    with first_use(_weighted_residuals, "the error estimate's kernels", 4):
        dual, primal = solve_dual(sol, final, integral, r, linear_solver=linear_solver)
        parts = _error_representation(sol, primal, dual, gauss)
        coarse, _ = solve_dual(sol, final, integral, r - 1, primal, linear_solver)
        coarse_value = _error_representation(sol, primal, coarse, gauss)["value"]
    dual_error = abs(parts["value"] - coarse_value)
    return ErrorEstimate(value=parts["value"],
                         bound=float(parts["bound_contributions"].sum() + parts["defect"]
                                     + dual_error),
                         contributions=parts["contributions"],
                         bound_contributions=parts["bound_contributions"],
                         orthogonality_defect=parts["defect"],
                         defect_contributions=parts["defect_contributions"],
                         dual_error=dual_error,
                         stability_factors=parts["stability_factors"], dual=dual,
                         states=ode.states)


#: estimate_error warns where the nonlinearity nu of the error equation exceeds
#: NONLINEAR_GOAL. Measured (goal U_i(T), cG(2), dG(2), mcG(2) at 1e-3 and 1e-6): estimate /
#: error 0.05-0.19 at nu = 30-64 (Lotka-Volterra from 0.05, Arenstorf's orbit), 0.6-8 at
#: nu <= 5 (pendulum, Lotka-Volterra dG(2), y' = y^2 near its blow-up), 0.98-1.03 at nu < 0.04.
NONLINEAR_GOAL = 10.0


#: The linearised change of a goal along the estimated error and its secant (G(U) - G(U - e),
#: for an integral goal int g(U) - g(U - e) dt) may differ by this fraction of the larger
#: before a warning.
GOAL_CURVATURE = 0.5
#: Runs of slabs at whose ends an integral goal's integrand is checked (:func:`_goal_curvature`).
CURVATURE_SAMPLES = 64


def _goal_curvature(sol, goal, value):
    """The warning where a goal expression is far from linear over the error itself.

    The estimate linearises G at U(T) and g at U(t): M(U) - M(u) ~ (grad G(U), e(T)) +
    int (grad g(U, t), e(t)) dt. With e the estimated error (:func:`dolfinode.global_error.along`:
    at T, and at the ends of CURVATURE_SAMPLES runs of slabs for an integral, trapezoidal
    there), that holds where the linearised change d and the secant s = G(U) - G(U - e)
    (+ int g(U) - g(U - e)) agree; the warning is given where
    |s - d| > GOAL_CURVATURE max(|s|, |d|) and |s - d| > rtol (1 + |M(U)|), or where s is not
    finite. Measured (u' = -u to T = 20, u(T) = 2.1e-9, cG(2) and mcG(2) at 1e-3 and 1e-6):
    1/u(T) was estimated at 0.005-0.46 x its error, log u(T) at 0.19-0.69 x, int 1/u dt at
    -4.5e28..0.5 x, unwarned. None for linear goals or where e is not computed
    (:func:`_nonlinearity`).
    """
    final, integral = resolve(goal, sol.ode)
    parts = [p for p in (final, integral) if p is not None and p.expression is not None]
    if not parts:
        return None
    from dolfinode import global_error  # (it imports dolfinode.dual)

    try:
        times, e = global_error.along(sol, CURVATURE_SAMPLES if integral in parts else 1)
    except ValueError:
        return None
    linear = secant = size = 0.0
    with np.errstate(all="ignore"):
        for part, at in ((final, times[-1:]), (integral, times)):
            if part not in parts:
                continue
            U = sol(at)
            E = e[:, -len(at):]
            lin = np.sum(part.at(U, at) * E, axis=0)
            sec = part.expression(list(U), at) - part.expression(list(U - E), at)
            own = part.expression(list(U), at) * np.ones(len(at))
            if part is integral:
                lin, sec, own = (np.trapezoid(v, at) for v in (lin, sec, own))
            linear += float(np.sum(lin))
            secant += float(np.sum(sec))
            size += float(np.sum(own))
    gap = abs(secant - linear)
    if np.isfinite(secant) and (gap <= GOAL_CURVATURE * max(abs(secant), abs(linear))
                                or gap <= sol.parameters["tolerance"] * (1.0 + abs(size))):
        return None
    return (f"the goal is far from linear over the error of this solution: along the "
            f"estimated error its change is {secant:.3g}, and {linear:.3g} linearised at U, "
            f"which the estimate {value:.3g} assumes. The error in the goal can be far from "
            f"the estimate; solve with a smaller absolute_tolerance (below the size of the "
            f"states the goal divides by or takes the logarithm of) and estimate that solution")


def _nonlinearity(sol):
    """nu along ``sol``: as its solve estimated it, else from
    :func:`dolfinode.global_error.estimate`; None where that is not computed."""
    nu = sol.stats.get("global error nonlinearity")
    if nu is not None:
        return float(nu)
    from dolfinode import global_error  # (it imports dolfinode.dual)

    try:
        return float(global_error.estimate(sol)[1])
    except ValueError:  # a large system without a narrow band, or too many common slabs
        return None


def _error_representation(sol, primal, dual, gauss):
    """The sums of the module docstring for one dual solution, per element and component."""
    x, w = np.polynomial.legendre.leggauss(gauss)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    d = sol.method.q - 1 if sol.method.family == "cG" else sol.method.q
    E = len(primal.t_start)
    phi_start, r_phi, abs_weighted = np.zeros(E), np.zeros(E), np.zeros(E)
    phi_moments, r_moments, projection = np.zeros((3, E, d + 1))
    norms = np.zeros(2)
    compiled = lower(sol.ode)

    def integrate(first_pass):
        _weighted_residuals(compiled.rhs.address, compiled.p, primal.grid, primal.ptr,
                            primal.t_start, primal.t_end, primal.coef, dual.coef, x, w,
                            projection, first_pass, phi_start, r_phi, phi_moments, r_moments,
                            abs_weighted, norms)

    integrate(True)
    degrees = np.arange(d + 1)
    projection[:] = (2 * degrees + 1) * phi_moments / (primal.t_end - primal.t_start)[:, None]
    integrate(False)
    jump = _jumps(primal, sol.ode.u0)
    pi_start = projection @ (-1.0) ** degrees  # P_m(-1) = (-1)^m
    eta = r_phi + jump * phi_start
    defects = np.sum(r_moments * projection, axis=1) + jump * pi_start
    local = abs_weighted + np.abs(jump) * np.abs(phi_start - pi_start)
    starts = primal.ptr[:-1]
    return {"value": float(eta.sum()), "contributions": np.add.reduceat(eta, starts),
            "bound_contributions": np.add.reduceat(local, starts),
            "defect": abs(float(defects.sum())),
            "defect_contributions": np.add.reduceat(defects, starts),
            "stability_factors": {"S0": float(norms[0]), "S1": float(norms[1])}}


def _jumps(primal, u0):
    """[U_i] at the start of every element: U(t^+) - U(t^-), with U(t0^-) = u0."""
    start = primal.coef[:, 0]
    end = primal.coef.sum(axis=1)
    before = np.empty_like(start)
    before[1:] = end[:-1]
    before[primal.ptr[:-1]] = u0
    return start - before


def _positive_int(value, name, default, minimum=1):
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)
