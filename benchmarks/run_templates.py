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
  rounding level with fixed steps, did not converge). Automatic modeling (issue 5), which the
  issue's T = 10 run needs, is not available yet: this short T measures the cost per
  component-element, solve / (N x steps), not a demo run. Wall and CPU time are recorded.
* memory: tracemalloc peak of Python/numpy allocations during build + lower + solve, and the
  process's peak RSS.

Part 2, code generation (p = 3 ... 30): lowering with an empty kernel cache of the template
lattice and of the per-expression lattice (the DOLFIN demo transcribed in
tests/systems/test_particles.py), the latter while it takes under ~60 s.

Writes templates.json (the raw records), templates.csv, templates_codegen.csv, templates.md
and templates.png to the output folder; ``--rewrite`` regenerates the last four from the json.

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


def _timed(function, *args, **kwargs):
    """(result, wall seconds, CPU seconds of this process) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def one_size(p):
    """Measure one lattice size in this process; prints a JSON record."""
    import numpy as np

    import dolfinode as dn
    from dolfinode.compile import lower, lowering
    from dolfinode.solve import newton_memory

    tracemalloc.start()
    ode, build, build_cpu = _timed(dn.systems.lattice, p, T=STEPS * K)
    compiled, first_lower, first_lower_cpu = _timed(lower, ode)
    lowering._loaded.clear()  # as a new process would: the library comes from the disk cache
    again, cached_build, _ = _timed(dn.systems.lattice, p, T=STEPS * K)
    _, cached_lower, cached_lower_cpu = _timed(lower, again)
    record = {"p": p, "N": ode.N, "springs": ode.templates[1].cells, "nnz": int(compiled.nnz),
              "build_s": build, "build_cpu_s": build_cpu, "lower_s": first_lower,
              "lower_cpu_s": first_lower_cpu, "library_from_disk": bool(compiled.cached),
              "build_again_s": cached_build, "lower_cached_s": cached_lower,
              "lower_cached_cpu_s": cached_lower_cpu}
    _, _, kl, ku = compiled.ordering
    record["bandwidth"] = kl + ku
    for method in ("cG(1)", "dG(1)"):
        # the banded Newton matrix Newton would need (not allocated: fixed point is used)
        stages = 1 if method.startswith("cG") else 2
        record[f"newton_band_GB_{method}"] = newton_memory(ode.N, kl, ku, stages) / 2**30
        sol, seconds, cpu = _timed(dn.solve, ode, method, fixed_time_step=True,
                                   initial_time_step=K, nonlinear_solver="fixed-point",
                                   number_of_samples=2)
        slabs = sol.stats["time slabs"]
        assert np.all(np.isfinite(sol.y)) and not sol.stats["newton"]
        record[f"solve_{method}_s"] = seconds
        record[f"solve_cpu_{method}_s"] = cpu
        record[f"slabs_{method}"] = int(slabs)
        record[f"iterations_{method}"] = sol.stats["nonlinear iterations"]
        record[f"us_per_component_element_{method}"] = 1e6 * seconds / (ode.N * slabs)
        record[f"us_cpu_per_component_element_{method}"] = 1e6 * cpu / (ode.N * slabs)
        del sol
    record["tracemalloc_peak_MB"] = tracemalloc.get_traced_memory()[1] / 2**20
    record["maxrss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(record))


def codegen(p, expressions):
    """Lowering time with an empty cache: template lattice or per-expression lattice."""
    import dolfinode as dn
    from dolfinode.compile import lower
    sys.path.insert(0, str(ROOT / "tests" / "systems"))
    from test_particles import dolfin_lattice

    ode, declare, declare_cpu = _timed(dolfin_lattice if expressions else dn.systems.lattice, p)
    _, seconds, cpu = _timed(lower, ode)
    print(json.dumps({"p": p, "N": ode.N, "expressions": expressions, "declare_s": declare,
                      "declare_cpu_s": declare_cpu, "lower_s": seconds, "lower_cpu_s": cpu}))


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
    parser.add_argument("--rewrite", action="store_true",
                        help="only rewrite the tables and plot from OUTPUT/templates.json")
    args = parser.parse_args()
    output = Path(args.output)
    if args.rewrite:
        records = json.loads((output / "templates.json").read_text())
        return write(output, records["scale"], records["codegen"])
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
    output.mkdir(parents=True, exist_ok=True)
    (output / "templates.json").write_text(json.dumps({"scale": scale, "codegen": gen}, indent=1))
    write(output, scale, gen)


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
        right.semilogy([r["p"] for r in rows], [r["declare_s"] + r["lower_s"] for r in rows],
                       marker, label="per-expression" if expressions else "template")
    right.set(xlabel="p", ylabel="declare + lower, empty cache (s)", title="code generation")
    right.legend()
    fig.tight_layout()
    fig.savefig(folder / "templates.png", dpi=100)
    lines = [
        "# Templates: the DOLFIN lattice at scale", "",
        ("Produced by `benchmarks/run_templates.py` (one process per size; see its docstring for "
        "what is timed). The machine (2 cores) was shared with other jobs: wall-clock times "
        "are noisy, CPU times (`time.process_time`, this process) are given next to them."), "",
        "## Scale: build, lower, solve, memory", "",
        (f"**Not the issue's setting.** Issue 7 asks for the lattice with automatic modeling at "
        f"T = 10; automatic modeling is not available yet, so the solves here are plain "
        f"mono-adaptive cG(1) and dG(1) with fixed-point iteration and {STEPS} fixed steps "
        f"k = {K:g} (T = {STEPS * K:g}). They measure the cost per component-element, "
        "solve / (N x steps), not a demo run."), "",
        ("Build = `dn.systems.lattice(p)`; lower = `lower(ode)` (first: the first size compiles "
        "the C kernels with gcc, the others load the library compiled for p = "
        f"{scale[0]['p']} from the disk cache, since the code does not depend on p; cached: a "
        "second lowering after clearing the in-memory library table). Memory: tracemalloc "
        "peak of Python/numpy allocations and the process's peak RSS, over build + lower + "
        "both solves. Newton band: what the banded Newton matrix would take if the solve "
        "needed Newton (it is allocated only then; above half the available memory the solve "
        "stops with a SolverError instead)."), "",
        ("| p | N | springs | bandwidth | build s (wall / CPU) | lower s, first | "
        "lower s, cached | cG(1) solve s (wall / CPU) | cG(1) us / comp-elem (CPU) | "
        "dG(1) solve s (wall / CPU) | dG(1) us / comp-elem (CPU) | tracemalloc MB | "
        "max RSS MB | Newton band GB, cG(1) / dG(1) |"),
        "|" + "---|" * 14]
    for r in scale:
        first = f"{r['lower_s']:.2f}" + ("" if r["library_from_disk"] else " (gcc, cold)")
        cells = [r["p"], r["N"], r["springs"], r["bandwidth"],
                 f"{r['build_s']:.2f} / {r['build_cpu_s']:.2f}", first,
                 f"{r['lower_cached_s']:.2f}"]
        for method in ("cG(1)", "dG(1)"):
            cells += [f"{r[f'solve_{method}_s']:.2f} / {r[f'solve_cpu_{method}_s']:.2f}",
                      f"{r[f'us_cpu_per_component_element_{method}']:.3f}"]
        cells += [f"{r['tracemalloc_peak_MB']:.0f}", f"{r['maxrss_MB']:.0f}",
                  f"{r['newton_band_GB_cG(1)']:.3g} / {r['newton_band_GB_dG(1)']:.3g}"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += [
        "", "## Code generation: template versus per-expression", "",
        ("Empty kernel cache per run; declare = building the ODE (sympy expressions for the "
        "per-expression lattice), lower = pattern + C generation + gcc. The per-expression "
        "series stops after the first size above 60 s. CPU times exclude gcc (a child "
         "process)."), "",
        "| p | N | kind | declare s (wall / CPU) | lower s (wall / CPU) |",
        "|---|---|---|---|---|"]
    for r in gen:
        kind = "per-expression" if r["expressions"] else "template"
        lines.append(f"| {r['p']} | {r['N']} | {kind} | {r['declare_s']:.2f} / "
                     f"{r['declare_cpu_s']:.2f} | {r['lower_s']:.2f} / {r['lower_cpu_s']:.2f} |")
    lines += ["", "![templates](templates.png)", ""]
    (folder / "templates.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
