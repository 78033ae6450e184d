"""Solver parameters and method names: defaults, did-you-mean errors and invalid values.

Every error is raised by ``dn.solve`` before anything is compiled, so these tests are fast.
"""
import math

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.parameters import DEFAULTS, check_parameters

u = sp.Symbol("u")


@pytest.fixture(scope="module")
def ode():
    return dn.ODE({u: -u}, u0=[1.0], T=1.0)


def test_no_parameters_gives_the_defaults():
    params = check_parameters({})
    assert params == DEFAULTS
    assert dn.default_parameters == DEFAULTS
    with pytest.raises(TypeError):
        dn.default_parameters["tolerance"] = 1.0


def test_given_parameters_override_defaults_and_are_normalised():
    params = check_parameters({"tolerance": 1, "initial_time_step": 1e-3, "fixed_time_step": True,
                               "nonlinear_solver": "newton", "maximum_iterations": 7})
    assert params["tolerance"] == 1.0 and isinstance(params["tolerance"], float)
    assert params["initial_time_step"] == 1e-3
    assert params["nonlinear_solver"] == "newton"
    assert params["maximum_iterations"] == 7
    assert params["number_of_samples"] == DEFAULTS["number_of_samples"]


def test_check_parameters_does_not_modify_the_defaults():
    before = dict(DEFAULTS)
    check_parameters({"tolerance": 0.5, "maximum_iterations": 3})
    assert DEFAULTS == before


# --- unknown names ------------------------------------------------------------------------


@pytest.mark.parametrize("typo, meant", [
    ("tolerence", "tolerance"),
    ("initial_timestep", "initial_time_step"),
    ("maximum_timestep", "maximum_time_step"),
    ("fixed_timestep", "fixed_time_step"),
    ("max_iterations", "maximum_iterations"),
    ("nonlinear_solve", "nonlinear_solver"),
])
def test_unknown_parameter_suggests_the_closest_name(ode, typo, meant):
    with pytest.raises(ValueError) as info:
        dn.solve(ode, **{typo: 1e-3})
    message = str(info.value)
    assert f"unknown parameter {typo!r}" in message
    assert f"did you mean {meant!r}?" in message


@pytest.mark.parametrize("scipy_name, meant", [
    ("atol", "absolute_tolerance"),
    ("rtol", "tolerance"),
    ("t_eval", "sample_times"),
    ("max_step", "maximum_time_step"),
    ("first_step", "initial_time_step"),
])
def test_scipy_names_suggest_dolfinodes(ode, scipy_name, meant):
    with pytest.raises(ValueError, match=f"did you mean {meant!r}\\? \\({scipy_name!r} is scipy"):
        dn.solve(ode, **{scipy_name: 1e-3})


@pytest.mark.parametrize("name", ["params", "u0", "T"])
def test_declaration_values_passed_to_solve_say_where_they_live(ode, name):
    # params= suggested 'progress'
    with pytest.raises(ValueError, match=f"{name} is the declaration's: set ode.{name} .*"
                                         f"Solver.*solve\\({name}="):
        dn.solve(ode, **{name: 1.0})


def test_scipy_arguments_without_a_parameter_say_where_they_live(ode):
    with pytest.raises(ValueError, match="'y0' .*scipy's name.*u0 of the ODE"):
        dn.solve(ode, y0=[1.0])
    with pytest.raises(ValueError, match="exact sparse Jacobian is derived"):
        dn.solve(ode, jac=None)


def test_tolerance_is_keyword_only(ode):
    with pytest.raises(TypeError, match="positional"):
        dn.solve(ode, "dG(2)", 1e-6)
    sol = dn.solve(ode, "dG(2)", tolerance=1e-6)
    assert sol.parameters["tolerance"] == 1e-6


def test_solve_documents_every_parameter_with_its_default():
    import ast
    import inspect

    from numpydoc.docscrape import FunctionDoc

    documented = {p.name: p for p in FunctionDoc(dn.solve)["Parameters"]}
    signature = inspect.signature(dn.solve)
    for name, default in DEFAULTS.items():
        assert name in documented, f"solve's docstring does not describe {name}"
        if name in signature.parameters:
            assert signature.parameters[name].default == default
        what = documented[name].type
        if default is None:
            assert what.endswith("optional"), f"{name}: {what!r} should say optional"
        else:
            assert ast.literal_eval(what.split("default ")[1]) == default, name


def test_unknown_parameter_without_a_close_name_lists_the_valid_ones(ode):
    with pytest.raises(ValueError) as info:
        dn.solve(ode, zzz=1)
    message = str(info.value)
    assert "unknown parameter 'zzz'" in message
    assert "did you mean" not in message
    for name in ("tolerance", "initial_time_step", "nonlinear_solver"):
        assert name in message


# --- invalid values -----------------------------------------------------------------------


@pytest.mark.parametrize("value", [-1e-3, 0.0, math.nan, math.inf])
def test_tolerance_must_be_positive_and_finite(ode, value):
    message = f"tolerance must be a positive finite number, got {value}"
    with pytest.raises(ValueError, match=message):
        dn.solve(ode, tolerance=value)


@pytest.mark.parametrize("value", [1e-300, 1e-15])
def test_tolerance_below_rounding_is_rejected(ode, value):
    # (1e-300 failed at t = 0 pointing at a singularity of f; 1e-15 ran into maximum_steps)
    with pytest.raises(ValueError, match=r"tolerance must be at least 2.2e-14 \(100 machine"):
        dn.solve(ode, tolerance=value)


def test_a_tolerance_below_rounding_with_absolute_tolerance_controls_the_absolute_error(ode):
    sol = dn.solve(ode, "cG(2)", tolerance=1e-20, absolute_tolerance=1e-8)
    assert abs(sol(1.0)[0] - math.exp(-1)) < 1e-7


def test_a_goal_tolerance_may_be_below_rounding():
    # with a goal the tolerance bounds the output's absolute error, which may be tiny
    w = sp.Symbol("w")
    sol = dn.solve(dn.ODE({w: -w}, u0=[1e-12], T=1.0), "cG(2)", goal={w: 1.0},
                   tolerance=1e-20)
    assert abs(sol(1.0)[0] - 1e-12 * math.exp(-1)) < 1e-20


@pytest.mark.parametrize("value", ["small", None, True])
def test_tolerance_must_be_a_number(ode, value):
    # (True was read as a tolerance of 1.0)
    with pytest.raises(TypeError, match="tolerance must be a positive number"):
        dn.solve(ode, tolerance=value)


@pytest.mark.parametrize("name", ["initial_time_step", "maximum_time_step", "safety_factor",
                                  "discrete_tolerance_factor"])
@pytest.mark.parametrize("value", [-1.0, 0.0, math.nan])
def test_positive_parameters(ode, name, value):
    with pytest.raises(ValueError, match=f"{name} must be a positive finite number"):
        dn.solve(ode, **{name: value})


@pytest.mark.parametrize("name", ["maximum_iterations", "number_of_samples", "maximum_steps"])
@pytest.mark.parametrize("value", [0, -3, 2.5, True])
def test_integer_parameters_must_be_positive_integers(ode, name, value):
    with pytest.raises(ValueError, match=f"{name} must be a positive integer, got {value!r}"):
        dn.solve(ode, **{name: value})


@pytest.mark.parametrize("value", [1.5, 5.0])
def test_safety_factor_above_one_is_rejected(ode, value):
    # with a safety factor > 1 the solve of u' = -u gave no result within 30 s (it hung)
    with pytest.raises(ValueError, match=r"safety_factor must lie in \(0, 1\]"):
        dn.solve(ode, safety_factor=value)


@pytest.mark.parametrize("name", ["fixed_time_step", "progress"])
@pytest.mark.parametrize("value", ["yes", "no", None, 0.5])
def test_switches_must_be_booleans(ode, name, value):
    # progress="no" showed a progress bar; fixed_time_step="yes" was taken as True
    with pytest.raises(TypeError, match=f"{name} must be True or False"):
        dn.solve(ode, initial_time_step=0.1, **{name: value})


@pytest.mark.parametrize("name", ["initial_time_step", "maximum_time_step"])
@pytest.mark.parametrize("method", ["cG(1)", "mcG(1)"])
def test_steps_below_double_precision_are_rejected(ode, name, method):
    # a SolverError said "the solution may blow up" at t = 0 (and for maximum_time_step on
    # cG(1) named the step 0.00125)
    with pytest.raises(ValueError, match=f"{name} = 1e-300 is below what double precision"):
        dn.solve(ode, method, **{name: 1e-300})


@pytest.mark.parametrize("typo, meant", [("newtn", "newton"), ("fixedpoint", "fixed-point"),
                                         ("fixed_point", "fixed-point")])
def test_unknown_nonlinear_solver_suggests_the_closest(ode, typo, meant):
    with pytest.raises(ValueError) as info:
        dn.solve(ode, nonlinear_solver=typo)
    message = str(info.value)
    assert f"unknown nonlinear_solver {typo!r}" in message
    assert f"did you mean {meant!r}?" in message
    assert "'default', 'fixed-point', 'newton'" in message


def test_fixed_time_step_needs_an_initial_time_step(ode):
    with pytest.raises(ValueError, match="fixed_time_step=True needs the step: give initial_time"):
        dn.solve(ode, fixed_time_step=True)


@pytest.mark.parametrize("value", [-1.0, [1.0, 2.0]])
def test_absolute_tolerance_is_checked(ode, value):
    with pytest.raises(ValueError, match="absolute_tolerance"):
        dn.solve(ode, absolute_tolerance=value)


def test_solve_needs_an_ode():
    with pytest.raises(TypeError, match="solve expects a dolfinode.ODE, got dict"):
        dn.solve({u: -u})


# --- method names -------------------------------------------------------------------------


@pytest.mark.parametrize("name, multi, family, q", [
    ("cG(1)", False, "cG", 1),
    ("dG(0)", False, "dG", 0),
    ("mcG(2)", True, "cG", 2),
    ("mdG(3)", True, "dG", 3),
    ("cG(10)", False, "cG", 10),
    (" dG( 2 ) ", False, "dG", 2),
])
def test_parse_method(name, multi, family, q):
    multi_adaptive, method = dn.parse_method(name)
    assert multi_adaptive is multi
    assert (method.family, method.q, method.name) == (family, q, f"{family}({q})")
    assert method is dn.make_method(family, q)


@pytest.mark.parametrize("name, canonical", [("cg(1)", "cG(1)"), ("DG(2)", "dG(2)"),
                                             ("MCG(1)", "cG(1)"), ("mdg(0)", "dG(0)")])
def test_method_names_are_case_insensitive(name, canonical):
    multi_adaptive, method = dn.parse_method(name)
    assert method.name == canonical
    assert multi_adaptive is name.lower().startswith("m")


def test_cg0_does_not_exist(ode):
    with pytest.raises(ValueError, match=r"cG\(q\) needs an integer q >= 1, got 0"):
        dn.solve(ode, method="cG(0)")


@pytest.mark.parametrize("name", ["dG(-1)", "RK4", "cG", "cG(1.5)", "cG(1)x", "gG(1)", ""])
def test_unknown_method_lists_the_valid_forms(ode, name):
    with pytest.raises(ValueError) as info:
        dn.solve(ode, method=name)
    message = str(info.value)
    assert f"unknown method {name!r}" in message
    assert "'cG(q)' (q >= 1), 'dG(q)' (q >= 0)" in message


@pytest.mark.parametrize("name", [1, None, ("cG", 1)])
def test_method_must_be_a_string(name):
    with pytest.raises(TypeError, match="method must be a string"):
        dn.parse_method(name)


@pytest.mark.parametrize("family, q", [("cG", 0), ("dG", -1), ("cG", 1.5), ("dG", "1")])
def test_make_method_needs_a_valid_degree(family, q):
    with pytest.raises(ValueError, match=r"needs an integer q >= [01]"):
        dn.make_method(family, q)


@pytest.mark.parametrize("name", ["cG(21)", "mdG(40)", "cG(99999999999999999999)"])
def test_degree_above_the_maximum_is_rejected(ode, name):
    # above q = 20 the step error estimate is rounding noise (cG(24): 1971 slabs for what
    # cG(20) does in 23, q >= 30: maximum_steps reached); q = 10**20 hung building the nodes
    with pytest.raises(ValueError, match=r"q <= 20"):
        dn.solve(ode, name)


@pytest.mark.parametrize("q", [1.0, np.float64(1)], ids=["float", "numpy-float"])
def test_float_degree_is_rejected_even_when_the_integer_one_is_cached(q):
    dn.make_method("cG", 1)
    with pytest.raises(ValueError, match=r"needs an integer q >= 1"):
        dn.make_method("cG", q)


def test_make_method_needs_a_known_family():
    with pytest.raises(ValueError, match="unknown method family 'RK'"):
        dn.make_method("RK", 1)


@pytest.mark.parametrize("name, value", [("average_length", 0.0), ("average_length", -1e-7),
                                         ("average_tolerance", 0.0), ("average_samples", 1),
                                         ("control_points", -1), ("model_tolerance", -0.1)])
def test_modeling_parameters_are_checked(name, value):
    u = sp.Symbol("u")
    with pytest.raises(ValueError, match=name):
        dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), automatic_modeling=True, **{name: value})


def test_nonlinear_solver_is_case_insensitive():
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), nonlinear_solver="Newton")
    assert sol.stats["newton"]


def test_every_default_passes_its_check():
    # check_parameters checks only the given names: the defaults must be valid as they are
    from dolfinode.parameters import _CHECKS

    assert set(_CHECKS) <= set(DEFAULTS)
    for name, check in _CHECKS.items():
        assert check(name, DEFAULTS[name]) == DEFAULTS[name], name


@pytest.mark.parametrize("name, value, error", [
    ("partitioning_threshold", 1.5, ValueError), ("interval_threshold", 0.0, ValueError),
    ("rebuild_model", "yes", TypeError), ("automatic_modeling", None, TypeError),
    ("subgrid_model", "linear", ValueError), ("average_samples", 2.0, ValueError)])
def test_remaining_parameters_are_checked(ode, name, value, error):
    with pytest.raises(error, match=name):
        dn.solve(ode, **{name: value})


@pytest.mark.parametrize("name", ["maximum_iterations", "number_of_samples", "maximum_steps"])
def test_numpy_integers_are_integers(ode, name):
    sol = dn.solve(ode, **{name: np.int64(5000)})
    assert sol.parameters[name] == 5000 and type(sol.parameters[name]) is int


@pytest.mark.parametrize("value, error", [("x", TypeError), (math.nan, ValueError),
                                          (0.0, ValueError)])
def test_scalar_absolute_tolerance_is_checked_with_its_name(ode, value, error):
    with pytest.raises(error, match="absolute_tolerance must be a positive"):
        dn.solve(ode, absolute_tolerance=value)


def test_step_limit_message_names_a_step_cap(ode):
    with pytest.raises(dn.SolverError, match="raise maximum_steps or maximum_time_step "
                                             r"\(the steps are capped at 1e-06\)"):
        dn.solve(ode, maximum_time_step=1e-6, maximum_steps=100)
    with pytest.raises(dn.SolverError, match="raise maximum_steps, loosen the tolerance"):
        dn.solve(ode, tolerance=1e-12, method="dG(0)", maximum_steps=100)


@pytest.mark.parametrize("scipy_method, galerkin", [("RK45", "cG(2)"), ("Radau", "dG(2)"),
                                                    ("BDF", "dG(1)")])
def test_scipy_method_names_suggest_a_galerkin_method(ode, scipy_method, galerkin):
    with pytest.raises(ValueError) as info:
        dn.solve(ode, scipy_method)
    assert f"is scipy's; a Galerkin method of similar order and stability is {galerkin!r}" in str(
        info.value)
