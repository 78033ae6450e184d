"""The loops' contract (named options and state) and the compile rules of their helpers."""
import numpy as np
import pytest
from numba import njit

from dolfinode.compile.jit import helper
from dolfinode.timeslab import contract


def test_options_and_state_are_named_records():
    options = contract.options(rtol=1e-6, T=2.0, fixed=True, max_iter=7)
    assert options.shape == (1,) and options.dtype == contract.OPTIONS
    assert options["rtol"][0] == 1e-6 and options["T"][0] == 2.0
    assert bool(options["fixed"][0]) and options["max_iter"][0] == 7
    assert options["kmax"][0] == 0.0 and not options["reuse"][0]  # unnamed: zero
    state = contract.state(t=0.5, k_next=0.1)
    assert state["t"][0] == 0.5 and state["k_next"][0] == 0.1
    with pytest.raises(TypeError, match="rtl"):
        contract.options(rtl=1e-6)


def test_both_loops_take_the_contract():
    """One options type and one state type for both loops: each is compiled for one
    signature whatever the method."""
    from dolfinode.timeslab import mono, multi

    for loop in (mono.advance, multi.advance):
        arguments = loop.signature.args
        assert contract.OPTIONS_TYPE in arguments and contract.STATE_TYPE in arguments


def test_a_helper_compiles_once_for_literal_arguments():
    """numba compiles an njit function once more per constant argument and for the literal
    first value of a counter; a helper is compiled for the unliteral types only."""
    @helper()
    def head(a, n, flag):
        return a[:n].sum() if flag else 0.0

    @njit
    def caller(a):
        n = 0
        for i in range(a.shape[0]):
            if a[i] > 0:
                n += 1
        return head(a, n, True) + head(a, 1, False) + head(a, n, n > 1)

    assert caller(np.ones(3)) == 6.0
    assert len(head.signatures) == 1
