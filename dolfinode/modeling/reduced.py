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
    """

    ode: ODE
    average_length: float
    g: dict = field(default_factory=dict)
    inactive: tuple = ()
    built: list = field(default_factory=list)
    control_points: list = field(default_factory=list)

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

    def modeling_error(self, S0):
        """The modeling-error bound  S0 * max_[0,T] ||g~ - g-bar||_l2  of the paper's error
        estimate, with the stability factor S0 = int_0^T ||phi|| dt of the dual problem."""
        return float(S0) * self.largest_defect

    def __repr__(self):
        return (f"ReducedModel(tau={self.average_length:.3g}, inactive={len(self.inactive)}, "
                f"built={len(self.built)}x, control points={len(self.control_points)})")
