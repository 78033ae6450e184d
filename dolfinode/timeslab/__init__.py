"""Time slabs: the compiled loops that build, solve and check one slab after another.

The constants below are shared by the mono- and multi-adaptive loops, the nonlinear solvers
and the driver, so every counter and status code has one index.
"""

# Indices into the integer counters (kept across calls by the driver). OUTSIDE: the component
# that left its declared domain (see CONSTRAINT), plus one.
SLABS, REJECTED, F_EVALUATIONS, JACOBIANS, FACTORIZATIONS, ITERATIONS, STORED, FAILED_SOLVES, \
    STIFF, ELEMENTS, SUBSLABS, OUTSIDE = range(12)
NUM_COUNTERS = 12
# Return codes of the loops (NEWTON_NEEDED: mono only, Newton needed but its matrices are not
# ready: their storage is decided when first needed, or they do not fit in memory;
# CONSTRAINT: a component declared nonnegative fell below its floor however short the step, or
# the right-hand side drives it below zero from zero).
DONE, FULL, NONCONVERGENCE, BLOWUP, UNDERFLOW, NEWTON_NEEDED, CONSTRAINT = range(7)
# Nonlinear solver modes, in the order of parameters.NONLINEAR_SOLVERS.
DEFAULT, FIXED_POINT, NEWTON = range(3)
#: Relative size of the smallest increment an iteration still resolves (about 50 ulp).
ROUNDING = 1e-14
#: Factor by which a step is shortened when a component leaves its declared domain.
CONSTRAINT_CUT = 0.5
