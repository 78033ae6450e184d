"""Template benchmark: the lattice of DOLFIN's modeling demo built with dn.systems.lattice.

Part 1, scale (p = 5, 50, 100, 300; N = 4 (p^2 + (p - 1)^2) components): each size runs in
a fresh Python process so that its peak resident memory (ru_maxrss) is its own. Measured
there, with time.perf_counter:

* build: ``dn.systems.lattice(p)`` (numpy geometry, springs, templates, validation);
* lower: ``lower(ode)``: CSR pattern, incidence, header, loading the kernels. The first size
  runs with an empty kernel cache (a cold gcc compile), the others find the library on disk
  (the generated code is the same for every p), and a second ODE of the same size is lowered
  again after clearing the in-memory library table (cached);
* solve: cG(1) and dG(1) (mono-adaptive, fixed-point iteration) with ``fixed_time_step`` and
  k = 1e-8 over 20 steps (T = 2e-7), m = 1e-12, M = 100: the small masses oscillate with
  angular frequency ~1.4e6, so k w = 0.014 (at k = 1e-7 the fixed-point iteration, driven to
  rounding level with fixed steps, did not converge, and the default switches to Newton whose
  banded LU has bandwidth ~20 p). Automatic modeling (issue 5) is not on this branch;
  this short T measures the cost per component-element, solve / (N x steps), not a demo run.
* memory: tracemalloc peak of Python/numpy allocations during build + lower + solve, and the
  process's peak RSS.

Part 2, code generation (p = 3 ... 30): lowering with an empty kernel cache of the template
lattice and of the per-expression lattice (the DOLFIN demo transcribed in
tests/systems/test_particles.py), the latter while it takes under ~60 s.

Usage::

    DOLFINODE_CACHE_DIR=... python benchmarks/run_templates.py [--quick] [--output doc/benchmarks]
"""
import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STEPS, K = 20, 1e-8


def one_size(p):
    """Measure one lattice size in this process; prints a JSON record."""
    import numpy as np

    import dolfinode as dn
    from dolfinode.compile import lower, lowering

    tracemalloc.start()
    start = time.perf_counter()
    ode = dn.systems.lattice(p, T=STEPS * K)
    build = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lower(ode)
    first_lower, cached_library = time.perf_counter() - start, compiled.cached
    lowering._loaded.clear()  # as a new process would: the library comes from the disk cache
    again = dn.systems.lattice(p, T=STEPS * K)
    start = time.perf_counter()
    lower(again)
    cached_lower = time.perf_counter() - start
    record = {"p": p, "N": ode.N, "springs": ode.templates[1].cells, "nnz": int(compiled.nnz),
                  "build_s": build, "lower_s": first_lower, "library_from_disk": bool(cached_library),
                  "lower_cached_s": cached_lower}
    _, _, kl, ku = compiled.ordering
    for method in ("cG(1)", "dG(1)"):
        S = 1 if method.startswith("cG") else 2
        # timeslab/mono.py allocates the banded Newton matrix (S N rows, 2 kl S + ku S + ...
        # columns) even for fixed-point iteration; skip sizes where it would exceed 2 GB
        band_gb = S * ode.N * (2 * kl * S + ku * S + 3 * (S - 1) + 1) * 8 / 2**30
        record[f"newton_band_GB_{method}"] = band_gb
        if band_gb > 2:
            for name in ("solve", "slabs", "us_per_component_element"):
                record[f"{name}_{method}" + ("_s" if name == "solve" else "")] = float("nan")
            continue
        start = time.perf_counter()
        sol = dn.solve(ode, method, fixed_time_step=True, initial_time_step=K,
                       nonlinear_solver="fixed-point", number_of_samples=2)
        seconds = time.perf_counter() - start
        slabs = sol.stats["time slabs"]
        assert np.all(np.isfinite(sol.y))
        record[f"solve_{method}_s"] = seconds
        record[f"slabs_{method}"] = int(slabs)
        record[f"us_per_component_element_{method}"] = 1e6 * seconds / (ode.N * slabs)
    record["tracemalloc_peak_MB"] = tracemalloc.get_traced_memory()[1] / 2**20
    record["maxrss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(record))


def codegen(p, expressions):
    """Lowering time with an empty cache: template lattice or per-expression lattice."""
    import dolfinode as dn
    from dolfinode.compile import lower
    sys.path.insert(0, str(ROOT / "tests" / "systems"))
    from test_particles import dolfin_lattice

    start = time.perf_counter()
    ode = dolfin_lattice(p) if expressions else dn.systems.lattice(p)
    declare = time.perf_counter() - start
    start = time.perf_counter()
    lower(ode)
    print(json.dumps({"p": p, "N": ode.N, "expressions": expressions, "declare_s": declare,
                          "lower_s": time.perf_counter() - start}))


def run(arguments, cache):
    env = dict(os.environ, DOLFINODE_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, __file__, *arguments], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--one", type=int)
    parser.add_argument("--codegen", type=int)
    parser.add_argument("--expressions", action="store_true")
    args = parser.parse_args()
    if args.one:
        return one_size(args.one)
    if args.codegen:
        return codegen(args.codegen, args.expressions)
    sizes = [5, 50] if args.quick else [5, 50, 100, 300]
    cache = tempfile.mkdtemp(prefix="dn-templates-")  # empty: the first size compiles cold
    scale = []
    for p in sizes:
        scale.append(run(["--one", str(p)], cache))
        print(scale[-1], flush=True)
    gen = []
    for expressions in (False, True):
        for p in ([3, 5, 7] if args.quick else [3, 5, 7, 10, 15, 20, 30]):
            record = run(["--codegen", str(p)] + (["--expressions"] if expressions else []),
                         tempfile.mkdtemp(prefix="dn-codegen-"))
            gen.append(record)
            print(record, flush=True)
            if record["declare_s"] + record["lower_s"] > 60:
                break
    write(Path(args.output), scale, gen)


def write(folder, scale, gen):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "templates.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(scale[0]))
        writer.writeheader()
        writer.writerows(scale)
    with open(folder / "templates_codegen.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(gen[0]))
        writer.writeheader()
        writer.writerows(gen)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    N = [r["N"] for r in scale]
    for method in ("cG(1)", "dG(1)"):
        left.loglog(N, [r[f"solve_{method}_s"] for r in scale], "o-", label=f"solve {method}")
    left.loglog(N, [r["build_s"] + r["lower_cached_s"] for r in scale], "s-",
                label="build + lower (cached)")
    left.loglog(N, [r["N"] * scale[0]["solve_cG(1)_s"] / scale[0]["N"] for r in scale],
                "k:", label="linear in N")
    left.set(xlabel="components N", ylabel="seconds", title=f"lattice, {STEPS} steps")
    left.legend()
    for expressions, marker in ((False, "o-"), (True, "s-")):
        rows = [r for r in gen if r["expressions"] == expressions]
        right.semilogy([r["p"] for r in rows], [r["declare_s"] + r["lower_s"] for r in rows], marker,
                       label="per-expression" if expressions else "template")
    right.set(xlabel="p", ylabel="declare + lower, empty cache (s)", title="code generation")
    right.legend()
    fig.tight_layout()
    fig.savefig(folder / "templates.png", dpi=100)
    lines = ["# Templates: the DOLFIN lattice at scale", "",
             "Produced by `benchmarks/run_templates.py` (one process per size; see its docstring "
             "for what is timed). Machine shared with other jobs (2 cores), times are wall "
             "clock.", "",
             "## Scale: build, lower, solve, memory", "",
             f"Solve: mono-adaptive, fixed-point iteration, {STEPS} fixed steps k = {K} (T = {STEPS * K:g}); "
             "automatic modeling is not on this branch, so this is the cost per element, "
             "not the demo's T = 10. nan: not run, because `timeslab/mono.py` allocates the "
             "banded Newton matrix (last column) even for fixed-point iteration; it dominates "
             "the memory columns from p = 50 on.", "",
             "| p | N | springs | nnz(J) | build s | lower s (first) | lower s (cached) | "
             "cG(1) s | cG(1) us/comp-elem | dG(1) s | dG(1) us/comp-elem | tracemalloc MB | "
             "max RSS MB | Newton band GB cG/dG |", "|" + "---|" * 14]
    for r in scale:
        first = f"{r['lower_s']:.2f}" + ("" if r["library_from_disk"] else " (gcc, cold)")
        band = f"{r['newton_band_GB_cG(1)']:.1f} / {r['newton_band_GB_dG(1)']:.1f}"
        lines.append(f"| {r['p']} | {r['N']} | {r['springs']} | {r['nnz']} | {r['build_s']:.2f} | "
                     f"{first} | {r['lower_cached_s']:.2f} | {r['solve_cG(1)_s']:.2f} | "
                     f"{r['us_per_component_element_cG(1)']:.3f} | {r['solve_dG(1)_s']:.2f} | "
                     f"{r['us_per_component_element_dG(1)']:.3f} | "
                     f"{r['tracemalloc_peak_MB']:.0f} | {r['maxrss_MB']:.0f} | {band} |")
    lines += ["", "## Code generation: template versus per-expression", "",
              "Empty kernel cache per run; declare = building the ODE (sympy expressions for "
              "the per-expression lattice), lower = pattern + C generation + gcc.", "",
              "| p | N | kind | declare s | lower s |", "|---|---|---|---|---|"]
    for r in gen:
        kind = "per-expression" if r["expressions"] else "template"
        lines.append(f"| {r['p']} | {r['N']} | {kind} | {r['declare_s']:.2f} | {r['lower_s']:.2f} |")
    lines += ["", "![templates](templates.png)", ""]
    (folder / "templates.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
