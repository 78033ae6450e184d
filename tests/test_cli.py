"""The dolfinode command and the progress bar."""
import numpy as np
import sympy as sp

import dolfinode as dn
from dolfinode.cli import main
from dolfinode.parameters import DEFAULTS


def test_info_prints_every_parameter(capsys):
    assert main(["info"]) == 0
    printed = capsys.readouterr().out
    for name in DEFAULTS:
        assert name in printed


def test_progress_bar_does_not_change_the_solution(capsys):
    u = sp.Symbol("u")
    ode = dn.ODE({u: -u}, u0=[1.0], T=2.0)
    plain = dn.solve(ode, method="dG(1)", tolerance=1e-8)
    shown = dn.solve(ode, method="dG(1)", tolerance=1e-8, progress=True)
    np.testing.assert_array_equal(plain.values, shown.values)
    assert "dolfinode" in capsys.readouterr().err


def test_compile_fills_the_caches(capsys):
    assert main(["compile"]) == 0
    printed = capsys.readouterr().err
    for what in ("cG(2)", "dG(1)", "mcG(2)", "estimate_error"):
        assert f"{what}: compiled" in printed
