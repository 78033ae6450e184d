"""``dolfinode bench``: run the suite and write its tables and plots."""
import argparse
import os
import subprocess
import time
from pathlib import Path

from dolfinode.bench import peer_report, peers, report
from dolfinode.bench.problems import PROBLEMS, QUICK_PROBLEMS, get_problem
from dolfinode.bench.runner import (
    MAXIMUM_STEPS,
    SCIPY_METHODS,
    TIME_LIMIT,
    check_methods,
    run_suite,
)

#: dolfinode's methods of a full run; "+modeling" runs only on problems that declare modeling.
DN_METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)", "cG(2)+modeling")
FULL_TOLERANCES = tuple(10.0 ** -e for e in range(3, 11))
#: The small stiff problems' sweep starts at 1e-2, the loosest tolerance the calibrated
#: mapping covers (doc/design/tolerance.md): dolfinode's 1e-3 runs gave 4.5-5.4 digits on
#: ROBER, VDPOL and POLLU, so the sweep had no run at 3-4 digits to compare there.
STIFF_TOLERANCES = tuple(10.0 ** -e for e in range(2, 11))
#: ``--peers``: (problems, dolfinode methods, scipy solvers, tolerances or None: the full
#: sweep) groups, each run with the installed compiled peers. Multi-adaptive methods where
#: components' time scales differ; no first-order methods on the Brusselator (at n = 1000,
#: dG(1) and cG(1) are slower than cG(2) at every accuracy, and dG(2) than cG(3)) nor on the
#: oscillating problems; the Brusselator from rtol 1e-1, where cG(2) and cG(3) deliver 2.4-3
#: digits (its rows at 4 digits are read off runs, not extrapolated); no scipy on the
#: Brusselator (lambdified f of 8000 expressions); dG(5) on the small stiff problems and
#: cG(5) on the seed model, which reach 8 digits in fewer slabs than q = 3 (VDPOL, seed).
PEER_GROUPS = (
    (("HIRES", "ROBER", "VDPOL", "POLLU"),
     ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)", "dG(5)"),
     ("Radau", "BDF", "LSODA"), STIFF_TOLERANCES),
    (("MEDAKZO",), ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)"),
     ("Radau", "BDF", "LSODA"), None),
    (("bruss-1000", "bruss-4000"), ("cG(2)", "cG(3)", "dG(3)"), (),
     tuple(10.0 ** -e for e in range(1, 11))),
    (("seed k=1e2", "seed k=1e4"), ("cG(2)", "cG(3)", "cG(5)", "dG(2)", "dG(3)", "mcG(2)", "mdG(2)"),
     ("DOP853", "Radau", "LSODA"), None),
    # to 1e-11: numbalsoda's DOP853 reached only 5.3 digits at 1e-8 on the chains
    (("chain-1e4", "chain-stiff"), ("cG(2)", "cG(3)", "mcG(2)", "mcG(3)", "mdG(2)"),
     ("DOP853", "Radau", "LSODA"), tuple(10.0 ** -e for e in range(3, 12))),
)
PEER_SCIPY = ("DOP853", "Radau", "BDF", "LSODA")
QUICK = {"methods": ("cG(2)", "dG(2)", "dG(3)", "DOP853", "Radau", "BDF", "LSODA"),
         "tolerances": (1e-4, 1e-7), "repeats": 1, "time_limit": 3.0}
REPEATS = 3
#: The default output folder, new for every run, in the current directory.
OUTPUT_PATTERN = "dolfinode-bench-%Y%m%d-%H%M%S"
#: The files a run writes into the output folder, per stem.
OUTPUT_SUFFIXES = (".csv", ".json", ".png", ".md")


def _list(text):
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:  # an empty list ran the whole default suite
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}; "
                                         "leave the option out for the default")
    return items


def _numbers(text):
    try:
        numbers = [float(x) for x in _list(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers such as 1e-3,1e-6, got {text!r}") from None
    outside = [x for x in numbers if not 0 < x < 1]
    if outside:
        raise argparse.ArgumentTypeError(f"tolerances must lie in (0, 1), got {outside[0]:g}")
    return numbers


def add_arguments(parser):
    parser.add_argument("--problems", type=_list, default=None,
                        help=f"comma-separated problem names (default: all of {', '.join(PROBLEMS)}"
                             f"; --quick: {', '.join(QUICK_PROBLEMS)})")
    parser.add_argument("--methods", type=_list, default=None,
                        help="comma-separated dolfinode methods and scipy solvers "
                             f"({', '.join(SCIPY_METHODS)}); default: "
                             f"{', '.join(DN_METHODS + SCIPY_METHODS)}; --quick: "
                             f"{', '.join(QUICK['methods'])}")
    parser.add_argument("--tolerances", type=_numbers,
                        default=None, help="comma-separated relative tolerances "
                                           "(default 1e-3, ..., 1e-10; --quick: 1e-4, 1e-7)")
    parser.add_argument("--quick", action="store_true",
                        help="four problems, seven methods, two tolerances, one timed repeat "
                             "(about a minute; default: off)")
    parser.add_argument("--repeats", type=int, default=None,
                        help=f"timed repeats per run, median (default {REPEATS}; --quick: "
                             f"{QUICK['repeats']})")
    parser.add_argument("--time-limit", type=float, default=None,
                        help=f"CPU seconds after which a scipy run is abandoned (default "
                             f"{TIME_LIMIT:g}; --quick: {QUICK['time_limit']:g})")
    parser.add_argument("--maximum-steps", type=int, default=None,
                        help=f"dolfinode's maximum_steps for every run (default {MAXIMUM_STEPS}; "
                             "it also bounds the memory of a stored solution)")
    parser.add_argument("--peers", action="store_true",
                        help="add the compiled peers that are installed (numbalsoda LSODA and "
                             "DOP853, CVODE through scikit-sundae, diffrax Kvaerno5 and Tsit5; "
                             "pip install dolfinode[bench]) and compare dolfinode with the best "
                             "peer; default problems: "
                             + "; ".join(", ".join(g) for g, *_ in PEER_GROUPS)
                             + "; the outputs are named peers.*")
    parser.add_argument("--output", default=None,
                        help="output folder (default: a new folder "
                             "dolfinode-bench-YYYYMMDD-HHMMSS in the current directory)")
    parser.add_argument("--name", default=None,
                        help="file stem of the outputs (default: suite; --peers: peers)")
    parser.add_argument("--force", action="store_true",
                        help="allow overwriting files that git tracks, such as the committed "
                             "records in doc/benchmarks (default: refuse)")
    parser.add_argument("--merge", action="store_true",
                        help="merge into the existing record OUTPUT/NAME.json: the problems run "
                             "replace theirs, the others are kept; all outputs are rewritten "
                             "(default: off)")
    parser.add_argument("--report-only", action="store_true",
                        help="run nothing: rewrite the tables, plot and README section from the "
                             "record OUTPUT/NAME.json (after a change of the report; default: "
                             "off)")
    parser.add_argument("--update-readme", metavar="README", default=None,
                        help="rewrite the benchmark-suite section of this README.md (default: "
                             "none)")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (default: a progress bar)")


def tracked_files(paths):
    """The existing files among ``paths`` that git tracks (none outside a git work tree or
    without git)."""
    tracked = []
    for path in map(Path, paths):
        if not path.is_file():
            continue
        try:
            listed = subprocess.run(["git", "ls-files", "--error-unmatch", "--", path.name],
                                    cwd=path.parent, capture_output=True, timeout=30, check=False)
        except (OSError, subprocess.SubprocessError):
            return []
        if listed.returncode == 0:
            tracked.append(path)
    return tracked


def _check_overwrite(args):
    """Refuse to write over files git tracks unless ``--force``."""
    out = Path(args.output)
    paths = [out / f"{args.name}{suffix}" for suffix in OUTPUT_SUFFIXES]
    if args.update_readme:
        paths.append(Path(args.update_readme))
    tracked = tracked_files(paths)
    if tracked and not args.force:
        raise ValueError(f"refusing to overwrite {', '.join(map(str, tracked))}: git tracks "
                         "them (committed records). Write elsewhere with --output, or pass "
                         "--force to overwrite them")


def _check_writable(folder):
    """Make the output ``folder`` now, so that a run that could not write its outputs fails
    before it runs instead of after (ValueError naming --output)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"cannot make the output folder {folder} ({error.strerror}); choose "
                         "another with --output") from error
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"the output folder {folder} is not writable; choose another with "
                         "--output")


def plan(args):
    """(groups, runner options) the arguments ask for, a group being (problems, methods,
    tolerances), run by one call of :func:`run_suite`; None for ``--report-only``. Sets the
    defaults of ``args.output`` and ``args.name``.

    Raises
    ------
    ValueError
        For an unknown problem or method, a non-positive number, a missing record for
        ``--merge`` or ``--report-only``, outputs that would overwrite files git tracks
        without ``--force``, or an output folder that cannot be made or written (made here).
    """
    if args.output is None:
        if args.merge or args.report_only:
            raise ValueError("--merge and --report-only need the --output folder of the record")
        args.output = time.strftime(OUTPUT_PATTERN)
    if args.name is None:
        args.name = "peers" if args.peers else "suite"
    record = Path(args.output) / f"{args.name}.json"
    if (args.merge or args.report_only) and not record.exists():
        raise ValueError(f"there is no record {record} to merge into or report from")
    _check_overwrite(args)
    if args.report_only:
        return None
    tolerances = list(args.tolerances or (QUICK["tolerances"] if args.quick
                                          else FULL_TOLERANCES))
    if not tolerances or any(not tol > 0 for tol in tolerances):
        raise ValueError(f"tolerances must be positive, got {tolerances}")
    groups = [([get_problem(n) for n in names], list(ms),
               list(args.tolerances or tols or tolerances))
              for names, ms, tols in _groups(args)]
    check_methods({m for _, ms, _ in groups for m in ms})
    options = {"repeats": (QUICK["repeats"] if args.quick else REPEATS) if args.repeats is None
               else args.repeats}
    if options["repeats"] < 1:
        raise ValueError(f"--repeats must be at least 1, got {args.repeats}")
    if args.quick:
        options["time_limit"] = QUICK["time_limit"]
    if args.maximum_steps is not None:
        if args.maximum_steps < 1:
            raise ValueError(f"--maximum-steps must be at least 1, got {args.maximum_steps}")
        options["maximum_steps"] = args.maximum_steps
    if args.time_limit is not None:
        if not args.time_limit > 0:
            raise ValueError(f"--time-limit must be positive, got {args.time_limit}")
        options["time_limit"] = args.time_limit
    _check_writable(Path(args.output))  # (last: a refused run leaves no folder)
    return groups, options


def _groups(args):
    """[(problem names, methods, tolerances or None)]: one group, or with ``--peers`` and no
    ``--methods`` the groups of :data:`PEER_GROUPS` (with ``--problems``, those of its problems
    that a group holds, and one group of the rest with every method); with ``--peers`` the
    installed compiled peers join every group."""
    names = args.problems or (QUICK_PROBLEMS if args.quick else list(PROBLEMS))
    if not args.peers:
        return [(names, args.methods or (QUICK["methods"] if args.quick
                                         else DN_METHODS + SCIPY_METHODS), None)]
    installed, _ = peers.available()
    if args.methods:
        return [(args.problems or [n for g, *_ in PEER_GROUPS for n in g],
                 list(args.methods) + installed, None)]
    groups = [([n for n in g if not args.problems or n in args.problems],
               ms + scipy + tuple(installed), tols) for g, ms, scipy, tols in PEER_GROUPS]
    grouped = {n for g, *_ in PEER_GROUPS for n in g}
    rest = [n for n in args.problems or () if n not in grouped]
    if rest:
        groups.append((rest, DN_METHODS[:-1] + PEER_SCIPY + tuple(installed), None))
    return [group for group in groups if group[0]]


def settings(options):
    """The run's limits and environment, for the record: time limit, maximum_steps, thread
    variables and the load average at the start."""
    env = [f"{k}={os.environ[k]}" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
           if k in os.environ]
    limit = options.get("time_limit", TIME_LIMIT)
    steps = options.get("maximum_steps", MAXIMUM_STEPS)
    return "; ".join([f"scipy runs abandoned after {limit:g} CPU s",
                      (f"dolfinode maximum_steps = {steps:,}, estimate_global_error=False "
                       "(the peers estimate no error at T)"),
                      f"load average {os.getloadavg()[0]:.1f} at the start", *env])


def run(args, planned, command="dolfinode bench"):
    """Run the suite as planned by :func:`plan` (None: only rewrite the outputs from the
    record); returns the headline dict."""
    start = time.perf_counter()
    out = Path(args.output)
    record = out / f"{args.name}.json"
    if planned is None:
        meta, rows, infos = report.read_record(record)
    else:
        groups, options = planned
        methods = list(dict.fromkeys(m for _, ms, _ in groups for m in ms))
        problems = [p for group, *_ in groups for p in group]
        tolerances = sorted({tol for *_, tols in groups for tol in tols}, reverse=True)
        meta = report.machine_info()   # before the run: the commit whose code is measured
        meta["settings"] = settings(options)
        if args.peers:
            meta["notes"] = peer_report.notes()
        rows, cases = [], []
        for group, group_methods, group_tolerances in groups:
            more_rows, more_cases = run_suite(group, group_methods, group_tolerances,
                                              progress=not args.no_progress, **options)
            rows += more_rows
            cases += more_cases
        meta["load_end"] = os.getloadavg()[0]
        meta.update(command=command, quick=bool(args.quick), tolerances=list(tolerances),
                    repeats=options["repeats"], methods=methods,
                    problems=[p.name for p in problems],
                    total_seconds=time.perf_counter() - start)
        infos = report.problem_info(cases)
        if args.merge:
            meta, rows, infos = report.merge(report.read_record(record), meta, rows, infos)
    if args.peers:
        heads = peer_report.write_outputs(out, args.name, meta, rows, infos)
        print(peer_report.summary_table(heads))
        print(f"wrote {out}/{args.name}.{{csv,json,png,md}} in "
              f"{time.perf_counter() - start:.0f} s")
        return heads
    heads = report.write_outputs(out, args.name, meta, rows, infos)
    print(report.summary_table(heads))
    print(f"wrote {out}/{args.name}.{{csv,json,png,md}} in "
          f"{time.perf_counter() - start:.0f} s")
    if args.update_readme:
        readme = Path(args.update_readme)

        def rel(p):
            try:
                return str(p.resolve().relative_to(readme.resolve().parent))
            except ValueError:
                return str(p)

        report.update_readme(readme, report.readme_paragraph(
            meta, heads, rel(out / f"{args.name}.md"), rel(out / f"{args.name}.png")))
    return heads
