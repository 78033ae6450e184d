"""The dual problem, a posteriori error estimates of goals, and goal-oriented adaptivity."""
from dolfinode.dual.estimate import ErrorEstimate, estimate_error
from dolfinode.dual.goal import Goal
from dolfinode.dual.problem import DualSolution, solve_dual

__all__ = ["DualSolution", "ErrorEstimate", "Goal", "estimate_error", "solve_dual"]
