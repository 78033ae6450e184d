"""Time slabs: the compiled loops that build, solve and check one slab after another.

The constants below are shared by the mono- and multi-adaptive loops and the driver: the
return codes, the nonlinear solver modes and the smallest resolvable step. The loops'
options and state are the named records of :mod:`dolfinode.timeslab.contract`; the work
counters live in :mod:`dolfinode.counters`.
"""
from dolfinode.compile.jit import helper

# The work counters (indices, re-exported: their home is dolfinode.counters).
from dolfinode.counters import (  # noqa: F401
    ELEMENTS,
    F_EVALUATIONS,
    FACTORIZATIONS,
    FAILED_SOLVES,
    ITERATIONS,
    JACOBIANS,
    NUM_COUNTERS,
    OUTSIDE,
    REJECTED,
    SLABS,
    STIFF,
    STORED,
    STORED_BLOCKS,
    SUBSLABS,
    SYNCHRONISED,
)

# Return codes of the loops (NEWTON_NEEDED: mono only, Newton needed but its matrices are not
# ready: their storage is decided when first needed, or they do not fit in memory;
# CONSTRAINT: a component declared nonnegative fell below its floor however short the step, or
# the right-hand side drives it below zero from zero).
DONE, FULL, NONCONVERGENCE, BLOWUP, UNDERFLOW, NEWTON_NEEDED, CONSTRAINT = range(7)
# Nonlinear solver modes, in the order of parameters.NONLINEAR_SOLVERS.
DEFAULT, FIXED_POINT, NEWTON = range(3)
#: Relative size of the smallest increment an iteration still resolves (about 50 ulp).
ROUNDING = 1e-14
#: A step collapsing near t = 0 (where every step is resolvable) stops at STEP_FLOOR
#: min(span, 1): far below any step a problem needs (kinetics on [0, 1e13] start at 1e-9).
STEP_FLOOR = 1e-20


@helper()
def smallest_step(t, span):
    """The smallest step double precision resolves at the time t: ROUNDING |t| (t + k must
    differ from t by some 50 ulp), plus the floor STEP_FLOOR min(span, 1) near t = 0."""
    return ROUNDING * abs(t) + STEP_FLOOR * min(span, 1.0)
#: Factor by which a step is shortened when a component leaves its declared domain.
CONSTRAINT_CUT = 0.5
