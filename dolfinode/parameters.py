"""Solver parameters with DOLFIN's names, their defaults, and did-you-mean validation."""
import difflib
import math
import numbers
import os
from types import MappingProxyType

import numpy as np
import sympy

#: Every parameter ``solve`` accepts, with its default.
DEFAULTS = {
    "tolerance": 1e-6,             # rtol of the step error estimate (DOLFIN: TOL)
    "absolute_tolerance": None,    # atol, scalar or per state; None: equal to tolerance
    "calibrate_tolerance": True,   # tolerance aims at the error at T; False: bounds each step
    "initial_time_step": None,     # None: chosen from f(u0)
    "maximum_time_step": None,     # None: T - t0
    "fixed_time_step": False,      # True: uniform steps of initial_time_step, no adaptivity
    "nonlinear_solver": "default",  # "default" | "fixed-point" | "newton"
    "discrete_tolerance_factor": 1e-3,  # nonlinear tolerance relative to the indicator's
    "maximum_iterations": 30,      # per nonlinear solve
    "safety_factor": 0.9,          # in (0, 1]
    "maximum_steps": 10_000_000,   # time slabs before giving up (SolverError)
    "number_of_samples": 101,      # output samples sol.t, sol.y
    "sample_times": None,          # explicit sample times in [t0, T] (solve_ivp's t_eval)
    "dense_output": True,          # True: history in memory; False: samples and the end only;
                                   # a path "run.h5": the history streamed to an HDF5 file
    "progress": False,             # tqdm progress bar
    "partitioning_threshold": 0.5,  # mcG/mdG: components with k >= theta max k share a sub-slab
    "interval_threshold": 0.9,     # mcG/mdG: a step >= beta times what is left is stretched to it
    "automatic_modeling": False,   # build a reduced model for unresolvable fast time scales
    "average_length": None,        # tau of the averages; None: from df/du(u0)'s scales
    "average_samples": 1000,       # samples per half averaging window
    "average_tolerance": 0.1,      # inactivate components whose average drifts less than this
    "control_points": 10,          # checks of the reduced model against the full model
    "model_tolerance": 0.02,       # rebuild when |g~ - g-bar| > model_tolerance (max |g-bar| + tol)
    "rebuild_model": True,         # False: build once, only measure the defect at control points
    "subgrid_model": "auto",       # "constant" | "affine" | "flow" | "auto": from the first window
    "strict": False,               # automatic modeling: raise instead of a ModelingWarning
    "events": None,                # g(u, t) expressions or dn.Event: zero crossings located
    "breakpoints": None,           # times where f(t) is not smooth that the declaration hides
    "estimate_global_error": "auto",  # the error at T after the solve, a warning above 10x:
                                      # True, False, or "auto" (long runs of small systems)
}

#: The defaults as users see them (``dn.default_parameters``): read-only, so that a change
#: cannot leak into every later solve.
READ_ONLY_DEFAULTS = MappingProxyType(DEFAULTS)

#: Names users bring from scipy's solve_ivp: dolfinode's parameter, or where the thing lives.
_FOREIGN_NAMES = {
    "atol": "absolute_tolerance",
    "rtol": "tolerance",
    "t_eval": "sample_times",
    "max_step": "maximum_time_step",
    "first_step": "initial_time_step",
    "y0": "u0 of the ODE (dn.ODE(..., u0=...))",
    "t_span": "t0 and T of the ODE (dn.ODE(..., T=..., t0=...))",
    "args": "params of the ODE (dn.ODE(..., params=...)) or dn.solve_ensemble",
    "jac": "nothing: the exact sparse Jacobian is derived from the declaration",
}

#: Values of the declaration, which dn.Solver.solve takes per call and dn.solve does not.
_DECLARATION_NAMES = ("u0", "params", "T", "t0")

NONLINEAR_SOLVERS = ("default", "fixed-point", "newton")
#: The subgrid models of automatic modeling (see :mod:`dolfinode.modeling.reduced`).
SUBGRID_MODELS = ("auto", "constant", "affine", "flow")


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


def _switch_or_auto(name, value):
    if isinstance(value, str) and value.lower() == "auto":
        return "auto"
    if not isinstance(value, (bool, int)):
        raise TypeError(f"{name} must be True, False or 'auto', got {value!r}")
    return bool(value)


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


def _events(name, value):
    """A sequence of events (a single one is accepted), as a list."""
    from dolfinode.events import Event

    if value is None:
        return None
    if isinstance(value, (Event, sympy.Basic)) or not np.iterable(value):
        value = [value]
    return [e if isinstance(e, Event) else Event(e) for e in value]


def _times(name, value):
    """None, or a sequence of finite real times as a float array."""
    if value is None:
        return None
    from dolfinode.ode import _reject_complex

    _reject_complex(np.asarray(value), name)
    try:
        times = np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a sequence of times, got {value!r}") from None
    if times.ndim != 1 or not np.all(np.isfinite(times)):
        raise ValueError(f"{name} must be a 1-D sequence of finite times, got {value!r}")
    return times


def _dense_output(name, value):
    """True, False, or the path of an HDF5 file (a str or os.PathLike) as a str."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (str, os.PathLike)) and os.fspath(value):
        path = os.fspath(value)
        if not path.endswith((".h5", ".hdf5")):
            raise ValueError(f"{name} as a path names an HDF5 file ending in .h5 or .hdf5, got "
                             f"{path!r}")
        return path
    raise TypeError(f"{name} must be True (history in memory), False (samples only) or the path "
                    f"of an HDF5 file such as 'run.h5', got {value!r}")


def _sample_times(name, value):
    """None, or increasing finite times as a read-only float array of their own (their range
    is checked by solve): the Solution's t, which the caller's array must not change later."""
    if (type(value) is np.ndarray and value.dtype == np.float64 and value.ndim == 1
            and value.size and math.isfinite(value[0]) and math.isfinite(value[-1])
            and (value[1:] > value[:-1]).all()):
        return _own(value)  # strictly increasing between finite ends: finite (no general checks)
    times = _times(name, value)
    if times is None:
        return None
    if times.size == 0:
        raise ValueError(f"{name} must be a non-empty sequence of times")
    if np.any(np.diff(times) <= 0):
        raise ValueError(f"{name} must be finite and strictly increasing, as solve_ivp's t_eval")
    return _own(times)


def _own(times):
    """A read-only copy of ``times``: shared by every solve of a Solver and its Solutions."""
    times = times.copy()
    times.flags.writeable = False
    return times


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
    "sample_times": _sample_times,
    "dense_output": _dense_output,
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
    "events": _events,
    "breakpoints": _times,
    "strict": _switch,
    "estimate_global_error": _switch_or_auto,
}


def _suggestion(name):
    """'; did you mean ...?' for an unknown parameter name: scipy's names first, then the
    closest of dolfinode's."""
    if name in _DECLARATION_NAMES:
        return (f": {name} is the declaration's: set ode.{name} (the next solve uses it), or "
                f"call dn.Solver(ode, method).solve({name}=...) for solves that vary it.")
    if name in _FOREIGN_NAMES:
        meant = _FOREIGN_NAMES[name]
        if " " in meant:
            return f" (scipy's name): in dolfinode that is {meant}."
        return f"; did you mean {meant!r}? ({name!r} is scipy's name)"
    close = difflib.get_close_matches(name, list(DEFAULTS), n=1, cutoff=0.4)
    return f"; did you mean {close[0]!r}?" if close else ""


def check_parameters(given):
    """Merge ``given`` into the defaults, each given value checked (and numbers made floats);
    unknown names raise with the closest valid name."""
    params = dict(DEFAULTS)
    for name, value in given.items():
        if name not in DEFAULTS:
            raise ValueError(f"unknown parameter {name!r}{_suggestion(name)} Valid parameters: "
                             f"{', '.join(sorted(DEFAULTS))}")
        check = _CHECKS.get(name)
        params[name] = value if check is None else check(name, value)
    if params["fixed_time_step"] and params["initial_time_step"] is None:
        raise ValueError("fixed_time_step=True needs the step: give initial_time_step=k")
    if params["automatic_modeling"] and params["fixed_time_step"]:
        raise ValueError("automatic_modeling needs adaptive time steps: the resolved windows "
                         "and the reduced model have time scales far apart; drop fixed_time_step")
    if params["automatic_modeling"] and params["dense_output"] is not True:
        raise ValueError("automatic_modeling joins the histories of its windows and checks the "
                         "reduced model on them: it needs dense_output=True")
    return params
