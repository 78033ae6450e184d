"""Reaction front, N = 1000 ... 16000: mcG(1) against cG(1) (issue 3's headline measurement).

u' = eps u_xx + gamma u^2 (1 - u), eps = 0.01, gamma = 1000, finite differences on N points
with mirror ghost points (homogeneous Neumann), h = L / (N - 1), L = 5 N / 1000 (the front
region keeps its size while the domain grows), u0 = 1 / (1 + exp(lam (x - 1))),
lam = 0.5 sqrt(2 gamma / eps) (DOLFIN's reaction demo). Declared as a template system
(`dn.Template`: a diffusion edge per neighbour pair, a reaction term per point), so the
generated code does not grow with N.

cG(1) runs at tolerance 1e-6, mcG(1) at 1e-6 and 4e-7, each after one warm-up call; the time
is the CPU time of the solve call (``time.process_time``: the machine may be shared). Error:
max_i |u_i(T) - ref_i|, reference dG(3) at tolerance 1e-10. The speed-up is taken at equal
error: mcG(1)'s time at cG(1)'s error, interpolated log-log between its two runs.

Usage::

    .venv/bin/python benchmarks/run_reaction_front.py [--sizes 1000,4000,16000] [--T 0.1]
        [--output doc/benchmarks]
"""
import argparse
import itertools
import math
import time
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.special import expit

import dolfinode as dn
from dolfinode.bench import report

EPS, GAMMA = 0.01, 1000.0


def front(n, T):
    """The reaction front on n points as a template system."""
    L = 5.0 * n / 1000.0
    h = L / (n - 1)
    lam = 0.5 * math.sqrt(2.0 * GAMMA / EPS)
    a, b, wa, wb, c, g, u = sp.symbols("a b w_a w_b c gamma u")
    edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    weights = np.ones((n - 1, 2))
    weights[0, 0] = weights[-1, 1] = 2.0   # ghost points u_{-1} = u_1, u_n = u_{n-2}
    diffusion = dn.Template(slots=(a, b), terms={a: wa * c * (b - a), b: wb * c * (a - b)},
                            indices=edges, params=(wa, wb), values=weights)
    reaction = dn.Template(slots=(u,), terms={u: g * u**2 * (1 - u)},
                           indices=np.arange(n)[:, None])
    u0 = expit(-lam * (np.linspace(0.0, L, n) - 1.0))
    return dn.TemplateODE([diffusion, reaction], u0=u0, T=T,
                          params={c: EPS / (h * h), g: GAMMA})


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


def plot(sizes, mono, multi, path, T):
    """CPU time against N (log-log) of cG(1) and of mcG(1) at cG(1)'s error."""
    fig, ax = report.single_panel()
    ax.loglog(sizes, [mono[n][0] for n in sizes], marker="o", label="cG(1)")
    ns = [n for n in sizes if multi[n]]
    ax.loglog(ns, [multi[n] for n in ns], marker="o", label="mcG(1), at cG(1)'s error")
    report.save_panel(fig, ax, path, f"reaction front, T = {T:g}, tolerance 1e-6", "N",
                      "CPU time [s]")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,4000,16000")
    parser.add_argument("--T", type=float, default=0.1)
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    rows = []
    for n in (int(v) for v in args.sizes.split(",")):
        ode = front(n, args.T)
        ref = dn.solve(ode, method="dG(3)", tolerance=1e-10)(args.T)
        for method, tol in (("cG(1)", 1e-6), ("mcG(1)", 1e-6), ("mcG(1)", 4e-7)):
            dn.solve(ode, method=method, tolerance=1e-2)  # warm-up: kernels and loops
            start = time.process_time()
            sol = dn.solve(ode, method=method, tolerance=tol)
            cpu = time.process_time() - start
            st = sol.stats
            rows.append((n, method, tol, cpu, st["elements"], st["time slabs"],
                         st["rejected steps"], float(np.max(np.abs(sol(args.T) - ref))),
                         st["f evaluations"]))
            print(*rows[-1], flush=True)
    lines = [f"# Reaction front: mcG(1) against cG(1), T = {args.T:g}, tolerance 1e-6", "",
             (f"`python benchmarks/run_reaction_front.py --sizes {args.sizes} --T {args.T:g}`, "
             f"{time.strftime('%Y-%m-%d')}; CPU time of the solve call."), "",
             ("| N | method | tolerance | CPU [s] | elements | time slabs | rejected | max error "
              "| ns per element | ns per f_i evaluation |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    # cG(1)'s f evaluations are of the whole f: N component evaluations each
    lines += [f"| {n} | {m} | {tol:g} | {c:.3g} | {e:,} | {s:,} | {r} | {err:.1e} "
              f"| {1e9 * c / e:.0f} | {1e9 * c / (fe * (1 if m.startswith('m') else n)):.0f} |"
              for n, m, tol, c, e, s, r, err, fe in rows]
    sizes = sorted({row[0] for row in rows})
    mono = {n: (c, err) for n, m, tol, c, e, s, r, err, fe in rows if m == "cG(1)"}
    multi = {n: time_at_error([(err, c) for n2, m, tol, c, e, s, r, err, fe in rows
                               if n2 == n and m == "mcG(1)"], mono[n][1]) for n in sizes}
    lines += ["", "mcG(1) against cG(1) at cG(1)'s error (mcG(1)'s time interpolated): "
              + ", ".join(f"N = {n}: {mono[n][0] / multi[n]:.2g}x faster" if multi[n] else
                          f"N = {n}: mcG(1)'s runs do not bracket cG(1)'s error"
                          for n in sizes)]
    if len(sizes) > 1 and multi[sizes[0]] and multi[sizes[-1]]:
        lines += [(f"Growth of mcG(1) at equal error, time(N = {sizes[-1]}) / "
                   f"time(N = {sizes[0]}): {multi[sizes[-1]] / multi[sizes[0]]:.2g} "
                   f"(cG(1): {mono[sizes[-1]][0] / mono[sizes[0]][0]:.2g}).")]
    out = Path(args.output) / "reaction_front.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    plot(sizes, mono, multi, out.with_suffix(".png"), args.T)
    lines += ["", "![time against N](reaction_front.png)"]
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
