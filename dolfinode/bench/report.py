"""Equal-accuracy comparison and the suite's outputs: CSV, JSON, work-precision PNG, Markdown.

Equal accuracy: for each method, log10(time) is interpolated linearly in mescd over its
tolerance sweep, reduced to its Pareto front (a run is dropped when a more accurate run of the
same method was faster), without extrapolation beyond its most accurate run; below its least
accurate run its fastest run's time is used (the measured cost of reaching at least that level,
marked clamped). At each level, dolfinode's fastest method is compared with scipy's fastest.
Where no scipy solver reached a level and every one was abandoned at the time limit, scipy's
time there is bounded below by the CPU time of its abandoned runs, and the ratio is an upper
bound (marked < in the tables).

On a problem that declares automatic modeling, the modeling variants ("cG(2)+modeling") are
also compared with scipy on their own (the problem's ``modeling_table``): they reach only a
few digits (the modeling error), and that comparison is the multiscale target's.
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

from dolfinode.bench.runner import ROW_FIELDS, accuracy_levels, split_modeling

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


def scipy_lower_bound(rows):
    """CPU seconds scipy needs at least, at a level none of its solvers reached: the smallest
    time of their abandoned runs (status "timeout") when every scipy solver of ``rows`` was
    abandoned; None otherwise (a solver that failed or ended its sweep below the level gives
    no bound)."""
    spent = {}
    for r in rows:
        if r["solver"] == "scipy":
            spent.setdefault(r["method"], [])
            if r["status"] == "timeout":
                spent[r["method"]].append(r["first_call_s"])
    if not spent or not all(spent.values()):
        return None
    return min(min(times) for times in spent.values())


def equal_accuracy(rows, problem, key="time_median_s"):
    """Per mescd level reached by both sides: dolfinode's and scipy's fastest method, their
    times and the ratio dolfinode / scipy (< 1: dolfinode faster). Where scipy reached no
    level but every solver was abandoned (:func:`scipy_lower_bound`), scipy's time is that
    lower bound ("scipy_bound" True) and the ratio an upper bound."""
    mine = [r for r in rows if r["problem"] == problem]
    methods = {(r["solver"], r["method"]) for r in mine}
    curves = {sm: curve(mine, problem, sm[1], key) for sm in methods}
    bound = scipy_lower_bound(mine)
    table = []
    for level in accuracy_levels(mine):
        best = {}
        for solver in ("dolfinode", "scipy"):
            hits = {m: time_at(c, level) for (s, m), c in curves.items() if s == solver}
            hits = {m: v for m, v in hits.items() if v is not None}
            if hits:
                m = min(hits, key=lambda name: hits[name][0])
                best[solver] = (m, *hits[m])
        bounded = "scipy" not in best and bound is not None
        if bounded:
            best["scipy"] = ("none (all over the time limit)", bound, False)
        if len(best) < 2:
            continue
        (dm, dt, dc), (sm, st, sc) = best["dolfinode"], best["scipy"]
        table.append({"level": level, "dolfinode_best": dm, "dolfinode_time_s": dt,
                      "dolfinode_clamped": dc, "scipy_best": sm, "scipy_time_s": st,
                      "scipy_clamped": sc, "scipy_bound": bounded, "ratio": dt / st})
    return table


def modeling_rows(rows):
    """The runs of the modeling variants and of scipy: the multiscale comparison's."""
    return [r for r in rows if r["solver"] == "scipy" or split_modeling(r["method"])[1]]


def headline(rows, problems):
    """Per problem (``problems``: name -> :func:`problem_info` entry): the equal-accuracy
    table and whether the target is met (dolfinode faster than scipy's best at every level
    >= TARGET_LEVEL that both reached); with modeling runs, also ``modeling_table``, the
    equal-accuracy table of the modeling variants alone against scipy."""
    out = {}
    for name, info in problems.items():
        table = equal_accuracy(rows, name)
        tight = [e for e in table if e["level"] >= TARGET_LEVEL]
        out[name] = {"stiff": info["stiff"], "multiscale": info["multiscale"], "table": table,
                     "target_met": bool(tight) and all(e["ratio"] < 1 for e in tight),
                     "levels_compared": [e["level"] for e in tight]}
        modeled = modeling_rows(r for r in rows if r["problem"] == name)
        if any(r["solver"] == "dolfinode" for r in modeled):
            out[name]["modeling_table"] = equal_accuracy(modeled, name)
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


def problem_info(cases):
    """What the record keeps of each problem, by name: its description, references, scoring,
    size and first-call (compile) times."""
    info = {}
    for c in cases:
        p = c.problem
        info[p.name] = {"description": p.description, "reference at T": p.reference,
                        "reference trajectory": c.reference_note, "atol/rtol": p.atol_ratio,
                        "stiff": p.stiff, "multiscale": p.multiscale,
                        "scored": None if p.scored is None else [str(c.ode.states[i])
                                                                 for i in p.scored],
                        "N": c.ode.N, "T": c.ode.T, "compile": c.compile}
    return info


def write_json(path, meta, rows, problems, heads):
    refs = {name: {k: v for k, v in info.items() if k != "compile"}
            for name, info in problems.items()}
    compile_info = {name: info["compile"] for name, info in problems.items()}
    Path(path).write_text(json.dumps({"meta": meta, "problems": refs, "compile": compile_info,
                                      "headline": heads, "runs": rows}, indent=1,
                                     default=float))


def read_record(path):
    """(meta, rows, problems) of a record written by :func:`write_json`; a field that an
    older record lacks is None (a problem's "multiscale" is then its headline's)."""
    record = json.loads(Path(path).read_text())
    problems = {name: {"multiscale": record["headline"][name].get("multiscale", False),
                       "scored": None, **entry, "compile": record["compile"][name]}
                for name, entry in record["problems"].items()}
    rows = [{k: r.get(k) for k in ROW_FIELDS} for r in record["runs"]]
    return record["meta"], rows, problems


def merge(record, meta, rows, problems):
    """Merge a run of some problems into a record ((meta, rows, problems) of
    :func:`read_record`): their runs and entries replace the record's, the others are kept
    (new problems last), and this run's meta is appended to the record's ``meta["merged"]``,
    from which earlier merges whose problems this run all replaces are dropped.
    Returns (meta, rows, problems) of the merged record."""
    old_meta, old_rows, old_problems = record
    problems = {**old_problems, **problems}
    order = {name: i for i, name in enumerate(problems)}
    rows = sorted([r for r in old_rows if r["problem"] not in meta["problems"]] + rows,
                  key=lambda r: order[r["problem"]])
    kept = [m for m in old_meta.get("merged", [])
            if not set(m["problems"]) <= set(meta["problems"])]
    merged = dict(old_meta, merged=kept + [meta])
    return merged, rows, problems


def plot(path, rows, problems, key="time_median_s",
         title="Work-precision: dolfinode vs scipy solve_ivp"):
    """Work-precision: one log-log panel per problem (``problems``: name -> :func:`problem_info`
    entry), error 10^-mescd at T against time (``key``: median or minimum)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys((r["solver"], r["method"]) for r in rows))
    colors = plt.get_cmap("tab20").colors
    # dolfinode: circles, solid; scipy: squares, dashed; compiled peers: triangles, dotted
    marks = {"dolfinode": ("o", "-"), "scipy": ("s", "--")}
    style = {sm: dict(zip(("marker", "linestyle"), marks.get(sm[0], ("^", ":"))),
                      color=colors[i % 20])
             for i, sm in enumerate(methods)}

    def label(sm):   # a compiled peer's label names its package already
        return f"{sm[0]} {sm[1]}" if sm[0] in marks else sm[1]

    ncol = min(3, len(problems))
    nrow = math.ceil(len(problems) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol, 4.2 * nrow + 0.8), squeeze=False)
    for ax, (name, info) in zip(axes.ravel(), problems.items()):
        for sm in methods:
            pts = sorted((r for r in rows if r["problem"] == name and (r["solver"], r["method"])
                          == sm and r["status"] == "ok"), key=lambda r: -r["tolerance"])
            if pts:
                ax.loglog([10.0 ** -r["mescd"] for r in pts], [r[key] for r in pts],
                          markersize=4, linewidth=1.3, label=label(sm), **style[sm])
        bound = scipy_lower_bound([r for r in rows if r["problem"] == name])
        if bound is not None:
            ax.axhline(bound, color="gray", linestyle=":", label="every scipy solver over the "
                                                                 "time limit (lower bound)")
        scored = f"; scored: {', '.join(info['scored'])}" if info.get("scored") else ""
        ax.set_title(f"{name} (N = {info['N']}{', stiff' if info['stiff'] else ''}{scored})",
                     fontsize=10)
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
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=2 * ncol,
               fontsize=8, frameon=False)
    fig.suptitle(f"{title} (right = more accurate, lower = faster)", fontsize=11)
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


def _ratio(e, digits=3):
    """A ratio for the tables: '0.05', or '< 0.05' when it is an upper bound."""
    return f"{'< ' if e.get('scipy_bound') else ''}{e['ratio']:.{digits}g}"


def _ratio_text(e):
    x = e["ratio"]
    if e.get("scipy_bound"):
        return f"over {1 / x:.3g}x faster"
    return f"{1 / x:.3g}x faster" if x < 1 else f"{x:.3g}x slower"


def _compared(h):
    """The equal-accuracy entries a problem's headline rests on: levels >= TARGET_LEVEL when
    both sides reached one, else all common levels."""
    tight = [e for e in h["table"] if e["level"] >= TARGET_LEVEL]
    return tight or h["table"]


def _multiscale_entries(h):
    """The entries of a multiscale problem's target: every level of its modeling table when
    it has modeling runs, else the levels >= TARGET_LEVEL."""
    if "modeling_table" in h:
        return h["modeling_table"]
    return [e for e in h["table"] if e["level"] >= TARGET_LEVEL]


def _range(entries):
    """The range of ratios over ``entries``: '0.5', '0.002-0.005', '< 0.01 to < 0.05'."""
    worst = max(entries, key=lambda e: e["ratio"])
    best = min(entries, key=lambda e: e["ratio"])
    low, high = _ratio(best, 2), _ratio(worst, 2)
    if low == high:
        return high
    return f"{low}{' to ' if '<' in low + high else '-'}{high}"


def _span(entries):
    """(worst ratio or None, text): the range of ratios over ``entries`` and the worst."""
    if not entries:
        return None, "no common level"
    worst = max(entries, key=lambda e: e["ratio"])
    return worst["ratio"], (f"ratio {_range(entries)} over mescd "
                            f"{entries[0]['level']}-{entries[-1]['level']}; worst at "
                            f"{worst['level']} digits: {worst['dolfinode_best']} vs "
                            f"{worst['scipy_best']}")


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
            return (f"{_ratio(e)} ({_ratio_text(e)}; {e['level']}, "
                    f"{e['dolfinode_best']} vs {e['scipy_best']})")

        lines.append(f"| {name} | {'yes' if h['stiff'] else 'no'} | {entries[0]['level']}-"
                     f"{entries[-1]['level']} | {cell(worst)} | {cell(best)} | {_verdict(h)} |")
    return "\n".join(lines)


def target_section(heads):
    """The issue's target, problem by problem: faster than every scipy solver at equal accuracy
    on every stiff problem at >= TARGET_LEVEL digits, and by orders of magnitude (ratio <=
    MULTISCALE_RATIO) on the multiscale problems, compared with the modeling runs where the
    problem has them; where it is met and where not, with the measured ratios."""
    lines = []
    if any(h["stiff"] for h in heads.values()):
        lines += [(f"Stiff problems (target: faster than scipy's fastest solver at every mescd >= "
                   f"{TARGET_LEVEL} both sides reached):"), ""]
    for name, h in heads.items():
        if h["stiff"]:
            worst, text = _span([e for e in h["table"] if e["level"] >= TARGET_LEVEL])
            verdict = "not compared" if worst is None else "met" if worst < 1 else "**not met**"
            lines.append(f"* {name}: {verdict} ({text})")
    if not any(h.get("multiscale") for h in heads.values()):
        return "\n".join(lines or ["No stiff or multiscale problem in this run."])
    lines += [""] * bool(lines) + [
        (f"Multiscale problems (target: orders of magnitude, here ratio <= "
         f"{MULTISCALE_RATIO:g} at every mescd >= {TARGET_LEVEL}; on a problem with "
         "automatic-modeling runs, those runs against scipy at every level both "
         "reached, since modeling reaches a few digits only; < = upper bound, every "
         "scipy solver over the time limit):"), ""]
    for name, h in heads.items():
        if h.get("multiscale"):
            worst, text = _span(_multiscale_entries(h))
            verdict = ("not compared" if worst is None else "met" if worst <= MULTISCALE_RATIO
                       else "**not met**")
            if "modeling_table" in h:
                plain = _span([e for e in h["table"] if e["level"] >= TARGET_LEVEL])[1]
                text = f"with automatic modeling: {text}. All methods, mescd >= 6: {plain}"
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
    ("The seed models are scored on x1 alone (the other components are the fast oscillation "
    "or carry a fast term of size 1/(8 sqrt(kappa)) that an averaged model omits; see "
    "`seed_model`). `cG(2)+modeling` solves them with automatic modeling (average_length "
    "30/sqrt(kappa)): its modeling error does not shrink with the tolerance, so it reaches a "
    "few digits only and is compared at those, mostly against scipy's loosest runs (*). "
    "Modeling resolves two average lengths around the start and each of its 10 control "
    "points; it saves work only when T holds many more fast periods than these windows: "
    "160 periods at kappa = 1e4 (T = 10) and 1e6 (T = 1), 1.6e5 at kappa = 1e8 (T = 10)."),
    ("A scipy solver abandoned at the time limit (status timeout) gives only a lower bound on "
    "its time; where every scipy solver was abandoned, the ratio is an upper bound (<), "
    "t_dolfinode / time limit, however much longer scipy would have taken."),
    ("A level marked * in a problem's table is below that solver's loosest run: its fastest "
    "run's time is used. The accuracy measurable against a published reference is limited by "
    "the reference (MEDAKZO's is good to about 10 mixed digits)."),
)


def level_table(table):
    lines = ["| mescd | best dolfinode | time | best scipy | time | ratio |",
             "|---|---|---|---|---|---|"]
    for e in table:
        scipy_time = f"{'> ' if e.get('scipy_bound') else ''}{fmt_s(e['scipy_time_s'])}"
        lines.append(f"| {e['level']} | {e['dolfinode_best']} | {fmt_s(e['dolfinode_time_s'])}"
                     f"{' *' if e['dolfinode_clamped'] else ''} | {e['scipy_best']} | "
                     f"{scipy_time}{' *' if e['scipy_clamped'] else ''} | {_ratio(e)} |")
    return "\n".join(lines)


def runs_table(rows, problem, key="time_median_s"):
    """The runs of ``problem``, one line each, timed by ``key`` (median or minimum)."""
    head = ["solver", "method", "tol", f"time ({key.split('_')[1]})", "reps", "mescd", "L2 (100 pts)",
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
            cells += [fmt_s(r[key]), str(r["repeats"]), f"{r['mescd']:.2f}",
                      f"{r['err_L2']:.2e}", n(r["f_evals"]), n(r["jacobians"]),
                      n(r["factorizations"]), n(r["steps"]), n(r["rejected"]),
                      n(r.get("elements"))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _merged_lines(meta):
    """Header lines of the runs merged into a record (:func:`merge`)."""
    return [(f"Merged: {', '.join(m['problems'])} re-run {m['date']} (git "
             f"{m['git_commit'] or '?'}), `{m['command']}` ({m['total_seconds']:.0f} s, "
             f"{m['settings']}); their runs, tables and panels replace the earlier ones  ")
            for m in meta.get("merged", [])]


def write_markdown(path, meta, rows, problems, heads, png_name, title="Benchmark suite"):
    out = [f"# {title}", "", f"Date: {meta['date']}  ",
           f"Machine: {meta['platform']}, {meta['cpu']}, {meta['cpu_count']} CPUs  ",
           (f"Versions: Python {meta['python']}, numpy {meta['numpy']}, scipy {meta['scipy']}, "
           f"numba {meta['numba']}, sympy {meta['sympy']}, dolfinode {meta['dolfinode']} "
           f"(git {meta['git_commit'] or '?'})  "),
           f"Command: `{meta['command']}` ({meta['total_seconds']:.0f} s)  ",
           (f"Tolerances: {', '.join(f'{x:g}' for x in meta['tolerances'])}; "
           + ("1 timed run" if meta["repeats"] == 1
              else f"{meta['repeats']} timed repeats (median)")
           + (f"; {meta['settings']}" if meta.get("settings") else "") + "  "),
           *meta.get("notes", []), *_merged_lines(meta), "",
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
           "L2 = RMS error over 100 equispaced points and all components; both over the "
           "problem's scored components where it names them (the seed models: x1)."),
           ("* Counts: dolfinode `sol.stats` (steps = time slabs; elements = component "
           "steps, N x steps for cG/dG, fewer for mcG/mdG); scipy nfev/njev/nlu, steps "
           "and rejected attempts from an instrumented run (n/a for LSODA)."),
           ("* A method that exceeds the time limit at one tolerance, or fails at two in a row, "
           "is skipped at the tighter ones."),
           ("* `<method>+modeling`: `dn.solve(..., automatic_modeling=True)` with the "
           "problem's modeling parameters (run only on problems that declare them); its "
           "stats count every inner solve."), "", "## Problems", "",
           ("| problem | N | stiff | description | reference at T | reference trajectory | "
           "atol/rtol | first dn.solve | compile |"), "|---|---|---|---|---|---|---|---|---|"]
    for name, info in problems.items():
        out.append(f"| {name} | {info['N']} | {'yes' if info['stiff'] else 'no'} | "
                   f"{info['description']} | {info['reference at T']} | "
                   f"{info['reference trajectory']} | {info['atol/rtol']:g} | "
                   f"{fmt_s(info['compile']['first_call_s'])} | "
                   f"{fmt_s(info['compile']['compile_time_s'])} |")
    for name in problems:
        out += ["", f"## {name}", "", "### Equal accuracy", "", level_table(heads[name]["table"])]
        if "modeling_table" in heads[name]:
            out += ["", "### Equal accuracy, automatic modeling against scipy", "",
                    level_table(heads[name]["modeling_table"])]
        out += ["", "### All runs", "", runs_table(rows, name)]
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
        text = f"{name} {_range(entries)} (mescd {entries[0]['level']}-{entries[-1]['level']})"
        modeled = h.get("modeling_table")
        if modeled:
            text += (f", with automatic modeling {_range(modeled)} (mescd "
                     f"{modeled[0]['level']}-{modeled[-1]['level']})")
        parts.append(text)
    stiff = [n for n, h in heads.items() if h["stiff"]]
    met = [n for n in stiff if heads[n]["target_met"]]
    missed = [f"{n} ({'slower at some level' if heads[n]['levels_compared'] else _verdict(heads[n])})"
              for n in stiff if not heads[n]["target_met"]]
    multi = [n for n, h in heads.items() if h.get("multiscale")]
    orders = [n for n in multi if _multiscale_entries(heads[n])
              and max(e["ratio"] for e in _multiscale_entries(heads[n])) <= MULTISCALE_RATIO]
    return "\n".join([
        README_BEGIN,
        ("**Benchmark suite.** `dolfinode bench` (or `python benchmarks/run_suite.py`; `--quick` "
        "for about a minute) runs the problem set of `dolfinode.bench` with dolfinode's methods "
        "and scipy's solvers and writes tables and work-precision plots to `doc/benchmarks/`."),
        "",
        (f"Measured {meta['date']} on a {meta['cpu_count']}-core machine shared with other jobs "
        f"({'quick run, ' if meta.get('quick') else ''}tolerances "
        f"{', '.join(f'{x:g}' for x in meta['tolerances'])}; `{meta['command']}`"
        + "".join(f"; {', '.join(m['problems'])} re-run {m['date']} with `{m['command']}`"
                  for m in meta.get("merged", []))
        + "). Time of "
        "dolfinode's fastest method / time of scipy's fastest solver at equal accuracy (mescd "
        f"at T; < 1: dolfinode faster), over the levels >= {TARGET_LEVEL} both reached (all "
        f"common levels where there are none): {'; '.join(parts)}. Target (faster than every "
        f"scipy solver at >= {TARGET_LEVEL} digits on every stiff problem): met on "
        f"{', '.join(met) or 'none'}{'; not met on ' + ', '.join(missed) if missed else ''}. "
        + (f"Orders of magnitude (ratio <= {MULTISCALE_RATIO:g}; with automatic modeling where "
           f"the problem has such runs) on the multiscale problems ({', '.join(multi)}): met on "
           f"{', '.join(orders) or 'none'}. " if multi else "")
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


def write_outputs(out_dir, stem, meta, rows, problems, title="Benchmark suite"):
    """Write ``stem``.csv/.json/.png/.md to ``out_dir`` (``problems``: name ->
    :func:`problem_info` entry); returns the headline dict."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    heads = headline(rows, problems)
    write_csv(out_dir / f"{stem}.csv", rows)
    write_json(out_dir / f"{stem}.json", meta, rows, problems, heads)
    plot(out_dir / f"{stem}.png", rows, problems)
    write_markdown(out_dir / f"{stem}.md", meta, rows, problems, heads, f"{stem}.png", title)
    return heads
