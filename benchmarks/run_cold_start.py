"""Cold start: the CPU time of the first contact with empty caches, and again with them filled.

Each stage runs in a fresh Python process with empty (then, in a second pass, the filled)
numba and kernel caches (NUMBA_CACHE_DIR, DOLFINODE_CACHE_DIR in a temporary folder):
``import dolfinode``; the first cG(2) solve and its first ``sol(t)``; the first mcG(2)
solve and its first ``sol(t)``; the first ``estimate_error`` (on a cG(2) solution); the
total is given with and without the two ``sol(t)`` stages. A stage's CPU time is the
process's user + system time (with the C compiler it starts) minus that of the stages
before it, measured inside the process with ``resource.getrusage``. The problem is the
harmonic oscillator u'' = -u on [0, 10].

Writes cold_start.json and cold_start.md to the output folder.

Usage::

    python benchmarks/run_cold_start.py [--output doc/benchmarks]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Run in the child: prints one JSON line of cumulative CPU seconds after each stage.
CHILD = r"""
import json, resource, sys

def cpu():
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

marks = {}
import dolfinode as dn
import sympy as sp
marks["import dolfinode"] = cpu()
u, v = sp.symbols("u v")
ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=10.0)
sol = dn.solve(ode, method="cG(2)", tolerance=1e-6)
marks["first cG(2) solve"] = cpu()
sol(0.5)
marks["first cG(2) sol(t)"] = cpu()
multi = dn.solve(ode, method="mcG(2)", tolerance=1e-6)
marks["first mcG(2) solve"] = cpu()
multi(0.5)
marks["first mcG(2) sol(t)"] = cpu()
dn.estimate_error(sol, goal={u: 1.0})
marks["first estimate_error"] = cpu()
print(json.dumps(marks))
"""


def run_stages(cache):
    """Cumulative CPU seconds after each stage, in a fresh process with caches in ``cache``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(cache) / "numba"),
               DOLFINODE_CACHE_DIR=str(Path(cache) / "kernels"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, check=True,
                         capture_output=True, text=True)
    marks = json.loads(out.stdout.strip().splitlines()[-1])
    stages, before = {}, 0.0
    for name, total in marks.items():
        stages[name] = total - before
        before = total
    return stages, out.stderr


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    args = parser.parse_args()
    load = os.getloadavg()[0]  # (CPU time is the measure; a loaded machine inflates it a little)
    with tempfile.TemporaryDirectory(prefix="dolfinode-cold-") as cache:
        cold, notices = run_stages(cache)
        warm, _ = run_stages(cache)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True, check=False).stdout.strip()
    record = {"commit": commit, "load": load, "cold": cold, "warm": warm,
              "notices": [line for line in notices.splitlines() if "dolfinode:" in line]}
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / "cold_start.json").write_text(json.dumps(record, indent=1) + "\n")
    lines = ["# Cold start", "",
             ("CPU seconds (user + system, with the C compiler) of each stage in a fresh process, "
             "with empty caches and then with the caches the first process filled "
             f"(`benchmarks/run_cold_start.py`, git {commit}, load average {load:.1f})."), "",
             "| stage | empty caches (s) | filled caches (s) |", "|---|---|---|"]
    for name in cold:
        lines.append(f"| {name} | {cold[name]:.1f} | {warm[name]:.2f} |")
    lines.append(f"| total | {sum(cold.values()):.1f} | {sum(warm.values()):.2f} |")
    solves = [name for name in cold if not name.endswith("sol(t)")]
    lines.append(f"| total without sol(t) | {sum(cold[n] for n in solves):.1f} | "
                 f"{sum(warm[n] for n in solves):.2f} |")
    lines += ["", "Notices printed on stderr with empty caches:", ""]
    lines += [f"    {line}" for line in record["notices"]] or ["    (none)"]
    lines += ["", ("They go to the `dolfinode` logger (WARNING); silence them with "
              "`logging.getLogger(\"dolfinode\").setLevel(logging.ERROR)`. `dolfinode compile` "
              "fills the caches ahead (images, CI).")]
    (output / "cold_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
