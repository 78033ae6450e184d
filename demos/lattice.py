"""A lattice with internal vibrations: automatic modeling of p^2 large and (p-1)^2 small masses.

The second example of Jansson, Johnson & Logg, "Computational modeling of dynamical systems"
(2005): p^2 large masses M = 100 on the grid of spacing h = 1/(p-1) over the unit square,
joined to their neighbours by springs of stiffness 1 and rest length h, and (p-1)^2 small
masses m at the cell centres, each joined to two opposite corners of its cell (alternating
diagonals, a checkerboard) by springs of stiffness 1 and rest length h sqrt(2)/2. Each small
mass starts at rest, displaced from the cell centre by h/4 in x and in y perpendicular to its
springs (as in DOLFIN's demo: +h/4 in x in even cell columns, -h/4 in y in even cell rows),
and vibrates on the time scale sqrt(m); its vibration pulls the corners inwards on average
and the lattice contracts on the time scale sqrt(M) ~ 10.

Plots the diameter D(t) (lower-left to upper-right large mass) and the distance d(t) (lower-
left large mass to lower-left small mass), the paper's figure 6, and with --compare the
reduced against the full solution for m = 1e-4, tau = 1 on [0, 20] and [0, 100] (figure 5),
with the model rebuilt at control points (affine in the slow state) and the paper's constant
model built once. Writes the trajectories as an XDMF
time series (ParaView: points for the masses, lines for the springs).

Run ``python demos/lattice.py --help`` for the options.
"""
import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import dolfinode as dn
from dolfinode.io import write_trajectory
from dolfinode.modeling import kernel_weights


@dataclass
class Lattice:
    """The declared ODE and its geometry: ``points`` (n, 2) initial positions, ``springs``
    (s, 2) index pairs, ``small`` indices of the small masses, ``x``/``y`` component indices
    of each mass's coordinates."""

    ode: dn.ODE
    points: np.ndarray
    springs: np.ndarray
    small: np.ndarray
    x: np.ndarray
    y: np.ndarray

    def positions(self, values):
        """(n, 2, M) positions from solution values (N, M)."""
        return np.stack([values[self.x], values[self.y]], axis=1)

    def components(self, particles):
        """Component indices of the positions and velocities of ``particles`` (sorted)."""
        x, y = self.x[particles], self.y[particles]
        return np.sort(np.concatenate([x, y, x + self.ode.N // 2, y + self.ode.N // 2]))

    def diameter(self, values):
        """D: distance between the lower-left and the upper-right large mass."""
        pos = self.positions(values)
        p2 = len(self.points) - len(self.small)
        return np.hypot(*(pos[p2 - 1] - pos[0]))

    def distance(self, values):
        """d: distance between the lower-left large mass and the lower-left small mass."""
        pos = self.positions(values)
        return np.hypot(*(pos[self.small[0]] - pos[0]))


def lattice(p=5, m=1e-12, M=100.0, T=10.0):
    """The lattice from the particle-system builder (``dn.systems.lattice_system``): a
    template system whose generated code does not depend on p."""
    ps = dn.systems.lattice_system(p, m, M)
    coordinates = ps.position_components(np.arange(ps.n))
    return Lattice(ps.ode(T=T), ps.positions, ps.springs, np.arange(p * p, ps.n),
                   coordinates[:, 0], coordinates[:, 1])


def reference(lat, T, tau, per_tau=100):
    """The full model with scipy's DOP853 (rtol 1e-8) and its average of length tau
    (the kernel of the modeling, :func:`~dolfinode.modeling.kernel_weights`):
    returns times on [tau, T - tau] (spacing tau / per_tau), D(t), D-bar(t) and the
    scipy solution."""
    from scipy.integrate import solve_ivp

    from dolfinode.compile import lower

    compiled = lower(lat.ode)
    full = solve_ivp(lambda t, u: compiled.f(u, t), (0.0, T), lat.ode.u0, method="DOP853",
                     rtol=1e-8, atol=1e-10, dense_output=True)
    grid = np.linspace(0.0, T, round(T / tau) * per_tau + 1)
    D = lat.diameter(full.sol(grid))
    D_bar = np.convolve(D, kernel_weights(per_tau), mode="valid")
    return grid[per_tau:-per_tau], D[per_tau:-per_tau], D_bar, full


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plots and the XDMF file (default: demos/output)")
    parser.add_argument("--quick", action="store_true",
                        help="small run for tests: p = 3, T = 2, and no --compare")
    parser.add_argument("-p", type=int, default=5, help="masses per side (default %(default)s)")
    parser.add_argument("-m", type=float, default=1e-12, help="small mass (default %(default)g)")
    parser.add_argument("--tau", type=float, default=1e-4, help="average length (default %(default)g)")
    parser.add_argument("-T", type=float, default=10.0, help="final time (default %(default)g)")
    parser.add_argument("--method", default="cG(2)", help="default: %(default)s")
    parser.add_argument("--tolerance", type=float, default=1e-4, help="default: %(default)g")
    parser.add_argument("--compare", action="store_true",
                        help="also m = 1e-4, tau = 1 on [0, 100] against the full model (figure 5)")
    args = parser.parse_args(argv)
    if args.quick:
        args.p, args.T, args.compare = 3, 2.0, False
    args.output.mkdir(parents=True, exist_ok=True)
    result = {}

    lat = lattice(args.p, args.m, T=args.T)
    start = time.perf_counter()
    sol = dn.solve(lat.ode, method=args.method, tolerance=args.tolerance,
                   automatic_modeling=True, average_length=args.tau, control_points=4)
    wall = time.perf_counter() - start
    inactive = {lat.ode.index(s) for s in sol.model.inactive}
    print(f"lattice p = {args.p}, m = {args.m:g}, tau = {args.tau:g}, T = {args.T:g}: "
          f"{lat.ode.N} components, {len(inactive)} inactive, {sol.stats['elements']} elements, "
          f"{wall:.2f} s; model built at t = {sol.model.built}")
    t = np.linspace(0.0, args.T, 400 if args.quick else 2000)
    values = sol(t)
    D = lat.diameter(values)
    # the small masses' period is 2 pi sqrt(m) (unit springs): 40 samples per period
    # up to where the reduced model takes over, so that the plot does not alias it
    takeover = sol.model.built[0]
    period = 2 * np.pi * np.sqrt(args.m)
    fast = np.union1d(np.linspace(0.0, takeover, min(int(40 * takeover / period) + 2, 200_000)),
                      np.linspace(takeover, 4 * args.tau, 400))
    d = lat.distance(sol(fast))
    print(f"  D(0) = {D[0]:.6f}, min D = {D.min():.6f}, D(T) = {D[-1]:.6f}")
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6))
    ax1.plot(t, D)
    ax1.set(xlabel="t", ylabel="D(t)", title=f"diameter, m = {args.m:g}, tau = {args.tau:g}")
    ax2.plot(fast, d, lw=0.6)
    for ax in (ax1, ax2):
        ax.axvline(takeover, color="k", ls=":", lw=0.8,
                   label=f"reduced model from t = {takeover:.3g}")
    ax2.legend(loc="upper right")
    ax2.set(xlabel="t", ylabel="d(t)", title="distance to the small mass on [0, 4 tau]: "
            "resolved, then the small masses at their average positions")
    fig.tight_layout()
    plot = args.output / "lattice.png"
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    xdmf = write_trajectory(args.output / "lattice.xdmf", lat.points, lat.springs,
                            t[::max(1, len(t) // 100)],
                            lat.positions(values[:, ::max(1, len(t) // 100)]))
    print(f"plot: {plot}\ntrajectory: {xdmf}")
    result.update({"plot": plot, "xdmf": xdmf, "solution": sol, "lattice": lat, "D": D,
                   "inactive": inactive})
    if args.compare:
        result["compare"] = compare(args)
    return result


def compare(args, T=100.0, tau=1.0, m=1e-4):
    """Figure 5: the reduced model (checked and rebuilt at 10 control points, affine in the
    slow state after the first rebuild; and the paper's constant model built once) against
    the full model and its average D-bar."""
    lat = lattice(args.p, m, T=T)
    times, D, D_bar, _ = reference(lat, T, tau)
    runs = {"rebuilt": {}, "built once": {"subgrid_model": "constant", "rebuild_model": False,
                                          "control_points": 0}}
    out = {}
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, options in runs.items():
        start = time.process_time()
        sol = dn.solve(lat.ode, method=args.method, tolerance=args.tolerance,
                       automatic_modeling=True, average_length=tau, **options)
        cpu = time.process_time() - start
        D_reduced = lat.diameter(sol(times))
        mask = times >= 2 * tau
        error = np.max(np.abs(D_reduced - D_bar)[mask])
        print(f"  m = {m:g}, tau = {tau:g}, model {label}: max |D - D-bar| on [2 tau, {T:g}] = "
              f"{error:.4f} ({len(sol.model.built)} builds, affine: {sol.model.affine}, "
              f"{sol.stats['elements']} elements, {cpu:.1f} s CPU)")
        out[label] = {"error": error, "builds": len(sol.model.built), "solution": sol}
        for ax, end in zip(axes, (20.0, T)):
            keep = times <= end
            ax.plot(times[keep], D_reduced[keep], label=f"reduced, {label}")
    print(f"  full model: D-bar contracts from {D_bar[0]:.4f} to {D_bar.min():.4f}")
    for ax, end in zip(axes, (20.0, T)):
        keep = times <= end
        ax.plot(times[keep], D[keep], "k:", lw=0.7, label="full")
        ax.plot(times[keep], D_bar[keep], "k--", label="full, averaged")
        ax.set(xlabel="t", ylabel="D(t)", title=f"m = {m:g}, tau = {tau:g} on [0, {end:g}]")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    plot = args.output / "lattice_compare.png"
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    out["plot"] = plot
    return out


if __name__ == "__main__":
    main()
