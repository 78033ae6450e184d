"""Equal-accuracy comparison and the suite's outputs: CSV, JSON, work-precision PNG, Markdown.

Equal accuracy: for each method, log10(time) is interpolated linearly in mescd over its
tolerance sweep, reduced to its Pareto front (a run is dropped when a more accurate run of the
same method was faster), without extrapolation beyond its most accurate run; below its least
accurate run its fastest run's time is used (the measured cost of reaching at least that level,
marked clamped). At each level, dolfinode's fastest method is compared with scipy's fastest.
"""
import csv
import datetime
import json
import math
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

from dolfinode.bench.runner import ROW_FIELDS, accuracy_levels

#: Headline target: dolfinode faster than every scipy solver at these levels and tighter.
TARGET_LEVEL = 6
#: "Orders of magnitude" on the multiscale problems: at most this time ratio.
MULTISCALE_RATIO = 0.01
README_BEGIN, README_END = "<!-- BENCHMARK SUITE -->", "<!-- /BENCHMARK SUITE -->"


def fmt_s(x):
    """A duration for tables: '1.23 ms' or '4.56 s'."""
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x * 1e3:.3g} ms" if x < 1 else f"{x:.3g} s"


def accuracy(row):
    """Digits of a run: its mescd, or -log10 of its error at T when it has no mescd."""
    if row.get("mescd") is not None:
        return row["mescd"]
    return -math.log10(max(row["err_T"], 1e-300))


def curve(rows, problem, method, key="time_median_s"):
    """(digits, log10 time) of one method's sweep on one problem (digits: :func:`accuracy`),
    as its Pareto front sorted by accuracy; None when it has no successful run."""
    pts = sorted((accuracy(r), math.log10(r[key])) for r in rows
                 if r["problem"] == problem and r["method"] == method and r["status"] == "ok"
                 and r[key] and math.isfinite(accuracy(r)))
    front = []
    for acc, logt in reversed(pts):
        if not front or logt < front[-1][1]:
            front.append((acc, logt))
    front.reverse()
    return np.array(front) if front else None


def time_at(c, level):
    """(time in s, clamped) for a curve to reach ``level``; None above its best accuracy."""
    if c is None or level > c[-1, 0]:
        return None
    if level < c[0, 0]:
        return 10.0 ** float(c[0, 1]), True
    return 10.0 ** float(np.interp(level, c[:, 0], c[:, 1])), False


def equal_accuracy(rows, problem, key="time_median_s"):
    """Per mescd level reached by both sides: dolfinode's and scipy's fastest method, their
    times and the ratio dolfinode / scipy (< 1: dolfinode faster)."""
    mine = [r for r in rows if r["problem"] == problem]
    methods = {(r["solver"], r["method"]) for r in mine}
    curves = {sm: curve(mine, problem, sm[1], key) for sm in methods}
    table = []
    for level in accuracy_levels(mine):
        best = {}
        for solver in ("dolfinode", "scipy"):
            hits = {m: time_at(c, level) for (s, m), c in curves.items() if s == solver}
            hits = {m: v for m, v in hits.items() if v is not None}
            if hits:
                m = min(hits, key=lambda name: hits[name][0])
                best[solver] = (m, *hits[m])
        if len(best) < 2:
            continue
        (dm, dt, dc), (sm, st, sc) = best["dolfinode"], best["scipy"]
        table.append({"level": level, "dolfinode_best": dm, "dolfinode_time_s": dt,
                      "dolfinode_clamped": dc, "scipy_best": sm, "scipy_time_s": st,
                      "scipy_clamped": sc, "ratio": dt / st})
    return table


def headline(rows, problems):
    """Per problem: the equal-accuracy table and whether the target is met (dolfinode faster
    than scipy's best at every level >= TARGET_LEVEL that both reached)."""
    out = {}
    for p in problems:
        table = equal_accuracy(rows, p.name)
        tight = [e for e in table if e["level"] >= TARGET_LEVEL]
        out[p.name] = {"stiff": p.stiff, "multiscale": p.multiscale, "table": table,
                       "target_met": bool(tight) and all(e["ratio"] < 1 for e in tight),
                       "levels_compared": [e["level"] for e in tight]}
    return out


def machine_info(root=None):
    """Date, machine, versions and git commit, for the record."""
    import numba
    import scipy
    import sympy

    import dolfinode

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    root = root or Path(dolfinode.__file__).resolve().parent.parent
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                                capture_output=True, text=True, timeout=10, check=False).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"date": datetime.date.today().isoformat(), "platform": platform.platform(),
            "cpu": cpu, "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__,
            "sympy": sympy.__version__, "dolfinode": dolfinode.__version__,
            "git_commit": commit}


def write_csv(path, rows):
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=ROW_FIELDS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if r[k] is None else r[k]) for k in ROW_FIELDS})


def write_json(path, meta, rows, cases, heads):
    refs = {c.problem.name: {"description": c.problem.description,
                             "reference at T": c.problem.reference,
                             "reference trajectory": c.reference_note,
                             "atol/rtol": c.problem.atol_ratio, "stiff": c.problem.stiff,
                             "N": c.ode.N, "T": c.ode.T} for c in cases}
    compile_info = {c.problem.name: c.compile for c in cases}
    Path(path).write_text(json.dumps({"meta": meta, "problems": refs, "compile": compile_info,
                                      "headline": heads, "runs": rows}, indent=1,
                                     default=float))


def plot(path, rows, problems):
    """Work-precision: one log-log panel per problem, error 10^-mescd at T against time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys((r["solver"], r["method"]) for r in rows))
    colors = plt.get_cmap("tab20").colors
    style = {sm: {"color": colors[i % 20], "marker": "o" if sm[0] == "dolfinode" else "s",
                      "linestyle": "-" if sm[0] == "dolfinode" else "--"}
             for i, sm in enumerate(methods)}
    ncol = min(3, len(problems))
    nrow = math.ceil(len(problems) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol, 4.2 * nrow + 0.8), squeeze=False)
    for ax, p in zip(axes.ravel(), problems):
        for sm in methods:
            pts = sorted((r for r in rows if r["problem"] == p.name and (r["solver"], r["method"])
                          == sm and r["status"] == "ok"), key=lambda r: -r["tolerance"])
            if pts:
                ax.loglog([10.0 ** -r["mescd"] for r in pts], [r["time_median_s"] for r in pts],
                          markersize=4, linewidth=1.3, label=f"{sm[0]} {sm[1]}", **style[sm])
        ax.set_title(f"{p.name} (N = {p.ode.N}{', stiff' if p.stiff else ''})", fontsize=10)
        ax.set_xlabel("mixed error at T, $10^{-\\mathrm{mescd}}$")
        ax.set_ylabel("CPU time [s]")
        ax.grid(True, which="major", alpha=0.4)
        ax.invert_xaxis()
    for ax in axes.ravel()[len(problems):]:
        ax.set_visible(False)
    handles, _labels = {}, {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=6, fontsize=8,
               frameon=False)
    fig.suptitle("Work-precision: dolfinode vs scipy solve_ivp (right = more accurate, "
                 "lower = faster)", fontsize=11)
    fig.tight_layout(rect=(0, 0.8 / (4.2 * nrow + 0.8) + 0.03, 1, 0.97))
    save_figure(fig, path)


def single_panel():
    """A new figure with one panel (matplotlib's Agg backend): (fig, ax)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(6, 4.5))


def save_panel(fig, ax, path, title, xlabel, ylabel):
    """Label, grid and legend a log-log panel of :func:`single_panel`, and save it."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path):
    """Write ``fig`` to ``path`` (PNG) through a temporary file, so that a failure leaves no
    half-written plot, and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)


def _ratio_text(x):
    return f"{1 / x:.3g}x faster" if x < 1 else f"{x:.3g}x slower"


def _compared(h):
    """The equal-accuracy entries a problem's headline rests on: levels >= TARGET_LEVEL when
    both sides reached one, else all common levels."""
    tight = [e for e in h["table"] if e["level"] >= TARGET_LEVEL]
    return tight or h["table"]


def _verdict(h):
    if not h["levels_compared"]:
        return f"no level >= {TARGET_LEVEL} reached by both"
    return "met" if h["target_met"] else "not met"


def summary_table(heads):
    """One line per problem: the slowest and the fastest ratio over the compared levels."""
    lines = [("| problem | stiff | mescd levels | dolfinode / scipy: worst (level, methods) | "
             "best (level, methods) | target (>= 6 digits) |"), "|---|---|---|---|---|---|"]
    for name, h in heads.items():
        entries = _compared(h)
        if not entries:
            lines.append(f"| {name} | {'yes' if h['stiff'] else 'no'} | no common level | "
                         "| | |")
            continue
        worst = max(entries, key=lambda e: e["ratio"])
        best = min(entries, key=lambda e: e["ratio"])

        def cell(e):
            return (f"{e['ratio']:.3g} ({_ratio_text(e['ratio'])}; {e['level']}, "
                    f"{e['dolfinode_best']} vs {e['scipy_best']})")

        lines.append(f"| {name} | {'yes' if h['stiff'] else 'no'} | {entries[0]['level']}-"
                     f"{entries[-1]['level']} | {cell(worst)} | {cell(best)} | {_verdict(h)} |")
    return "\n".join(lines)


def target_section(heads):
    """The issue's target, problem by problem: faster than every scipy solver at equal accuracy
    on every stiff problem at >= TARGET_LEVEL digits, and by orders of magnitude (ratio <=
    MULTISCALE_RATIO) on the multiscale problems; where it is met and where not, with the
    measured ratios."""
    def ratios(h):
        entries = [e for e in h["table"] if e["level"] >= TARGET_LEVEL]
        if not entries:
            return None, f"no level >= {TARGET_LEVEL} reached by both sides"
        worst = max(entries, key=lambda e: e["ratio"])
        best = min(entries, key=lambda e: e["ratio"])
        text = (f"ratio {best['ratio']:.2g}-{worst['ratio']:.2g} over mescd "
                f"{entries[0]['level']}-{entries[-1]['level']}; worst at {worst['level']} "
                f"digits: {worst['dolfinode_best']} vs {worst['scipy_best']}")
        return worst["ratio"], text

    lines = [(f"Stiff problems (target: faster than scipy's fastest solver at every mescd >= "
              f"{TARGET_LEVEL} both sides reached):"), ""]
    for name, h in heads.items():
        if h["stiff"]:
            worst, text = ratios(h)
            verdict = "not compared" if worst is None else "met" if worst < 1 else "**not met**"
            lines.append(f"* {name}: {verdict} ({text})")
    lines += ["", (f"Multiscale problems (target: orders of magnitude, here ratio <= "
                   f"{MULTISCALE_RATIO:g} at every mescd >= {TARGET_LEVEL}):"), ""]
    for name, h in heads.items():
        if h.get("multiscale"):
            worst, text = ratios(h)
            verdict = ("not compared" if worst is None else "met" if worst <= MULTISCALE_RATIO
                       else "**not met**")
            lines.append(f"* {name}: {verdict} ({text})")
    return "\n".join(lines)


#: What the ratios do and do not say (written under the target in every suite.md).
CAVEATS = (
    ("Kernel compile times are excluded (the problems table lists the first `dn.solve`, which "
    "generates and compiles or loads the kernels; a cold compile takes seconds, more than most "
    "solves here)."),
    ("scipy's RK45, DOP853, Radau and BDF step in Python, and LSODA (Fortran) calls a Python "
    "right-hand side: much of each ratio is interpreter overhead, not the method. Compiled "
    "peers (SUNDIALS, Julia's solvers) are not measured here."),
    ("The seed models are solved here without automatic modeling, resolving every fast period "
    "(as scipy must); the orders of magnitude on multiscale problems are what automatic "
    "modeling (`doc/benchmarks/modeling.md`) and multi-adaptivity are for, and are not shown "
    "by these runs."),
    ("A level marked * in a problem's table is below that solver's loosest run: its fastest "
    "run's time is used. The accuracy measurable against a published reference is limited by "
    "the reference (MEDAKZO's is good to about 10 mixed digits)."),
)


def level_table(table):
    lines = ["| mescd | best dolfinode | time | best scipy | time | ratio |",
             "|---|---|---|---|---|---|"]
    for e in table:
        lines.append(f"| {e['level']} | {e['dolfinode_best']} | {fmt_s(e['dolfinode_time_s'])}"
                     f"{' *' if e['dolfinode_clamped'] else ''} | {e['scipy_best']} | "
                     f"{fmt_s(e['scipy_time_s'])}{' *' if e['scipy_clamped'] else ''} | "
                     f"{e['ratio']:.3g} |")
    return "\n".join(lines)


def runs_table(rows, problem):
    head = ["solver", "method", "tol", "time (median)", "reps", "mescd", "L2 (100 pts)",
            "f evals", "Jac", "LU", "steps", "rejected", "elements"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def n(x):
        return "n/a" if x is None else str(x)

    for r in rows:
        if r["problem"] != problem:
            continue
        cells = [r["solver"], r["method"], f"{r['tolerance']:.0e}"]
        if r["status"] != "ok":
            cells += [f"{r['status']}: {r['note']}".replace("|", "/")] + [""] * (len(head) - 4)
        else:
            cells += [fmt_s(r["time_median_s"]), str(r["repeats"]), f"{r['mescd']:.2f}",
                      f"{r['err_L2']:.2e}", n(r["f_evals"]), n(r["jacobians"]),
                      n(r["factorizations"]), n(r["steps"]), n(r["rejected"]),
                      n(r.get("elements"))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_markdown(path, meta, rows, cases, heads, png_name, title="Benchmark suite"):
    out = [f"# {title}", "", f"Date: {meta['date']}  ",
           f"Machine: {meta['platform']}, {meta['cpu']}, {meta['cpu_count']} CPUs  ",
           (f"Versions: Python {meta['python']}, numpy {meta['numpy']}, scipy {meta['scipy']}, "
           f"numba {meta['numba']}, sympy {meta['sympy']}, dolfinode {meta['dolfinode']} "
           f"(git {meta['git_commit'] or '?'})  "),
           f"Command: `{meta['command']}` ({meta['total_seconds']:.0f} s)  ",
           (f"Tolerances: {', '.join(f'{x:g}' for x in meta['tolerances'])}; "
           f"{meta['repeats']} timed repeats (median)"), "",
           "## Equal accuracy, at the tightest level both sides reached", "",
           summary_table(heads), "",
           ("Ratio = time of dolfinode's fastest method / time of scipy's fastest solver at the "
           "same mescd (< 1: dolfinode faster). * = that solver's loosest run was already more "
           "accurate; its fastest time is used. Target: faster than every scipy solver at every "
           f"level >= {TARGET_LEVEL} reached by both."), "",
           f"![work-precision]({png_name})", "", "## Target: where it is met", "",
           target_section(heads), "", "What the ratios do not say:", "",
           *(f"* {c}" for c in CAVEATS), "",
           "## How it is measured", "",
           ("* Tolerances: dolfinode `tolerance` = rtol, `absolute_tolerance` = atol; scipy "
           "`solve_ivp(rtol=rtol, atol=atol)`; atol = rtol x the problem's atol/rtol."),
           ("* scipy gets NumPy right-hand sides and exact Jacobians lambdified from the same "
           "sympy declaration (sparse CSC above 40 components)."),
           ("* Time: CPU time (`time.process_time`, the machine is shared) of the whole `dn.solve` / "
           "`solve_ivp` call (scipy with `t_eval` "
           "at 100 points), median of repeats in interleaved rounds after one untimed run; "
           "dolfinode's kernel compile is excluded (table below)."),
           ("* mescd = min_i -log10(|y_i(T) - ref_i| / (atol/rtol + |ref_i|)) (Test Set); "
           "L2 = RMS error over 100 equispaced points and all components."),
           ("* Counts: dolfinode `sol.stats` (steps = time slabs; elements = component "
           "steps, N x steps for cG/dG, fewer for mcG/mdG); scipy nfev/njev/nlu, steps "
           "and rejected attempts from an instrumented run (n/a for LSODA)."),
           ("* A method that fails or exceeds the time limit at one tolerance is skipped at the "
           "tighter ones."), "", "## Problems", "",
           ("| problem | N | stiff | description | reference at T | reference trajectory | "
           "atol/rtol | first dn.solve | compile |"), "|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        p = c.problem
        out.append(f"| {p.name} | {c.ode.N} | {'yes' if p.stiff else 'no'} | {p.description} | "
                   f"{p.reference} | {c.reference_note} | {p.atol_ratio:g} | "
                   f"{fmt_s(c.compile['first_call_s'])} | {fmt_s(c.compile['compile_time_s'])} |")
    for c in cases:
        name = c.problem.name
        out += ["", f"## {name}", "", "### Equal accuracy", "", level_table(heads[name]["table"]),
                "", "### All runs", "", runs_table(rows, name)]
    out.append("")
    Path(path).write_text("\n".join(out))


def readme_paragraph(meta, heads, md_rel, png_rel):
    """The README's headline: per problem, the range of dolfinode / scipy time ratios at equal
    accuracy, and whether the target is met on the stiff problems."""
    parts = []
    for name, h in heads.items():
        entries = _compared(h)
        if not entries:
            parts.append(f"{name}: no common accuracy level")
            continue
        ratios = [e["ratio"] for e in entries]
        lo, hi = min(ratios), max(ratios)
        span = f"{lo:.2g}" if f"{lo:.2g}" == f"{hi:.2g}" else f"{lo:.2g}-{hi:.2g}"
        parts.append(f"{name} {span} (mescd {entries[0]['level']}-{entries[-1]['level']})")
    stiff = [n for n, h in heads.items() if h["stiff"]]
    met = [n for n in stiff if heads[n]["target_met"]]
    missed = [f"{n} ({'slower at some level' if heads[n]['levels_compared'] else _verdict(heads[n])})"
              for n in stiff if not heads[n]["target_met"]]
    multi = [n for n, h in heads.items() if h.get("multiscale")]
    orders = [n for n in multi if heads[n]["levels_compared"]
              and max(e["ratio"] for e in _compared(heads[n])) <= MULTISCALE_RATIO]
    return "\n".join([
        README_BEGIN,
        ("**Benchmark suite.** `dolfinode bench` (or `python benchmarks/run_suite.py`; `--quick` "
        "for about a minute) runs the problem set of `dolfinode.bench` with dolfinode's methods "
        "and scipy's solvers and writes tables and work-precision plots to `doc/benchmarks/`."),
        "",
        (f"Measured {meta['date']} on a {meta['cpu_count']}-core machine shared with other jobs "
        f"({'quick run, ' if meta.get('quick') else ''}tolerances "
        f"{', '.join(f'{x:g}' for x in meta['tolerances'])}; `{meta['command']}`). Time of "
        "dolfinode's fastest method / time of scipy's fastest solver at equal accuracy (mescd "
        f"at T; < 1: dolfinode faster), over the levels >= {TARGET_LEVEL} both reached (all "
        f"common levels where there are none): {'; '.join(parts)}. Target (faster than every "
        f"scipy solver at >= {TARGET_LEVEL} digits on every stiff problem): met on "
        f"{', '.join(met) or 'none'}; not met on {', '.join(missed) or 'none'}. "
        + (f"Orders of magnitude (ratio <= {MULTISCALE_RATIO:g}) on the multiscale problems "
           f"({', '.join(multi)}): met on {', '.join(orders) or 'none'}. " if multi else "")
        + "Kernel compile "
        f"times are not included; times are CPU times. Tables: [{md_rel}]({md_rel}); plot: "
        f"[{png_rel}]({png_rel})."),
        README_END])


def update_readme(readme, block):
    """Replace the README section between README_BEGIN and README_END by ``block`` (appended
    to the Benchmarks section's end when the markers are missing)."""
    path = Path(readme)
    text = path.read_text()
    if README_BEGIN in text and README_END in text:
        start = text.index(README_BEGIN)
        end = text.index(README_END, start) + len(README_END)
        text = text[:start] + block + text[end:]
    else:
        anchor = text.find("\n## Documentation")
        anchor = len(text) if anchor < 0 else anchor
        text = text[:anchor] + "\n" + block + "\n" + text[anchor:]
    path.write_text(text)


def write_outputs(out_dir, stem, meta, rows, cases, title="Benchmark suite"):
    """Write ``stem``.csv/.json/.png/.md to ``out_dir``; returns the headline dict."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    problems = [c.problem for c in cases]
    heads = headline(rows, problems)
    write_csv(out_dir / f"{stem}.csv", rows)
    write_json(out_dir / f"{stem}.json", meta, rows, cases, heads)
    plot(out_dir / f"{stem}.png", rows, problems)
    write_markdown(out_dir / f"{stem}.md", meta, rows, cases, heads, f"{stem}.png", title)
    return heads
