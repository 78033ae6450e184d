"""Peak memory against the stored history (issue 32), written to doc/benchmarks/memory.md.

Every case runs in its own process: after the imports and a small warm-up solve of the same
method (so that loading the compiled loops is not counted) the resident-set peak is reset
(/proc/self/clear_refs) and the case's peak above that baseline is reported with its
history, the elements a dense solve stores (mono-adaptive: t, k and (q + 1) N values per
slab; multi-adaptive: component, start, end and q + 1 values per element).

- chain: the mass-spring chain of ``dolfinode.problems`` (200 masses, N = 400, T = 1000), cG(1)
  and mcG(1), dense, samples only (101 samples) and streamed to HDF5;
- template: 10^5 decaying components (a TemplateODE), cG(1) with 2000 fixed steps, dense and
  samples only;
- build: the chain's mcG(1) run, from its stored chunks to the Solution;
- xdmf: ``write_trajectory`` of 1000 masses x 3000 steps, positions given as an array and as
  a function of the time: time, peak, file sizes against the positions' bytes.

Usage::

    .venv/bin/python benchmarks/run_memory.py [--output doc/benchmarks] [--cases chain,xdmf]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = ("chain", "template", "build", "xdmf")
#: The chain's final time: histories of 0.5 GB (cG(1)) and 0.7 GB (mcG(1)).
CHAIN_T = 1000.0


def _rss(field):
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith(field))


def _reset_peak():
    """Reset VmHWM to the current RSS; the baseline."""
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")
    return _rss("VmRSS:")


def _history_bytes(sol, N):
    """Bytes a dense solve stores for ``sol``'s elements (see the module docstring)."""
    stats, q = sol.stats, sol.method.q
    if stats["method"].startswith("m"):
        return stats["elements"] * 8 * (3 + q + 1)
    return stats["time slabs"] * 8 * (2 + (q + 1) * N)


def _solve_case(ode, method, parameters, warmup):
    import dolfinode as dn

    dn.solve(warmup, method, **{k: v for k, v in parameters.items()
                                if k in ("fixed_time_step",)},
             **({"initial_time_step": warmup.T / 10} if parameters.get("fixed_time_step")
                else {}))
    base = _reset_peak()
    start = time.perf_counter()
    sol = dn.solve(ode, method, **parameters)
    seconds = time.perf_counter() - start
    return {"peak": _rss("VmHWM:") - base, "history": _history_bytes(sol, ode.N),
            "seconds": seconds, "elements": sol.stats["elements"]}


def case_chain(kind, method):
    from dolfinode.problems import mass_spring_chain

    ode, _ = mass_spring_chain(200, T=CHAIN_T)
    small, _ = mass_spring_chain(3, T=1.0)
    parameters = {"tolerance": 1e-6}
    folder = tempfile.mkdtemp()
    if kind == "samples":
        parameters["dense_output"] = False
    elif kind == "hdf5":
        parameters["dense_output"] = os.path.join(folder, "run.h5")
    result = _solve_case(ode, method, parameters, small)
    if kind == "hdf5":
        result["file"] = os.path.getsize(parameters["dense_output"])
    return result


def _decay(n):
    import numpy as np
    import sympy as sp

    import dolfinode as dn

    x, c = sp.symbols("x c")
    decay = dn.Template(slots=(x,), terms={x: -c * x}, indices=np.arange(n)[:, None],
                        params=(c,), values=np.linspace(0.1, 1.0, n))
    return dn.TemplateODE(decay, u0=np.ones(n), T=1.0)


def case_template(kind, method):
    parameters = {"fixed_time_step": True, "initial_time_step": 1.0 / 2000,
                  "dense_output": kind == "dense"}
    return _solve_case(_decay(100_000), method, parameters, _decay(3))


def case_build(kind, method):
    """The chain's mcG(1) run, dense: the peak while its stored chunks become the Solution."""
    from dolfinode.io import history
    from dolfinode.problems import mass_spring_chain

    ode, _ = mass_spring_chain(200, T=CHAIN_T)
    small, _ = mass_spring_chain(3, T=1.0)
    finish, measured = history.InMemory.finish, {}

    def measured_finish(sink, completed):
        measured["history"] = sink.bytes
        measured["base"] = _reset_peak() - sink.bytes
        measured["start"] = time.perf_counter()
        return finish(sink, completed)

    history.InMemory.finish = measured_finish
    _solve_case(ode, method, {"tolerance": 1e-6}, small)
    return {"peak": _rss("VmHWM:") - measured["base"], "history": measured["history"],
            "seconds": time.perf_counter() - measured["start"]}


def case_xdmf(kind, method, steps=3000):
    import numpy as np

    from dolfinode.io import write_trajectory

    n = 1000
    rng = np.random.default_rng(0)
    points = rng.uniform(size=(n, 2))
    springs = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    times = np.linspace(0.0, 1.0, steps)

    def at(t):
        return points + 0.01 * np.sin(t)

    positions = points[:, :, None] + 0.01 * np.sin(times) if kind == "array" else at
    folder = Path(tempfile.mkdtemp())
    base = _reset_peak()
    start = time.perf_counter()
    path = write_trajectory(folder / "run.xdmf", points, springs, times, positions)
    seconds = time.perf_counter() - start
    return {"peak": _rss("VmHWM:") - base, "history": n * 2 * steps * 8, "seconds": seconds,
            "file": path.stat().st_size + path.with_suffix(".h5").stat().st_size}


def run(case, kind, method):
    """One case in a fresh process; its result dict."""
    command = [sys.executable, __file__, "--one", f"{case}:{kind}:{method}"]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        return {"error": result.stderr.strip().splitlines()[-1]}
    return json.loads(result.stdout.strip().splitlines()[-1])


PLAN = {"chain": [(k, m) for m in ("cG(1)", "mcG(1)") for k in ("dense", "samples", "hdf5")],
        "template": [(k, "cG(1)") for k in ("dense", "samples")],
        "build": [("dense", "mcG(1)")],
        "xdmf": [(k, "-") for k in ("array", "function")]}


#: What issue 32 measured before (main at fdc9652, another machine), for comparison.
BEFORE = ("Before (issue 32, main at fdc9652): the history was always kept, with no check "
          "against the available memory (a template system of 10^5 components took 10.9 GB, of "
          "10^6 components was killed by the OOM killer at 24.3 GB); building a multi-adaptive "
          "Solution peaked at 2.35 x its history (lexsort and reordered copies); the XDMF "
          "writer held the whole file in memory: 1000 masses x 3000 steps gave a 399 MB file "
          "(8.7 x the data) and a 795 MB peak.")


def _mb(x):
    return f"{x / 2**20:,.0f}"


def write(rows, output):
    output.mkdir(parents=True, exist_ok=True)
    (output / "memory.json").write_text(json.dumps(rows, indent=1))
    intro = (f"`benchmarks/run_memory.py` on {os.uname().nodename} ({os.cpu_count()} cores), "
             f"{time.strftime('%Y-%m-%d')}. Peak: the resident-set peak of the case above its "
             "process's baseline after the imports and a warm-up solve (build: from the stored "
             "chunks to the Solution, the history included); history: the bytes a dense solve "
             "stores for the same run (for the XDMF cases: the positions, n x 2 x steps "
             "doubles; the file holds positions and displacements in 3-D, 3x that).")
    header = ("| case | method | output | history [MB] | peak [MB] | peak / history | time [s] "
              "| file [MB] |")
    lines = ["# Memory against the stored history", "", intro, "", header,
             "|---|---|---|---:|---:|---:|---:|---:|"]
    after = ["", BEFORE]
    for row in rows:
        if "error" in row:
            lines.append(f"| {row['case']} | {row['method']} | {row['kind']} | failed: "
                         f"{row['error']} | | | | |")
            continue
        file = _mb(row["file"]) if "file" in row else ""
        lines.append(f"| {row['case']} | {row['method']} | {row['kind']} | "
                     f"{_mb(row['history'])} | {_mb(row['peak'])} | "
                     f"{row['peak'] / row['history']:.2f} | {row['seconds']:.1f} | {file} |")
    (output / "memory.md").write_text("\n".join(lines + after) + "\n")
    print("\n".join(lines))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", type=Path, default=Path("doc/benchmarks"))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        case, kind, method = args.one.split(":")
        print(json.dumps(globals()[f"case_{case}"](kind, method)))
        return
    rows = []
    for case in args.cases.split(","):
        for kind, method in PLAN[case]:
            rows.append({"case": case, "kind": kind, "method": method,
                         **run(case, kind, method)})
            print(rows[-1], flush=True)
    write(rows, args.output)


if __name__ == "__main__":
    main()
