"""Work-precision benchmark: dolfinode cG(q)/dG(q) against scipy.integrate.solve_ivp.

Problems (all in one process, one run):

* HIRES (Test Set, n = 8, stiff) on [0, 321.8122]; reference at T = problems.HIRES_REFERENCE,
  reference trajectory on 100 equispaced points from scipy Radau at rtol = 1e-12, atol = 1e-16.
* Harmonic oscillator u' = v, v' = -u on [0, 100]; exact solution (sin t, cos t).

Solvers: dolfinode cG(1..3), dG(1..3) over tolerance = 1e-3 ... 1e-10 (absolute_tolerance =
tolerance, the default); scipy Radau, BDF, LSODA, DOP853 over rtol = atol = 1e-3 ... 1e-10 with
hand-written NumPy right-hand sides and analytic Jacobians (scipy's best case).

Errors: HIRES mescd (Test Set, atol/rtol = 1) and max |y(T) - ref|; harmonic max |y(T) - exact|;
for both an L2 error = root mean square over 100 equispaced points and all components.

Timing: wall time of the whole call (dn.solve / solve_ivp) with time.perf_counter, median of
3-7 repeats (until 0.5 s of repeats) after one untimed warm-up run that also produces the
errors and counts. dolfinode's kernel compile time is reported separately, from the first call
per problem (by default into a fresh, empty kernel cache, so it is a real cold compile).

Usage::

    .venv/bin/python benchmarks/run_foundation.py [--quick] [--output DIR] [--update-readme]
"""
import argparse
import csv
import datetime
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
HIRES_T = 321.8122
HARMONIC_T = 100.0
N_EVAL = 100
DN_METHODS = ["cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)"]
SCIPY_METHODS = ["Radau", "BDF", "LSODA", "DOP853"]
FULL_TOLERANCES = [10.0 ** -e for e in range(3, 11)]
QUICK_TOLERANCES = [1e-3, 1e-6, 1e-9]
MIN_REPEATS, MAX_REPEATS, REPEAT_BUDGET = 3, 7, 0.5   # seconds of timed repeats
DOP853_LIMIT = 2.0   # seconds: DOP853 on (stiff) HIRES is abandoned past this
HEADLINE_LEVELS = [4, 5, 6, 7, 8, 9, 10, 11, 12]   # mescd levels tried for the comparison
README_BEGIN, README_END = "<!-- BENCHMARK TABLE -->", "<!-- /BENCHMARK TABLE -->"


# ----------------------------------------------------------------------------------------------
# Hand-written NumPy right-hand sides and Jacobians for scipy
# ----------------------------------------------------------------------------------------------

def hires_rhs(t, y):
    y1, y2, y3, y4, y5, y6, y7, y8 = y
    r = 280.0 * y6 * y8
    return np.array([
        -1.71 * y1 + 0.43 * y2 + 8.32 * y3 + 0.0007,
        1.71 * y1 - 8.75 * y2,
        -10.03 * y3 + 0.43 * y4 + 0.035 * y5,
        8.32 * y2 + 1.71 * y3 - 1.12 * y4,
        -1.745 * y5 + 0.43 * y6 + 0.43 * y7,
        -r + 0.69 * y4 + 1.71 * y5 - 0.43 * y6 + 0.69 * y7,
        r - 1.81 * y7,
        -r + 1.81 * y7,
    ])


_HIRES_J0 = np.zeros((8, 8))
_HIRES_J0[0, :3] = (-1.71, 0.43, 8.32)
_HIRES_J0[1, :2] = (1.71, -8.75)
_HIRES_J0[2, 2:5] = (-10.03, 0.43, 0.035)
_HIRES_J0[3, 1:4] = (8.32, 1.71, -1.12)
_HIRES_J0[4, 4:7] = (-1.745, 0.43, 0.43)
_HIRES_J0[5, 3:7] = (0.69, 1.71, -0.43, 0.69)
_HIRES_J0[6, 6] = -1.81
_HIRES_J0[7, 6] = 1.81


def hires_jac(t, y):
    J = _HIRES_J0.copy()
    a, b = 280.0 * y[7], 280.0 * y[5]   # d(280 y6 y8)/dy6, d(280 y6 y8)/dy8
    J[5, 5] -= a
    J[5, 7] = -b
    J[6, 5] = a
    J[6, 7] = b
    J[7, 5] = -a
    J[7, 7] = -b
    return J


def harmonic_rhs(t, y):
    return np.array([y[1], -y[0]])


_HARMONIC_J = np.array([[0.0, 1.0], [-1.0, 0.0]])


def harmonic_jac(t, y):
    return _HARMONIC_J


# ----------------------------------------------------------------------------------------------
# Problems
# ----------------------------------------------------------------------------------------------

def make_problems(quick):
    from scipy.integrate import solve_ivp

    from dolfinode import problems

    t_eval = np.linspace(0.0, HIRES_T, N_EVAL)
    # Reference trajectory for the L2 error (the Test Set gives only y(T)): Radau at
    # rtol = 1e-12, atol = 1e-16 agrees with HIRES_REFERENCE to ~15 digits (mescd 14.9).
    rtol, atol = (1e-11, 1e-15) if quick else (1e-12, 1e-16)
    start = time.perf_counter()
    ref = solve_ivp(hires_rhs, (0.0, HIRES_T), np.array([1.0, 0, 0, 0, 0, 0, 0, 0.0057]),
                    method="Radau", rtol=rtol, atol=atol, jac=hires_jac, t_eval=t_eval)
    if not ref.success:
        raise RuntimeError(f"HIRES reference trajectory failed: {ref.message}")
    ref_info = {"method": "scipy Radau", "rtol": rtol, "atol": atol,
                "mescd at T vs HIRES_REFERENCE": problems.mescd(ref.y[:, -1],
                                                                problems.HIRES_REFERENCE),
                "seconds": time.perf_counter() - start}
    ref_y = ref.y.copy()
    ref_y[:, -1] = problems.HIRES_REFERENCE
    harmonic_ode, exact = problems.harmonic(T=HARMONIC_T)
    h_eval = np.linspace(0.0, HARMONIC_T, N_EVAL)
    return [
        dict(name="HIRES", ode=problems.hires(T=HIRES_T), T=HIRES_T,
             y0=np.array([1.0, 0, 0, 0, 0, 0, 0, 0.0057]), rhs=hires_rhs, jac=hires_jac,
             final=problems.HIRES_REFERENCE, t_eval=t_eval, ref_y=ref_y, mescd=problems.mescd,
             reference=ref_info),
        dict(name="harmonic", ode=harmonic_ode, T=HARMONIC_T, y0=np.array([0.0, 1.0]),
             rhs=harmonic_rhs, jac=harmonic_jac, final=exact(HARMONIC_T), t_eval=h_eval,
             ref_y=exact(h_eval), mescd=None, reference={"method": "exact (sin t, cos t)"}),
    ]


# ----------------------------------------------------------------------------------------------
# Running and timing
# ----------------------------------------------------------------------------------------------

def time_interleaved(jobs, quick):
    """Time every job (row, call) in rounds: each round makes one timed call of every job that
    still needs one (at least MIN_REPEATS, then until REPEAT_BUDGET seconds or MAX_REPEATS).

    Interleaving spreads bursts of load from other processes on the machine over many
    configurations instead of letting one burst inflate all repeats of one configuration.
    A call returns dolfinode's stats["solve time"] or None.
    """
    times = {id(row): [] for row, _ in jobs}
    inner = {id(row): [] for row, _ in jobs}

    def needs_more(row):
        t = times[id(row)]
        if quick:
            return not t
        return len(t) < MIN_REPEATS or (len(t) < MAX_REPEATS and sum(t) < REPEAT_BUDGET)

    rounds = 1 if quick else MAX_REPEATS
    for k in range(rounds):
        pending = [(row, call) for row, call in jobs if needs_more(row)]
        if not pending:
            break
        start = time.perf_counter()
        for row, call in pending:
            t0 = time.perf_counter()
            out = call()
            times[id(row)].append(time.perf_counter() - t0)
            if out is not None:
                inner[id(row)].append(out)
        print(f"timing round {k + 1}: {len(pending)} runs, {time.perf_counter() - start:.1f} s",
              flush=True)
    for row, _ in jobs:
        t = times[id(row)]
        row.update(time_median_s=float(np.median(t)), time_min_s=float(np.min(t)),
                   repeats=len(t))
        if inner[id(row)]:
            row["dn_solve_time_s"] = float(np.median(inner[id(row)]))


def errors(problem, y_final, y_samples):
    err_T = float(np.max(np.abs(y_final - problem["final"])))
    l2 = float(np.sqrt(np.mean((y_samples - problem["ref_y"]) ** 2)))
    mescd = problem["mescd"](y_final, problem["final"]) if problem["mescd"] else None
    return {"mescd": mescd, "err_T": err_T, "err_L2": l2}


def base_row(problem, solver, method, tol):
    return {"problem": problem["name"], "solver": solver, "method": method, "tolerance": tol,
            "status": "ok", "note": "", "time_median_s": None, "time_min_s": None,
            "repeats": 0, "first_call_s": None, "dn_solve_time_s": None, "mescd": None,
            "err_T": None, "err_L2": None, "f_evals": None, "jacobians": None,
            "factorizations": None, "steps": None, "rejected": None,
            "failed_nonlinear_solves": None, "nonlinear_iterations": None}


def run_dolfinode(dn, problem, method, tol):
    """Untimed warm-up run: errors and counts. Returns (row, timed call or None)."""
    row = base_row(problem, "dolfinode", method, tol)
    ode = problem["ode"]
    try:
        start = time.perf_counter()
        sol = dn.solve(ode, method=method, tolerance=tol)   # warm-up, errors and counts
        row["first_call_s"] = time.perf_counter() - start
    except Exception as exc:   # SolverError or anything else: record, go on
        row["status"] = "failed"
        row["note"] = f"{type(exc).__name__}: {exc}"
        return row, None
    st = sol.stats
    row.update(errors(problem, sol(ode.T), sol(problem["t_eval"])))
    row.update(f_evals=st["f evaluations"], jacobians=st["jacobian evaluations"],
               factorizations=st["factorizations"], steps=st["time slabs"],
               rejected=st["rejected steps"], failed_nonlinear_solves=st["failed nonlinear solves"],
               nonlinear_iterations=st["nonlinear iterations"])
    if not st["newton"]:
        row["note"] = "fixed-point iteration (no Newton)"
    return row, lambda: dn.solve(ode, method=method, tolerance=tol).stats["solve time"]


class _Timeout(Exception):
    pass


def _with_deadline(fun, seconds):
    deadline = time.perf_counter() + seconds
    last = [0.0]

    def wrapped(t, y):
        last[0] = t
        if time.perf_counter() > deadline:
            raise _Timeout(t)
        return fun(t, y)

    return wrapped, last


def _scipy_counts(method, problem, tol):
    """Accepted steps and step attempts, from one untimed instrumented run.

    solve_ivp reports neither; accepted steps are len(res.t) - 1 without t_eval, attempts are
    calls of the per-attempt routine (Radau: collocation solve, BDF: BDF system solve, DOP853:
    rk_step), so 'rejected' = attempts - accepted includes Newton-failure retries. LSODA's
    Fortran does not expose rejections.
    """
    from scipy.integrate import solve_ivp
    from scipy.integrate._ivp import bdf, radau, rk

    target = {"Radau": (radau, "solve_collocation_system"), "BDF": (bdf, "solve_bdf_system"),
              "DOP853": (rk, "rk_step")}.get(method)
    calls = [0]
    original = None
    if target is not None and hasattr(*target):
        module, name = target
        original = getattr(module, name)

        def counting(*args, **kwargs):
            calls[0] += 1
            return original(*args, **kwargs)

        setattr(module, name, counting)
    try:
        kwargs = {} if method == "DOP853" else {"jac": problem["jac"]}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = solve_ivp(problem["rhs"], (0.0, problem["T"]), problem["y0"], method=method,
                            rtol=tol, atol=tol, **kwargs)
    finally:
        if original is not None:
            setattr(target[0], target[1], original)
    steps = len(res.t) - 1
    rejected = calls[0] - steps if original is not None else None
    return steps, rejected


def run_scipy(problem, method, tol, skip_reason=None):
    """Untimed warm-up run: errors and counts. Returns (row, timed call or None)."""
    from scipy.integrate import solve_ivp

    row = base_row(problem, "scipy", method, tol)
    if skip_reason:
        row["status"] = "skipped"
        row["note"] = skip_reason
        return row, None
    kwargs = {} if method == "DOP853" else {"jac": problem["jac"]}
    span, y0, t_eval = (0.0, problem["T"]), problem["y0"], problem["t_eval"]

    def call(fun):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = solve_ivp(fun, span, y0, method=method, rtol=tol, atol=tol, t_eval=t_eval,
                            **kwargs)
        return res, caught

    fun = problem["rhs"]
    limit = DOP853_LIMIT if (method == "DOP853" and problem["name"] == "HIRES") else None
    if limit:
        fun, last = _with_deadline(fun, limit)
    try:
        start = time.perf_counter()
        res, caught = call(fun)
        row["first_call_s"] = time.perf_counter() - start
    except _Timeout:
        row["status"] = "skipped"
        row["note"] = (f"over {limit:g} s (abandoned at t = {last[0]:.4g} of {problem['T']:g}; "
                       "explicit method on a stiff problem)")
        return row, None
    except Exception as exc:
        row["status"] = "failed"
        row["note"] = f"{type(exc).__name__}: {exc}"
        return row, None
    if not res.success:
        row["status"] = "failed"
        row["note"] = f"solve_ivp: {res.message} (t = {res.t[-1] if len(res.t) else 0:.4g})"
        return row, None
    if caught:
        row["note"] = "; ".join(sorted({str(w.message).split("\n")[0] for w in caught}))
    row.update(errors(problem, res.y[:, -1], res.y))
    row.update(f_evals=int(res.nfev), jacobians=int(res.njev), factorizations=int(res.nlu))
    try:
        row["steps"], row["rejected"] = _scipy_counts(method, problem, tol)
    except Exception as exc:
        row["note"] = (row["note"] + "; " if row["note"] else "") + f"step count failed: {exc}"
    fun = problem["rhs"]

    def timed():
        call(fun)

    return row, timed


def fmt_s(x):
    if x is None:
        return "-"
    return f"{x * 1e3:.3g} ms" if x < 1 else f"{x:.3g} s"


def progress(row, timed=False):
    head = f"[{row['problem']}] {row['solver']:9s} {row['method']:6s} tol={row['tolerance']:.0e}"
    if row["status"] != "ok":
        print(f"{head}: {row['status'].upper()} {row['note']}", flush=True)
        return
    if timed:
        inner = (f", dn solve time {fmt_s(row['dn_solve_time_s'])}"
                 if row["dn_solve_time_s"] is not None else "")
        print(f"{head}: {fmt_s(row['time_median_s']):>9s} median of {row['repeats']}"
              f"{inner}", flush=True)
        return
    acc = (f"mescd {row['mescd']:.2f}" if row["mescd"] is not None
           else f"err(T) {row['err_T']:.2e}")
    print(f"{head}: first {fmt_s(row['first_call_s']):>9s}, {acc}, L2 {row['err_L2']:.2e}, "
          f"steps {row['steps']}, f {row['f_evals']}", flush=True)


# ----------------------------------------------------------------------------------------------
# Equal-accuracy comparison
# ----------------------------------------------------------------------------------------------

def accuracy(row):
    """Digits used for the equal-accuracy comparison: mescd (HIRES), -log10 err(T) otherwise."""
    if row["mescd"] is not None:
        return row["mescd"]
    return -math.log10(max(row["err_T"], 1e-300))


def curve(rows, problem, solver, method, key="time_median_s"):
    """(accuracy, log10 time) points of one solver's sweep, sorted by accuracy, reduced to its
    Pareto front: a run is dropped when a more accurate run of the same solver was faster
    (timing noise or a step-size controller that over-solves loose tolerances), so the time
    to reach a level never decreases with the level."""
    pts = sorted((accuracy(r), math.log10(r[key])) for r in rows
                 if r["problem"] == problem and r["solver"] == solver and r["method"] == method
                 and r["status"] == "ok" and r[key])
    front = []
    for acc, logt in reversed(pts):   # most accurate first
        if not front or logt < front[-1][1]:
            front.append((acc, logt))
    front.reverse()
    return np.array(front) if front else None


def time_at(c, level):
    """(time in s, clamped) to reach an accuracy level; None above the solver's best accuracy.

    Inside the sweep log10(time) is interpolated linearly in the accuracy. Below the sweep (the
    loosest tolerance is already more accurate than the level) the fastest run is used: it is
    the measured cost of reaching at least that level, marked as clamped.
    """
    if c is None or level > c[-1, 0]:
        return None
    if level < c[0, 0]:
        return 10.0 ** float(c[0, 1]), True
    return 10.0 ** float(np.interp(level, c[:, 0], c[:, 1])), False


def equal_accuracy(rows, problem, levels, key="time_median_s", scipy_key="time_median_s"):
    dn_curves = {m: curve(rows, problem, "dolfinode", m, key) for m in DN_METHODS}
    sp_curves = {m: curve(rows, problem, "scipy", m, scipy_key) for m in SCIPY_METHODS}
    table = []
    for level in levels:
        dn_t = {m: time_at(c, level) for m, c in dn_curves.items()}
        sp_t = {m: time_at(c, level) for m, c in sp_curves.items()}
        dn_t = {m: v for m, v in dn_t.items() if v is not None}
        sp_t = {m: v for m, v in sp_t.items() if v is not None}
        if not dn_t or not sp_t:
            continue
        best_dn = min(dn_t, key=lambda m: dn_t[m][0])
        best_sp = min(sp_t, key=lambda m: sp_t[m][0])
        radau = sp_t.get("Radau")
        table.append({
            "level": level, "dolfinode_best": best_dn, "dolfinode_time_s": dn_t[best_dn][0],
            "dolfinode_clamped": dn_t[best_dn][1],
            "radau_time_s": radau[0] if radau else None,
            "radau_clamped": radau[1] if radau else None,
            "ratio_vs_radau": dn_t[best_dn][0] / radau[0] if radau else None,
            "scipy_best": best_sp, "scipy_best_time_s": sp_t[best_sp][0],
            "scipy_best_clamped": sp_t[best_sp][1],
            "ratio_vs_best_scipy": dn_t[best_dn][0] / sp_t[best_sp][0],
        })
    return table


# ----------------------------------------------------------------------------------------------
# Outputs
# ----------------------------------------------------------------------------------------------

def machine_info():
    import numba
    import scipy
    import sympy

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                capture_output=True, text=True, timeout=10).stdout.strip()
    except Exception:
        commit = ""
    import dolfinode
    return {"date": datetime.date.today().isoformat(), "platform": platform.platform(),
            "cpu": cpu, "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__,
            "sympy": sympy.__version__, "dolfinode": dolfinode.__version__,
            "git_commit": commit}


CSV_FIELDS = list(base_row({"name": ""}, "", "", 0.0).keys())


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
    styles = {m: dict(color=colors[i], marker="o", linestyle="-")
              for i, m in enumerate(DN_METHODS)}
    for i, m in enumerate(SCIPY_METHODS):
        styles[m] = dict(color=colors[6 + i], marker="s", linestyle="--")
    fig, axes = plt.subplots(1, len(problems), figsize=(6.2 * len(problems), 5.2))
    for ax, problem in zip(np.atleast_1d(axes), problems):
        name = problem["name"]
        for solver, methods in (("dolfinode", DN_METHODS), ("scipy", SCIPY_METHODS)):
            for m in methods:
                pts = [r for r in rows if r["problem"] == name and r["solver"] == solver
                       and r["method"] == m and r["status"] == "ok"]
                if not pts:
                    continue
                pts.sort(key=lambda r: r["tolerance"], reverse=True)
                x = [10.0 ** -r["mescd"] if r["mescd"] is not None else r["err_T"] for r in pts]
                y = [r["time_median_s"] for r in pts]
                label = f"dolfinode {m}" if solver == "dolfinode" else f"scipy {m}"
                ax.loglog(x, y, label=label, markersize=4, linewidth=1.4, **styles[m])
        ax.set_xlabel("mixed error at T, $10^{-\\mathrm{mescd}}$" if name == "HIRES"
                      else "max |error| at T")
        ax.set_ylabel("wall time per solve [s]")
        title = (f"HIRES, T = {HIRES_T}" if name == "HIRES"
                 else f"harmonic oscillator, T = {HARMONIC_T:g}")
        ax.set_title(title)
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.12)
        ax.invert_xaxis()
    handles, labels = np.atleast_1d(axes)[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=9, frameon=False)
    fig.suptitle("Work-precision: dolfinode cG(q)/dG(q) vs scipy solve_ivp "
                 "(right = more accurate, lower = faster)", fontsize=11)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def md_table(rows, problem):
    is_hires = problem == "HIRES"
    head = ["solver", "method", "tol", "time (median)", "reps", "mescd" if is_hires else None,
            "err(T) max", "L2 (100 pts)", "f evals", "Jac", "LU", "steps", "rejected"]
    head = [h for h in head if h]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if r["problem"] != problem:
            continue
        if r["status"] != "ok":
            cells = [r["solver"], r["method"], f"{r['tolerance']:.0e}",
                     f"{r['status']}: {r['note']}"] + [""] * (len(head) - 4)
        else:
            def n(x):
                return "n/a" if x is None else str(x)
            cells = [r["solver"], r["method"], f"{r['tolerance']:.0e}", fmt_s(r["time_median_s"]),
                     str(r["repeats"])]
            if is_hires:
                cells.append(f"{r['mescd']:.2f}")
            cells += [f"{r['err_T']:.2e}", f"{r['err_L2']:.2e}", n(r["f_evals"]),
                      n(r["jacobians"]), n(r["factorizations"]), n(r["steps"]), n(r["rejected"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def headline_table(table, digits_name):
    lines = [f"| {digits_name} | best dolfinode | time | scipy Radau | ratio vs Radau | "
             "best scipy | time | ratio vs best scipy |", "|---|---|---|---|---|---|---|---|"]

    def t(x, clamped):
        return fmt_s(x) + (" *" if clamped else "")

    for e in table:
        ratio_r = f"{e['ratio_vs_radau']:.3g}" if e["ratio_vs_radau"] else "-"
        lines.append(f"| {e['level']} | {e['dolfinode_best']} | "
                     f"{t(e['dolfinode_time_s'], e['dolfinode_clamped'])} | "
                     f"{t(e['radau_time_s'], e['radau_clamped'])} | {ratio_r} | "
                     f"{e['scipy_best']} | {t(e['scipy_best_time_s'], e['scipy_best_clamped'])}"
                     f" | {e['ratio_vs_best_scipy']:.3g} |")
    lines += ["", "\\* the solver's loosest run is already more accurate than this level: its "
              "fastest run's time is used (cost of reaching at least the level)."]
    return "\n".join(lines)


def headline_sentence(table, levels=(5, 6, 7, 8)):
    sel = [e for e in table if e["level"] in levels] or table
    if not sel:
        return "no common accuracy level reached by dolfinode and scipy"

    def ratio(x):
        return f"{x:.2g} ({1 / x:.2g}x faster)" if x < 1 else f"{x:.2g} ({x:.2g}x slower)"

    radau = ", ".join(f"{ratio(e['ratio_vs_radau'])} at mescd {e['level']}" for e in sel
                      if e["ratio_vs_radau"])
    best = ", ".join(f"{ratio(e['ratio_vs_best_scipy'])} vs {e['scipy_best']} at mescd "
                     f"{e['level']}" for e in sel)
    return (f"on HIRES, time of dolfinode's best method / time of scipy Radau at equal mescd: "
            f"{radau}; / time of the best scipy solver: {best}")


def write_markdown(path, meta, rows, problems, headline, compile_info, png_name):
    out = ["# Foundation work-precision benchmark", "",
           f"Date: {meta['date']}  ", f"Machine: {meta['platform']}, {meta['cpu']}, "
           f"{meta['cpu_count']} CPUs  ",
           f"Versions: Python {meta['python']}, numpy {meta['numpy']}, scipy {meta['scipy']}, "
           f"numba {meta['numba']}, sympy {meta['sympy']}, dolfinode {meta['dolfinode']} "
           f"(git {meta['git_commit'] or '?'})  ",
           f"Command: `{meta['command']}` ({'quick' if meta['quick'] else 'full'} run, "
           f"{meta['total_seconds']:.0f} s in total)", "",
           f"**Headline.** {headline_sentence(headline['HIRES'])[0].upper()}"
           f"{headline_sentence(headline['HIRES'])[1:]}.", "",
           f"![work-precision]({png_name})", "",
           "## How it is measured", "",
           "* Tolerances: dolfinode `tolerance` = rtol (absolute_tolerance = tolerance); scipy "
           "`solve_ivp` rtol = atol. scipy gets hand-written NumPy right-hand sides and the "
           "analytic Jacobian (Radau, BDF, LSODA).",
           "* Time: wall time (time.perf_counter) of the whole `dn.solve(...)` / `solve_ivp(...)` "
           "call, median of 3-7 repeats (until 0.5 s) after an untimed warm-up run; the "
           "`solve_ivp` call includes `t_eval` (100 points), `dn.solve` includes its 101 default "
           "samples. Kernel compile time is excluded and reported below.",
           "* Errors: HIRES `mescd` = min_i -log10(|y_i - ref_i| / (1 + |ref_i|)) at T against "
           "the Test Set reference; `err(T) max` = max_i |y_i(T) - ref_i|; `L2` = root mean "
           "square over 100 equispaced points and all components (HIRES against "
           f"{problems[0]['reference']['method']} at rtol = "
           f"{problems[0]['reference'].get('rtol')}, atol = {problems[0]['reference'].get('atol')},"
           " whose mescd vs the Test Set value is "
           f"{problems[0]['reference'].get('mescd at T vs HIRES_REFERENCE', float('nan')):.1f}; "
           "harmonic against the exact solution).",
           "* Counts: dolfinode's `sol.stats` (steps = time slabs; rejected = rejected steps, "
           "failed nonlinear solves are in the CSV). scipy: f evals / Jac / LU from "
           "`solve_ivp`; steps and rejected from a separate untimed run (rejected = step attempts "
           "- accepted steps, including Newton-failure retries; n/a for LSODA).",
           "* Equal-accuracy ratio: for each solver, log10(time) is interpolated linearly in "
           "mescd (HIRES) or -log10 err(T) (harmonic) over its tolerance sweep, reduced to its "
           "Pareto front (a run is dropped when a more accurate run of the same solver was "
           "faster), with no extrapolation beyond its most accurate run; below its least "
           "accurate run the fastest run's time is used, marked *; 'best dolfinode' is the "
           "fastest of cG(1..3)/dG(1..3) at that level, 'best scipy' the fastest of the four "
           "scipy methods. Ratio < 1: dolfinode faster.",
           "", "## dolfinode compile time (first call per problem)", "",
           "| problem | first call wall | stats['compile time'] | kernel cache |",
           "|---|---|---|---|"]
    for name, c in compile_info.items():
        out.append(f"| {name} | {fmt_s(c['first_call_s'])} | {fmt_s(c['compile_time_s'])} | "
                   f"{c['cache']} |")
    out += ["", f"`import dolfinode` took {fmt_s(meta['import_seconds'])} (it loads the "
            "numba-cached time-slab loop).", ""]
    for problem in problems:
        name = problem["name"]
        digits = "mescd" if name == "HIRES" else "-log10 err(T)"
        out += [f"## {name}", "", f"### Equal accuracy ({digits})", "",
                headline_table(headline[name], digits), "",
                "Same comparison with dolfinode's internal `stats['solve time']` (compiled "
                "stepping loop only, without the Python work around it in `dn.solve`):", "",
                headline_table(headline[name + " (solve time)"], digits), "",
                "Same comparison with the fastest instead of the median repeat (both sides), "
                "as a check on timing noise from other processes on the machine:", "",
                headline_table(headline[name + " (min time)"], digits), "",
                "### All runs", "", md_table(rows, name), ""]
    Path(path).write_text("\n".join(out))


def readme_block(meta, headline, compile_info, md_rel, png_rel):
    compile_s = compile_info.get("HIRES", {}).get("compile_time_s")
    lines = [README_BEGIN,
             "Work-precision on HIRES and the harmonic oscillator, against scipy's `solve_ivp` "
             "(Radau, BDF, LSODA, DOP853, with hand-written NumPy right-hand sides and analytic "
             "Jacobians): `.venv/bin/python benchmarks/run_foundation.py` (`--quick` for a "
             "short run, `--update-readme` to regenerate this paragraph). Results are written "
             "to `doc/benchmarks/`.", "",
             f"Measured {meta['date']} on this {meta['cpu_count']}-core machine"
             f"{' (quick run)' if meta['quick'] else ''}, as the median wall time of the whole "
             f"solve call: {headline_sentence(headline['HIRES'])}. dolfinode's one-off kernel "
             f"compile for HIRES ({fmt_s(compile_s)}) is not included. "
             f"Full tables: [{md_rel}]({md_rel}); plot: [{png_rel}]({png_rel}).",
             README_END]
    return "\n".join(lines)


def update_readme(block):
    path = ROOT / "README.md"
    text = path.read_text()
    if README_BEGIN not in text:
        print(f"README.md has no {README_BEGIN} marker; not updated", file=sys.stderr)
        return
    start = text.index(README_BEGIN)
    if README_END in text[start:]:
        end = text.index(README_END, start) + len(README_END)
    else:
        end = start + len(README_BEGIN)
    path.write_text(text[:start] + block + text[end:])
    print("README.md benchmark section updated", flush=True)


# ----------------------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="tolerances 1e-3, 1e-6, 1e-9 and single timed runs")
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"),
                        help="output folder (default doc/benchmarks)")
    parser.add_argument("--update-readme", action="store_true",
                        help="rewrite the README's <!-- BENCHMARK TABLE --> section")
    parser.add_argument("--warm-cache", action="store_true",
                        help="use the configured kernel cache (DOLFINODE_CACHE_DIR) instead of "
                             "a fresh one, so the reported compile time may be a cache load")
    args = parser.parse_args(argv)
    wall_start = time.perf_counter()
    out_dir = Path(args.output).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    tolerances = QUICK_TOLERANCES if args.quick else FULL_TOLERANCES

    fresh_cache = None
    if not args.warm_cache:
        fresh_cache = tempfile.mkdtemp(prefix="dolfinode-bench-cache-")
        os.environ["DOLFINODE_CACHE_DIR"] = fresh_cache
    sys.path.insert(0, str(ROOT))
    start = time.perf_counter()
    import dolfinode as dn
    from dolfinode.compile.cache import cache_directory
    import_seconds = time.perf_counter() - start
    print(f"import dolfinode: {import_seconds:.2f} s; kernel cache {cache_directory()}"
          f"{' (fresh)' if fresh_cache else ''}", flush=True)

    try:
        problems = make_problems(args.quick)
        ref = problems[0]["reference"]
        print(f"HIRES reference trajectory: Radau rtol={ref['rtol']:g} atol={ref['atol']:g}, "
              f"mescd {ref['mescd at T vs HIRES_REFERENCE']:.2f} vs the Test Set, "
              f"{ref['seconds']:.1f} s", flush=True)
        rows, jobs, compile_info = [], [], {}
        for problem in problems:
            # Cold first call: kernel compile time, reported separately from the timings.
            folder = cache_directory()
            before = set(folder.rglob("*")) if folder.exists() else set()
            start = time.perf_counter()
            sol = dn.solve(problem["ode"], method="cG(1)", tolerance=1e-3)
            first = time.perf_counter() - start
            new = (set(folder.rglob("*")) - before) if folder.exists() else set()
            compile_info[problem["name"]] = {
                "first_call_s": first, "compile_time_s": sol.stats["compile time"],
                "cache": "cold (kernels generated and compiled)" if new
                else "warm (kernels loaded from disk cache)"}
            print(f"[{problem['name']}] dolfinode first call {first:.2f} s, compile time "
                  f"{sol.stats['compile time']:.2f} s ({compile_info[problem['name']]['cache']})",
                  flush=True)
            for method in DN_METHODS:
                for tol in tolerances:
                    row, call = run_dolfinode(dn, problem, method, tol)
                    rows.append(row)
                    jobs += [(row, call)] if call else []
                    progress(row)
            for method in SCIPY_METHODS:
                skip = None
                for tol in tolerances:
                    row, call = run_scipy(problem, method, tol, skip)
                    rows.append(row)
                    jobs += [(row, call)] if call else []
                    progress(row)
                    if row["status"] == "skipped" and skip is None:
                        skip = f"over {DOP853_LIMIT:g} s at a looser tolerance"
        print(f"timing {len(jobs)} runs in interleaved rounds (median of "
              f"{'1' if args.quick else f'{MIN_REPEATS}-{MAX_REPEATS}'} per run)", flush=True)
        time_interleaved(jobs, args.quick)
        for row, _ in jobs:
            progress(row, timed=True)
    finally:
        if fresh_cache:
            shutil.rmtree(fresh_cache, ignore_errors=True)

    headline = {}
    for problem in problems:
        name = problem["name"]
        levels = HEADLINE_LEVELS if name == "HIRES" else list(range(2, 13))
        headline[name] = equal_accuracy(rows, name, levels)
        headline[name + " (solve time)"] = equal_accuracy(rows, name, levels, "dn_solve_time_s")
        headline[name + " (min time)"] = equal_accuracy(rows, name, levels, "time_min_s",
                                                        "time_min_s")

    meta = machine_info()
    meta.update(quick=args.quick, tolerances=tolerances, import_seconds=import_seconds,
                command="python benchmarks/run_foundation.py" + (" --quick" if args.quick else ""),
                kernel_cache="fresh temporary" if fresh_cache else "configured",
                total_seconds=time.perf_counter() - wall_start)
    write_csv(out_dir / "foundation.csv", rows)
    plot(out_dir / "foundation.png", rows, problems)
    meta["total_seconds"] = time.perf_counter() - wall_start
    (out_dir / "foundation.json").write_text(json.dumps(
        {"meta": meta, "references": {p["name"]: p["reference"] for p in problems},
         "compile": compile_info, "headline": headline, "runs": rows}, indent=1))
    write_markdown(out_dir / "foundation.md", meta, rows, problems, headline, compile_info,
                   "foundation.png")
    print(headline_sentence(headline["HIRES"]), flush=True)
    print(f"wrote {out_dir}/foundation.{{csv,json,png,md}} in {meta['total_seconds']:.0f} s",
          flush=True)
    if args.update_readme:
        def rel(p):
            try:
                return str(p.relative_to(ROOT))
            except ValueError:
                return str(p)
        update_readme(readme_block(meta, headline, compile_info, rel(out_dir / "foundation.md"),
                                   rel(out_dir / "foundation.png")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
