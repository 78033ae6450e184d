"""Multi-adaptive benchmark: dolfinode mcG(q)/mdG(q) against cG(q)/dG(q) and scipy.solve_ivp.

Problems (all in one process, one run):

* Two weakly coupled oscillators, x1'' = -x1 + eps (x2 - x1), x2'' = -w^2 x2 + eps (x1 - x2),
  eps = 1e-3, w = 1000, (x1, v1, x2, v2)(0) = (1, 0, 1, 0), T = 10. Error: |x1(T) - ref| of the
  slow position only; reference: the matrix exponential (the system is linear), checked
  against dolfinode cG(4) at tolerance 1e-13.
* Mass-spring chain: N = 200 unit masses in 1D (reduced from 1000 to keep sympy's
  per-expression code generation short), unit springs between neighbours and to fixed walls,
  10 evenly spaced springs 1e6 times stiffer; x_i(0) = sin(pi i / (N + 1)), v(0) = 0, T = 10.
  Error: max_i |x_i(T) - ref_i| over all positions; reference: expm of the 2N x 2N matrix,
  checked against the modal solution from the SVD of W^(1/2) B (-K = B^T W B; eigh(-K) is
  ~1e-8 off in the low frequencies). A method that damps the 10 fast modes has the error of
  the slow modes alone, 2.0e-3, whatever its tolerance.
* Reaction front (Savcenco-Hundsdorfer-Verwer, DOLFIN's reaction benchmark):
  u' = eps u_xx + gamma u^2 (1 - u), eps = 0.01, gamma = 1000, finite differences on N points
  with homogeneous Neumann conditions (mirror ghost points), h = L / (N - 1), L = 5 N / 1000,
  u0 = 1 / (1 + exp(lam (x - 1))), lam = 0.5 sqrt(2 gamma / eps), T = 0.05 (quick: 0.01),
  N = 500 and 1000 (quick: 500). Error: max_i |u_i(T) - ref_i|; reference: scipy Radau with the
  sparse Jacobian at rtol = 1e-10, atol = 1e-12, checked against scipy DOP853 at rtol = 1e-12
  (dolfinode dG(3) at tolerance 1e-10 is reported too: it is only ~1e-6 accurate here).

Solvers: dolfinode mcG/mdG and cG/dG (tolerance = absolute_tolerance = TOL); scipy solve_ivp
(rtol = atol = TOL) with NumPy right-hand sides and analytic Jacobians (sparse for Radau/BDF,
banded for LSODA on the reaction front, dense for LSODA on the chain).

Timing: every run is preceded by probes, the same call on [t0, t0 + f (T - t0)] for
f in PROBE_FRACTIONS (after one untimed dolfinode call per method and problem), which warm up
the compiled loops and predict the cost of the full run by extrapolating the cost rate
between the last two probes; a run predicted to take more than RUN_LIMIT seconds (or,
mono-adaptive, more than maximum_steps slabs) is skipped. The full run then gives errors and
counts; if it took less than SINGLE_RUN seconds it is timed again, 3 to 7 times in interleaved
rounds (median; dolfinode.bench.runner.time_interleaved), otherwise that single run is the timing.
The time is the wall time of the dn.solve / solve_ivp call; kernel compile time is measured
on the first (cold) call per problem and reported separately. scipy runs are abandoned after
2 x RUN_LIMIT seconds, and a method abandoned at a looser tolerance is not tried at tighter
ones. Predictions are rough (within ~2x: the cost per unit time is not constant).

Usage::

    .venv/bin/python benchmarks/run_multiadaptive.py [--quick] [--output DIR] [--warm-cache]
"""
import argparse
import csv
import json
import math
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from dolfinode.bench import report
from dolfinode.bench.runner import RunTimeout, time_interleaved, with_deadline

MULTI = ["mcG(1)", "mcG(2)", "mdG(1)", "mdG(2)"]
MONO = ["cG(1)", "cG(2)", "dG(1)", "dG(2)"]
COUNTERPART = {"mcG(1)": "cG(1)", "mcG(2)": "cG(2)", "mdG(1)": "dG(1)", "mdG(2)": "dG(2)"}
PROBE_FRACTIONS = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 0.05)   # probes solve on [t0, t0 + f (T - t0)]
PROBE_STOP = 3.0             # a probe predicting over PROBE_STOP x RUN_LIMIT ends the probing
PROBE_MIN = 0.05             # seconds: shorter probes are dominated by per-call overheads
PROBE_TRANSIENT = 0.25       # seconds of start-up cost discounted before stopping early
RUN_LIMIT = {False: 22.0, True: 4.0}      # seconds (full, quick): longer runs are skipped
SINGLE_RUN = 5.0             # seconds: runs longer than this are timed once
MAXIMUM_STEPS = 10_000_000   # dolfinode's default maximum_steps (mono: time slabs)

CHAIN_N, CHAIN_STIFF, CHAIN_SPRINGS, CHAIN_T = 200, 1e6, 10, 10.0
OSC_EPS, OSC_W, OSC_T = 1e-3, 1000.0, 10.0
REACTION_EPS, REACTION_GAMMA = 0.01, 1000.0


def first_call(dn, ode):
    """The first dn.solve of a declaration (dG(1), tolerance 1e-2): kernel generation and C
    compile, or a load from the disk cache; called before anything else solves ``ode``."""
    from dolfinode.compile.cache import cache_directory

    folder = cache_directory()
    before = set(folder.rglob("*")) if folder.exists() else set()
    start = time.perf_counter()
    sol = dn.solve(ode, method="dG(1)", tolerance=1e-2)
    first = time.perf_counter() - start
    new = (set(folder.rglob("*")) - before) if folder.exists() else set()
    return {"N": ode.N, "first_call_s": first, "compile_time_s": sol.stats["compile time"],
            "cache": "cold (kernels generated and compiled)" if new
            else "warm (kernels loaded from disk cache)"}


# ----------------------------------------------------------------------------------------------
# Problems: dolfinode declaration, NumPy right-hand side and Jacobian for scipy, reference
# ----------------------------------------------------------------------------------------------

def oscillators(dn, quick):
    import scipy.linalg as sl
    import sympy as sp

    x1, v1, x2, v2, eps, w = sp.symbols("x1 v1 x2 v2 epsilon omega")
    ode = dn.ODE({x1: v1, v1: -x1 + eps * (x2 - x1), x2: v2, v2: -w**2 * x2 + eps * (x1 - x2)},
                 u0=[1.0, 0.0, 1.0, 0.0], T=OSC_T, params={eps: OSC_EPS, w: OSC_W})
    A = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-1.0 - OSC_EPS, 0.0, OSC_EPS, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [OSC_EPS, 0.0, -OSC_W**2 - OSC_EPS, 0.0]])
    compiled = first_call(dn, ode)
    y0 = ode.u0.copy()
    start = time.perf_counter()
    ref = sl.expm(A * OSC_T) @ y0
    check = dn.solve(ode, method="cG(4)", tolerance=1e-13)
    reference = {"method": "scipy.linalg.expm (exact for this linear system)",
                 "check": "dolfinode cG(4), tolerance 1e-13",
                 "check |x1 difference|": float(abs(check(OSC_T)[0] - ref[0])),
                 "check max difference, all components": float(np.max(np.abs(check(OSC_T)
                                                                             - ref))),
                 "seconds": time.perf_counter() - start}
    tols = [1e-4, 1e-6] if quick else [1e-4, 1e-6, 1e-8]
    return dict(name="oscillators", title=f"oscillators 1 : {OSC_W:g}, x1(T) error", ode=ode,
                T=OSC_T, y0=y0, rhs=lambda t, y: A @ y, jac=lambda t, y: A, ref=ref,
                error=lambda y: float(abs(y[0] - ref[0])), error_name="|x1(T) - ref|",
                error_all=lambda y: float(np.max(np.abs(y[[0, 2]] - ref[[0, 2]]))),
                methods=MULTI + MONO, scipy={"DOP853": {}, "LSODA": {"jac": lambda t, y: A}},
                tolerances=tols, reference=reference, compile=compiled,
                groups={"slow (x1)": [0], "fast (x2)": [2]})


def chain(dn, quick):
    import scipy.linalg as sl
    import scipy.sparse as sps
    import sympy as sp

    n = CHAIN_N
    stiff = [int((m + 0.5) * (n + 1) / CHAIN_SPRINGS) for m in range(CHAIN_SPRINGS)]
    k = np.ones(n + 1)          # spring j joins mass j-1 and mass j (masses 0..n-1; walls)
    k[stiff] = CHAIN_STIFF
    x = sp.symbols(f"x0:{n}")
    ks, kS = sp.symbols("k_soft k_stiff")
    ksym = [kS if j in stiff else ks for j in range(n + 1)]
    acc = {}
    for i in range(n):
        left = x[i - 1] - x[i] if i > 0 else -x[i]
        right = x[i + 1] - x[i] if i < n - 1 else -x[i]
        acc[x[i]] = ksym[i] * left + ksym[i + 1] * right
    x0 = np.sin(np.pi * np.arange(1, n + 1) / (n + 1))
    ode = dn.ODE.second_order(acc, x0=x0, v0=np.zeros(n), T=CHAIN_T,
                              params={ks: 1.0, kS: CHAIN_STIFF})
    K = sps.diags([-(k[:-1] + k[1:]), k[1:-1], k[1:-1]], [0, 1, -1], format="csr")
    A = sps.bmat([[None, sps.identity(n)], [K, None]], format="csr")
    Adense = A.toarray()
    compiled = first_call(dn, ode)
    y0 = ode.u0.copy()
    start = time.perf_counter()
    ref = sl.expm(Adense * CHAIN_T) @ y0
    # Check: -K = G^T G with G = W^(1/2) B (B: differences across the n + 1 springs, W: their
    # stiffnesses); with G = U diag(s) V^T, x(t) = V cos(s t) V^T x0 (v0 = 0). The SVD gives
    # the low frequencies s to eps ||G||, where eigh(-K) would give s^2 only to eps ||K||
    # (phase errors ~1e-8 here).
    B = sps.diags([np.ones(n), -np.ones(n)], [0, -1], shape=(n + 1, n)).toarray()
    _, sv, Vt = np.linalg.svd(np.sqrt(k)[:, None] * B, full_matrices=False)
    modal = Vt.T @ (np.cos(sv * CHAIN_T) * (Vt @ x0))
    slow_modes = sv < 100.0   # the stiff springs' modes oscillate at ~sqrt(2e6) = 1414
    only_slow = Vt[slow_modes].T @ (np.cos(sv[slow_modes] * CHAIN_T) * (Vt[slow_modes] @ x0))
    reference = {"method": "scipy.linalg.expm of the 2N x 2N matrix",
                 "check": "modal solution from the SVD of W^(1/2) B (-K = B^T W B)",
                 "check max |position difference|": float(np.max(np.abs(modal - ref[:n]))),
                 "seconds": time.perf_counter() - start,
                 "error of the slow modes alone (a method that damps the "
                 f"{int((~slow_modes).sum())} fast modes away)":
                 float(np.max(np.abs(only_slow - ref[:n])))}
    fast = sorted({i for j in stiff for i in (j - 1, j) if 0 <= i < n})
    slow = [i for i in range(n) if i not in fast]
    tols = [1e-4, 1e-6] if quick else [1e-4, 1e-6, 1e-8]
    return dict(name="chain", title=f"mass-spring chain, N = {n}, max position error",
                ode=ode, T=CHAIN_T, y0=y0, rhs=lambda t, y: A @ y, ref=ref,
                error=lambda y: float(np.max(np.abs(y[:n] - ref[:n]))),
                error_all=lambda y: float(np.max(np.abs(y[:n] - ref[:n]))),
                error_name="max_i |x_i(T) - ref_i|", methods=MULTI + MONO,
                scipy={"DOP853": {}, "LSODA": {"jac": lambda t, y: Adense}},
                tolerances=tols, reference=reference, compile=compiled,
                groups={f"slow ({len(slow)} masses, x and v)": slow + [n + i for i in slow],
                        f"fast ({len(fast)} masses at stiff springs, x and v)":
                        fast + [n + i for i in fast]},
                stiff_springs=stiff, damped_error=float(np.max(np.abs(only_slow - ref[:n]))))


def reaction(dn, n, T, quick):
    import scipy.sparse as sps
    import sympy as sp
    from scipy.integrate import solve_ivp
    from scipy.special import expit

    L = 5.0 * n / 1000.0
    h = L / (n - 1)
    lam = 0.5 * math.sqrt(2.0 * REACTION_GAMMA / REACTION_EPS)
    xs = np.linspace(0.0, L, n)
    u = sp.symbols(f"u0:{n}")
    e, g, h2 = sp.symbols("epsilon gamma h2")
    rhs = {}
    for i in range(n):
        left = u[i - 1] if i > 0 else u[1]            # mirror ghost points: u_{-1} = u_1,
        right = u[i + 1] if i < n - 1 else u[n - 2]   # u_n = u_{n-2}
        rhs[u[i]] = e * (left - 2 * u[i] + right) / h2 + g * u[i] ** 2 * (1 - u[i])
    u0 = expit(-lam * (xs - 1.0))     # 1 / (1 + exp(lam (x - 1))) without overflow
    ode = dn.ODE(rhs, u0=u0, T=T, params={e: REACTION_EPS, g: REACTION_GAMMA, h2: h * h})
    compiled = first_call(dn, ode)
    c = REACTION_EPS / (h * h)
    D = sps.diags([-2.0 * np.ones(n), np.ones(n - 1), np.ones(n - 1)], [0, 1, -1], format="lil")
    D[0, 1] = 2.0
    D[n - 1, n - 2] = 2.0
    D = (c * D).tocsr()
    sup = c * np.r_[2.0, np.ones(n - 2)]        # D[i, i+1]
    sub = c * np.r_[np.ones(n - 2), 2.0]        # D[i+1, i]

    def f(t, y):
        return D @ y + REACTION_GAMMA * y * y * (1.0 - y)

    def jac_sparse(t, y):
        return D + sps.diags(REACTION_GAMMA * (2.0 * y - 3.0 * y * y))

    def jac_banded(t, y):   # LSODA's packed format: J[i, j] at [1 + i - j, j]
        out = np.zeros((3, n))
        out[0, 1:] = sup
        out[1] = -2.0 * c + REACTION_GAMMA * (2.0 * y - 3.0 * y * y)
        out[2, :-1] = sub
        return out

    start = time.perf_counter()
    sol = solve_ivp(f, (0.0, T), u0, method="Radau", rtol=1e-10, atol=1e-12, jac=jac_sparse)
    if not sol.success:
        raise RuntimeError(f"reaction reference failed: {sol.message}")
    ref = sol.y[:, -1]
    seconds = time.perf_counter() - start
    check = solve_ivp(f, (0.0, T), u0, method="DOP853", rtol=1e-12, atol=1e-14)
    reference = {"method": "scipy Radau, sparse Jacobian, rtol 1e-10, atol 1e-12",
                 "seconds": seconds, "check": "scipy DOP853, rtol 1e-12, atol 1e-14",
                 "check max difference": float(np.max(np.abs(check.y[:, -1] - ref)))}
    tols = [1e-4, 1e-6]
    methods = ["mcG(1)", "mdG(1)", "cG(1)", "dG(1)"]
    return dict(name=f"reaction N={n}", title=f"reaction front, N = {n}, T = {T:g}, "
                "max error", ode=ode, T=T, y0=u0, rhs=f, ref=ref,
                error=lambda y: float(np.max(np.abs(y - ref))),
                error_all=lambda y: float(np.max(np.abs(y - ref))),
                error_name="max_i |u_i(T) - ref_i|", methods=methods,
                scipy={"Radau": {"jac": jac_sparse}, "BDF": {"jac": jac_sparse},
                       "LSODA": {"jac": jac_banded, "lband": 1, "uband": 1}},
                tolerances=tols, reference=reference, dolfinode_check=("dG(3)", 1e-10),
                compile=compiled,
                groups={"elsewhere": list(np.flatnonzero(np.abs(ref - u0) <= 1e-3)),
                        "front region (|u_i(T) - u0_i| > 1e-3)":
                        list(np.flatnonzero(np.abs(ref - u0) > 1e-3))})


# ----------------------------------------------------------------------------------------------
# Runs
# ----------------------------------------------------------------------------------------------

def base_row(problem, solver, method, tol):
    return {"problem": problem["name"], "N": problem["ode"].N, "solver": solver,
            "method": method, "multi_adaptive": method in MULTI, "tolerance": tol,
            "status": "ok", "note": "", "time_median_s": None, "time_min_s": None,
            "repeats": 0, "first_call_s": None, "dn_solve_time_s": None, "probe_s": None,
            "probe_fraction": None, "predicted_s": None, "mescd": None, "err_T": None,
            "err_all": None, "elements": None, "time_slabs": None, "f_evals": None,
            "component_evals": None, "efficiency_index": None, "ns_per_element": None,
            "rejected": None, "nonlinear_iterations": None, "newton": None,
            "elements_slow_mean": None, "elements_fast_mean": None, "elements_min": None,
            "elements_max": None}


def probe_deadline(frac, limit):
    return PROBE_TRANSIENT + PROBE_STOP * limit * frac


def predict(row, solve_span, limit):
    """Escalating probes: solve_span(fraction) solves on [t0, t0 + fraction (T - t0)] and
    returns its seconds (None: abandoned at probe_deadline). The last (largest) probe decides;
    a smaller one ends the escalation only if, less PROBE_TRANSIENT seconds (the start-up
    steps can cost far more than their share of the interval: mdG(1) on the oscillators
    spends 6% of its time in the first 0.1%), it still predicts more than PROBE_STOP x limit.
    Returns True to run in full."""
    spent, previous = 0.0, None
    for frac in PROBE_FRACTIONS:
        seconds = solve_span(frac)
        if seconds is None:
            row.update(status="skipped", note=f"probe on {frac:g} T abandoned after "
                       f"{probe_deadline(frac, limit):.2g} s (the full run would take over "
                       f"{PROBE_STOP:g} x {limit:g} s at that rate)")
            return False
        spent += seconds
        predicted = seconds / frac
        if previous is not None and seconds >= PROBE_MIN:
            # extrapolate the cost rate between the last two probes: neither the start-up
            # transient (often costlier) nor a cost rate that grows with t is averaged in
            rate = max(seconds - previous[1], 0.0) / (frac - previous[0])
            predicted = seconds + rate * (1.0 - frac)
        previous = (frac, seconds)
        row.update(probe_s=spent, probe_fraction=frac, predicted_s=predicted)
        if (seconds - PROBE_TRANSIENT) / frac > PROBE_STOP * limit:
            break
    if row["predicted_s"] > limit:
        row.update(status="skipped", note=f"predicted {row['predicted_s']:.3g} s > {limit:g} s "
                   f"(probe on {row['probe_fraction']:g} T: {seconds:.2g} s)")
        return False
    return True


def probe_ode(dn, problem, frac):
    """The declaration on the shorter interval [t0, t0 + frac (T - t0)] (lowered on first use,
    from the in-memory kernel table: no recompilation)."""
    key = ("_probe", frac)
    if key not in problem:
        ode = problem["ode"]
        problem[key] = dn.ODE(list(zip(ode.states, ode.rhs)), u0=ode.u0, params=ode.params,
                              t0=ode.t0, T=ode.t0 + frac * (ode.T - ode.t0))
    return problem[key]


def run_dolfinode(dn, problem, method, tol, limit):
    """Probes, then one full run for errors and counts. Returns (row, call for re-timing)."""
    row = base_row(problem, "dolfinode", method, tol)
    ode = problem["ode"]
    slabs = {}
    warm = problem.setdefault("_warm", set())
    if method not in warm:   # the first call of a method on a problem costs up to ~0.1 s more
        dn.solve(probe_ode(dn, problem, PROBE_FRACTIONS[0]), method=method, tolerance=1e-2)
        warm.add(method)

    def solve_span(frac):
        st = dn.solve(probe_ode(dn, problem, frac), method=method, tolerance=tol).stats
        slabs["predicted"] = st["time slabs"] / frac
        return st["solve time"]   # the stepping loop: no lowering, no sampling

    try:
        go = predict(row, solve_span, limit)
    except Exception as exc:
        row.update(status="failed", note=f"probe: {type(exc).__name__}: {exc}")
        return row, None
    if not go:
        return row, None
    if method not in MULTI and slabs["predicted"] > MAXIMUM_STEPS:
        row.update(status="skipped", note=f"predicted {slabs['predicted']:.2g} time slabs > "
                   f"maximum_steps = {MAXIMUM_STEPS:.0e}")
        return row, None
    try:
        start = time.perf_counter()
        sol = dn.solve(ode, method=method, tolerance=tol)
        row["first_call_s"] = time.perf_counter() - start
    except Exception as exc:
        row.update(status="failed", note=f"{type(exc).__name__}: {exc}")
        return row, None
    st = sol.stats
    n = ode.N
    y = sol(ode.T)
    row.update(err_T=problem["error"](y), err_all=problem["error_all"](y),
               elements=st["elements"], time_slabs=st["time slabs"], f_evals=st["f evaluations"],
               component_evals=st["f evaluations"] * (1 if method in MULTI else n),
               efficiency_index=st.get("efficiency index"), rejected=st["rejected steps"],
               nonlinear_iterations=st["nonlinear iterations"], newton=st["newton"])
    per = st.get("elements per component")
    if per is None:
        per = np.full(n, st["time slabs"])
    groups = list(problem["groups"].values())
    row.update(elements_slow_mean=float(np.mean(per[groups[0]])),
               elements_fast_mean=float(np.mean(per[groups[1]])),
               elements_min=int(per.min()), elements_max=int(per.max()))
    if method in MULTI and n <= 8:
        row["elements_per_component"] = [int(e) for e in per]
    row.update(time_median_s=row["first_call_s"], time_min_s=row["first_call_s"],
               dn_solve_time_s=st["solve time"], repeats=1)
    if row["first_call_s"] > SINGLE_RUN:
        row["note"] = f"single timed run (> {SINGLE_RUN:g} s)"
        return row, None
    return row, lambda: dn.solve(ode, method=method, tolerance=tol).stats["solve time"]


def run_scipy(problem, method, tol, limit, skip_reason=None):
    from scipy.integrate import solve_ivp

    row = base_row(problem, "scipy", method, tol)
    if skip_reason:
        row.update(status="skipped", note=skip_reason)
        return row, None
    kwargs = problem["scipy"][method]
    t0, T, y0 = problem["ode"].t0, problem["T"], problem["y0"]

    def call(fun, end=T):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = solve_ivp(fun, (t0, end), y0, method=method, rtol=tol, atol=tol, **kwargs)
        return res, caught

    def solve_span(frac):
        fun, _ = with_deadline(problem["rhs"], probe_deadline(frac, limit))
        start = time.perf_counter()
        try:
            call(fun, t0 + frac * (T - t0))
        except RunTimeout:
            return None
        return time.perf_counter() - start

    try:
        go = predict(row, solve_span, limit)
    except Exception as exc:
        row.update(status="failed", note=f"probe: {type(exc).__name__}: {exc}")
        return row, None
    if not go:
        return row, None
    fun, last = with_deadline(problem["rhs"], 2 * limit)
    try:
        start = time.perf_counter()
        res, caught = call(fun)
        row["first_call_s"] = time.perf_counter() - start
    except RunTimeout:
        row.update(status="skipped", note=f"over {2 * limit:g} s (abandoned at t = "
                   f"{last[0]:.4g} of {T:g})")
        return row, None
    except Exception as exc:
        row.update(status="failed", note=f"{type(exc).__name__}: {exc}")
        return row, None
    if not res.success:
        row.update(status="failed", note=f"solve_ivp: {res.message}")
        return row, None
    if caught:
        row["note"] = "; ".join(sorted({str(w.message).split("\n")[0] for w in caught}))
    n = len(y0)
    steps = len(res.t) - 1
    y = res.y[:, -1]
    row.update(err_T=problem["error"](y), err_all=problem["error_all"](y), time_slabs=steps,
               elements=steps * n, f_evals=int(res.nfev), component_evals=int(res.nfev) * n,
               time_median_s=row["first_call_s"], time_min_s=row["first_call_s"], repeats=1)
    if row["first_call_s"] > SINGLE_RUN:
        row["note"] = (row["note"] + "; " if row["note"] else "") + \
            f"single timed run (> {SINGLE_RUN:g} s)"
        return row, None

    def timed():
        call(problem["rhs"])

    return row, timed


def progress(row, timed=False):
    head = (f"[{row['problem']}] {row['solver']:9s} {row['method']:6s} "
            f"tol={row['tolerance']:.0e}")
    if row["status"] != "ok":
        print(f"{head}: {row['status'].upper()} {row['note']}", flush=True)
        return
    if timed:
        print(f"{head}: {report.fmt_s(row['time_median_s']):>9s} median of {row['repeats']}",
              flush=True)
        return
    extra = ""
    if row["efficiency_index"] is not None:
        extra = (f", efficiency index {row['efficiency_index']:.2f}, elements per component "
                 f"{row['elements_min']}..{row['elements_max']}")
    probe_s = (f" (probes {report.fmt_s(row['probe_s'])}, predicted "
               f"{report.fmt_s(row['predicted_s'])})" if row["probe_s"] is not None else "")
    print(f"{head}: {report.fmt_s(row['first_call_s']):>9s}{probe_s}, error {row['err_T']:.2e}, "
          f"elements {row['elements']}, f evals {row['f_evals']}{extra}", flush=True)


def finish_row(row):
    if row["status"] == "ok" and row["elements"]:
        t = row["dn_solve_time_s"] if row["solver"] == "dolfinode" else row["time_median_s"]
        row["ns_per_element"] = 1e9 * t / row["elements"]


# ----------------------------------------------------------------------------------------------
# Headline
# ----------------------------------------------------------------------------------------------

def ok(rows, problem, solver=None, method=None):
    return [r for r in rows if r["problem"] == problem and r["status"] == "ok"
            and (solver is None or r["solver"] == solver)
            and (method is None or r["method"] == method)]


def best_at(rows, problem, solver, methods, error):
    """(method, time, clamped) of the fastest of `methods` reaching `error`, with log10(time)
    interpolated in -log10(error) over each method's Pareto front (dolfinode.bench.report's rule), or
    None when none reaches it."""
    level = -math.log10(max(error, 1e-300))
    best = None
    for m in methods:
        c = report.curve(rows, problem, m)
        hit = report.time_at(c, level)
        if hit is not None and (best is None or hit[0] < best[1]):
            best = (m, hit[0], hit[1])
    return best


def headline(rows, problem):
    name = problem["name"]
    out = []
    for multi in [m for m in problem["methods"] if m in MULTI]:
        mono = COUNTERPART[multi]
        both = sorted({r["tolerance"] for r in ok(rows, name, "dolfinode", multi)}
                      & {r["tolerance"] for r in ok(rows, name, "dolfinode", mono)})
        entry = {"multi": multi, "mono": mono, "tolerance": None}
        mruns = ok(rows, name, "dolfinode", multi)
        if not mruns:
            first = [r for r in rows if r["problem"] == name and r["method"] == multi]
            entry["note"] = f"{first[0]['status']} at {first[0]['tolerance']:.0e}: " \
                f"{first[0]['note']}" if first else "not run"
        if both:
            tol = min(both)
            rm = [r for r in mruns if r["tolerance"] == tol][0]
            rn = [r for r in ok(rows, name, "dolfinode", mono) if r["tolerance"] == tol][0]
            entry.update(tolerance=tol, multi_time_s=rm["time_median_s"],
                         mono_time_s=rn["time_median_s"],
                         time_ratio=rm["time_median_s"] / rn["time_median_s"],
                         multi_error=rm["err_T"], mono_error=rn["err_T"],
                         element_ratio=rm["elements"] / rn["elements"],
                         multi_ns_per_element=rm["ns_per_element"],
                         mono_ns_per_element=rn["ns_per_element"],
                         slow_fast=(rm["elements_slow_mean"] / rm["elements_fast_mean"]
                                    if rm["elements_fast_mean"] else None))
        if mruns:   # the multi-adaptive method's most accurate run at equal error
            rm = min(mruns, key=lambda r: r["tolerance"])
            entry.update(eq_tolerance=rm["tolerance"], eq_error=rm["err_T"],
                         eq_multi_time_s=rm["time_median_s"])
            mono_eq = best_at(rows, name, "dolfinode", [mono], rm["err_T"])
            if mono_eq:
                entry.update(mono_eq_time_s=mono_eq[1], mono_eq_clamped=mono_eq[2],
                             mono_eq_ratio=rm["time_median_s"] / mono_eq[1])
            best = best_at(rows, name, "scipy", problem["scipy"], rm["err_T"])
            if best:
                entry.update(scipy_best=best[0], scipy_time_s=best[1], scipy_clamped=best[2],
                             scipy_ratio=rm["time_median_s"] / best[1])
        out.append(entry)
    return out


def x_text(x):
    """A time ratio as 'N x slower' / 'N x faster'."""
    return f"{x:.3g}x slower" if x >= 1 else f"{1 / x:.3g}x faster"


def summary_line(problem, entries):
    """One sentence per problem: multi / mono at the tightest common tolerance."""
    parts = []
    for e in entries:
        if e["tolerance"] is not None:
            parts.append(f"{e['multi']}/{e['mono']} {x_text(e['time_ratio'])} "
                         f"({report.fmt_s(e['multi_time_s'])} vs {report.fmt_s(e['mono_time_s'])} at "
                         f"tolerance {e['tolerance']:.0e})")
        else:
            parts.append(f"{e['multi']}/{e['mono']}: no common tolerance")
    text = f"{problem['name']}: " + ", ".join(parts)
    ratios = [f"{e['multi']} 1 : {1 / e['slow_fast']:.0f}" for e in entries
              if e.get("slow_fast") and problem["name"] == "oscillators"]
    if ratios:
        text += "; elements slow (x1) : fast (x2): " + ", ".join(ratios)
    return text


def damped(problem, row):
    """Whether a run's error is the amplitude of the fast modes, i.e. it damped them away."""
    ref = problem.get("damped_error")
    return ref is not None and row["err_T"] is not None and abs(row["err_T"] - ref) < 0.01 * ref


def notes_for(problem, entries, rows):
    name = problem["name"]
    parts = []
    costs = [f"{e['multi']} uses x{e['element_ratio']:.2g} the elements of {e['mono']} at "
             f"{e['multi_ns_per_element']:,.0f} ns per element against "
             f"{e['mono_ns_per_element']:,.0f}" for e in entries if e["tolerance"] is not None]
    if costs:
        parts.append("at the tightest common tolerance " + "; ".join(costs))
    skipped = [f"{e['multi']} ({e['note']})" for e in entries if e.get("note")]
    if skipped:
        parts.append("no run of " + "; ".join(skipped))
    if name == "oscillators":
        ratios = [f"{e['multi']} 1 : {1 / e['slow_fast']:.0f}" for e in entries
                  if e.get("slow_fast")]
        parts.append("elements of the slow x1 : fast x2 at that tolerance: " + ", ".join(ratios))
        lost = [f"{r['method']} at {r['tolerance']:.0e}" for r in ok(rows, name, "dolfinode")
                if r["err_all"] > 0.5]
        if lost:
            parts.append("runs with x2(T) wrong by more than 0.5 (its amplitude is 1: the fast "
                         "oscillation is damped (dG) or out of phase), x1 still accurate: "
                         + ", ".join(lost))
    if problem.get("damped_error") is not None:
        lost = [f"{r['solver'] + ' ' if r['solver'] == 'scipy' else ''}{r['method']} at "
                f"{r['tolerance']:.0e}" for r in ok(rows, name) if damped(problem, r)]
        if lost:
            parts.append(f"error {problem['damped_error']:.3g} = that of the slow modes alone "
                         "(the fast modes, amplitude ~2e-3 per mass, damped away, as an L-stable "
                         "dG method does on steps much longer than their period 4.4e-3): "
                         + ", ".join(lost) + "; equal-error comparisons at this level compare "
                         "damped solutions")
    return f"**{name}**: " + "; ".join(parts) + "." if parts else ""


def summary_table(problems, heads):
    lines = ["| problem | multi / mono | tightest common tol | multi time | mono time | "
             "**multi / mono** | error multi, mono | at multi's best error: multi / mono | "
             "multi / best scipy |", "|" + "---|" * 9]
    for p in problems:
        for e in heads[p["name"]]:
            pair = f"{e['multi']} / {e['mono']}"
            if e["tolerance"] is not None:
                cells = [f"{e['tolerance']:.0e}", report.fmt_s(e["multi_time_s"]),
                         report.fmt_s(e["mono_time_s"]), f"**{x_text(e['time_ratio'])}**",
                         f"{e['multi_error']:.1e}, {e['mono_error']:.1e}"]
            else:
                cells = ["-", "-", "-", "-", "-"]
            if e.get("eq_error") is not None:
                cells.append((f"{x_text(e['mono_eq_ratio'])}"
                              f"{' *' if e['mono_eq_clamped'] else ''}"
                              if e.get("mono_eq_ratio") else f"{e['mono']} never as accurate")
                             + f" (error {e['eq_error']:.1e})")
                cells.append(f"{x_text(e['scipy_ratio'])} ({e['scipy_best']}"
                             f"{' *' if e['scipy_clamped'] else ''})"
                             if e.get("scipy_best") else "no scipy run as accurate")
            else:
                cells += [e.get("note", "-"), "-"]
            lines.append("| " + " | ".join([p["name"], pair] + cells) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Outputs
# ----------------------------------------------------------------------------------------------

CSV_FIELDS = list(base_row({"name": "", "ode": type("O", (), {"N": 0})()}, "", "", 0.0).keys())


def write_csv(path, rows):
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_FIELDS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if r[k] is None else r[k]) for k in CSV_FIELDS})


def plot(path, rows, problems):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = plt.get_cmap("tab10").colors
    styles = {}
    for i, m in enumerate(MULTI):
        styles[m] = dict(color=colors[i], marker="o", linestyle="-", linewidth=1.8)
        styles[COUNTERPART[m]] = dict(color=colors[i], marker="^", linestyle="--",
                                      linewidth=1.1, markerfacecolor="none")
    for i, m in enumerate(["DOP853", "LSODA", "Radau", "BDF"]):
        styles[m] = dict(color=("0.1", "0.45", colors[5], colors[6])[i], marker="s",
                         linestyle=":", linewidth=1.1)
    ncol = 2
    nrow = (len(problems) + 1) // 2
    fig, axes = plt.subplots(nrow, ncol, figsize=(12.4, 5.0 * nrow), squeeze=False)
    seen = {}
    for ax, problem in zip(axes.ravel(), problems):
        name = problem["name"]
        for solver, methods in (("dolfinode", problem["methods"]),
                                ("scipy", list(problem["scipy"]))):
            for m in methods:
                pts = sorted(ok(rows, name, solver, m), key=lambda r: -r["tolerance"])
                if not pts:
                    continue
                label = f"dolfinode {m}" if solver == "dolfinode" else f"scipy {m}"
                line, = ax.loglog([r["err_T"] for r in pts], [r["time_median_s"] for r in pts],
                                  label=label, markersize=5, **styles[m])
                seen.setdefault(label, line)
        if problem.get("damped_error") is not None:
            ax.axvline(problem["damped_error"], color="0.5", linewidth=0.9, linestyle="-.")
            ax.annotate("fast modes damped", (problem["damped_error"], 0.98),
                        xycoords=("data", "axes fraction"), rotation=90, fontsize=8,
                        ha="right", va="top", color="0.4")
        ax.set_xlabel(f"error at T, {problem['error_name']}")
        ax.set_ylabel("wall time per solve [s]")
        ax.set_title(problem["title"], fontsize=10)
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.12)
        ax.invert_xaxis()
    for ax in axes.ravel()[len(problems):]:
        ax.axis("off")
    order = [f"dolfinode {m}" for m in MULTI + MONO] + \
        [f"scipy {m}" for m in ["DOP853", "LSODA", "Radau", "BDF"]]
    labels = [lab for lab in order if lab in seen]
    fig.legend([seen[lab] for lab in labels], labels, loc="lower center", ncol=6, fontsize=9,
               frameon=False)
    fig.suptitle("Work-precision: multi-adaptive mcG/mdG (solid) vs mono-adaptive cG/dG "
                 "(dashed, same colour) vs scipy (dotted); right = more accurate, lower = faster",
                 fontsize=10.5)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def md_table(rows, problem):
    name = problem["name"]
    head = ["solver", "method", "tol", "time (median)", "reps", "error", "error, all positions",
            "elements", "slabs",
            "f evals", "component evals", "eff. index", "ns/element", "elements slow : fast",
            "rejected", "nonlin. it."]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def n(x, fmt="{}"):
        return "-" if x is None else fmt.format(x)

    for r in rows:
        if r["problem"] != name:
            continue
        if r["status"] != "ok":
            cells = [r["solver"], r["method"], f"{r['tolerance']:.0e}",
                     f"{r['status']}: {r['note']}"] + [""] * (len(head) - 4)
        else:
            ratio = "-"
            if r["solver"] == "dolfinode" and r["elements_fast_mean"]:
                ratio = f"{r['elements_slow_mean']:.4g} : {r['elements_fast_mean']:.4g}"
            cells = [r["solver"], r["method"], f"{r['tolerance']:.0e}",
                     report.fmt_s(r["time_median_s"]), str(r["repeats"]),
                     f"{r['err_T']:.2e}" + (" (damped)" if damped(problem, r) else ""),
                     f"{r['err_all']:.2e}",
                     n(r["elements"]), n(r["time_slabs"]), n(r["f_evals"]),
                     n(r["component_evals"]), n(r["efficiency_index"], "{:.2f}"),
                     n(r["ns_per_element"], "{:.3g}"), ratio, n(r["rejected"]),
                     n(r["nonlinear_iterations"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def headline_table(entries):
    lines = ["| multi | mono | tol | multi time | mono time | time ratio | multi error | "
             "mono error | element ratio | ns/element multi : mono | multi's most accurate run "
             "(tol, error, time) | mono time at that error | multi / mono | best scipy at that "
             "error | multi / scipy |", "|" + "---|" * 15]

    def t(x, clamped):
        return report.fmt_s(x) + (" *" if clamped else "")

    for e in entries:
        if e["tolerance"] is not None:
            cells = [e["multi"], e["mono"], f"{e['tolerance']:.0e}", report.fmt_s(e["multi_time_s"]),
                     report.fmt_s(e["mono_time_s"]), f"{e['time_ratio']:.3g}",
                     f"{e['multi_error']:.2e}", f"{e['mono_error']:.2e}",
                     f"{e['element_ratio']:.3g}",
                     f"{e['multi_ns_per_element']:,.0f} : {e['mono_ns_per_element']:,.0f}"]
        else:
            cells = [e["multi"], e["mono"], "-", "-", "-", "no common tolerance", "-", "-", "-",
                     "-"]
        if e.get("eq_error") is None:
            cells += ["no run", "-", "-", "-", "-"]
        else:
            cells.append(f"{e['eq_tolerance']:.0e}, {e['eq_error']:.2e}, "
                         f"{report.fmt_s(e['eq_multi_time_s'])}")
            if e.get("mono_eq_ratio"):
                cells += [t(e["mono_eq_time_s"], e["mono_eq_clamped"]),
                          f"{e['mono_eq_ratio']:.3g}"]
            else:
                cells += ["not reached", "-"]
            if e.get("scipy_best"):
                cells += [f"{e['scipy_best']} {t(e['scipy_time_s'], e['scipy_clamped'])}",
                          f"{e['scipy_ratio']:.3g}"]
            else:
                cells += ["not reached", "-"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_markdown(path, meta, rows, problems, heads, compile_info, notes, png_name):
    out = ["# Multi-adaptive benchmark (work in progress)", "",
           f"Date: {meta['date']}  ",
           f"Machine: {meta['platform']}, {meta['cpu']}, {meta['cpu_count']} CPUs  ",
           f"Versions: Python {meta['python']}, numpy {meta['numpy']}, scipy {meta['scipy']}, "
           f"numba {meta['numba']}, sympy {meta['sympy']}, dolfinode {meta['dolfinode']} "
           f"(git {meta['git_commit'] or '?'}, with uncommitted changes if any)  ",
           f"Command: `{meta['command']}` ({'quick' if meta['quick'] else 'full'} run, "
           f"{meta['total_seconds']:.0f} s in total)", "",
           "## Headline", "",
           "Wall time of the multi-adaptive method over its mono-adaptive counterpart at the "
           "tightest tolerance both ran, and at equal error (the multi-adaptive method's most "
           "accurate run; * = the other method's loosest run was already more accurate, its "
           "time is used):", "", summary_table(problems, heads), "", *[f"* {s}" for s in notes],
           "",
           f"![work-precision]({png_name})", "",
           "## Problems", "",
           f"* **oscillators**: x1'' = -x1 + eps (x2 - x1), x2'' = -w^2 x2 + eps (x1 - x2), "
           f"eps = {OSC_EPS:g}, w = {OSC_W:g}, (x1, v1, x2, v2)(0) = (1, 0, 1, 0), "
           f"T = {OSC_T:g}. Error: |x1(T) - ref| (slow position only).",
           f"* **chain**: N = {CHAIN_N} unit masses (reduced from the 1000 of the original "
           "problem statement: dolfinode generates and compiles C code per expression, so the "
           "one-off compile grows with N), unit springs between neighbours and to fixed walls "
           f"at both ends, {CHAIN_SPRINGS} evenly spaced springs {CHAIN_STIFF:g} times stiffer, "
           f"x_i(0) = sin(pi i / (N + 1)), v(0) = 0, T = {CHAIN_T:g}, declared with "
           "`dn.ODE.second_order` (2N = 400 components). Error: max over all positions at T.",
           f"* **reaction**: u' = eps u_xx + gamma u^2 (1 - u), eps = {REACTION_EPS:g}, "
           f"gamma = {REACTION_GAMMA:g}, N points, h = L/(N - 1), L = 5 N / 1000, mirror ghost "
           "points (Neumann), u0 = 1 / (1 + exp(lam (x - 1))), lam = 0.5 sqrt(2 gamma / eps); "
           f"T = {problems[-1]['T']:g}. Error: max over all components at T.", "",
           "## How it is measured", "",
           "* Tolerances: dolfinode `tolerance` = TOL (`absolute_tolerance` = TOL, the "
           "default); scipy `solve_ivp` rtol = atol = TOL.",
           "* Time: wall time of the whole `dn.solve(...)` / `solve_ivp(...)` call. Each run "
           "is preceded by probes, the same call on [0, f T] for f = "
           f"{', '.join(f'{f:g}' for f in PROBE_FRACTIONS)} (stopping early once a probe, "
           f"less {PROBE_TRANSIENT:g} s for the start-up, predicts more than {PROBE_STOP:g} x "
           "the run limit), after one untimed call per method and problem: they warm up the "
           "compiled "
           "loops and predict the full run by extrapolating the cost rate between the last two "
           "probes (or as probe time / f while probes take under "
           f"{PROBE_MIN:g} s; dolfinode: the probes' `stats['solve time']`); runs predicted over "
           f"{meta['run_limit_s']:g} s are skipped. Then one full run gives errors and counts; "
           f"runs under {SINGLE_RUN:g} s are re-timed "
           f"{'once' if meta['quick'] else '3-7 times in interleaved rounds (median)'}, longer "
           "ones keep that single time. Kernel compile time is excluded (table below).",
           "* error: the problem's error measure (above); error, all positions: the same over "
           "every position (oscillators: x1 and x2; a method that damps the fast oscillation "
           "has an error of its amplitude, 1, there).",
           "* elements: dolfinode multi-adaptive: total elements over all components; "
           "mono-adaptive: time slabs x N; scipy: accepted steps x N.",
           "* f evals: multi-adaptive: evaluations of single components f_i; mono-adaptive and "
           "scipy: evaluations of the full vector f. component evals: multi f evals, mono/scipy "
           "f evals x N.",
           "* ns/element: dolfinode `stats['solve time']` (the compiled stepping loop, without "
           "the sampling around it) / elements; scipy: wall time / elements.",
           "* elements slow : fast: mean elements per component over the slow and the fast "
           "group (oscillators: x1 vs x2; chain: masses away from vs at the stiff springs; "
           "reaction: components away from vs in the region the front crosses).",
           "* Headline ratios: multi-adaptive / mono-adaptive wall time at the tightest "
           "tolerance both ran (at equal tolerance the mono-adaptive method is usually much "
           "more accurate on the slow components, since its shared step follows the fast "
           "ones); and at equal error: the multi-adaptive method's most accurate run against "
           "its mono-adaptive counterpart and the fastest scipy method, with log10(time) "
           "interpolated in -log10(error) over that method's tolerance sweep "
           "(dolfinode.bench.report's rule; * = its loosest run was already more accurate, its "
           "time is used).", "",
           "## References", ""]
    for p in problems:
        out.append(f"* {p['name']}: " + ", ".join(
            f"{k} = {v:.3g}" if isinstance(v, float) else f"{k}: {v}"
            for k, v in p["reference"].items()))
    out += ["", "## One-off costs (not in the timings)", "",
            f"* `import dolfinode`: {report.fmt_s(meta['import_seconds'])}; loading (or, after a "
            "change, JIT-compiling) the multi-adaptive loop, `from dolfinode.timeslab import "
            f"multi`: {report.fmt_s(meta['multi_import_seconds'])}.", "",
            "| problem | N | first call wall | stats['compile time'] | kernel cache |",
            "|---|---|---|---|---|"]
    for name, c in compile_info.items():
        out.append(f"| {name} | {c['N']} | {report.fmt_s(c['first_call_s'])} | "
                   f"{report.fmt_s(c['compile_time_s'])} | {c['cache']} |")
    for p in problems:
        out += ["", f"## {p['name']}", "", "### Multi vs mono (tightest common tolerance) and "
                "vs scipy", "", headline_table(heads[p["name"]]), "", "### All runs", "",
                md_table(rows, p)]
    out.append("")
    Path(path).write_text("\n".join(out))


# ----------------------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="fewer tolerances and problems, single timed runs, 4 s run limit")
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"),
                        help="output folder (default doc/benchmarks)")
    parser.add_argument("--warm-cache", action="store_true",
                        help="use the configured kernel cache (DOLFINODE_CACHE_DIR) instead of "
                             "a fresh one, so the reported compile time may be a cache load")
    args = parser.parse_args(argv)
    wall_start = time.perf_counter()
    out_dir = Path(args.output).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    limit = RUN_LIMIT[args.quick]

    fresh_cache = None
    if not args.warm_cache:
        fresh_cache = tempfile.mkdtemp(prefix="dolfinode-bench-cache-")
        os.environ["DOLFINODE_CACHE_DIR"] = fresh_cache
    sys.path.insert(0, str(ROOT))
    start = time.perf_counter()
    import dolfinode as dn
    from dolfinode.compile.cache import cache_directory
    import_seconds = time.perf_counter() - start
    start = time.perf_counter()
    from dolfinode.timeslab import multi
    multi_import_seconds = time.perf_counter() - start
    print(f"import dolfinode: {import_seconds:.2f} s, multi-adaptive loop: "
          f"{multi_import_seconds:.2f} s; kernel cache {cache_directory()}"
          f"{' (fresh)' if fresh_cache else ''}", flush=True)

    builders = [lambda: oscillators(dn, args.quick), lambda: chain(dn, args.quick)]
    reaction_T = 0.01 if args.quick else 0.05
    for n in ([500] if args.quick else [500, 1000]):
        builders.append(lambda n=n: reaction(dn, n, reaction_T, args.quick))

    rows, jobs, problems, compile_info = [], [], [], {}
    try:
        for build in builders:
            start = time.perf_counter()
            problem = build()
            name = problem["name"]
            compile_info[name] = problem["compile"]
            check = problem.get("dolfinode_check")
            if check:   # for information: dolfinode's high order at a tight tolerance
                m, tol = check
                c = dn.solve(problem["ode"], method=m, tolerance=tol)
                problem["reference"][f"dolfinode {m} at tolerance {tol:g}: error"] = \
                    problem["error"](c(problem["T"]))
            problems.append(problem)
            print(f"[{name}] N = {problem['ode'].N}: set-up and reference "
                  f"{time.perf_counter() - start:.1f} s, first call "
                  f"{compile_info[name]['first_call_s']:.2f} s (compile "
                  f"{compile_info[name]['compile_time_s']:.2f} s, {compile_info[name]['cache']}); "
                  f"reference: {problem['reference']}", flush=True)
            for method in problem["methods"]:
                for tol in problem["tolerances"]:
                    row, call = run_dolfinode(dn, problem, method, tol, limit)
                    rows.append(row)
                    jobs += [(row, call)] if call else []
                    progress(row)
            for method in problem["scipy"]:
                skip = None
                for tol in problem["tolerances"]:
                    row, call = run_scipy(problem, method, tol, limit, skip)
                    rows.append(row)
                    jobs += [(row, call)] if call else []
                    progress(row)
                    if row["status"] == "skipped" and skip is None:
                        skip = f"over {limit:g} s at a looser tolerance"
        print(f"re-timing {len(jobs)} runs under {SINGLE_RUN:g} s in interleaved rounds "
              f"({'1 round' if args.quick else 'median of 3-7'})", flush=True)
        time_interleaved(jobs, 1 if args.quick else 5, 0.5)
        for row, _ in jobs:
            progress(row, timed=True)
    finally:
        if fresh_cache:
            shutil.rmtree(fresh_cache, ignore_errors=True)
    for row in rows:
        finish_row(row)

    heads = {p["name"]: headline(rows, p) for p in problems}
    summary = [summary_line(p, heads[p["name"]]) for p in problems]
    notes = [notes_for(p, heads[p["name"]], rows) for p in problems]
    notes = [n for n in notes if n]

    meta = report.machine_info()
    meta.update(quick=args.quick, run_limit_s=limit, import_seconds=import_seconds,
                multi_import_seconds=multi_import_seconds,
                command="python benchmarks/run_multiadaptive.py" +
                (" --quick" if args.quick else ""),
                kernel_cache="fresh temporary" if fresh_cache else "configured")
    write_csv(out_dir / "multiadaptive.csv", rows)
    plot(out_dir / "multiadaptive.png", rows, problems)
    meta["total_seconds"] = time.perf_counter() - wall_start
    refs = {p["name"]: p["reference"] for p in problems}
    (out_dir / "multiadaptive.json").write_text(json.dumps(
        {"meta": meta, "references": refs, "compile": compile_info, "headline": heads,
         "summary": summary, "notes": notes, "runs": rows}, indent=1, default=float))
    write_markdown(out_dir / "multiadaptive.md", meta, rows, problems, heads, compile_info,
                   notes, "multiadaptive.png")
    for s in summary:
        print(s, flush=True)
    print(f"wrote {out_dir}/multiadaptive.{{csv,json,png,md}} in {meta['total_seconds']:.0f} s",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
