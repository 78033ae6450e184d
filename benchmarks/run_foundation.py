"""Foundation work-precision benchmark: HIRES and the harmonic oscillator (T = 100), dolfinode
cG(1..3)/dG(1..3) against scipy Radau, BDF, LSODA and DOP853.

A preset of ``dolfinode bench`` (see dolfinode.bench); any of its options may follow, e.g.
``--quick`` or ``--tolerances 1e-4,1e-8``. Writes doc/benchmarks/foundation.{csv,json,png,md}.

Usage::

    .venv/bin/python benchmarks/run_foundation.py [--quick] [--output DIR]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dolfinode.cli import main

PRESET = ["--problems", "HIRES,harmonic",
          "--methods", "cG(1),cG(2),cG(3),dG(1),dG(2),dG(3),Radau,BDF,LSODA,DOP853",
          "--name", "foundation", "--output", str(ROOT / "doc" / "benchmarks")]

if __name__ == "__main__":
    sys.exit(main(["bench", *PRESET, *sys.argv[1:]]))
