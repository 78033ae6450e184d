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
