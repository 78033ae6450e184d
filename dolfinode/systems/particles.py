"""Particle (mass-spring) systems in 1, 2 or 3 dimensions, built on templates.

Newton's second law for n particles with positions x_i in R^d, velocities v_i and masses m_i,

    x_i' = v_i,
    v_i' = (1 / m_i) (sum_{springs (i, j)} k_ij (r_ij - L_ij) (x_j - x_i) / r_ij + F_i(x_i, v_i, t)),

with r_ij = |x_j - x_i|, stiffness k_ij and rest length L_ij. The state is ordered as in
DOLFIN's ParticleSystem and :meth:`dolfinode.ODE.second_order`: all positions (x_0, y_0,
z_0, x_1, ...), then all velocities in the same order. Each spring, each external force
and the kinematics x' = v are one :class:`~dolfinode.systems.template.Template` each, so the
generated code is the same for every number of particles.
"""
from collections.abc import Sequence

import numpy as np
import sympy as sp

from dolfinode.systems.template import Template, TemplateODE, spells_index

_AXES = "xyz"


class ParticleNames(Sequence):
    """State names of a particle system: x_i, y_i, z_i, then x_i_dot, y_i_dot, z_i_dot."""

    def __init__(self, n, dim):
        self.n, self.dim = int(n), int(dim)

    def __len__(self):
        return 2 * self.n * self.dim

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(len(self)))]
        if not -len(self) <= k < len(self):
            raise IndexError(f"state {k} out of range for {len(self)} states")
        velocity, rest = divmod(k % len(self), self.n * self.dim)
        particle, axis = divmod(rest, self.dim)
        return f"{_AXES[axis]}_{particle}" + ("_dot" if velocity else "")

    def __contains__(self, name):
        # parsed, not searched: Sequence's default would build the 2 n dim names
        name = str(name).removesuffix("_dot")
        axis, _, particle = name.partition("_")
        return axis in _AXES[:self.dim] and len(axis) == 1 and spells_index(particle, self.n)


def _local(dim, suffix=""):
    return (sp.symbols(" ".join(f"{a}{suffix}" for a in _AXES[:dim]), real=True, seq=True),
            sp.symbols(" ".join(f"v{a}{suffix}" for a in _AXES[:dim]), real=True, seq=True))


class ParticleSystem:
    """Builder of a mass-spring system; :meth:`ode` returns its :class:`TemplateODE`.

    Parameters
    ----------
    positions : array_like, shape (n, dim)
        Initial positions, dim = 1, 2 or 3 (shape (n,) means dim = 1).
    velocities : array_like, shape (n, dim), optional
        Initial velocities (default zero).
    masses : float or array_like, shape (n,)
        Positive masses.

    Attributes
    ----------
    x, v : tuple of sympy Symbol
        One particle's position and velocity coordinates, for external forces.

    Examples
    --------
    >>> ps = ParticleSystem([[0.0], [1.5]], masses=[1.0, 2.0])
    >>> ode = ps.add_springs([[0, 1]], stiffness=3.0, rest_length=1.0).ode(T=10.0)
    """

    def __init__(self, positions, velocities=None, masses=1.0):
        x0 = np.array(positions, dtype=float)
        if x0.ndim == 1:
            x0 = x0[:, None]
        if x0.ndim != 2 or x0.shape[1] not in (1, 2, 3) or len(x0) == 0:
            raise ValueError(f"positions must have shape (n, dim) with dim 1, 2 or 3, got "
                             f"{np.shape(positions)}")
        self.n, self.dim = x0.shape
        v0 = np.zeros_like(x0) if velocities is None else np.array(velocities, dtype=float)
        if v0.ndim == 1 and self.dim == 1:
            v0 = v0[:, None]
        if v0.shape != x0.shape:
            raise ValueError(f"velocities must have the shape of positions {x0.shape}, got {v0.shape}")
        m = np.broadcast_to(np.array(masses, dtype=float), (self.n,)) if np.ndim(masses) == 0 \
            else np.array(masses, dtype=float)
        if m.shape != (self.n,):
            raise ValueError(f"masses must be one number or {self.n} numbers, got shape {m.shape}")
        if not np.all(m > 0) or not np.all(np.isfinite(m)):
            raise ValueError(f"masses must be positive and finite, got {m[~(m > 0) | ~np.isfinite(m)][0]}")
        for name, a in (("positions", x0), ("velocities", v0)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be finite")
        self.positions, self.velocities, self.masses = x0, v0, np.ascontiguousarray(m)
        self.x, self.v = _local(self.dim)
        self._springs = []  # (pairs, stiffness, rest length) blocks
        self._forces = []   # (force expressions, particles)

    @property
    def springs(self):
        """The particle pairs of all springs added so far, shape (E, 2)."""
        if not self._springs:
            return np.zeros((0, 2), dtype=np.int64)
        return np.concatenate([block[0] for block in self._springs])

    def position_components(self, particles):
        """Component indices of the positions of ``particles``, shape (len, dim)."""
        return np.asarray(particles, dtype=np.int64)[:, None] * self.dim + np.arange(self.dim)

    def velocity_components(self, particles):
        """Component indices of the velocities of ``particles``, shape (len, dim)."""
        return self.position_components(particles) + self.n * self.dim

    def _particles(self, particles, what):
        array = np.asarray(particles)
        if array.size and not np.issubdtype(array.dtype, np.integer):
            raise TypeError(f"{what} must hold particle numbers (integers), got {array.dtype}")
        if array.size and (array.min() < 0 or array.max() >= self.n):
            raise ValueError(f"{what} refers to particle {array.max() if array.max() >= self.n else array.min()}"
                             f", outside [0, {self.n})")
        return array.astype(np.int64)

    def add_springs(self, pairs, stiffness=1.0, rest_length=None):
        """Add springs between particle pairs; returns the builder.

        Parameters
        ----------
        pairs : array_like of int, shape (E, 2)
        stiffness : float or array_like, shape (E,)
        rest_length : float or array_like, shape (E,), optional
            Default: the initial distances (springs at rest).
        """
        pairs = self._particles(pairs, "pairs")
        if pairs.ndim != 2 or pairs.shape[1] != 2:
            raise ValueError(f"pairs must have shape (E, 2), got {pairs.shape}")
        if np.any(pairs[:, 0] == pairs[:, 1]):
            raise ValueError(f"spring {int(np.flatnonzero(pairs[:, 0] == pairs[:, 1])[0])} joins "
                             "a particle to itself")
        if rest_length is None:
            d = self.positions[pairs[:, 1]] - self.positions[pairs[:, 0]]
            rest_length = np.sqrt(np.sum(d * d, axis=1))
        columns = []
        for name, value in (("stiffness", stiffness), ("rest_length", rest_length)):
            array = np.broadcast_to(np.asarray(value, dtype=float), (len(pairs),))
            if not np.all(np.isfinite(array)) or np.any(array < 0):
                raise ValueError(f"{name} must be finite and non-negative")
            columns.append(array)
        self._springs.append((pairs, *columns))
        return self

    def add_force(self, force, particles=None):
        """Add an external force F(x, v, t) on ``particles`` (default all); returns the builder.

        ``force`` holds dim sympy expressions in :attr:`x`, :attr:`v`, ``dn.t`` and the
        global parameters given to :meth:`ode`; gravity in 2-D is ``(0, -g)``.
        """
        force = tuple(force)
        if len(force) != self.dim:
            raise ValueError(f"force must have {self.dim} components (one per dimension), got {len(force)}")
        chosen = np.arange(self.n) if particles is None else self._particles(particles, "particles")
        self._forces.append((force, chosen.ravel()))
        return self

    def _spring_template(self):
        (xa, va), (xb, vb) = _local(self.dim, "_a"), _local(self.dim, "_b")
        k, rest, ma, mb = sp.symbols("k L m_a m_b", positive=True)
        r = sp.sqrt(sum((b - a) ** 2 for a, b in zip(xa, xb)))
        force = [k * (r - rest) * (b - a) / r for a, b in zip(xa, xb)]  # on a, from b
        terms = {**{v: f / ma for v, f in zip(va, force)}, **{v: -f / mb for v, f in zip(vb, force)}}
        pairs = self.springs
        a, b = pairs[:, 0], pairs[:, 1]
        indices = np.hstack([self.position_components(a), self.position_components(b),
                             self.velocity_components(a), self.velocity_components(b)])
        values = np.column_stack([np.concatenate([block[1] for block in self._springs]),
                                  np.concatenate([block[2] for block in self._springs]),
                                  self.masses[a], self.masses[b]])
        return Template((*xa, *xb, *va, *vb), terms, indices, (k, rest, ma, mb), values)

    def _force_template(self, force, particles):
        m = sp.Symbol("m", positive=True)
        indices = np.hstack([self.position_components(particles), self.velocity_components(particles)])
        terms = {v: f / m for v, f in zip(self.v, force) if f != 0}
        if not terms:
            return None
        return Template((*self.x, *self.v), terms, indices, (m,), self.masses[particles])

    def ode(self, T, t0=0.0, params=None):
        """The system as a :class:`TemplateODE` on (t0, T] (global ``params`` for the forces)."""
        everyone = np.arange(self.n)
        kinematics = Template((*self.x, *self.v), dict(zip(self.x, self.v)),
                              np.hstack([self.position_components(everyone),
                                         self.velocity_components(everyone)]))
        templates = [kinematics]
        if self._springs:
            templates.append(self._spring_template())
        templates += [tf for tf in (self._force_template(*f) for f in self._forces) if tf is not None]
        u0 = np.concatenate([self.positions.ravel(), self.velocities.ravel()])
        return TemplateODE(templates, u0=u0, T=T, params=params, t0=t0,
                           names=ParticleNames(self.n, self.dim))


def lattice(p=5, m=1e-12, M=100.0, T=10.0):
    """The lattice of DOLFIN's automatic-modeling demo as a :class:`TemplateODE` on [0, T]:
    ``lattice_system(p, m, M).ode(T)``, N = 4 (p^2 + (p - 1)^2) components."""
    return lattice_system(p, m, M).ode(T=T)


def lattice_system(p=5, m=1e-12, M=100.0):
    """The lattice of DOLFIN's automatic-modeling demo (``modeling/lattice``, 2004), in 2-D,
    as a :class:`ParticleSystem` (its ``positions`` and ``springs`` give the geometry).

    p^2 large masses M on a square grid of spacing h = 1/(p - 1), numbered row by row;
    then (p - 1)^2 small masses m, one per cell, at the cell centre displaced by
    (+-h/4, -+h/4) in a checkerboard pattern (+h/4 in x for even cell columns, -h/4 in y for
    even cell rows). Unit springs join horizontal and vertical neighbours (rest length h) and
    every small mass to the two corners of its cell whose grid indices have an even sum
    (rest length h/sqrt(2)); the small masses start off their rest positions, perpendicular
    to their springs.

    Returns
    -------
    ParticleSystem of p^2 + (p - 1)^2 particles.
    """
    if int(p) != p or p < 2:
        raise ValueError(f"the lattice needs p >= 2 large masses per side, got {p}")
    p = int(p)
    h = 1.0 / float(p - 1)
    hsmall = 0.5 * np.sqrt(2.0) * h
    i2, i1 = np.divmod(np.arange(p * p), p)
    large = np.column_stack([i1 * h, i2 * h])
    c2, c1 = np.divmod(np.arange((p - 1) ** 2), p - 1)
    dx = np.where(c1 % 2 == 0, 0.25 * h, -0.25 * h)
    dy = np.where(c2 % 2 == 0, -0.25 * h, 0.25 * h)
    small = np.column_stack([0.5 * h + c1 * h + dx, 0.5 * h + c2 * h + dy])
    masses = np.concatenate([np.full(p * p, float(M)), np.full((p - 1) ** 2, float(m))])
    ps = ParticleSystem(np.vstack([large, small]), masses=masses)
    grid = np.arange(p * p).reshape(p, p)  # grid[i2, i1]
    ps.add_springs(np.column_stack([grid[:, :-1].ravel(), grid[:, 1:].ravel()]), 1.0, h)
    ps.add_springs(np.column_stack([grid[:-1, :].ravel(), grid[1:, :].ravel()]), 1.0, h)
    cell = p * p + np.arange((p - 1) ** 2)
    even = (c1 + c2) % 2 == 0  # diagonal SW-NE, else SE-NW
    first = np.where(even, grid[c2, c1], grid[c2, c1 + 1])
    second = np.where(even, grid[c2 + 1, c1 + 1], grid[c2 + 1, c1])
    ps.add_springs(np.column_stack([np.repeat(cell, 2), np.column_stack([first, second]).ravel()]),
                   1.0, hsmall)
    return ps
