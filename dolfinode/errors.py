"""Exceptions raised by dolfinode."""


class SolverError(RuntimeError):
    """A solve that cannot continue: non-convergence, step size underflow or blow-up.

    Attributes
    ----------
    t : float
        The time reached when the solver stopped.
    success, status, message : False, -1 and the message, as a failed ``solve_ivp`` result
        (so that the members of ``solve_ensemble(..., return_exceptions=True)`` all have them).
    """

    success = False
    status = -1

    def __init__(self, message, t=None):
        super().__init__(message)
        self.t = t

    @property
    def message(self):
        return str(self)


class OutOfMemoryError(SolverError, MemoryError):
    """A solve that ran out of the memory available to the process: a SolverError whose
    message says what to change (``dense_output``, ``reduce=`` of an ensemble), and a
    MemoryError for code that catches that."""


class ModelingWarning(UserWarning):
    """Automatic modeling whose reduced model may not represent the full one: its a posteriori
    error estimate, or a defect found at a control point times the span it acted on, exceeds
    the tolerance (see :mod:`dolfinode.modeling.validity`; ``strict=True`` raises
    :class:`SolverError` instead)."""


class ToleranceWarning(UserWarning):
    """A solve whose error at T may exceed the tolerance although every step met its
    estimate: the calibrated tolerance (see :func:`dolfinode.solve`) was measured not to hold
    in the regime the run reached (:func:`dolfinode.adaptivity.undamped_warning`)."""
