"""Multi-adaptive benchmark: dolfinode mcG(1..2)/mdG(1..2) against cG(1..2)/dG(1..2) and scipy
DOP853, LSODA, Radau and BDF on the problems of dolfinode.bench.multirate:

* ``oscillators``: two weakly coupled oscillators, frequencies 1 and 1000, T = 10;
* ``chain-stiff``: 200 unit masses, 10 of the 201 springs 1e6 times stiffer, T = 0.1;
* ``reaction-500``: the reaction front u' = 0.01 u_xx + 1000 u^2 (1 - u) on 500 points, T = 0.05.

A preset of ``dolfinode bench`` (see dolfinode.bench: CPU times, mescd and L2 scores, counts
including each run's number of elements); any of its options may follow, e.g. ``--quick`` (one
timed repeat, 3 s scipy limit) or ``--tolerances 1e-4,1e-6``. Writes
doc/benchmarks/multiadaptive.{csv,json,png,md}. dolfinode runs have no time limit, only
``--maximum-steps``; the multi-adaptive methods can take minutes at tight tolerances.

Usage::

    .venv/bin/python benchmarks/run_multiadaptive.py [--quick] [--tolerances ...]
"""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dolfinode.cli import main

PRESET = ["--problems", "oscillators,chain-stiff,reaction-500",
          "--methods", "mcG(1),mcG(2),mdG(1),mdG(2),cG(1),cG(2),dG(1),dG(2),DOP853,LSODA,Radau,BDF",
          "--tolerances", "1e-3,1e-4,1e-5,1e-6",
          "--name", "multiadaptive", "--output", os.path.relpath(ROOT / "doc" / "benchmarks"),
          "--force"]

if __name__ == "__main__":
    sys.exit(main(["bench", *PRESET, *sys.argv[1:]]))
