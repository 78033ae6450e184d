"""The benchmark library: problems, scipy functions, scoring, runner, outputs and the CLI."""
import json

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench import problems as P
from dolfinode.bench import report
from dolfinode.bench.numpy_functions import numpy_functions
from dolfinode.bench.runner import ROW_FIELDS, run_suite
from dolfinode.cli import main


def test_mescd_counts_digits():
    ref = np.array([1.0, 1e-3])
    assert P.mescd(ref + [1e-6, 0.0], ref) == pytest.approx(-np.log10(1e-6 / 2))
    # with atol/rtol = 1e-4 the small component's error weighs 1 / (1e-4 + 1e-3)
    assert P.mescd(ref + [0.0, 1e-9], ref, 1e-4) == pytest.approx(-np.log10(1e-9 / 1.1e-3))
    assert P.mescd([np.nan, 1e-3], ref) == -np.inf
    with pytest.raises(ValueError, match="shapes"):
        P.mescd([1.0], ref)


@pytest.mark.parametrize("name", ["HIRES", "VDPOLM", "Arenstorf", "chain"])
def test_numpy_functions_match_the_declaration(name):
    """f and J lambdified for scipy agree with dolfinode's compiled kernel and with a central
    difference of f (POLLU's rate constants up to 4e11 defeat a finite difference)."""
    from dolfinode.compile import lower

    p = P.get_problem(name)
    fun, jac = numpy_functions(p.ode)
    y = p.ode.u0 + 0.01 * np.random.default_rng(0).random(p.ode.N)
    np.testing.assert_allclose(fun(0.3, y), lower(p.ode).f(y.copy(), 0.3), rtol=1e-12,
                               atol=1e-12)
    J = jac(0.3, y)
    J = J.toarray() if hasattr(J, "toarray") else J
    h = 1e-7
    for j in range(min(p.ode.N, 6)):
        e = np.zeros(p.ode.N)
        e[j] = h * max(1.0, abs(y[j]))
        fd = (fun(0.3, y + e) - fun(0.3, y - e)) / (2 * e[j])
        np.testing.assert_allclose(J[:, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max() + 1e-9)


def test_published_references_agree_with_a_tight_scipy_solve():
    """The Test Set values typed in for HIRES and POLLU are the solution (scipy Radau at
    rtol 1e-10 reproduces them to 8+ digits), and the closed forms solve their ODEs."""
    for p in (P.hires_problem(), P.pollu()):
        fun, jac = numpy_functions(p.ode)
        res = solve_ivp(fun, (0, p.T), p.ode.u0, method="Radau", rtol=1e-10, atol=1e-12,
                        jac=jac)
        assert P.mescd(res.y[:, -1], p.final) > 8
    for p in (P.seed_model(1e2, T=2.0), P.mass_spring_chain(n=6, T=2.0)):
        fun, _ = numpy_functions(p.ode)
        res = solve_ivp(fun, (0, p.T), p.ode.u0, method="DOP853", rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(res.y[:, -1], p.final, atol=1e-8)
        np.testing.assert_allclose(p.exact(0.0), p.ode.u0, atol=1e-12)


def test_problem_without_published_value_gets_a_reference_trajectory():
    from dolfinode.bench.runner import Case

    p = P.lorenz_problem(T=1.0)
    assert p.final is None
    case = Case(p)
    assert "DOP853" in case.reference_note and case.ref_y.shape == (3, 100)
    np.testing.assert_array_equal(p.final, case.ref_y[:, -1])
    np.testing.assert_allclose(case.ref_y[:, 0], p.ode.u0)
    score = case.score(p.final + 1e-6, case.ref_y + 1e-6)
    assert score["err_T"] == pytest.approx(1e-6, rel=1e-6)
    assert score["err_L2"] == pytest.approx(1e-6, rel=1e-6)


def test_unknown_problem_suggests_a_name():
    with pytest.raises(ValueError, match="did you mean 'ROBER'"):
        P.get_problem("ROBBER")


def test_runner_on_a_tiny_problem(tiny):
    rows, cases = run_suite([tiny()], ["dG(1)", "cG(2)", "Radau", "RK45"], [1e-3, 1e-6],
                            repeats=2, progress=False)
    assert len(rows) == 8 and all(set(r) == set(ROW_FIELDS) for r in rows)
    for r in rows:
        assert r["status"] == "ok", r["note"]
        assert r["time_median_s"] > 0 and r["repeats"] == 2 and r["steps"] > 0
        # measured error agrees with the score: mescd from |y(T) - exp(-2)|
        assert r["mescd"] == pytest.approx(-np.log10(r["err_T"] / (1 + np.exp(-2))))
    for method in ("dG(1)", "cG(2)", "Radau", "RK45"):
        loose, tight = [r for r in rows if r["method"] == method]
        assert tight["mescd"] > loose["mescd"] + 1, method
        assert tight["err_L2"] < loose["err_L2"]
    assert cases[0].compile["first_call_s"] > 0


def test_runner_records_failures_and_skips_tighter_tolerances():
    u = sp.Symbol("u")
    blowup = P.Problem("blowup", dn.ODE({u: u**2}, u0=[1.0], T=2.0), stiff=False,
                       final=np.array([1.0]), reference="none (blows up at t = 1)")
    blowup.exact = lambda s: np.ones((1, np.size(s)))
    rows, _ = run_suite([blowup], ["dG(1)", "RK45"], [1e-3, 1e-4, 1e-5], repeats=1,
                        progress=False)
    status = {(r["method"], r["tolerance"]): r["status"] for r in rows}
    # a failure at one tolerance need not repeat at a tighter one: skipped after two in a row
    assert [status[("dG(1)", tol)] for tol in (1e-3, 1e-4, 1e-5)] == ["failed", "failed",
                                                                       "skipped"]
    assert status[("RK45", 1e-3)] == "failed"


def test_large_systems_get_sparse_jacobians_and_lsoda_a_dense_one():
    p = P.reaction_front(n=50, T=0.002)
    rows, _ = run_suite([p], ["LSODA", "Radau", "dG(2)"], [1e-4], repeats=1, progress=False)
    for r in rows:
        assert r["status"] == "ok", r["note"]
        assert r["mescd"] > 3


def test_bad_runner_input_is_rejected(tiny):
    with pytest.raises(ValueError, match="at least one"):
        run_suite([], ["dG(1)"], [1e-3], progress=False)
    with pytest.raises(ValueError):
        run_suite([tiny()], ["xG(1)"], [1e-3], progress=False)


def test_equal_accuracy_interpolates_on_the_pareto_front():
    rows = []
    for method, solver, pts in (("A", "dolfinode", [(3.0, 1e-3), (5.0, 1e-2), (7.0, 1e-1)]),
                                ("B", "scipy", [(4.0, 1e-2), (6.0, 1.0), (5.5, 2.0)])):
        for digits, seconds in pts:
            rows.append({"problem": "p", "solver": solver, "method": method, "status": "ok",
                         "mescd": digits, "time_median_s": seconds})
    table = {e["level"]: e for e in report.equal_accuracy(rows, "p")}
    assert sorted(table) == [3, 4, 5, 6]
    assert table[4]["dolfinode_time_s"] == pytest.approx(10 ** -2.5)
    assert table[4]["scipy_time_s"] == pytest.approx(1e-2) and not table[4]["scipy_clamped"]
    assert table[3]["scipy_clamped"]          # below B's loosest run
    assert table[6]["scipy_time_s"] == pytest.approx(1.0)   # (5.5, 2 s) is off the front


def test_headline_verdicts():
    def entry(level, ratio):
        return {"level": level, "ratio": ratio, "dolfinode_best": "dG(2)", "scipy_best": "Radau",
                "dolfinode_time_s": ratio, "scipy_time_s": 1.0, "dolfinode_clamped": False,
                "scipy_clamped": False}

    rows = []
    for solver, method, pts in (("dolfinode", "dG(2)", [(5.0, 0.1), (8.0, 0.4)]),
                                ("scipy", "Radau", [(5.0, 1.0), (8.0, 0.2)])):
        rows += [{"problem": "p", "solver": solver, "method": method, "status": "ok",
                  "mescd": d, "time_median_s": s} for d, s in pts]
    heads = report.headline(rows, {"p": {"stiff": True, "multiscale": False}})
    assert heads["p"]["levels_compared"] == [6, 7, 8] and not heads["p"]["target_met"]
    heads["q"] = {"stiff": True, "table": [entry(4, 0.5)], "target_met": False,
                  "levels_compared": []}
    heads["r"] = {"stiff": True, "table": [entry(6, 0.5), entry(7, 0.25)], "target_met": True,
                  "levels_compared": [6, 7]}
    text = report.readme_paragraph({"date": "d", "cpu_count": 2, "tolerances": [1e-4],
                                    "command": "c"}, heads, "m", "p")
    assert "met on r; not met on p (slower at some level), q (no level >= 6" in text
    assert "r 0.25-0.5 (mescd 6-7)" in text
    del heads["p"], heads["q"]
    text = report.readme_paragraph({"date": "d", "cpu_count": 2, "tolerances": [1e-4],
                                    "command": "c"}, heads, "m", "p")
    assert "met on r. " in text and "not met" not in text
    table = report.summary_table(heads)
    assert "| r | yes | 6-7 | 0.5 (2x faster; 6, dG(2) vs Radau)" in table


def test_cli_bench_writes_every_output(tmp_path, capsys, tiny_registered):
    readme = tmp_path / "README.md"
    readme.write_text("# x\n\n## Benchmarks\n\n## Documentation\n")
    assert main(["bench", "--problems", "decay", "--methods", "dG(1),LSODA", "--tolerances",
                 "1e-3,1e-5", "--repeats", "1", "--output", str(tmp_path), "--no-progress",
                 "--update-readme", str(readme)]) == 0
    for ext in ("csv", "json", "png", "md"):
        assert (tmp_path / f"suite.{ext}").stat().st_size > 0
    record = json.loads((tmp_path / "suite.json").read_text())
    assert len(record["runs"]) == 4 and "decay" in record["headline"]
    text = readme.read_text()
    assert report.README_BEGIN in text and "decay" in text
    assert text.index(report.README_END) < text.index("## Documentation")
    assert "decay" in capsys.readouterr().out


def test_cli_bench_rejects_bad_input(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "--problems", "nonsense", "--no-progress"])
    assert "unknown benchmark problem" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "--methods", "Radau,eG(1)", "--no-progress"])
    err = capsys.readouterr().err
    assert "eG(1)" in err and "or a scipy solver: RK45, DOP853" in err
    with pytest.raises(SystemExit):
        main(["bench", "--tolerances", "1e-4,-1", "--no-progress"])
    assert "tolerances must lie in (0, 1), got -1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "--tolerances", "1e-4,abc", "--no-progress"])
    assert "expected comma-separated numbers" in capsys.readouterr().err


def test_multiadaptive_problems_are_found_by_name_and_solve_their_odes():
    """The problems of benchmarks/run_multiadaptive.py (not in the default suite)."""
    from dolfinode.bench.multirate import MULTIADAPTIVE_PROBLEMS

    assert not set(MULTIADAPTIVE_PROBLEMS) & set(P.PROBLEMS)
    p = P.get_problem("Oscillators")
    assert p.name == "oscillators" and p.ode.N == 4
    fun, _ = numpy_functions(p.ode)
    res = solve_ivp(fun, (0, 0.05), p.ode.u0, method="DOP853", rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res.y[:, -1], p.exact(0.05), rtol=1e-9, atol=1e-9)
    # building the 200-mass chain takes ~10 s of sympy: only its registration is checked
    assert {"chain-stiff", "reaction-500"} <= set(MULTIADAPTIVE_PROBLEMS)


def test_target_section_states_met_and_missed_with_ratios():
    def entry(level, ratio):
        return {"level": level, "ratio": ratio, "dolfinode_best": "dG(2)", "scipy_best": "LSODA"}

    heads = {"fast": {"stiff": True, "multiscale": True, "table": [entry(6, 0.005), entry(7, 0.002)]},
             "slow": {"stiff": True, "multiscale": False, "table": [entry(5, 0.1), entry(6, 2.0)]},
             "wave": {"stiff": False, "multiscale": True, "table": [entry(6, 0.5)]}}
    text = report.target_section(heads)
    assert "* fast: met (ratio 0.002-0.005 over mescd 6-7" in text
    assert "* slow: **not met** (ratio 2 over mescd 6-6; worst at 6 digits: dG(2) vs LSODA)" in text
    assert "* wave: **not met** (ratio 0.5 over" in text
    assert text.count("* fast") == 2 and "* slow" not in text.split("Multiscale")[1]


# the seed model at kappa = 1e4 resolves 66% of [t0, T]: modeling warns that it saves little
@pytest.mark.filterwarnings("ignore:automatic modeling resolves")
def test_modeling_variant_runs_where_declared_and_is_scored_on_x1(tiny):
    """cG(2)+modeling runs on a seed model (its declared average_length) and not on a problem
    without modeling parameters; the seed models are scored on x1 alone."""
    seed = P.seed_model(1e6, T=1.0)
    assert seed.modeling == {"average_length": pytest.approx(0.03)} and seed.scored == (0,)
    assert P.seed_model(1e2).modeling is None
    rows, cases = run_suite([seed, tiny()], ["cG(2)+modeling", "cG(2)"], [1e-3], repeats=1,
                            progress=False)
    assert [(r["problem"], r["method"]) for r in rows] == [
        (seed.name, "cG(2)+modeling"), (seed.name, "cG(2)"), ("decay", "cG(2)")]
    modeled = rows[0]
    assert set(modeled) == set(ROW_FIELDS) and modeled["status"] == "ok", modeled["note"]
    assert modeled["time_median_s"] > 0 and modeled["elements"] > 0
    assert modeled["factorizations"] is None and modeled["dn_solve_time_s"] is None
    # the modeling error bounds it: the omitted A cos(2 w t), |A| ~ 1 / (16 kappa) = 6e-8 at
    # kappa = 1e6 (measured 7.4 digits in x1 at T)
    assert 4 < modeled["mescd"] < 8.5
    assert modeled["mescd"] == pytest.approx(
        -np.log10(modeled["err_T"] / (1 + abs(seed.final[0]))))
    # x1 only: an error in the fast components does not count
    case = cases[0]
    wrong = seed.final + [0.0, 1.0, 0.0, 1.0]
    assert case.score(wrong, case.ref_y)["mescd"] == 300
    info = report.problem_info(cases)
    assert info[seed.name]["scored"] == ["x1"] and info["decay"]["scored"] is None


def test_abandoned_scipy_runs_are_timeouts_and_bound_scipy_time():
    rows, _ = run_suite([P.seed_model(1e6, T=1.0)], ["RK45"], [1e-3, 1e-4], repeats=1,
                        time_limit=0.02, progress=False)
    assert [r["status"] for r in rows] == ["timeout", "skipped"]
    assert rows[0]["first_call_s"] >= 0.02 and "over 0.02 s" in rows[0]["note"]
    assert rows[1]["note"] == "timeout at tolerance 0.001"

    def run(solver, method, status, digits=None, seconds=None, spent=None):
        return {"problem": "p", "solver": solver, "method": method, "status": status,
                "mescd": digits, "time_median_s": seconds, "first_call_s": spent}

    rows = [run("dolfinode", "cG(2)+modeling", "ok", 2.5, 0.01),
            run("dolfinode", "cG(2)+modeling", "ok", 3.0, 0.02),
            run("scipy", "DOP853", "ok", 2.2, 1.0), run("scipy", "DOP853", "timeout", spent=5.1),
            run("scipy", "Radau", "timeout", spent=5.0)]
    table = {e["level"]: e for e in report.equal_accuracy(rows, "p")}
    assert not table[2]["scipy_bound"] and table[2]["scipy_best"] == "DOP853"
    # level 3: no scipy solver reached it and every one was abandoned: scipy > 5 s
    assert table[3]["scipy_bound"] and table[3]["scipy_time_s"] == 5.0
    assert table[3]["ratio"] == pytest.approx(0.02 / 5.0)
    assert "| 3 | cG(2)+modeling | 20 ms | none (all over the time limit) | > 5 s | < 0.004 |" \
        in report.level_table(table.values())
    # a solver that ended its sweep below a level gives no bound there
    rows.append(run("scipy", "LSODA", "ok", 2.1, 0.5))
    assert [e["level"] for e in report.equal_accuracy(rows, "p")] == [2]


def test_multiscale_target_uses_the_modeling_runs():
    def run(method, solver, digits, seconds):
        return {"problem": "s", "solver": solver, "method": method, "status": "ok",
                "mescd": digits, "time_median_s": seconds, "first_call_s": seconds}

    rows = [run("cG(2)+modeling", "dolfinode", 4.2, 0.001), run("dG(3)", "dolfinode", 6.5, 0.05),
            run("dG(3)", "dolfinode", 8.5, 0.1), run("LSODA", "scipy", 4.5, 0.2),
            run("LSODA", "scipy", 8.5, 1.0)]
    heads = report.headline(rows, {"s": {"stiff": False, "multiscale": True}})
    h = heads["s"]
    assert [e["level"] for e in h["modeling_table"]] == [4]
    assert h["modeling_table"][0]["ratio"] == pytest.approx(0.005)
    assert h["modeling_table"][0]["scipy_clamped"]   # LSODA's loosest run is more accurate
    text = report.target_section(heads)
    assert ("* s: met (with automatic modeling: ratio 0.005 over mescd 4-4; worst at 4 "
            "digits: cG(2)+modeling vs LSODA. All methods, mescd >= 6: ratio") in text
    readme = report.readme_paragraph({"date": "d", "cpu_count": 2, "tolerances": [1e-4],
                                      "command": "c"}, heads, "m", "p")
    assert "with automatic modeling 0.005 (mescd 4-4)" in readme
    assert "(s): met on s." in readme


def test_cli_bench_merges_a_run_into_the_record_and_rewrites_it(tmp_path, monkeypatch,
                                                                 tiny_registered):
    from dolfinode.bench import problems

    def renamed():
        problem = tiny_registered()
        problem.name = "decay2"
        return problem

    monkeypatch.setitem(problems.PROBLEMS, "decay2", renamed)
    common = ["--methods", "dG(1),LSODA", "--tolerances", "1e-3", "--repeats", "1",
              "--output", str(tmp_path), "--no-progress"]
    with pytest.raises(SystemExit):
        main(["bench", "--problems", "decay", "--merge", *common])
    assert main(["bench", "--problems", "decay,decay2", *common]) == 0
    first = json.loads((tmp_path / "suite.json").read_text())
    assert main(["bench", "--problems", "decay2", "--methods", "cG(1),LSODA", "--merge",
                 *common[2:]]) == 0
    record = json.loads((tmp_path / "suite.json").read_text())
    assert list(record["problems"]) == ["decay", "decay2"]
    methods = [(r["problem"], r["method"]) for r in record["runs"]]
    assert methods == [("decay", "dG(1)"), ("decay", "LSODA"), ("decay2", "cG(1)"),
                       ("decay2", "LSODA")]
    assert record["runs"][0] == first["runs"][0]
    assert record["meta"]["command"] == first["meta"]["command"]
    assert record["meta"]["merged"][0]["problems"] == ["decay2"]
    assert "Merged: decay2 re-run" in (tmp_path / "suite.md").read_text()
    # merging decay2 again supersedes the first merge's note
    assert main(["bench", "--problems", "decay2", "--methods", "cG(1),LSODA", "--merge",
                 *common[2:]]) == 0
    record = json.loads((tmp_path / "suite.json").read_text())
    assert [m["problems"] for m in record["meta"]["merged"]] == [["decay2"]]
    # --report-only rewrites the outputs from the record, running nothing
    (tmp_path / "suite.md").unlink()
    assert main(["bench", "--report-only", "--output", str(tmp_path), "--no-progress"]) == 0
    assert json.loads((tmp_path / "suite.json").read_text())["runs"] == record["runs"]
    assert "Merged: decay2 re-run" in (tmp_path / "suite.md").read_text()


def test_reaction_front_travels_inside_the_domain():
    """The suite's front starts inside [0, L] and moves right at about sqrt(gamma eps / 2)."""
    p = P.reaction_front(n=200, T=0.05)
    xs = np.linspace(0.0, 1.0, 200)
    sol = dn.solve(p.ode, method="dG(2)", tolerance=1e-6)

    def position(u):
        return np.interp(0.5, u[::-1], xs[::-1])  # u decreases in x

    moved = position(sol(p.ode.T)) - position(p.ode.u0)
    assert 0.0 < position(p.ode.u0) < 0.9
    assert moved == pytest.approx(np.sqrt(1000.0 * 0.01 / 2) * p.ode.T, rel=0.25)
