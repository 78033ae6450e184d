"""The dual's stage systems: banded LU against scipy's splu, per interval of the union grid.

For each problem a primal solution is computed, then ``solve_dual`` runs once per linear
solver (after an untimed warm-up that also compiles) and its CPU time (time.process_time) is
divided by the number of intervals. Problems: the DOLFIN lattice (2-D, m = 1, cG(1) with 4
fixed steps, dual cG(3)) for p = 5, 10, 20, 30; the mass-spring chain (1-D, band 2) with
50, 250, 2500 masses (cG(1), fixed steps 0.05, dual cG(3)); a 60 x 60 reaction-diffusion
lattice (N = 3600, cG(2) at tolerance 1e-4, dual cG(4)). Reports which solver
``dolfinode.linalg.wide_band`` picks and the largest difference of the two duals.

Writes dual_lu.json and dual_lu.md to the output folder.

Usage::

    DOLFINODE_CACHE_DIR=... python benchmarks/run_dual_lu.py [--output doc/benchmarks]
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np
import sympy as sp

import dolfinode as dn
from dolfinode import problems
from dolfinode.compile import lower
from dolfinode.dual.goal import resolve
from dolfinode.dual.problem import solve_dual
from dolfinode.linalg import wide_band

ROOT = Path(__file__).resolve().parents[1]


def reaction_diffusion(n=60, diffusion=1e-3):
    """u' = D Laplace u + u (1 - u) on an n x n grid (5-point stencil), as templates."""
    a, b, x = sp.symbols("a b x")
    grid = np.arange(n * n).reshape(n, n)
    edges = np.vstack([np.column_stack([grid[:, :-1].ravel(), grid[:, 1:].ravel()]),
                       np.column_stack([grid[:-1, :].ravel(), grid[1:, :].ravel()])])
    D = diffusion * (n - 1) ** 2
    exchange = dn.Template((a, b), {a: D * (b - a), b: D * (a - b)}, edges)
    growth = dn.Template((x,), {x: x * (1 - x)}, np.arange(n * n)[:, None])
    s = np.linspace(0, 1, n)
    u0 = np.exp(-50 * (s[:, None] ** 2 + s[None, :] ** 2)).ravel()
    return dn.TemplateODE([exchange, growth], u0=u0, T=1.0)


def cases():
    for p in (5, 10, 20, 30):
        ode = dn.systems.lattice(p, m=1.0, T=0.5)
        yield f"lattice p = {p}", ode, {"fixed_time_step": True, "initial_time_step": 0.125,
                                        "nonlinear_solver": "fixed-point"}, "cG(1)", 3
    for masses in (50, 250, 2500):
        ode, _ = problems.mass_spring_chain(masses)
        yield f"chain, {masses} masses", ode, {"fixed_time_step": True,
                                               "initial_time_step": 0.05}, "cG(1)", 3
    yield "reaction-diffusion 60 x 60", reaction_diffusion(), {"tolerance": 1e-4}, "cG(2)", 4


def measure(name, ode, parameters, method, degree):
    sol = dn.solve(ode, method, number_of_samples=2, **parameters)
    final, integral = resolve({ode.states[0]: 1.0, ode.states[-1]: 1.0}, ode)
    _, _, kl, ku = lower(ode).ordering
    record = {"problem": name, "N": ode.N, "kl + ku": kl + ku, "r": degree,
              "chosen": "sparse" if wide_band(degree * ode.N, degree * (kl + ku + 2))
              else "banded"}
    duals = {}
    for solver in ("banded", "sparse"):
        solve_dual(sol, final, integral, degree, linear_solver=solver)  # compile, warm up
        cpu = time.process_time()
        duals[solver], primal = solve_dual(sol, final, integral, degree, linear_solver=solver)
        intervals = len(primal.grid) - 1
        record["intervals"] = intervals
        record[f"{solver}_s"] = (time.process_time() - cpu) / intervals
    scale = np.max(np.abs(duals["banded"].coef))
    record["difference"] = float(np.max(np.abs(duals["banded"].coef - duals["sparse"].coef))
                                 / scale)
    return record


def write(folder, records):
    lines = [
        "# The dual's stage systems: banded LU against splu", "",
        ("Produced by `benchmarks/run_dual_lu.py` (see its docstring). CPU seconds per interval "
         "of the union grid (Jacobian evaluations, assembly and factorisation), 2-core machine "
         "shared with other jobs. Band: kl + ku of the Jacobian in its bandwidth ordering; the "
         "stage matrix's band is r (kl + ku + 2). Chosen: what `estimate_error` uses by "
         "default (`dolfinode.linalg.wide_band`). Difference: max |phi_banded - phi_splu| / "
         "max |phi|."), "",
        ("| problem | N | kl + ku | r | intervals | banded s | splu s | banded / splu | chosen "
         "| difference |"),
        "|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        lines.append(f"| {r['problem']} | {r['N']} | {r['kl + ku']} | {r['r']} | "
                     f"{r['intervals']} | {r['banded_s']:.3g} | {r['sparse_s']:.3g} | "
                     f"{r['banded_s'] / r['sparse_s']:.2g} | {r['chosen']} | "
                     f"{r['difference']:.1e} |")
    (folder / "dual_lu.md").write_text("\n".join(lines) + "\n")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    output = Path(parser.parse_args().output)
    records = []
    for case in cases():
        records.append(measure(*case))
        print(records[-1], flush=True)
    output.mkdir(parents=True, exist_ok=True)
    (output / "dual_lu.json").write_text(json.dumps(records, indent=1))
    write(output, records)


if __name__ == "__main__":
    main()
