"""The benchmark problem set, declared with the public API.

Every builder returns a :class:`Problem`: the :class:`~dolfinode.ODE` and what it is scored
against, either a closed-form solution or a published reference value at the final time
(Test Set for IVP Solvers, F. Mazzia, C. Magherini et al., University of Bari; the values are
copied digit for digit from its ``solut`` routines). The declarations double as examples of how
to write systems for dolfinode: one sympy expression per component, parameters as symbols.

MEDAKZO's declaration and its 400 reference values are in :mod:`dolfinode.bench.medakzo`.

The functions :func:`harmonic`, :func:`lorenz`, :func:`stiff_decay`, :func:`hires` and
:func:`stiff_suite` return plain ``ODE`` objects (and exact solutions) as they always did; they
are re-exported by :mod:`dolfinode.problems` for the demos and tests.
"""
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import sympy as sp

from dolfinode.ode import ODE


@dataclass
class Problem:
    """A benchmark problem: an ODE and its reference.

    Attributes
    ----------
    name : str
        Short name used on the command line and in the tables (``"HIRES"``).
    ode : ODE
    stiff : bool
        Whether the problem is stiff (explicit methods are not expected to finish).
    final : ndarray, shape (N,), or None
        Reference solution at T (exact, or published with ~15 correct digits); None when
        there is none, in which case the runner takes the last point of its reference
        trajectory.
    exact : callable or None
        Closed-form solution t -> (N,) or (N, M); None when only ``final`` is known, in which
        case the runner computes a reference trajectory with a tight scipy solve.
    atol_ratio : float
        absolute_tolerance / tolerance used for every solver, and atol/rtol in mescd.
    reference : str
        Where ``final`` comes from.
    description : str
        One line: the equation or its source.
    multiscale : bool
        Whether the problem has widely separated time scales in different components (the
        issue's "multiscale problems", where the target is orders of magnitude).
    modeling : dict or None
        Solver parameters of automatic modeling (``average_length``, ...) for the method
        variants ``"<method>+modeling"``; None: those variants are not run on the problem.
    scored : tuple of int or None
        Indices of the components the scores (mescd, errors) are taken over; None: all.
    """

    name: str
    ode: ODE
    stiff: bool
    final: np.ndarray
    exact: Callable | None = None
    atol_ratio: float = 1.0
    reference: str = ""
    description: str = ""
    multiscale: bool = False
    modeling: dict | None = None
    scored: tuple | None = None

    @property
    def T(self):
        return self.ode.T


def mescd(y, reference, atol_over_rtol=1.0):
    """Mixed-error significant correct digits (Test Set for IVP Solvers):

        mescd = min_i -log10(|y_i - ref_i| / (atol/rtol + |ref_i|)).

    Parameters
    ----------
    y, reference : array_like, shape (N,)
    atol_over_rtol : float
        The ratio of absolute to relative tolerance used for the run.

    Returns
    -------
    float
        Capped at 300 digits for an exact match.
    """
    y, reference = np.asarray(y, dtype=float), np.asarray(reference, dtype=float)
    if y.shape != reference.shape:
        raise ValueError(f"mescd: shapes {y.shape} and {reference.shape} differ")
    err = np.abs(y - reference) / (atol_over_rtol + np.abs(reference))
    if not np.all(np.isfinite(err)):
        return -np.inf
    return float(-np.log10(max(err.max(), 1e-300)))


# ---------------------------------------------------------------------------------------------
# Small problems with closed-form solutions (also used by the demos and tests)
# ---------------------------------------------------------------------------------------------

def harmonic(T=4 * np.pi):
    """u'' = -u as u' = v, v' = -u with u(0) = 0, v(0) = 1: exact u = sin t, v = cos t."""
    u, v = sp.symbols("u v")
    ode = ODE({u: v, v: -u}, u0={u: 0.0, v: 1.0}, T=T)
    return ode, lambda s: np.array([np.sin(s), np.cos(s)])


def lorenz(T=5.0, sigma=10.0, rho=28.0, beta=8.0 / 3.0):
    """Lorenz system, u0 = (1, 0, 0) as in DOLFIN's demo (no closed form)."""
    x, y, z, s, r, b = sp.symbols("x y z sigma rho beta")
    return ODE({x: s * (y - x), y: x * (r - z) - y, z: x * y - b * z},
               u0={x: 1.0, y: 0.0, z: 0.0}, T=T, params={s: sigma, r: rho, b: beta})


def stiff_decay(lam=1000.0, T=10.0):
    """Stiff test equation u' = -lam u, u(0) = 1 (DOLFIN stiff problem 1): exact exp(-lam t)."""
    u, a = sp.symbols("u lambda")
    ode = ODE({u: -a * u}, u0={u: 1.0}, T=T, params={a: lam})
    return ode, lambda s: np.array([np.exp(-lam * np.asarray(s))])


def linear(A, u0, T, b=None, name="u"):
    """u' = A u + b declared symbolically, with the exact solution by the matrix exponential:
    u(t) = e^{At} (u0 + A^{-1} b) - A^{-1} b."""
    import scipy.linalg as sl

    A = np.asarray(A, dtype=float)
    n = len(A)
    u = sp.symbols(f"{name}0:{n}")
    b = np.zeros(n) if b is None else np.asarray(b, dtype=float)
    rhs = {u[i]: sum(A[i, j] * u[j] for j in range(n) if A[i, j]) + b[i] for i in range(n)}
    u0 = np.asarray(u0, dtype=float)
    shift = np.linalg.solve(A, b)

    def exact(s):
        if np.ndim(s) == 0:
            return sl.expm(A * s) @ (u0 + shift) - shift
        return np.column_stack([exact(float(si)) for si in s])

    return ODE(rhs, u0=u0, T=T), exact


#: HIRES reference at T = 321.8122 (Test Set, hires.f; RADAU5 in quad precision).
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


def stiff_suite():
    """DOLFIN's stiff test problems (demo "stiff"; Logg, Multi-adaptive time integration, 2004),
    as (name, ode, exact or None). Problem 5 (Chemical Akzo Nobel, relaxed) is left out: its
    equations are not available here."""
    suite = []
    ode, exact = stiff_decay(1000.0, 10.0)
    suite.append(("1 decay", ode, exact))
    suite.append(("2 diagonal", *linear(np.diag([-100.0, -1000.0]), [1.0, 1.0], 10.0)))
    suite.append(("3 non-normal", *linear([[-1000.0, 10000.0], [0.0, -100.0]], [1.0, 1.0], 1.0)))
    suite.append(("3b critically damped", *linear([[0.0, 1.0], [-1e4, -200.0]], [1.0, 1.0], 1.0)))
    suite.append(("4 HIRES", hires(), None))
    x, y = sp.symbols("x y")
    suite.append(("6 van der Pol", ODE({x: y, y: 10.0 * (1 - x**2) * y - x}, u0=[2.0, 0.0],
                                       T=100.0), None))
    n = 101
    h = 1.0 / (n + 1)
    L = (np.diag(-2.0 * np.ones(n)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1))
    source = np.zeros(n)
    source[n // 2] = 100.0
    suite.append(("7 heat", *linear(L / h**2, np.zeros(n), 1.0, b=source)))
    suite.append(("8 Robertson", rober(T=0.3).ode, None))
    u1, u2, u3 = sp.symbols("u1:4")
    suite.append(("9 mixed", ODE({u1: u2, u2: -(1 - u3) * u1, u3: -1000.0 * (u1**2 + u2**2) * u3},
                                 u0=[0.0, 1.0, 1.0], T=30.0), None))
    return suite


# ---------------------------------------------------------------------------------------------
# The benchmark set
# ---------------------------------------------------------------------------------------------

TEST_SET = "Test Set for IVP Solvers (Mazzia, Magherini et al.)"


def hires_problem(T=321.8122):
    """HIRES with the Test Set reference at T = 321.8122."""
    if T != 321.8122:
        raise ValueError("the HIRES reference is published for T = 321.8122 only")
    return Problem("HIRES", hires(T), stiff=True, final=HIRES_REFERENCE.copy(),
                   reference=f"{TEST_SET}, hires.f (RADAU5, quad precision)",
                   description="plant physiology, 8 components, Test Set hires.f")


ROBER_REFERENCE = np.array([0.2083340149701255e-7, 0.8333360770334713e-13, 0.9999999791665050])


def rober(T=1e11, nonnegative=False):
    """ROBER (Robertson's chemical kinetics) on [0, 1e11]:

        y1' = -0.04 y1 + 1e4 y2 y3,  y2' = 0.04 y1 - 1e4 y2 y3 - 3e7 y2^2,  y3' = 3e7 y2^2.

    y2 ~ 1e-13 at T, so the absolute tolerance is 1e-4 times the relative one (the Test Set's
    atol = 1e-14 at rtol = 1e-10). y1 + y2 + y3 = 1 is conserved. ``nonnegative=True``
    declares the concentrations nonnegative (the suite runs without: scipy has no such
    constraint)."""
    y1, y2, y3, k1, k2, k3 = sp.symbols("y1 y2 y3 k1 k2 k3")
    ode = ODE({y1: -k1 * y1 + k3 * y2 * y3,
               y2: k1 * y1 - k3 * y2 * y3 - k2 * y2**2,
               y3: k2 * y2**2},
              u0=[1.0, 0.0, 0.0], T=T, params={k1: 0.04, k2: 3e7, k3: 1e4},
              nonnegative=nonnegative)
    final = ROBER_REFERENCE.copy() if T == 1e11 else None
    return Problem("ROBER", ode, stiff=True, final=final, atol_ratio=1e-4,
                   reference=f"{TEST_SET}, rober.f (RADAU, extended precision)",
                   description="Robertson kinetics to t = 1e11, Test Set rober.f")


def vdpol(eps=1e-6):
    """VDPOL (van der Pol in the Test Set's scaling): y1' = y2, y2' = ((1 - y1^2) y2 - y1)/eps,
    y(0) = (2, 0), T = 2, eps = 1e-6."""
    if eps != 1e-6:
        raise ValueError("the VDPOL reference is published for eps = 1e-6 only")
    y1, y2, e = sp.symbols("y1 y2 epsilon")
    ode = ODE({y1: y2, y2: ((1 - y1**2) * y2 - y1) / e}, u0=[2.0, 0.0], T=2.0,
              params={e: eps})
    return Problem("VDPOL", ode, stiff=True,
                   final=np.array([0.1706167732170483e1, -0.8928097010247975e0]),
                   reference=f"{TEST_SET}, vdpol.f (RADAU, extended precision)",
                   description="van der Pol, eps = 1e-6 (Test Set scaling), T = 2")


def vdpolm():
    """VDPOLM (van der Pol, unscaled, mu = 1000): y1' = y2, y2' = mu (1 - y1^2) y2 - y1,
    y(0) = (2, 0), T = 2000."""
    y1, y2, mu = sp.symbols("y1 y2 mu")
    ode = ODE({y1: y2, y2: mu * (1 - y1**2) * y2 - y1}, u0=[2.0, 0.0], T=2000.0,
              params={mu: 1000.0})
    return Problem("VDPOLM", ode, stiff=True,
                   final=np.array([0.1706167732170469e1, -0.8928097010248125e-3]),
                   reference=f"{TEST_SET}, vdpolm.f (RADAU, extended precision)",
                   description="van der Pol, mu = 1000, T = 2000")


POLLU_RATES = (.35, .266e2, .123e5, .86e-3, .82e-3, .15e5, .13e-3, .24e5, .165e5, .9e4, .22e-1,
               .12e5, .188e1, .163e5, .48e7, .35e-3, .175e-1, .1e9, .444e12, .124e4, .21e1,
               .578e1, .474e-1, .178e4, .312e1)

POLLU_REFERENCE = np.array([
    0.5646255480022769e-01, 0.1342484130422339e+00, 0.4139734331099427e-08, 0.5523140207484359e-02,
    0.2018977262302196e-06, 0.1464541863493966e-06, 0.7784249118997964e-01, 0.3245075353396018e+00,
    0.7494013383880406e-02, 0.1622293157301561e-07, 0.1135863833257075e-07, 0.2230505975721359e-02,
    0.2087162882798630e-03, 0.1396921016840158e-04, 0.8964884856898295e-02, 0.4352846369330103e-17,
    0.6899219696263405e-02, 0.1007803037365946e-03, 0.1772146513969984e-05, 0.5682943292316392e-04])


def pollu():
    """POLLU (air pollution model, Verwer 1994): 20 species, 25 reactions, T = 60."""
    y = sp.symbols("y1:21")
    k = sp.symbols("k1:26")
    Y = (None,) + y   # 1-based, as in the Test Set
    r = [None,
         k[0] * Y[1], k[1] * Y[2] * Y[4], k[2] * Y[5] * Y[2], k[3] * Y[7], k[4] * Y[7],
         k[5] * Y[7] * Y[6], k[6] * Y[9], k[7] * Y[9] * Y[6], k[8] * Y[11] * Y[2],
         k[9] * Y[11] * Y[1], k[10] * Y[13], k[11] * Y[10] * Y[2], k[12] * Y[14],
         k[13] * Y[1] * Y[6], k[14] * Y[3], k[15] * Y[4], k[16] * Y[4], k[17] * Y[16],
         k[18] * Y[16], k[19] * Y[17] * Y[6], k[20] * Y[19], k[21] * Y[19], k[22] * Y[1] * Y[4],
         k[23] * Y[19] * Y[1], k[24] * Y[20]]
    rhs = [
        -r[1] - r[10] - r[14] - r[23] - r[24] + r[2] + r[3] + r[9] + r[11] + r[12] + r[22] + r[25],
        -r[2] - r[3] - r[9] - r[12] + r[1] + r[21],
        -r[15] + r[1] + r[17] + r[19] + r[22],
        -r[2] - r[16] - r[17] - r[23] + r[15],
        -r[3] + 2 * r[4] + r[6] + r[7] + r[13] + r[20],
        -r[6] - r[8] - r[14] - r[20] + r[3] + 2 * r[18],
        -r[4] - r[5] - r[6] + r[13],
        r[4] + r[5] + r[6] + r[7],
        -r[7] - r[8],
        -r[12] + r[7] + r[9],
        -r[9] - r[10] + r[8] + r[11],
        r[9],
        -r[11] + r[10],
        -r[13] + r[12],
        r[14],
        -r[18] - r[19] + r[16],
        -r[20],
        r[20],
        -r[21] - r[22] - r[24] + r[23] + r[25],
        -r[25] + r[24],
    ]
    u0 = np.zeros(20)
    u0[[1, 3, 6, 7, 8, 16]] = (0.2, 0.04, 0.1, 0.3, 0.01, 0.007)
    ode = ODE(dict(zip(y, rhs)), u0=u0, T=60.0, params=dict(zip(k, POLLU_RATES)))
    return Problem("POLLU", ode, stiff=True, final=POLLU_REFERENCE.copy(),
                   reference=f"{TEST_SET}, pollu.f (RADAU5, quad precision)",
                   description="air pollution, 20 species (Verwer 1994), T = 60")


def medakzo():
    """MEDAKZO (Medical Akzo Nobel, Test Set ``medakzo.f``): 400 components, a discretised
    reaction-convection-diffusion PDE with a discontinuity in time at t = 5, T = 20; declared
    as a template system in :mod:`dolfinode.bench.medakzo`. Scored with atol = rtol (the
    u-components are ~1e-4 at T, the v-components near the inflow ~1e-143)."""
    from dolfinode.bench.medakzo import MEDAKZO_REFERENCE, medakzo_ode

    return Problem("MEDAKZO", medakzo_ode(), stiff=True, final=MEDAKZO_REFERENCE.copy(),
                   reference=f"{TEST_SET}, medakzo.f (PSIDE, rtol = atol = 1e-10)",
                   description="Medical Akzo Nobel, 400 components (method of lines, "
                               "200 points), phi(t) jumps at t = 5, T = 20")


ARENSTORF_PERIOD = 17.0652165601579625588917206249


def arenstorf(periods=1):
    """Arenstorf orbit of the restricted three-body problem (Hairer-Noersett-Wanner I, p. 129):
    periodic, so the exact solution at T = periods x 17.0652... is the initial value."""
    y1, y2, v1, v2, mu = sp.symbols("y1 y2 v1 v2 mu")
    nu = 1 - mu
    d1 = ((y1 + mu) ** 2 + y2**2) ** sp.Rational(3, 2)
    d2 = ((y1 - nu) ** 2 + y2**2) ** sp.Rational(3, 2)
    u0 = np.array([0.994, 0.0, 0.0, -2.00158510637908252240537862224])
    ode = ODE({y1: v1, y2: v2,
               v1: y1 + 2 * v2 - nu * (y1 + mu) / d1 - mu * (y1 - nu) / d2,
               v2: y2 - 2 * v1 - nu * y2 / d1 - mu * y2 / d2},
              u0=u0, T=periods * ARENSTORF_PERIOD, params={mu: 0.012277471})
    return Problem("Arenstorf", ode, stiff=False, final=u0.copy(),
                   reference="periodic orbit: y(T) = y(0)",
                   description="restricted three-body orbit, one period (nonstiff)")


def harmonic_problem(T=100.0):
    """The harmonic oscillator of :func:`harmonic` on [0, T] (exact solution)."""
    ode, exact = harmonic(T)
    return Problem("harmonic", ode, stiff=False, final=exact(T), exact=exact,
                   reference="exact (sin t, cos t)", description=f"u'' = -u, T = {T:g}")


def lorenz_problem(T=5.0):
    """Lorenz system on [0, T]: chaotic, so errors grow like e^{0.9 t}; the reference is a
    tight scipy DOP853 solve (reported with the results)."""
    return Problem("Lorenz", lorenz(T), stiff=False, final=None,
                   reference="scipy DOP853 at rtol = 1e-13 (computed)",
                   description=f"Lorenz (sigma, rho, beta) = (10, 28, 8/3), T = {T:g}")


def reaction_front(n=200, T=0.05, eps=0.01, gamma=1000.0):
    """Reaction front u_t = eps u_xx + gamma u^2 (1 - u) on n points (Logg's multi-adaptive
    reaction-diffusion example): second differences with mirror ghost points (Neumann), domain
    length L = 5 n / 1000, u0 = 1 / (1 + exp(lam (x - x0))), lam = sqrt(gamma / (2 eps)),
    x0 = min(1, L / 2): the front starts inside the domain and travels right at about
    sqrt(gamma eps / 2)."""
    from scipy.special import expit

    L = 5.0 * n / 1000.0
    h = L / (n - 1)
    lam = np.sqrt(gamma / (2.0 * eps))
    x0 = min(1.0, L / 2)
    xs = np.linspace(0.0, L, n)
    u = sp.symbols(f"u0:{n}")
    e, g, h2 = sp.symbols("epsilon gamma h2")
    rhs = {}
    for i in range(n):
        left = u[i - 1] if i > 0 else u[1]
        right = u[i + 1] if i < n - 1 else u[n - 2]
        rhs[u[i]] = e * (left - 2 * u[i] + right) / h2 + g * u[i] ** 2 * (1 - u[i])
    ode = ODE(rhs, u0=expit(-lam * (xs - x0)), T=T, params={e: eps, g: gamma, h2: h * h})
    return Problem("reaction", ode, stiff=True, final=None, multiscale=True,
                   reference="scipy Radau at rtol = 1e-11 (computed)",
                   description=f"reaction front, N = {n}, T = {T:g}")


def brusselator(n=1000, T=10.0, alpha=1.0 / 50.0):
    """The 1-D Brusselator BRUSS of Hairer-Wanner II (Section IV.1) on n interior points:

        u_i' = 1 + u_i^2 v_i - 4 u_i + alpha (n + 1)^2 (u_(i-1) - 2 u_i + u_(i+1)),
        v_i' = 3 u_i - u_i^2 v_i + alpha (n + 1)^2 (v_(i-1) - 2 v_i + v_(i+1)),

    u_0 = u_(n+1) = 1, v_0 = v_(n+1) = 3, u_i(0) = 1 + sin(2 pi x_i), v_i(0) = 3,
    x_i = i / (n + 1), t in [0, T]; components interleaved (u_1, v_1, u_2, ...), so the
    Jacobian has bandwidth 2. No published reference: the runner computes one."""
    u = sp.symbols(f"u1:{n + 1}")
    v = sp.symbols(f"v1:{n + 1}")
    c = sp.Symbol("c")   # alpha (n + 1)^2
    rhs = {}
    for i in range(n):
        ul, ur = (u[i - 1] if i > 0 else 1), (u[i + 1] if i < n - 1 else 1)
        vl, vr = (v[i - 1] if i > 0 else 3), (v[i + 1] if i < n - 1 else 3)
        rhs[u[i]] = 1 + u[i] ** 2 * v[i] - 4 * u[i] + c * (ul - 2 * u[i] + ur)
        rhs[v[i]] = 3 * u[i] - u[i] ** 2 * v[i] + c * (vl - 2 * v[i] + vr)
    x = np.arange(1, n + 1) / (n + 1)
    u0 = np.column_stack([1 + np.sin(2 * np.pi * x), np.full(n, 3.0)]).ravel()
    ode = ODE(rhs, u0=u0, T=T, params={c: alpha * (n + 1) ** 2})
    return Problem(f"bruss-{n}", ode, stiff=True, final=None,
                   reference="scipy Radau at rtol = 1e-11 (computed)",
                   description=f"1-D Brusselator (Hairer-Wanner II), n = {n} points "
                               f"(N = {2 * n}), alpha = {alpha:g}, T = {T:g}")


def mass_spring_chain(n=50, stiffness=1e4, stiff_springs=2, T=10.0, cubic=0.0):
    """Chain of n unit masses between two walls, unit springs, ``stiff_springs`` evenly spaced
    springs ``stiffness`` times stiffer; x_i(0) = sin(pi i / (n + 1)), v(0) = 0. Linear: the
    exact solution is the matrix exponential. ``cubic`` > 0: each spring's force at
    elongation d is k (d + cubic d^3) (a Fermi-Pasta-Ulam chain; no reference)."""
    import scipy.linalg as sl

    stiff = [int((m + 0.5) * (n + 1) / stiff_springs) for m in range(stiff_springs)]
    x = sp.symbols(f"x0:{n}")
    ks, kS = sp.symbols("k_soft k_stiff")
    ksym = [kS if j in stiff else ks for j in range(n + 1)]
    def force(d):
        return d + cubic * d**3 if cubic else d

    acc = {}
    for i in range(n):
        left = x[i - 1] - x[i] if i > 0 else -x[i]
        right = x[i + 1] - x[i] if i < n - 1 else -x[i]
        acc[x[i]] = ksym[i] * force(left) + ksym[i + 1] * force(right)
    x0 = np.sin(np.pi * np.arange(1, n + 1) / (n + 1))
    ode = ODE.second_order(acc, x0=x0, v0=np.zeros(n), T=T, params={ks: 1.0, kS: stiffness})
    if cubic:
        return Problem("fpu-chain", ode, stiff=False, final=None, multiscale=True,
                       reference="none: the runner computes one",
                       description=f"cubic-spring chain, {n} masses, {stiff_springs} springs "
                                   f"{stiffness:g}x stiffer, cubic {cubic:g}, T = {T:g}")
    kvec = np.where(np.isin(np.arange(n + 1), stiff), stiffness, 1.0)
    K = (np.diag(-(kvec[:-1] + kvec[1:])) + np.diag(kvec[1:-1], 1) + np.diag(kvec[1:-1], -1))
    A = np.block([[np.zeros((n, n)), np.eye(n)], [K, np.zeros((n, n))]])
    # eigendecomposition once, so that the 100-point reference trajectory is cheap
    w, V = sl.eig(A)
    c = np.linalg.solve(V, ode.u0)

    def exact(s):
        s = np.asarray(s, dtype=float)
        out = (V @ (c[:, None] * np.exp(np.outer(w, np.atleast_1d(s))))).real
        return out[:, 0] if s.ndim == 0 else out

    return Problem("chain", ode, stiff=False, final=exact(T), exact=exact, multiscale=True,
                   reference="modal solution (eigendecomposition of the linear system)",
                   description=f"mass-spring chain, {n} masses, {stiff_springs} springs "
                               f"{stiffness:g}x stiffer, T = {T:g}")


def seed_model(kappa=1e4, T=10.0):
    """The seed model of automatic modeling (DOLFIN demo ode/modeling/simple):

        x1'' = -x1 + x2^2 / 2,  x2'' = -kappa x2,  x(0) = (0, 1),  x'(0) = 0.

    Exact, with w = sqrt(kappa) and A = -1 / (4 (4 kappa - 1)):
    x2 = cos(w t), x1 = (1 - cos t) / 4 + A (cos(2 w t) - cos t).

    Scored on x1 alone: x2 and x2' are the fast oscillation, which automatic modeling replaces
    by its average, and x1' carries a fast term -2 w A sin(2 w t) of amplitude ~ 1 / (8 w)
    that the averaged model omits by construction, while the fast part of x1, A cos(2 w t),
    is ~ 1 / (16 kappa), below every accuracy compared. For kappa >= 1e4 the problem declares
    automatic modeling with average_length 30 / w (about five fast periods); at smaller
    kappa the averaging window would span much of the slow period 2 pi."""
    x1, x2, k = sp.symbols("x1 x2 kappa")
    ode = ODE.second_order({x1: -x1 + x2**2 / 2, x2: -k * x2}, x0=[0.0, 1.0], v0=[0.0, 0.0],
                           T=T, params={k: kappa})
    w = np.sqrt(kappa)
    A = -1.0 / (4.0 * (4.0 * kappa - 1.0))

    def exact(s):
        s = np.asarray(s, dtype=float)
        return np.array([0.25 * (1 - np.cos(s)) + A * (np.cos(2 * w * s) - np.cos(s)),
                         np.cos(w * s),
                         0.25 * np.sin(s) + A * (np.sin(s) - 2 * w * np.sin(2 * w * s)),
                         -w * np.sin(w * s)])

    return Problem(f"seed k={kappa:g}", ode, stiff=False, final=exact(T), exact=exact,
                   multiscale=True, scored=(0,),
                   modeling={"average_length": 30.0 / w} if kappa >= 1e4 else None,
                   reference="closed form (scored: x1)",
                   description=f"automatic-modeling seed problem, kappa = {kappa:g}, T = {T:g}")


#: Builders of the benchmark set by name (called without arguments).
PROBLEMS = {
    "HIRES": hires_problem,
    "ROBER": rober,
    "VDPOL": vdpol,
    "VDPOLM": vdpolm,
    "POLLU": pollu,
    "MEDAKZO": medakzo,
    "Arenstorf": arenstorf,
    "harmonic": harmonic_problem,
    "Lorenz": lorenz_problem,
    "reaction": reaction_front,
    "chain": mass_spring_chain,
    "seed k=1e2": lambda: seed_model(1e2),
    "seed k=1e4": lambda: seed_model(1e4),
    "seed k=1e6": lambda: seed_model(1e6, T=1.0),
    "seed k=1e8": lambda: seed_model(1e8, T=10.0),
}

#: Problems of the compiled-peer comparison outside the default suite (``dolfinode bench
#: --peers``): the Brusselator, whose Jacobian is banded.
PEER_PROBLEMS = {
    "bruss-1000": lambda: brusselator(1000),
    "bruss-4000": lambda: brusselator(4000),
}

#: The problems of a ``--quick`` run.
QUICK_PROBLEMS = ("HIRES", "ROBER", "VDPOLM", "Arenstorf")


def get_problem(name):
    """Build a problem of :data:`PROBLEMS`, of the multi-adaptive set
    (:data:`dolfinode.bench.multirate.MULTIADAPTIVE_PROBLEMS`) or of :data:`PEER_PROBLEMS` by
    name (case-insensitive)."""
    from dolfinode.bench.multirate import MULTIADAPTIVE_PROBLEMS

    known = {**PROBLEMS, **MULTIADAPTIVE_PROBLEMS, **PEER_PROBLEMS}
    for key, build in known.items():
        if key.lower() == name.lower():
            return build()
    import difflib
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.4)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise ValueError(f"unknown benchmark problem {name!r}{hint} Known: {', '.join(known)}")
