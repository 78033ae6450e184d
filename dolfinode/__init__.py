"""dolfinode: variational (Galerkin) time integration of ODE systems declared in sympy.

Public surface (see shared/API.md): ``ODE``, ``t``, ``solve``, ``Solver`` (many small
solves), ``Solution``, ``SolverError``, ``estimate_error``, ``Goal``, ``ErrorEstimate``;
structured systems ``Template``, ``TemplateODE``, ``ParticleSystem`` (``dolfinode.systems``);
ensembles ``solve_ensemble``, ``vary``.
"""
from dolfinode import systems
from dolfinode.dual import ErrorEstimate, Goal, estimate_error
from dolfinode.ensemble import solve_ensemble, vary
from dolfinode.errors import SolverError
from dolfinode.methods import Method, make_method, parse_method
from dolfinode.ode import ODE, t
from dolfinode.parameters import DEFAULTS as default_parameters
from dolfinode.solution import Solution
from dolfinode.solve import solve
from dolfinode.solver import Solver
from dolfinode.systems import ParticleSystem, Template, TemplateODE

__version__ = "0.1.0"

__all__ = ["ODE", "ErrorEstimate", "Goal", "Method", "ParticleSystem", "Solution",
           "Solver", "SolverError", "Template", "TemplateODE", "default_parameters",
           "estimate_error", "make_method", "parse_method", "solve", "solve_ensemble", "systems",
           "t", "vary"]
