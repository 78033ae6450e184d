"""The dolfinode command.

``dolfinode info`` prints the default parameters; ``dolfinode cache info|clear`` shows or
empties the kernel cache; ``dolfinode compile`` compiles every time-slab loop and the
error estimate's kernels into the caches (NUMBA_CACHE_DIR, DOLFINODE_CACHE_DIR), for
images and CI; ``dolfinode bench`` runs the benchmark suite (see :mod:`dolfinode.bench`).
"""
import argparse
import shlex
import sys

import dolfinode


def main(argv=None):
    given = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog="dolfinode", description=dolfinode.__doc__.split("\n")[0])
    parser.add_argument("--version", action="version",
                        version=f"dolfinode {dolfinode.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="print the solver parameters and their defaults")
    cache = sub.add_parser("cache", help="the compiled kernel cache ($DOLFINODE_CACHE_DIR)")
    cache.add_argument("action", choices=("info", "clear"),
                       help="info: its folder, libraries and size; clear: remove its files")
    sub.add_parser("compile", help="compile and cache every loop ahead of the first solve")
    bench_parser = sub.add_parser("bench", help="run the benchmark suite: work-precision "
                                                "against scipy, tables and plots")
    if given[:1] == ["bench"]:  # its options need the benchmark library, imported only then
        from dolfinode.bench import command as bench

        bench.add_arguments(bench_parser)
    args = parser.parse_args(given)
    if args.command == "info":
        from dolfinode.parameters import DEFAULTS

        width = max(len(name) for name in DEFAULTS)
        for name, value in DEFAULTS.items():
            print(f"{name:<{width}}  {value!r}")
    elif args.command == "cache":
        _cache(args.action)
    elif args.command == "compile":
        _compile_everything()
    elif args.command == "bench":
        try:
            planned = bench.plan(args)
        except ValueError as exc:
            parser.error(str(exc))
        bench.run(args, planned, command="dolfinode " + shlex.join(given))
    return 0


def _cache(action):
    """``dolfinode cache info`` or ``dolfinode cache clear``."""
    from dolfinode.compile import cache

    if action == "clear":
        print(f"removed {cache.clear_cache()} files from {cache.cache_directory()}")
        return
    info = cache.cache_info()
    print(f"folder     {info['folder']} (set DOLFINODE_CACHE_DIR to move it)")
    print(f"libraries  {info['libraries']} ({info['valid']} valid; an invalid one is rebuilt "
          "when next used)")
    print(f"size       {info['bytes'] / 2**20:.2f} MiB")


def _compile_everything():
    """Compile (or load from the caches) the mono- and multi-adaptive loops, the dual's and
    the solution's kernels: a small oscillator solved with cG(2), dG(1), mcG(2) and its
    error estimated, each path once, and by a prepared dn.Solver; then the routines
    compiled on first use that it did not call (the stiff solvers, the multi-adaptive
    sweeps and error filter)."""
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
    dn.Solver(ode, method="dG(1)", tolerance=1e-4).solve()  # (its one compiled call)
    print("Solver.solve: compiled", file=sys.stderr)
    from dolfinode.compile.jit import compile_pending

    for what in compile_pending():  # (the paths the oscillator does not take: stiff, multi-rate)
        print(f"{what}: compiled", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
