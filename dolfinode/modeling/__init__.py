"""Automatic modeling: reduced models of systems with unresolvable fast time scales."""
from dolfinode.modeling.averaging import WindowAverages, average_window, kernel_weights
from dolfinode.modeling.driver import MODELING_PARAMETERS, ModelingSolution, solve_with_modeling
from dolfinode.modeling.reduced import ControlPoint, ReducedModel, fast_time_scale
from dolfinode.modeling.validity import ModelingError

__all__ = [
           "MODELING_PARAMETERS",
           "ControlPoint",
           "ModelingError",
           "ModelingSolution",
           "ReducedModel",
           "WindowAverages",
           "average_window",
           "fast_time_scale",
           "kernel_weights",
           "solve_with_modeling",
]
