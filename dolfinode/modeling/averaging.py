"""Smooth time averages of a resolved solution: u-bar, f-bar and the variance g-bar.

Jansson, Johnson & Logg, "Computational modeling of dynamical systems" (2005), section 3,
average with a box of length tau. A box average of a fast oscillation is accurate only to
O(1/(omega tau)) unless the box holds a whole number of periods (the original DOLFIN found
g~ = 0.2495 instead of 1/4), and any positive kernel shifts a slow component by its
curvature: u-bar(t) = u(t) + m_2 tau^2 u''(t) / 2 + ..., with m_2 the kernel's second
moment (the Hann kernel cos^2 has m_2 = 0.13: three digits of the seed model at
kappa = 1e4). Here the box is replaced by the fourth-order kernel

    K_tau(s) = (a + b s^2 / tau^2) cos^6(pi s / (2 tau)) / tau  on [-tau, tau],

with a, b such that its integral is 1 and its second moment 0: the average of a cubic is
its value at the centre (slow bias O(tau^4 u^(4))), and its Fourier transform decays like
(omega tau)^-7, so the average of cos(omega t) is below 1.3e-5 for omega tau >= 30 and
6e-8 for omega tau >= 60, for any phase. Its negative lobes (min K tau = -0.19) make it a
signed average.
"""
from dataclasses import dataclass
from functools import cache

import numpy as np

from dolfinode.compile.signatures import call_rhs_rows


@cache
def kernel_weights(samples):
    """Trapezoidal weights of the averaging kernel K_tau (module docstring) at
    ``2 samples + 1`` equispaced points s_j of [-1, 1]: w_j = (a + b s_j^2) cos^6(pi s_j / 2)
    with the discrete moments sum w_j = 1 and sum w_j s_j^2 = 0 (the kernel vanishes with
    five derivatives at both ends, so the trapezoidal rule is spectrally accurate for
    smooth integrands). Made once per ``samples`` (read-only): recomputed per window they
    were a noticeable part of a small modeling solve."""
    s = np.linspace(-1.0, 1.0, 2 * samples + 1)
    base = np.cos(0.5 * np.pi * s) ** 6
    m0, m2, m4 = (base @ s**k for k in (0, 2, 4))
    a, b = np.linalg.solve([[m0, m2], [m2, m4]], [1.0, 0.0])
    weights = (a + b * s**2) * base
    weights.setflags(write=False)
    return weights


#: Degree of the polynomial in time that stands for a slow component across a window when its
#: fast oscillation is measured: the least-squares residual of a smooth u over [-tau, tau]
#: is then O(tau^6 |u^(6)| / 6!), below the oscillation of any fast scale worth modeling.
TREND_DEGREE = 5


@cache
def trend_basis(samples):
    """Orthonormal columns (2 ``samples`` + 1, TREND_DEGREE + 1) spanning the polynomials of
    degree <= TREND_DEGREE at the equispaced averaging times of a window (the QR factor of
    their Legendre-Vandermonde matrix)."""
    s = np.linspace(-1.0, 1.0, 2 * samples + 1)
    basis = np.linalg.qr(np.polynomial.legendre.legvander(s, TREND_DEGREE))[0]
    basis.setflags(write=False)
    return basis


#: A component whose range over the window, max u - min u, is at most REST_ROUNDING x its size
#: is at rest there (its values differ by rounding): drift 0.
REST_ROUNDING = 64 * np.finfo(float).eps


@dataclass
class WindowAverages:
    """Averages of the full model over one resolved window [t_c - tau, t_c + tau].

    Attributes
    ----------
    center : t_c
    u_bar : average of u, centred at t_c (length tau)
    f_bar : average of f(u(t), t)
    g_bar : the variance  g-bar = f-bar - f(u-bar, t_c)
    drift : |u-bar(t_c + tau/2) - u-bar(t_c - tau/2)| / (max u - min u) per component: the
        change of the average relative to the oscillation (DOLFIN's activity test); 0 for a
        component at rest (max u - min u within rounding of |u|, REST_ROUNDING)
    fluctuation : u(t_c + tau) - u-bar(t_c): a point on the fast orbit, used as the
        perturbation that restarts the full model at control points
    halves : the averages of the two half windows, :class:`HalfWindow` about t_c -+ tau / 2
        (two more samples of the slow state and the force for the affine model's first fit)
    amplitude : sqrt(2) x the root mean square of u - p over the window's samples, p the
        least-squares polynomial of degree TREND_DEGREE in t: the amplitude of u's fast
        oscillation (of a sinusoid, exactly), by which u differs from u-bar pointwise
    """

    center: float
    u_bar: np.ndarray
    f_bar: np.ndarray
    g_bar: np.ndarray
    drift: np.ndarray
    fluctuation: np.ndarray
    halves: tuple = ()
    amplitude: np.ndarray = None


@dataclass
class HalfWindow:
    """u-bar and f-bar over a half window, centred at ``center`` (length tau / 2)."""

    center: float
    u_bar: np.ndarray
    f_bar: np.ndarray


def window_times(center, tau, samples, t0, T):
    """The times at which :func:`average_window` reads the solution: the ``2 samples + 1``
    points of [center - tau, center + tau] and the ``samples + 1`` (even ``samples``) points
    of each half window, clipped to [t0, T] (center +- tau may round outside the window)."""
    def sample(middle, half_width, n):
        times = middle + half_width * np.linspace(-1.0, 1.0, 2 * n + 1)
        return np.clip(times, t0, T)

    return (sample(center, tau, samples), sample(center - tau / 2, tau / 2, samples // 2),
            sample(center + tau / 2, tau / 2, samples // 2))


class WindowAverager:
    """The sums of :func:`average_window` accumulated from consecutive pieces of a resolved
    window, so that the window is never held: neither its elements nor its values at the
    2 ``samples`` + 1 averaging times (N of them per time).

    Parameters
    ----------
    compiled : :class:`~dolfinode.compile.lowering.CompiledODE` of the full model
    center, tau : float
    samples : int, points per half window (DOLFIN's ``average_samples``)
    t0, T : the window's ends (the :func:`window_times` are clipped to them)
    """

    def __init__(self, compiled, center, tau, samples, t0, T):
        self.compiled, self.center = compiled, center
        times, first_times, second_times = window_times(center, tau, samples, t0, T)
        half = kernel_weights(samples // 2)
        self.tau = tau
        # per set of times: the times, their weights, the rows of _sums (u, f), the first
        # time unread
        self._reads = [[times, kernel_weights(samples), (0, 1), 0],
                       [first_times, half, (2, 4), 0], [second_times, half, (3, 5), 0]]
        # u-bar, f-bar, the u-bar and f-bar of the two half windows; the range of u; u at
        # the end
        self._sums = np.zeros((6, compiled.N))
        self._max, self._min = np.full(compiled.N, -np.inf), np.full(compiled.N, np.inf)
        self._last = None
        # the window's values projected on trend_basis and their squares, shifted by the
        # first value (the squares then do not cancel the solution's size)
        self._trend = np.zeros((compiled.N, TREND_DEGREE + 1))
        self._basis = trend_basis(samples)
        self._squares = np.zeros(compiled.N)
        self._shift = None

    def record(self, piece):
        """Add the averaging times in a piece of the window (a solution on a sub-interval;
        pieces are recorded in time order)."""
        for read in self._reads:
            times, weights, (row, f_row), start = read
            end = np.searchsorted(times, piece.ode.T, side="right")
            if end == start:
                continue
            read[3] = end
            values = piece(times[start:end])
            self._sums[row] += values @ weights[start:end]
            states = np.ascontiguousarray(values.T)
            f_values = np.empty_like(states)
            call_rhs_rows(self.compiled.rhs.address, states,
                          np.ascontiguousarray(times[start:end]), self.compiled.p, f_values)
            self._sums[f_row] += weights[start:end] @ f_values
            if row == 0:
                np.maximum(self._max, values.max(axis=1), out=self._max)
                np.minimum(self._min, values.min(axis=1), out=self._min)
                self._last = values[:, -1].copy()
                if self._shift is None:
                    self._shift = values[:, 0].copy()
                shifted = values - self._shift[:, None]
                self._trend += shifted @ self._basis[start:end]
                self._squares += np.einsum("ij,ij->i", shifted, shifted)

    def averages(self):
        """The :class:`WindowAverages` once every piece is recorded."""
        u_bar, f_bar, first, second, f_first, f_second = self._sums
        spread = self._max - self._min
        # at rest (no spread above the rounding of its size): its average does not move
        rest = spread <= REST_ROUNDING * np.maximum(np.abs(self._max), np.abs(self._min))
        with np.errstate(divide="ignore", invalid="ignore"):
            drift = np.where(rest, 0.0, np.abs(second - first) / spread)
        halves = (HalfWindow(self.center - self.tau / 2, first, f_first),
                  HalfWindow(self.center + self.tau / 2, second, f_second))
        residual = np.maximum(self._squares - np.sum(self._trend**2, axis=1), 0.0)
        amplitude = np.sqrt(2 * residual / len(self._reads[0][0]))
        return WindowAverages(self.center, u_bar, f_bar,
                              f_bar - self.compiled.f(u_bar, self.center), drift,
                              self._last - u_bar, halves, amplitude)


def average_window(solution, compiled, center, tau, samples):
    """Averages of a solution resolved on [center - tau, center + tau].

    Parameters
    ----------
    solution : :class:`~dolfinode.solution.Solution` of the full model on the window
    compiled : :class:`~dolfinode.compile.lowering.CompiledODE` of the full model
    center, tau : float
    samples : int, points per half window (DOLFIN's ``average_samples``)

    Returns
    -------
    WindowAverages
    """
    averager = WindowAverager(compiled, center, tau, samples, solution.ode.t0, solution.ode.T)
    averager.record(solution)
    return averager.averages()
