"""dolfinode: variational (Galerkin) time integration of ODE systems declared in sympy.

The public surface is this package's namespace (``__all__``): declarations ``ODE``, ``t`` and
the structured systems ``Template``, ``TemplateODE``, ``ParticleSystem`` (``systems``);
``solve`` and ``Solver`` (many small solves), their ``Solution``, ``SolverError``,
``ModelingWarning`` and ``ToleranceWarning``; error estimates ``estimate_error``, ``Goal``,
``ErrorEstimate``; events ``Event``; stored solutions ``load_solution``; ensembles
``solve_ensemble``, ``vary``; the methods ``Method``, ``make_method``, ``parse_method``;
``default_parameters``. The documentation's API reference
has a page for each.
"""
# (source_stamp first: before any compiled function is declared)
from dolfinode import source_stamp, systems  # noqa: F401
from dolfinode.dual import ErrorEstimate, Goal, estimate_error
from dolfinode.ensemble import solve_ensemble, vary
from dolfinode.errors import ModelingWarning, SolverError, ToleranceWarning
from dolfinode.events import Event
from dolfinode.io.stored import load_solution
from dolfinode.methods import Method, make_method, parse_method
from dolfinode.ode import ODE, t
from dolfinode.parameters import READ_ONLY_DEFAULTS as default_parameters
from dolfinode.solution import Solution
from dolfinode.solve import solve
from dolfinode.solver import Solver
from dolfinode.systems import ParticleSystem, Template, TemplateODE

__version__ = "0.1.0"

__all__ = ["ODE", "ErrorEstimate", "Event", "Goal", "Method", "ModelingWarning", "ParticleSystem",
           "Solution", "Solver", "SolverError", "Template", "TemplateODE", "ToleranceWarning",
           "default_parameters",
           "estimate_error", "load_solution", "make_method", "parse_method", "solve",
           "solve_ensemble", "systems", "t", "vary"]
