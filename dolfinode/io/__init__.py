"""File output: trajectories of particle systems as XDMF time series (meshio), solution
histories in HDF5 (:mod:`dolfinode.io.stored`). Imported on first use: meshio takes 0.3 s."""

__all__ = ["read_trajectory", "write_trajectory"]


def __getattr__(name):
    if name in __all__:
        from dolfinode.io import trajectory

        return getattr(trajectory, name)
    raise AttributeError(f"module 'dolfinode.io' has no attribute {name!r}")
