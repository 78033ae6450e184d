"""method="auto": the mono- or multi-adaptive variant, chosen by racing pilot solves."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench.multirate import oscillator_bank
from dolfinode.family import auto_base
from dolfinode.problems import mass_spring_chain


@pytest.mark.parametrize("name, base", [("auto", "cG(2)"), ("auto:dG(1)", "dG(1)"),
                                        (" AUTO : cg( 3 ) ", "cG(3)"), ("cG(2)", None),
                                        ("auto:mcG(2)", None), ("autocG(2)", None), (2, None)])
def test_auto_base(name, base):
    assert auto_base(name) == base


def test_unknown_method_names_auto():
    with pytest.raises(ValueError, match="'auto'"):
        dn.solve(mass_spring_chain(4, T=1.0)[0], "auto:mcG(2)")


def _same_solution(auto, direct):
    _, t_start, t_end, values = auto.elements()
    expected = direct.elements()
    assert auto.multi == direct.multi
    assert len(t_start) == len(expected[1])
    np.testing.assert_array_equal(values, expected[3])
    np.testing.assert_array_equal(t_end, expected[2])


def test_uniform_chain_picks_mono():
    """Without scale separation every component takes the same step: mono-adaptive."""
    ode = mass_spring_chain(40, T=200.0)[0]
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert choice["method"] == "cG(2)" and sol.stats["method"] == "cG(2)", choice
    pilots = choice["cG(2)"]
    assert len(pilots["pilot horizons"]) >= 2 and pilots["predicted time"] > 0
    assert pilots["pilot horizons"][-1] >= 0.01 * 200.0
    assert choice["pilot cpu time"] >= sum(pilots["pilot cpu times"])
    # "auto" solves on the step mapping (calibrate_tolerance=False)
    _same_solution(sol, dn.solve(ode, "cG(2)", tolerance=1e-6, calibrate_tolerance=False))


def test_output_parameters_are_the_final_solves(tmp_path):
    """Sample times and a history file refer to [t0, T]: the pilots leave them alone."""
    ode = mass_spring_chain(10, T=20.0)[0]
    sol = dn.solve(ode, "auto", sample_times=[5.0, 20.0], dense_output=False)
    np.testing.assert_array_equal(sol.t, [5.0, 20.0])
    direct = dn.solve(ode, sol.stats["method"], sample_times=[5.0, 20.0], dense_output=False,
                      calibrate_tolerance=False)  # as "auto" solves
    np.testing.assert_array_equal(sol.y, direct.y)


def test_scale_separation_picks_multi():
    """One oscillator 1000x faster than 200 others: mcG(2) is 27x faster, predicted 4.5x."""
    ode = oscillator_bank(n=200, w=1000.0, T=0.5).ode
    sol = dn.solve(ode, "auto", tolerance=1e-6)
    choice = sol.stats["family choice"]
    assert choice["method"] == "mcG(2)" and sol.stats["method"] == "mcG(2)", choice
    assert choice["mcG(2)"]["efficiency index"] > 5
    _same_solution(sol, dn.solve(ode, "mcG(2)", tolerance=1e-6))


def test_failing_pilots_are_not_silent():
    """Both variants fail on their pilots: the full solve raises what went wrong."""
    with pytest.raises(dn.SolverError, match="maximum_steps"):
        dn.solve(mass_spring_chain(4, T=100.0)[0], "auto", maximum_steps=3)
