"""When to leave the banded LU for a sparse one: a criterion measured on stage systems.

The banded LU of :mod:`dolfinode.linalg.banded` costs O(n b^2) for n unknowns and band b; on
chains b is a few, on 2-D lattices it grows like sqrt(N) and a fill-reducing sparse LU
(scipy's SuperLU) is much faster. The Python loop around a sparse factorisation costs a
fixed overhead per system, so small systems stay banded.
"""


#: splu is used when the stage matrix's band r (kl + ku + 2) exceeds this ...
SPARSE_BAND = 200
#: ... and it has at least this many unknowns (below, the Python loop over intervals of the
#: sparse path costs more than the factorisations).
SPARSE_MINIMUM = 1000


def wide_band(n_unknowns, band):
    """Whether a stage system I - h (A (x) I) diag(J_m) with ``n_unknowns`` = r N unknowns and
    total band ``band`` (in the Jacobian's bandwidth ordering) is solved faster by scipy's
    splu than by the compiled banded LU of :mod:`dolfinode.linalg.banded`.

    Measured on the dual's per-interval stage systems (CPU, cG(3), 2026-11-23): the banded
    LU costs about 0.2 us + 3.5e-11 band^2 s per unknown, splu 1-8 us per unknown (1-D
    chains to 2-D lattices). On chains (band 18) the banded LU is 3-7x faster (N = 100 to
    5000); on the 2-D lattice (band 354-1776) splu is 1.6x faster at N = 164, 7x at
    N = 724, 19x at N = 3044 and 18x at N = 6964 (2.3 s against 0.13 s), on a 60 x 60
    reaction-diffusion grid (r = 4, band 488) 4.6x; see doc/benchmarks/dual_lu.md
    (benchmarks/run_dual_lu.py). The crossover, 3.5e-11 band^2 ~ 1-3 us, is at a band of
    170-290. A re-run on 2026-11-24 (same code) found the banded LU about 2x faster against
    splu (the shared machine's state): 0.75x splu's time at N = 164, 3.8-7.1x on the larger
    lattices, 1.6x on the reaction-diffusion grid; every choice stays the faster one.
    """
    return n_unknowns >= SPARSE_MINIMUM and band > SPARSE_BAND
