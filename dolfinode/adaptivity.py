"""Step-size selection from the Galerkin residual, for mono-adaptive time slabs.

The indicator of an element of length k is (Eriksson-Estep-Hansbo-Johnson, the seed paper's
error representation with stability factor and interpolation constant taken as one)

    eps = max_i k^p |R_i| / (atol_i + rtol |U_i(t_n)|),
    R_i = U_i'(t_n) - f_i(U(t_n), t_n)  (+ |[U_i]_{n-1}| / k for dG),

with p = q (cG) or q + 1 (dG), so that eps = O(k^(2q)) or O(k^(2q+1)) and the global error is
about S * rtol * max eps. A step is accepted when eps <= 1. The next step comes from a PI
controller on eps (Gustafsson; Soederlind's digital filters, as DOLFIN's H211PI intended):

    k_new = k * clamp(safety * eps^(-0.7/P) * eps_prev^(0.4/P), 0.2, 5),   P = 2q or 2q + 1.
"""
import math

from numba import njit

#: Smallest and largest factor by which a step may change.
MIN_FACTOR = 0.2
MAX_FACTOR = 5.0


@njit(cache=True)
def next_step(k, eps, eps_prev, order, safety, accepted):
    """Next step length after a step of length k with indicator eps (<= 1: accepted)."""
    eps = max(eps, 1e-10)
    if accepted:
        factor = safety * eps ** (-0.7 / order) * max(eps_prev, 1e-10) ** (0.4 / order)
    else:
        factor = safety * eps ** (-1.0 / order)
    if not math.isfinite(factor):
        factor = MIN_FACTOR
    return k * min(MAX_FACTOR, max(MIN_FACTOR, factor))
