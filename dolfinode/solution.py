"""The Galerkin solution: exact piecewise polynomials, dense evaluation and samples."""
import numpy as np


class Solution:
    """Piecewise polynomial solution U of a Galerkin method on a partition of [t0, T].

    Element n covers [t_n, t_n + k_n]; its polynomial of degree q takes the values
    ``values[n, j]`` at the method's nodes t_n + tau_j k_n and is evaluated exactly with the
    method's Lagrange basis. At an element boundary the value of the element to the left is
    returned (for dG the left limit U(t_n^-)).

    Attributes
    ----------
    t, y : sample times (M,) and values (N, M), ``number_of_samples`` equispaced points
    stats : dict of counters and timings
    method : the :class:`~dolfinode.methods.Method`
    """

    def __init__(self, ode, method, t_start, k, values, stats, number_of_samples):
        self.ode = ode
        self.method = method
        self.t_start = t_start
        self.k = k
        self.values = values
        self.stats = stats
        self._t_end = t_start + k
        self.t = np.linspace(ode.t0, ode.T, number_of_samples)
        self.y = self(self.t)

    @property
    def states(self):
        return self.ode.states

    def __call__(self, t):
        """U(t): shape (N,) for a scalar t, (N, len(t)) for an array (scipy's convention)."""
        scalar = np.ndim(t) == 0
        times = np.atleast_1d(np.asarray(t, dtype=float))
        if times.size and (np.any(~np.isfinite(times)) or times.min() < self.ode.t0
                           or times.max() > self.ode.T):
            raise ValueError(f"the solution is defined on [{self.ode.t0}, {self.ode.T}], "
                             f"got t outside it")
        n = np.searchsorted(self._t_end, times, side="left")
        n = np.minimum(n, len(self.k) - 1)
        tau = np.clip((times - self.t_start[n]) / self.k[n], 0.0, 1.0)
        basis = self.method.basis(tau)                      # (M, q+1)
        out = np.einsum("mj,mjn->nm", basis, self.values[n])  # (N, M)
        return out[:, 0] if scalar else out

    def time_steps(self):
        """Element start times and lengths (t_n, k_n) of the shared partition."""
        return self.t_start.copy(), self.k.copy()

    def __repr__(self):
        return (f"Solution({self.method.name}, N={self.ode.N}, elements={len(self.k)}, "
                f"t=[{self.ode.t0}, {self.ode.T}])")
