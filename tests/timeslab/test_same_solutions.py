"""The loops give the same solutions as the recorded ones: counts exactly, u(T) to 1e-12.

The expected values come from ``tests/timeslab/regenerate.py`` (see there); a restructure of
the time-slab loops must not change them. A change of the algorithm itself regenerates them.
"""
import json

import numpy as np
import pytest
from regenerate import DATA, cases, record

EXPECTED = json.loads(DATA.read_text())
CASES = cases()


@pytest.mark.parametrize("name, method", [(name, method) for name in EXPECTED
                                          for method in EXPECTED[name]])
def test_same_counts_and_final_value(name, method):
    ode, tolerance = CASES[name]
    expected = EXPECTED[name][method]
    got = record(ode, method, tolerance)
    assert {k: v for k, v in got.items() if k != "u(T)"} == {
        k: v for k, v in expected.items() if k != "u(T)"}
    np.testing.assert_allclose(got["u(T)"], expected["u(T)"], rtol=1e-12, atol=1e-300)
