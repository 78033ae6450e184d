"""Solver parameters with DOLFIN's names, their defaults, and did-you-mean validation."""
import difflib
import math

#: Every parameter ``solve`` accepts, with its default.
DEFAULTS = {
    "tolerance": 1e-6,             # rtol of the step error estimate (DOLFIN: TOL)
    "absolute_tolerance": None,    # atol, scalar or per state; None: equal to tolerance
    "initial_time_step": None,     # None: chosen from f(u0)
    "maximum_time_step": None,     # None: T - t0
    "fixed_time_step": False,      # True: uniform steps of initial_time_step, no adaptivity
    "nonlinear_solver": "default",  # "default" | "fixed-point" | "newton"
    "discrete_tolerance_factor": 1e-3,  # nonlinear tolerance relative to the indicator's
    "maximum_iterations": 30,      # per nonlinear solve
    "safety_factor": 0.9,
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
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def check_parameters(given):
    """Merge ``given`` into the defaults; unknown names raise with the closest valid name."""
    for name in given:
        if name not in DEFAULTS:
            close = difflib.get_close_matches(name, list(DEFAULTS), n=1,
                                              cutoff=0.4)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown parameter {name!r}{hint} Valid parameters: "
                             f"{', '.join(sorted(DEFAULTS))}")
    params = dict(DEFAULTS, **given)
    params["tolerance"] = _positive("tolerance", params["tolerance"], allow_none=False)
    if not isinstance(params["initial_time_step"], dict):  # per state: checked by solve
        params["initial_time_step"] = _positive("initial_time_step", params["initial_time_step"])
    for name in ("partitioning_threshold", "interval_threshold"):
        value = _positive(name, params[name], allow_none=False)
        if value > 1:
            raise ValueError(f"{name} must lie in (0, 1], got {value}")
        params[name] = value
    params["maximum_time_step"] = _positive("maximum_time_step", params["maximum_time_step"])
    params["discrete_tolerance_factor"] = _positive(
        "discrete_tolerance_factor", params["discrete_tolerance_factor"], allow_none=False)
    params["safety_factor"] = _positive("safety_factor", params["safety_factor"], allow_none=False)
    if isinstance(params["nonlinear_solver"], str):
        params["nonlinear_solver"] = params["nonlinear_solver"].lower()
    if params["nonlinear_solver"] not in NONLINEAR_SOLVERS:
        close = difflib.get_close_matches(str(params["nonlinear_solver"]), NONLINEAR_SOLVERS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown nonlinear_solver {params['nonlinear_solver']!r}{hint} "
                         f"Choose one of {NONLINEAR_SOLVERS}")
    for name in ("maximum_iterations", "number_of_samples", "maximum_steps"):
        value = params[name]
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    _check_modeling(params)
    if params["fixed_time_step"] and params["initial_time_step"] is None:
        raise ValueError("fixed_time_step=True needs the step: give initial_time_step=k")
    return params


def _check_modeling(params):
    """Validate the automatic-modeling parameters in place."""
    params["average_length"] = _positive("average_length", params["average_length"])
    for name in ("average_tolerance", "model_tolerance"):
        params[name] = _positive(name, params[name], allow_none=False)
    for name, low in (("average_samples", 2), ("control_points", 0)):
        value = params[name]
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    for name in ("automatic_modeling", "rebuild_model"):
        if not isinstance(params[name], (bool, int)):
            raise TypeError(f"{name} must be True or False, got {params[name]!r}")
    if params["subgrid_model"] not in SUBGRID_MODELS:
        close = difflib.get_close_matches(str(params["subgrid_model"]), SUBGRID_MODELS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown subgrid_model {params['subgrid_model']!r}{hint} Choose one "
                         f"of {SUBGRID_MODELS}")
    if params["automatic_modeling"] and params["fixed_time_step"]:
        raise ValueError("automatic_modeling needs adaptive time steps: the resolved windows "
                         "and the reduced model have time scales far apart; drop fixed_time_step")
