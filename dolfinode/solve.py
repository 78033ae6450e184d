"""The driver: ``solve(ode, method, **parameters) -> Solution``."""
import time

import numpy as np

from dolfinode.compile import lower
from dolfinode.errors import SolverError
from dolfinode.methods import parse_method
from dolfinode.ode import ODE, _vector_by_state
from dolfinode.parameters import check_parameters
from dolfinode.solution import Solution
from dolfinode.timeslab import mono

#: Relative size (times |t|) below which a time step cannot be resolved in double precision.
_KMIN_RELATIVE = 1e-14


def _absolute_tolerance(ode, value, rtol):
    if value is None:
        return np.full(ode.N, rtol)
    if np.isscalar(value):
        atol = np.full(ode.N, float(value))
    else:
        atol = _vector_by_state(value, ode.states, "absolute_tolerance")
    if np.any(~(atol > 0)) or np.any(~np.isfinite(atol)):
        raise ValueError(f"absolute_tolerance must be positive and finite, got {value!r}")
    return atol


def _initial_step(f0, u0, atol, rtol, span):
    """k0 = 0.01 |u0| / |f(u0)| in the scaled norm (Hairer-Noersett-Wanner's first guess)."""
    scale = atol + rtol * np.abs(u0)
    d0 = np.max(np.abs(u0) / scale)
    d1 = np.max(np.abs(f0) / scale)
    k0 = 1e-6 * span if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    return min(k0, span)


def solve(ode, method="cG(1)", **parameters):
    """Solve the ODE with a Galerkin method.

    Parameters
    ----------
    ode : ODE
    method : str
        "cG(q)" (q >= 1) or "dG(q)" (q >= 0), one time step shared by all components.
    **parameters
        See :data:`dolfinode.parameters.DEFAULTS` (DOLFIN's names).

    Returns
    -------
    Solution

    Raises
    ------
    ValueError, TypeError
        For invalid parameters (with the closest valid name).
    SolverError
        When the solver cannot continue; the message names the time reached.
    """
    if not isinstance(ode, ODE):
        raise TypeError(f"solve expects a dolfinode.ODE, got {type(ode).__name__}")
    params = check_parameters(parameters)
    multi_adaptive, m = parse_method(method)
    if multi_adaptive:
        raise NotImplementedError(f"{method}: the multi-adaptive solver is not available yet; "
                                  f"use {m.name} (one time step for all components)")
    compiled = lower(ode)
    start = time.perf_counter()
    rtol = params["tolerance"]
    atol = _absolute_tolerance(ode, params["absolute_tolerance"], rtol)
    span = ode.T - ode.t0
    x = ode.u0.copy()
    f0 = compiled.f(x, ode.t0)
    if not np.all(np.isfinite(f0)):
        bad = ode.states[int(np.flatnonzero(~np.isfinite(f0))[0])]
        raise ValueError(f"f(u0, t0) is not finite in the right-hand side of {bad}: check u0 "
                         "and the parameters")
    kmax = params["maximum_time_step"] or span
    fixed = bool(params["fixed_time_step"])
    k0 = params["initial_time_step"] or _initial_step(f0, x, atol, rtol, span)
    _, position, kl, ku = compiled.ordering

    iopts = np.array([("default", "fixed-point", "newton").index(params["nonlinear_solver"]),
                      int(fixed), params["maximum_iterations"], int(m.family == "dG")],
                     dtype=np.int64)
    fopts = np.array([rtol, ode.T, kmax, params["safety_factor"],
                      params["discrete_tolerance_factor"], m.order, m.residual_power,
                      _KMIN_RELATIVE])
    if fixed:  # no error control: iterate to rounding level, relative to the solution size
        atol = np.ones(ode.N)
        fopts[mono.RTOL] = 1.0
        fopts[mono.DTOL] = 1e-15
    state = np.array([ode.t0, k0, 1.0, 1.0])
    counters = np.zeros(mono.NUM_COUNTERS, dtype=np.int64)
    tau = m.nodes[m.stages].copy()
    A = np.array(m.A)
    b0, dend, lval = m.b0.copy(), m.end_derivative.copy(), m.left_value.copy()
    nodes = m.q + 1
    capacity = int(max(64, min(20000, 2 ** 21 // (nodes * ode.N))))
    if params["progress"]:
        capacity = min(capacity, 500)
    chunks_t, chunks_k, chunks_X = [], [], []
    bar = _progress_bar(ode) if params["progress"] else None
    try:
        while True:
            size = min(capacity, params["maximum_steps"] - counters[mono.STEPS])
            out_t = np.empty(size)
            out_k = np.empty(size)
            out_X = np.empty((size, nodes, ode.N))
            status = mono.advance(compiled.rhs, compiled.jacobian, compiled.p, compiled.indptr,
                                  compiled.indices, position, kl, ku, A, b0, tau, dend, lval,
                                  iopts, fopts, atol, x, f0, state, counters, out_t, out_k, out_X)
            n = counters[mono.STORED]
            chunks_t.append(out_t[:n])
            chunks_k.append(out_k[:n])
            chunks_X.append(out_X[:n])
            if bar is not None:
                bar.update(state[mono.T_NOW] - bar.n)
            if status != mono.FULL:
                break
            if counters[mono.STEPS] >= params["maximum_steps"]:
                status = mono.STEP_LIMIT
                break
    finally:
        if bar is not None:
            bar.close()
    if status != mono.DONE:
        raise SolverError(_failure_message(status, state, fixed, x), t=float(state[mono.T_NOW]))
    solve_time = time.perf_counter() - start
    t_start = np.concatenate(chunks_t)
    k = np.concatenate(chunks_k)
    values = np.concatenate(chunks_X)
    stats = {
        "method": m.name,
        "time slabs": int(counters[mono.STEPS]),
        "elements": int(counters[mono.STEPS]) * ode.N,
        "rejected steps": int(counters[mono.REJECTED]),
        "f evaluations": int(counters[mono.F_EVALUATIONS]),
        "jacobian evaluations": int(counters[mono.JACOBIANS]),
        "factorizations": int(counters[mono.FACTORIZATIONS]),
        "nonlinear iterations": int(counters[mono.ITERATIONS]),
        "failed nonlinear solves": int(counters[mono.FAILED_SOLVES]),
        "newton": bool(counters[mono.STIFF]) or params["nonlinear_solver"] == "newton",
        "bandwidth": (kl, ku),
        "compile time": compiled.compile_time,
        "solve time": solve_time,
    }
    return Solution(ode, m, t_start, k, values, stats, params["number_of_samples"])


def _failure_message(status, state, fixed, x):
    t, k = state[mono.T_NOW], state[mono.K_NEXT]
    size = f"max |u| = {np.max(np.abs(x)):.3g} there"
    if status == mono.STEP_LIMIT:
        return (f"maximum_steps was reached at t = {t:.6g} ({size}); raise maximum_steps, loosen "
                "the tolerance, or use a higher-order method")
    if status == mono.NONCONVERGENCE:
        if fixed:
            return (f"the nonlinear solver did not converge at t = {t:.6g} with the fixed time "
                    f"step {k:.3g}; use a smaller initial_time_step or nonlinear_solver='newton'")
        return (f"the nonlinear solver did not converge at t = {t:.6g}, even after reducing the "
                f"time step to {k:.3g}; try nonlinear_solver='newton', a dG(q) method, or check "
                f"the right-hand side for a singularity near this time ({size})")
    if status == mono.BLOWUP:
        return (f"the solution is not finite or blows up near t = {t:.6g} (time step reduced to "
                f"{k:.3g}; {size}): the exact solution may have a finite-time singularity there")
    return (f"the time step fell to {k:.3g} at t = {t:.6g}, below what double precision "
            f"resolves ({size}): the solution may blow up near this time, or the tolerance is "
            "too tight for double precision")


def _progress_bar(ode):
    from tqdm.auto import tqdm

    return tqdm(total=ode.T - ode.t0, unit="t", desc="dolfinode",
                bar_format="{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}]")
