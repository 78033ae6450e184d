"""Exceptions raised by dolfinode."""


class SolverError(RuntimeError):
    """A solve that cannot continue: non-convergence, step size underflow or blow-up.

    Attributes
    ----------
    t : float
        The time reached when the solver stopped.
    """

    def __init__(self, message, t=None):
        super().__init__(message)
        self.t = t


class ModelingWarning(UserWarning):
    """Automatic modeling whose reduced model may not represent the full one: its a posteriori
    error estimate exceeds the tolerance, or its last control point found a defect above
    model_tolerance (see :mod:`dolfinode.modeling.validity`)."""
