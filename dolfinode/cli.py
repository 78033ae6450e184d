"""The ``dolfinode`` command.

``dolfinode info`` prints the default parameters; ``dolfinode bench`` runs the benchmark suite
(see :mod:`dolfinode.bench`).
"""
import argparse
import shlex
import sys

from dolfinode.parameters import DEFAULTS


def main(argv=None):
    parser = argparse.ArgumentParser(prog="dolfinode", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="print the solver parameters and their defaults")
    from dolfinode.bench import command as bench

    bench.add_arguments(sub.add_parser("bench", help="run the benchmark suite: work-precision "
                                                     "against scipy, tables and plots"))
    args = parser.parse_args(argv)
    if args.command == "info":
        width = max(len(name) for name in DEFAULTS)
        for name, value in DEFAULTS.items():
            print(f"{name:<{width}}  {value!r}")
    elif args.command == "bench":
        try:
            planned = bench.plan(args)
        except ValueError as exc:
            parser.error(str(exc))
        given = sys.argv[1:] if argv is None else argv
        bench.run(args, planned, command="dolfinode " + shlex.join(given))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
