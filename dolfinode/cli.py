"""The ``dolfinode`` command: ``dolfinode info`` prints the default parameters."""
import argparse

from dolfinode.parameters import DEFAULTS


def main(argv=None):
    parser = argparse.ArgumentParser(prog="dolfinode", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="print the solver parameters and their defaults")
    args = parser.parse_args(argv)
    if args.command == "info":
        width = max(len(name) for name in DEFAULTS)
        for name, value in DEFAULTS.items():
            print(f"{name:<{width}}  {value!r}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
