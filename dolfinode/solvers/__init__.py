"""Nonlinear solvers for the discrete equations on a time slab."""
