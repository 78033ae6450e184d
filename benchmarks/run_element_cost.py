"""The cost of a multi-adaptive element against a mono-adaptive component-step (issue 29,
item 6: an element of mcG(q) at most 2x a component-step of cG(q) when all components share
one step).

The problem is the uniform chain without scale separation,
``dolfinode.problems.mass_spring_chain(100, T=200)`` (200 components), where every component
is active on about the same scale. Two settings:

* ``adaptive``: tolerance 1e-6, each method's own steps (mcG(q)'s slabs are synchronised
  where its partition would save less than ``SYNCHRONISE``, see
  ``dolfinode.timeslab.multi.loop``);
* ``fixed``: every component on one fixed step (``fixed_time_step=True``), so that mcG(q)
  and cG(q) take the same elements and solve the same equations.

Every solve runs without the global error estimate (``estimate_global_error=False``: its
dual solve, on by default for long runs of small systems, cost 0.7 s of a 0.8 s adaptive
cG(1) solve here and is not the element's cost). Every solve is timed by CPU time (``time.process_time``: the machine is shared), after one
untimed call per method (compile and load apart), in interleaved rounds; the table gives the
minimum over the rounds, the CPU time per element (per component-step for cG(q)), the ratio
mcG(q)/cG(q) per element and of the whole solve, and the error at T.

Usage::

    PYTHONPATH=$PWD python benchmarks/run_element_cost.py [--rounds 5] [--output doc/benchmarks]
"""
import argparse
import json
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

import dolfinode as dn
from dolfinode.problems import mass_spring_chain

TARGET = 2.0
#: The fixed steps: about as many slabs as the adaptive cG(q) at tolerance 1e-6.
FIXED_STEPS = {1: 0.005, 2: 0.1}


def settings():
    """(name, q, keyword arguments of dn.solve)."""
    rows = []
    for q in (1, 2):
        rows.append(("adaptive", q, {"tolerance": 1e-6}))
        rows.append(("fixed", q, {"fixed_time_step": True, "initial_time_step": FIXED_STEPS[q]}))
    return rows


def cpu_time(ode, method, kwargs):
    """(CPU seconds, solution) of one solve."""
    start = time.process_time()
    sol = dn.solve(ode, method, number_of_samples=2, estimate_global_error=False, **kwargs)
    return time.process_time() - start, sol


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    ode, exact = mass_spring_chain(100, T=200.0)
    rows = []
    for name, q, kwargs in settings():
        methods = [f"cG({q})", f"mcG({q})"]
        for method in methods:  # untimed: compile and load
            cpu_time(ode, method, kwargs)
        times = {method: [] for method in methods}
        solutions = {}
        for _ in range(args.rounds):
            for method in methods:
                seconds, solutions[method] = cpu_time(ode, method, kwargs)
                times[method].append(seconds)
        row = {"setting": name, "q": q, "kwargs": kwargs}
        for method in methods:
            sol = solutions[method]
            elements = int(sol.stats["elements"])
            best = min(times[method])
            row[method] = {
                "cpu": best, "elements": elements, "per_element": best / elements,
                "slabs": int(sol.stats["time slabs"]),
                "synchronised": sol.stats.get("synchronised slabs"),
                "error": float(np.abs(sol(ode.T) - exact(ode.T)).max())}
        mono, multi = (row[m] for m in methods)
        row["ratio_per_element"] = multi["per_element"] / mono["per_element"]
        row["ratio_solve"] = multi["cpu"] / mono["cpu"]
        rows.append(row)
        print(name, q, f"{row['ratio_per_element']:.2f} per element, "
              f"{row['ratio_solve']:.2f} per solve", flush=True)
    record = {
        "date": time.strftime("%Y-%m-%d"),
        "git": subprocess.run(["git", "rev-parse", "--short", "HEAD"], check=False,
                              capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip(),
        "machine": f"{platform.platform()}, {platform.processor() or platform.machine()}",
        "load": list(__import__("os").getloadavg()),
        "rounds": args.rounds, "rows": rows}
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / "element_cost.json").write_text(json.dumps(record, indent=1) + "\n")
    header = ("| setting | q | cG(q): CPU, component-steps, per step, error | "
              "mcG(q): CPU, elements (synchronised slabs / slabs), per element, error | "
              "ratio per element | ratio per solve |")
    lines = [header, "|---|---|---|---|---|---|"]
    for row in rows:
        mono, multi = row[f"cG({row['q']})"], row[f"mcG({row['q']})"]
        lines.append(
            f"| {row['setting']} | {row['q']} | {mono['cpu']:.3g} s, {mono['elements']:,}, "
            f"{1e9 * mono['per_element']:.0f} ns, {mono['error']:.2g} | "
            f"{multi['cpu']:.3g} s, {multi['elements']:,} ({multi['synchronised']} / "
            f"{multi['slabs']}), {1e9 * multi['per_element']:.0f} ns, {multi['error']:.2g} | "
            f"{row['ratio_per_element']:.2f} | {row['ratio_solve']:.2f} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
