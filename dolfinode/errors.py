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
    error estimate, or a defect found at a control point times the span it acted on, exceeds
    the tolerance (see :mod:`dolfinode.modeling.validity`; ``strict=True`` raises
    :class:`SolverError` instead)."""
