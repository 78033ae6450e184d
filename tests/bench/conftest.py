"""Shared by the bench tests: a tiny benchmark problem, u' = -2 u on [0, 1], u(0) = 1, and
the scripts of benchmarks/ as modules."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.bench import problems as P


def _decay():
    u, lam = sp.symbols("u lam")
    ode = dn.ODE({u: -lam * u}, u0=[1.0], T=1.0, params={lam: 2.0})
    return P.Problem("decay", ode, stiff=False, final=np.array([np.exp(-2.0)]),
                     exact=lambda s: np.atleast_2d(np.exp(-2.0 * np.asarray(s))),
                     reference="exact")


@pytest.fixture
def tiny():
    """The factory of the tiny problem (a new Problem per call)."""
    return _decay


@pytest.fixture
def tiny_registered(monkeypatch):
    """The tiny problem registered as "decay" for ``dolfinode bench --problems decay``."""
    monkeypatch.setitem(P.PROBLEMS, "decay", _decay)
    return _decay


@pytest.fixture(scope="session")
def benchmark_script():
    """The loader of a script of benchmarks/ by its name, as a module (its ``main`` not run)."""
    def load(name):
        path = Path(__file__).resolve().parents[2] / "benchmarks" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load
