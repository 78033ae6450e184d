"""The dolfinode command.

``dolfinode info`` prints the default parameters; ``dolfinode bench`` runs the benchmark suite
(see :mod:`dolfinode.bench`).
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
    elif args.command == "bench":
        try:
            planned = bench.plan(args)
        except ValueError as exc:
            parser.error(str(exc))
        bench.run(args, planned, command="dolfinode " + shlex.join(given))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
