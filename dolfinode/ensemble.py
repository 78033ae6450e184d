"""Ensembles: one declaration solved for many parameter values or initial values.

Each variation is solved independently, u_k' = f(u_k, t; p_k), u_k(t0) = u0_k, through
any :class:`concurrent.futures.Executor` or a ``dask.distributed.Client`` (both offer
``submit(fn, *args)`` returning futures with ``result()``). What travels to a worker is the
declaration (sympy expressions or templates and arrays), never compiled kernels: the worker
lowers it once and then finds the kernels in its own disk cache (``DOLFINODE_CACHE_DIR``),
so on a cluster every node compiles each distinct system at most once.
"""
import difflib
from collections.abc import Mapping, Sequence

import sympy as sp

from dolfinode.family import auto_base
from dolfinode.methods import parse_method
from dolfinode.ode import ODE
from dolfinode.parameters import check_parameters

#: Keys of a variation besides parameter symbols.
_FIELDS = ("u0", "T", "t0")


def vary(ode, variation):
    """A copy of ``ode`` with some parameter values, the initial value or the time interval
    replaced, validated like the original declaration.

    Parameters
    ----------
    ode : ODE or TemplateODE
    variation : dict
        Keys: parameter symbols (or their names) -> new values; ``"u0"`` -> initial values
        (dict by state or sequence); ``"T"``, ``"t0"`` -> times.

    Raises
    ------
    TypeError, ValueError
        For keys that are neither parameters nor fields (with the closest name), and values
        the declaration would reject.
    """
    if not isinstance(variation, Mapping):
        raise TypeError(f"a variation must be a dict {{parameter or 'u0'/'T'/'t0': value}}, got "
                        f"{type(variation).__name__}: {variation!r}")
    by_name = {s.name: s for s in ode.params}
    params = dict(ode.params)
    # a shallow copy without copy.copy's protocol (a prepared solve notices it); the kernels
    # are shared: lower() makes their p from the copy's values
    new = object.__new__(type(ode))
    new.__dict__.update(ode.__dict__)
    for key, value in variation.items():
        if key not in _FIELDS:
            params[parameter_symbol(by_name, key)] = value
    new.params = params
    if "u0" in variation:
        new.u0 = variation["u0"]
    new._set_interval(variation.get("t0", ode.t0), variation.get("T", ode.T))
    return new


def parameter_symbol(by_name, key):
    """The parameter symbol of a variation key (its symbol or name; ``by_name``: name ->
    symbol); ValueError with the closest name for any other key."""
    symbol = by_name.get(key.name if isinstance(key, sp.Symbol) else key)
    if symbol is None or (key is not symbol and isinstance(key, sp.Symbol) and key != symbol):
        name = getattr(key, "name", str(key))
        match = difflib.get_close_matches(name, [*by_name, *_FIELDS], n=1, cutoff=0.5)
        hint = f"; did you mean {match[0]!r}?" if match else ""
        raise ValueError(f"variation key {key!r} is neither a parameter of the ODE nor one of "
                         f"{', '.join(_FIELDS)}{hint}")
    return symbol


def _solve_variation(ode, method, parameters, reduce):
    """Runs on a worker: solve one variation and optionally reduce its solution."""
    from dolfinode.solve import solve
    solution = solve(ode, method, **parameters)
    return solution if reduce is None else reduce(solution)


def solve_ensemble(ode, variations, executor=None, reduce=None, progress=False,
                   method="cG(1)", return_exceptions=False, **parameters):
    """Solve ``ode`` once per variation, in parallel through ``executor``.

    Parameters
    ----------
    ode : ODE or TemplateODE
        The base declaration.
    variations : sequence of dict
        One dict per run, see :func:`vary`; e.g. ``[{k: 1.0}, {k: 2.0, "u0": [0, 1]}]``.
    executor : concurrent.futures.Executor or dask.distributed.Client, optional
        Where the runs go (default: one after another in this process). With a process pool
        or a cluster, ``reduce`` must be picklable (a module-level function, not a lambda).
        For a cluster: ``Client("tcp://scheduler:8786")``. On a dask cluster the runs of a
        worker that dies are resubmitted by the scheduler (up to its ``allowed_failures``).
    reduce : callable, optional
        Solution -> value computed where the run happened (only the value comes back),
        e.g. ``lambda sol: sol(sol.ode.T)`` in process.
    progress : bool
        Show a tqdm bar over the runs.
    method, **parameters
        As for :func:`dolfinode.solve`; checked before any run starts.
    return_exceptions : bool, default False
        True: a run that fails takes its place in the result as its exception (the
        convention of ``asyncio.gather``), and every other run completes. False: the first
        failure is raised.

    Returns
    -------
    list
        Solutions (or reduced values), in the order of ``variations``; with
        ``return_exceptions=True`` failed runs are their exceptions (a
        :class:`~dolfinode.SolverError` has ``status`` -1 and ``success`` False, like the
        solutions' ``status`` 0 or 1 and ``success`` True).

    Raises
    ------
    TypeError, ValueError
        For bad variations or parameters, before anything runs. Unless
        ``return_exceptions``, an error in a run is raised again here, with a note naming the
        variation (the runs not yet finished are cancelled).
    """
    if isinstance(variations, (Mapping, str)) or not isinstance(variations, Sequence):
        raise TypeError("variations must be a sequence (list) of dicts, one per run, got "
                        f"{type(variations).__name__}")
    if not isinstance(ode, ODE):
        raise TypeError(f"solve_ensemble expects a dolfinode.ODE, got {type(ode).__name__}")
    if reduce is not None and not callable(reduce):
        raise TypeError(f"reduce must be a function of the solution, got {reduce!r}")
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError("executor must be a concurrent.futures.Executor or a "
                        f"dask.distributed.Client (something with submit), got {executor!r}")
    parse_method(auto_base(method) or method)
    check_parameters(parameters)
    runs = [vary(ode, variation) for variation in variations]
    if executor is None:
        return _collect(runs, progress, return_exceptions,
                        lambda run: _solve_variation(run, method, parameters, reduce))
    futures = [executor.submit(_solve_variation, run, method, parameters, reduce) for run in runs]
    try:
        return _collect(futures, progress, return_exceptions, lambda future: future.result())
    finally:
        for future in futures:  # after a failure: do not leave the rest running
            future.cancel()


def _collect(items, progress, return_exceptions, result):
    """``result(item)`` for every item in order, with a progress bar; a failure is kept in
    place (``return_exceptions``) or raised with a note naming its variation."""
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=len(items), unit="run", desc="ensemble")
    out = []
    try:
        for number, item in enumerate(items):
            try:
                out.append(result(item))
            except Exception as error:
                if hasattr(error, "add_note"):  # Python >= 3.11
                    held = ("; the runs before it are kept in this process: reduce= keeps "
                            "only what you need of each" if number and
                            isinstance(error, MemoryError) else "")
                    error.add_note(f"(in variation {number} of solve_ensemble{held}"
                                   + (")" if return_exceptions else
                                      "; return_exceptions=True keeps the other runs)"))
                if not return_exceptions:
                    raise
                out.append(error)
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    return out
