"""The reduced model f~ = f + g~ with inactivated fast components, and its record.

Jansson, Johnson & Logg (2005), sections 3-6: the reduced model

    u~' = f(u~, t) + g~(u~, t),   u~(t_c) = u-bar(t_c),

with a subgrid model g~ approximating the variance g-bar = avg f(u) - f(u-bar). Components
whose average does not change over the resolved window (the fast ones) are *inactivated*,
g~_i = -f_i: they keep the value of their average, which removes the leftover fast
oscillation of amplitude ~1/(sqrt(kappa) tau) that would otherwise force small steps in the
reduced system (the paper's section 5, "Solving the reduced system").
"""
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from dolfinode.ode import ODE

#: tau = AVERAGE_PERIODS / |lambda|_max when average_length is not given: about 16 periods of
#: the fastest oscillation in each half of the window, enough for the Hann average to reach
#: O((|lambda| tau)^-3) = 1e-6.
AVERAGE_PERIODS = 100.0


def fast_time_scale(compiled, u, t):
    """1 / |lambda|_max: the fastest time scale of the linearisation df/du at (u, t).

    The spectral radius is computed from the dense Jacobian for N <= 500 and with ARPACK
    (largest magnitude) otherwise.
    """
    J = compiled.jacobian_matrix(u, t)
    if J.shape[0] <= 500:
        radius = np.max(np.abs(np.linalg.eigvals(J.toarray())))
    else:
        from scipy.sparse.linalg import eigs

        radius = np.max(np.abs(eigs(J.astype(float), k=1, which="LM",
                                    return_eigenvectors=False)))
    return 1.0 / radius if radius > 0 else np.inf


def component_frequencies(compiled, u, t):
    """omega_i = sqrt(|(J^2)_ii|), J = df/du at (u, t): the time scale 1/omega_i on which
    component i moves by itself.

    For a second-order system x' = v, v' = a(x), J^2 = diag(da/dx, da/dx), so omega_i^2 is
    the stiffness over the mass acting on the coordinate (and on its velocity); for
    u' = -lambda u, omega = |lambda|. (J^2)_ii = sum_k J_ik J_ki.
    """
    J = compiled.jacobian_matrix(u, t)
    return np.sqrt(np.abs(np.asarray(J.multiply(J.T).sum(axis=1)).ravel()))


@dataclass
class ControlPoint:
    """A check of the reduced model against the full model resolved around ``time``.

    ``defect`` is the l2 norm over the active components of

        f(u-bar_A, U_I, t) + g~ - avg f(u)  =  g~ - g-bar,

    the reduced right-hand side at the window average (active components A) and the model's
    frozen values (inactive components I) against the average of the full one: the integrand
    of the modeling-error term of the error representation. ``relative_defect`` is its max
    norm over max |g-bar|.
    """

    time: float
    defect: float
    relative_defect: float
    rebuilt: bool
    elements: int


@dataclass
class ModelingError:
    """The modeling-error estimate of :meth:`ReducedModel.modeling_error`.

    Attributes
    ----------
    bound : S0 * largest_defect, the bound of the modeling error in the goal
    S0 : int ||phi||_l2 dt of the reduced model's dual problem
    largest_defect : max over the control points of ||g~ - g-bar||_l2
    discretization : the dual estimate of the reduced solution's own discretisation error in
        the goal (against the exact reduced solution u~)
    """

    bound: float
    S0: float
    largest_defect: float
    discretization: float


@dataclass
class ReducedModel:
    """The automatically built reduced model and its history (``sol.model``).

    Attributes
    ----------
    average_length : tau (given or chosen from the fast time scale)
    g : dict state -> subgrid model value g~ as last built (for an inactive state,
        g~_i = -f_i(u-bar), the paper's inactivation)
    inactive : tuple of the inactivated states
    built : times at which the model was built (the first is t0 + tau)
    control_points : list of :class:`ControlPoint`
    reduced : the reduced solution on (t_c, T] (a :class:`~dolfinode.Solution` of the
        reduced ODE; set by the solver)
    """

    ode: ODE
    average_length: float
    g: dict = field(default_factory=dict)
    inactive: tuple = ()
    built: list = field(default_factory=list)
    control_points: list = field(default_factory=list)
    reduced: object = None

    def __post_init__(self):
        taken = {s.name for s in self.ode.states} | {s.name for s in self.ode.params}
        self._symbols = []
        for s in self.ode.states:
            name = f"g_{s.name}"
            while name in taken:
                name += "_"
            self._symbols.append(sp.Symbol(name, real=True))
        self._g = np.zeros(self.ode.N)
        self._active = np.ones(self.ode.N, dtype=bool)
        self._frozen = np.zeros(self.ode.N)

    @property
    def active(self):
        """Boolean mask of the active components."""
        return self._active.copy()

    def build(self, averages, inactive_mask, time):
        """(Re)build from window averages: g~ = g-bar on active components, inactive ones
        frozen at their average."""
        self._active = ~inactive_mask
        self._g = np.where(self._active, averages.g_bar, 0.0)
        self._frozen = np.where(inactive_mask, averages.u_bar, 0.0)
        f_bar_state = averages.f_bar - averages.g_bar  # f(u-bar, t_c)
        self.g = {s: float(self._g[i] if self._active[i] else -f_bar_state[i])
                  for i, s in enumerate(self.ode.states)}
        self.inactive = tuple(s for s, a in zip(self.ode.states, self._active) if not a)
        self.built.append(float(time))

    def state(self, u):
        """u with its inactive components replaced by their frozen averages."""
        return np.where(self._active, u, self._frozen)

    def declaration(self, u0, t0, T):
        """The reduced ODE on [t0, T]: f_i + g~_i for active i, 0 for inactive i.

        g~ enters as parameters, so a rebuilt model reuses the compiled kernels.
        """
        rhs = {s: (expr + g if a else sp.S.Zero)
               for s, expr, g, a in zip(self.ode.states, self.ode.rhs, self._symbols,
                                        self._active)}
        params = dict(self.ode.params)
        params.update({g: float(v) for g, v in zip(self._symbols, self._g)})
        return ODE(rhs, u0=self.state(u0), T=T, t0=t0, params=params)

    def defect(self, compiled, averages):
        """g~ - g-bar on the active components (zero elsewhere), see :class:`ControlPoint`."""
        reduced_rhs = compiled.f(self.state(averages.u_bar), averages.center) + self._g
        return np.where(self._active, reduced_rhs - averages.f_bar, 0.0)

    @property
    def largest_defect(self):
        """max over the control points of ||g~ - g-bar||_l2 (0 without control points)."""
        return max((c.defect for c in self.control_points), default=0.0)

    def modeling_error(self, goal=None):
        """The modeling-error bound of the paper's error estimate for a goal.

        The error of the reduced solution U in the average u-bar, measured by a goal M, has
        the modeling term  int (phi, g~ - g-bar) dt, hence (the seed paper, "Error analysis")

            |M(U) - M(u-bar)| <= S1 max ||k R~(U)||  +  S0 max_[t_c, T] ||g~ - g-bar||_l2,

        with S0 = int_{t_c}^T ||phi||_l2 dt of the dual problem of the reduced model,
        -phi' = (df~/du)^T phi, linearised at U (its discretisation part is
        ``discretization``, from :func:`dolfinode.estimate_error`, with the residual taken
        against the model as last built). max ||g~ - g-bar|| is the largest defect found at
        the control points.

        Parameters
        ----------
        goal : any goal form of :func:`dolfinode.estimate_error`, optional
            Default: the final-time output (psi, u(T)) with psi_i = 1 on every active
            component (inactive components are frozen averages, not outputs of the model).

        Returns
        -------
        ModelingError
        """
        if self.reduced is None:
            raise ValueError("the reduced model has not been solved yet: modeling_error is "
                             "available on sol.model after dn.solve(..., "
                             "automatic_modeling=True)")
        if not self.control_points:
            raise ValueError("no control points: max |g~ - g-bar| is unknown; solve with "
                             "control_points >= 1")
        from dolfinode.dual import estimate_error

        estimate = estimate_error(self.reduced,
                                  self._active.astype(float) if goal is None else goal)
        S0 = estimate.stability_factors["S0"]
        return ModelingError(bound=S0 * self.largest_defect, S0=S0,
                             largest_defect=self.largest_defect,
                             discretization=estimate.value)

    def __repr__(self):
        return (f"ReducedModel(tau={self.average_length:.3g}, inactive={len(self.inactive)}, "
                f"built={len(self.built)}x, control points={len(self.control_points)})")
