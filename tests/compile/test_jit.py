"""Loops compiled on first use, and the compile notice."""
import logging
import threading

import numpy as np
import pytest
from numba import types

from dolfinode.compile import jit
from dolfinode.compile.jit import Loop, announced, first_use


def _square(x):
    return x * x


def test_loop_compiles_its_signature_on_first_call_and_no_other():
    loop = Loop(_square, types.float64(types.float64), "a test loop", 1)
    assert not loop.is_compiled
    assert loop(3.0) == 9.0
    assert loop.is_compiled
    assert len(loop.compile().signatures) == 1
    with pytest.raises(TypeError):
        loop(np.ones(2))  # another type is refused, not compiled a second time


def test_a_long_block_is_announced_once(monkeypatch, caplog):
    monkeypatch.setattr(jit, "NOTICE_AFTER", 0.01)
    done = threading.Event()
    with caplog.at_level(logging.WARNING, logger="dolfinode"):
        with announced("the test loop", 20):
            done.wait(0.5)
    notices = [r.getMessage() for r in caplog.records if r.name == "dolfinode"]
    assert notices == ["dolfinode: compiling the test loop once (about 20 s); it is cached "
                       "afterwards"]


def test_a_short_block_and_a_compiled_function_are_not_announced(monkeypatch, caplog):
    monkeypatch.setattr(jit, "NOTICE_AFTER", 0.05)
    loop = Loop(_square, types.float64(types.float64), "a test loop", 1)
    loop(2.0)
    with caplog.at_level(logging.WARNING, logger="dolfinode"):
        with announced("the test loop", 20):
            pass
        with first_use(loop.compile(), "the test loop", 20):
            pass
        done = threading.Event()
        done.wait(0.2)  # a cancelled notice stays silent afterwards too
    assert not [r for r in caplog.records if r.name == "dolfinode"]
