"""Lowering of ODE declarations to kernels: f, f_i and the sparse Jacobian against sympy,
the dependency graph, constants, and the on-disk kernel cache."""
import json
import textwrap

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile import CompiledODE, lower

t = dn.t


# --- systems --------------------------------------------------------------------------------


def oscillator():
    u, v, k, c = sp.symbols("u v k c")
    return dn.ODE({u: v, v: -k * u - c * v * u**2 + sp.sin(t) * u},
                  u0=[1.0, 0.0], T=1.0, params={k: 4.0, c: 0.3})


def elementary():
    x, y, z, a, b = sp.symbols("x y z a b")
    return dn.ODE({
        x: a * sp.exp(-y) * x + sp.log(1 + z**2),
        y: sp.sqrt(1 + x**2 + z**2) - b * t * y,
        z: sp.sin(x * y * t) + sp.cos(z) ** 3 / (1 + x**2) + sp.tanh(b * z),
    }, u0=[1.0, 0.5, 0.2], T=1.0, params={a: -1.5, b: 0.7})


def piecewise():
    x, y, w = sp.symbols("x y w")
    return dn.ODE({
        x: sp.Piecewise((x**2 * y, x > y), (sp.exp(y) * x, True)),
        y: sp.Piecewise((-x * t, t < 1), (sp.atan(y), True)) + sp.Max(x, w) * sp.Min(y, 2 * w),
        w: sp.atan2(x, 1 + y**2) + sp.erf(w * x) + sp.Rational(1, 3) * w,
    }, u0=[1.0, 0.5, 0.2], T=2.0)


def with_abs():
    x, y = sp.Symbol("x"), sp.Symbol("y", real=True)
    return dn.ODE({x: sp.Abs(x) * y + sp.sin(x), y: -sp.Abs(y) * x + sp.Abs(x - y) * t},
                  u0=[1.0, 0.5], T=1.0)


SYSTEMS = [
    pytest.param(oscillator, id="oscillator"),
    pytest.param(elementary, id="elementary"),
    pytest.param(piecewise, id="piecewise"),
    pytest.param(with_abs, id="abs"),
]


def chain(n=50):
    """A sparse chain: f_i couples u_{i-1}, u_i, u_{i+1}, plus a few long-range couplings,
    a component that depends on no state and one that depends on others only."""
    u = sp.symbols(f"u0:{n}")
    k = sp.Symbol("k")
    rhs = {}
    for i in range(n):
        expr = -2 * u[i] + k * sp.sin(u[i - 1] if i > 0 else 0)
        if i + 1 < n:
            expr += u[i + 1] ** 2 / (1 + t)
        rhs[u[i]] = expr
    rhs[u[7]] += sp.exp(-u[40]) * u[25]
    rhs[u[31]] = sp.cos(t) * k                  # depends on no state
    rhs[u[44]] = u[3] * u[45] + sp.sqrt(2 + u[12] ** 2)  # not on itself
    expected = np.zeros((n, n), dtype=bool)
    for i in range(n):
        expected[i, max(i - 1, 0):min(i + 2, n)] = True
    expected[7, [25, 40]] = True
    expected[31, :] = False
    expected[44, :] = False
    expected[44, [3, 45, 12]] = True
    ode = dn.ODE(rhs, u0=np.linspace(0.1, 1.0, n), T=1.0, params={k: 0.75})
    return ode, expected


# --- sympy references -----------------------------------------------------------------------


def _evaluate(ode, exprs, x, time):
    """Evaluate sympy expressions with mpmath at 30 digits (not through the kernel printer)."""
    arguments = [*ode.states, *ode.parameter_symbols, t]
    function = sp.lambdify(arguments, exprs, modules="mpmath")
    with mp.workdps(30):
        values = function(*[mp.mpf(float(a)) for a in (*x, *ode.parameter_values, time)])
    return np.array(values, dtype=float)


def sympy_rhs(ode, x, time):
    return _evaluate(ode, list(ode.rhs), x, time)


def sympy_jacobian(ode, x, time):
    # differentiate with respect to real stand-ins, so that |u| has its real derivative
    real = [sp.Dummy(s.name, real=True) for s in ode.states]
    J = sp.Matrix(ode.rhs).xreplace(dict(zip(ode.states, real))).jacobian(real)
    return _evaluate(ode, J.xreplace(dict(zip(real, ode.states))).tolist(), x, time)


def random_points(count, n, seed):
    rng = np.random.default_rng(seed)
    return [(rng.uniform(0.2, 1.5, n), float(rng.uniform(0.0, 2.0))) for _ in range(count)]


# --- (a) Jacobian, (c) rhs, (d) rhs_component ---------------------------------------------------


@pytest.mark.parametrize("make", SYSTEMS)
def test_jacobian_equals_sympy_dense_jacobian(make):
    ode = make()
    compiled = lower(ode)
    assert isinstance(compiled, CompiledODE) and compiled.N == ode.N
    for x, time in random_points(4, ode.N, seed=1):
        J = compiled.jacobian_matrix(x, time).toarray()
        np.testing.assert_allclose(J, sympy_jacobian(ode, x, time), rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("make", SYSTEMS)
def test_rhs_equals_sympy(make):
    ode = make()
    compiled = lower(ode)
    for x, time in random_points(4, ode.N, seed=2):
        np.testing.assert_allclose(compiled.f(x, time), sympy_rhs(ode, x, time),
                                   rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("make", SYSTEMS)
def test_rhs_component_equals_the_full_rhs(make):
    ode = make()
    compiled = lower(ode)
    for x, time in random_points(3, ode.N, seed=3):
        full = compiled.f(x, time)
        parts = [compiled.f_component(i, x, time) for i in range(ode.N)]
        # equal up to rounding: rhs eliminates common subexpressions across components
        np.testing.assert_allclose(parts, full, rtol=1e-14, atol=1e-15)


def test_rhs_writes_into_the_given_array():
    ode = oscillator()
    compiled = lower(ode)
    x, out = np.array([0.3, -0.7]), np.full(2, np.nan)
    compiled.rhs(x.ctypes.data, 0.25, compiled.p.ctypes.data, out.ctypes.data)
    np.testing.assert_array_equal(out, compiled.f(x, 0.25))
    data = np.full(compiled.nnz, np.nan)
    compiled.jacobian(x.ctypes.data, 0.25, compiled.p.ctypes.data, data.ctypes.data)
    assert np.all(np.isfinite(data))


@pytest.mark.parametrize("expr, derivative", [
    pytest.param(lambda x: sp.sign(x), lambda x: 0.0, id="sign"),
    pytest.param(lambda x: sp.Heaviside(x), lambda x: 0.0, id="Heaviside"),
    pytest.param(lambda x: sp.floor(x), lambda x: 0.0, id="floor"),
    pytest.param(lambda x: sp.ceiling(x), lambda x: 0.0, id="ceiling"),
    # of an expression: sympy's chain rule leaves Subs(Derivative(floor(xi), xi), xi, 3 x)
    pytest.param(lambda x: sp.floor(3 * x), lambda x: 0.0, id="floor(3x)"),
    pytest.param(lambda x: sp.ceiling(2 * x + 1), lambda x: 0.0, id="ceiling(2x + 1)"),
    pytest.param(lambda x: sp.sign(x**2 - 1), lambda x: 0.0, id="sign(x^2 - 1)"),
])
def test_piecewise_constant_functions_lower_with_zero_derivative(expr, derivative):
    x, y = sp.symbols("x y")
    ode = dn.ODE({x: expr(x) * y + x, y: -x}, u0=[0.5, 1.0], T=1.0)
    compiled = lower(ode)
    point = np.array([0.3, 2.0])
    np.testing.assert_allclose(compiled.f(point, 0.0), sympy_rhs(ode, point, 0.0))
    J = compiled.jacobian_matrix(point, 0.0).toarray()
    np.testing.assert_allclose(J, [[1 + 2.0 * derivative(0.3), float(expr(0.3))], [-1, 0]])


@pytest.mark.parametrize("x0, slope", [(0.1, 4.0), (0.3, 0.0), (-0.3, 0.0)])
def test_nested_min_max_lower_with_their_derivative(x0, slope):
    # sympy's derivative of Max(-1, Min(1, 4 x)) holds the literal false, which C lacks
    x, v = sp.symbols("x v")
    ode = dn.ODE({x: v, v: -sp.Max(-1, sp.Min(1, 4 * x))}, u0=[1.0, 0.0], T=1.0)
    J = lower(ode).jacobian_matrix(np.array([x0, 0.0]), 0.0).toarray()
    np.testing.assert_array_equal(J, [[0.0, 1.0], [-slope, 0.0]])


def test_large_integer_constants():
    x = sp.Symbol("x")
    ode = dn.ODE({x: 10**20 * x + sp.Rational(1, 10**20)}, u0=[1.0], T=1.0)
    compiled = lower(ode)
    assert compiled.f([2.0], 0.0)[0] == pytest.approx(2e20, rel=1e-15)


def test_coefficients_sympy_folds_beyond_double_range():
    """sympy writes exp(-1e4 (t - 3)) as 6.8e13028 exp(-1e4 t) and exp(1e4 (t - 3)) as
    1.5e-13029 exp(1e4 t): printed as they are, inf (no C) and 0 (f = 0)."""
    x, y = sp.symbols("x y")
    ode = dn.ODE({x: 1 / (1 + sp.exp(-1e4 * (t - 3))), y: -2 * y * sp.exp(1e4 * (t - 3)) ** 3},
                 u0=[0.0, 1.0], T=4.0)
    compiled = lower(ode)
    for time in (2.999, 3.0, 3.0001):
        step, grow = float(1 / (1 + mp.exp(-1e4 * (time - 3)))), float(mp.exp(3e4 * (time - 3)))
        np.testing.assert_allclose(compiled.f([0.0, 1.5], time), [step, -3 * grow], rtol=1e-11)
        np.testing.assert_allclose(compiled.jacobian_matrix([0.0, 1.5], time).toarray(),
                                   [[0, 0], [0, -2 * grow]], rtol=1e-11)


def test_a_literal_zero_float_is_a_double():
    """sympy >= 1.13 has Float(0.0) != 0: a literal 0.0 (a Piecewise branch, Max(x, 0.0))
    is a zero, not a constant that underflowed."""
    x, a = sp.symbols("x a")
    ode = dn.ODE({x: sp.Piecewise((1.0, t > a), (0.0, True)) + sp.Max(x, 0.0)}, u0=[-1.0],
                 T=1.0, params={a: 0.5})
    assert any(c.is_Float and c.is_zero for c in ode.rhs[0].atoms(sp.Float))
    compiled = lower(ode)
    np.testing.assert_array_equal(compiled.f([-1.0], 0.2), [0.0])
    np.testing.assert_array_equal(compiled.f([0.25], 0.7), [1.25])


def test_a_constant_beyond_double_range_is_an_error():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match="beyond the range of double precision"):
        lower(dn.ODE({x: sp.Float(1e200) ** 2 * x}, u0=[1.0], T=1.0))


# --- (b) dependency graph and (d) the dispatch tree on a large system ---------------------------


def test_dependencies_equal_the_symbolic_sparsity_of_a_chain():
    ode, expected = chain(50)
    compiled = lower(ode)
    deps = compiled.dependencies()
    assert deps.shape == (50, 50)
    np.testing.assert_array_equal(deps.toarray(), expected)
    # the same pattern read off sympy: which states appear in each f_i
    symbolic = np.array([[s in f.free_symbols for s in ode.states] for f in ode.rhs])
    np.testing.assert_array_equal(deps.toarray(), symbolic)
    assert compiled.indptr.dtype == np.int64 and compiled.indices.dtype == np.int64
    assert compiled.nnz == expected.sum()
    for i in range(50):  # rows sorted, no duplicates
        row = compiled.indices[compiled.indptr[i]:compiled.indptr[i + 1]]
        assert np.all(np.diff(row) > 0)


def test_chain_kernels_equal_sympy():
    ode, _ = chain(50)
    compiled = lower(ode)
    for x, time in random_points(2, ode.N, seed=4):
        full = compiled.f(x, time)
        np.testing.assert_allclose(full, sympy_rhs(ode, x, time), rtol=1e-14, atol=1e-15)
        # every case of the jump table returns its own component
        parts = np.array([compiled.f_component(i, x, time) for i in range(ode.N)])
        np.testing.assert_allclose(parts, full, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(compiled.jacobian_matrix(x, time).toarray(),
                                   sympy_jacobian(ode, x, time), rtol=1e-13, atol=1e-14)


# --- (e) constants ------------------------------------------------------------------------------


def test_floating_constants_keep_full_double_precision():
    coefficients = [0.7371312573325668, 0.1, 1.0000000000000002, 6.02214076e23,
                    1.2345678901234567e-300]
    x = sp.symbols("x0:5")
    ode = dn.ODE({xi: c * xi for xi, c in zip(x, coefficients)}, u0=np.ones(5), T=1.0)
    compiled = lower(ode)
    point = np.array([3.0, 7.0, 0.5, -1.25, 2.0])
    f = compiled.f(point, 0.0)
    for i, c in enumerate(coefficients):
        assert f[i] == c * point[i]  # exactly: the printed constant is the same double
    np.testing.assert_array_equal(compiled.jacobian_matrix(point, 0.0).diagonal(), coefficients)


def test_parameter_values_keep_full_double_precision():
    x, a = sp.symbols("x a")
    value = 0.1428571428571428492126926812488818541169166564941406
    ode = dn.ODE({x: a * x}, u0=[1.0], T=1.0, params={a: value})
    compiled = lower(ode)
    assert compiled.p.dtype == np.float64 and compiled.p[0] == value
    assert compiled.f([3.0], 0.0)[0] == value * 3.0


def test_rational_constants_are_divided_in_floating_point():
    x = sp.Symbol("x")
    ode = dn.ODE({x: sp.Rational(1, 3) * x + sp.Rational(2, 7)}, u0=[1.0], T=1.0)
    compiled = lower(ode)
    assert compiled.f([1.0], 0.0)[0] == pytest.approx(1 / 3 + 2 / 7, rel=2e-16)


# --- (f) caching --------------------------------------------------------------------------------


def test_same_expressions_are_memoised_in_process():
    first = lower(oscillator())
    second = lower(oscillator())
    assert second.cached
    assert second.rhs is first.rhs and second.jacobian is first.jacobian
    np.testing.assert_array_equal(second.indptr, first.indptr)


def test_lowering_and_band_ordering_are_memoised_on_the_declaration():
    """Every solve of one declaration lowers it again: it gets the first lowering, with the
    band ordering once computed (not computed again per solve)."""
    ode = oscillator()
    first = lower(ode)
    assert first.ordering is lower(ode).ordering
    again = lower(ode)
    assert again.cached and again.compile_time == 0.0 and first.compile_time > 0.0


def test_new_declarations_of_the_same_expressions_share_pattern_and_ordering():
    """Automatic modeling declares the same expressions dozens of times with new initial
    values and parameters: the pattern and band ordering are not derived again, and another
    expression is not served the memoised lowering."""
    ode = oscillator()
    again = dn.ODE(dict(zip(ode.states, ode.rhs)), u0=[0.5, 2.0], T=3.0,
                   params={s: 3 * v for s, v in ode.params.items()})
    a, b = lower(ode), lower(again)
    assert b.indptr is a.indptr and b.ordering is a.ordering
    u, v = ode.states
    other = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=1.0)
    c = lower(other)
    assert c.rhs is not a.rhs
    np.testing.assert_allclose(c.f([0.4, 0.9], 0.3), [0.9, -0.4], rtol=1e-15)


def test_parameter_values_are_not_compiled_in():
    ode = oscillator()
    other = dn.ODE(dict(zip(ode.states, ode.rhs)), u0=[1.0, 0.0], T=1.0,
                   params={s: 2 * v for s, v in ode.params.items()})
    a, b = lower(ode), lower(other)
    assert b.rhs is a.rhs
    np.testing.assert_array_equal(b.p, 2 * a.p)
    x = np.array([0.4, 0.9])
    np.testing.assert_allclose(b.f(x, 0.3), sympy_rhs(other, x, 0.3), rtol=1e-14)
    assert not np.allclose(a.f(x, 0.3), b.f(x, 0.3))


_CACHE_SCRIPT = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    import sympy as sp
    import dolfinode as dn
    from dolfinode.compile import lower
    from dolfinode.compile.cache import cache_directory

    u, v, k = sp.symbols("u v k")

    def system(name):
        if name == "A":
            return dn.ODE({u: v, v: -k * u * sp.sin(dn.t)}, [1.0, 0.0], 1.0, params={k: 2.0})
        if name == "A-params":   # same expressions, other parameter values
            return dn.ODE({u: v, v: -k * u * sp.sin(dn.t)}, [3.0, 1.0], 5.0, params={k: -7.5})
        if name == "B":          # another expression
            return dn.ODE({u: v, v: -k * u * sp.cos(dn.t)}, [1.0, 0.0], 1.0, params={k: 2.0})

    def snapshot():
        root = cache_directory()
        return {str(p.relative_to(root)): [p.stat().st_size, p.stat().st_mtime_ns]
                for p in sorted(root.rglob("*")) if p.is_file()}

    report = []
    for name in sys.argv[1:]:
        compiled = lower(system(name))
        value = float(compiled.f([0.5, 2.0], 0.25)[1])
        report.append({"name": name, "cached": compiled.cached, "value": value,
                       "files": snapshot()})
    print(json.dumps(report))
""")


def run_fresh(run_python, cache_dir, *systems):
    result = run_python(_CACHE_SCRIPT, *systems, env={"DOLFINODE_CACHE_DIR": str(cache_dir)})
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def kernel_files(files):
    return sorted(name for name in files if name.startswith("dn_") and name.endswith(".so"))


def test_disk_cache_across_processes(tmp_path, run_python):
    (first,) = run_fresh(run_python, tmp_path, "A")
    assert first["cached"] is False
    assert len(kernel_files(first["files"])) == 1

    again, params, other = run_fresh(run_python, tmp_path, "A", "A-params", "B")
    # same expressions in a fresh process: loaded, nothing generated, compiled or rewritten
    assert again["cached"] is True
    assert again["files"] == first["files"]
    assert again["value"] == first["value"]
    # other parameter values: the same kernel
    assert params["cached"] is True
    assert params["files"] == first["files"]
    assert params["value"] != first["value"]
    # another expression: a new kernel file beside the first
    assert other["cached"] is False
    new = set(kernel_files(other["files"])) - set(kernel_files(first["files"]))
    assert len(kernel_files(other["files"])) == 2 and len(new) == 1

    every_file = [p.name for p in tmp_path.rglob("*")]
    assert not [name for name in every_file if name.endswith(".tmp")]


def test_a_failed_compile_leaves_nothing_in_the_cache(tmp_path, monkeypatch):
    """A source the C compiler rejects is removed with the failure, so that it is generated
    again next time rather than failing again from the cache."""
    from dolfinode.compile import cache, lowering

    monkeypatch.setenv("DOLFINODE_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(lowering, "_loaded", {})
    monkeypatch.setattr(cache, "c_compiler", lambda: "false")  # exits 1, writes nothing
    x, y = sp.symbols("x y")
    ode = dn.ODE({x: y * sp.cos(x), y: -x}, u0=[0.5, 1.0], T=1.0)
    with pytest.raises(RuntimeError, match="compiling the kernels of dn_.*failed"):
        lower(ode)
    assert not list(tmp_path.rglob("dn_*"))
    monkeypatch.undo()
    monkeypatch.setenv("DOLFINODE_CACHE_DIR", str(tmp_path))
    ode._compiled = None
    assert lower(ode).f([0.5, 1.0], 0.0)[1] == -0.5


def test_expected_values_in_the_cache_script():
    """The values the cache test compares come from the declared systems (checked in-process)."""
    u, v, k = sp.symbols("u v k")
    ode = dn.ODE({u: v, v: -k * u * sp.sin(t)}, [1.0, 0.0], 1.0, params={k: 2.0})
    assert lower(ode).f([0.5, 2.0], 0.25)[1] == pytest.approx(-2.0 * 0.5 * np.sin(0.25), rel=1e-15)


@pytest.mark.parametrize("make", SYSTEMS)
def test_jacobian_rows_equal_the_full_jacobian(make):
    ode = make()
    compiled = lower(ode)
    for x, time in random_points(2, ode.N, seed=5):
        J = compiled.jacobian_matrix(x, time)
        for i in range(ode.N):
            np.testing.assert_allclose(compiled.jacobian_row_values(i, x, time),
                                       J.data[J.indptr[i]:J.indptr[i + 1]], rtol=1e-14, atol=1e-15)


# --- structured expression systems: lowered once per shape --------------------------------------


@pytest.fixture
def small_structured(monkeypatch):
    """Systems from 24 components lowered by shape (STRUCTURED_MIN is 256), so that the
    per-expression references compile quickly; the in-process memo starts empty."""
    from dolfinode.compile import lowering

    monkeypatch.setattr(lowering, "STRUCTURED_MIN", 24)
    monkeypatch.setattr(lowering, "_lowerings", {})
    return lowering


def stencil(n, nonnegative=None, power=2):
    """u_i' = e (u_(i-1) - 2 u_i + u_(i+1)) + g u_i^power (1 - u_i) + sin(t) on n points,
    mirror ends: three shapes (two ends, the interior) whatever n."""
    u = sp.symbols(f"u0:{n}")
    e, g = sp.symbols("e g")
    rhs = {}
    for i in range(n):
        left = u[i - 1] if i > 0 else u[1]
        right = u[i + 1] if i < n - 1 else u[n - 2]
        rhs[u[i]] = e * (left - 2 * u[i] + right) + g * u[i] ** power * (1 - u[i]) + sp.sin(t)
    return dn.ODE(rhs, u0=np.linspace(0.0, 1.0, n), T=0.1, params={e: 50.0, g: 3.0},
                  nonnegative=nonnegative)


def per_expression(ode, lowering):
    """A new declaration of ``ode`` lowered one expression at a time (past the memo)."""
    saved = lowering.STRUCTURED_MIN, lowering._lowerings
    lowering.STRUCTURED_MIN, lowering._lowerings = 10**9, {}
    try:
        return lower(dn.ODE(dict(zip(ode.states, ode.rhs)), u0=ode.u0, T=ode.T,
                            params=ode.params, nonnegative=ode.nonnegative))
    finally:
        lowering.STRUCTURED_MIN, lowering._lowerings = saved


def test_structured_kernels_equal_the_per_expression_kernels(small_structured):
    ode = stencil(40)
    structured, reference = lower(ode), per_expression(ode, small_structured)
    assert structured.templates == 3 and reference.templates == 0  # ends and interior
    np.testing.assert_array_equal(structured.indptr, reference.indptr)
    np.testing.assert_array_equal(structured.indices, reference.indices)
    for x, time in random_points(2, ode.N, seed=6):
        f = structured.f(x, time)
        np.testing.assert_allclose(f, reference.f(x, time), rtol=1e-14, atol=1e-13)
        J = structured.jacobian_matrix(x, time)
        np.testing.assert_allclose(J.data, reference.jacobian_matrix(x, time).data, rtol=1e-14,
                                   atol=1e-13)
        for i in range(ode.N):
            assert structured.f_component(i, x, time) == f[i]
            np.testing.assert_array_equal(structured.jacobian_row_values(i, x, time),
                                          J.data[J.indptr[i]:J.indptr[i + 1]])


def test_structured_code_does_not_grow_with_n():
    """Two sizes of one stencil (above STRUCTURED_MIN) share the kernel library: its key
    holds the shapes, not N."""
    small, large = lower(stencil(300)), lower(stencil(1000))
    assert small.templates == large.templates == 3 and large.rhs is small.rhs
    x = np.linspace(0.2, 0.9, 1000)
    f = large.f(x, 0.5)
    assert f[500] == pytest.approx(50.0 * (x[499] - 2 * x[500] + x[501])
                                   + 3.0 * x[500] ** 2 * (1 - x[500]) + np.sin(0.5), rel=1e-12)
    assert f[999] == pytest.approx(50.0 * (2 * x[998] - 2 * x[999])
                                   + 3.0 * x[999] ** 2 * (1 - x[999]) + np.sin(0.5), rel=1e-12)


def test_systems_with_many_shapes_stay_per_expression(small_structured):
    n = 40
    u = sp.symbols(f"u0:{n}")
    distinct = dn.ODE({u[i]: -(i + 1) * u[i] for i in range(n)}, u0=np.ones(n), T=1.0)
    assert lower(distinct).templates == 0  # one shape per component
    assert lower(stencil(20)).templates == 0  # below STRUCTURED_MIN
    assert lower(stencil(n)).templates == 3


def test_structured_kernels_clamp_nonnegative_components_in_powers(small_structured):
    """sqrt(u_i) of a component declared nonnegative reads max(u_i, 0), by shape as per
    expression; the other components are read as they are."""
    ode = stencil(40, nonnegative=[f"u{i}" for i in range(0, 40, 2)], power=sp.Rational(1, 2))
    structured, reference = lower(ode), per_expression(ode, small_structured)
    # shapes: the ends, the interior with an even (clamped) and with an odd centre
    assert structured.templates == 4 and reference.templates == 0
    x = np.linspace(-0.5, 1.0, 40)
    f = structured.f(x, 0.3)
    np.testing.assert_allclose(f, reference.f(x, 0.3), rtol=1e-14, atol=1e-13)
    np.testing.assert_allclose(structured.jacobian_matrix(x, 0.3).data,
                               reference.jacobian_matrix(x, 0.3).data, rtol=1e-14, atol=1e-13)
    negative = np.flatnonzero(x < 0)
    assert np.isfinite(f[negative[::2]]).all() and np.isnan(f[negative[1::2]]).all()


def test_structured_solve_equals_the_per_expression_solve(small_structured):
    ode = stencil(40)
    reference = per_expression(ode, small_structured)
    for method in ("cG(2)", "dG(1)", "mcG(2)"):
        for solver in ("fixed-point", "newton"):
            sol = dn.solve(ode, method, tolerance=1e-6, nonlinear_solver=solver)
            ode._compiled = reference
            again = dn.solve(ode, method, tolerance=1e-6, nonlinear_solver=solver)
            ode._compiled = None
            assert sol.stats["time slabs"] == again.stats["time slabs"]
            np.testing.assert_allclose(sol.y, again.y, rtol=1e-10, atol=1e-12)
