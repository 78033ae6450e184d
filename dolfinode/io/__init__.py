"""File output: trajectories of particle systems as XDMF time series (meshio)."""
from dolfinode.io.trajectory import read_trajectory, write_trajectory

__all__ = ["read_trajectory", "write_trajectory"]
