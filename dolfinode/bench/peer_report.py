"""The compiled-peer comparison (``dolfinode bench --peers``): ratios, targets and outputs.

At 4, 6, 8 and 10 correct digits (mescd at T), every method's time is read off its
work-precision curve (:func:`dolfinode.bench.report.curve`, Pareto front, log-time
interpolated; below its loosest run its fastest time, marked *) using the **minimum** of its
timed repeats. The ratio is dolfinode's fastest method / the fastest peer (compiled or scipy;
> 1: dolfinode slower), and against the issue's targets:

* small stiff problems (HIRES, ROBER, VDPOL, POLLU, MEDAKZO): at most 1.0x numbalsoda's LSODA
  at 6 digits and 0.5x at 8 and above;
* the Brusselator: at most 1.0x CVODE (band solver, exact Jacobian) at every level;
* the stiff-spring chains: the best multi-adaptive method at least 3x faster than the best
  peer (ratio <= 1/3) at every level.
"""
from importlib import metadata
from pathlib import Path

from dolfinode.bench import peers, report

#: Accuracy levels (mescd at T) of the comparison.
LEVELS = (4, 6, 8, 10)
_LSODA = ("numbalsoda-LSODA", {6: 1.0, 8: 0.5, 10: 0.5}, ("<= 1.0x numbalsoda LSODA at 6 "
                                                           "digits, <= 0.5x at 8+"))
_CVODE = ("CVODE-BDF", dict.fromkeys(LEVELS, 1.0), "<= 1.0x CVODE (band) at every level")
_MULTI = (None, dict.fromkeys(LEVELS, 1 / 3), ("multi-adaptive >= 3x faster than "
                                                "the best peer"))
#: problem -> (the peer it is compared with, None: the best peer; {level: largest ratio};
#: the target in words).
TARGETS = {"HIRES": _LSODA, "ROBER": _LSODA, "VDPOL": _LSODA, "POLLU": _LSODA,
           "MEDAKZO": _LSODA, "bruss-1000": _CVODE, "bruss-4000": _CVODE,
           "chain-1e4": _MULTI, "chain-stiff": _MULTI}
_PACKAGES = ("numbalsoda", "scikit-sundae", "diffrax", "jax")


def notes():
    """Header lines for the record: the peers' versions and the ones missing."""
    versions = []
    for name in _PACKAGES:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            pass
    _, missing = peers.available()
    return [f"Peers: {', '.join(versions) or 'none installed'}  ", *(f"{m}  " for m in missing)]


def _multi_adaptive(method):
    return method.startswith(("mcG", "mdG"))


def _fastest(times, keep):
    """(method, time, clamped) of the fastest of ``times`` (method -> (time, clamped) or
    None) whose method passes ``keep``; None when none reached the level."""
    hits = {m: v for m, v in times.items() if v is not None and keep(m)}
    if not hits:
        return None
    m = min(hits, key=lambda name: hits[name][0])
    return (m, *hits[m])


def level_entries(rows, problem, key="time_min_s"):
    """Per level of :data:`LEVELS`: every method's time there, dolfinode's fastest, the
    fastest peer (compiled or scipy), the target's reference and the ratios."""
    mine = [r for r in rows if r["problem"] == problem]
    solver_of = {r["method"]: r["solver"] for r in mine}
    curves = {m: report.curve(mine, problem, m, key) for m in solver_of}
    reference, limits, _ = TARGETS.get(problem, (None, {}, ""))
    multi_target = TARGETS.get(problem) is _MULTI
    entries = []
    for level in LEVELS:
        times = {m: report.time_at(c, level) for m, c in curves.items()}
        best = _fastest(times, lambda m: solver_of[m] == "dolfinode")
        mine_best = (_fastest(times, lambda m: solver_of[m] == "dolfinode"
                              and _multi_adaptive(m)) if multi_target else best)
        peer = _fastest(times, lambda m: solver_of[m] != "dolfinode")
        target = (peer if reference is None else
                  _fastest(times, lambda m: m == reference))
        entry = {"level": level, "times": {m: v and v[0] for m, v in times.items()},
                 "clamped": sorted(m for m, v in times.items() if v and v[1]),
                 "dolfinode_best": best, "peer_best": peer,
                 "ratio": best[1] / peer[1] if best and peer else None}
        if level in limits:
            ratio = mine_best[1] / target[1] if mine_best and target else None
            entry.update(target_ratio=ratio, target_limit=limits[level],
                         target_against=target and target[0],
                         target_met=None if ratio is None else ratio <= limits[level])
        entries.append(entry)
    return entries


def headline(rows, problems):
    """Per problem (``problems``: name -> :func:`~dolfinode.bench.report.problem_info` entry):
    its level entries and the verdict on its target (met at every level where both sides
    reached it; None without a target or a common level)."""
    out = {}
    for name, info in problems.items():
        entries = level_entries(rows, name)
        judged = [e["target_met"] for e in entries if e.get("target_met") is not None]
        out[name] = {"stiff": info["stiff"], "multiscale": info["multiscale"],
                     "entries": entries, "target": TARGETS.get(name, (None, {}, ""))[2],
                     "target_met": all(judged) if judged else None}
    return out


def _ratio_cell(ratio, a, b):
    if ratio is None:
        return "-"
    return f"{ratio:.2g} ({a} / {b})"


def summary_table(heads):
    """Per problem: dolfinode's best / the best peer at each level, and the target's ratios."""
    lines = ["| problem | " + " | ".join(f"{lv} digits" for lv in LEVELS)
             + " | target | target ratios (4/6/8/10) | verdict |",
             "|---|" + "---|" * (len(LEVELS) + 3)]
    for name, h in heads.items():
        cells = []
        for e in h["entries"]:
            b, p = e["dolfinode_best"], e["peer_best"]
            cells.append(_ratio_cell(e["ratio"], b and b[0], p and p[0]))
        target = " / ".join("-" if e.get("target_ratio") is None else
                            f"{e['target_ratio']:.2g}" for e in h["entries"]
                            if "target_limit" in e)
        verdict = {None: "not compared" if h["target"] else "", True: "met",
                   False: "**not met**"}[h["target_met"]]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {h['target'] or '-'} | {target or '-'} | {verdict} |")
    return "\n".join(lines)


def level_table(entry_list, methods):
    """One problem's levels: every method's time (minimum of repeats) and the ratio."""
    lines = ["| digits | " + " | ".join(methods) + " | dolfinode / best peer |",
             "|---|" + "---|" * (len(methods) + 1)]
    for e in entry_list:
        cells = [("-" if e["times"].get(m) is None else
                  report.fmt_s(e["times"][m]) + (" *" if m in e["clamped"] else ""))
                 for m in methods]
        ratio = "-" if e["ratio"] is None else f"{e['ratio']:.3g}"
        lines.append(f"| {e['level']} | " + " | ".join(cells) + f" | {ratio} |")
    return "\n".join(lines)


def compile_table(problems):
    lines = ["| problem | N | first dn.solve | dolfinode compile | peer builds |",
             "|---|---|---|---|---|"]
    for name, info in problems.items():
        c = info["compile"]
        builds = ", ".join(f"{m} {report.fmt_s(s)}" for m, s in c.get("peers", {}).items())
        lines.append(f"| {name} | {info['N']} | {report.fmt_s(c['first_call_s'])} | "
                     f"{report.fmt_s(c['compile_time_s'])} | {builds or '-'} |")
    return "\n".join(lines)


HOW = (
    ("Time: CPU time (`time.process_time`, all threads of the process) of one whole solve "
     "with output at 100 points (dolfinode: the `dn.solve` call and the evaluation of its "
     "Solution at the 100 points, 7-8 us of the time on HIRES, ROBER, VDPOL and POLLU; rows "
     "merged from runs before git 911915b timed the `dn.solve` call alone; from git 2fde9bd "
     "a repeated call takes the prepared path dn.solve keeps per option set, 50-90 us less "
     "Python per call on those four problems, as a user's repeated calls do), the **minimum** "
     "of the timed repeats, taken in interleaved rounds (one call of every run per round) "
     "after an untimed run; compile and build times are excluded (table above; a peer's build "
     "is its code generation and compile plus one warm-up solve at rtol 1e-3, and includes "
     "numbalsoda's driver compile on its first problem and JAX tracing)."),
    ("numbalsoda (C++ LSODA, DOP853): a numba cfunc right-hand side generated from the same "
     "sympy expressions (`dolfinode.bench.peers.numba_rhs_source`); LSODA forms its Jacobian by "
     "finite differences and factors it dense (run for N <= 400); f evals counted by the cfunc."),
    ("CVODE (SUNDIALS BDF through scikit-sundae): dolfinode's compiled C right-hand side and "
     "exact Jacobian called from the Python callbacks scikit-sundae requires (a few us per "
     "call); band linear solver where the Jacobian is banded and N >= 50, dense otherwise. "
     "The peer keeps the parameter vector its callbacks point to: before git 9a59794 it was "
     "freed once dolfinode had compiled the problem, and CVODE read reused memory (its mxstep "
     "warnings on the Brusselator); the CVODE rows of problems not re-run since may be "
     "affected. On MEDAKZO at rtol 1e-3 CVODE's own step collapses at t = 12.66 (mxstep)."),
    ("diffrax (Kvaerno5 on the stiff problems, Tsit5 on the others), JAX CPU in double "
     "precision, PID step control with default coefficients, first step 1e-8 for Kvaerno5; "
     "the right-hand side lambdified to JAX; the whole solve jit-compiled once per problem "
     "(Kvaerno5 for N <= 100, Tsit5 for N <= 400)."),
    ("scipy (DOP853, Radau, BDF, LSODA): lambdified NumPy right-hand sides and exact Jacobians, "
     "as in the benchmark suite; abandoned at the time limit."),
    ("Accuracy: mescd = min_i -log10(|y_i(T) - ref_i| / (atol/rtol + |ref_i|)) (Test Set), over "
     "the scored components. rtol = tolerance, atol = rtol x the problem's atol/rtol for every "
     "solver. A time at a level is read off the method's Pareto front, log-linearly "
     "interpolated in mescd; * = below the method's loosest run (its fastest time)."),
    ("The fastest peer at a level is the fastest among those whose sweep reached it: where a "
     "fast peer's tightest tolerance fell short of a level (LSODA and DOP853 deliver fewer "
     "digits than their rtol), the ratio there is against a slower peer and flatters "
     "dolfinode."),
)


def write_markdown(path, meta, rows, problems, heads, png_name):
    out = ["# Compiled peers: work-precision", "", f"Date: {meta['date']}  ",
           f"Machine: {meta['platform']}, {meta['cpu']}, {meta['cpu_count']} CPUs  ",
           (f"Versions: Python {meta['python']}, numpy {meta['numpy']}, scipy {meta['scipy']}, "
            f"numba {meta['numba']}, sympy {meta['sympy']}, dolfinode {meta['dolfinode']} "
            f"(git {meta['git_commit'] or '?'})  "),
           f"Command: `{meta['command']}` ({meta['total_seconds']:.0f} s)  ",
           (f"Tolerances: {', '.join(f'{x:g}' for x in meta['tolerances'])}; up to "
            f"{meta['repeats']} timed repeats (minimum); {meta.get('settings', '')}; load "
            f"average {meta.get('load_end', float('nan')):.1f} at the end  "),
           *meta.get("notes", []), *report._merged_lines(meta), "",
           "## dolfinode's fastest method / the fastest peer, at equal accuracy", "",
           summary_table(heads), "",
           ("Cells: time ratio (> 1: dolfinode slower) at 4/6/8/10 digits (mescd at T), with the "
            "two methods; '-': one side did not reach that accuracy. Target ratios: dolfinode's "
            "best (multi-adaptive on the chains) / the target's peer, at the target's levels."),
           "", f"![work-precision]({png_name})", "",
           "## Compile and build times (excluded from every timing)", "",
           compile_table(problems), "", "## How it is measured", "",
           *(f"* {h}" for h in HOW)]
    for name, h in heads.items():
        methods = list(dict.fromkeys(r["method"] for r in rows if r["problem"] == name))
        out += ["", f"## {name}", "", problems[name]["description"], "",
                level_table(h["entries"], methods), "", "### All runs", "",
                report.runs_table(rows, name, key="time_min_s")]
    out.append("")
    Path(path).write_text("\n".join(out))


def write_outputs(out_dir, stem, meta, rows, problems):
    """Write ``stem``.csv/.json/.png/.md to ``out_dir``; returns the headline dict."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    heads = headline(rows, problems)
    report.write_csv(out_dir / f"{stem}.csv", rows)
    report.write_json(out_dir / f"{stem}.json", meta, rows, problems, heads)
    report.plot(out_dir / f"{stem}.png", rows, problems, key="time_min_s",
                title="Work-precision: dolfinode vs compiled peers and scipy (minimum CPU time)")
    write_markdown(out_dir / f"{stem}.md", meta, rows, problems, heads, f"{stem}.png")
    return heads

