"""Reference problems, kept under this name for the demos and tests.

The problems now live in :mod:`dolfinode.bench.problems` with the rest of the benchmark set;
this module re-exports the small ones.
"""
from dolfinode.bench.problems import (  # noqa: F401
    HIRES_REFERENCE,
    harmonic,
    hires,
    lorenz,
    mescd,
    stiff_decay,
    stiff_suite,
)
