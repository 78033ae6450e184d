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


def oscillator_bank(n=50, w=1000.0, T=1.0, eps=1e-2):
    """n slow oscillators of frequencies 1..2 (evenly spaced) and one of frequency w, coupled
    to the first by eps:

        x_j'' = -omega_j^2 x_j (+ eps x_f for j = 1),  x_f'' = -w^2 x_f + eps x_1,
        x(0) = 1, v(0) = 0;

    every oscillator starts displaced, so the spread of time scales (w against 1..2) is
    there from t0, the case where ``method="auto"`` must pick the multi-adaptive variant.
    Linear: the exact solution is the matrix exponential."""
    A = np.zeros((2 * n + 2, 2 * n + 2))
    for j, omega in enumerate(np.linspace(1.0, 2.0, n)):
        A[2 * j, 2 * j + 1], A[2 * j + 1, 2 * j] = 1.0, -omega**2
    A[2 * n, 2 * n + 1], A[2 * n + 1, 2 * n] = 1.0, -w**2
    A[1, 2 * n] = A[2 * n + 1, 0] = eps
    u0 = np.zeros(2 * n + 2)
    u0[::2] = 1.0
    ode, exact = linear(A, u0, T, name="x")
    return Problem("oscillator bank", ode, stiff=False, final=exact(T), exact=exact,
                   multiscale=True, reference="matrix exponential (linear system)",
                   description=f"{n} oscillators of frequencies 1..2 and one of {w:g}, "
                               f"coupling {eps:g}, T = {T:g}")


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
