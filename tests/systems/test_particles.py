"""The ParticleSystem builder: Newton's law with springs and external forces in 1-3 D, and the
lattice of DOLFIN's automatic-modeling demo against a per-expression transcription of it."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile import lower


def dolfin_lattice(p, m=1e-12, M=100.0):
    """The lattice demo (DOLFIN modeling/lattice/main.cpp, 2004) transcribed term by term:
    x0, y0, mass, Fx, Fy as in the C++ class, accelerations F / mass (ParticleSystem::f)."""
    n = p * p + (p - 1) ** 2
    h = 1.0 / float(p - 1)
    hsmall = 0.5 * np.sqrt(2.0) * h
    X = [sp.Symbol(f"x_{i}") for i in range(n)]
    Y = [sp.Symbol(f"y_{i}") for i in range(n)]

    def dist(i, j):
        return sp.sqrt((X[i] - X[j]) ** 2 + (Y[i] - Y[j]) ** 2)

    def force(i, C):  # C = X for Fx, Y for Fy
        f = sp.S.Zero
        if i < p * p:
            i1, i2 = i % p, i // p
            j = p * p + (i2 - 1) * (p - 1) + (i1 - 1)  # small mass at south-west
            neighbours = [(i1 > 0, i - 1, h), (i1 < p - 1, i + 1, h), (i2 > 0, i - p, h),
                          (i2 < p - 1, i + p, h)]
            even = (i1 + i2) % 2 == 0
            neighbours += [(i1 > 0 and i2 > 0 and even, j, hsmall),
                           (i1 < p - 1 and i2 > 0 and even, j + 1, hsmall),
                           (i1 > 0 and i2 < p - 1 and even, j + p - 1, hsmall),
                           (i1 < p - 1 and i2 < p - 1 and even, j + p - 1 + 1, hsmall)]
        else:
            i1, i2 = (i - p * p) % (p - 1), (i - p * p) // (p - 1)
            j = i2 * p + i1  # large mass at south-west
            even = (i1 + i2) % 2 == 0
            neighbours = [(even, j, hsmall), (not even, j + 1, hsmall), (not even, j + p, hsmall),
                          (even, j + p + 1, hsmall)]
        for present, other, rest in neighbours:
            if present:
                r = dist(i, other)
                f += (r - rest) * (C[other] - C[i]) / r
        return f

    def mass(i):
        return M if i < p * p else m

    x0, y0 = [], []
    for i in range(n):
        if i < p * p:
            x0.append(float(i % p) * h)
            y0.append(float(i // p) * h)
        else:
            c1, c2 = (i - p * p) % (p - 1), (i - p * p) // (p - 1)
            dx = 0.25 * h if c1 % 2 == 0 else -0.25 * h
            dy = -0.25 * h if c2 % 2 == 0 else 0.25 * h
            x0.append(0.5 * h + float(c1) * h + dx)
            y0.append(0.5 * h + float(c2) * h + dy)
    accelerations, positions0 = {}, {}
    for i in range(n):
        accelerations[X[i]] = force(i, X) / mass(i)
        accelerations[Y[i]] = force(i, Y) / mass(i)
        positions0[X[i]], positions0[Y[i]] = x0[i], y0[i]
    return dn.ODE.second_order(accelerations, x0=positions0, v0=dict.fromkeys(positions0, 0.0),
                               T=10.0)


@pytest.mark.parametrize("p", [2, 4])  # 4: interior masses of both parities
def test_lattice_reproduces_the_per_expression_lattice(p):
    built, reference = dn.systems.lattice(p), dolfin_lattice(p)
    assert built.N == reference.N == 4 * (p * p + (p - 1) ** 2)
    assert [s.name for s in built.states] == [s.name for s in reference.states]
    np.testing.assert_array_equal(built.u0, reference.u0)
    cb, cr = lower(built), lower(reference)
    np.testing.assert_array_equal(cb.indptr, cr.indptr)
    np.testing.assert_array_equal(cb.indices, cr.indices)
    rng = np.random.default_rng(p)
    for u in [built.u0, built.u0 + 0.01 * rng.normal(size=built.N)]:
        fb, fr = cb.f(u, 0.0), cr.f(u, 0.0)
        scale = np.abs(fr).max()
        np.testing.assert_allclose(fb, fr, rtol=1e-13, atol=1e-14 * scale)
        Jb, Jr = cb.jacobian_matrix(u, 0.0), cr.jacobian_matrix(u, 0.0)
        np.testing.assert_allclose(Jb.data, Jr.data, rtol=1e-12, atol=1e-13 * abs(Jr.data).max())


def test_lattice_solution_equals_per_expression_solution():
    built, reference = dn.systems.lattice(3, m=1e-2), dolfin_lattice(3, m=1e-2)
    kwargs = {"tolerance": 1e-6, "number_of_samples": 3}
    for ode in (built, reference):
        ode.T = 0.05
    sb, sr = dn.solve(built, "cG(1)", **kwargs), dn.solve(reference, "cG(1)", **kwargs)
    np.testing.assert_allclose(sb.y, sr.y, rtol=1e-9, atol=1e-12)


def _lattice_demo():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[2] / "demos" / "lattice.py"
    spec = importlib.util.spec_from_file_location("demo_lattice", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_lattice_demo_reproduces_the_per_expression_lattice():
    """demos/lattice.py declares the lattice with the builder; the term-by-term transcription
    of DOLFIN's demo gives the same f, Jacobian and solution (issue 7). The per-expression
    systems are those of the tests above, so their kernels are compiled once."""
    demo = _lattice_demo()
    lat, reference = demo.lattice(4), dolfin_lattice(4)
    np.testing.assert_array_equal(lat.ode.u0, reference.u0)
    np.testing.assert_array_equal(lat.points.ravel(), reference.u0[:reference.N // 2])
    cb, cr = lower(lat.ode), lower(reference)
    np.testing.assert_array_equal(cb.indptr, cr.indptr)
    np.testing.assert_array_equal(cb.indices, cr.indices)
    u = lat.ode.u0 + 0.01 * np.random.default_rng(0).normal(size=lat.ode.N)
    fr = cr.f(u, 0.0)
    np.testing.assert_allclose(cb.f(u, 0.0), fr, rtol=1e-13, atol=1e-14 * np.abs(fr).max())
    Jb, Jr = cb.jacobian_matrix(u, 0.0), cr.jacobian_matrix(u, 0.0).tocsr()
    np.testing.assert_allclose(Jb.data, Jr.data, rtol=1e-12, atol=1e-13 * np.abs(Jr.data).max())
    # the demo's springs join the particles whose accelerations depend on each other
    half = reference.N // 2
    coupled = {(i, int(j)) for i in range(len(lat.points))
               for j in np.unique(Jr[half + 2 * i].indices // 2) if i < j < len(lat.points)}
    assert {tuple(sorted(map(int, e))) for e in lat.springs} == coupled
    assert list(lat.small) == list(range(16, 25))
    small, reference = demo.lattice(3, m=1e-2, T=0.05), dolfin_lattice(3, m=1e-2)
    reference.T = 0.05
    kwargs = {"tolerance": 1e-6, "number_of_samples": 3}
    sb, sr = dn.solve(small.ode, "cG(1)", **kwargs), dn.solve(reference, "cG(1)", **kwargs)
    np.testing.assert_allclose(sb.y, sr.y, rtol=1e-9, atol=1e-12)


def test_lattice_geometry():
    ode = dn.systems.lattice(5)
    n = 25 + 16
    x = ode.u0[:2 * n].reshape(n, 2)
    np.testing.assert_allclose(x[:25], np.column_stack([np.tile(np.arange(5), 5),
                                                        np.repeat(np.arange(5), 5)]) / 4)
    np.testing.assert_allclose(x[25], [0.125 + 0.0625, 0.125 - 0.0625])  # cell (0, 0)
    np.testing.assert_allclose(x[26], [0.375 - 0.0625, 0.125 - 0.0625])  # cell (1, 0)
    np.testing.assert_allclose(x[29], [0.125 + 0.0625, 0.375 + 0.0625])  # cell (0, 1)
    assert not ode.u0[2 * n:].any()
    springs = ode.templates[1]
    assert springs.cells == 2 * 5 * 4 + 2 * 16
    np.testing.assert_allclose(np.sort(np.unique(springs.values[:, 1])),
                               [np.sqrt(2) / 8, 0.25])


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_two_body_spring_with_gravity_matches_newton(dim):
    g = sp.Symbol("g")
    x0 = np.zeros((2, dim))
    x0[1, 0] = 1.5
    ps = dn.ParticleSystem(x0, velocities=np.ones((2, dim)), masses=[1.0, 2.0])
    ps.add_springs([[0, 1]], stiffness=3.0, rest_length=1.0)
    ps.add_force([0] * (dim - 1) + [-g], particles=[1])
    ode = ps.ode(T=1.0, params={g: 9.81})
    assert ode.N == 4 * dim and ode.states[2 * dim].name == "x_0_dot"
    u = np.random.default_rng(dim).normal(size=ode.N)
    X, V = u[:2 * dim].reshape(2, dim), u[2 * dim:]
    d = X[1] - X[0]
    r = np.linalg.norm(d)
    F = 3.0 * (r - 1.0) * d / r
    gravity = np.zeros(dim)
    gravity[-1] = -9.81
    expected = np.concatenate([V, F / 1.0, (-F + gravity) / 2.0])  # gravity is a force
    np.testing.assert_allclose(lower(ode).f(u, 0.0), expected, rtol=1e-13)


def test_spring_at_rest_by_default_and_energy_conserved():
    ps = dn.ParticleSystem([[0.0, 0.0], [1.0, 0.5], [0.2, 1.1]], masses=[1.0, 2.0, 0.5],
                           velocities=[[0.1, 0.0], [0.0, -0.2], [0.3, 0.1]])
    ps.add_springs([[0, 1], [1, 2], [2, 0]], stiffness=[1.0, 2.0, 3.0])
    ode = ps.ode(T=2.0)
    assert not lower(ode).f(ode.u0, 0.0)[6:].any()  # rest lengths = initial distances
    sol = dn.solve(ode, "cG(2)", tolerance=1e-8)

    def energy(u):
        X, V = u[:6].reshape(3, 2), u[6:].reshape(3, 2)
        kinetic = 0.5 * np.sum(ps.masses * np.sum(V * V, axis=1))
        springs = ode.templates[1]
        pairs = np.array([[0, 1], [1, 2], [2, 0]])
        r = np.linalg.norm(X[pairs[:, 1]] - X[pairs[:, 0]], axis=1)
        return kinetic + 0.5 * np.sum(springs.values[:, 0] * (r - springs.values[:, 1]) ** 2)

    assert abs(energy(sol(2.0)) - energy(ode.u0)) < 1e-6 * energy(ode.u0)


def test_bad_particle_systems_are_rejected():
    with pytest.raises(ValueError, match="dim 1, 2 or 3"):
        dn.ParticleSystem(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="masses must be positive"):
        dn.ParticleSystem(np.zeros((2, 2)), masses=[1.0, 0.0])
    with pytest.raises(ValueError, match="one number or 2 numbers"):
        dn.ParticleSystem(np.zeros((2, 2)), masses=[1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="shape of positions"):
        dn.ParticleSystem(np.zeros((2, 2)), velocities=np.zeros((2, 3)))
    ps = dn.ParticleSystem(np.eye(2))
    with pytest.raises(ValueError, match="particle 2, outside"):
        ps.add_springs([[0, 2]])
    with pytest.raises(ValueError, match="to itself"):
        ps.add_springs([[1, 1]])
    with pytest.raises(ValueError, match=r"shape \(E, 2\)"):
        ps.add_springs([[0, 1, 1]])
    with pytest.raises(ValueError, match="non-negative"):
        ps.add_springs([[0, 1]], stiffness=-1.0)
    with pytest.raises(ValueError, match="2 components"):
        ps.add_force([1.0])
    with pytest.raises(ValueError, match="p >= 2"):
        dn.systems.lattice(1)


@pytest.fixture(scope="module")
def lattice_reference():
    """The lattice demo with p = 10 (N = 724) over a few periods of the small masses, and a
    DOP853 reference solution at T."""
    from scipy.integrate import solve_ivp

    ode = dn.systems.lattice(10, T=4e-6)
    compiled = lower(ode)
    ref = solve_ivp(lambda t, u: compiled.f(u, t), (0.0, ode.T), ode.u0, method="DOP853",
                    rtol=1e-11, atol=1e-13)
    large = np.r_[np.arange(200), 2 * 181 + np.arange(200)]  # x, y and velocities of M's
    return ode, ref.y[:, -1], large


@pytest.mark.parametrize("method", ["mcG(1)", "mdG(1)"])
def test_multi_adaptive_on_the_lattice(lattice_reference, method):
    """mcG(1)/mdG(1) on the template lattice: accurate against DOP853 and, for mcG(1), with far
    fewer elements for the large masses (omega ~ 0.1) than the small ones (omega ~ 1.4e6)."""
    ode, exact, large = lattice_reference
    sol = dn.solve(ode, method, tolerance=1e-4, number_of_samples=2)
    scale = np.abs(exact - ode.u0).max()  # velocities of the small masses, ~ 1e4
    error = np.abs(sol(ode.T) - exact).max() / scale
    mono = dn.solve(ode, method[1:], tolerance=1e-4, number_of_samples=2)
    mono_error = np.abs(mono(ode.T) - exact).max() / scale
    assert error < 1e-2 and error < 3 * mono_error + 1e-5
    per_component = sol.stats["elements per component"]
    assert per_component.min() >= 1 and per_component.sum() == sol.stats["elements"]
    if method == "mcG(1)":
        small = np.setdiff1d(np.arange(ode.N), large)
        assert np.median(per_component[large]) * 4 < np.median(per_component[small])
