"""Dense output: the error inside elements and the cost of evaluating ``sol(t)``.

Inside an element a mono-adaptive dG(q) solution (q >= 1) is evaluated by the Radau
collocation polynomial with its defect correction where their residual tests pass
(``dolfinode.solution._evaluate_dg``), a cG(q)
solution (q >= 2) by the Lobatto IIIA collocation polynomial, corrected by its defect, or
a quasi-steady value where a component is stiff, one kind per element for all components,
each where its residual test passes (``_evaluate_cg``), else, and for cG(1), by the
Galerkin polynomial U. Both are evaluated here
on the same solutions (the nodes are the same bit for bit), so "Galerkin" is what ``sol(t)``
gave before.

* error: the mixed error max_i |U_i(t) - u_i(t)| / (atol + rtol |u_i(t)|), atol = rtol = the
  tolerance, over the samples, on the harmonic oscillator (T = 20, 2001 samples) and on the
  random stiff linear systems of tests/stability/test_random_linear.py (T = 1, 101 samples,
  12 systems: seed s, 2 + s % 3 states, stiffness 8 s / 11), with the error at the element
  ends (the nodes) for reference;
* multi-adaptive: mdG(q) and mcG(3) (the same dense values per component and element,
  ``_correct_multi``) against mono dG(q) and cG(3) on two problems whose components take different
  steps, a strongly coupled fast-slow pair driving a slow rotation (T = 10) and the
  two-species Brusselator (T = 20), 20001 samples against solve_ivp's Radau at 1e-13,
  with the longest element's component and its step over the shortest step of the others
  at the worst sample;
* cost: wall time per sample of 1e5 sorted samples and per call of ``sol(t)`` at a scalar t
  (harmonic, dG(2), cG(2) and cG(3) at 1e-6), minimum over interleaved repeats, compile
  excluded; multi-adaptive scalar calls on a chain of 12 masses (N = 24, 1e-6): 200 sorted
  calls on a new solution (the elements read are formed as the calls go) and the same
  calls again (kept between calls), against the values without f.

Writes doc/benchmarks/dense_output.md (overwritten).

Usage::

    python benchmarks/run_dense_output.py [--output doc/benchmarks] [--repeats 15]
"""
import argparse
import os
import platform
import time
from datetime import date
from pathlib import Path

import numpy as np
import scipy.linalg as sl

import dolfinode as dn
from dolfinode.bench.problems import harmonic, linear
from dolfinode.solution import Solution, _evaluate_shared

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("dG(1)", "dG(2)", "dG(3)", "cG(1)", "cG(2)", "cG(3)")
TOLERANCES = (1e-4, 1e-6, 1e-8)


def galerkin(sol, times):
    """The Galerkin polynomial U at ``times`` (the element values, no collocation)."""
    out = np.empty((times.size, sol.ode.N)).T
    _evaluate_shared(sol.t_start, sol.t_start + sol.k, sol.values, sol.method.nodes,
                     sol.method.barycentric_weights, times, out)
    return out


def mixed(U, u, tol):
    return float((np.abs(U - u) / (tol + tol * np.abs(u))).max())


def errors(sol, exact, t, tol):
    """(Galerkin, dense) error over the samples t (t0 excluded) and the error at the nodes."""
    u = exact(t)
    ends = sol.t_start + sol.k
    return (mixed(galerkin(sol, t), u, tol), mixed(sol(t), u, tol),
            mixed(sol.values[:, -1, :].T, exact(ends), tol))


def random_system(seed, n, stiffness):
    # the systems of tests/stability/test_random_linear.py
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = Q @ (np.eye(n) + 0.3 * np.triu(rng.standard_normal((n, n)), 1))
    rates = 10.0 ** np.sort(rng.uniform(0.0, stiffness, n))
    rates[0] = 1.0
    A = V @ np.diag(-rates) @ np.linalg.inv(V)
    return A, rng.standard_normal(n)


def harmonic_rows():
    ode, exact = harmonic(20.0)
    t = np.linspace(0.0, 20.0, 2001)[1:]
    rows = []
    for method in METHODS:
        for tol in TOLERANCES:
            sol = dn.solve(ode, method=method, tolerance=tol)
            rows.append((method, tol, sol.k.size, *errors(sol, exact, t, tol)))
    return rows


def random_rows(tol=1e-6):
    rows = []
    for method in METHODS:
        worst = np.zeros(3)
        for seed in range(12):
            A, u0 = random_system(seed, 2 + seed % 3, 8.0 * seed / 11)
            ode, _ = linear(A, u0, 1.0)
            sol = dn.solve(ode, method=method, tolerance=tol)

            def exact(s, A=A, u0=u0):
                return np.column_stack([sl.expm(A * x) @ u0 for x in np.atleast_1d(s)])
            t = np.linspace(0.0, 1.0, 101)[1:]
            worst = np.maximum(worst, errors(sol, exact, t, tol))
        rows.append((method, tol, *worst))
    return rows


#: (mono, multi) pairs of the multi-adaptive section, and its tolerances and samples.
MULTI_PAIRS = (("dG(1)", "mdG(1)"), ("dG(2)", "mdG(2)"), ("dG(3)", "mdG(3)"),
               ("cG(3)", "mcG(3)"))
MULTI_TOLERANCES = (1e-5, 1e-7)
MULTI_SAMPLES = 20001


def multi_problems():
    """(name, ode, f(t, u) for solve_ivp) of the multi-adaptive section."""
    import sympy as sp

    a, b, c, d = sp.symbols("a b c d")
    strong = dn.ODE({a: -1000 * a + 999 * b + sp.sin(c), b: 999 * a - 1000 * b, c: d, d: -c},
                    u0=[1.0, 0.0, 0.0, 1.0], T=10.0)
    bruss = dn.ODE({a: 1 + a**2 * b - 4 * a, b: 3 * a - a**2 * b}, u0=[1.5, 3.0], T=20.0)
    return (("fast-slow pair", strong,
             lambda t, u: [-1000 * u[0] + 999 * u[1] + np.sin(u[2]), 999 * u[0] - 1000 * u[1],
                           u[3], -u[2]]),
            ("Brusselator", bruss,
             lambda t, u: [1 + u[0] ** 2 * u[1] - 4 * u[0], 3 * u[0] - u[0] ** 2 * u[1]]))


def multi_rows():
    """(problem, method, tol, elements, dense inside, nodes, worst component, its step over
    the shortest step of the other components there) for MULTI_PAIRS."""
    from scipy.integrate import solve_ivp

    rows = []
    for name, ode, f in multi_problems():
        exact = solve_ivp(f, (ode.t0, ode.T), ode.u0, method="Radau", rtol=1e-13,
                          atol=1e-15, dense_output=True).sol
        t = np.linspace(ode.t0, ode.T, MULTI_SAMPLES)[1:]
        u = exact(t)
        for pair in MULTI_PAIRS:
            for tol in MULTI_TOLERANCES:
                for method in pair:
                    sol = dn.solve(ode, method=method, tolerance=tol)
                    ptr, a, b, values = sol.elements()
                    e = np.abs(sol(t) - u) / (tol + tol * np.abs(u))
                    i, m = np.unravel_index(np.argmax(e), e.shape)
                    steps = [(b - a)[ptr[j]:ptr[j + 1]][np.searchsorted(b[ptr[j]:ptr[j + 1]],
                                                                       t[m])]
                             for j in range(ode.N)]
                    others = min(k for j, k in enumerate(steps) if j != i)
                    rows.append((name, method, tol, b.size, e.max(),
                                 mixed(values[:, -1], exact(b)[np.repeat(
                                     np.arange(ode.N), np.diff(ptr)), np.arange(b.size)], tol),
                                 ode.states[i], steps[i] / others))
    return rows


def old_evaluate(self, times):
    out = np.empty((times.size, self._declaration.N)).T
    _evaluate_shared(self.t_start, self.t_start + self.k, self.values, self.method.nodes,
                     self.method.barycentric_weights, times, out)
    return out


def costs(repeats):
    """Per sample (1e5 samples) and per scalar call, before (Galerkin) and after, in us."""
    ode, _ = harmonic(20.0)
    times = np.sort(np.random.default_rng(0).uniform(0.0, 20.0, 100_000))
    new_evaluate = Solution._evaluate
    result = {}
    for method in ("dG(2)", "cG(2)", "cG(3)"):
        sol = dn.solve(ode, method=method, tolerance=1e-6)
        best = {}
        for _ in range(repeats):
            for name, evaluate in (("before", old_evaluate), ("after", new_evaluate)):
                Solution._evaluate = evaluate
                sol(times[:10])  # (warm)
                start = time.perf_counter()
                sol(times)
                per_sample = (time.perf_counter() - start) / times.size
                start = time.perf_counter()
                for s in times[:2000:10]:
                    sol(s)
                per_call = (time.perf_counter() - start) / 200
                old = best.get(name, (np.inf, np.inf))
                best[name] = (min(old[0], per_sample), min(old[1], per_call))
        Solution._evaluate = new_evaluate
        result[method] = best
    return result


def chain12():
    """12 masses with springs stiffening along the chain, the first displaced (T = 10)."""
    import sympy as sp

    n = 12
    x, v = sp.symbols(f"x0:{n}"), sp.symbols(f"v0:{n}")
    rhs = {}
    for i in range(n):
        rhs[x[i]] = v[i]
        rhs[v[i]] = ((x[i - 1] if i else 0) - 2 * x[i] + (x[i + 1] if i < n - 1 else 0)) * (1 + i)
    return dn.ODE(rhs, u0=[1.0] + [0.0] * (2 * n - 1), T=10.0)


def multi_costs(repeats):
    """Per scalar call of the chain of 12 masses, in us: (elements, without f, a new
    solution's calls, the same calls again) per method."""
    ode = chain12()
    times = np.sort(np.random.default_rng(0).uniform(ode.t0, ode.T, 20_000))[:2000:10]
    result = {}
    for method in ("mcG(2)", "mcG(3)", "mdG(1)", "mdG(2)"):
        solved = dn.solve(ode, method=method, tolerance=1e-6)
        elements = solved.elements()
        best = np.full(3, np.inf)
        for _ in range(repeats):
            sol = Solution.grouped(ode, solved.method, *elements, {}, 11)
            sol(times[0] / 2)  # (the kernels and f made)
            spent = []
            for call in (lambda t, sol=sol: sol._evaluate(np.array([t, t]), dense=False), sol,
                         sol):
                start = time.perf_counter()
                for t in times:
                    call(t)
                spent.append((time.perf_counter() - start) / times.size)
            best = np.minimum(best, spent)
        result[method] = (elements[1].size, *(best * 1e6))
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    lines = ["# Dense output: error inside elements, cost of sol(t)", "",
             (f"{date.today()}, {platform.processor() or platform.machine()}, "
             f"{os.cpu_count()} cores (shared), `python benchmarks/run_dense_output.py`. "
             "Error: max over the samples of the mixed error / tolerance (atol = rtol); "
             "Galerkin: the element polynomial U (every method's sol(t) before the "
             "collocation dense outputs of dG(q) and cG(q), and cG(1)'s now); dense: sol(t) "
             "now."), "",
             "## Harmonic oscillator, T = 20, 2001 samples", "",
             "| method | tol | elements | Galerkin inside | dense inside | nodes |",
             "|---|---|---|---|---|---|"]
    for method, tol, n, g, d, nodes in harmonic_rows():
        lines.append(f"| {method} | {tol:g} | {n} | {g:.3g} | {d:.3g} | {nodes:.3g} |")
    lines += ["", ("## Random stiff linear systems (12, stiffness up to 1e8), T = 1, "
              "101 samples, tolerance 1e-6, worst system"), "",
              "| method | Galerkin inside | dense inside | nodes |", "|---|---|---|---|"]
    for method, _tol, g, d, nodes in random_rows():
        lines.append(f"| {method} | {g:.3g} | {d:.3g} | {nodes:.3g} |")
    lines += ["", (f"## Multi-adaptive against mono-adaptive, {MULTI_SAMPLES} samples"), "",
              ("| problem | method | tol | elements | dense inside | nodes | worst component | "
               "its step / shortest other |"), "|---|---|---|---|---|---|---|---|"]
    for name, method, tol, n, d, nodes, worst, ratio in multi_rows():
        lines.append(f"| {name} | {method} | {tol:g} | {n} | {d:.3g} | {nodes:.3g} | {worst} "
                     f"| {ratio:.2g} |")
    lines += ["", (f"## Cost (harmonic, tolerance 1e-6; minimum of {args.repeats} interleaved "
              "repeats, wall clock)"), "",
              ("| method | per sample, 1e5 sorted samples: before / after (ratio) | "
              "sol(t), scalar t: before / after (ratio) |"), "|---|---|---|"]
    for method, best in costs(args.repeats).items():
        (b_s, b_c), (a_s, a_c) = best["before"], best["after"]
        lines.append(f"| {method} | {b_s * 1e9:.1f} / {a_s * 1e9:.1f} ns ({a_s / b_s:.2f}) | "
                     f"{b_c * 1e6:.2f} / {a_c * 1e6:.2f} us ({a_c / b_c:.2f}) |")
    lines += ["", (f"## Cost, multi-adaptive (chain of 12 masses, N = 24, tolerance 1e-6; "
                   f"minimum of {args.repeats} repeats, 200 sorted scalar calls)"), "",
              "| method | elements | without f | new solution | again |", "|---|---|---|---|---|"]
    for method, (n, without, first, again) in multi_costs(args.repeats).items():
        lines.append(f"| {method} | {n} | {without:.1f} us | {first:.1f} us | {again:.1f} us |")
    text = "\n".join(lines) + "\n"
    Path(args.output).mkdir(parents=True, exist_ok=True)
    Path(args.output, "dense_output.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
