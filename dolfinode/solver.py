"""A prepared solver for many small solves of one declaration (parameter fits, sweeps).

``Solver(ode, method, **parameters)`` checks the method and the parameters and lowers the
ODE once; ``solver.solve(u0=, params=, T=, t0=)`` then solves with those values replaced,
exactly as :func:`dolfinode.solve` solves :func:`dolfinode.vary` (ode, values): the same
steps and values, bit for bit. The parameter values reach the compiled kernels as the
vector ``p`` of each call, never through the declaration the solver was made from.
"""
import numpy as np

from dolfinode.ensemble import vary
from dolfinode.methods import parse_method
from dolfinode.ode import ODE
from dolfinode.parameters import check_parameters
from dolfinode.solve import check_tolerance, lowered, solve, solve_lowered


class Solver:
    """Solve one ODE declaration many times with other initial values, parameters or times.

    Parameters
    ----------
    ode : ODE or TemplateODE
    method : str
        As for :func:`dolfinode.solve` ("cG(q)", "dG(q)", "mcG(q)", "mdG(q)").
    **parameters
        As for :func:`dolfinode.solve` (DOLFIN's names); checked here, once.

    Raises
    ------
    TypeError, ValueError
        For an invalid ODE, method or parameter (with the closest valid name).

    Examples
    --------
    >>> solver = dn.Solver(ode, method="dG(2)", tolerance=1e-8)      # doctest: +SKIP
    >>> sol = solver.solve(u0=[0.5, 0.0], params={k: 9.0})          # doctest: +SKIP
    """

    def __init__(self, ode, method="cG(1)", **parameters):
        if not isinstance(ode, ODE):
            raise TypeError(f"Solver expects a dolfinode.ODE, got {type(ode).__name__}")
        if "goal" in parameters:
            raise ValueError("Solver solves without a goal: for goal-oriented adaptivity "
                             "call dn.solve(ode, goal=...)")
        self._multi_adaptive, self._method = parse_method(method)
        self._params = check_parameters(parameters)
        check_tolerance(self._params)
        self.ode = ode
        self.method = method
        self.parameters = dict(parameters)
        lowered(ode, self._params)  # compiled now, kept on the declaration for every call

    def solve(self, u0=None, params=None, T=None, t0=None):
        """Solve with the given initial values, parameter values and interval (each defaults
        to the declaration's); returns a :class:`~dolfinode.Solution` as
        :func:`dolfinode.solve` does, whose ``sol.ode`` carries the values used.

        Parameters
        ----------
        u0 : dict or sequence, optional
            Initial values by state symbol, or in component order.
        params : dict, optional
            Parameter symbols (or names) -> values; the others keep the declaration's.
        T, t0 : float, optional

        Raises
        ------
        TypeError, ValueError
            For values the declaration would reject.
        SolverError
            As :func:`dolfinode.solve`.
        """
        variation = {} if params is None else dict(params)
        if isinstance(u0, (list, tuple)) and all(isinstance(x, (int, float)) for x in u0):
            u0 = np.array(u0, dtype=float)  # checked as an array: 4x faster than as a list
        for name, value in (("u0", u0), ("T", T), ("t0", t0)):
            if value is not None:
                variation[name] = value
        ode = vary(self.ode, variation)
        if self._params["automatic_modeling"]:  # a driver over many solves
            return solve(ode, self.method, **self.parameters)
        # the kernels' p is made from the varied declaration's values (CompiledODE.again)
        compiled, plan = lowered(ode, self._params)
        return solve_lowered(ode, compiled, plan, self._multi_adaptive, self._method,
                             self._params)
