"""Compiled linear algebra for the Newton solvers, and when a sparse LU is faster."""
from dolfinode.linalg.banded import band_lu, band_solve, band_storage, bandwidth_ordering
from dolfinode.linalg.sparse import wide_band

__all__ = ["band_lu", "band_solve", "band_storage", "bandwidth_ordering", "wide_band"]
