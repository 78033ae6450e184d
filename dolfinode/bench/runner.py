"""Tolerance sweeps of dolfinode methods and scipy solvers, scored and timed in one process.

For every problem, method and tolerance one untimed run gives the errors and counts; then all
runs are re-timed in interleaved rounds (one call of every run per round), so that a burst of
load from other processes spreads over many runs instead of inflating one; the time of a run is
the median of its repeats. Runs are timed in CPU time of this process (``time.process_time``,
all its threads), not wall time: the benchmark machines are shared, and CPU time does not count
the time other processes hold the cores. dolfinode's kernel compile is measured once per
problem, on the first call, and reported on its own (it is not part of any timing).

Scores (Test Set and SciMLBenchmarks conventions):

* mescd = min_i -log10(|y_i(T) - ref_i| / (atol/rtol + |ref_i|)), against the problem's
  published or exact value at T;
* L2 = root mean square of y - y_ref over 100 equispaced points and all components, against
  the exact solution or a tight scipy reference trajectory.
"""
import math
import time
import warnings
from functools import cached_property

import numpy as np

from dolfinode.bench import peers
from dolfinode.bench.numpy_functions import SPARSE_FROM, numpy_functions
from dolfinode.bench.problems import mescd

#: The scipy solvers the runner knows.
SCIPY_METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA")
#: Solvers that use a Jacobian.
IMPLICIT = ("Radau", "BDF", "LSODA")
#: The clock of every timed run: CPU time of this process (robust on a shared machine).
clock = time.process_time
#: Points of the L2 error.
N_EVAL = 100
#: Default CPU seconds after which a scipy run is abandoned, and dolfinode's maximum_steps.
TIME_LIMIT, MAXIMUM_STEPS = 20.0, 200_000
#: Suffix of a method label that solves with automatic modeling ("cG(2)+modeling"), with the
#: parameters the problem declares (``Problem.modeling``).
MODELING = "+modeling"

ROW_FIELDS = ("problem", "solver", "method", "tolerance", "atol", "status", "note",
              "time_median_s", "time_min_s", "repeats", "first_call_s", "dn_solve_time_s", "mescd",
              "err_T", "err_L2", "f_evals", "jacobians", "factorizations", "steps", "rejected",
              "elements")


def check_methods(methods):
    """Raise ValueError for a name that is neither a scipy solver, a compiled peer
    (:data:`dolfinode.bench.peers.PEERS`) nor a dolfinode method."""
    import dolfinode as dn

    for m in methods:
        if not is_scipy(m) and not peers.is_peer(m):
            try:
                dn.parse_method(split_modeling(m)[0])
            except ValueError as error:
                raise ValueError(f"{error}; or a scipy solver: {', '.join(SCIPY_METHODS)}; "
                                 f"or a compiled peer: {', '.join(peers.PEERS)} "
                                 "(a dolfinode method with '+modeling': automatic "
                                 "modeling)") from None


def is_scipy(method):
    """Whether ``method`` names a scipy solver (else a dolfinode method)."""
    return method in SCIPY_METHODS


def split_modeling(method):
    """(dolfinode method, whether with automatic modeling) of a method label."""
    if method.endswith(MODELING):
        return method[:-len(MODELING)], True
    return method, False


def applies(problem, method):
    """Whether the runner runs ``method`` on ``problem``: a modeling variant only on a problem
    that declares modeling parameters, a compiled peer only where it is installed and suited
    (:meth:`dolfinode.bench.peers.Peer.unsuitable`)."""
    if peers.is_peer(method):
        return peers.installed(method) and peers.PEERS[method][0].unsuitable(problem) is None
    return not split_modeling(method)[1] or problem.modeling is not None


class RunTimeout(Exception):
    """A scipy run passed its time limit."""


def with_deadline(fun, seconds):
    """fun wrapped to raise RunTimeout once ``seconds`` of CPU time (:data:`clock`) have
    passed; also records the last t."""
    deadline = clock() + seconds
    last = [0.0]

    def wrapped(s, y):
        last[0] = s
        if clock() > deadline:
            raise RunTimeout(s)
        return fun(s, y)

    return wrapped, last


class Case:
    """A problem prepared for the runner: scipy functions, the reference trajectory, scoring.

    Parameters
    ----------
    problem : Problem
    """

    def __init__(self, problem):
        self.problem = problem
        self.ode = problem.ode
        self.t_eval = np.linspace(self.ode.t0, self.ode.T, N_EVAL)
        start = time.perf_counter()
        if problem.exact is not None:
            self.ref_y = np.asarray(problem.exact(self.t_eval), dtype=float)
            self.reference_note = problem.reference
        else:
            self.ref_y, self.reference_note = self._reference_trajectory()
        if problem.final is None:
            problem.final = self.ref_y[:, -1].copy()
        self.ref_y[:, -1] = problem.final
        self.reference_seconds = time.perf_counter() - start
        self.compile = None
        self.peers = {}

    @cached_property
    def _numpy_functions(self):
        return numpy_functions(self.ode)

    @property
    def fun(self):
        """scipy's right-hand side f(t, y) (lambdified on first use: O(N) sympy work)."""
        return self._numpy_functions[0]

    @property
    def jac(self):
        """scipy's Jacobian J(t, y) (see :func:`numpy_functions`)."""
        return self._numpy_functions[1]

    def _reference_trajectory(self):
        """The solution at the 100 points from scipy at a tight tolerance (Radau for stiff
        problems, DOP853 otherwise), with dolfinode's compiled f and exact Jacobian: the
        same equations as the lambdified ones, and fast for large N."""
        from scipy.integrate import solve_ivp

        from dolfinode.compile.lowering import lower

        p = self.problem
        method, rtol = ("Radau", 1e-11) if p.stiff else ("DOP853", 1e-13)
        atol = rtol * p.atol_ratio * 1e-2
        compiled = lower(self.ode)
        if self.ode.N > SPARSE_FROM:
            def jac(s, y):
                return compiled.jacobian_matrix(y, s).tocsc()
        else:
            def jac(s, y):
                return compiled.jacobian_matrix(y, s).toarray()

        def fun(s, y):
            return compiled.f(y, s)

        kwargs = {"jac": jac} if method == "Radau" else {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = solve_ivp(fun, (self.ode.t0, self.ode.T), self.ode.u0, method=method,
                            rtol=rtol, atol=atol, t_eval=self.t_eval, **kwargs)
        if not res.success:
            raise RuntimeError(f"{p.name}: reference trajectory failed: {res.message}")
        note = f"scipy {method}, rtol = {rtol:g}, atol = {atol:g}"
        if p.final is not None:
            note += f" (mescd {mescd(res.y[:, -1], p.final, p.atol_ratio):.1f} at T)"
        return res.y.copy(), note

    def score(self, y_final, y_samples):
        """mescd at T, max error at T and L2 error over the 100 points, over the problem's
        scored components."""
        p = self.problem
        scored = slice(None) if p.scored is None else list(p.scored)
        y_final = np.asarray(y_final, dtype=float)[scored]
        samples = np.asarray(y_samples)[scored]
        return {"mescd": mescd(y_final, p.final[scored], p.atol_ratio),
                "err_T": float(np.max(np.abs(y_final - p.final[scored]))),
                "err_L2": float(np.sqrt(np.mean((samples - self.ref_y[scored]) ** 2)))}


def _row(case, method, tol):
    row = dict.fromkeys(ROW_FIELDS)
    solver = ("scipy" if is_scipy(method) else peers.PEERS[method][0].solver
              if peers.is_peer(method) else "dolfinode")
    row.update(problem=case.problem.name, solver=solver,
               method=method, tolerance=tol, atol=tol * case.problem.atol_ratio, status="ok",
               note="", repeats=0)
    return row


def first_call(case):
    """The first dn.solve of a problem (dG(1), tolerance 1e-2): kernel generation and C compile
    or a load from the disk cache. Its times are stored in ``case.compile``."""
    import dolfinode as dn

    start = time.perf_counter()
    try:
        sol = dn.solve(case.ode, method="dG(1)", tolerance=1e-2, maximum_steps=1000,
                       estimate_global_error=False)
        compile_s = sol.stats["compile time"]
    except dn.SolverError:
        compile_s = float("nan")
    case.compile = {"N": case.ode.N, "first_call_s": time.perf_counter() - start,
                    "compile_time_s": compile_s}
    return case.compile


def run_dolfinode(case, method, tol, maximum_steps):
    """One untimed dolfinode run: errors and counts. Returns (row, timed call or None).
    A modeling variant (:data:`MODELING`) solves with automatic modeling and the problem's
    modeling parameters."""
    import dolfinode as dn

    row = _row(case, method, tol)
    base, modeling = split_modeling(method)
    # (the peers estimate no error at T: the comparison times the integration alone)
    options = {"method": base, "tolerance": tol, "absolute_tolerance": row["atol"],
               "maximum_steps": maximum_steps, "estimate_global_error": False}
    if modeling:
        options.update(automatic_modeling=True, **case.problem.modeling)
    try:
        start = clock()
        sol = dn.solve(case.ode, **options)
        row["first_call_s"] = clock() - start
    except (dn.SolverError, ValueError) as exc:
        row.update(status="failed", note=f"{type(exc).__name__}: {exc}")
        return row, None
    st = sol.stats
    row.update(case.score(sol(case.ode.T), sol(case.t_eval)))
    row.update(f_evals=st["f evaluations"], jacobians=st["jacobian evaluations"],
               factorizations=st.get("factorizations"), steps=st["time slabs"],
               rejected=st["rejected steps"], elements=st["elements"])

    def timed():
        sol = dn.solve(case.ode, **options)
        sol(case.t_eval)   # the peers return the 100 points inside their timed call too
        # with modeling, "solve time" is the wall time of the whole pipeline, not a loop's
        return None if modeling else sol.stats["solve time"]

    return row, timed


def _scipy_solve(case, method, tol, fun, **extra):
    from scipy.integrate import solve_ivp

    kwargs = {}
    if method == "LSODA" and case.ode.N > SPARSE_FROM:   # LSODA takes dense (or banded) only
        kwargs["jac"] = lambda s, y: case.jac(s, y).toarray()
    elif method in IMPLICIT:
        kwargs["jac"] = case.jac
    atol = tol * case.problem.atol_ratio
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = solve_ivp(fun, (case.ode.t0, case.ode.T), case.ode.u0, method=method, rtol=tol,
                        atol=atol, **kwargs, **extra)
    return res, caught


def _scipy_counts(case, method, tol):
    """Accepted steps and rejected step attempts from one untimed instrumented run.

    solve_ivp reports neither: accepted steps are len(res.t) - 1 without t_eval; attempts are
    calls of the per-attempt routine (Radau: collocation solve, BDF: BDF system solve, RK:
    rk_step), so 'rejected' includes Newton-failure retries. LSODA does not expose them.
    """
    from scipy.integrate._ivp import bdf, radau, rk

    target = {"Radau": (radau, "solve_collocation_system"), "BDF": (bdf, "solve_bdf_system"),
              "DOP853": (rk, "rk_step"), "RK45": (rk, "rk_step")}.get(method)
    if target is None or not hasattr(*target):
        res, _ = _scipy_solve(case, method, tol, case.fun)
        return len(res.t) - 1, None
    module, name = target
    original = getattr(module, name)
    calls = [0]

    def counting(*args, **kwargs):
        calls[0] += 1
        return original(*args, **kwargs)

    setattr(module, name, counting)
    try:
        res, _ = _scipy_solve(case, method, tol, case.fun)
    finally:
        setattr(module, name, original)
    steps = len(res.t) - 1
    return steps, calls[0] - steps


def run_scipy(case, method, tol, time_limit):
    """One untimed scipy run: errors and counts. Returns (row, timed call or None).

    A run is abandoned after ``time_limit`` CPU seconds: status "timeout", with the CPU time
    it had used in ``first_call_s`` (a lower bound on its time)."""
    row = _row(case, method, tol)
    start = clock()   # before the deadline is set, so an abandoned run reports >= time_limit
    fun, last = with_deadline(case.fun, time_limit)
    try:
        res, caught = _scipy_solve(case, method, tol, fun, t_eval=case.t_eval)
        row["first_call_s"] = clock() - start
    except RunTimeout:
        row.update(status="timeout", first_call_s=clock() - start,
                   note=f"over {time_limit:g} s (abandoned at t = {last[0]:.4g} of "
                        f"{case.ode.T:g})")
        return row, None
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
        row.update(status="failed", note=f"{type(exc).__name__}: {exc}")   # scipy raised
        return row, None
    if not res.success:
        row.update(status="failed", note=f"solve_ivp: {res.message}")
        return row, None
    if caught:
        row["note"] = "; ".join(sorted({str(w.message).split("\n")[0] for w in caught}))
    y = res.y
    if y.shape[1] != N_EVAL or not np.all(np.isfinite(y)):
        row.update(status="failed", note="solve_ivp returned a non-finite solution")
        return row, None
    row.update(case.score(y[:, -1], y))
    row.update(f_evals=int(res.nfev), jacobians=int(res.njev), factorizations=int(res.nlu))
    row["steps"], row["rejected"] = _scipy_counts(case, method, tol)
    def timed():
        _scipy_solve(case, method, tol, case.fun, t_eval=case.t_eval)

    return row, timed


def run_peer(case, method, tol):
    """One untimed run of a compiled peer (built on its first run on the problem, the build
    time stored in ``case.compile["peers"]``): errors and counts. Returns (row, timed call
    or None)."""
    row = _row(case, method, tol)
    peer = case.peers.get(method)
    if peer is None:
        peer = case.peers[method] = peers.make_peer(method, case.ode, case.t_eval)
        case.compile.setdefault("peers", {})[method] = peer.build()
    try:
        start = clock()
        y, counts = peer.solve(tol, row["atol"])
        row["first_call_s"] = clock() - start
    except peers.PeerFailed as exc:
        row.update(status="failed", note=str(exc))
        return row, None
    if not np.all(np.isfinite(y)):
        row.update(status="failed", note=f"{method} returned a non-finite solution")
        return row, None
    row.update(case.score(y[:, -1], y), note=peer.note, **counts)

    def timed():
        try:
            peer.solve(tol, row["atol"])
        except peers.PeerFailed as exc:  # CVODE may fail on a repeat that passed before
            row["note"] = f"a timed repeat failed: {exc}"

    return row, timed


def time_interleaved(jobs, repeats, budget, bar=None):
    """Time every (row, call) in rounds of one call each: ``repeats`` calls, fewer once a
    run's calls add up to ``budget`` seconds (at least one); stores the median and the minimum
    in the row. A call may return dolfinode's ``stats["solve time"]`` (the compiled loop
    alone), whose median goes to ``dn_solve_time_s``."""
    times = {id(row): [row["first_call_s"]] for row, _ in jobs}
    inner = {id(row): [] for row, _ in jobs}
    for _ in range(repeats):
        for row, call in jobs:
            spent = times[id(row)]
            if len(spent) > repeats or (len(spent) > 1 and sum(spent) > budget):
                if bar is not None:
                    bar.update(1)
                continue
            start = clock()
            out = call()
            spent.append(clock() - start)
            if isinstance(out, float):
                inner[id(row)].append(out)
            if bar is not None:
                bar.update(1)
    for row, _ in jobs:
        spent = times[id(row)]
        timed = spent[1:] or spent   # the first call warms caches; it counts only when alone
        row.update(time_median_s=float(np.median(timed)), time_min_s=float(np.min(timed)),
                   repeats=len(timed))
        if inner[id(row)]:
            row["dn_solve_time_s"] = float(np.median(inner[id(row)]))


def run_suite(problems, methods, tolerances, *, repeats=3, budget=2.0, time_limit=TIME_LIMIT,
              maximum_steps=MAXIMUM_STEPS, progress=True):
    """Sweep every method over the tolerances on every problem, score and time the runs.

    Parameters
    ----------
    problems : list of Problem
    methods : list of str
        dolfinode methods ("cG(2)", "mdG(1)", ...), their automatic-modeling variants
        ("cG(2)+modeling", run only on problems that declare ``modeling``), scipy solvers
        (:data:`SCIPY_METHODS`) and compiled peers (:data:`dolfinode.bench.peers.PEERS`,
        run only where installed and suited).
    tolerances : list of float
        Relative tolerances; the absolute tolerance is ``problem.atol_ratio`` times each.
    repeats : int
        Timed calls per run (median); a run stops repeating once its timed calls add up to
        ``budget`` seconds.
    budget : float
    time_limit : float
        CPU seconds after which a scipy run is abandoned (explicit methods on stiff problems).
    maximum_steps : int
        dolfinode's ``maximum_steps`` (time slabs) for every run; it also bounds the memory of
        the stored solution (steps x N x (q + 1) values: 2.6 GB for dG(3) at N = 400).
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    rows : list of dict
        One per (problem, method, tolerance), keys :data:`ROW_FIELDS`.
    cases : list of Case
        The problems with their reference trajectories and compile times.

    Notes
    -----
    Once a method is abandoned (time limit) at one tolerance, or has failed at two in a row,
    its tighter tolerances are skipped: a failure at a loose tolerance (ROBER with cG(2) at
    1e-3, Newton's steps collapsing) need not repeat at tighter ones.
    A modeling variant has no rows on a problem without modeling parameters.
    """
    from tqdm.auto import tqdm

    if not problems or not methods or not tolerances:
        raise ValueError("run_suite needs at least one problem, one method and one tolerance")
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    check_methods(methods)
    tolerances = sorted(tolerances, reverse=True)
    total = sum(applies(p, m) for p in problems for m in methods) * len(tolerances)
    bar = tqdm(total=total * (1 + repeats), desc="bench", unit="run", disable=not progress)
    rows, jobs, cases = [], [], []
    try:
        for problem in problems:
            bar.set_postfix_str(f"{problem.name}: reference")
            case = Case(problem)
            first_call(case)
            cases.append(case)
            for method in (m for m in methods if applies(problem, m)):
                bar.set_postfix_str(f"{problem.name} {method}")
                given_up = None
                failures = 0  # in a row
                for tol in tolerances:
                    if given_up:
                        row = _row(case, method, tol)
                        row.update(status="skipped", note=given_up)
                        call = None
                    elif is_scipy(method):
                        row, call = run_scipy(case, method, tol, time_limit)
                    elif peers.is_peer(method):
                        row, call = run_peer(case, method, tol)
                    else:
                        row, call = run_dolfinode(case, method, tol, maximum_steps)
                    failures = failures + 1 if row["status"] == "failed" else 0
                    if not given_up and (row["status"] == "timeout" or failures == 2):
                        given_up = f"{row['status']} at tolerance {tol:g}"
                    rows.append(row)
                    if call is not None:
                        jobs.append((row, call))
                    else:
                        bar.update(repeats)
                    bar.update(1)
        bar.set_postfix_str("timing")
        time_interleaved(jobs, repeats, budget, bar)
    finally:
        bar.close()
    return rows, cases


def accuracy_levels(rows):
    """Integer mescd levels reached by at least one run."""
    vals = [r["mescd"] for r in rows if r["status"] == "ok" and r["mescd"] is not None
            and math.isfinite(r["mescd"])]
    if not vals:
        return []
    return list(range(max(1, math.floor(min(vals))), math.floor(max(vals)) + 1))
