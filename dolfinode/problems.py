"""Reference problems declared with the public API, with their exact or published solutions.

Used by the demos, the benchmarks and the tests; each function returns an
:class:`~dolfinode.ODE` and, where one exists, a reference.
"""
import numpy as np
import sympy as sp

from dolfinode.ode import ODE


def harmonic(T=4 * np.pi):
    """u'' = -u as u' = v, v' = -u with u(0) = 0, v(0) = 1: exact u = sin t, v = cos t."""
    u, v = sp.symbols("u v")
    ode = ODE({u: v, v: -u}, u0={u: 0.0, v: 1.0}, T=T)
    return ode, lambda t: np.array([np.sin(t), np.cos(t)])


def lorenz(T=5.0, sigma=10.0, rho=28.0, beta=8.0 / 3.0):
    """Lorenz system, u0 = (1, 0, 0) as in DOLFIN's demo (no closed form)."""
    x, y, z, s, r, b = sp.symbols("x y z sigma rho beta")
    return ODE({x: s * (y - x), y: x * (r - z) - y, z: x * y - b * z},
               u0={x: 1.0, y: 0.0, z: 0.0}, T=T, params={s: sigma, r: rho, b: beta})


def stiff_decay(lam=1000.0, T=10.0):
    """Stiff test equation u' = -lam u, u(0) = 1 (DOLFIN stiff problem 1): exact exp(-lam t)."""
    u, a = sp.symbols("u lambda")
    ode = ODE({u: -a * u}, u0={u: 1.0}, T=T, params={a: lam})
    return ode, lambda t: np.array([np.exp(-lam * t)])


#: HIRES reference at T = 321.8122 (Test Set for IVP Solvers, hires.f; RADAU5 in quad precision).
HIRES_REFERENCE = np.array([
    0.7371312573325668e-3, 0.1442485726316185e-3, 0.5888729740967575e-4, 0.1175651343283149e-2,
    0.2386356198831331e-2, 0.6238968252742796e-2, 0.2849998395185769e-2, 0.2850001604814231e-2])


def hires(T=321.8122):
    """HIRES (High Irradiance RESponse, plant physiology), 8 stiff components."""
    y1, y2, y3, y4, y5, y6, y7, y8 = sp.symbols("y1:9")
    rhs = {
        y1: -1.71 * y1 + 0.43 * y2 + 8.32 * y3 + 0.0007,
        y2: 1.71 * y1 - 8.75 * y2,
        y3: -10.03 * y3 + 0.43 * y4 + 0.035 * y5,
        y4: 8.32 * y2 + 1.71 * y3 - 1.12 * y4,
        y5: -1.745 * y5 + 0.43 * y6 + 0.43 * y7,
        y6: -280 * y6 * y8 + 0.69 * y4 + 1.71 * y5 - 0.43 * y6 + 0.69 * y7,
        y7: 280 * y6 * y8 - 1.81 * y7,
        y8: -280 * y6 * y8 + 1.81 * y7,
    }
    return ODE(rhs, u0=[1.0, 0, 0, 0, 0, 0, 0, 0.0057], T=T)


def mescd(y, reference, atol_over_rtol=1.0):
    """Mixed-error significant correct digits of the Test Set:
    min_i -log10(|y_i - ref_i| / (atol/rtol + |ref_i|))."""
    err = np.abs(np.asarray(y) - reference) / (atol_over_rtol + np.abs(reference))
    return float(-np.log10(max(err.max(), 1e-300)))


def _linear(A, u0, T, b=None, name="u"):
    """u' = A u (+ b) declared symbolically, with the exact solution by the matrix exponential."""
    import scipy.linalg as sl

    A = np.asarray(A, dtype=float)
    n = len(A)
    u = sp.symbols(f"{name}0:{n}")
    b = np.zeros(n) if b is None else np.asarray(b, dtype=float)
    rhs = {u[i]: sum(A[i, j] * u[j] for j in range(n) if A[i, j]) + b[i] for i in range(n)}
    u0 = np.asarray(u0, dtype=float)
    shift = np.linalg.solve(A, b)  # u = e^{At}(u0 + A^{-1} b) - A^{-1} b

    def exact(t):
        return sl.expm(A * t) @ (u0 + shift) - shift

    return ODE(rhs, u0=u0, T=T), exact


def stiff_suite():
    """DOLFIN's stiff test problems (demo "stiff"; Logg, Multi-adaptive time integration, 2004),
    as (name, ode, exact or None). Problem 5 (Chemical Akzo Nobel, relaxed) is left out: its
    equations are not available here."""
    suite = []
    ode, exact = stiff_decay(1000.0, 10.0)
    suite.append(("1 decay", ode, exact))
    suite.append(("2 diagonal", *_linear(np.diag([-100.0, -1000.0]), [1.0, 1.0], 10.0)))
    suite.append(("3 non-normal", *_linear([[-1000.0, 10000.0], [0.0, -100.0]], [1.0, 1.0], 1.0)))
    suite.append(("3b critically damped", *_linear([[0.0, 1.0], [-1e4, -200.0]], [1.0, 1.0], 1.0)))
    suite.append(("4 HIRES", hires(), None))
    x, y = sp.symbols("x y")
    suite.append(("6 van der Pol", ODE({x: y, y: 10.0 * (1 - x**2) * y - x}, u0=[2.0, 0.0],
                                       T=100.0), None))
    n = 101
    h = 1.0 / (n + 1)
    L = (np.diag(-2.0 * np.ones(n)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1))
    source = np.zeros(n)
    source[n // 2] = 100.0
    suite.append(("7 heat", *_linear(L / h**2, np.zeros(n), 1.0, b=source)))
    y1, y2, y3 = sp.symbols("y1:4")
    suite.append(("8 Robertson", ODE({y1: -0.04 * y1 + 1e4 * y2 * y3,
                                      y2: 0.04 * y1 - 1e4 * y2 * y3 - 3e7 * y2**2,
                                      y3: 3e7 * y2**2}, u0=[1.0, 0.0, 0.0], T=0.3), None))
    u1, u2, u3 = sp.symbols("u1:4")
    suite.append(("9 mixed", ODE({u1: u2, u2: -(1 - u3) * u1, u3: -1000.0 * (u1**2 + u2**2) * u3},
                                 u0=[0.0, 1.0, 1.0], T=30.0), None))
    return suite
