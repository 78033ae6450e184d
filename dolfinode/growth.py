"""Growing modes that a step spans: where the step control cannot see the error.

On a step of length k from U_n, a mode of the Jacobian J = df/du with eigenvalue lambda,
Re lambda > 0, grows by exp(z), z = k lambda, in the exact flow, and by the method's
stability function R(z) in the discrete one (:func:`dolfinode.methods.method.
stability_function`): |R(z)| <= 1 for large z (L-stable dG(q) damps it to 0). Its amplitude
at U_n is the distance to the equilibrium along the mode, f(U_n) ~ J (U_n - U*) hence

    a = |w^T f(U_n)| / |lambda|,   w the mode's left eigenvector (w^T v = 1),

and the step's error in that mode is a |exp(z) - R(z)| v. The step control measures the
residual, which stays small while a sits below the tolerance: u' = 50 (u - 1) from
u0 = 1 + 1e-6 took one step to T = 1 and returned u = 1 where u(1) = 5e15 (dG(2), mdG(1),
cG(1), dG(0), unwarned), and u' = 1e100 u returned u(T) = 0. A run is warned where a step
with Re z > SPANNED misses more than MISSED x the tolerance (atol_i + rtol |U_i|) in a
mode. For a multi-adaptive run z is an eigenvalue of K J, K = diag(k_i) the components'
steps (k J for a shared step). The steps' Gershgorin bound max_i k_i (J_ii + sum_j |J_ij|)
selects the candidates, so that a run without growing modes pays one Jacobian per step.
"""
import numpy as np

from dolfinode.compile.signatures import call_rhs_rows
from dolfinode.methods.method import stability_function

#: A step spans a mode where Re z > SPANNED (the mode grows e-fold within the step).
SPANNED = 1.0
#: The step's error in a spanned mode is reported above MISSED x the tolerance (an error of
#: atol becoming 10 atol, as :data:`dolfinode.solve.LOST_GROWTH`).
MISSED = 10.0
#: At most MAX_CANDIDATES steps (the largest Gershgorin bounds) of a system with more than
#: MAX_DENSE components get a dense eigen-decomposition.
MAX_DENSE, MAX_CANDIDATES = 64, 32


def spanned_growth(sol, compiled, m, atol, rtol):
    """The step of ``sol`` (by the method ``m``, tolerances ``atol``, ``rtol``) that misses
    the most of a growing mode, as (t, z, ratio, i): its start time, z = k lambda, the error
    over the tolerance in the mode (log10: it may be past double precision) and the
    component i the mode moves most; None where no step misses more than MISSED x the
    tolerance (or ``sol`` has no history)."""
    if not sol.dense or sol.stats.get("time slabs", 0) == 0:
        return None
    times, steps = _steps(sol)
    U = np.ascontiguousarray(sol(times).T)
    data = np.empty((len(times), max(compiled.nnz, 1)))
    call_rhs_rows(compiled.jacobian.address, U, times, compiled.p, data)
    candidates = _candidates(compiled, data[:, :compiled.nnz], steps)
    if not candidates.size:
        return None
    J = np.zeros((candidates.size, compiled.N, compiled.N))
    rows = np.repeat(np.arange(compiled.N), np.diff(compiled.indptr))
    J[:, rows, compiled.indices] = data[candidates, :compiled.nnz]
    f = np.empty((candidates.size, compiled.N))
    call_rhs_rows(compiled.rhs.address, np.ascontiguousarray(U[candidates]), times[candidates],
                  compiled.p, f)
    worst = None
    num, den = stability_function(m)
    for c, Jc, fc in zip(candidates.tolist(), J, f):
        found = _missed(steps[c][:, None] * Jc, steps[c] * fc, U[c], atol, rtol, num, den)
        if found is not None and (worst is None or found[1] > worst[2]):
            worst = (float(times[c]), found[0], found[1], found[2], float(steps[c][found[2]]))
    return worst


def _steps(sol):
    """(times, steps): the start of every step and, per step, the step of each component
    there ((P, N); the shared step of a cG(q)/dG(q) run)."""
    if not sol.multi:
        t_start, k = sol.time_steps()
        return t_start, np.repeat(k[:, None], sol.ode.N, axis=1)
    ptr, t_start, t_end, _ = sol.elements()
    times = np.unique(t_start)
    steps = np.empty((times.size, sol.ode.N))
    for i in range(sol.ode.N):
        a, b = ptr[i], ptr[i + 1]
        at = np.clip(np.searchsorted(t_start[a:b], times, side="right") - 1, 0, b - a - 1)
        steps[:, i] = (t_end[a:b] - t_start[a:b])[at]
    return times, steps


def _candidates(compiled, data, steps):
    """The steps whose Gershgorin bound of Re z exceeds SPANNED, at most MAX_CANDIDATES
    (the largest bounds) for a system of more than MAX_DENSE components."""
    N = compiled.N
    rows = np.repeat(np.arange(N), np.diff(compiled.indptr))
    diagonal = rows == compiled.indices
    radius = np.where(diagonal, data, np.abs(data))  # J_ii + sum_{j != i} |J_ij| per row
    bound = np.zeros((len(data), N))
    np.add.at(bound.T, rows, radius.T)
    bound = np.max(steps * bound, axis=1)
    candidates = np.flatnonzero(bound > SPANNED)
    if N > MAX_DENSE and candidates.size > MAX_CANDIDATES:
        candidates = candidates[np.argsort(bound[candidates])[-MAX_CANDIDATES:]]
    return candidates


def _missed(Z, g, U, atol, rtol, num, den):
    """(z, log10 ratio, i) of the mode of ``Z`` = K J (Re z > SPANNED) whose step error
    a |exp(z) - R(z)| |v_i| / (atol_i + rtol |U_i|), a = |w^T K f| / |z| (``g`` = K f),
    is largest, where its ratio exceeds MISSED; None otherwise (and for a defective Z)."""
    with np.errstate(all="ignore"):
        z, V = np.linalg.eig(Z)
        try:
            W = np.linalg.inv(V)
        except np.linalg.LinAlgError:
            return None
        best = None
        for j in np.flatnonzero(z.real > SPANNED).tolist():
            amplitude = abs(W[j] @ g) / abs(z[j])
            # log|exp(z) - R(z)| = Re z + log|1 - R(z) exp(-z)|: finite past exp's range
            R = np.polyval(num[::-1], z[j]) / np.polyval(den[::-1], z[j])
            carried = R * np.exp(-z[j]) if z[j].real < 700 else 0.0
            gap = z[j].real + np.log(abs(1.0 - carried)) if np.isfinite(carried) else np.inf
            scale = np.abs(V[:, j]) / (atol + rtol * np.abs(U))
            i = int(np.argmax(scale))
            ratio = (np.log(amplitude * scale[i]) + gap) / np.log(10.0)
            if ratio > np.log10(MISSED) and (best is None or ratio > best[1]):
                best = (complex(z[j]), float(ratio), i)
    return best


def message(ode, m, found):
    """The ToleranceWarning's text for :func:`spanned_growth`'s ``found`` of a solve of
    ``ode`` by ``m``: the cause, and the step bound that resolves the mode, or where its
    growth to T is past double precision, that no step does."""
    t, z, ratio, i, k = found
    rate, name = z.real / k, ode.states[i].name
    family = "L-stable, damps it" if m.family == "dG" else "A-stable, does not grow it"
    growth = rate * (ode.T - t)
    size = f"{10 ** ratio:.3g} x" if ratio < 300 else f"10^{ratio:.3g} x"
    if growth > np.log(np.finfo(float).max):
        what = (f"exp(lambda (T - t)) = exp({growth:.3g}) is past double precision: no step "
                f"resolves it; check the model, its scaling or its parameters")
    else:
        what = (f"give maximum_time_step below 1 / lambda (e.g. {0.1 / rate:.3g}), or an "
                f"absolute_tolerance below the mode's amplitude")
    return (f"a growing mode of the Jacobian (rate lambda = {rate:.3g}, mostly in {name}) "
            f"spans the step k = {k:.3g} at t = {t:.6g} (k lambda = {z.real:.3g}): the exact "
            f"solution grows by exp({z.real:.3g}) over it where the discrete one ({m.name}, "
            f"{family}) does not, and the step control does not see it below the tolerance "
            f"(the step's error in that mode is {size} the tolerance). The solution "
            f"from t = {t:.6g} on may be wrong at any tolerance: {what}")
