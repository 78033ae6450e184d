"""Template benchmark: the lattice of DOLFIN's modeling demo built with dn.systems.lattice.

Part 1, scale (p = 5, 50, 100, 300; N = 4 (p^2 + (p - 1)^2) components): each size runs in
a fresh Python process so that its peak resident memory (ru_maxrss) is its own. Measured
there, with time.perf_counter (wall) and time.process_time (CPU of this process):

* build: ``dn.systems.lattice(p)`` (numpy geometry, springs, templates, validation);
* lower: ``lower(ode)``: CSR pattern, incidence, header, loading the kernels. The first size
  runs with an empty kernel cache (a cold gcc compile), the others find the library on disk
  (the generated code is the same for every p), and a second ODE of the same size is lowered
  again after clearing the in-memory library table (cached);
* short solve (the issue's lattice, m = 1e-12, M = 100): cG(1) and dG(1), fixed-point
  iteration, 20 fixed steps k = 1e-8 (the small masses oscillate with angular frequency
  ~1.4e6, k w = 0.014): the cost per component-element, solve / (N x steps), of a second
  solve (the first also loads kernels and compiled loops);
* T = 10 without modeling: the same lattice with m = 1 (no fast scale: with m = 1e-12 the
  run needs ~10^8 steps, see the report), adaptive cG(1) and dG(1) at tolerance 1e-3 with
  fixed-point iteration and maximum_time_step = 0.1: cost per component-element (of a
  second solve, as above) and the memory of the stored solution per component-element;
* memory: tracemalloc peak of Python/numpy allocations and the process's peak RSS.

Part 2, automatic modeling (the issue's run): ``dn.solve(lattice(p), "cG(2)",
tolerance=1e-4, automatic_modeling=True, average_length=1e-4, control_points=4)`` with
T = 10, m = 1e-12, as demos/lattice.py, in a process of its own with a time limit; a run
over the limit records the innermost dolfinode frames it was in.

Part 3, code generation (p = 3 ... 30): lowering with an empty kernel cache of the template
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
import re
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STEPS, K = 20, 1e-8
#: The T = 10 run without modeling: slow small masses, adaptive steps up to 0.1.
PLAIN = {"m": 1.0, "T": 10.0, "tolerance": 1e-3, "maximum_time_step": 0.1}
#: The issue's run with automatic modeling (the settings of demos/lattice.py).
MODELING = {"method": "cG(2)", "tolerance": 1e-4, "automatic_modeling": True,
            "average_length": 1e-4, "control_points": 4}
METHODS = ("cG(1)", "dG(1)")


def _timed(function, *args, **kwargs):
    """(result, wall seconds, CPU seconds of this process) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def _maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one_size(p):
    """Measure one lattice size in this process; prints a JSON record."""
    import numpy as np

    import dolfinode as dn
    from dolfinode.compile import lower, lowering
    from dolfinode.linalg.newton_matrix import band_structure

    tracemalloc.start()
    ode, build, build_cpu = _timed(dn.systems.lattice, p, T=STEPS * K)
    compiled, first_lower, first_lower_cpu = _timed(lower, ode)
    lowering._loaded.clear()  # as a new process would: the library comes from the disk cache
    again, cached_build, cached_build_cpu = _timed(dn.systems.lattice, p, T=STEPS * K)
    _, cached_lower, cached_lower_cpu = _timed(lower, again)
    record = {"p": p, "N": ode.N, "springs": ode.templates[1].cells, "nnz": int(compiled.nnz),
              "build_s": build, "build_cpu_s": build_cpu, "lower_s": first_lower,
              "lower_cpu_s": first_lower_cpu, "library_from_disk": bool(compiled.cached),
              "build_again_s": cached_build, "build_again_cpu_s": cached_build_cpu,
              "lower_cached_s": cached_lower, "lower_cached_cpu_s": cached_lower_cpu}
    del again
    _, position, kl, ku = compiled.ordering
    record["bandwidth"] = kl + ku
    band = band_structure(position, kl, ku)
    for method in METHODS:
        # the banded Newton matrix Newton would need (not allocated: fixed point is used)
        stages = 1 if method.startswith("cG") else 2
        record[f"newton_band_GB_{method}"] = band.memory(stages) / 2**30
        short = {"fixed_time_step": True, "initial_time_step": K,
                 "nonlinear_solver": "fixed-point", "number_of_samples": 2}
        dn.solve(ode, method, **short)  # the first solve also loads kernels and compiled loops
        sol, seconds, cpu = _timed(dn.solve, ode, method, **short)
        slabs = sol.stats["time slabs"]
        assert np.all(np.isfinite(sol.y)) and not sol.stats["newton"]
        record[f"solve_{method}_s"] = seconds
        record[f"solve_cpu_{method}_s"] = cpu
        record[f"slabs_{method}"] = int(slabs)
        record[f"iterations_{method}"] = sol.stats["nonlinear iterations"]
        record[f"us_per_component_element_{method}"] = 1e6 * seconds / (ode.N * slabs)
        record[f"us_cpu_per_component_element_{method}"] = 1e6 * cpu / (ode.N * slabs)
        del sol
    del ode, compiled
    plain = dn.systems.lattice(p, m=PLAIN["m"], T=PLAIN["T"])
    adaptive = {"tolerance": PLAIN["tolerance"], "maximum_time_step": PLAIN["maximum_time_step"],
                "nonlinear_solver": "fixed-point", "number_of_samples": 2}
    for method in METHODS:
        dn.solve(plain, method, **adaptive)  # as above, the second solve is measured
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        sol, seconds, cpu = _timed(dn.solve, plain, method, **adaptive)
        elements = plain.N * sol.stats["time slabs"]
        assert np.all(np.isfinite(sol.y))
        stored = sol.values.nbytes + sol.t_start.nbytes + sol.k.nbytes
        record[f"plain_{method}"] = {
            "s": seconds, "cpu_s": cpu, "slabs": int(sol.stats["time slabs"]),
            "us_cpu_per_component_element": 1e6 * cpu / elements,
            "stored_bytes_per_component_element": stored / elements,
            "peak_bytes_per_component_element":
                (tracemalloc.get_traced_memory()[1] - before) / elements,
            "stored_MB": stored / 2**20}
        del sol
    record["tracemalloc_peak_MB"] = tracemalloc.get_traced_memory()[1] / 2**20
    record["maxrss_MB"] = _maxrss_mb()
    print(json.dumps(record))


def modeling(p):
    """The issue's run: lattice(p), T = 10, automatic modeling; prints a JSON record."""
    import dolfinode as dn
    from dolfinode.modeling import ModelingSolution

    ode, build, _ = _timed(dn.systems.lattice, p, T=10.0)
    before = _maxrss_mb()
    sol, seconds, cpu = _timed(dn.solve, ode, **MODELING)
    stats = sol.stats
    reduced = sol.model.reduced
    # the returned elements: the reduced solution's, and the start's when it is kept whole
    start_kept = not isinstance(sol, ModelingSolution)
    stored = reduced.values.nbytes + (sol.values.nbytes if start_kept else 0)
    print(json.dumps({"p": p, "N": ode.N, "finished": True, "build_s": build,
                      "solve_s": seconds, "solve_cpu_s": cpu,
                      "compile_s": stats["compile time"], "elements": int(stats["elements"]),
                      "slabs": int(stats["time slabs"]),
                      "inactive": int((~sol.model.active).sum()),
                      "us_cpu_per_element": 1e6 * cpu / stats["elements"],
                      "reduced_slabs": len(reduced.k), "start_kept": start_kept,
                      "stored_MB": stored / 2**20, "maxrss_before_MB": before,
                      "maxrss_MB": _maxrss_mb()}))


def codegen(p, expressions):
    """Lowering time with an empty cache: template lattice or per-expression lattice."""
    import dolfinode as dn
    from dolfinode.compile import lower
    sys.path.insert(0, str(ROOT / "tests" / "systems"))
    from test_particles import dolfin_lattice

    ode, declare, declare_cpu = _timed(dolfin_lattice if expressions else dn.systems.lattice, p)
    compiled, seconds, cpu = _timed(lower, ode)
    print(json.dumps({"p": p, "N": ode.N, "expressions": expressions, "declare_s": declare,
                      "declare_cpu_s": declare_cpu, "lower_s": seconds, "lower_cpu_s": cpu,
                      "by_shape": expressions and compiled.templates > 0}))


def run(arguments, cache, limit=None):
    """Run this script with ``arguments`` in a fresh process; its last JSON line, or a record
    of how it ended without one (time limit or error)."""
    env = dict(os.environ, DOLFINODE_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
    try:
        done = subprocess.run([sys.executable, __file__, *arguments], env=env, check=False,
                              capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired as stopped:
        return {"finished": False, "limit_s": limit, "where": _where(stopped.stderr)}
    if done.returncode != 0:
        timeout = "Timeout (" in done.stderr  # faulthandler's time limit
        return {"finished": False, "limit_s": limit if timeout else None,
                "error": None if timeout else done.stderr.strip().splitlines()[-1],
                "where": _where(done.stderr)}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _where(stderr):
    """The innermost dolfinode frames of the traceback faulthandler wrote before the limit."""
    text = stderr.decode() if isinstance(stderr, bytes) else (stderr or "")
    frames = [line.strip() for line in text.splitlines() if "dolfinode" in line]
    return frames[:4]


def _frame(line):
    """'File ".../dolfinode/ode.py", line 48 in f' -> 'dolfinode/ode.py:48 f'."""
    match = re.search(r'File ".*?(dolfinode/[^"]+)", line (\d+) in (\S+)', line)
    return f"{match[1]}:{match[2]} {match[3]}" if match else line


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--one", type=int)
    parser.add_argument("--modeling", type=int)
    parser.add_argument("--limit", type=float, default=900.0,
                        help="seconds per automatic-modeling run (default %(default)s)")
    parser.add_argument("--codegen", type=int)
    parser.add_argument("--codegen-limit", type=float, default=60.0,
                        help="stop the per-expression series after the first size above this "
                             "many seconds (default %(default)s)")
    parser.add_argument("--expressions", action="store_true")
    parser.add_argument("--sizes", help="comma-separated p for the scale and modeling parts "
                        "(default 5,50,100,300; --quick: 5,50); rows of other sizes are kept "
                        "from the json")
    parser.add_argument("--parts", default="scale,modeling,codegen",
                        help="comma-separated parts to run; the others are kept from the json")
    parser.add_argument("--rewrite", action="store_true",
                        help="only rewrite the tables and plot from OUTPUT/templates.json")
    args = parser.parse_args()
    output = Path(args.output)
    if args.one:
        return one_size(args.one)
    if args.modeling:
        import faulthandler
        faulthandler.dump_traceback_later(args.limit, exit=True)  # names where a slow run is
        return modeling(args.modeling)
    if args.codegen:
        return codegen(args.codegen, args.expressions)
    saved = output / "templates.json"
    records = json.loads(saved.read_text()) if saved.exists() else {}
    if args.rewrite:
        return write(output, records)
    parts = args.parts.split(",")
    sizes = [5, 50] if args.quick else [5, 50, 100, 300]
    if args.sizes:
        sizes = [int(p) for p in args.sizes.split(",")]
    cache = tempfile.mkdtemp(prefix="dn-templates-")  # empty: the first size compiles cold
    if "scale" in parts:
        records["scale"] = [r for r in records.get("scale", []) if r["p"] not in sizes]
        for p in sizes:
            records["scale"].append(run(["--one", str(p)], cache))
            print(records["scale"][-1], flush=True)
        records["scale"].sort(key=lambda r: r["p"])
    if "modeling" in parts:
        records["modeling"] = [r for r in records.get("modeling", []) if r["p"] not in sizes]
        for p in sizes:
            # the child stops itself (faulthandler) a little before the parent would kill it
            record = run(["--modeling", str(p), "--limit", str(args.limit)], cache,
                         args.limit + 30)
            record.setdefault("p", p)
            if record.get("limit_s"):
                record["limit_s"] = args.limit
            # again, with the kernels of the first run on disk; the kernels do not depend
            # on p, so the later sizes find them there already
            if record.get("finished") and p == sizes[0]:
                record["warm"] = run(["--modeling", str(p), "--limit", str(args.limit)], cache,
                                     args.limit + 30)
            records["modeling"].append(record)
            print(record, flush=True)
            if not record.get("finished"):
                break  # larger sizes only take longer
        records["modeling"].sort(key=lambda r: r["p"])
    if "codegen" in parts:
        records["codegen"] = []
        for expressions in (False, True):
            for p in ([3, 5, 7] if args.quick else [3, 5, 7, 10, 15, 20, 30]):
                record = run(["--codegen", str(p)] + (["--expressions"] if expressions else []),
                             tempfile.mkdtemp(prefix="dn-codegen-"))
                records["codegen"].append(record)
                print(record, flush=True)
                if record["declare_s"] + record["lower_s"] > args.codegen_limit:
                    break
    output.mkdir(parents=True, exist_ok=True)
    saved.write_text(json.dumps(records, indent=1))
    write(output, records)


def _scale_tables(scale):
    lines = [
        "## Scale: build, lower, solve, memory", "",
        ("Build = `dn.systems.lattice(p)`; lower = `lower(ode)` (first: the first size compiles "
         "the C kernels with gcc, the others load the library compiled for p = "
         f"{scale[0]['p']} from the disk cache, since the code does not depend on p; cached: a "
         "second build and lowering after clearing the in-memory library table, as in a new "
         "process). Memory: tracemalloc peak of Python/numpy allocations and the process's "
         "peak RSS, over everything the process did. Newton band: what the banded Newton "
         "matrix would take if the solve needed Newton (it is allocated only then; above half "
         "the available memory the solve stops with a SolverError instead)."), "",
        ("| p | N | springs | bandwidth | build s (wall / CPU) | lower s, first (wall / CPU) "
         "| build + lower s, cached (wall / CPU) | tracemalloc MB | max RSS MB "
         "| Newton band GB, cG(1) / dG(1) |"),
        "|" + "---|" * 10]
    for r in scale:
        first = f"{r['lower_s']:.2f} / {r['lower_cpu_s']:.2f}" + \
            ("" if r["library_from_disk"] else " (gcc, cold)")
        cached = (f"{r['build_again_s'] + r['lower_cached_s']:.2f} / "
                  f"{r['build_again_cpu_s'] + r['lower_cached_cpu_s']:.2f}")
        cells = [r["p"], r["N"], r["springs"], r["bandwidth"],
                 f"{r['build_s']:.2f} / {r['build_cpu_s']:.2f}", first, cached,
                 f"{r['tracemalloc_peak_MB']:.0f}", f"{r['maxrss_MB']:.0f}",
                 f"{r['newton_band_GB_cG(1)']:.3g} / {r['newton_band_GB_dG(1)']:.3g}"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += [
        "", (f"**Short solve** of the issue's lattice (m = 1e-12, M = 100): {STEPS} fixed steps "
             f"k = {K:g}, fixed-point iteration; us = CPU microseconds per component-element, "
             "solve / (N x steps), of the second solve (the first also loads the kernels "
             "and the compiled loops: up to 1.6 s at p = 5 after a cold compile)."), "",
        "| p | N | cG(1) s (wall / CPU) | cG(1) us | dG(1) s (wall / CPU) | dG(1) us |",
        "|---|---|---|---|---|---|"]
    for r in scale:
        cells = [r["p"], r["N"]]
        for method in METHODS:
            cells += [f"{r[f'solve_{method}_s']:.2f} / {r[f'solve_cpu_{method}_s']:.2f}",
                      f"{r[f'us_cpu_per_component_element_{method}']:.3f}"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += [
        "", (f"**T = {PLAIN['T']:g} without modeling**, the lattice with m = {PLAIN['m']:g} "
             f"(no fast scale), adaptive, tolerance {PLAIN['tolerance']:g}, maximum_time_step "
             f"{PLAIN['maximum_time_step']:g}, fixed-point iteration, the second solve "
             "measured. Stored: bytes of the "
             "solution's arrays per component-element; peak: tracemalloc peak during the solve "
             "per component-element."), "",
        ("| p | N | method | slabs | s (wall / CPU) | us / comp-elem (CPU) | stored B / "
         "comp-elem | peak B / comp-elem | stored MB |"),
        "|---|---|---|---|---|---|---|---|---|"]
    for r in scale:
        for method in METHODS:
            q = r[f"plain_{method}"]
            lines.append(f"| {r['p']} | {r['N']} | {method} | {q['slabs']} | {q['s']:.2f} / "
                         f"{q['cpu_s']:.2f} | {q['us_cpu_per_component_element']:.3f} | "
                         f"{q['stored_bytes_per_component_element']:.1f} | "
                         f"{q['peak_bytes_per_component_element']:.1f} | {q['stored_MB']:.0f} |")
    return lines


def _modeling_table(rows):
    lines = [
        "## The issue's run: automatic modeling, T = 10", "",
        ("`dn.solve(dn.systems.lattice(p), method='cG(2)', tolerance=1e-4, "
         "automatic_modeling=True, average_length=1e-4, control_points=4)`, m = 1e-12, "
         "M = 100, one process per size with a time limit; sizes after the first run that "
         "does not finish are not tried. The first size runs with an empty kernel cache and "
         "again with its kernels on disk; the windows and reduced models are template "
         "systems, whose kernels do not depend on p, so the later sizes find them on disk. "
         "Compile: kernel loading and generation inside the solve (wall). Elements are "
         "component-elements (N per time slab: cG(2) is mono-adaptive), over every inner "
         "solve; us = CPU microseconds per component-element. Stored: the reduced solution's "
         "slabs, whether the resolved start [t0, t_c] is kept element by element (below "
         "START_BYTES) and the MB of elements the returned solution holds. RSS: the "
         "process's peak resident memory (including the ~0.2 GB of Python, numpy, the "
         "compiled kernels and the lattice), before the solve (after building the lattice) "
         "and in all; per component: the solve's part, (max - before) / N."), "",
        ("| p | N | finished | solve s (wall / CPU) | compile s | elements | slabs | "
         "inactive | us CPU / comp-elem | stored: reduced slabs, start kept, MB | RSS before "
         "solve MB | max RSS MB | solve's RSS kB / component |"),
        "|" + "---|" * 13]

    def cells(r, label):
        stored = (f"{r['reduced_slabs']}, {'yes' if r['start_kept'] else 'no'}, "
                  f"{r['stored_MB']:.1f}")
        return (f"| {r['p']} | {r['N']} | {label} | {r['solve_s']:.1f} / "
                f"{r['solve_cpu_s']:.1f} | {r['compile_s']:.1f} | {r['elements']} | "
                f"{r['slabs']} | {r['inactive']} | {r['us_cpu_per_element']:.3f} | {stored} | "
                f"{r['maxrss_before_MB']:.0f} | {r['maxrss_MB']:.0f} | "
                f"{1024 * (r['maxrss_MB'] - r['maxrss_before_MB']) / r['N']:.1f} |")

    for r in rows:
        if r.get("finished"):
            w = r.get("warm") or {}
            lines.append(cells(r, "yes, empty kernel cache" if w else "yes"))
            if w.get("finished"):
                lines.append(cells(w, "yes, kernels cached"))
        else:
            why = (f"no: stopped at the {r['limit_s']:.0f} s limit" if r.get("limit_s")
                   else f"no: {r.get('error')}")
            where = " < ".join(_frame(f) for f in r.get("where", [])).replace("|", "/")
            lines.append(f"| {r['p']} | | {why} (in: {where}) |" + " |" * 10)
    if any(not r.get("finished") for r in rows):
        lines += ["", "'in:' gives the innermost frames of the run when it was stopped."]
    lines += ["", ("Almost all elements are those of the resolved windows (five windows of "
                   "2 tau, one build and four control points, with steps below the fast "
                   "period); the reduced model itself takes a few slabs. Each window is "
                   "solved in pieces of about WINDOW_PIECE_BYTES (64 MB) of elements, each "
                   "added to the window's running averages and dropped, so the windows' "
                   "memory does not grow with N; above START_BYTES (64 MB) the resolved start "
                   "[t0, t_c] is not stored (sol(t) there solves it again), and the returned "
                   "solution holds the reduced slabs.")]
    return lines


def _codegen_table(gen):
    lines = [
        "## Code generation: template versus per-expression", "",
        ("Empty kernel cache per run; declare = building the ODE (sympy expressions for the "
         "per-expression lattice), lower = pattern + C generation + gcc. The per-expression "
         "series stops after the first size above a time limit. CPU times exclude gcc (a "
         "child process). Per-expression, by shape: an expression system of N >= 256 whose "
         "right-hand sides take few shapes (the lattice's take 21) is lowered as templates, one "
         "per shape (`dolfinode.compile.lowering.STRUCTURED_MIN`)."), "",
        "| p | N | kind | declare s (wall / CPU) | lower s (wall / CPU) |",
        "|---|---|---|---|---|"]
    for r in gen:
        kind = "template"
        if r["expressions"]:
            kind = "per-expression, by shape" if r.get("by_shape") else "per-expression"
        lines.append(f"| {r['p']} | {r['N']} | {kind} | {r['declare_s']:.2f} / "
                     f"{r['declare_cpu_s']:.2f} | {r['lower_s']:.2f} / {r['lower_cpu_s']:.2f} |")
    return lines


def _plot(folder, scale, gen):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    N = [r["N"] for r in scale]
    for method in METHODS:
        left.loglog(N, [r[f"plain_{method}"]["cpu_s"] for r in scale], "o-",
                    label=f"T = {PLAIN['T']:g} solve {method}")
    left.loglog(N, [r["build_again_cpu_s"] + r["lower_cached_cpu_s"] for r in scale], "s-",
                label="build + lower (cached)")
    reference = scale[-1]["plain_cG(1)"]["cpu_s"] / scale[-1]["N"]
    left.loglog(N, [n * reference for n in N], "k:", label="linear in N")
    left.set(xlabel="components N", ylabel="CPU seconds", title="lattice")
    left.legend()
    for expressions, marker in ((False, "o-"), (True, "s-")):
        rows = [r for r in gen if r["expressions"] == expressions]
        right.semilogy([r["p"] for r in rows], [r["declare_s"] + r["lower_s"] for r in rows],
                       marker, label="per-expression" if expressions else "template")
    right.set(xlabel="p", ylabel="declare + lower, empty cache (s)", title="code generation")
    right.legend()
    fig.tight_layout()
    fig.savefig(folder / "templates.png", dpi=100)
    plt.close(fig)


def write(folder, records):
    scale, gen = records["scale"], records["codegen"]
    folder.mkdir(parents=True, exist_ok=True)
    flat = [{k: v for k, v in r.items() if not isinstance(v, dict)} |
            {f"{k}_{key}": value for k, v in r.items() if isinstance(v, dict)
             for key, value in v.items()} for r in scale]
    for name, rows in (("templates.csv", flat), ("templates_codegen.csv", gen)):
        with open(folder / name, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    _plot(folder, scale, gen)
    lines = [
        "# Templates: the DOLFIN lattice at scale", "",
        ("Produced by `benchmarks/run_templates.py` (one process per size; see its docstring "
         "for what is timed). The machine (2 cores) was shared with other jobs: wall-clock "
         "times are noisy, CPU times (`time.process_time`, this process) are given next to "
         "them."), ""]
    lines += _scale_tables(scale) + [""]
    if records.get("modeling"):
        lines += _modeling_table(records["modeling"]) + [""]
    lines += _codegen_table(gen) + ["", "![templates](templates.png)", ""]
    (folder / "templates.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
