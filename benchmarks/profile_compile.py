"""Where the cold start's compile time goes: per numba function and per compile phase.

Runs the stages of ``benchmarks/run_cold_start.py`` (import, first cG(2), first mcG(2), first
``estimate_error``) in a fresh process with empty caches, and attributes every second of
numba's compile to the function being compiled (exclusive of the functions it compiles in
turn) and to a phase:

=========  ==================================================================
typing     numba's passes before lowering: bytecode analysis, inlining, type inference
lowering   numba IR to LLVM IR (native_lowering, nopython_backend)
opt-fn     LLVM's per-function optimisation of the lowered module
opt-mod    LLVM's optimisation of the linked module (the function with the
           LLVM IR of every numba function it calls, optimised again)
codegen    machine code (the JIT's object, also written to numba's cache)
=========  ==================================================================

It also counts each function's compiled specialisations and the size (lines of LLVM IR)
of its linked module, splits the compile by stage, and charges numba's own functions (its
``np.empty``, string formatting, ...) to the dolfinode function whose compile needs them.
Prints the tables; ``--json FILE`` writes the records.

Usage::

    python benchmarks/profile_compile.py [--json FILE] [--top 30]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, resource, sys, time
from collections import defaultdict
from numba.core import event, codegen

def cpu():
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime

stack = []  # [name, kind, start, children]
seconds = defaultdict(float)  # (function, phase, stage) -> exclusive CPU seconds
compiles = defaultdict(int)
lines = {}
stage = ["import"]
within = defaultdict(float)  # (numba's own function, the dolfinode function compiling it) -> s

def current():
    for frame in reversed(stack):
        if frame[1] == "compile":
            return frame[0]
    return "(outside)"

def enter(name, kind):
    stack.append([name, kind, cpu(), 0.0])

def leave():
    name, kind, start, children = stack.pop()
    total = cpu() - start
    if stack:
        stack[-1][3] += total
    seconds[(current() if kind != "compile" else name,
             kind if kind != "compile" else "other", stage[0])] += total - children
    owner = current()
    if kind == "compile" and not name.startswith("dolfinode") and owner.startswith("dolfinode"):
        within[(name, owner)] += total  # with the numba functions it compiles in turn

LOWERING = {"native_lowering", "nopython_backend"}

class Listener(event.Listener):
    def __init__(self, kind):
        self.kind = kind
    def on_start(self, ev):
        if self.kind == "compile":
            d = ev.data["dispatcher"]
            name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
            compiles[name] += 1
            enter(name, "compile")
        else:
            name = ev.data["name"].split(" [")[0]
            enter(None, "lowering" if name in LOWERING else "typing")
    def on_end(self, ev):
        leave()

event.register("numba:compile", Listener("compile"))
event.register("numba:run_pass", Listener("pass"))

def timed(cls, method, phase):
    original = getattr(cls, method)
    def wrapper(self, *args, **kwargs):
        enter(None, phase)
        try:
            return original(self, *args, **kwargs)
        finally:
            leave()
            if method == "_optimize_final_module":
                lines[current()] = max(lines.get(current(), 0),
                                       str(self._final_module).count("\n"))
    setattr(cls, method, wrapper)

timed(codegen.CPUCodeLibrary, "_optimize_functions", "opt-fn")
timed(codegen.CPUCodeLibrary, "_optimize_final_module", "opt-mod")
timed(codegen.JITCodeLibrary, "_finalize_specific", "codegen")

marks = {}
start = cpu()
import dolfinode as dn
import sympy as sp
marks["import"] = cpu() - start
u, v = sp.symbols("u v")
ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=10.0)
start = cpu()
stage[0] = "cG(2)"
sol = dn.solve(ode, method="cG(2)", tolerance=1e-6)
marks["cG(2)"] = cpu() - start
start = cpu()
stage[0] = "mcG(2)"
dn.solve(ode, method="mcG(2)", tolerance=1e-6)
marks["mcG(2)"] = cpu() - start
start = cpu()
stage[0] = "estimate_error"
dn.estimate_error(sol, goal={u: 1.0})
marks["estimate_error"] = cpu() - start
print(json.dumps({"marks": marks, "compiles": compiles, "lines": lines,
                  "seconds": [[f, p, g, s] for (f, p, g), s in seconds.items()],
                  "within": [[f, o, s] for (f, o), s in within.items()]}))
"""


def profile():
    """The records of one cold run (empty caches in a temporary folder)."""
    with tempfile.TemporaryDirectory(prefix="dolfinode-profile-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(cache) / "numba"),
                   DOLFINODE_CACHE_DIR=str(Path(cache) / "kernels"),
                   PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        out = subprocess.run([sys.executable, "-c", CHILD], env=env, check=False,
                             capture_output=True, text=True)
    if out.returncode:
        sys.exit(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _short(name):
    """module.function of a dotted name (numba's: the overloaded function)."""
    return ".".join(name.replace(".<locals>", "").split(".")[-2:])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json")
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args()
    record = profile()
    if args.json:
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")
    phases = ["typing", "lowering", "opt-fn", "opt-mod", "codegen", "other"]
    table, stages = {}, {}
    for function, phase, stage, seconds in record["seconds"]:
        table.setdefault(function, dict.fromkeys(phases, 0.0))[phase] += seconds
        stages.setdefault(stage, {}).setdefault(function, 0.0)
        stages[stage][function] += seconds
    print("stages (CPU s):", {k: round(v, 2) for k, v in record["marks"].items()})
    totals = {p: sum(row[p] for row in table.values()) for p in phases}
    print("phases (CPU s):", {k: round(v, 2) for k, v in totals.items()})
    print(f"{'function':60s} {'n':>3s} {'lines':>7s} " + " ".join(f"{p:>8s}" for p in phases)
          + "    total")
    rows = sorted(table.items(), key=lambda item: -sum(item[1].values()))
    for function, row in rows[:args.top]:
        print(f"{function[-60:]:60s} {record['compiles'].get(function, 0):3d} "
              f"{record['lines'].get(function, 0):7d} "
              + " ".join(f"{row[p]:8.2f}" for p in phases) + f" {sum(row.values()):8.2f}")
    for stage, functions in stages.items():
        top = sorted(functions.items(), key=lambda item: -item[1])[:args.top // 3]
        print(f"\n{stage}: compile {sum(functions.values()):.2f} s; "
              + ", ".join(f"{_short(name)} {s:.2f}" for name, s in top))
    owners = {}
    for function, owner, seconds in record["within"]:
        owners[owner] = owners.get(owner, 0.0) + seconds
    print("\nnumba's own functions, by the dolfinode function compiling them (inclusive s): "
          + ", ".join(f"{_short(o)} {s:.2f}"
                      for o, s in sorted(owners.items(), key=lambda item: -item[1])[:12]))


if __name__ == "__main__":
    main()
