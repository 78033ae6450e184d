"""Automatic modeling on the seed paper's lattice (demos/lattice.py): p = 5, 25 large masses
M = 100 and 16 small masses m = 1e-4, 164 components (positions and velocities in 2-D)."""
import importlib.util
from pathlib import Path

import numpy as np

import dolfinode as dn

DEMO = Path(__file__).parents[2] / "demos" / "lattice.py"


def _lattice_module():
    spec = importlib.util.spec_from_file_location("demo_lattice", DEMO)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_inactivated_components_are_exactly_the_fast_ones():
    """The 64 components of the small masses (x, y and their velocities) are inactivated and
    no other: large masses whose average does not move over the window (the middle of an
    edge moves along the edge only) are slow and stay active."""
    lat = _lattice_module().lattice(5, m=1e-4, T=5.0)
    sol = dn.solve(lat.ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                   average_length=1.0, control_points=0)
    n = len(lat.points)
    small = set(lat.small)
    fast = {s for i, s in enumerate(lat.ode.states) if i % n in small}
    assert len(fast) == 4 * 16
    assert set(sol.model.inactive) == fast
    # the large masses keep moving: the lattice contracts (D(5) < D(0) = sqrt 2)
    assert lat.diameter(sol(5.0)[:, None])[0] < np.sqrt(2) - 1e-3
