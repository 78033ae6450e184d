"""Multi-adaptive benchmark problems: a few fast components among many slow ones.

These are the problems of ``benchmarks/run_multiadaptive.py`` (mcG(q)/mdG(q) against
cG(q)/dG(q) and scipy). They are not in the default suite (:data:`~dolfinode.bench.problems.PROBLEMS`)
but are found by :func:`~dolfinode.bench.problems.get_problem`, so ``dolfinode bench --problems
oscillators`` runs them.
"""
import numpy as np

from dolfinode.bench.problems import Problem, linear, mass_spring_chain, reaction_front


def coupled_oscillators(eps=1e-3, w=1000.0, T=10.0):
    """Two weakly coupled oscillators of frequencies 1 and w:

        x1'' = -x1 + eps (x2 - x1),  x2'' = -w^2 x2 + eps (x1 - x2),
        (x1, v1, x2, v2)(0) = (1, 0, 1, 0);

    linear, so the exact solution is the matrix exponential."""
    A = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-1.0 - eps, 0.0, eps, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [eps, 0.0, -w**2 - eps, 0.0]])
    ode, exact = linear(A, [1.0, 0.0, 1.0, 0.0], T, name="x")
    return Problem("oscillators", ode, stiff=False, final=exact(T), exact=exact, multiscale=True,
                   reference="matrix exponential (linear system)",
                   description=f"two oscillators, frequencies 1 and {w:g}, coupling {eps:g}, "
                               f"T = {T:g}")


def _renamed(problem, name):
    problem.name = name
    return problem


#: Builders of the multi-adaptive problems by name (called without arguments).
MULTIADAPTIVE_PROBLEMS = {
    "oscillators": coupled_oscillators,
    # T = 0.1 (22 periods of the fast springs) as in benchmarks/run_chain.py: at T = 10 mcG(1)
    # alone ran for over 9 minutes at tolerance 1e-4
    "chain-stiff": lambda: _renamed(mass_spring_chain(n=200, stiffness=1e6, stiff_springs=10,
                                                      T=0.1), "chain-stiff"),
    # the same chain with springs 1e4 times stiffer: T = 1 holds the same 22 fast periods
    "chain-1e4": lambda: _renamed(mass_spring_chain(n=200, stiffness=1e4, stiff_springs=10,
                                                    T=1.0), "chain-1e4"),
    "reaction-500": lambda: _renamed(reaction_front(n=500, T=0.05), "reaction-500"),
}
