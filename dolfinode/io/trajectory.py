"""Particle trajectories as an XDMF time series that ParaView opens.

The mesh points are the masses and its line cells the springs (ParaView's "Points"
representation shows the masses); every time step stores
the displacement from the initial positions as the point field ``displacement`` (ParaView:
"Warp By Vector" shows the motion) and the current positions as ``position``. As FEniCS's
``XDMFFile``, the heavy data go to an HDF5 file beside the XDMF one (``name.h5``), both written
step by step (memory independent of the number of steps) in the layout of meshio's
``TimeSeriesWriter``, so meshio and ParaView read them. Both files appear only when complete
(:func:`dolfinode.io.atomic.new_file`): a failed or killed write leaves nothing behind.
"""
from pathlib import Path

import meshio
import numpy as np

from dolfinode.io.atomic import new_file
from dolfinode.io.stored import bound_metadata_cache


def write_trajectory(filename, points, springs, times, positions):
    """Write masses and springs moving in time: ``filename`` (.xdmf) and its heavy data
    ``filename`` with the suffix .h5.

    Parameters
    ----------
    filename : path ending in .xdmf
    points : (n, d) initial positions, d = 2 or 3
    springs : (s, 2) index pairs of the masses each spring joins
    times : (M,) output times
    positions : (n, d, M) positions at those times, or a function of the time returning the
        (n, d) positions then (evaluated one step at a time, so that the M steps are never
        held at once)

    Returns
    -------
    Path of the written XDMF file.

    Raises
    ------
    ValueError
        For a file name, shapes or springs that do not fit; OSError naming the file when it
        cannot be written.
    """
    filename = Path(filename)
    if filename.suffix != ".xdmf":
        raise ValueError(f"write_trajectory writes XDMF: the file name must end in .xdmf, "
                         f"got {filename.name!r}")
    points = np.asarray(points, dtype=float)
    n, dim = points.shape
    times = np.asarray(times, dtype=float).ravel()
    at = _positions(positions, n, dim, times)
    springs = np.asarray(springs, dtype=np.int64).reshape(-1, 2)
    if springs.size and (springs.min() < 0 or springs.max() >= n):
        raise ValueError(f"springs must join masses 0..{n - 1}")
    import h5py

    heavy = filename.with_suffix(".h5")
    start = np.hstack([points, np.zeros((n, 3 - dim))])
    # the data are named first, as the inner file
    with new_file(filename) as xdmf, new_file(heavy) as data, h5py.File(data, "w") as h5:
        bound_metadata_cache(h5)  # 4.7 kB per dataset written otherwise: 28 MB at 3000 steps
        h5["data0"], h5["data1"] = start, springs
        xdmf.write(_HEAD.encode())
        current = start.copy()
        for j, tj in enumerate(times):
            current[:, :dim] = at(j)
            h5[f"data{2 * j + 2}"], h5[f"data{2 * j + 3}"] = current, current - start
            xdmf.write(_STEP.format(t=float(tj), n=n, file=heavy.name, position=2 * j + 2,
                                    displacement=2 * j + 3).encode())
        xdmf.write(_TAIL.format(n=n, s=len(springs), file=heavy.name).encode())
    return filename


def _positions(positions, n, dim, times):
    """The positions of step j, at(j), from an (n, d, M) array or a function of the time."""
    if callable(positions):
        def at(j):
            value = np.asarray(positions(times[j]), dtype=float)
            if value.shape != (n, dim):
                raise ValueError(f"positions(t) must return shape (n, d) = ({n}, {dim}), got "
                                 f"{value.shape} at t = {times[j]}")
            return value
        return at
    positions = np.asarray(positions, dtype=float)
    if positions.shape != (n, dim, times.size):
        raise ValueError(f"positions must have shape (n, d, M) = ({n}, {dim}, {times.size}), "
                         f"got {positions.shape}")
    return lambda j: positions[:, :, j]


_HEAD = ('<Xdmf xmlns:xi="http://www.w3.org/2003/XInclude" Version="3.0"><Domain>'
         '<Grid Name="TimeSeries_dolfinode" GridType="Collection" CollectionType="Temporal">\n')
_FIELD = ('<Attribute Name="{name}" AttributeType="Vector" Center="Node"><DataItem '
          'DataType="Float" Dimensions="{{n}} 3" Format="HDF" Precision="8">'
          '{{file}}:/data{{{name}}}</DataItem></Attribute>')
_STEP = ('<Grid><xi:include xpointer="xpointer(//Grid[@Name=&quot;mesh&quot;]/*'
         '[self::Topology or self::Geometry])" /><Time Value="{t!r}" />'
         + _FIELD.format(name="position") + _FIELD.format(name="displacement") + '</Grid>\n')
_TAIL = ('</Grid><Grid Name="mesh" GridType="Uniform"><Geometry GeometryType="XYZ"><DataItem '
         'DataType="Float" Dimensions="{n} 3" Format="HDF" Precision="8">{file}:/data0'
         '</DataItem></Geometry><Topology TopologyType="Polyline" NumberOfElements="{s}" '
         'NodesPerElement="2"><DataItem DataType="Int" Dimensions="{s} 2" Format="HDF" '
         'Precision="8">{file}:/data1</DataItem></Topology></Grid></Domain></Xdmf>\n')


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
