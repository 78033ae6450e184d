"""Compiled peers for the benchmark suite: numbalsoda, CVODE (scikit-sundae) and diffrax.

Each peer solves the same sympy declaration as dolfinode, through one small interface
(:class:`Peer`): ``build`` once (code generation and compile, timed apart), then
``solve(rtol, atol)`` as often as the runner times it, returning the solution at the runner's
100 points and the counts the peer reports.

* numbalsoda (C++ LSODA and DOP853): a numba ``cfunc`` right-hand side ``rhs(t, u, du, p)``
  generated from the sympy expressions (:func:`numba_rhs_source`), so no Python runs in the
  loop. LSODA builds its Jacobian by finite differences and factors it dense.
* CVODE (SUNDIALS BDF through scikit-sundae): the right-hand side and exact Jacobian are
  dolfinode's own compiled C kernels (generated from the same sympy), called from the Python
  callbacks scikit-sundae requires; band linear solver where the Jacobian is banded, dense for
  small systems, SuperLU otherwise.
* diffrax (Kvaerno5 for stiff problems, Tsit5 otherwise) on JAX CPU in double precision: the
  right-hand side lambdified to JAX; the whole solve is jit-compiled once per problem.

The peers are optional (``pip install dolfinode[bench]``; numbalsoda builds from source with
a C++ and a Fortran compiler, e.g. ``apt-get install gfortran``): :func:`available` lists
those installed, and the runner skips the others with a note.
"""
import importlib.util
import math
import time

import numpy as np
import sympy as sp

from dolfinode.ode import t as time_symbol

#: Largest system given to a peer that factors a dense N x N matrix (numbalsoda's LSODA) or
#: traces one scalar expression per component (diffrax).
DENSE_LIMIT = 400
#: Smallest system that CVODE solves with its band linear solver (when the band is narrow).
BAND_FROM = 50
#: Steps a peer may take: CVODE between two output points, numbalsoda and diffrax in all
#: (a peer's ``max_steps``).
MAXIMUM_STEPS = 200_000


def numba_rhs_source(ode):
    """Python source of ``rhs(t, u, du, p)`` for a numba cfunc, from ``ode``'s sympy
    right-hand sides: du[i] = f_i(u, t) with the parameter values substituted and common
    subexpressions eliminated; p[0] counts the calls (p[0] += 1).

    Returns
    -------
    str
        A function definition that reads math functions from the ``math`` module.
    """
    from sympy.printing.pycode import PythonCodePrinter

    u = [sp.Symbol(f"u[{i}]", real=True) for i in range(ode.N)]
    subs = dict(zip(ode.states, u))
    subs.update(zip(ode.parameter_symbols, map(sp.Float, ode.parameter_values)))
    subs[time_symbol] = sp.Symbol("t", real=True)
    rhs = [sp.sympify(e).xreplace(subs) for e in ode.rhs]
    temporaries, reduced = sp.cse(rhs, symbols=sp.numbered_symbols("c"))
    printer = PythonCodePrinter({"fully_qualified_modules": True})
    lines = ["def rhs(t, u, du, p):", "    p[0] += 1.0"]
    lines += [f"    {s} = {printer.doprint(e)}" for s, e in temporaries]
    lines += [f"    du[{i}] = {printer.doprint(e)}" for i, e in enumerate(reduced)]
    return "\n".join(lines) + "\n"


def numba_rhs(ode):
    """The numba cfunc of :func:`numba_rhs_source`, with numbalsoda's signature
    void(double, double*, double*, double*)."""
    from numba import cfunc, types

    namespace = {"math": math}
    exec(compile(numba_rhs_source(ode), "<dolfinode numba rhs>", "exec"), namespace)
    signature = types.void(types.double, types.CPointer(types.double),
                           types.CPointer(types.double), types.CPointer(types.double))
    return cfunc(signature)(namespace["rhs"])


class PeerFailed(Exception):
    """A peer did not reach T (its message says why)."""


class Peer:
    """A compiled peer solver on one problem.

    Subclasses set ``solver`` (the package) and ``method``, may refuse a problem in
    :meth:`unsuitable`, compile in :meth:`_build` and solve in :meth:`solve`.

    Parameters
    ----------
    ode : ODE
    t_eval : ndarray
        The output points (the runner's 100 points; the last is T).
    """

    solver = method = ""
    #: Why the peer refuses N > ``largest`` (None: it does not).
    dense = None
    largest = DENSE_LIMIT
    #: True: stiff problems only; False: nonstiff only; None: both.
    stiff = None
    #: The peer's step limit (set on an instance for a long resolved run).
    max_steps = MAXIMUM_STEPS

    def __init__(self, ode, t_eval):
        self.ode = ode
        self.t_eval = np.ascontiguousarray(t_eval, dtype=float)
        self.u0 = np.array(ode.u0, dtype=float)
        self.compile_s = None
        self.note = ""

    @classmethod
    def unsuitable(cls, problem):
        """Why the peer does not run ``problem`` (None: it does)."""
        if cls.dense and problem.ode.N > cls.largest:
            return f"N > {cls.largest}: {cls.dense}"
        if cls.stiff is not None and problem.stiff != cls.stiff:
            return f"{cls.method} is for {'' if cls.stiff else 'non'}stiff problems"
        return None

    def build(self):
        """Generate and compile (once); returns the seconds it took."""
        if self.compile_s is None:
            start = time.perf_counter()
            self._build()
            try:
                self.solve(1e-3, 1e-6)   # compiles the drivers for these argument types
            except PeerFailed:
                pass
            self.compile_s = time.perf_counter() - start
        return self.compile_s

    def _build(self):
        raise NotImplementedError

    def solve(self, rtol, atol):
        """(y, counts): the solution at ``t_eval``, shape (N, len(t_eval)), and a dict of
        counts (f_evals, jacobians, steps, rejected; None where the peer reports none).

        Raises
        ------
        PeerFailed
            When the peer stops before T.
        """
        raise NotImplementedError


def _counts(f_evals=None, jacobians=None, steps=None, rejected=None):
    return {"f_evals": f_evals, "jacobians": jacobians, "steps": steps, "rejected": rejected}


class _Numbalsoda(Peer):
    solver = "numbalsoda"
    dense = "LSODA factors a dense N x N matrix"

    def _build(self):
        import numbalsoda

        self._rhs = numba_rhs(self.ode)
        self._solve = getattr(numbalsoda, self.method.lower())
        self._calls = np.zeros(1)

    def solve(self, rtol, atol):
        self._calls[0] = 0.0
        usol, success = self._solve(self._rhs.address, self.u0, self.t_eval, self._calls,
                                    rtol=rtol, atol=atol, mxstep=self.max_steps)
        if not success:
            raise PeerFailed(f"numbalsoda {self.method} did not reach T")
        return usol.T, _counts(f_evals=int(self._calls[0]))


class NumbalsodaLSODA(_Numbalsoda):
    method = "LSODA"


class NumbalsodaDOP853(_Numbalsoda):
    method = "DOP853"
    stiff = False


def bandwidths(indptr, indices):
    """(kl, ku): the lower and upper bandwidth of a CSR pattern."""
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    offsets = indices - rows
    return int(max(0, -offsets.min(initial=0))), int(max(0, offsets.max(initial=0)))


class CVODE(Peer):
    """CVODE's BDF with dolfinode's compiled right-hand side and exact Jacobian."""

    solver, method = "scikit-sundae", "CVODE-BDF"

    def _build(self):
        from dolfinode.compile.lowering import lower

        c = lower(self.ode)
        # the callbacks pass p's address: keep its owner (a later lower() makes a fresh p)
        self._compiled = c
        n = c.N
        p = c.p.ctypes.data
        rhs, jac = c.rhs, c.jacobian
        values = np.empty(max(c.nnz, 1))
        rows = np.repeat(np.arange(n), np.diff(c.indptr))
        cols = c.indices
        self._calls = [0, 0]
        calls = self._calls

        def rhsfn(s, y, yp):
            calls[0] += 1
            rhs(y.ctypes.data, s, p, yp.ctypes.data)

        kl, ku = bandwidths(c.indptr, c.indices)
        if n >= BAND_FROM and kl + ku + 1 <= n // 4:
            options = {"linsolver": "band", "lband": kl, "uband": ku}
            self.note = f"band linear solver (kl = {kl}, ku = {ku})"
        elif n <= DENSE_LIMIT:
            options = {"linsolver": "dense"}
            self.note = "dense linear solver"
        else:
            options = {"linsolver": "sparse",
                       "sparsity": c.dependencies().tocsc().astype(float)}
            self.note = "sparse (SuperLU_MT) linear solver"
        if options["linsolver"] == "sparse":
            # JJ is the CSC value array of the pattern: the CSR values permuted
            order = np.lexsort((rows, cols))

            def jacfn(s, y, yp, JJ):
                calls[1] += 1
                jac(y.ctypes.data, s, p, values.ctypes.data)
                JJ[:] = values[order]
        else:
            def jacfn(s, y, yp, JJ):
                calls[1] += 1
                jac(y.ctypes.data, s, p, values.ctypes.data)
                JJ[rows, cols] = values[:len(rows)]

        self._options = dict(options, method="BDF", jacfn=jacfn, max_num_steps=MAXIMUM_STEPS)
        self._rhsfn = rhsfn

    def solve(self, rtol, atol):
        from sksundae.cvode import CVODE as Solver

        self._calls[:] = [0, 0]
        res = Solver(self._rhsfn, rtol=rtol, atol=atol, **self._options).solve(
            self.t_eval, self.u0)
        if not res.success:
            raise PeerFailed(f"CVODE: {res.message}")
        return np.asarray(res.y).T, _counts(f_evals=self._calls[0], jacobians=self._calls[1])


class _Diffrax(Peer):
    solver = "diffrax"
    dense = "one traced expression per component"

    def _build(self):
        import diffrax
        import jax

        jax.config.update("jax_enable_x64", True)
        import jax.numpy as jnp

        values = dict(zip(self.ode.parameter_symbols, self.ode.parameter_values))
        rhs = [sp.sympify(e).xreplace(values) for e in self.ode.rhs]
        f_raw = sp.lambdify((time_symbol, list(self.ode.states)), rhs, modules="jax", cse=True)

        def vector_field(s, y, args):
            return jnp.stack([jnp.asarray(v, dtype=jnp.float64) * jnp.ones_like(s)
                              for v in f_raw(s, y)])

        term = diffrax.ODETerm(vector_field)
        scheme = getattr(diffrax, self.method)()
        ts = jnp.asarray(self.t_eval)
        t0, T = float(self.t_eval[0]), float(self.t_eval[-1])
        # Kvaerno5's automatic first step fails on VDPOL (every step rejected): start small
        dt0 = 1e-8 * min(1.0, T - t0) if self.stiff else None

        def run(y0, rtol, atol):
            sol = diffrax.diffeqsolve(
                term, scheme, t0=t0, t1=T, dt0=dt0, y0=y0, saveat=diffrax.SaveAt(ts=ts),
                stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
                max_steps=MAXIMUM_STEPS, throw=False)
            return (sol.ys, sol.result == diffrax.RESULTS.successful,
                    sol.stats["num_accepted_steps"], sol.stats["num_rejected_steps"])

        self._run = jax.jit(run)
        self._y0 = jnp.asarray(self.u0)

    def solve(self, rtol, atol):
        ys, ok, steps, rejected = self._run(self._y0, rtol, atol)
        ys = np.asarray(ys.block_until_ready())
        if not bool(ok) or not np.all(np.isfinite(ys)):
            raise PeerFailed(f"diffrax {self.method} did not reach T (max_steps = "
                             f"{MAXIMUM_STEPS} or a step size collapse)")
        return ys.T, _counts(steps=int(steps), rejected=int(rejected))


class DiffraxKvaerno5(_Diffrax):
    method = "Kvaerno5"
    stiff = True
    # its Newton iterations factor a dense Jacobian from N JAX derivatives, and a stuck run
    # cannot be abandoned at a time limit: MEDAKZO (N = 400) is left out
    largest = 100
    dense = "a dense Jacobian from N forward derivatives in every Newton matrix"


class DiffraxTsit5(_Diffrax):
    method = "Tsit5"
    stiff = False


#: The peers by method label, and the package each needs.
PEERS = {"numbalsoda-LSODA": (NumbalsodaLSODA, "numbalsoda"),
         "numbalsoda-DOP853": (NumbalsodaDOP853, "numbalsoda"),
         "CVODE-BDF": (CVODE, "sksundae"),
         "diffrax-Kvaerno5": (DiffraxKvaerno5, "diffrax"),
         "diffrax-Tsit5": (DiffraxTsit5, "diffrax")}


def is_peer(method):
    """Whether ``method`` labels a compiled peer."""
    return method in PEERS


def installed(method):
    """Whether the package of peer ``method`` can be imported."""
    return importlib.util.find_spec(PEERS[method][1]) is not None


def available():
    """(installed peer labels, notes on the missing ones)."""
    labels = [m for m in PEERS if installed(m)]
    missing = sorted({PEERS[m][1] for m in PEERS if not installed(m)})
    notes = [f"{pkg} not installed: its peers are skipped (pip install dolfinode[bench])"
             for pkg in missing]
    return labels, notes


def make_peer(method, ode, t_eval):
    """The peer labelled ``method`` on ``ode`` (not yet built)."""
    return PEERS[method][0](ode, t_eval)

