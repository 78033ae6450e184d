"""Loops compiled on first use, and the compile notice."""
import logging
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from numba import njit, types

from dolfinode.compile import jit
from dolfinode.compile.jit import Loop, announced, first_use

ROOT = Path(__file__).resolve().parents[2]


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
    with caplog.at_level(logging.WARNING, logger="dolfinode"), announced("the test loop", 20):
        done.wait(0.5)
    notices = [r.getMessage() for r in caplog.records if r.name == "dolfinode"]
    assert notices == [("dolfinode: compiling the test loop once (about 20 s); it is cached "
                        "afterwards")]


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


@jit.linked
@njit(cache=False, error_model="numpy")
def _axpy(a, x, y):
    """y += a x; returns sum(y)."""
    total = 0.0
    for i in range(x.shape[0]):
        y[i] += a * x[i]
        total += y[i]
    return total


@njit(cache=False)
def _twice(a, x, y):
    return _axpy(a, x, y) + _axpy(a, x, y)


def test_a_linked_function_is_called_not_copied_into_its_caller():
    x, y = np.arange(3.0), np.ones(3)
    assert _twice(2.0, x, y) == (3.0 + 2 * 3.0) + (3.0 + 4 * 3.0)  # y = 1 + 2x, then 1 + 4x
    np.testing.assert_array_equal(y, 1.0 + 4.0 * x)
    assert _axpy(1.0, x, y) == 3.0 + 5 * 3.0  # from Python: the numba function
    ir = next(iter(_twice.inspect_llvm().values()))
    callee = _axpy.dispatcher.overloads[_axpy.signatures[0]].fndesc.llvm_func_name
    assert "declare i32 @dolfinode." in ir and "._axpy." in ir  # its symbol is called
    assert callee not in ir  # ... and no copy of its code


LINKED_MODULE = '''
import numpy as np
from numba import njit
from dolfinode.compile.jit import linked

@linked
@njit(cache=True, error_model="numpy")
def scale(x, c):
    for i in range(x.shape[0]):
        x[i] *= c

@njit(cache=True)
def caller(x):
    scale(x, 2.0)
    return x.sum()
'''


def test_a_cached_caller_links_its_callee_when_loaded(tmp_path):
    """In a fresh process the caller comes from numba's cache, its callee linked before it
    (else the JIT would abort on an unresolved symbol)."""
    (tmp_path / "linked_module.py").write_text(LINKED_MODULE)
    script = ("import numpy as np, linked_module as m\n"
              "print(m.caller(np.ones(3)), sum(m.caller.stats.cache_hits.values()))\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    runs = [subprocess.run([sys.executable, "-c", script], env=env, cwd=tmp_path, check=True,
                           capture_output=True, text=True).stdout.split() for _ in range(2)]
    assert runs == [["6.0", "0"], ["6.0", "1"]]


def test_a_cached_caller_expecting_another_return_type_is_refused():
    """The link a caller's cache holds names the return type it was compiled for: a callee
    that now returns another type is an error, not a call with the wrong layout."""
    x = np.ones(2)
    _axpy(1.0, x, x.copy())
    key = f"{_axpy.py_func.__module__}:{_axpy.py_func.__qualname__}"
    args = _axpy.signatures[0]
    assert jit._Link(key, args, types.float64)() == _axpy.dispatcher.overloads[args].signature
    with pytest.raises(RuntimeError, match="clear numba's cache"):
        jit._Link(key, args, types.int64)()


@jit.linked(returns=types.float64, what="a lazy test routine", seconds=1)
@njit(cache=False, error_model="numpy")
def _lazy_sum(x):
    return x.sum()


@jit.linked(returns=types.int64, what="a wrongly declared routine", seconds=1)
@njit(cache=False, error_model="numpy")
def _declared_wrong(x):
    return x.sum()  # a float, declared int64


@njit(cache=False)
def _maybe(x, call):
    return _lazy_sum(x) if call else -1.0


@njit(cache=False)
def _call_declared_wrong(x):
    return float(_declared_wrong(x))


def test_a_lazily_linked_function_is_compiled_on_its_first_call_only():
    x = np.arange(4.0)
    assert _maybe(x, False) == -1.0
    assert not _lazy_sum.signatures  # the caller is compiled, the callee not
    assert _maybe(x, True) == 6.0
    assert len(_lazy_sum.signatures) == 1
    assert _maybe(2 * x, True) == 12.0


@jit.linked(returns=types.float64, what="a pending test routine", seconds=1)
@njit(cache=False, error_model="numpy")
def _pending(x):
    return x[0]


@njit(cache=False)
def _never(x, call):
    return _pending(x) if call else 0.0


def test_compile_pending_compiles_the_lazy_routines_not_called_yet():
    assert _never(np.ones(1), False) == 0.0
    assert not _pending.signatures
    assert "a pending test routine" in jit.compile_pending()
    assert len(_pending.signatures) == 1
    assert _never(np.full(1, 2.0), True) == 2.0


def test_a_lazily_linked_function_of_another_return_type_raises(caplog, monkeypatch):
    monkeypatch.setattr(jit, "_SLOTS", dict(jit._SLOTS))  # (its failed link is not kept)
    with pytest.raises(RuntimeError, match="compiling .*_declared_wrong failed"):
        _call_declared_wrong(np.ones(2))
    assert "correct the declaration" in caplog.text


LAZY_MODULE = '''
import numpy as np
from numba import njit, types
from dolfinode.compile.jit import linked

@linked(returns=types.float64, what="a test routine", seconds=1)
@njit(cache=True, error_model="numpy")
def total(x):
    return x.sum()

@njit(cache=True)
def caller(x, call):
    return total(x) if call else 0.0
'''


def test_a_cached_caller_compiles_its_lazy_callee_only_when_called(tmp_path):
    (tmp_path / "lazy_module.py").write_text(LAZY_MODULE)
    script = ("import numpy as np, lazy_module as m\n"
              "a = m.caller(np.ones(3), False)\n"
              "print(a, len(m.total.signatures), m.caller(np.ones(3), True),\n"
              "      sum(m.caller.stats.cache_hits.values()))\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    runs = [subprocess.run([sys.executable, "-c", script], env=env, cwd=tmp_path, check=True,
                           capture_output=True, text=True).stdout.split() for _ in range(2)]
    assert runs == [["0.0", "0", "3.0", "0"], ["0.0", "0", "3.0", "1"]]


def test_a_linked_function_must_declare_its_error_model():
    """numba gives a function without one the error model of the compile it first runs in:
    a lazily linked routine would get python's (zero-division checks) where its eager twin
    got its caller's."""
    with pytest.raises(TypeError, match="declare its error model"):
        jit.linked(njit(cache=False)(_square))


@jit.linked(returns=types.float64, what="a lazy division", seconds=1)
@njit(cache=False, error_model="numpy")
def _lazy_ratio(a, b):
    return a / b


@njit(cache=False)  # python's error model: its own divisions by zero raise
def _ratio_caller(a, b):
    return _lazy_ratio(a, b)


def test_a_lazily_linked_function_keeps_its_error_model_when_compiled_at_run_time():
    assert _ratio_caller(1.0, 0.0) == np.inf  # numpy's model, not ZeroDivisionError
    overload = _lazy_ratio.dispatcher.overloads[_lazy_ratio.signatures[0]]
    assert "ZeroDivisionError" not in overload.library.get_llvm_str()


@jit.linked(returns=types.float64, what="a twice specialised routine", seconds=1)
@njit(cache=False, error_model="numpy")
def _first(x):
    return float(x[0])


@njit(cache=False)
def _both(x, y):
    return _first(x) + _first(y)


def test_a_lazy_routine_is_announced_once_for_all_its_specialisations(monkeypatch, caplog):
    monkeypatch.setattr(jit, "NOTICE_AFTER", 0.0)
    with caplog.at_level(logging.WARNING, logger="dolfinode"):
        assert _both(np.ones(1), np.ones(1, dtype=np.int64)) == 2.0
        threading.Event().wait(0.2)  # (the notice's timer thread)
    assert len(_first.signatures) == 2
    notices = [r.getMessage() for r in caplog.records if "twice specialised" in r.getMessage()]
    assert len(notices) == 1


@jit.helper()
def _dot(x, y):
    """x . y."""
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * y[i]
    return total


@njit(cache=False)
def _norm2(x):
    return _dot(x, x)


def test_a_helper_has_no_python_wrapper_and_runs_from_python_too():
    """A helper compiled for a compiled caller carries no CPython wrapper (its entry point
    from Python would be null); called from Python it runs a copy that has one."""
    x = np.array([1.0, 2.0, 3.0])
    assert _norm2(x) == 14.0
    (signature,) = _dot.signatures
    overload = _dot.overloads[signature]
    wrapper = overload.fndesc.llvm_cpython_wrapper_name
    assert overload.library.get_pointer_to_function(wrapper) == 0
    assert _dot(x, 2.0 * x) == 28.0  # from Python: the copy
    assert _dot._from_python.signatures == [signature]
    assert len(_dot.signatures) == 1


def test_a_helper_run_from_python_is_not_announced_again(monkeypatch, caplog):
    """first_use knows a helper compiled for Python (its copy) as compiled."""
    x = np.array([1.0, 2.0])
    _dot(x, x)
    monkeypatch.setattr(jit, "NOTICE_AFTER", 0.01)
    with (caplog.at_level(logging.WARNING, logger="dolfinode"),
          first_use(_dot, "the test helper", 20)):
        threading.Event().wait(0.2)
    assert not [r for r in caplog.records if r.name == "dolfinode"]
