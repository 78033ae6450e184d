"""The ``dolfinode`` command.

``dolfinode info`` prints the default parameters; ``dolfinode bench`` runs the benchmark suite
(see :mod:`dolfinode.bench`); ``dolfinode compile`` compiles every time-slab loop and the
error estimate's kernels into the caches (NUMBA_CACHE_DIR, DOLFINODE_CACHE_DIR), for images
and CI, so that no later process compiles them.
"""
import argparse
import shlex
import sys

from dolfinode.parameters import DEFAULTS


def main(argv=None):
    parser = argparse.ArgumentParser(prog="dolfinode", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="print the solver parameters and their defaults")
    sub.add_parser("compile", help="compile and cache every loop ahead of the first solve")
    from dolfinode.bench import command as bench

    bench.add_arguments(sub.add_parser("bench", help="run the benchmark suite: work-precision "
                                                     "against scipy, tables and plots"))
    args = parser.parse_args(argv)
    if args.command == "info":
        width = max(len(name) for name in DEFAULTS)
        for name, value in DEFAULTS.items():
            print(f"{name:<{width}}  {value!r}")
    elif args.command == "compile":
        compile_everything()
    elif args.command == "bench":
        try:
            planned = bench.plan(args)
        except ValueError as exc:
            parser.error(str(exc))
        given = sys.argv[1:] if argv is None else argv
        bench.run(args, planned, command="dolfinode " + shlex.join(given))
    return 0


def compile_everything():
    """Compile (or load from the caches) the mono- and multi-adaptive loops, the dual's and
    the solution's kernels: a small oscillator solved with cG(2), dG(1), mcG(2) and its
    error estimated, each path once."""
    import sympy as sp

    import dolfinode as dn

    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=1.0)
    for method in ("cG(2)", "dG(1)", "mcG(2)"):
        sol = dn.solve(ode, method=method, tolerance=1e-4)
        sol(0.5)
        print(f"{method}: compiled", file=sys.stderr)
    dn.estimate_error(dn.solve(ode, method="cG(2)", tolerance=1e-4), goal={u: 1.0})
    print("estimate_error: compiled", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
