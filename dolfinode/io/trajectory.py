"""Particle trajectories as an XDMF time series that ParaView opens.

The mesh points are the masses and its line cells the springs (ParaView's "Points"
representation shows the masses); every time step stores
the displacement from the initial positions as the point field ``displacement`` (ParaView:
"Warp By Vector" shows the motion) and the current positions as ``position``. The data are
inline XML (no HDF5 dependency). The file is written to a temporary name in the target
folder and renamed when complete, so a failure never leaves a half-written file behind.
"""
import os
import tempfile
from pathlib import Path

import meshio
import numpy as np


def _umask():
    """The process's file-creation mask (reading it means setting it: set it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_trajectory(filename, points, springs, times, positions):
    """Write masses and springs moving in time.

    Parameters
    ----------
    filename : path ending in .xdmf
    points : (n, d) initial positions, d = 2 or 3
    springs : (s, 2) index pairs of the masses each spring joins
    times : (M,) output times
    positions : (n, d, M) positions at those times

    Returns
    -------
    Path of the written file.
    """
    filename = Path(filename)
    if filename.suffix != ".xdmf":
        raise ValueError(f"write_trajectory writes XDMF: the file name must end in .xdmf, "
                         f"got {filename.name!r}")
    points = np.asarray(points, dtype=float)
    n, dim = points.shape
    positions = np.asarray(positions, dtype=float)
    times = np.asarray(times, dtype=float)
    if positions.shape != (n, dim, times.size):
        raise ValueError(f"positions must have shape (n, d, M) = ({n}, {dim}, {times.size}), "
                         f"got {positions.shape}")
    springs = np.asarray(springs, dtype=np.int64).reshape(-1, 2)
    if springs.size and (springs.min() < 0 or springs.max() >= n):
        raise ValueError(f"springs must join masses 0..{n - 1}")
    pad = np.zeros((n, 3 - dim))
    # one block of line cells: meshio 5.3 mis-writes mixed topologies (vertex + line)
    cells = [("line", springs)]
    filename.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".xdmf", dir=filename.parent)
    os.close(fd)
    try:
        with meshio.xdmf.TimeSeriesWriter(tmp, data_format="XML") as writer:
            writer.write_points_cells(np.hstack([points, pad]), cells)
            for j, tj in enumerate(times):
                current = np.hstack([positions[:, :, j], pad])
                writer.write_data(float(tj), point_data={
                    "position": current, "displacement": current - np.hstack([points, pad])})
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600; an output is 0644
        os.replace(tmp, filename)
    except BaseException:
        os.unlink(tmp)
        raise
    return filename


def read_trajectory(filename):
    """Read a file of :func:`write_trajectory`: (points (n, 3), springs (s, 2), times (M,),
    positions (n, 3, M))."""
    with meshio.xdmf.TimeSeriesReader(str(filename)) as reader:
        points, cells = reader.read_points_cells()
        times, positions = [], []
        for k in range(reader.num_steps):
            tk, point_data, _ = reader.read_data(k)
            times.append(tk)
            positions.append(point_data["position"])
    springs = next(c.data for c in cells if c.type == "line")
    return points, springs, np.array(times), np.stack(positions, axis=2)
