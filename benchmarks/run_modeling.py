"""Cost of the simple model against kappa: automatic modeling beside scipy on the full model.

For kappa = 1e4 ... 1e18 (tau = 100 / sqrt(kappa), cG(2), tolerance 1e-4): wall time (best of
``--repeat``) and elements with automatic modeling, and the wall time and steps of scipy's
DOP853 and LSODA (rtol 1e-6, atol 1e-9) on the full model over [0, 100], each stopped after
``--cap`` seconds (then reported as not finished). Writes doc/benchmarks/modeling.{md,csv,png}.

``--classes``: instead, the four classes of issue 28 (dolfinode.bench.multiscale) at scale
separations 1e4 ... 1e12 (``--kappas``; beyond 1e8 the modeling CPU time only): error of
the slow components against the full model resolved by numbalsoda's DOP853 (scipy's Radau
for Michaelis-Menten, rtol 1e-12) and averaged with the modeling kernel, the modeling error
estimate, whether a ModelingWarning fired, CPU time, and the CPU time of the resolving solvers at
the same accuracy: numbalsoda's DOP853 (LSODA for Michaelis-Menten) and scipy's, each at the loosest
rtol whose kernel averages are as close to the reference as the modeling's. Writes
doc/benchmarks/modeling_classes.{md,csv,png}.

``--lattice``: instead, the paper's figure 5 (the lattice with m = 1e-4, tau = 1, T = 100,
p = 3 and 5): max |D - D-bar| on [2 tau, T] against the full model's averaged diameter
(DOP853), for the default subgrid model (auto: affine after the first rebuild), the constant
model rebuilt at the control points, and the constant model built once; CPU times.
Writes doc/benchmarks/modeling_lattice.md.
"""
import argparse
import csv
import signal
import sys
import time
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench.report import machine_info
from dolfinode.compile import lower

sys.path.insert(0, str(Path(__file__).parents[1] / "demos"))
from lattice import lattice, reference
from simple_model import simple_model


class _Timeout(Exception):
    pass


def scipy_cost(ode, method, cap):
    compiled = lower(ode)
    start = time.perf_counter()

    def f(t, u):
        if time.perf_counter() - start > cap:
            raise _Timeout
        return compiled.f(u, t)

    try:
        sol = solve_ivp(f, (0.0, ode.T), ode.u0, method=method, rtol=1e-6, atol=1e-9)
    except _Timeout:
        return None, None, None
    t = np.linspace(0, ode.T, 2001)
    error = np.max(np.abs(np.interp(t, sol.t, sol.y[0]) - (1 - np.cos(t)) / 4))
    return time.perf_counter() - start, sol.t.size, error


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cap", type=float, default=60.0, help="seconds per scipy run")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--output", type=Path, default=Path(__file__).parents[1] / "doc" / "benchmarks")
    parser.add_argument("--lattice", action="store_true",
                        help="the lattice comparison (figure 5) instead of the kappa sweep")
    parser.add_argument("--classes", action="store_true",
                        help="the four classes of issue 28 instead of the kappa sweep")
    parser.add_argument("--kappas", type=float, nargs="+",
                        default=[1e4, 1e6, 1e8, 1e10, 1e12],
                        help="scale separations of --classes (resolved up to 1e8)")
    args = parser.parse_args(argv)
    if args.lattice:
        return lattice_drift(args.output)
    if args.classes:
        return classes(args.output, args.cap, args.kappas, args.repeat)
    rows = []
    for exponent in (4, 6, 8, 10, 12, 14, 16, 18):
        kappa = 10.0 ** exponent
        ode = simple_model(kappa)
        walls = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            sol = dn.solve(ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                           average_length=100 / np.sqrt(kappa))
            walls.append(time.perf_counter() - start)
        t = np.linspace(0, 100, 2001)
        row = {"kappa": kappa, "modeling wall [s]": min(walls),
               "modeling elements": sol.stats["elements"],
               "modeling max|U1-(1-cos t)/4|": np.max(np.abs(sol(t)[0] - (1 - np.cos(t)) / 4))}
        for method in ("DOP853", "LSODA"):
            wall, steps, error = scipy_cost(ode, method, args.cap)
            row[f"{method} wall [s]"], row[f"{method} steps"] = wall, steps
            row[f"{method} max|u1-(1-cos t)/4|"] = error
        print(row, flush=True)
        rows.append(row)
    args.output.mkdir(parents=True, exist_ok=True)
    with open(args.output / "modeling.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    kappas = [r["kappa"] for r in rows]
    ax.loglog(kappas, [r["modeling wall [s]"] for r in rows], "o-", label="dolfinode, automatic modeling")
    for method in ("DOP853", "LSODA"):
        done = [(r["kappa"], r[f"{method} wall [s]"]) for r in rows if r[f"{method} wall [s]"]]
        if done:
            ax.loglog(*zip(*done), "s--", label=f"scipy {method}, full model")
    ax.axhline(args.cap, color="gray", ls=":", label=f"scipy cap {args.cap:g} s")
    ax.set(xlabel="kappa", ylabel="wall time [s]", title="simple model on [0, 100]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.output / "modeling.png", dpi=110)
    meta = machine_info()
    lines = ["# Automatic modeling: cost of the simple model against kappa", "",
             (f"Measured {meta['date']} (git {meta['git_commit']}) on {meta['cpu']}, "
             f"{meta['cpu_count']} CPUs."), "",
             ("`python benchmarks/run_modeling.py` (cG(2), tolerance 1e-4, tau = 100/sqrt(kappa), "
              f"best of {args.repeat}; scipy rtol 1e-6, atol 1e-9, capped at {args.cap:g} s; "
              "'-' = not finished)."), "",
             ("| kappa | modeling wall [s] | elements | max err U1 | DOP853 wall [s] | DOP853 steps "
              "| LSODA wall [s] | LSODA steps |"), "|---|---|---|---|---|---|---|---|"]
    fmt = lambda v, f: "-" if v is None else format(v, f)
    for r in rows:
        lines.append(f"| {r['kappa']:.0e} | {r['modeling wall [s]']:.2f} | "
                     f"{r['modeling elements']} | {r['modeling max|U1-(1-cos t)/4|']:.1e} | "
                     f"{fmt(r['DOP853 wall [s]'], '.2f')} | {fmt(r['DOP853 steps'], 'd')} | "
                     f"{fmt(r['LSODA wall [s]'], '.2f')} | {fmt(r['LSODA steps'], 'd')} |")
    lines += ["", "![cost against kappa](modeling.png)", ""]
    (args.output / "modeling.md").write_text("\n".join(lines))


def lattice_drift(output, T=100.0, tau=1.0, m=1e-4):
    """The lattice of figure 5: drift of the reduced diameter from the averaged full one."""
    models = {"auto (default)": {},
              "constant, rebuilt": {"subgrid_model": "constant"},
              "constant, built once": {"subgrid_model": "constant", "rebuild_model": False,
                                       "control_points": 0}}
    lines = ["# Automatic modeling: the lattice of figure 5", "",
             (f"`python benchmarks/run_modeling.py --lattice`: m = {m:g}, tau = {tau:g}, "
              f"T = {T:g}, cG(2), tolerance 1e-4, 10 control points (default), "
              "model_tolerance 0.02 (default). D-bar: the full model's diameter (scipy DOP853, "
              "rtol 1e-8) averaged with the modeling kernel of length tau. CPU seconds (process "
              "time, kernels cached; the first row includes loading them)."), "",
             ("| p | N | subgrid model | max abs(D - D-bar) on [2 tau, T] | builds | elements "
              "| CPU [s] | contraction of D-bar | DOP853 CPU [s] |"),
             "|---|---|---|---|---|---|---|---|---|"]
    for p in (3, 5):
        lat = lattice(p, m, T=T)
        start = time.process_time()
        times, _, D_bar, _ = reference(lat, T, tau)
        reference_cpu = time.process_time() - start
        after = times >= 2 * tau
        for name, options in models.items():
            start = time.process_time()
            sol = dn.solve(lat.ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                           average_length=tau, **options)
            cpu = time.process_time() - start
            drift = np.max(np.abs(lat.diameter(sol(times[after])) - D_bar[after]))
            line = (f"| {p} | {lat.ode.N} | {name} | {drift:.4f} | {len(sol.model.built)} | "
                    f"{sol.stats['elements']} | {cpu:.1f} | {np.sqrt(2) - D_bar.min():.4f} | "
                    f"{reference_cpu:.1f} |")
            print(line, flush=True)
            lines.append(line)
    lines.append("")
    output.mkdir(parents=True, exist_ok=True)
    (output / "modeling_lattice.md").write_text("\n".join(lines))


def _capped(function, cap):
    """function() and its CPU time, or (None, None) after ``cap`` seconds of wall time."""
    def stop(signum, frame):
        raise _Timeout

    signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, cap)
    start = time.process_time()
    try:
        return function(), time.process_time() - start
    except _Timeout:
        return None, None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


#: Tolerances swept by the resolving solvers (atol = rtol / 100), loosest first.
RESOLVING_RTOLS = tuple(10.0 ** -e for e in range(3, 13))
#: The references: scipy Radau (stiff) or numbalsoda's DOP853 at this rtol, checked at 10x it.
REFERENCE_RTOL = 1e-12
#: Above this scale separation only the modeling is measured (numbalsoda's reference would
#: take ~10^3 s at 1e12).
RESOLVED_UP_TO = 1e10
#: Above this scale separation scipy's DOP853 is not run (113 s at 1e8 for the adiabatic
#: class): its CPU is bounded below from the last measured one, see :func:`_scipy_lower_bound`.
SCIPY_UP_TO = 1e8


def _score(averages, reference, slow):
    """max over the slow components of max |average - reference| / range of the reference."""
    return max(np.max(np.abs(averages[i] - reference[i])) / np.ptp(reference[i]) for i in slow)


def classes(output, cap, kappas=(1e4, 1e6, 1e8, 1e10, 1e12), repeat=3):
    """The four classes of issue 28 against a resolved, kernel-averaged reference, and the
    resolving solvers at the modeling's accuracy."""
    from dolfinode.bench import multiscale

    rows = []
    for name, build in multiscale.CLASSES.items():
        stiff = name == "michaelis_menten"
        for kappa in kappas:
            ode, slow = build(kappa)
            row = {"class": name, "scale separation": kappa}
            settings = {"method": "cG(2)", "tolerance": 1e-4, "automatic_modeling": True}
            try:
                dn.solve(ode, **settings)  # compiled kernels cached: the next are timed
                cpus = []
                for _ in range(repeat):
                    with warnings.catch_warnings(record=True) as caught:
                        warnings.simplefilter("always")
                        start = time.process_time()
                        sol = dn.solve(ode, **settings)
                        cpus.append(time.process_time() - start)
                row["modeling CPU [s]"] = min(cpus)
            except ValueError as error:
                row["outcome"] = "ValueError: " + str(error).split(":")[0]
                print(row, flush=True)
                rows.append(row)
                continue
            fired = [w for w in caught if issubclass(w.category, dn.ModelingWarning)]
            row["model"] = sol.model.subgrid_model if sol.model.subgrid_model == "flow" else \
                ("affine" if sol.model.affine else "constant")
            row["outcome"] = "ModelingWarning" if fired else "no warning"
            row["estimate"] = sol.model.estimate.total
            if kappa > RESOLVED_UP_TO:  # the cost of modeling only
                print(row, flush=True)
                rows.append(row)
                write_classes(rows, output, cap)
                continue
            tau = sol.model.average_length
            times = np.linspace(0.1 * ode.T, ode.T, 200)  # the same for every kappa
            grid, average = multiscale.kernel_grid(times, tau)
            method = "Radau" if stiff else "numbalsoda"
            start = time.process_time()
            reference = multiscale.averaged_reference(ode, times, tau, method, REFERENCE_RTOL)
            row["reference CPU [s]"] = time.process_time() - start
            row["reference error / range"] = _score(multiscale.averaged_reference(
                ode, times, tau, method, 10 * REFERENCE_RTOL), reference, slow)
            U = sol(times)
            row["max error / range"] = target = _score(U, reference, slow)
            row["error at T"] = max(abs(U[i, -1] - reference[i, -1]) for i in slow)
            row.update(_compiled_resolving(ode, stiff, grid, average, reference, slow, target,
                                           repeat))
            if kappa <= SCIPY_UP_TO or stiff:  # (an implicit solver's cost is flat in kappa)
                row.update(_scipy_resolving(ode, stiff, grid, average, reference, slow,
                                            target, row["compiled rtol"], cap))
            else:
                row.update(_scipy_lower_bound(rows, row))
            print(row, flush=True)
            rows.append(row)
            write_classes(rows, output, cap)  # (a long run keeps what it measured)


def _compiled_resolving(ode, stiff, grid, average, reference, slow, target, repeat):
    """numbalsoda's DOP853 (LSODA when stiff) on the full model at the loosest of
    RESOLVING_RTOLS whose kernel averages are within ``target`` of the reference: its rtol,
    error and CPU seconds (best of ``repeat``, 101 output points, compiled first)."""
    from dolfinode.bench import peers

    row = {"compiled": "numbalsoda " + ("LSODA" if stiff else "DOP853"), "compiled rtol": None,
           "compiled error / range": None, "compiled CPU [s]": None}
    if not _numbalsoda_installed():
        return row
    peer = (peers.NumbalsodaLSODA if stiff else peers.NumbalsodaDOP853)(
        ode, np.concatenate([[ode.t0], grid]))
    peer.max_steps = 10**9
    peer.build()
    for rtol in RESOLVING_RTOLS:
        try:
            error = _score(average(peer.solve(rtol, rtol / 100)[0][:, 1:]), reference, slow)
        except peers.PeerFailed:
            continue
        if error <= target:
            peer.t_eval = np.linspace(ode.t0, ode.T, 101)  # as a user who wants the solution
            cpu = []
            for _ in range(repeat):
                start = time.process_time()
                peer.solve(rtol, rtol / 100)
                cpu.append(time.process_time() - start)
            row.update({"compiled rtol": rtol, "compiled error / range": error,
                        "compiled CPU [s]": min(cpu)})
            break
    return row


def _scipy_resolving(ode, stiff, grid, average, reference, slow, target, loosest, cap):
    """scipy's DOP853 (LSODA when stiff) on the full model from the rtol ``loosest`` (the
    compiled solver's, the same method; the loosest of RESOLVING_RTOLS without it) tightened
    by 10
    until its kernel averages are within ``target`` of the reference, each run stopped after
    ``cap`` seconds of wall time: its rtol, error and CPU seconds."""
    compiled = lower(ode)
    method = "LSODA" if stiff else "DOP853"
    row = {"scipy": method, "scipy rtol": None, "scipy error / range": None,
           "scipy CPU [s]": None}
    for rtol in [r for r in RESOLVING_RTOLS if loosest is None or r <= loosest][:3]:
        full, cpu = _capped(lambda rtol=rtol: solve_ivp(
            lambda t, u: compiled.f(u, t), (ode.t0, grid[-1]), ode.u0, method=method,
            rtol=rtol, atol=rtol / 100, t_eval=grid), cap)
        if full is None:
            row["scipy rtol"] = rtol  # not finished at this rtol
            return row
        error = _score(average(full.y), reference, slow)
        row.update({"scipy rtol": rtol, "scipy error / range": error, "scipy CPU [s]": cpu})
        if error <= target:
            return row
    row["scipy CPU [s]"] = None  # not within the target at any rtol tried
    return row


def _scipy_lower_bound(rows, row):
    """scipy's CPU at a scale separation it is not run at, bounded below by the last
    measured one (same class) times the ratio of fast periods, sqrt(kappa / kappa_m):
    explicit steps per period are fixed by rtol, so the bound holds when the rtol
    numbalsoda needs here is no looser than scipy's there."""
    measured = [r for r in rows if r["class"] == row["class"] and r.get("scipy CPU [s]")]
    if not measured or row.get("compiled rtol") is None \
            or row["compiled rtol"] > measured[-1]["scipy rtol"]:
        return {}
    last = measured[-1]
    ratio = np.sqrt(row["scale separation"] / last["scale separation"])
    return {"scipy": last["scipy"], "scipy CPU lower bound [s]": last["scipy CPU [s]"] * ratio}


def _numbalsoda_installed():
    try:
        import numbalsoda  # noqa: F401
    except ImportError:
        return False
    return True


def write_classes(rows, output, cap):
    """doc/benchmarks/modeling_classes.{csv,png,md} from the rows of :func:`classes`."""
    from dolfinode.bench import multiscale

    output.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(k for r in rows for k in r))
    with open(output / "modeling_classes.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=names)
        writer.writeheader()
        writer.writerows(rows)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for number, name in enumerate(multiscale.CLASSES):
        color = f"C{number}"
        for key, style, label in (("modeling CPU [s]", "o-", "automatic modeling"),
                                  ("compiled CPU [s]", "^:", "numbalsoda"),
                                  ("scipy CPU [s]", "s--", "scipy")):
            done = [(r["scale separation"], r[key]) for r in rows
                    if r["class"] == name and r.get(key)]
            if done:
                ax.loglog(*zip(*done), style, color=color, label=f"{name}, {label}")
    ax.axhline(cap, color="gray", ls=":", label=f"cap {cap:g} s (wall)")
    ax.set(xlabel="scale separation kappa", ylabel="CPU time [s]",
           title="issue 28 classes: automatic modeling against resolving at equal accuracy")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(output / "modeling_classes.png", dpi=110)
    meta = machine_info()

    def fmt(r, k, f):
        return "-" if r.get(k) is None else format(r[k], f)

    def capped(r):  # scipy stopped at the cap at its first rtol
        return r.get("scipy rtol") is not None and r.get("scipy error / range") is None

    def ratio(r, k):
        if r.get("modeling CPU [s]") is None:
            return "-"
        if k == "scipy CPU [s]" and capped(r):
            return f"> {cap / r['modeling CPU [s]']:.0f}"
        if k == "scipy CPU [s]" and r.get("scipy CPU lower bound [s]"):
            return f">= {r['scipy CPU lower bound [s]'] / r['modeling CPU [s]']:.0f}"
        if r.get(k) is None:
            return "-"
        value = r[k] / r["modeling CPU [s]"]
        return f"{value:.0f}" if value >= 10 else f"{value:.2g}"

    def scipy_cpu(r):
        if capped(r):
            return f"> {cap:g} (wall)"
        if r.get("scipy CPU lower bound [s]"):
            return f">= {r['scipy CPU lower bound [s]']:.3g} (not run)"
        return fmt(r, "scipy CPU [s]", ".3g")

    lines = ["# Automatic modeling on the four classes of issue 28", "",
             (f"Measured {meta['date']} (git {meta['git_commit']}) on {meta['cpu']}, "
             f"{meta['cpu_count']} CPUs (shared)."), "",
             ("`python benchmarks/run_modeling.py --classes`: cG(2), tolerance 1e-4, defaults "
              "otherwise; CPU seconds, best of 3 after a first solve that compiles. Error: max "
              "over [T / 10, T] of |U - u-bar| over the range of u-bar for the slow "
              "components; u-bar is the full model resolved by numbalsoda's DOP853 "
              f"(scipy's Radau for Michaelis-Menten) at rtol {REFERENCE_RTOL:g}, atol = rtol "
              "/ 100, and averaged with the modeling kernel; 'ref. error' is the same score "
              "of the reference at 10x its rtol. Estimate: sol.model.estimate.total "
              "(modeling + discretisation, largest slow component at T). Resolving: the full "
              "model at the loosest rtol in 1e-3 ... 1e-12 (atol = rtol / 100) whose kernel "
              "averages are within the modeling's error (the same score), numbalsoda's "
              "DOP853 (LSODA for Michaelis-Menten; CPU of the solve with 101 output points, "
              "compiled first, best of 3) and scipy's (from the rtol numbalsoda needed, "
              "tightened by 10 while its error is above). Ratio: resolving CPU / modeling "
              f"CPU. '> {cap:g} (wall)': scipy not finished within {cap:g} s of wall time at "
              "the rtol numbalsoda needed (the ratio is then a lower bound); '>= X (not "
              f"run)': scipy's DOP853 is not run above {SCIPY_UP_TO:g}, its CPU is bounded "
              "below by its last measured CPU (at kappa_m, the largest kappa it finished at) "
              "times sqrt(kappa / kappa_m), the ratio of fast periods (an explicit solver's "
              "steps per period are fixed by the rtol, and numbalsoda's rtol here is no "
              "looser than scipy's at kappa_m): an "
              "extrapolated lower bound, not a measurement; '-': not reached, or not "
              f"resolved (above {RESOLVED_UP_TO:g})."), "",
             ("| class | kappa | model | outcome | modeling CPU [s] | max error / range | "
              "error at T | estimate | ref. error | numbalsoda rtol | numbalsoda CPU [s] "
              "| ratio | scipy rtol | scipy CPU [s] | ratio |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['class']} | {r['scale separation']:.0e} | {r.get('model', '-')} "
                     f"| {r['outcome']} | {fmt(r, 'modeling CPU [s]', '.2g')} | "
                     f"{fmt(r, 'max error / range', '.1e')} | {fmt(r, 'error at T', '.1e')} | "
                     f"{fmt(r, 'estimate', '.1e')} | {fmt(r, 'reference error / range', '.0e')} "
                     f"| {fmt(r, 'compiled rtol', '.0e')} | {fmt(r, 'compiled CPU [s]', '.2g')} "
                     f"| {ratio(r, 'compiled CPU [s]')} | {fmt(r, 'scipy rtol', '.0e')} | "
                     f"{scipy_cpu(r)} "
                     f"| {ratio(r, 'scipy CPU [s]')} |")
    lines += ["", "![CPU time against the scale separation](modeling_classes.png)", "",
              ("Classes (dolfinode/bench/multiscale.py): adiabatic, x1'' = -x1 + x2^2/2, "
              "x2'' = -kappa (1 + x1) x2, T = 50; fermi_pasta_ulam, m = 2 stiff springs of "
              "frequency sqrt(kappa), T = 50; michaelis_menten, s' = -s + (s + 0.5) c, "
              "c' = kappa (s - (s + 1) c), T = 5; proportional, y' = cos t - y x^2, "
              "x'' = -kappa x, T = 50. Model: what subgrid_model='auto' chose (constant or "
              "affine g~ with inactivated components, or the flow-averaged model, "
              "dolfinode.modeling.flow). For the flow the error is against the reference "
              "averaged with the flow's average_length, and the estimate is the difference of "
              "the flows at two scale separations (no dual). Michaelis-Menten is stiff, not "
              "oscillatory: an implicit resolving solver needs about 130 steps whatever "
              "kappa, so modeling is slower there; it is right and checked. Where the modeling's "
              "error is below the reference's own ('ref. error': the flows at 1e4, where "
              "the full model is solved), the resolving solvers run at the reference's rtol: "
              "the comparison then says only that both are as close as the reference can "
              "tell. Proportional at 1e10 and 1e12: the first control point, 4.5 away, is "
              "too far (9e3 and 9e4 half windows) to extrapolate the half windows' affine "
              "fit, so 'auto' adds an early check about 3e-3 after the start "
              "(ReducedModel.early_check, where the constant model's predicted error is a "
              "tenth of the tolerance) and rebuilds the model affine there; before, it "
              "started constant and was rightly warned (defect times span 2.2)."), ""]
    (output / "modeling_classes.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
