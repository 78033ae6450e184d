"""Compiled linear algebra for the Newton solvers."""
from dolfinode.linalg.banded import band_lu, band_solve, band_storage, bandwidth_ordering

__all__ = ["band_lu", "band_solve", "band_storage", "bandwidth_ordering"]
