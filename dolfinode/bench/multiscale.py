"""Four classes of multiscale systems on which automatic modeling must be right or say it is not,
with a resolved reference averaged with the modeling kernel.

Each builder takes the scale separation ``kappa`` (the fast rate squared for oscillators, the
fast rate for relaxation) and returns ``(ode, slow)``: the ODE and the indices of its slow
components, the outputs that are scored.

1. :func:`adiabatic`: the seed model with a fast frequency depending on the slow state,
   x1'' = -x1 + x2^2 / 2, x2'' = -kappa (1 + x1) x2; the fast amplitude follows x1 through
   the adiabatic invariant E2 / omega, so the averaged force on x1 depends on x1.
2. :func:`fermi_pasta_ulam`: stiff springs of frequency sqrt(kappa) alternating with soft
   cubic ones (Hairer, Lubich & Wanner, Geometric Numerical Integration, I.5); energy moves
   among the stiff springs on the slow scale.
3. :func:`michaelis_menten`: s' = -s + (s + K - lam) c, eps c' = s - (s + K) c with
   eps = 1 / kappa: c relaxes to its slow manifold c = s / (s + K).
4. :func:`proportional`: y' = cos t - y x^2, x'' = -kappa x: the subgrid term -y (x^2 - x-bar^2)
   is proportional to the slow state.
"""
import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

from dolfinode.compile import lower
from dolfinode.ode import ODE, t


def adiabatic(kappa=1e4, T=50.0):
    x1, x2, k = sp.symbols("x1 x2 kappa")
    ode = ODE.second_order({x1: -x1 + x2**2 / 2, x2: -k * (1 + x1) * x2}, x0=[0.0, 1.0],
                           v0=[0.0, 0.0], T=T, params={k: kappa})
    return ode, [0]


def fermi_pasta_ulam(kappa=1e4, T=50.0, m=2):
    """H = sum p^2 / 2 + kappa / 4 sum_i (q_{2i} - q_{2i-1})^2 + sum_i (q_{2i+1} - q_{2i})^4,
    q_0 = q_{2m+1} = 0, from the book's initial values (q_1 = 1, p_1 = 1, q_2 = p_2 = 0, rest
    zero, with the first stiff spring stretched by 1 / sqrt(kappa))."""
    q = sp.symbols(f"q1:{2 * m + 1}")
    k = sp.Symbol("kappa")
    ext = (0, *q, 0)
    V = sum(k / 4 * (ext[2 * i] - ext[2 * i - 1])**2 for i in range(1, m + 1)) \
        + sum((ext[2 * i + 1] - ext[2 * i])**4 for i in range(m + 1))
    x0 = np.zeros(2 * m)
    x0[0], x0[1] = 1.0, 1.0 + 1.0 / np.sqrt(kappa)
    v0 = np.zeros(2 * m)
    v0[0] = 1.0
    ode = ODE.second_order({qi: -sp.diff(V, qi) for qi in q}, x0=x0, v0=v0, T=T,
                           params={k: kappa})
    return ode, list(range(2 * m))


def michaelis_menten(kappa=1e4, T=5.0, K=1.0, lam=0.5):
    s, c, k = sp.symbols("s c kappa")
    ode = ODE({s: -s + (s + K - lam) * c, c: k * (s - (s + K) * c)}, u0=[1.0, 0.0], T=T,
              params={k: kappa})
    return ode, [0]


def proportional(kappa=1e4, T=50.0):
    y, x, v, k = sp.symbols("y x v kappa")
    ode = ODE({y: sp.cos(t) - y * x**2, x: v, v: -k * x}, u0=[0.0, 1.0, 0.0],
              T=T, params={k: kappa})
    return ode, [0]


CLASSES = {"adiabatic": adiabatic, "fermi_pasta_ulam": fermi_pasta_ulam,
           "michaelis_menten": michaelis_menten, "proportional": proportional}


def kernel_grid(times, tau, samples=400):
    """(grid, average): the sorted times at which a solution is read for the kernel averages
    of half-length ``tau`` around each of ``times``, and the map from its values there,
    shape (N, len(grid)), to the averages, shape (N, len(times))."""
    from dolfinode.modeling.averaging import kernel_weights

    times = np.asarray(times, dtype=float)
    w = kernel_weights(samples)
    offsets = tau * np.linspace(-1.0, 1.0, w.size)
    grid, inverse = np.unique((times[:, None] + offsets).ravel(), return_inverse=True)

    def average(values):
        return values[:, inverse].reshape(len(values), times.size, w.size) @ w

    return grid, average


def averaged_reference(ode, times, tau, method="DOP853", rtol=1e-10, samples=400):
    """The full model resolved by scipy (``method``, ``rtol``, atol = rtol / 100), or by
    numbalsoda's compiled DOP853 for ``method="numbalsoda"``, and averaged with the modeling
    kernel of half-length ``tau`` around each of ``times``, all in [t0 + tau, T - tau].
    Returns an array (N, len(times))."""
    grid, average = kernel_grid(times, tau, samples)
    if method == "numbalsoda":
        from dolfinode.bench.peers import NumbalsodaDOP853

        peer = NumbalsodaDOP853(ode, np.concatenate([[ode.t0], grid]))  # from u0 at t0
        peer.max_steps = 10**9  # a resolved run at a large separation takes millions
        peer.build()
        return average(peer.solve(rtol, rtol / 100)[0][:, 1:])
    compiled = lower(ode)
    jac = (lambda t, u: compiled.jacobian_matrix(u, t)) if method in ("Radau", "BDF") else None
    sol = solve_ivp(lambda t, u: compiled.f(u, t), (ode.t0, grid[-1]), ode.u0,
                    method=method, rtol=rtol, atol=rtol / 100, t_eval=grid,
                    **({} if jac is None else {"jac": jac}))
    if sol.status != 0:
        raise RuntimeError(f"reference solve failed: {sol.message}")
    return average(sol.y)
