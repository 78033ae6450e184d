"""The work counters of a solve: one int64 array that the time-slab loops and the nonlinear
solvers increment and the driver turns into ``Solution.stats`` (indices below).

OUTSIDE: the component that left its declared domain (status CONSTRAINT), plus one. Its own
module, so that :mod:`dolfinode.solvers` and :mod:`dolfinode.timeslab` both read it and
neither imports the other's package for it. SYNCHRONISED: the multi-adaptive slabs solved as
one mono-adaptive slab (every component on one step). STORED_BLOCKS: the multi-adaptive slabs
with every component on one step stored as blocks in the loop's last call
(:mod:`dolfinode.io.history`), beside the STORED elements.
"""
SLABS, REJECTED, F_EVALUATIONS, JACOBIANS, FACTORIZATIONS, ITERATIONS, STORED, FAILED_SOLVES, \
    STIFF, ELEMENTS, SUBSLABS, OUTSIDE, SYNCHRONISED, STORED_BLOCKS = range(14)
NUM_COUNTERS = 14
