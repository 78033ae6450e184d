"""The benchmark suite: every problem of dolfinode.bench, dolfinode cG(1..3)/dG(1..3) (and
cG(2)+modeling on the problems that declare automatic modeling) against scipy RK45, DOP853,
Radau, BDF and LSODA; rewrites the committed record doc/benchmarks/suite.{csv,json,png,md}.
Same as ``dolfinode bench --output doc/benchmarks --force``; any of its options may follow
(``--quick``, ``--problems``, ``--methods``, ``--tolerances``). The README's figures are
checked against this record by tests/test_readme.py.

Usage::

    .venv/bin/python benchmarks/run_suite.py            # full run
    .venv/bin/python benchmarks/run_suite.py --quick    # about a minute
"""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dolfinode.cli import main

if __name__ == "__main__":
    # relative paths: the tables record the command, which should not name this checkout
    sys.exit(main(["bench", "--output", os.path.relpath(ROOT / "doc" / "benchmarks"), "--force",
                   *sys.argv[1:]]))
