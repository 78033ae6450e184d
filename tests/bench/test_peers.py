"""The compiled peers of ``dolfinode bench --peers``: generated right-hand sides, adapters,
the runner's handling of peers, the Brusselator and the peers' ratios and targets."""
import ctypes

import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench import command, peer_report, peers
from dolfinode.bench import problems as P
from dolfinode.bench.runner import run_suite
from dolfinode.compile import lower


def _pointer(array):
    return array.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


@pytest.mark.parametrize("name", ["HIRES", "POLLU", "Arenstorf", "seed k=1e2"])
def test_generated_numba_rhs_equals_the_compiled_f(name):
    """The numba cfunc generated from the sympy declaration (numbalsoda's right-hand side)
    is dolfinode's compiled f on random states, and counts its calls in p[0]."""
    ode = P.get_problem(name).ode
    rhs = peers.numba_rhs(ode)
    rng = np.random.default_rng(1)
    calls = np.zeros(1)
    for k in range(3):
        u = np.abs(ode.u0) + rng.random(ode.N)
        du = np.empty(ode.N)
        rhs.ctypes(0.7 * k, _pointer(u), _pointer(du), _pointer(calls))
        expected = lower(ode).f(u, 0.7 * k)
        np.testing.assert_allclose(du, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())
    assert calls[0] == 3


def _stiff_linear():
    """y' = A y with eigenvalues -1 and -1000 (exact solution by the matrix exponential)."""
    ode, exact = P.linear([[-1.0, 1.0], [0.0, -1000.0]], [1.0, 1.0], 2.0)
    return P.Problem("stiff-linear", ode, stiff=True, final=exact(2.0), exact=exact)


@pytest.mark.parametrize("method", list(peers.PEERS))
def test_each_installed_peer_solves_to_its_tolerance(method):
    """Each peer reaches its tolerance on a small problem it suits (stiff linear, or the
    harmonic oscillator for the explicit ones): error at T within 100 x tolerance, and
    tighter with a tighter tolerance."""
    pytest.importorskip(peers.PEERS[method][1])
    problem = _stiff_linear()
    if peers.PEERS[method][0].unsuitable(problem):
        problem = P.harmonic_problem(T=5.0)
    t_eval = np.linspace(0.0, problem.T, 11)
    peer = peers.make_peer(method, problem.ode, t_eval)
    assert peer.build() > 0
    errors = []
    for tol in (1e-5, 1e-8):
        y, counts = peer.solve(tol, tol)
        assert y.shape == (problem.ode.N, 11)
        np.testing.assert_allclose(y[:, 0], problem.ode.u0)
        errors.append(np.abs(y[:, -1] - problem.final).max())
        assert errors[-1] < 100 * tol, (method, tol, errors[-1])
        assert set(counts) == {"f_evals", "jacobians", "steps", "rejected"}
    assert errors[1] < errors[0]


def test_cvode_uses_the_band_solver_on_the_brusselator():
    pytest.importorskip("sksundae")
    problem = P.brusselator(n=30, T=1.0)
    peer = peers.make_peer("CVODE-BDF", problem.ode, np.linspace(0.0, 1.0, 5))
    peer.build()
    assert peer.note == "band linear solver (kl = 2, ku = 2)"
    y, counts = peer.solve(1e-8, 1e-8)
    assert counts["jacobians"] > 0 and counts["f_evals"] > counts["jacobians"]
    ref = dn.solve(problem.ode, method="cG(3)", tolerance=1e-9)(1.0)
    np.testing.assert_allclose(y[:, -1], ref, atol=1e-6)


def test_brusselator_is_hairer_wanner_bruss():
    """f of the declaration equals the finite-difference Brusselator written with NumPy, and
    the interleaved ordering gives a Jacobian of bandwidth 2."""
    n = 7
    problem = P.brusselator(n=n)
    ode = problem.ode
    assert problem.name == "bruss-7" and ode.N == 2 * n and ode.T == 10.0
    x = np.arange(1, n + 1) / (n + 1)
    np.testing.assert_allclose(ode.u0[0::2], 1 + np.sin(2 * np.pi * x))
    y = 1.0 + np.random.default_rng(0).random(2 * n)
    u, v = y[0::2], y[1::2]
    c = (n + 1) ** 2 / 50.0
    lap_u = np.diff(np.concatenate([[1.0], u, [1.0]]), 2)
    lap_v = np.diff(np.concatenate([[3.0], v, [3.0]]), 2)
    expected = np.empty(2 * n)
    expected[0::2] = 1 + u**2 * v - 4 * u + c * lap_u
    expected[1::2] = 3 * u - u**2 * v + c * lap_v
    compiled = lower(ode)
    np.testing.assert_allclose(compiled.f(y, 0.0), expected, rtol=1e-12)
    assert peers.bandwidths(compiled.indptr, compiled.indices) == (2, 2)


def test_runner_times_peers_with_dolfinode_and_skips_what_does_not_apply(monkeypatch):
    """Peers get rows like any method (scored, timed, build time apart); a peer not installed,
    or unsuited to the problem, gets none."""
    pytest.importorskip("sksundae")
    problem = _stiff_linear()
    rows, cases = run_suite([problem], ["dG(2)", "CVODE-BDF", "numbalsoda-DOP853"],
                            [1e-4, 1e-7], repeats=2, progress=False)
    cvode = [r for r in rows if r["method"] == "CVODE-BDF"]
    assert [r["solver"] for r in cvode] == ["scikit-sundae"] * 2
    assert all(r["status"] == "ok" and r["time_min_s"] > 0 and r["repeats"] == 2
               for r in cvode)
    assert cvode[1]["mescd"] > cvode[0]["mescd"]
    assert not [r for r in rows if r["method"] == "numbalsoda-DOP853"]   # explicit, stiff
    assert cases[0].compile["peers"]["CVODE-BDF"] > 0
    monkeypatch.setattr(peers, "installed", lambda method: False)
    rows, _ = run_suite([problem], ["dG(2)", "CVODE-BDF"], [1e-4], repeats=1, progress=False)
    assert [r["method"] for r in rows] == ["dG(2)"]


def test_peers_option_plans_the_groups(monkeypatch):
    """--peers runs the issue's problems in groups with the installed peers; --problems and
    --methods narrow it; the outputs are named peers.* in a new folder."""
    import argparse

    monkeypatch.setattr(peers, "available", lambda: (["CVODE-BDF"], []))
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    args = parser.parse_args(["--peers"])
    monkeypatch.setattr(command, "get_problem", lambda name: name)   # no problem is built
    groups, _ = command.plan(args)
    assert args.output.startswith("dolfinode-bench-") and args.name == "peers"
    names = [n for group, *_ in groups for n in group]
    assert names == [n for g, *_ in command.PEER_GROUPS for n in g]
    assert all("CVODE-BDF" in ms for _, ms, _ in groups)
    assert any("mcG(2)" in ms for _, ms, _ in groups)
    assert groups[0][2] == list(command.STIFF_TOLERANCES) and groups[-1][2][-1] == 1e-11
    assert groups[1][2] == list(command.FULL_TOLERANCES)
    # --problems: each problem keeps its group's sweep
    args = parser.parse_args(["--peers", "--problems", "ROBER,MEDAKZO,POLLU"])
    assert [(names, tols) for names, _, tols in command.plan(args)[0]] == [
        (["ROBER", "POLLU"], list(command.STIFF_TOLERANCES)),
        (["MEDAKZO"], list(command.FULL_TOLERANCES))]
    args = parser.parse_args(["--peers", "--problems", "HIRES", "--methods", "dG(2)",
                              "--tolerances", "1e-4"])
    assert command.plan(args)[0] == [(["HIRES"], ["dG(2)", "CVODE-BDF"], [1e-4])]


def test_peers_problems_keep_their_groups(monkeypatch):
    """--peers --problems re-runs rows as the full run makes them: each named problem with its
    group's methods and tolerances (the Brusselator: no scipy, from rtol 1e-1), a problem of
    no group with every method."""
    import argparse

    monkeypatch.setattr(peers, "available", lambda: (["CVODE-BDF"], []))
    monkeypatch.setattr(command, "get_problem", lambda name: name)
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    args = parser.parse_args(["--peers", "--problems", "bruss-4000,decay,MEDAKZO",
                              "--output", "out"])
    groups, _ = command.plan(args)
    bruss = next(g for g in command.PEER_GROUPS if "bruss-4000" in g[0])
    medakzo = next(g for g in command.PEER_GROUPS if "MEDAKZO" in g[0])
    assert groups[0] == (["MEDAKZO"], list(medakzo[1]) + list(medakzo[2]) + ["CVODE-BDF"],
                         list(command.FULL_TOLERANCES))
    assert groups[1] == (["bruss-4000"], list(bruss[1]) + ["CVODE-BDF"], list(bruss[3]))
    assert groups[1][2][0] == 1e-1 and not set(groups[1][1]) & set(command.PEER_SCIPY)
    assert groups[2][0] == ["decay"] and "cG(1)" in groups[2][1] and "BDF" in groups[2][1]


def _rows(problem, curves):
    return [{"problem": problem, "solver": solver, "method": method, "status": "ok",
             "mescd": digits, "time_min_s": seconds}
            for solver, method, pts in curves for digits, seconds in pts]


def test_level_ratios_and_targets():
    """Ratios are read off each method's work-precision curve at 4/6/8/10 digits; the target
    is judged against its peer (LSODA on the small stiff problems) or, on the chains, with
    the multi-adaptive methods against the best peer."""
    rows = _rows("HIRES", [("dolfinode", "cG(3)", [(4.0, 4e-3), (10.0, 4e-3)]),
                           ("numbalsoda", "numbalsoda-LSODA", [(4.0, 1e-3), (8.0, 1e-2)]),
                           ("scipy", "Radau", [(4.0, 1.0), (10.0, 10.0)])])
    entries = {e["level"]: e for e in peer_report.level_entries(rows, "HIRES")}
    assert entries[4]["ratio"] == pytest.approx(4.0)
    assert entries[4]["peer_best"][0] == "numbalsoda-LSODA" and "target_ratio" not in entries[4]
    # LSODA at 6 digits: 10^-3 x 10^(2/4) s
    assert entries[6]["target_ratio"] == pytest.approx(4e-3 / 10 ** -2.5)
    assert not entries[6]["target_met"] and entries[8]["target_met"]
    assert entries[10]["target_ratio"] is None and entries[10]["peer_best"][0] == "Radau"
    heads = peer_report.headline(rows, {"HIRES": {"stiff": True, "multiscale": False}})
    assert heads["HIRES"]["target_met"] is False
    assert "**not met**" in peer_report.summary_table(heads)

    rows = _rows("chain-1e4", [("dolfinode", "cG(2)", [(4.0, 1e-4), (6.0, 1e-4)]),
                               ("dolfinode", "mcG(2)", [(4.0, 3e-3), (6.0, 3e-3)]),
                               ("numbalsoda", "numbalsoda-DOP853", [(4.0, 1e-2), (6.0, 1e-2)])])
    entries = {e["level"]: e for e in peer_report.level_entries(rows, "chain-1e4")}
    assert entries[4]["ratio"] == pytest.approx(0.01)          # cG(2) is dolfinode's best
    assert entries[4]["target_ratio"] == pytest.approx(0.3)    # but the target is mcG's
    assert entries[6]["target_met"]


def test_cvode_keeps_its_parameter_vector():
    """CVODE's callbacks pass the kernels a pointer to the parameters: after dolfinode has
    compiled the ODE, ``lower`` returns a copy with a fresh parameter vector, which the peer
    must keep alive (once freed, its memory is reused and CVODE solves another problem)."""
    import gc

    pytest.importorskip("sksundae")
    problem = P.brusselator(n=30, T=1.0)
    ref = dn.solve(problem.ode, method="cG(3)", tolerance=1e-9)(1.0)   # compiled first
    peer = peers.make_peer("CVODE-BDF", problem.ode, np.linspace(0.0, 1.0, 5))
    peer.build()
    gc.collect()
    garbage = [np.full(len(problem.ode.parameter_values), 1e6) for _ in range(2000)]
    y, _ = peer.solve(1e-8, 1e-8)
    del garbage
    np.testing.assert_allclose(y[:, -1], ref, atol=1e-6)
