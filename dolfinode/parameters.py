"""Solver parameters with DOLFIN's names, their defaults, and did-you-mean validation."""
import difflib
import math
import numbers

import numpy as np

#: Every parameter ``solve`` accepts, with its default.
DEFAULTS = {
    "tolerance": 1e-6,             # rtol of the step error estimate (DOLFIN: TOL)
    "absolute_tolerance": None,    # atol, scalar or per state; None: equal to tolerance
    "calibrate_tolerance": False,  # True: tolerances aim at the error at T (solve's Notes)
    "initial_time_step": None,     # None: chosen from f(u0)
    "maximum_time_step": None,     # None: T - t0
    "fixed_time_step": False,      # True: uniform steps of initial_time_step, no adaptivity
    "nonlinear_solver": "default",  # "default" | "fixed-point" | "newton"
    "discrete_tolerance_factor": 1e-3,  # nonlinear tolerance relative to the indicator's
    "maximum_iterations": 30,      # per nonlinear solve
    "safety_factor": 0.9,          # in (0, 1]
    "maximum_steps": 10_000_000,   # time slabs before giving up (SolverError)
    "number_of_samples": 101,      # output samples sol.t, sol.y
    "progress": False,             # tqdm progress bar
    "partitioning_threshold": 0.5,  # mcG/mdG: components with k >= theta max k share a sub-slab
    "interval_threshold": 0.9,     # mcG/mdG: a step >= beta times what is left is stretched to it
    "automatic_modeling": False,   # build a reduced model for unresolvable fast time scales
    "average_length": None,        # tau of the averages; None: 100 / |lambda|_max of df/du(u0)
    "average_samples": 1000,       # samples per half averaging window
    "average_tolerance": 0.1,      # inactivate components whose average drifts less than this
    "control_points": 10,          # checks of the reduced model against the full model
    "model_tolerance": 0.02,       # rebuild when |g~ - g-bar| > model_tolerance max |g-bar|
    "rebuild_model": True,         # False: build once, only measure the defect at control points
    "subgrid_model": "auto",       # "constant" | "affine" in the slow state | "auto": affine after a rebuild
}

NONLINEAR_SOLVERS = ("default", "fixed-point", "newton")
#: The subgrid models of automatic modeling (see :mod:`dolfinode.modeling.reduced`).
SUBGRID_MODELS = ("auto", "constant", "affine")


def _positive(name, value, allow_none=True):
    if value is None and allow_none:
        return None
    try:
        if isinstance(value, bool):  # (True would be read as 1.0)
            raise TypeError
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def _required(name, value):
    return _positive(name, value, allow_none=False)


def _fraction(name, value):
    value = _required(name, value)
    if value > 1:
        raise ValueError(f"{name} must lie in (0, 1], got {value}")
    return value


def _integer_from(low):
    """Check for an integer >= low (Python's or numpy's; not a bool), returned as an int."""
    what = "a positive integer" if low == 1 else f"an integer >= {low}"

    def check(name, value):
        if (not isinstance(value, numbers.Integral) or isinstance(value, bool)
                or value < low):
            raise ValueError(f"{name} must be {what}, got {value!r}")
        return int(value)
    return check


_count = _integer_from(1)


def _switch(name, value):
    if not isinstance(value, (bool, int)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return value


def _choice(choices):
    def check(name, value):
        if isinstance(value, str):
            value = value.lower()
        if value not in choices:
            close = difflib.get_close_matches(str(value), choices, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown {name} {value!r}{hint} Choose one of {choices}")
        return value
    return check


def _per_state_or_positive(name, value):
    """A positive number, or values per state (a dict or a sequence: checked by solve)."""
    if isinstance(value, dict) or not (value is None or np.isscalar(value)):
        return value
    return _positive(name, value)


#: How each parameter is checked and normalised, ``check(name, value) -> value`` (the
#: defaults pass their checks, so only the given names are checked).
_CHECKS = {
    "tolerance": _required,
    "absolute_tolerance": _per_state_or_positive,
    "initial_time_step": _per_state_or_positive,
    "maximum_time_step": _positive,
    "fixed_time_step": _switch,
    "calibrate_tolerance": _switch,
    "nonlinear_solver": _choice(NONLINEAR_SOLVERS),
    "discrete_tolerance_factor": _required,
    "maximum_iterations": _count,
    "safety_factor": _fraction,
    "maximum_steps": _count,
    "number_of_samples": _count,
    "progress": _switch,
    "partitioning_threshold": _fraction,
    "interval_threshold": _fraction,
    "automatic_modeling": _switch,
    "average_length": _positive,
    "average_samples": _integer_from(2),
    "average_tolerance": _required,
    "control_points": _integer_from(0),
    "model_tolerance": _required,
    "rebuild_model": _switch,
    "subgrid_model": _choice(SUBGRID_MODELS),
}


def check_parameters(given):
    """Merge ``given`` into the defaults, each given value checked (and numbers made floats);
    unknown names raise with the closest valid name."""
    params = dict(DEFAULTS)
    for name, value in given.items():
        if name not in DEFAULTS:
            close = difflib.get_close_matches(name, list(DEFAULTS), n=1,
                                              cutoff=0.4)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown parameter {name!r}{hint} Valid parameters: "
                             f"{', '.join(sorted(DEFAULTS))}")
        check = _CHECKS.get(name)
        params[name] = value if check is None else check(name, value)
    if params["fixed_time_step"] and params["initial_time_step"] is None:
        raise ValueError("fixed_time_step=True needs the step: give initial_time_step=k")
    if params["automatic_modeling"] and params["fixed_time_step"]:
        raise ValueError("automatic_modeling needs adaptive time steps: the resolved windows "
                         "and the reduced model have time scales far apart; drop fixed_time_step")
    return params
