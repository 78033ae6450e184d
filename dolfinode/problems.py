"""Reference problems declared with the public API, with their exact or published solutions.

The small classics (harmonic oscillator, Lorenz, stiff decay, HIRES, linear systems) live in
:mod:`dolfinode.bench.problems` with the rest of the benchmark set and are re-exported here;
this module adds the problems of the error-estimate tests and benchmark.
"""
import numpy as np
import scipy.linalg as sl
import sympy as sp
from scipy.integrate import solve_ivp

from dolfinode.bench.problems import (  # noqa: F401
    HIRES_REFERENCE,
    harmonic,
    hires,
    linear,
    lorenz,
    mescd,
    stiff_decay,
    stiff_suite,
)
from dolfinode.ode import ODE

NON_NORMAL = np.array([[-1.0, 20.0], [0.0, -2.0]])


def random_stable(n=10, seed=1):
    """A random n x n matrix shifted to spectral abscissa -0.5, and a random initial value
    (both from ``numpy.random.default_rng(seed)``): u' = A u is non-normal and oscillatory."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(n, n))
    A = B - (np.abs(np.linalg.eigvals(B).real).max() + 0.5) * np.eye(n)
    return A, rng.normal(size=n)


def van_der_pol(T=10.0, mu=10.0):
    """x' = y, y' = mu (1 - x^2) y - x with x(0) = 2, y(0) = 0 (no closed form)."""
    x, y = sp.symbols("x y")
    return ODE({x: y, y: mu * (1 - x**2) * y - x}, u0=[2.0, 0.0], T=T)


def driven_oscillator(T=4.0):
    """a' = -a/2, and a stiff oscillator b' = c, c' = -400 b + a driven by a that does not act
    back: only a influences the goal a(T) (exactly e^{-T/2})."""
    a, b, c = sp.symbols("a b c")
    ode = ODE({a: -0.5 * a, b: c, c: -400 * b + a}, u0=[1.0, 1.0, 0.0], T=T)
    return ode, lambda t: np.array([np.exp(-0.5 * t)])


def reference_solution(ode, rtol=1e-13):
    """u(T) by scipy's DOP853 at ``rtol`` (atol rtol / 10) on the compiled right-hand side, for
    non-stiff problems without a closed form (for van der Pol with mu = 10 on [0, 10] it agrees
    with Radau at rtol 1e-13 to 1e-8, 50 times faster)."""
    from dolfinode.compile import lower

    compiled = lower(ode)
    sol = solve_ivp(lambda t, u: compiled.f(u, t), (ode.t0, ode.T), ode.u0, method="DOP853",
                    rtol=rtol, atol=0.1 * rtol)
    return sol.y[:, -1]


def estimate_suite():
    """The problems on which the dual error estimates are tested and benchmarked, as a dict
    name -> (ode, u(T)): exact by the matrix exponential for the linear ones (decay, harmonic,
    :data:`NON_NORMAL`, :func:`random_stable`), :func:`reference_solution` for Lorenz (T = 5)
    and :func:`van_der_pol`."""
    out = {}
    for name, (ode, exact) in [("decay", stiff_decay(lam=1.0, T=5.0)),
                               ("harmonic", harmonic(T=10.0)),
                               ("non-normal", linear(NON_NORMAL, [1.0, 1.0], 3.0)),
                               ("random 10", linear(*random_stable(10), 2.0))]:
        out[name] = (ode, exact(ode.T))
    for name, ode in [("lorenz", lorenz(T=5.0)), ("van der pol", van_der_pol())]:
        out[name] = (ode, reference_solution(ode))
    return out


def mass_spring_chain(masses=500, T=10.0, width=None):
    """A chain of unit masses joined by unit springs, fixed at both ends:

        x_i'' = x_{i-1} - 2 x_i + x_{i+1},   x_0 = x_{n+1} = 0,   i = 1..n,

    as 2n first-order equations with the states ordered x_1..x_n, v_1..v_n (so the Jacobian's
    natural bandwidth is n; a bandwidth ordering makes it 2). Starts at rest from a Gaussian
    displacement x_i(0) = exp(-((i - (n + 1)/2) / width)^2), width = n/20 by default (at
    least 2), which splits into two waves of speed one mass per unit time.

    Returns (ode, exact) with exact(t) = (x(t), v(t)) from the eigenvectors V and frequencies
    w of the stiffness matrix K: x(t) = V cos(w t) V^T x(0), v(t) = -V w sin(w t) V^T x(0).
    """
    n = int(masses)
    if n < 1:
        raise ValueError(f"masses must be a positive integer, got {masses!r}")
    width = max(n / 20, 2.0) if width is None else float(width)
    x = sp.symbols(f"x1:{n + 1}")
    v = sp.symbols(f"v1:{n + 1}")
    outside = sp.Integer(0)
    rhs = {x[i]: v[i] for i in range(n)}
    for i in range(n):
        left = x[i - 1] if i > 0 else outside
        right = x[i + 1] if i < n - 1 else outside
        rhs[v[i]] = left - 2 * x[i] + right
    x0 = np.exp(-(((np.arange(1, n + 1) - (n + 1) / 2) / width) ** 2))
    w2, V = sl.eigh_tridiagonal(2.0 * np.ones(n), -np.ones(n - 1))
    w = np.sqrt(w2)
    modes = V.T @ x0

    def exact(t):
        return np.concatenate([V @ (np.cos(w * t) * modes), -V @ (w * np.sin(w * t) * modes)])

    return ODE(rhs, u0=np.concatenate([x0, np.zeros(n)]), T=T), exact


def reaction_diffusion_front(N=1000, T=5.0, diffusion=1.0, rate=1.0, length=None):
    """Fisher-KPP front u_t = D u_xx + r u (1 - u) on [0, length] with zero-flux ends, by
    central differences on N points (spacing h = length / (N - 1)):

        u_i' = D (u_{i-1} - 2 u_i + u_{i+1}) / h^2 + r u_i (1 - u_i),   u_{-1} = u_1,
        u_N = u_{N-2},

    from u(x, 0) = 1 / (1 + e^{x - length/10}); the front moves right at speed about
    2 sqrt(D r). length = N / 10 by default (h about 0.1). No closed form.
    """
    N = int(N)
    if N < 3:
        raise ValueError(f"N must be an integer >= 3, got {N!r}")
    length = N / 10 if length is None else float(length)
    h = length / (N - 1)
    u = sp.symbols(f"u0:{N}")
    D, r = sp.symbols("D r")
    rhs = {}
    for i in range(N):
        left = u[i - 1] if i > 0 else u[1]
        right = u[i + 1] if i < N - 1 else u[N - 2]
        rhs[u[i]] = D * (left - 2 * u[i] + right) / h**2 + r * u[i] * (1 - u[i])
    x = np.linspace(0.0, length, N)
    return ODE(rhs, u0=1.0 / (1.0 + np.exp(x - length / 10)), T=T,
               params={D: diffusion, r: rate})
