"""Multi-adaptive time slabs: mcG(q) and mdG(q) with individual time steps per component.

Slabs are built by :mod:`dolfinode.timeslab.partition`. The Galerkin equations of every
element, xi = x_left + k M^{-1} m with the moments m_l = int f_i(U) tau^l, are solved by
Gauss-Seidel sweeps, each element update damped by its own Newton matrix
(I - k J_ii A)^{-1} so that components stiff on their own step converge. The moments are
integrated exactly (for linear f) by the method's quadrature on every interval between the
element ends of the dependencies, each dependency read from its own element polynomial
(interpolated from larger elements, the exact small elements inside a larger one) through
cursors that walk its elements in time order: sampling a large element only at its own nodes
would alias the fast forcing of small ones and lose the 2q / 2q + 1 nodal order.

A slab is solved window by window (the sub-slabs nested in each top-level sub-slab, in time
order), then the top level, each to convergence; the global iteration stops when the
windows' response to the top level's change is below the discrete tolerance. The slab length
limit climbs on the measured cost per unit time (``steps.slab_limit``). When Gauss-Seidel fails
or converges too slowly the problem is treated as stiff, and the elements of each sub-slab
(one interval, several components) are updated together by a simplified Newton step with the
sparse sympy Jacobian at the slab start restricted to them, split by the eigenstructure of
the stage matrix into n x n band systems as in the mono-adaptive loop, and factored once for
all the sub-slabs and sweeps with the same components and step.

A slab whose partition would save little (it takes at least a quarter of the elements of
every component on the smallest desired step, ``loop.SYNCHRONISE``; an eighth after a
synchronised slab) is synchronised: every active component on that step, solved as one
mono-adaptive slab by the mono loop's fixed-point iteration with the whole system's f
(``sweeps.synchronised``; the element equations with equal steps are cG(q)'s and dG(q)'s), at
a fraction of the cost of component kernels and moments per element. Its residuals are not filtered
(fixed point converged: not stiff), and a component held below its own desired step scales its
estimate to that step, so that the slabs return to the partition when the steps spread again. Stiff
slabs (Newton) and slabs with frozen components keep the element-wise solve.

Components at rest are frozen (``freezing.freeze``): no elements, the constant x_i for the others,
until they drift; then their constant element over the whole span is stored. After a slab the
frozen components that read an active one (all of them for non-autonomous f) are checked by
one evaluation of f_i at the slab end.

After a slab, every element's residual R = U' - f_i(U) at its end gives the local error
estimate of :mod:`dolfinode.adaptivity` (order q + 1 for mcG(q) and mdG(q)), filtered on each
sub-slab, (I - gamma k J_gg)^{-1} k R (:func:`dolfinode.adaptivity.filter_residuals`), and scaled by
atol + rtol max |U_i| over the slab; the slab is accepted when all are <= ACCEPTANCE_MARGIN,
and each component gets its own next step. Unfiltered, k |R| of a stiff component is
k |lambda| times its distance from the quasi-steady state: mcG(2) needs millions of slabs on
ROBER to 1e11 without the filter, about a thousand with it. DOLFIN's indicators k^q |R| (mcG) and
k^(q+1) |R| (mdG) depend on the unit of time: for q >= 2 and k < 1 they let fast components
step over their oscillation (mcG(3) on the stiff chain: 15x too long steps, errors
10^3-10^5 x tolerance), and mdG(1) reached 2600x the error of dG(1) on the template lattice.

Modules, in the order a slab goes through them: :mod:`dolfinode.timeslab.partition` builds
it; :mod:`.slab` solves it (the initial guess, the synchronised path, the sweep driver);
:mod:`.moments` integrates f_i(U) on an element; :mod:`.sweeps` holds the Gauss-Seidel sweeps
and the group Newton step over a sub-slab with the band matrices of
:mod:`dolfinode.linalg.group`; :mod:`.control` estimates the error of every component
(filtered by :mod:`dolfinode.adaptivity`), accepts or rejects and chooses the next steps;
:mod:`.steps` ties and grades them along couplings and limits the slab length;
:mod:`.freezing` freezes, checks and wakes components; :mod:`.loop` runs it all
(:data:`advance`) and holds the work space. The driver passes the options and state of
:mod:`dolfinode.timeslab.contract`.
"""
from dolfinode.timeslab.multi.loop import advance, carry, grown, method_tables  # noqa: F401
