"""Write the expected values of tests/timeslab/test_same_solutions.py.

Solves a handful of small problems with cG(2), dG(1), mcG(1), mcG(2) and mdG(1) and records
each solve's counts (slabs, elements, f evaluations, ...) and u(T) in
tests/timeslab/data/same_solutions.json. The test checks that a restructure of the loops
leaves them unchanged (counts exactly, u(T) to 1e-12 relative). After a change that alters the
algorithm on purpose (a new step control, Jacobian reuse), regenerate them and say so in the
commit::

    PYTHONPATH=$PWD python tests/timeslab/regenerate.py
"""
import json
import sys
from pathlib import Path

import dolfinode as dn
from dolfinode import problems
from dolfinode.bench.problems import rober

DATA = Path(__file__).with_name("data") / "same_solutions.json"
METHODS = ("cG(2)", "dG(1)", "mcG(1)", "mcG(2)", "mdG(1)")
#: The integer statistics compared exactly (and "sub-slabs" of the multi-adaptive solves).
COUNTS = ("time slabs", "elements", "rejected steps", "f evaluations", "jacobian evaluations",
          "nonlinear iterations", "failed nonlinear solves", "factorizations")


def cases():
    """name -> (ode, tolerance): smooth, mildly stiff, stiff with nonnegative components,
    a wave on a chain (windows), a front (freezing)."""
    return {
        "harmonic": (problems.harmonic(T=10.0)[0], 1e-6),
        "van der pol": (problems.van_der_pol(T=3.0), 1e-5),
        "hires": (problems.hires(T=5.0), 1e-5),
        "rober": (rober(T=100.0, nonnegative=True).ode, 1e-5),
        "chain": (problems.mass_spring_chain(12, T=4.0)[0], 1e-5),
        "front": (problems.reaction_diffusion_front(40, T=3.0), 1e-4),
    }


def record(ode, method, tolerance):
    """The counts and u(T) of one solve."""
    sol = dn.solve(ode, method=method, tolerance=tolerance)
    entry = {name: int(sol.stats[name]) for name in COUNTS + ("sub-slabs",)
             if name in sol.stats}
    entry["u(T)"] = [float(v) for v in sol(ode.T)]
    return entry


def main():
    data = {name: {method: record(ode, method, tolerance) for method in METHODS}
            for name, (ode, tolerance) in cases().items()}
    DATA.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {DATA}", file=sys.stderr)


if __name__ == "__main__":
    main()
