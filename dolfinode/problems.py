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
