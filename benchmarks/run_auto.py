"""method="auto" against cG(q) and mcG(q) (issue 29, item 6: auto within 1.3x of the better).

The problems: the uniform chain without scale separation
(``dolfinode.problems.mass_spring_chain(100, T=200)``, where mono-adaptive cG(2) is far
cheaper), the stiff-spring chain (``dolfinode.bench.problems.mass_spring_chain``: 200 masses,
10 or 2 springs 1e6 stiffer, T = 0.1), the reaction front (``reaction_front(n=500, T=0.05)``)
an oscillator bank (``dolfinode.bench.multirate.oscillator_bank``: one fast oscillator
among 100 slow ones, where mcG(2) is far cheaper), and, added after auto's rules were set
(not tuned on), the seed model of automatic modeling at kappa = 1e2
(``dolfinode.bench.problems.seed_model``: one slow and one 10x faster oscillator) and a
bank whose one fast oscillator appears at T/3 (:func:`late_fast_bank`: the scales change
during the solve); and, added before the prediction was reworked for issue 29 item 6b (not
tuned on either), a bank whose fast oscillator slows down at T/2 (:func:`early_fast_bank`)
and a stiff diffusion with a moving local source (:func:`moving_source`).
All three methods solve with ``calibrate_tolerance=False``: the same step tolerance (by
default each is calibrated to the error at T, mcG(q) with its own constants); the error at T
is reported with them.
Every solve is timed by CPU time (``time.process_time``: the machine is shared), after an
untimed call per method (compile and load apart), in interleaved rounds; the table gives each
method's minimum over the rounds, the choice auto made, and auto / min(cG(q), mcG(q)).

With ``--calibrated`` all three solve with ``calibrate_tolerance=True`` (dn.solve's
default) instead, into auto-calibrated.md/.json.

Usage::

    .venv/bin/python benchmarks/run_auto.py [--rounds 7] [--calibrated] [--output doc/benchmarks]
"""
import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import sympy as sp

import dolfinode as dn
from dolfinode.bench.multirate import oscillator_bank
from dolfinode.bench.problems import mass_spring_chain, reaction_front, seed_model
from dolfinode.problems import mass_spring_chain as uniform_chain

TARGET = 1.3
#: What the last run showed, in words (kept with the script that measures it).
NOTES = [
    ("0.99-1.28x in this run (the merged tree, load 1.0; the front 1.28x, the moving source "
     "1.25x); on the helper's branch 0.93-1.27x (load 2.6-2.7: three helpers on 2 cores), "
     "0.92-1.26x in one four "
     "minutes before (load 1.5-1.7); the code before this change gave 0.92-1.32x in a run "
     "between them (2-spring chain 1.31x, front 1.32x, late fast bank 1.27x). Above 1.2x: "
     "the front (1.25-1.26x), the moving source (1.24-1.27x: seven cG(2) stretches on a 7 ms "
     "solve, about 0.2 ms of solve call and prediction each) and the bank slowing at T/2 "
     "(1.21-1.22x). What changed (issue 29 item 6b, again): the stretches of both variants "
     "are joined lazily as one MixedSolution (the cG(2) slabs stay shared slabs: 1.5 ms of "
     "the late bank's 31 ms went into copying them into N elements each); a variant's "
     "restart is at least the largest measured before, so the chain's mcG(2), whose trial "
     "measured 0.8 ms while later stretches looked 0.1 ms, takes two stretches after the "
     "trial, not four; RESTART_SHARE 0.1 -> 0.05, and a multi-adaptive stretch runs to T "
     "when what would be left is shorter than that least length (the front: trial, then one "
     "mcG(2) stretch; 1.32 -> 1.25x); MAX_STRETCH 0.25 -> 0.2 (the late bank switches at "
     "2.46 instead of 2.76: 1.27 -> 1.17-1.18x); COST_RATIO, the prior cost of an mcG(2) "
     "element, 12 -> 7 (measured now: 6.8-20 where the steps spread, 3-4 where every slab "
     "is synchronised), recorded with each prediction as \"prior\" or \"measured\"."),
    ("Where the rest goes (measured on the code of this run, minimum of interleaved "
     "repeats): the front pays two mcG(2) starts of about 0.85 ms each (every component "
     "active until found at rest; the trial's 4 % costs 1.3 ms where the steady rate gives "
     "0.5 ms) and a 1 % cG(2) stretch, on a 10.5 ms solve; the 2-spring chain about 0.8 ms "
     "per mcG(2) start on 37 ms. The multi-adaptive loop restarts its slab-length limit and "
     "freezing at each call; carrying them over is the loop's business "
     "(timeslab/multi), not tried here. Entering mcG(2) at the common step instead of each "
     "component's own was measured both ways: 5-7 % better on the front and both ramped "
     "banks, 15 % worse on the 2-spring chain at the calibrated tolerance; not changed.")]

#: What the last run with --calibrated showed.
CALIBRATED_NOTES = [
    ("0.81-1.62x in this run (load 2.6), 0.77-1.68x in one four minutes before (load 1.8); "
     "the code before this change gave 0.77-1.84x (uniform chain 1.35, 2-spring chain 1.29, "
     "front 1.84, bank 1.29, late bank 1.37, early bank 1.48, moving source 1.33x; load "
     "2.0). **Above 1.3x: the uniform chain (1.41x), the front (1.62-1.68x), the bank "
     "slowing at T/2 (1.36-1.37x), the moving source (1.30-1.31x).** The calibrated "
     "tolerances are looser (cG(2) 4x faster than at the step tolerance 1e-6, mcG(2) 3x), "
     "so the solves take 0.4-12 ms apart from the two chains and the bank, and auto's fixed "
     "costs weigh 3-4x more: seven cG(2) stretches at about 0.2 ms each on the uniform "
     "chain's 4 ms, two mcG(2) starts of about 1 ms on the early bank's 7 ms. The front "
     "switches to mcG(2) although cG(2) is 1.08x cheaper over [0, T]: the trial's rate is "
     "compared with the 1 % cG(2) stretch before it, whose second half (the front forming) "
     "costs 6x cG(2)'s mean rate; the mcG(2) stretch then runs to T (its restart is dear), "
     "so no check sees cG(2) cheaper later. The choice of family is within 1.1x of the "
     "better everywhere but the late bank, where auto stayed with cG(2) in 4 of 9 rounds "
     "(cG(2) 1.41x mcG(2)'s time): at this tolerance the ramp's second half predicts mcG(2) "
     "near the 1.5x margin, so the decision follows the timing noise.")]


def late_fast_bank(n=60, T=6.0):
    """n oscillators of frequency 1..2 and one whose frequency ramps from 1 to 100 around
    t = T/3, all displaced at t = 0: one time scale until the ramp, two after it."""
    x, v = sp.symbols(f"x:{n + 1}"), sp.symbols(f"v:{n + 1}")
    omega = list(np.linspace(1.0, 2.0, n)) + [1 + 99 * (1 + sp.tanh(5 * (dn.t - T / 3))) / 2]
    rhs = {}
    for i in range(n + 1):
        rhs[x[i]] = v[i]
        rhs[v[i]] = -omega[i] ** 2 * x[i]
    return dn.ODE(rhs, u0={**dict.fromkeys(x, 1.0), **dict.fromkeys(v, 0.0)}, T=T)


def early_fast_bank(n=60, T=6.0):
    """n oscillators of frequency 1..2 and one whose frequency ramps from 100 down to 1
    around t = T/2: two time scales until the ramp, one after it (the fast part switches
    off halfway)."""
    x, v = sp.symbols(f"x:{n + 1}"), sp.symbols(f"v:{n + 1}")
    omega = list(np.linspace(1.0, 2.0, n)) + [1 + 99 * (1 - sp.tanh(5 * (dn.t - T / 2))) / 2]
    rhs = {}
    for i in range(n + 1):
        rhs[x[i]] = v[i]
        rhs[v[i]] = -omega[i] ** 2 * x[i]
    return dn.ODE(rhs, u0={**dict.fromkeys(x, 1.0), **dict.fromkeys(v, 0.0)}, T=T)


def moving_source(n=100, T=1.0, D=0.01):
    """u_t = D u_xx - u + 10 exp(-((x - c(t)) / 0.03)^2) on n points of [0, 1] (zero
    Dirichlet values outside), c(t) = 0.2 + 0.6 t / T: a stiff diffusion (D / h^2 = 98)
    with a local source moving across the domain, fast only where it passes."""
    h = 1.0 / (n + 1)
    u = sp.symbols(f"u0:{n}")
    centre = 0.2 + 0.6 * dn.t / T
    rhs = {}
    for i in range(n):
        left = u[i - 1] if i > 0 else 0
        right = u[i + 1] if i < n - 1 else 0
        source = 10 * sp.exp(-(((i + 1) * h - centre) / 0.03) ** 2)
        rhs[u[i]] = D * (left - 2 * u[i] + right) / h**2 - u[i] + source
    return dn.ODE(rhs, u0=np.zeros(n), T=T)


def problems():
    """(name, ode, tolerance, base method, u(T) or None) of the problems."""
    uniform, exact = uniform_chain(100, T=200)
    bench = [("stiff-spring chain, 200 masses, 10 springs 1e6 stiffer, T = 0.1",
              mass_spring_chain(n=200, stiffness=1e6, stiff_springs=10, T=0.1)),
             ("stiff-spring chain, 200 masses, 2 springs 1e6 stiffer, T = 0.1",
              mass_spring_chain(n=200, stiffness=1e6, stiff_springs=2, T=0.1)),
             ("reaction front, N = 500, T = 0.05", reaction_front(n=500, T=0.05)),
             ("oscillator bank, 100 of frequency 1..2 and one of 1000, T = 2",
              oscillator_bank(n=100, w=1000.0, T=2.0)),
             ("seed model, kappa = 1e2, T = 10 (new)", seed_model(1e2, T=10.0))]
    late = ("61 oscillators, one ramping from frequency 1 to 100 at t = 2, T = 6 (new)",
            late_fast_bank(), 1e-5, "cG(2)", None)
    # added before the prediction of issue 29 item 6b was reworked (not tuned on)
    later = [("61 oscillators, one slowing from frequency 100 to 1 at t = 3, T = 6 (new)",
              early_fast_bank(), 1e-5, "cG(2)", None),
             ("diffusion with a moving local source, N = 100, T = 1 (new)", moving_source(),
              1e-6, "cG(2)", None)]
    return ([("uniform chain, 100 masses, T = 200", uniform, 1e-6, "cG(2)",
              exact(200.0))]
            + [(name, problem.ode, 1e-6, "cG(2)", problem.final) for name, problem in bench]
            + [late] + later)


def reference(ode, final):
    """u(T): ``final`` if known, else cG(3) at a step tolerance of 1e-11."""
    if final is not None:
        return np.asarray(final, dtype=float)
    return dn.solve(ode, "cG(3)", tolerance=1e-11, calibrate_tolerance=False,
                    number_of_samples=2)(ode.T)


def cpu_time(ode, method, tolerance, calibrate=False):
    """(CPU seconds, solution) of one solve, at the step tolerance as given (or calibrated
    to the error at T, each variant with its own constants)."""
    start = time.process_time()
    sol = dn.solve(ode, method, tolerance=tolerance, number_of_samples=2,
                   calibrate_tolerance=calibrate)
    return time.process_time() - start, sol


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calibrated", action="store_true",
                        help="solve with calibrate_tolerance=True (the default of dn.solve); "
                             "writes auto-calibrated.md/.json")
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    rows = []
    for name, ode, tolerance, base, final in problems():
        methods = [base, "m" + base, "auto:" + base]
        exact = reference(ode, final)
        errors = {}
        for method in methods:  # untimed: compile and load
            cpu_time(ode, method, tolerance, args.calibrated)
        times = {method: [] for method in methods}
        choices = []
        for _ in range(args.rounds):
            for method in methods:
                seconds, sol = cpu_time(ode, method, tolerance, args.calibrated)
                times[method].append(seconds)
                errors[method] = float(np.abs(sol(ode.T) - exact).max())
                if method.startswith("auto"):
                    choices.append(sol.stats["method"])
                    evidence = sol.stats["family choice"]
        best = {method: min(values) for method, values in times.items()}
        better = min(best[base], best["m" + base])
        rows.append({"problem": name, "tolerance": tolerance, "times": times, "minima": best,
                     "choices": choices, "ratio": best["auto:" + base] / better,
                     "errors at T": errors,
                     "last evidence": evidence})
        print(name, best, choices, rows[-1]["ratio"], flush=True)
    lines = ["# method=\"auto\": mono- or multi-adaptive, switched in stretches", "",
             (f"`python benchmarks/run_auto.py --rounds {args.rounds}"
              + (" --calibrated" if args.calibrated else "") + "`, "
              f"{time.strftime('%Y-%m-%d')}, {platform.processor() or platform.machine()}, "
              "a machine shared with other jobs: CPU time (`time.process_time`) of the whole "
              f"`dn.solve` call, minimum over {args.rounds} interleaved rounds after an untimed "
              "call per method."), "",
             ("| problem | tolerance | cG(2) [s] | mcG(2) [s] | auto [s] | auto chose | "
              f"auto / better (target <= {TARGET}) | max error at T: cG(2), mcG(2), auto |"),
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        base, multi, auto = r["minima"]
        chosen = ", ".join(f"{m} ({r['choices'].count(m)}/{len(r['choices'])})"
                           for m in sorted(set(r["choices"])))
        lines.append(f"| {r['problem']} | {r['tolerance']:g} | {r['minima'][base]:.3g} | "
                     f"{r['minima'][multi]:.3g} | {r['minima'][auto]:.3g} | {chosen} | "
                     f"{r['ratio']:.2f}x | "
                     + ", ".join(f"{r['errors at T'][m]:.1e}" for m in (base, multi, auto))
                     + " |")
    accuracy = ("All three solve with calibrate_tolerance=True (dn.solve's default: each "
                 "variant's step tolerance from its own constants, aimed at the error at T; "
                 "the errors at T are in the last column)." if args.calibrated else
                 "All three solve at the same step tolerance (calibrate_tolerance=False; the "
                 "errors at T are in the last column).")
    report = "auto-calibrated" if args.calibrated else "auto"
    lines += ["", ("auto solves [t0, T] in stretches (1, 4, 16 %, then 20 % of it; an mcG(2) "
                   "stretch longer where its restart, the largest measured, would cost more "
                   "than 5 % of it, at most 50 %, and to T where what would be left is too "
                   "short to pay one) starting with cG(2); after each stretch it measures the "
                   "current variant's CPU rate over the stretch's second half, predicts "
                   "mcG(2)'s (or cG(2)'s) from the elements that variant would take there "
                   "and, when that is 1.5x below the measured rate, solves the next stretch "
                   "with the other variant as a trial, which continues if measured cheaper; a "
                   "system of fewer than 22 components is solved by cG(2) in one call "
                   "(dolfinode/family.py). Its time includes the restarts, the trials and the "
                   "joining of the stretches into one solution. " + accuracy + " \"auto "
                   f"chose\" is `sol.stats[\"method\"]` per round; the evidence of the last "
                   f"round is in {report}.json (`sol.stats[\"family choice\"]`)."), ""]
    lines += CALIBRATED_NOTES if args.calibrated else NOTES
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{report}.md").write_text("\n".join(lines) + "\n")
    (out / f"{report}.json").write_text(json.dumps(rows, indent=1, default=str) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
