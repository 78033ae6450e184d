"""The ODEs of automatic modeling: the full model in a window's local time."""
import numpy as np
import sympy as sp

import dolfinode as dn
from dolfinode.compile import lower
from dolfinode.modeling.declaration import ReducedDeclaration, WindowModel


def test_pieces_of_one_window_share_their_lowering():
    """Declarations with the same shift (the pieces of one window) share the kernels, the
    parameters and the band ordering; another shift is lowered on its own."""
    ode = dn.systems.lattice(3, T=1.0)
    window = WindowModel(ode)
    first = window.declaration(ode.u0, 0.0, 1e-3, 2.0)
    compiled = lower(first)
    ordering = compiled.ordering  # as a solve of the first piece computes it
    piece = window.declaration(2 * ode.u0, 1e-3, 2e-3, 2.0)
    again = lower(piece)
    assert again.ordering is ordering and np.array_equal(again.p, compiled.p)
    np.testing.assert_array_equal(piece.u0, 2 * ode.u0)
    assert (piece.t0, piece.T) == (1e-3, 2e-3)
    other = lower(window.declaration(ode.u0, 0.0, 1e-3, 3.0))
    assert other.p is not compiled.p and not np.array_equal(other.p, compiled.p)
    t = 0.5e-3
    np.testing.assert_allclose(other.f(ode.u0, t), lower(ode).f(ode.u0, t + 3.0))


def test_declarations_keep_the_nonnegative_components():
    """The window and reduced ODEs carry the declaration; their initial values (averages,
    with the kernel's negative lobes) are set to max(u0, 0) on those components."""
    a, b = sp.symbols("a b")
    ode = dn.ODE({a: -a + b, b: -1e3 * b}, u0=[1.0, 1.0], T=1.0, nonnegative=[b])
    u0 = np.array([-0.5, -1e-9])
    window = WindowModel(ode).declaration(u0, 0.0, 1e-3, 0.5)
    reduced = ReducedDeclaration(ode, active=[True, False]).declaration(u0, 0.5, 1.0, np.zeros(2))
    for declared in (window, reduced):
        assert declared.nonnegative.tolist() == [False, True]
        assert declared.u0.tolist() == [-0.5, 0.0]
