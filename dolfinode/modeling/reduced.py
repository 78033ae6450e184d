"""The reduced model f~ = f + g~ with inactivated fast components, and its record.

Jansson, Johnson & Logg (2005), sections 3-6: the reduced model

    u~' = f(u~, t) + g~(u~, t),   u~(t_c) = u-bar(t_c),

with a subgrid model g~ approximating the variance g-bar = avg f(u) - f(u-bar). Components
whose average does not change over the resolved window (the fast ones) are *inactivated*,
g~_i = -f_i: they keep the value of their average, which removes the leftover fast
oscillation of amplitude ~1/(sqrt(kappa) tau) that would otherwise force small steps in the
reduced system (the paper's section 5, "Solving the reduced system").

The subgrid model is constant, g~ = g-bar of the last build, or affine in the slow state,

    g~(u~) = g-bar_k + G (u~ - u-bar_k),

with G fitted by least squares to the differences of the last windows' (u-bar, g-bar)
(builds and checks; at the first build, the two half windows and the window), on the pattern
of the active variables that reach g-bar through the inactive ones (the entries of
J_AI (J_II)^* J_IA) or that f combines with them (mixed second derivatives). The paper's
constant model is exact for its simple model; on the lattice g-bar follows the slow
contraction and the affine model follows it between control points.

Fast components that relax instead of oscillating are not frozen but follow their slow
manifold (:mod:`dolfinode.modeling.manifold`); the fluctuation that restarts the full model
at a control point is carried to the current slow state by its action
(:func:`adiabatic_scaling`).
"""
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
from scipy import sparse

from dolfinode.compile import lower
from dolfinode.modeling import validity
from dolfinode.modeling.declaration import ReducedDeclaration
from dolfinode.modeling.manifold import project
from dolfinode.ode import ODE
from dolfinode.systems.template import TemplateODE

#: tau = AVERAGE_PERIODS / |lambda|_max when average_length is not given: about 16 periods of
#: the fastest oscillation in each half of the window, where the average of its oscillation
#: is below 1e-9 (the kernel's transform decays like (|lambda| tau)^-7, see
#: :mod:`dolfinode.modeling.averaging`).
AVERAGE_PERIODS = 100.0
#: The default tau is also at most SLOW_FRACTION of the slow time scale (the kernel's bias of
#: a slow component is m_4 (tau / slow scale)^4 / 24), but not below MINIMUM_PERIODS /
#: |lambda|_max (the average of the fast oscillation below 1.3e-5).
SLOW_FRACTION = 0.2
MINIMUM_PERIODS = 30.0
#: Eigenvalues at least this factor below |lambda|_max are the slow ones.
SCALE_SEPARATION = 100.0
#: Up to this many components :func:`component_frequencies` works on a dense Jacobian.
DENSE_FREQUENCIES = 64
#: Relative accuracy of the spectral radius (a time scale: a few digits suffice).
SPECTRAL_TOLERANCE = 1e-6
#: Up to this many inactive components :func:`amplitude_rate` takes the eigenvalues of their
#: block of df/du (a dense eigenproblem); above, it is not measured.
DAMPING_COMPONENTS = 400
#: Real parts of eigenvalues below this many machine epsilons of their modulus are rounding
#: (the seed model's pair at kappa = 1e18 coupled to a second: 1.6e-8 at |lambda| = 1e9).
DAMPING_ROUNDING = 64
#: Windows (the last build and the checks and builds before it) fitted by the affine model.
AFFINE_SAMPLES = 4
#: Singular values of the fit below this fraction of the largest are dropped (the windows
#: move mostly along one slow mode; a second direction is mostly measurement noise).
AFFINE_RCOND = 0.1
#: "auto" starts affine when a constant g~ would miss the first check by this many
#: model tolerances (see ReducedModel._constant_fails; set above the paper's lattice, 15-37
#: for p = 7, 5, 3, and below the proportional class of
#: dolfinode.bench.multiscale, 1300-4400).
AFFINE_START = 100.0
#: ... and only when the first control point is at most this many half windows away: the
#: fit's error over the baseline tau / 2 grows with the extrapolation (the lattice with
#: m = 1e-12, tau = 1e-4, control points 2 apart, 4e4 half windows: the reduced model blew up).
AFFINE_EXTRAPOLATION = 1000.0
#: Beyond that, "auto" checks early instead, where the constant model's predicted local error
#: (defect times span, rate x d^2) is this fraction of the tolerance; the check rebuilds the
#: model affine, fitted over the baseline d (the proportional class at kappa = 1e10: local
#: error 2.2 with the first check 4.5 away).
EARLY_CHECK_FRACTION = 0.1


def fast_time_scale(compiled, u, t):
    """1 / |lambda|_max: the fastest time scale of the linearisation df/du at (u, t).

    The spectral radius is computed from the dense Jacobian for N <= 500 and with ARPACK
    (largest magnitude) otherwise, from a fixed start vector (ARPACK's own is random, and the
    windows' step bound, so every element of a modeling solve, would vary from run to run) to
    a relative accuracy of SPECTRAL_TOLERANCE (to machine precision, a tight cluster of fast
    eigenvalues, as the lattice's small masses, takes ARPACK tens of thousands of
    iterations).
    """
    J = compiled.jacobian_matrix(u, t)
    if J.shape[0] <= 500:
        radius = np.max(np.abs(np.linalg.eigvals(J.toarray())))
    else:
        from scipy.sparse.linalg import eigs

        start = np.random.default_rng(0).standard_normal(J.shape[0])
        radius = np.max(np.abs(eigs(J.astype(float), k=1, which="LM", v0=start,
                                    tol=SPECTRAL_TOLERANCE, return_eigenvectors=False)))
    return 1.0 / radius if radius > 0 else np.inf


def default_average_length(compiled, u, t):
    """tau from both scales of df/du at (u, t): AVERAGE_PERIODS / |lambda|_max, shortened
    towards SLOW_FRACTION / |lambda_slow| (the largest |lambda| at least SCALE_SEPARATION
    below |lambda|_max) but not below MINIMUM_PERIODS / |lambda|_max. Systems of more than
    500 components look at the fast scale only (ARPACK gives |lambda|_max alone)."""
    fastest = fast_time_scale(compiled, u, t)
    tau = AVERAGE_PERIODS * fastest
    J = compiled.jacobian_matrix(u, t)
    if J.shape[0] <= 500 and np.isfinite(fastest):
        moduli = np.abs(np.linalg.eigvals(J.toarray()))
        slow = moduli[(moduli > 0) & (moduli * fastest <= 1 / SCALE_SEPARATION)]
        if slow.size:
            tau = min(tau, max(SLOW_FRACTION / slow.max(), MINIMUM_PERIODS * fastest))
    return tau


def component_frequencies(J):
    """omega_i of the sparse Jacobian J = df/du: the time scale 1/omega_i on which component i
    moves by itself,

        omega_i^2 = J_ii^2 + |sum_{k != i, J_ik J_ki < 0} J_ik J_ki|,

    its own rate and its oscillatory couplings. For a second-order system x' = v, v' = a(x),
    J_xv J_vx = da/dx < 0 is the stiffness over the mass acting on the coordinate (and on its
    velocity); for u' = -lambda u, omega = |lambda|. A coupling of positive product is not
    an oscillation: in Michaelis-Menten, s' = -s + (s + K - lam) c with eps c' = s - (s + K) c,
    J_sc J_cs ~ 1/eps would make the slow substrate s fast.
    """
    if J.shape[0] <= DENSE_FREQUENCIES:  # scipy.sparse's overhead dominates small systems
        J = J.toarray() if sparse.issparse(J) else np.asarray(J)
        products = J * J.T
        diagonal = np.diag(products).copy()
        return np.sqrt(diagonal + np.abs(np.minimum(products, 0.0).sum(axis=1)))
    J = sparse.csr_matrix(J)
    products = J.multiply(J.T).tocsr()
    diagonal = products.diagonal()
    products.data = np.minimum(products.data, 0.0)  # the diagonal J_ii^2 drops out too
    return np.sqrt(diagonal + np.abs(np.asarray(products.sum(axis=1)).ravel()))


def adiabatic_scaling(J_old, J_new):
    """Factors that carry a fast oscillation's fluctuation from the slow state of J_old = df/du
    to that of J_new, conserving its action E / omega.

    Component i oscillates with the partner j of most negative J_ij J_ji (x' = b v, v' = c x
    for the pair (x, v)); the action fixes the amplitudes, x ~ (b / |c|)^(1/4),
    v ~ (|c| / b)^(1/4), so x is scaled by ((|J_ij| / |J_ji|)_new / (|J_ij| / |J_ji|)_old)^(1/4).
    Components without an oscillatory partner keep factor 1. On the seed model with
    x2'' = -kappa (1 + x1) x2, the recorded fluctuation restarted at another slow state
    gave g-bar from 0.208 to 0.250 depending on its phase; scaled, the same at every phase.
    """
    if J_old.shape[0] <= DENSE_FREQUENCIES:  # scipy.sparse's overhead dominates small systems
        J_old, J_new = (J.toarray() if sparse.issparse(J) else np.asarray(J)
                        for J in (J_old, J_new))
        products = J_old * J_old.T
        np.fill_diagonal(products, 0.0)
        partner = np.argmin(products, axis=1)  # the most negative product
        rows = np.flatnonzero(products[np.arange(len(partner)), partner] < 0)
        cols = partner[rows]
    else:
        J_old, J_new = sparse.csr_matrix(J_old), sparse.csr_matrix(J_new)
        products = J_old.multiply(J_old.T).tocoo()
        oscillatory = (products.row != products.col) & (products.data < 0)
        row, col = products.row[oscillatory], products.col[oscillatory]
        first = np.lexsort((products.data[oscillatory], row))  # per row, most negative first
        row, col = row[first], col[first]
        keep = np.r_[True, row[1:] != row[:-1]][:row.size]
        rows, cols = row[keep], col[keep]
    factor = np.ones(J_old.shape[0])
    if not rows.size:
        return factor

    def ratio(J):
        forward = np.abs(np.asarray(J[rows, cols]).ravel())
        backward = np.abs(np.asarray(J[cols, rows]).ravel())
        with np.errstate(divide="ignore", invalid="ignore"):
            return forward / backward

    scaled = (ratio(J_new) / ratio(J_old)) ** 0.25
    factor[rows] = np.where(np.isfinite(scaled) & (scaled > 0), scaled, 1.0)
    return factor


def slaving_possible(ode):
    """Whether relaxing components can be put on their slow manifold: the rates of the
    manifold are derived per expression, so not for a TemplateODE."""
    return not isinstance(ode, TemplateODE)


def amplitude_rate(J, inactive):
    """2 Re lambda of largest modulus over the oscillating eigenvalues (|Im lambda| >
    |Re lambda|) of the block of J = df/du on the ``inactive`` components: the rate at which
    the squared amplitudes of the fast oscillation, and with them g-bar, decay (damping,
    negative) or grow.

    The reduced model does not follow it: every control point restarts the full model with
    the fluctuation recorded at the last build, so its windows see the amplitude of the first
    window (x'' = -kappa x - c x' with c = 0.01 over [0, 10]: g-bar fell by 10 % and the
    checks found defects of 5e-4). :func:`dolfinode.modeling.validity.modeling_error` adds
    the drift |g-bar| (exp(rate (t - t_c)) - 1) to the defects. 0 above DAMPING_COMPONENTS
    inactive components (not measured)."""
    index = np.flatnonzero(inactive)
    if index.size == 0 or index.size > DAMPING_COMPONENTS:
        return 0.0
    J = J.toarray() if sparse.issparse(J) else np.asarray(J)
    eigenvalues = np.linalg.eigvals(J[np.ix_(index, index)])
    real = np.abs(eigenvalues.real)
    oscillating = (np.abs(eigenvalues.imag) > real) \
        & (real > DAMPING_ROUNDING * np.finfo(float).eps * np.abs(eigenvalues))
    if not oscillating.any():
        return 0.0
    chosen = eigenvalues.real[oscillating]
    return 2.0 * float(chosen[np.argmax(np.abs(chosen))])


def relaxing_components(J, inactive):
    """The inactive components that relax rather than oscillate: J_ii < 0 carries at least
    half of omega_i^2 (:func:`component_frequencies`); see :mod:`dolfinode.modeling.manifold`.
    """
    diagonal = sparse.csr_matrix(J).diagonal()
    return inactive & (diagonal < 0) & (diagonal**2 >= 0.5 * component_frequencies(J)**2)


def inactive_components(ode, compiled, tau, drift, average_tolerance):
    """The components of ``ode`` to inactivate (at u0, t0): the fast ones (at least one period 2 pi / omega_i in
    the averaging length tau, see :func:`component_frequencies`) whose average does not move
    (``drift`` < ``average_tolerance``), closed under mutual coupling: a fast component
    stays active when a fast component coupled both ways with it (J_ij J_ji != 0) does.

    One of a pair frozen at its average while its partner evolves makes the partner drift
    (x' = v, v' = -kappa x with x frozen at a nonzero average: v grows linearly); on the
    seed model with tau = 1.6 fast periods v's average moved and the reduced model blew up.
    Relaxing fast components (:func:`relaxing_components`) are inactivated whatever their
    drift: the reduced model puts them on their slow manifold.
    Raises ValueError when fast components exist but none can be inactivated, or when all
    would be."""
    J = compiled.jacobian_matrix(ode.u0, ode.t0)
    fast = component_frequencies(J) * tau >= 2 * np.pi
    # a relaxing component follows its slow manifold, however far the manifold moves
    relaxing = relaxing_components(J, fast) if slaving_possible(ode) else np.zeros_like(fast)
    inactive = fast & ((drift < average_tolerance) | relaxing)
    mutual = (abs(J).multiply(abs(J.T)) > 0).astype(float)
    while True:
        blocked = (mutual @ (fast & ~inactive).astype(float)) > 0
        if not np.any(inactive & blocked):
            break
        inactive &= ~blocked
    if fast.any() and not inactive.any():
        moving = np.flatnonzero(fast & ~(drift < average_tolerance))
        raise ValueError(
            f"automatic modeling can inactivate none of the {int(fast.sum())} fast components: "
            f"the averages of {len(moving)} of them ({ode.states[int(moving[0])]} first) move by "
            f"more than average_tolerance = {average_tolerance:g} over the window (largest "
            f"drift {float(np.max(drift[fast])):.3g}), and each fast component is inactivated "
            f"only with its fast partners. Either average_length = {tau:.3g} is too short for "
            "the average to settle (use at least two periods of the fastest scale, or a "
            "larger average_tolerance), or the averages really move: the slow variables are "
            "combinations of fast components (the centre of a stiff spring whose ends "
            "oscillate, as in the Fermi-Pasta-Ulam problem), which inactivating components "
            "cannot represent; then use subgrid_model='flow' (the default does when a "
            "parameter sets the fast scale) or solve without automatic_modeling")
    if inactive.all():
        raise ValueError(
            "automatic modeling would inactivate every component: all of them are fast "
            f"(omega_i average_length >= 2 pi, average_length = {tau:.3g}) and no slow "
            "component is left to solve for; the slow variables are combinations of the "
            "components (as the centres of stiff springs), which a reduced model of "
            "inactivated components cannot represent: use subgrid_model='flow' or solve "
            "without automatic_modeling")
    return inactive


@dataclass
class ControlPoint:
    """A check of the reduced model against the full model resolved around ``time``.

    ``defect`` is the l2 norm over the active components of

        f(u-bar_A, U_I, t) + g~ - avg f(u)  =  g~ - g-bar,

    the reduced right-hand side at the window average (active components A) and the model's
    frozen values (inactive components I) against the average of the full one: the integrand
    of the modeling-error term of the error representation. ``relative_defect`` is its max
    norm over max |g-bar| + tolerance (a scale that cannot vanish). ``defects`` and ``g_bar``
    are the vectors g~ - g-bar and g-bar (zero on inactive components).
    """

    time: float
    defect: float
    relative_defect: float
    rebuilt: bool
    elements: int
    defects: np.ndarray = None
    g_bar: np.ndarray = None


def affine_pattern(jacobian, active, perturbed=None):
    """Entries (i, j), i and j active, on which g-bar_i may depend on u_j:

    - the pattern J_AI (J_II)^* J_IA: the active variables j that move the inactive (fast)
      variables that f_i depends on (g-bar_i is an average over those fast variables);
    - with ``perturbed``, df/du at the same slow state with the fast components moved: the
      entries of J_AA that the fast components change, the mixed second derivatives
      d^2 f_i / du_j du_I (y' = -y x^2 with x fast: g-bar = -y avg(x^2 - x-bar^2) is
      proportional to y although x does not depend on y).
    """
    inactive = ~active
    A, I = np.flatnonzero(active), np.flatnonzero(inactive)
    J = (sparse.csr_matrix(jacobian) != 0).astype(np.int8)
    J_AI, J_IA, J_II = J[A][:, I], J[I][:, A], J[I][:, I]
    reach = J_IA.copy()
    while True:  # reach = (I + J_II + J_II^2 + ...) J_IA, by fixed point
        grown = ((reach + J_II @ reach) != 0).astype(np.int8)
        if grown.nnz == reach.nnz:
            break
        reach = grown
    B = J_AI @ reach
    if perturbed is not None:
        mixed = sparse.csr_matrix(perturbed) - sparse.csr_matrix(jacobian)
        B = B + (abs(mixed[A][:, A]) > 0).astype(np.int8)
    B = sparse.coo_matrix(B != 0)
    order = np.lexsort((B.col, B.row))
    return A[B.row[order]], A[B.col[order]]


def fit_affine(pattern, u_bars, g_bars):
    """Least-squares G on ``pattern`` from windows (u-bar_k, g-bar_k), k = 1..K:
    minimum-norm solution of  G_i. (u-bar_k - u-bar_K) = g-bar_ik - g-bar_iK  per row i,
    with singular values below AFFINE_RCOND of the largest dropped. Returns the entries."""
    rows, cols = pattern
    values = np.zeros(len(rows))
    if len(u_bars) < 2 or not len(rows):
        return values
    dU = np.asarray(u_bars[:-1]) - u_bars[-1]
    dG = np.asarray(g_bars[:-1]) - g_bars[-1]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1], True])
    for a, b in pairwise(starts):
        values[a:b] = np.linalg.lstsq(dU[:, cols[a:b]], dG[:, rows[a]],
                                      rcond=AFFINE_RCOND)[0]
    return values


@dataclass
class ReducedModel:
    """The automatically built reduced model and its history (``sol.model``).

    Attributes
    ----------
    average_length : tau (given or chosen from the fast time scale)
    g : dict state -> subgrid model value g~ as last built (for an inactive state,
        g~_i = -f_i(u-bar), the paper's inactivation); made on first use
    inactive : tuple of the inactivated states (frozen or slaved); made on first use
    built : times at which the model was built (the first is t_c = t0 + tau, the centre of
        the first resolved window [t0, t0 + 2 tau], where the reduced solution starts)
    control_points : list of :class:`ControlPoint`
    reduced : the reduced solution on (t_c, T] (a :class:`~dolfinode.Solution` of the
        reduced ODE; set by the solver)
    estimate : the :class:`~dolfinode.modeling.validity.ModelingError` of the default goal,
        checked after the solve (None without control points)
    subgrid_model : "auto", "constant" or "affine" (the ``subgrid_model`` parameter)
    affine : whether g~ is affine in the slow state (from the start for "affine"; for
        "auto" from the start when the first window shows a constant g~ would fail the
        first check, see :meth:`_constant_fails`, else from the first rebuild)
    spacing, tolerance, model_tolerance : of the control points, set by the solver
    early_check : for "auto", the distance from t_c of an extra first control point when the
        first window shows a constant g~ failing but too far from the first check to fit an
        affine one (see :meth:`_constant_fails`); None otherwise
    G : scipy.sparse matrix (N, N), the slope of the affine model as last built (zero for
        the constant model)
    slaved : tuple of the inactive states that relax to their slow manifold and follow it
        (:mod:`dolfinode.modeling.manifold`) instead of being frozen; made on first use
    amplitude_rate : the rate at which the fast oscillation's squared amplitudes grow
        (decay: negative) by themselves (:func:`amplitude_rate`), which the model does not
        follow
    """

    ode: ODE
    average_length: float
    built: list = field(default_factory=list)
    control_points: list = field(default_factory=list)
    reduced: object = None
    estimate: object = None
    subgrid_model: str = "constant"
    affine: bool = False
    spacing: float = np.inf
    tolerance: float = 0.0
    model_tolerance: float = np.inf
    early_check: float = None
    amplitude_rate: float = 0.0

    def __post_init__(self):
        N = self.ode.N
        self._g = np.zeros(N)        # g~ at the reference state: g-bar of the last build
        self._reference = np.zeros(N)  # u-bar of the last build
        self._G = np.zeros(0)        # G's entries on self._pattern
        self._pattern = (np.zeros(0, dtype=np.int64),) * 2
        self._active = np.ones(N, dtype=bool)
        self._frozen = np.zeros(N)
        self._slaved = np.zeros(N, dtype=bool)
        self._compiled = None
        self._g_inactive = np.zeros(N)  # -f_i(u-bar) of the last build
        self._windows = []           # (u-bar, g-bar) of every window, for the affine fit
        self._declarations = {}
        self.affine = self.subgrid_model == "affine"

    @property
    def active(self):
        """Boolean mask of the active components."""
        return self._active.copy()

    @property
    def G(self):
        rows, cols = self._pattern if len(self._G) else (np.zeros(0, dtype=np.int64),) * 2
        return sparse.csr_matrix((self._G, (rows, cols)), shape=(self.ode.N,) * 2)

    def _apply_G(self, v):
        """G v from G's entries on the pattern (a sparse matrix built per call cost more
        than the product)."""
        if not len(self._G):
            return np.zeros(self.ode.N)
        rows, cols = self._pattern
        return np.bincount(rows, weights=self._G * v[cols], minlength=self.ode.N)

    @property
    def windows(self):
        """The :class:`~dolfinode.modeling.averaging.WindowAverages` of every resolved window,
        in time order."""
        return tuple(self._windows)

    def record(self, averages):
        """Keep a window's averages as data for the affine fit."""
        self._windows.append(averages)

    def build(self, averages, inactive_mask, time, compiled):
        """(Re)build from window averages: g~ = g-bar on active components (plus, for the
        affine model, G fitted to the recorded windows), inactive ones frozen at their
        average.

        The affine model is fitted to what the reduced model must supply at each recorded
        window k, y_k = f-bar_k - f(u-bar_k with the inactive components at their new
        frozen values): y_k is g-bar_k plus the error of freezing the fast components while
        the slow ones move (a small mass frozen in space anchors the corners it should
        follow); at the newest window y = g-bar."""
        recent = self._windows[-AFFINE_SAMPLES:]
        if not self.built:
            self._active = ~inactive_mask
            self._compiled = compiled
            if slaving_possible(self.ode):
                self._slaved = relaxing_components(
                    compiled.jacobian_matrix(averages.u_bar, averages.center), inactive_mask)
            self.amplitude_rate = amplitude_rate(
                compiled.jacobian_matrix(averages.u_bar, averages.center),
                inactive_mask & ~self._slaved)
            moved = averages.u_bar + np.where(inactive_mask, averages.fluctuation, 0.0)
            self._pattern = affine_pattern(
                compiled.jacobian_matrix(averages.u_bar, averages.center), self._active,
                compiled.jacobian_matrix(moved, averages.center))
            # not with slaved components: the first window's first half holds their
            # relaxation onto the manifold, and over tau / 2 the slow state barely moves
            # (Michaelis-Menten at eps = 1e-8: G from the halves put s off by 0.1)
            if self.subgrid_model == "auto" and len(self._pattern[0]) \
                    and not self._slaved.any():
                self.affine = self._constant_fails(averages, compiled)
            recent = [*averages.halves, averages]  # the affine model's first fit
        elif self.subgrid_model == "auto":
            self.affine = True  # the constant model needed a rebuild
        self._frozen = np.where(inactive_mask, averages.u_bar, 0.0)
        self._g = np.where(self._active, averages.g_bar, 0.0)
        self._reference = averages.u_bar.copy()
        if self.affine:
            targets = [w.f_bar - compiled.f(self.state(w.u_bar, w.center), w.center)
                       for w in recent]
            self._G = fit_affine(self._pattern, [w.u_bar for w in recent], targets)
        self._g_inactive = -(averages.f_bar - averages.g_bar)  # -f(u-bar, t_c)
        self.built.append(float(time))

    def _constant_fails(self, averages, compiled):
        """Whether a constant g~ would be off at the first control point by more than
        AFFINE_START model tolerances, extrapolating the change of g-bar between the two
        half windows, and the check is at most AFFINE_EXTRAPOLATION half windows away: then
        "auto" is affine from the start, fitted to the half windows. Their
        short baseline tau / 2 makes that fit noisy: on the lattice (predicted 0.30-0.74
        for p = 7, 5, 3 and model_tolerance 0.02) starting affine raised the drift of D from
        D-bar from 0.0040 to 0.0074 at p = 3, so the bar is high; the proportional class
        (y' = cos t - y x^2, predicted 27 and 88 at kappa = 1e4, 1e6) starts affine (its
        error from 0.53 to 1.5e-5 of the range); class 1 (0.76) does not (it would go from
        0.13 to 0.039, warned either way). A check farther than that (the proportional class
        at kappa = 1e10, 9000 half windows) sets :attr:`early_check` to d with
        rate x d^2 = EARLY_CHECK_FRACTION x tolerance, and the model starts constant."""
        first, second = (h.f_bar - compiled.f(self.state(h.u_bar, h.center), h.center)
                         for h in averages.halves)
        rate = np.max(np.abs(second - first)[self._active]) / (self.average_length / 2)
        scale = np.max(np.abs(averages.g_bar[self._active])) + self.tolerance
        if not rate * self.spacing / scale > AFFINE_START * self.model_tolerance:
            return False
        if self.spacing <= AFFINE_EXTRAPOLATION * self.average_length / 2:
            return True
        self.early_check = max(np.sqrt(EARLY_CHECK_FRACTION * self.tolerance / rate),
                               self.average_length)
        return False

    # g and inactive are by state symbol: a lattice of 10^5 masses creates its N symbols
    # only if they are asked for, not at every build
    @property
    def g(self):
        return {s: float(self._g[i] if self._active[i] else self._g_inactive[i])
                for i, s in enumerate(self.ode.states)} if self.built else {}

    @property
    def inactive(self):
        return tuple(self.ode.states[i] for i in np.flatnonzero(~self._active)) \
            if self.built else ()

    @property
    def slaved(self):
        return tuple(self.ode.states[i] for i in np.flatnonzero(self._slaved))

    def state(self, u, time=None):
        """u with its frozen components replaced by their frozen averages, and, given the
        time, its slaved components projected onto their slow manifold."""
        u = np.where(self._active | self._slaved, u, self._frozen)
        return u if time is None else project(self._compiled, u, time, self._slaved)

    def subgrid(self, u):
        """g~(u) on the active components (zero elsewhere)."""
        g = self._g.copy()
        if self.affine and len(self._G):
            g += self._apply_G(self.state(u) - self.state(self._reference))
        return np.where(self._active, g, 0.0)

    def declaration(self, u0, t0, T):
        """The reduced ODE on [t0, T] from u0 (slaved components projected onto their
        manifold): f_i + g~_i(u) for active i, the manifold's rates for slaved i, 0 for
        frozen i.

        g~ (and G) enter as parameters, so a rebuilt model reuses the compiled kernels.
        """
        if self.affine not in self._declarations:
            self._declarations[self.affine] = ReducedDeclaration(
                self.ode, self._active, self._pattern if self.affine else None, self._slaved)
        declarer = self._declarations[self.affine]
        u0 = self.state(u0, t0)
        if not self.affine:
            return declarer.declaration(u0, t0, T, self._g)
        # g + G (u - r) = (g - G r) + G u
        constant = self._g - self._apply_G(self.state(self._reference))
        return declarer.declaration(u0, t0, T, constant, self._G)

    def defect(self, compiled, averages):
        """g~ - g-bar on the active components (zero elsewhere), see :class:`ControlPoint`."""
        u = self.state(averages.u_bar, averages.center)
        reduced_rhs = compiled.f(u, averages.center) + self.subgrid(u)
        return np.where(self._active, reduced_rhs - averages.f_bar, 0.0)

    @property
    def largest_defect(self):
        """max over the control points of ||g~ - g-bar||_l2 (0 without control points)."""
        return max((c.defect for c in self.control_points), default=0.0)

    def modeling_error(self, goal=None):
        """The error estimate of the reduced solution against the average of the full model
        in a goal: the modeling part int (|phi|, |g~ - g-bar|) dt (at most the paper's
        S0 max ||g~ - g-bar||) and the discretisation part, see
        :mod:`dolfinode.modeling.validity`.

        Parameters
        ----------
        goal : any goal form of :func:`dolfinode.estimate_error`, optional
            Default: each active (slow) component at T on its own, the largest estimate
            (inactive components are frozen averages, not outputs of the model).

        Returns
        -------
        :class:`~dolfinode.modeling.validity.ModelingError`
        """
        if self.reduced is None:
            raise ValueError("the reduced model has not been solved yet: modeling_error is "
                             "available on sol.model after dn.solve(..., "
                             "automatic_modeling=True)")
        if not self.control_points:
            raise ValueError("no control points: max |g~ - g-bar| is unknown; solve with "
                             "control_points >= 1")
        return validity.modeling_error(self, goal)

    def __getstate__(self):
        # the kernels (ctypes) do not pickle: lowered again from the declaration when read
        state = self.__dict__.copy()
        if state["_compiled"] is not None:
            state["_lower_again"] = True
            del state["_compiled"]
        return state

    def __getattr__(self, name):
        # (called only for what the instance lacks: _compiled after unpickling)
        if name == "_compiled" and self.__dict__.get("_lower_again"):
            self._compiled = lower(self.ode)
            return self._compiled
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __repr__(self):
        return (f"ReducedModel(tau={self.average_length:.3g}, "
                f"inactive={int(np.count_nonzero(~self._active))}, "
                f"built={len(self.built)}x, control points={len(self.control_points)})")
