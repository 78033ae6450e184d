"""The kernels' numba interface: the no-reference-counting option and raw addresses."""
import numba.core.cpu
import numpy as np
from numba import njit

from dolfinode.compile import lower, signatures
from dolfinode.problems import harmonic


def test_no_refcount_falls_back_to_plain_njit(monkeypatch):
    assert signatures._no_refcount() == {"_nrt": False}  # this numba has the option
    monkeypatch.setattr(numba.core.cpu, "CPUTargetOptions", type("Options", (), {}))
    assert signatures._no_refcount() == {}


@njit
def _rhs_of_rows(rhs_address, p, states, out):
    # every row of states through the kernel, addressed in place
    rhs = signatures.rhs_kernel(rhs_address)
    N = states.shape[1]
    for j in range(states.shape[0]):
        rhs(signatures.address(states, j * N), 0.0, signatures.address(p, 0),
            signatures.address(out, j * N))


def test_address_passes_a_row_in_place():
    ode, _ = harmonic(T=1.0)
    compiled = lower(ode)
    states = np.arange(8.0).reshape(4, 2)
    out = np.zeros_like(states)
    _rhs_of_rows(compiled.rhs.address, compiled.p, states, out)
    expected = np.array([compiled.f(u, 0.0) for u in states])
    assert np.array_equal(out, expected)
