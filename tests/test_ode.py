"""ODE declaration: what is stored, and every invalid input with its error message."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn

u, v, w, k = sp.symbols("u v w k")


def oscillator(**overrides):
    """u' = v, v' = -k u: the keyword arguments of a valid declaration, with overrides."""
    kwargs = {"rhs": {u: v, v: -k * u}, "u0": {u: 1.0, v: 0.0}, "T": 1.0, "params": {k: 4.0}}
    kwargs.update(overrides)
    return kwargs


def declare(**overrides):
    kwargs = oscillator(**overrides)
    return dn.ODE(kwargs.pop("rhs"), **kwargs)


# --- a valid declaration ------------------------------------------------------------------


def test_size_states_and_component_order_follow_dict_keys():
    ode = dn.ODE({w: -w, u: v, v: -u}, u0={u: 1.0, v: 2.0, w: 3.0}, T=1.0)
    assert ode.N == 3
    assert ode.states == (w, u, v)
    assert ode.rhs == (-w, v, -u)
    # u0 given by symbol is laid out in component (key) order, not in the dict's order
    np.testing.assert_array_equal(ode.u0, [3.0, 1.0, 2.0])
    assert [ode.index(s) for s in (w, u, v)] == [0, 1, 2]


def test_pairs_sequence_declares_the_same_system_as_a_dict():
    a = dn.ODE({u: v, v: -u}, u0=[1.0, 2.0], T=1.0)
    b = dn.ODE([(u, v), (v, -u)], u0=[1.0, 2.0], T=1.0)
    assert a.states == b.states and a.rhs == b.rhs
    np.testing.assert_array_equal(a.u0, b.u0)


def test_u0_by_dict_and_by_sequence_give_the_same_vector():
    by_dict = declare(u0={v: -2.5, u: 0.125})
    by_list = declare(u0=[0.125, -2.5])
    by_array = declare(u0=np.array([0.125, -2.5]))
    for ode in (by_dict, by_list, by_array):
        assert ode.u0.dtype == np.float64
        np.testing.assert_array_equal(ode.u0, [0.125, -2.5])


def test_parameters_are_stored_as_floats_in_declaration_order():
    a, b = sp.symbols("a b")
    ode = dn.ODE({u: -a * u + b}, u0=[1.0], T=2.0, params={b: 3, a: sp.Rational(1, 4)})
    assert ode.parameter_symbols == (b, a)
    np.testing.assert_array_equal(ode.parameter_values, [3.0, 0.25])
    assert all(isinstance(value, float) for value in ode.params.values())
    assert ode.rhs == (-a * u + b,)


def test_time_symbol_is_accepted_in_rhs():
    ode = dn.ODE({u: sp.sin(dn.t) * u}, u0=[1.0], T=3.0, t0=1.0)
    assert dn.t in ode.rhs[0].free_symbols
    assert (ode.t0, ode.T) == (1.0, 3.0)


def test_numbers_are_accepted_as_right_hand_sides():
    ode = dn.ODE({u: 2, v: np.float64(0.5)}, u0=[0.0, 0.0], T=1.0)
    assert ode.rhs == (sp.Integer(2), sp.Float(0.5))
    assert all(isinstance(e, sp.Expr) for e in ode.rhs)


def test_second_order_layout_positions_then_velocities():
    x1, x2, kappa = sp.symbols("x1 x2 kappa")
    ode = dn.ODE.second_order(
        {x1: -x1 + x2**2 / 2, x2: -kappa * x2},
        x0={x1: 0.5, x2: 1.0}, v0={x2: -3.0, x1: 2.0}, T=100.0, params={kappa: 1e18})
    x1_dot, x2_dot = sp.Symbol("x1_dot"), sp.Symbol("x2_dot")
    assert ode.N == 4
    assert ode.states == (x1, x2, x1_dot, x2_dot)
    assert ode.rhs == (x1_dot, x2_dot, -x1 + x2**2 / 2, -kappa * x2)
    np.testing.assert_array_equal(ode.u0, [0.5, 1.0, 2.0, -3.0])
    assert ode.velocity(x1) == x1_dot and ode.velocity(x2) == x2_dot
    assert ode.params == {kappa: 1e18}


def test_second_order_default_velocity_symbols_can_appear_in_accelerations():
    x = sp.Symbol("x")
    damping = -x - sp.Symbol("x_dot") / 10
    ode = dn.ODE.second_order({x: damping}, x0=[1.0], v0=[0.0], T=1.0)
    assert ode.states == (x, sp.Symbol("x_dot"))
    assert ode.rhs == (sp.Symbol("x_dot"), damping)


def test_second_order_custom_velocity_symbols():
    x, y, p, q = sp.symbols("x y p q")
    ode = dn.ODE.second_order({x: -p, y: -x * q}, x0=[1.0, 2.0], v0=[3.0, 4.0], T=1.0,
                              velocities={x: p, y: q})
    assert ode.states == (x, y, p, q)
    assert ode.rhs == (p, q, -p, -x * q)
    assert ode.velocity(x) is p and ode.velocity(y) is q
    np.testing.assert_array_equal(ode.u0, [1.0, 2.0, 3.0, 4.0])


def test_second_order_v0_by_velocity_symbols():
    # (keyed by velocity symbols, v0 raised "x_dot ... is not a state")
    x, y, p, q = sp.symbols("x y p q")
    ode = dn.ODE.second_order({x: -p, y: -x * q}, x0=[1.0, 2.0], v0={p: 3.0, "q": 4.0},
                              T=1.0, velocities={x: p, y: q})
    np.testing.assert_array_equal(ode.u0, [1.0, 2.0, 3.0, 4.0])
    ode = dn.ODE.second_order({x: -x}, x0=[1.0], v0={sp.Symbol("x_dot"): 2.0}, T=1.0)
    np.testing.assert_array_equal(ode.u0, [1.0, 2.0])


def test_velocity_of_a_first_order_system_raises():
    with pytest.raises(ValueError, match="not a position of a second-order system"):
        declare().velocity(u)


def test_velocity_of_a_velocity_raises():
    x = sp.Symbol("x")
    ode = dn.ODE.second_order({x: -x}, x0=[1.0], v0=[0.0], T=1.0)
    with pytest.raises(ValueError, match="x_dot"):
        ode.velocity(ode.velocity(x))


def test_second_order_velocities_must_name_positions():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match=r"velocities names v, which is not a position"):
        dn.ODE.second_order({x: -x}, x0=[1.0], v0=[0.0], T=1.0, velocities={v: w})


# --- unknown symbols ----------------------------------------------------------------------


def test_unknown_symbol_suggests_the_close_name():
    vv = sp.Symbol("vv")
    with pytest.raises(ValueError) as info:
        declare(rhs={u: v, v: -k * vv})
    message = str(info.value)
    assert "unknown symbol 'vv'" in message
    assert "right-hand side of v" in message
    assert "did you mean 'v'?" in message


def test_parameter_without_a_value_asks_for_params():
    with pytest.raises(ValueError) as info:
        declare(params={})
    message = str(info.value)
    assert "unknown symbol 'k'" in message
    assert "params=" in message


def test_plain_symbol_t_hints_at_dn_t():
    plain_t = sp.Symbol("t")
    assert plain_t != dn.t
    with pytest.raises(ValueError) as info:
        declare(rhs={u: v, v: -k * u + sp.cos(plain_t)})
    assert "unknown symbol 't'" in str(info.value)
    assert "use dn.t" in str(info.value)


def test_symbol_t_with_other_assumptions_hints_at_dn_t():
    with pytest.raises(ValueError, match="use dn.t"):
        declare(rhs={u: v, v: sp.Symbol("t", positive=True)})


def test_time_symbol_cannot_be_a_state():
    with pytest.raises(ValueError, match="time symbol and cannot be a state"):
        dn.ODE({dn.t: 1}, u0=[0.0], T=1.0)


def test_time_symbol_cannot_be_a_parameter():
    with pytest.raises(ValueError, match="dn.t is the time and cannot be a parameter"):
        declare(params={k: 1.0, dn.t: 2.0})


# --- u0 -----------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_u0_names_the_state(bad):
    with pytest.raises(ValueError) as info:
        declare(u0=[1.0, bad])
    assert "u0 is not finite for v" in str(info.value)


def test_non_finite_u0_in_a_dict_names_the_state():
    with pytest.raises(ValueError, match="u0 is not finite for u"):
        declare(u0={u: float("nan"), v: 0.0})


def test_integer_too_large_for_a_double_is_reported_as_not_finite():
    # float(10**400) raises OverflowError, which escaped as neither ValueError nor TypeError
    with pytest.raises(ValueError, match="u0 is not finite for u: inf"):
        declare(u0=[10**400, 0.0])
    with pytest.raises(ValueError, match="T must be finite, got inf"):
        declare(T=10**400)
    with pytest.raises(ValueError, match="parameter k must be finite, got -inf"):
        declare(params={k: -10**400})


@pytest.mark.parametrize("values", [[1.0], [1.0, 2.0, 3.0], []])
def test_wrongly_sized_u0_gives_both_sizes(values):
    with pytest.raises(ValueError) as info:
        declare(u0=values)
    message = str(info.value)
    assert f"u0 has {len(values)} values but the system has 2 states" in message
    assert "(u, v)" in message


@pytest.mark.parametrize("values", [1.0, [[1.0, 0.0]], None, "10"])
def test_u0_that_is_not_a_vector_raises_type_error(values):
    with pytest.raises(TypeError, match="u0 must be a dict by state symbol or a sequence of 2"):
        declare(u0=values)


def test_u0_with_non_numbers_raises_type_error():
    with pytest.raises(TypeError, match="u0 must hold real numbers"):
        declare(u0=[1.0, "one"])


def test_u0_with_a_parameter_expression_names_it_and_the_way_to_vary_it():
    # it said "u0 must hold real numbers, got [1.0, sqrt(k)]"
    with pytest.raises(TypeError, match=r"u0 for v is sqrt\(k\), an expression of k: .*"
                                        r"dn.Solver\(ode\).solve\(u0=..., params=...\)"):
        declare(u0={u: 1.0, v: sp.sqrt(k)})


def test_u0_dict_missing_a_state():
    with pytest.raises(ValueError, match="u0 is missing values for v"):
        declare(u0={u: 1.0})


def test_u0_dict_with_an_unknown_key_suggests_the_state():
    uu = sp.Symbol("uu")
    with pytest.raises(ValueError) as info:
        declare(u0={uu: 1.0, v: 0.0})
    message = str(info.value)
    assert "u0 has a value for uu, which is not a state" in message
    assert "did you mean 'u'?" in message
    assert "states are u, v" in message


def test_u0_dict_with_an_extra_key():
    with pytest.raises(ValueError, match="u0 has a value for w, which is not a state"):
        declare(u0={u: 1.0, v: 0.0, w: 2.0})


# --- time interval -----------------------------------------------------------------------


def test_final_time_equal_to_initial_time():
    with pytest.raises(ValueError, match=r"T = 0.0 must be larger than t0 = 0.0"):
        declare(T=0.0)


def test_final_time_before_initial_time():
    with pytest.raises(ValueError, match=r"T = 1.0 must be larger than t0 = 2.0"):
        declare(T=1.0, t0=2.0)


def test_negative_final_time():
    with pytest.raises(ValueError, match=r"T = -1.0 must be larger than t0 = 0.0"):
        declare(T=-1.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_final_time(bad):
    with pytest.raises(ValueError, match=f"T must be finite, got {bad}"):
        declare(T=bad)


def test_non_finite_initial_time():
    with pytest.raises(ValueError, match="t0 must be finite"):
        declare(t0=-np.inf)


def test_final_time_that_is_not_a_number():
    with pytest.raises(TypeError, match="T must be a real number, got 'ten'"):
        declare(T="ten")


# --- states -------------------------------------------------------------------------------


def test_two_symbols_with_the_same_name_are_duplicate_states():
    plain, real = sp.Symbol("u"), sp.Symbol("u", real=True)
    assert plain != real  # different sympy symbols, same name in messages and output
    with pytest.raises(ValueError, match="duplicate state 'u'"):
        dn.ODE({plain: 1, real: 2}, u0=[0.0, 0.0], T=1.0)


def test_duplicate_pairs_are_duplicate_states():
    with pytest.raises(ValueError, match="duplicate state 'u'"):
        dn.ODE([(u, v), (v, -u), (u, 1)], u0=[0.0, 0.0, 0.0], T=1.0)


def test_empty_system():
    with pytest.raises(ValueError, match="at least one state"):
        dn.ODE({}, u0=[], T=1.0)


@pytest.mark.parametrize("state", ["u", u + 1])
def test_states_must_be_symbols(state):
    with pytest.raises(TypeError, match="states must be sympy Symbols"):
        dn.ODE({state: 1}, u0=[0.0], T=1.0)


def test_rhs_pairs_must_be_pairs():
    with pytest.raises(TypeError, match=r"\(state, expression\) pairs"):
        dn.ODE([(u, v, 1)], u0=[0.0], T=1.0)


def test_rhs_must_be_a_dict_or_pairs():
    with pytest.raises(TypeError, match="rhs must be a dict"):
        dn.ODE(42, u0=[0.0], T=1.0)


# --- right-hand side expressions ----------------------------------------------------------


def test_python_object_is_not_an_expression():
    with pytest.raises(TypeError) as info:
        declare(rhs={u: v, v: object()})
    message = str(info.value)
    assert "right-hand side of v is not a sympy expression" in message
    assert "object" in message


def test_string_is_not_an_expression():
    # strings are not parsed: sympify would eval them, and 'u' would not be the user's symbol
    with pytest.raises(TypeError, match="right-hand side of v is not a sympy expression: '-u'"):
        declare(rhs={u: v, v: "-u"})


def test_none_is_not_an_expression():
    with pytest.raises(TypeError, match="right-hand side of u is not a sympy expression"):
        declare(rhs={u: None, v: -u})


def test_relational_is_not_a_scalar_expression():
    with pytest.raises(TypeError, match="must be a scalar sympy expression, got StrictGreaterThan"):
        declare(rhs={u: u > 1, v: -u})


def test_complex_expression_is_rejected():
    with pytest.raises(ValueError, match="right-hand side of v is not a finite real expression"):
        declare(rhs={u: v, v: sp.I * u})


@pytest.mark.parametrize("infinite", [sp.oo, -sp.oo, u - sp.oo, sp.Min(u, -sp.oo), sp.zoo * u,
                                      sp.nan])
def test_infinite_expression_is_rejected(infinite):
    """-oo is sympy's NegativeInfinity, an atom of its own: it does not contain oo."""
    with pytest.raises(ValueError, match="right-hand side of u is not a finite real expression"):
        declare(rhs={u: infinite, v: -u})


@pytest.mark.parametrize("make, shown", [
    pytest.param(lambda: sp.Function("g")(u), "g(u)", id="undefined"),
    pytest.param(lambda: sp.gamma(u), "gamma(u)", id="gamma"),
])
def test_function_that_cannot_be_compiled_is_named(make, shown):
    with pytest.raises((ValueError, TypeError)) as info:
        declare(rhs={u: v, v: make()})
    message = str(info.value)
    assert "right-hand side of v" in message
    assert shown in message and "cannot be compiled" in message


def test_matrix_is_not_a_scalar_expression():
    with pytest.raises(TypeError, match="right-hand side of u must be a scalar sympy expression"):
        declare(rhs={u: sp.Matrix([u, v]), v: -u})


def test_allowed_functions_are_accepted():
    rhs = {u: sp.sqrt(1 + u**2) + sp.Abs(v) + sp.exp(-dn.t), v: sp.Max(u, v) * sp.atan2(u, v)}
    ode = declare(rhs=rhs)
    assert ode.rhs == tuple(rhs.values())


def test_mod_and_frac_are_floors():
    """A sawtooth written with Mod or frac is accepted as the floor it is, whose jumps the
    solver finds (both were refused as 'cannot be compiled')."""
    p = sp.Symbol("p")
    ode = dn.ODE({u: sp.Mod(dn.t, p) + sp.frac(2 * dn.t), v: -v}, u0=[0.0, 1.0], T=2.0,
                 params={p: 0.75})
    assert not ode.rhs[0].has(sp.Mod, sp.frac)
    sol = dn.solve(ode, method="cG(2)", tolerance=1e-8)
    # the integrals of the teeth: 2 of 0.75^2/2, one of 0.5^2/2; 4 of 1/4 (frac(2t))
    exact = 2 * 0.75**2 / 2 + 0.5**2 / 2 + 4 * 0.25
    assert abs(sol(2.0)[0] - exact) <= 1e-8


def test_derivative_in_rhs_cannot_be_compiled():
    with pytest.raises(ValueError, match=r"uses Derivative\(.*\), which cannot be compiled"):
        declare(rhs={u: v, v: sp.Derivative(sp.sin(u), u, evaluate=False)})


# --- parameters ---------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_parameter_value(bad):
    with pytest.raises(ValueError, match=f"parameter k must be finite, got {bad}"):
        declare(params={k: bad})


def test_parameter_value_that_is_not_a_number():
    with pytest.raises(TypeError, match="parameter k must be a real number, got 'four'"):
        declare(params={k: "four"})


def test_state_used_as_a_parameter():
    with pytest.raises(ValueError, match="u is both a state and a parameter"):
        declare(params={k: 4.0, u: 1.0})


def test_parameter_keys_are_symbols_or_their_names():
    assert declare(params={"k": 4.0}).params == declare(params={k: 4.0}).params
    with pytest.raises(ValueError, match="params has 'kk', which no right-hand side uses; "
                                         "did you mean 'k'"):
        declare(params={"kk": 4.0})
    with pytest.raises(ValueError, match="params has 'u', which no right-hand side uses"):
        declare(params={"u": 4.0})  # a state, not a parameter
    with pytest.raises(TypeError, match="parameter keys must be sympy Symbols or their names, "
                                        "got 3"):
        declare(params={3: 4.0})


def test_template_parameter_keys_by_name():
    a, b, c = sp.symbols("a b c")
    spring = dn.Template(slots=(a, b), terms={a: c * (b - a), b: c * (a - b)},
                         indices=[[0, 1]])
    by_name = dn.TemplateODE(spring, u0=[1.0, 0.0], T=1.0, params={"c": 2.0})
    assert by_name.params == {c: 2.0}
    with pytest.raises(ValueError, match="params has 'a', which no right-hand side uses"):
        dn.TemplateODE(spring, u0=[1.0, 0.0], T=1.0, params={"a": 2.0, "c": 2.0})


def test_parameter_given_by_symbol_and_by_name_raises():
    # {k: 4.0, "k": 5.0} silently kept the last value
    with pytest.raises(ValueError, match="parameter k is given twice"):
        declare(params={k: 4.0, "k": 5.0})


def test_symbol_with_other_assumptions_than_the_parameter_says_so():
    # the message was "unknown symbol 'a' ...; did you mean 'a'?"
    a = sp.Symbol("a", positive=True)
    with pytest.raises(ValueError, match="other assumptions") as info:
        dn.ODE({u: -a * u}, u0=[1.0], T=1.0, params={sp.Symbol("a"): 1.0})
    assert "did you mean 'a'" not in str(info.value)


def test_params_must_be_a_dict():
    with pytest.raises(TypeError, match="params must be a dict"):
        declare(params=[4.0])


# --- declared domain ------------------------------------------------------------------------


def test_nonnegative_is_a_mask_in_component_order():
    assert declare().nonnegative.tolist() == [False, False]
    assert declare(nonnegative=True).nonnegative.tolist() == [True, True]
    assert declare(nonnegative=[v]).nonnegative.tolist() == [False, True]
    assert declare(nonnegative=("u",)).nonnegative.tolist() == [True, False]
    assert declare(nonnegative=np.array([False, True])).nonnegative.tolist() == [False, True]


def test_nonnegative_unknown_state_suggests_the_name():
    with pytest.raises(ValueError, match="'vv' is not a state; did you mean 'v'"):
        declare(nonnegative=["vv"])


def test_nonnegative_mask_of_the_wrong_size():
    with pytest.raises(ValueError, match=r"nonnegative as a mask needs shape \(2,\), got \(3,\)"):
        declare(nonnegative=np.array([True, False, True]))


@pytest.mark.parametrize("bad", [u, "u", 1.5])
def test_nonnegative_state_outside_a_sequence(bad):
    with pytest.raises(TypeError, match="nonnegative must be True, a sequence of states"):
        declare(nonnegative=bad)


def test_negative_initial_value_of_a_nonnegative_state():
    with pytest.raises(ValueError, match="u0 of u is -0.5, but u is declared nonnegative"):
        declare(u0={u: -0.5, v: 0.0}, nonnegative=[u])
    assert declare(u0={u: 1.0, v: -0.5}, nonnegative=[u]).u0.tolist() == [1.0, -0.5]


def test_second_order_nonnegative_counts_positions_then_velocities():
    x1, x2 = sp.symbols("x1 x2")
    ode = dn.ODE.second_order({x1: -x1, x2: -x2}, x0=[1.0, 2.0], v0=[0.0, 0.0], T=1.0,
                              nonnegative=[x2])
    assert ode.nonnegative.tolist() == [False, True, False, False]


# --- values set after a solve are honoured; what the kernels are built from is fixed ------


@pytest.mark.parametrize("method", ["cG(2)", "mcG(2)"])
def test_a_parameter_changed_after_a_solve_is_honoured(method):
    ode = declare(T=1.0)
    first = dn.solve(ode, method, tolerance=1e-8)
    ode.params[k] = 9.0  # issue 32: the parameter vector of the first solve was reused
    second = dn.solve(ode, method, tolerance=1e-8)
    assert first(1.0)[0] == pytest.approx(np.cos(2.0), abs=1e-6)
    assert second(1.0)[0] == pytest.approx(np.cos(3.0), abs=1e-6)
    assert first.ode.params[k] == 4.0 and second.ode.params[k] == 9.0  # as solved


def test_u0_t0_and_T_set_after_a_solve_are_honoured():
    ode = declare()
    dn.solve(ode, "cG(2)", tolerance=1e-8)
    ode.params["k"] = 1.0
    ode.u0 = [2.0, 0.0]
    ode.T, ode.t0 = 3.0, 1.0
    sol = dn.solve(ode, "cG(2)", tolerance=1e-8)
    assert sol.t[0] == 1.0 and sol.t[-1] == 3.0
    assert sol(3.0)[0] == pytest.approx(2.0 * np.cos(2.0), abs=1e-6)


def test_values_set_on_an_ode_are_checked_as_declared():
    ode = declare()
    with pytest.raises(ValueError, match="parameter k must be finite"):
        ode.params[k] = np.inf
    with pytest.raises(KeyError, match="a new parameter needs a new ODE"):
        ode.params[sp.Symbol("c")] = 1.0
    with pytest.raises(TypeError, match="cannot be removed"):
        del ode.params[k]
    with pytest.raises(ValueError, match="T = -0.5 must be larger than t0 = 0.0"):
        ode.T = -0.5
    with pytest.raises(ValueError, match="read-only"):
        ode.u0[0] = 3.0  # in place it would skip the checks: assign ode.u0 instead
    with pytest.raises(ValueError, match="u0 is not finite for u"):
        ode.u0 = [np.nan, 0.0]
    assert ode.params == {k: 4.0} and ode.u0.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("name", ["states", "rhs", "nonnegative"])
def test_what_the_kernels_are_built_from_cannot_be_set(name):
    ode = declare()
    with pytest.raises(AttributeError, match=f"ode.{name} is fixed by the declaration"):
        setattr(ode, name, getattr(ode, name))


def test_copies_and_solutions_have_their_own_parameter_values():
    import copy
    import pickle

    ode = declare()
    for other in (copy.copy(ode), pickle.loads(pickle.dumps(ode)), dn.vary(ode, {k: 2.0})):
        other.params[k] = 7.0
    assert ode.params[k] == 4.0


# --- complex values -------------------------------------------------------------------------


@pytest.mark.parametrize("where, value, words", [
    ("params", {k: np.complex128(4.0)}, "parameter k is complex"),
    ("u0", [1.0, np.complex64(0.0)], "u0 is complex"),
    ("u0", np.array([1.0, 2.0j]), "u0 is complex"),
    ("T", np.complex128(1.0), "T is complex"),
])
def test_complex_values_are_rejected_not_truncated(where, value, words):
    # float() of a numpy complex drops the imaginary part with only a warning
    with pytest.raises(TypeError, match=words):
        declare(**{where: value})


def test_complex_values_of_a_template_system_are_rejected():
    x, c = sp.symbols("x c")
    decay = dn.Template(slots=(x,), terms={x: -c * x}, indices=[[0], [1]], params=(c,),
                        values=[1.0, 2.0])
    with pytest.raises(TypeError, match="u0 is complex"):
        dn.TemplateODE(decay, u0=np.array([1.0, 1j]), T=1.0)
    with pytest.raises(TypeError, match="values is complex"):
        dn.Template(slots=(x,), terms={x: -c * x}, indices=[[0]], params=(c,),
                    values=np.array([1j]))


def test_a_parameter_of_a_template_system_changed_after_a_solve_is_honoured():
    x, rate = sp.symbols("x rate")
    decay = dn.Template(slots=(x,), terms={x: -rate * x}, indices=[[0], [1]])
    ode = dn.TemplateODE(decay, u0=[1.0, 2.0], T=1.0, params={rate: 1.0})
    first = dn.solve(ode, "cG(2)", tolerance=1e-8)(1.0)
    ode.params[rate] = 2.0
    np.testing.assert_allclose(first, [np.exp(-1.0), 2 * np.exp(-1.0)], rtol=1e-6)
    np.testing.assert_allclose(dn.solve(ode, "cG(2)", tolerance=1e-8)(1.0),
                               [np.exp(-2.0), 2 * np.exp(-2.0)], rtol=1e-6)
