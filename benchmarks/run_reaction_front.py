"""Reaction front, N = 1000 ... 16000: mcG(q) against cG(1) and scipy (issue 3's headline).

u' = eps u_xx + gamma u^2 (1 - u), eps = 0.01, gamma = 1000, finite differences on N points
with mirror ghost points (homogeneous Neumann), h = L / (N - 1), L = 5 N / 1000 (the front
region keeps its size while the domain grows), u0 = 1 / (1 + exp(lam (x - 1))),
lam = 0.5 sqrt(2 gamma / eps) (DOLFIN's reaction demo). Declared as a template system
(`dn.Template`: a diffusion edge per neighbour pair, a reaction term per point), so the
generated code does not grow with N.

cG(1) runs at tolerance 1e-6, mcG(1) at 1e-6 and 4e-7, mcG(2) and mcG(3) at 1e-3 ... 1e-10,
each method after one warm-up call; the time is the CPU time of the solve call
(``time.process_time``: the machine may be shared), the minimum of two under a second. Error:
max_i |u_i(T) - ref_i|, reference dG(3) at tolerance 1e-10 (checked against dG(3) at 1e-11 and
DOP853 at rtol = atol = 1e-12). The speed-up is taken at equal error: mcG(1)'s time at cG(1)'s
error, interpolated log-log between its two runs.

scipy's ``solve_ivp`` solvers (LSODA, DOP853, Radau, BDF) are the peers: they solve the same
discretization, written by hand in NumPy (``front_numpy``; the template system has no cheap
per-component expressions at N = 16000), with the analytic Jacobian, tridiagonal,

    J = tridiag(c_i^-, -2 c + gamma u_i (2 - 3 u_i), c_i^+),  c = eps / h^2,

where c_0^+ = c_{N-1}^- = 2 c (the ghost points) and all other off-diagonal entries are c:
sparse (CSC) for Radau and BDF, in band storage (``lband = uband = 1``) for LSODA (as fast as
LSODA's own banded difference quotients here: LSODA stays in its nonstiff Adams mode and
evaluates no Jacobian; a dense one would take 2 GB at N = 16000). Each sweeps rtol = atol =
1e-4 ... 1e-11 (dolfinode's default absolute tolerance equals its tolerance), with t_eval = [T]
only. Every run is made once untimed (the error, and the time limit: a run past ``--time-limit``
CPU seconds is abandoned from inside f, and the solver's tighter tolerances are skipped), then
timed once, twice when under a second (the minimum of the two). The markdown gets a table of
these runs and one of every solver's time at cG(1)'s error (interpolated log-log like
mcG(1)'s) with the time ratios mcG(1) / fastest scipy and cG(1) / fastest scipy (< 1: the
dolfinode method is faster); the plot gets the fastest scipy solver as a third line. At the
errors 1e-5 ... 1e-9 the fastest dolfinode method (of cG(1), mcG(1), mcG(2), mcG(3)) meets
the fastest scipy solver in a last table (each one's time interpolated the same way), and
``reaction_front_wp.png`` plots every method's CPU time against its error, a panel per N.

Usage::

    .venv/bin/python benchmarks/run_reaction_front.py [--sizes 1000,4000,16000] [--T 0.1]
        [--time-limit 60] [--output doc/benchmarks]
"""
import argparse
import functools
import itertools
import math
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sps
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.special import expit

import dolfinode as dn
from dolfinode.bench import report
from dolfinode.bench.runner import RunTimeout, clock, with_deadline

EPS, GAMMA = 0.01, 1000.0
#: scipy's solvers and their tolerances (rtol = atol).
SCIPY = ("LSODA", "DOP853", "Radau", "BDF")
SCIPY_TOLERANCES = tuple(10.0**-k for k in range(4, 12))
#: dolfinode's methods and their tolerances.
HIGH_ORDER_TOLERANCES = tuple(10.0**-k for k in range(3, 11))
DOLFINODE_RUNS = (("cG(1)", (1e-6,)), ("mcG(1)", (1e-6, 4e-7)),
                  ("mcG(2)", HIGH_ORDER_TOLERANCES), ("mcG(3)", HIGH_ORDER_TOLERANCES))
DOLFINODE = tuple(method for method, _ in DOLFINODE_RUNS)
#: The errors at which the fastest dolfinode method and the fastest scipy solver are compared.
ERROR_LEVELS = tuple(10.0**-k for k in range(5, 10))
#: A run faster than this (CPU seconds) is timed twice.
TIME_TWICE_BELOW = 1.0


def grid(n):
    """The points x_i = i h, h = L / (n - 1), L = 5 n / 1000, and c = eps / h^2."""
    L = 5.0 * n / 1000.0
    h = L / (n - 1)
    return np.linspace(0.0, L, n), EPS / (h * h)


def front(n, T):
    """The reaction front on n points as a template system."""
    x, c_value = grid(n)
    lam = 0.5 * math.sqrt(2.0 * GAMMA / EPS)
    a, b, wa, wb, c, g, u = sp.symbols("a b w_a w_b c gamma u")
    edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    weights = np.ones((n - 1, 2))
    weights[0, 0] = weights[-1, 1] = 2.0   # ghost points u_{-1} = u_1, u_n = u_{n-2}
    diffusion = dn.Template(slots=(a, b), terms={a: wa * c * (b - a), b: wb * c * (a - b)},
                            indices=edges, params=(wa, wb), values=weights)
    reaction = dn.Template(slots=(u,), terms={u: g * u**2 * (1 - u)},
                           indices=np.arange(n)[:, None])
    u0 = expit(-lam * (x - 1.0))
    return dn.TemplateODE([diffusion, reaction], u0=u0, T=T, params={c: c_value, g: GAMMA})


def front_numpy(n):
    """The right-hand side and Jacobian of ``front(n, T)`` in NumPy, for ``solve_ivp``.

    f_i = c (u_{i-1} - 2 u_i + u_{i+1}) + gamma u_i^2 (1 - u_i), with the ghost points
    u_{-1} = u_1 and u_n = u_{n-2}; J = df/du is tridiagonal.

    Returns
    -------
    fun : callable
        fun(t, u) -> f, ndarray (n,).
    bands : callable
        bands(t, u) -> J in LAPACK band storage, ndarray (3, n): bands[1 + i - j, j] = J_ij
        (LSODA with ``lband = uband = 1``).
    jac : callable
        jac(t, u) -> J, scipy.sparse CSC matrix (Radau, BDF).
    """
    c = grid(n)[1]
    upper = np.full(n - 1, c)   # J_{i, i+1}
    lower = np.full(n - 1, c)   # J_{i+1, i}
    upper[0] = lower[-1] = 2.0 * c

    def fun(t, u):
        du = np.diff(u)
        f = GAMMA * u * u * (1.0 - u)
        f[:-1] += upper * du
        f[1:] -= lower * du
        return f

    def bands(t, u):
        b = np.zeros((3, n))
        b[0, 1:] = upper
        b[1] = GAMMA * u * (2.0 - 3.0 * u) - 2.0 * c
        b[2, :-1] = lower
        return b

    def jac(t, u):
        # band storage is the DIA format with offsets 1, 0, -1
        return sps.dia_matrix((bands(t, u), [1, 0, -1]), shape=(n, n)).tocsc()

    return fun, bands, jac


def timed(call):
    """``call()`` timed once, twice when under :data:`TIME_TWICE_BELOW` CPU seconds: (its
    result, the minimum time)."""
    times = []
    while not times or (len(times) == 1 and times[0] < TIME_TWICE_BELOW):
        start = clock()
        result = call()
        times.append(clock() - start)
    return result, min(times)


def reference(ode):
    """The reference u(T), dG(3) at tolerance 1e-10, and its max-norm distances to dG(3) at
    1e-11 and to DOP853 at rtol = atol = 1e-12 (its accuracy check)."""
    ref = dn.solve(ode, method="dG(3)", tolerance=1e-10)(ode.T)
    tighter = dn.solve(ode, method="dG(3)", tolerance=1e-11)(ode.T)
    dop = solve_ivp(front_numpy(ode.N)[0], (ode.t0, ode.T), ode.u0, method="DOP853", rtol=1e-12,
                    atol=1e-12, t_eval=[ode.T]).y[:, -1]
    return ref, float(np.max(np.abs(tighter - ref))), float(np.max(np.abs(dop - ref)))


def run_scipy(ode, method, tolerances, ref, time_limit):
    """Sweep one scipy solver over ``tolerances`` (loosest first) on ``ode``.

    Every run is made once untimed (the error max_i |u_i(T) - ref_i|, and the time limit:
    past ``time_limit`` CPU seconds it is abandoned and the tighter tolerances are skipped),
    then :func:`timed`.

    Returns
    -------
    rows : list of tuple
        (N, method, tolerance, CPU seconds or None, f evaluations, Jacobian evaluations,
        LU factorizations, max error, note).
    """
    fun, bands, jac = front_numpy(ode.N)
    options = {"LSODA": {"jac": bands, "lband": 1, "uband": 1}, "Radau": {"jac": jac},
               "BDF": {"jac": jac}}.get(method, {})

    def solve(f, tol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return solve_ivp(f, (ode.t0, ode.T), ode.u0, method=method, rtol=tol, atol=tol,
                             t_eval=[ode.T], **options)

    rows = []
    for tol in tolerances:
        f, last = with_deadline(fun, time_limit)
        try:
            res = solve(f, tol)
        except RunTimeout:
            rows.append((ode.N, method, tol, None, None, None, None, None,
                         f"abandoned after {time_limit:g} s at t = {last[0]:.3g}"))
            break
        if not res.success:
            rows.append((ode.N, method, tol, None, None, None, None, None, res.message))
            break
        cpu = timed(functools.partial(solve, fun, tol))[1]
        rows.append((ode.N, method, tol, cpu, res.nfev, res.njev, res.nlu,
                     float(np.max(np.abs(res.y[:, -1] - ref))), ""))
        print(*rows[-1], flush=True)
    return rows


def time_at_error(points, error):
    """The time at ``error`` from (error, time) points, interpolated log-log between the two
    points around it (None when they do not bracket it)."""
    points = sorted(points)
    for (e1, t1), (e2, t2) in itertools.pairwise(points):
        if e1 <= error <= e2:
            if e2 == e1:
                return t1
            w = math.log(error / e1) / math.log(e2 / e1)
            return math.exp((1 - w) * math.log(t1) + w * math.log(t2))
    return None


def work_precision(rows):
    """The (error, CPU time) points of run rows (N, method, tolerance, CPU seconds or None, ...,
    max error at index 7), abandoned runs left out: {N: {method: [(error, time)]}}."""
    curves = {}
    for row in rows:
        if row[3] is not None:
            curves.setdefault(row[0], {}).setdefault(row[1], []).append((row[7], row[3]))
    return curves


def fastest(curves, methods, error):
    """The fastest of ``methods`` at ``error`` (:func:`time_at_error` on each one's points in
    ``curves``, {method: [(error, time)]}): (method, time), or None when none brackets it."""
    times = ((m, time_at_error(curves.get(m, []), error)) for m in methods)
    return min(((m, t) for m, t in times if t), key=lambda mt: mt[1], default=None)


def equal_error(curves, levels):
    """The fastest dolfinode method and the fastest scipy solver at each error level of
    ``levels`` where both have a time, per N of ``curves`` (from :func:`work_precision`).

    Returns
    -------
    list of tuple
        (N, level, (dolfinode method, time), (scipy solver, time), the scipy solvers whose
        runs do not bracket the level).
    """
    rows = []
    for n, level in itertools.product(sorted(curves), levels):
        dolfinode, scipy = fastest(curves[n], DOLFINODE, level), fastest(curves[n], SCIPY, level)
        if dolfinode and scipy:
            rows.append((n, level, dolfinode, scipy, [
                m for m in SCIPY if time_at_error(curves[n].get(m, []), level) is None]))
    return rows


def plot(sizes, mono, multi, best, path, T):
    """CPU time against N (log-log) of cG(1), and of mcG(1) and the fastest scipy solver
    (named at each point) at cG(1)'s error."""
    fig, ax = report.single_panel()
    ax.loglog(sizes, [mono[n][0] for n in sizes], marker="o", label="cG(1)")
    ns = [n for n in sizes if multi[n]]
    ax.loglog(ns, [multi[n] for n in ns], marker="o", label="mcG(1), at cG(1)'s error")
    ns = [n for n in sizes if best[n]]
    ax.loglog(ns, [best[n][1] for n in ns], marker="o",
              label="fastest scipy solver, at cG(1)'s error")
    for n in ns:
        ax.annotate(best[n][0], (n, best[n][1]), textcoords="offset points", xytext=(4, -10),
                    fontsize=7)
    report.save_panel(fig, ax, path, f"reaction front, T = {T:g}, tolerance 1e-6", "N",
                      "CPU time [s]")


def plot_work_precision(curves, path, T):
    """CPU time against max error (log-log), one panel per N and one line per method of
    ``curves`` (from :func:`work_precision`; dolfinode solid, scipy dashed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted(curves)
    fig, axes = plt.subplots(1, len(sizes), figsize=(4.5 * len(sizes), 4.6), squeeze=False)
    colors = plt.get_cmap("tab10").colors
    for ax, n in zip(axes[0], sizes):
        for i, m in enumerate(DOLFINODE + SCIPY):
            points = sorted(curves[n].get(m, []))
            if points:
                ax.loglog(*zip(*points), color=colors[i], marker="o" if m in DOLFINODE else "s",
                          linestyle="-" if m in DOLFINODE else "--", markersize=4, label=m)
        ax.set_title(f"N = {n}", fontsize=10)
        ax.set_xlabel("max error at T")
        ax.grid(True, which="major", alpha=0.4)
        ax.invert_xaxis()
    axes[0, 0].set_ylabel("CPU time [s]")
    axes[0, -1].legend(fontsize=8)
    fig.suptitle(f"reaction front, T = {T:g}: work-precision (right = more accurate, lower = "
                 "faster)", fontsize=11)
    fig.tight_layout()
    report.save_figure(fig, path)


def scipy_section(sizes, scipy_rows, curves, mono, multi):
    """Markdown lines of the scipy runs and of the times at cG(1)'s error (``curves`` from
    :func:`work_precision`), and the fastest scipy solver at cG(1)'s error per N: (solver,
    time) or None."""
    lines = ["", (f"scipy's `solve_ivp`, rtol = atol = {SCIPY_TOLERANCES[0]:g} ... "
                  f"{SCIPY_TOLERANCES[-1]:g}, the hand-written NumPy f and analytic Jacobian "
                  "(LSODA banded, Radau and BDF sparse); CPU time of one call after an untimed "
                  f"one (the minimum of two under {TIME_TWICE_BELOW:g} s):"), "",
             ("| N | solver | rtol = atol | CPU [s] | f evaluations | Jacobians | LU "
              "| max error |"), "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {n} | {m} | {tol:g} | {note} | | | | |" if c is None else
              f"| {n} | {m} | {tol:g} | {c:.3g} | {fe:,} | {je} | {lu} | {err:.1e} |"
              for n, m, tol, c, fe, je, lu, err, note in scipy_rows]
    at = {n: {m: time_at_error(curves[n].get(m, []), mono[n][1]) for m in SCIPY} for n in sizes}
    best = {n: fastest(curves[n], SCIPY, mono[n][1]) for n in sizes}
    lines += ["", ("Time at cG(1)'s error (log-log interpolation between the runs around it; '-' "
                   "where they do not bracket it) and time ratios to the fastest scipy solver "
                   "(< 1: faster than it):"), "",
              "| N | max error | cG(1) | mcG(1) | " + " | ".join(SCIPY)
              + " | fastest scipy | mcG(1) / scipy | cG(1) / scipy |",
              "|---" * (len(SCIPY) + 7) + "|"]

    def cell(value):
        return f"{value:.3g}" if value else "-"

    for n in sizes:
        solver, t = best[n] or ("-", None)
        lines.append(f"| {n} | {mono[n][1]:.1e} | {cell(mono[n][0])} | {cell(multi[n])} | "
                     + " | ".join(cell(at[n][m]) for m in SCIPY)
                     + f" | {solver} | {cell(multi[n] and t and multi[n] / t)} | "
                       f"{cell(t and mono[n][0] / t)} |")
    lines += ["", "mcG(1) against the fastest scipy solver at cG(1)'s error: " + ", ".join(
        f"N = {n}: {best[n][0]} {best[n][1]:.2g} s, mcG(1) {multi[n] / best[n][1]:.2g}x its time"
        if best[n] and multi[n] else f"N = {n}: no interpolated time" for n in sizes)
        + (f"; growth of the fastest scipy time, N = {sizes[0]} to {sizes[-1]}: "
           f"{best[sizes[-1]][1] / best[sizes[0]][1]:.2g}." if len(sizes) > 1
           and best[sizes[0]] and best[sizes[-1]] else ".")]
    return lines, best


def equal_error_section(curves, checks):
    """Markdown lines of the reference check (``checks``: N -> distances of :func:`reference`)
    and of the fastest dolfinode method against the fastest scipy solver at
    :data:`ERROR_LEVELS`."""
    lines = ["", ("Reference check, max_i |ref_i - u_i(T)| of the dG(3) reference (tolerance "
                  "1e-10) against dG(3) at 1e-11 and DOP853 at rtol = atol = 1e-12: "
                  + ", ".join(f"N = {n}: {tight:.1e} and {dop:.1e}"
                              for n, (tight, dop) in checks.items()) + "."), "",
             ("Fastest dolfinode method (of " + ", ".join(DOLFINODE) + ") and fastest scipy "
              "solver at equal max error (times interpolated log-log as above; levels where "
              "either side's runs do not bracket the error are left out); ratio < 1: dolfinode "
              "faster:"), "",
             ("| N | max error | dolfinode | CPU [s] | scipy | CPU [s] | dolfinode / scipy "
              "| scipy solvers not bracketing it |"), "|---|---|---|---|---|---|---|---|"]
    rows = equal_error(curves, ERROR_LEVELS)
    lines += [f"| {n} | {level:.0e} | {dm} | {dt:.3g} | {sm} | {st:.3g} | {dt / st:.2g} "
              f"| {', '.join(missing)} |" for n, level, (dm, dt), (sm, st), missing in rows]
    summary = []
    for n in sorted(curves):
        ratios = [(dt / st, level) for n2, level, (dm, dt), (sm, st), _ in rows if n2 == n]
        if ratios:
            summary.append(f"N = {n}: {min(ratios)[0]:.2g}-{max(ratios)[0]:.2g} (errors "
                           f"{max(ratios, key=lambda r: r[1])[1]:.0e} ... "
                           f"{min(ratios, key=lambda r: r[1])[1]:.0e})")
    slower = [f"N = {n} at {level:.0e} ({dt / st:.2g}x)"
              for n, level, (dm, dt), (sm, st), _ in rows if dt > st]
    lines += ["", "Fastest dolfinode method / fastest scipy solver at equal error: "
              + ", ".join(summary) + "; dolfinode's fastest is "
              + (f"slower at {', '.join(slower)}." if slower else "faster at every level compared.")]
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,4000,16000")
    parser.add_argument("--T", type=float, default=0.1)
    parser.add_argument("--time-limit", type=float, default=60.0,
                        help="CPU seconds after which a scipy run is abandoned")
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    rows, scipy_rows, checks = [], [], {}
    for n in (int(v) for v in args.sizes.split(",")):
        ode = front(n, args.T)
        ref, *checks[n] = reference(ode)
        print("reference check", n, *checks[n], flush=True)
        for method, tolerances in DOLFINODE_RUNS:
            dn.solve(ode, method=method, tolerance=1e-2)  # warm-up: kernels and loops
            for tol in tolerances:
                # the solve alone, as the peers' (they estimate no error at T)
                sol, cpu = timed(functools.partial(dn.solve, ode, method=method, tolerance=tol,
                                                   estimate_global_error=False))
                st = sol.stats
                rows.append((n, method, tol, cpu, st["elements"], st["time slabs"],
                             st["rejected steps"], float(np.max(np.abs(sol(args.T) - ref))),
                             st["f evaluations"]))
                print(*rows[-1], flush=True)
        for method in SCIPY:
            scipy_rows += run_scipy(ode, method, SCIPY_TOLERANCES, ref, args.time_limit)
    lines = [f"# Reaction front: mcG(q) against cG(1) and scipy, T = {args.T:g}", "",
             (f"`python benchmarks/run_reaction_front.py --sizes {args.sizes} --T {args.T:g} "
              f"--time-limit {args.time_limit:g}`, {time.strftime('%Y-%m-%d')}; CPU time of the "
              f"solve call after a warm-up (the minimum of two under {TIME_TWICE_BELOW:g} s)."),
             "",
             ("| N | method | tolerance | CPU [s] | elements | time slabs | rejected | max error "
              "| ns per element | ns per f_i evaluation |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    # cG(1)'s f evaluations are of the whole f: N component evaluations each
    lines += [f"| {n} | {m} | {tol:g} | {c:.3g} | {e:,} | {s:,} | {r} | {err:.1e} "
              f"| {1e9 * c / e:.0f} | {1e9 * c / (fe * (1 if m.startswith('m') else n)):.0f} |"
              for n, m, tol, c, e, s, r, err, fe in rows]
    sizes = sorted({row[0] for row in rows})
    mono = {n: (c, err) for n, m, tol, c, e, s, r, err, fe in rows if m == "cG(1)"}
    curves = work_precision(rows + scipy_rows)
    multi = {n: time_at_error(curves[n]["mcG(1)"], mono[n][1]) for n in sizes}
    lines += ["", "mcG(1) against cG(1) at cG(1)'s error (mcG(1)'s time interpolated): "
              + ", ".join(f"N = {n}: {mono[n][0] / multi[n]:.2g}x faster" if multi[n] else
                          f"N = {n}: mcG(1)'s runs do not bracket cG(1)'s error"
                          for n in sizes)]
    if len(sizes) > 1 and multi[sizes[0]] and multi[sizes[-1]]:
        lines += [(f"Growth of mcG(1) at equal error, time(N = {sizes[-1]}) / "
                   f"time(N = {sizes[0]}): {multi[sizes[-1]] / multi[sizes[0]]:.2g} "
                   f"(cG(1): {mono[sizes[-1]][0] / mono[sizes[0]][0]:.2g}).")]
    scipy_table, best = scipy_section(sizes, scipy_rows, curves, mono, multi)
    lines += scipy_table + equal_error_section(curves, checks)
    out = Path(args.output) / "reaction_front.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    plot(sizes, mono, multi, best, out.with_suffix(".png"), args.T)
    plot_work_precision(curves, out.with_name("reaction_front_wp.png"), args.T)
    lines += ["", "![time against N](reaction_front.png)", "",
              "![work-precision](reaction_front_wp.png)"]
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
