"""The dolfinode command and the progress bar."""
import numpy as np
import pytest
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


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"dolfinode {dn.__version__}"
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert "bench" in text and "info" in text and "--version" in text
    assert "``" not in text and "`" not in text  # plain text, not reStructuredText


@pytest.mark.parametrize("arguments, words", [
    (["--problems", ""], "argument --problems: expected a comma-separated list"),
    (["--methods", " , "], "argument --methods: expected a comma-separated list"),
    (["--tolerances", ""], "argument --tolerances: expected a comma-separated list"),
    (["--tolerances", "1e-4,inf"], "tolerances must lie in (0, 1), got inf"),
    (["--tolerances", "2"], "tolerances must lie in (0, 1), got 2"),
    (["--tolerances", "0"], "tolerances must lie in (0, 1), got 0"),
    (["--repeats", "0"], "--repeats must be at least 1, got 0"),
])
def test_bench_rejects_empty_lists_and_values_out_of_range(tmp_path, capsys, arguments, words):
    # each of these ran the whole default suite (or 3 repeats) into the output folder
    with pytest.raises(SystemExit):
        main(["bench", *arguments, "--output", str(tmp_path / "out")])
    assert words in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_compile_fills_the_caches(capsys):
    assert main(["compile"]) == 0
    printed = capsys.readouterr().err
    for what in ("cG(2)", "dG(1)", "mcG(2)", "estimate_error", "Solver.solve"):
        assert f"{what}: compiled" in printed
    from dolfinode.compile import jit
    from dolfinode.timeslab import prepared

    assert prepared.run.is_compiled and prepared.workspace.is_compiled

    assert jit._SLOTS  # the stiff solvers' links, registered by their callers
    assert all(slot.value for _, slot, _ in jit._SLOTS.values())  # ... and compiled
