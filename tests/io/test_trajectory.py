"""XDMF trajectories: written atomically, read back exactly."""
import os
import stat

import numpy as np
import pytest

from dolfinode.io import read_trajectory, write_trajectory


def test_round_trip(tmp_path):
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.5]])
    springs = np.array([[0, 1], [1, 2], [0, 2]])
    times = np.linspace(0.0, 1.0, 5)
    positions = points[:, :, None] + 0.1 * np.sin(times)[None, None, :]
    path = write_trajectory(tmp_path / "traj.xdmf", points, springs, times, positions)
    P, S, T, X = read_trajectory(path)
    assert np.allclose(P[:, :2], points) and np.all(P[:, 2] == 0)
    assert np.array_equal(S, springs)
    assert np.allclose(T, times)
    assert np.allclose(X[:, :2], positions)
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_file_mode_follows_the_umask_as_other_outputs(tmp_path, umask, mode):
    points = np.array([[0.0, 0.0], [1.0, 0.0]])
    old = os.umask(umask)
    try:
        path = write_trajectory(tmp_path / "traj.xdmf", points, [[0, 1]], [0.0],
                                points[:, :, None])
        plain = tmp_path / "plain.txt"
        plain.write_text("x")  # how Python's open() creates a file
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == mode == stat.S_IMODE(plain.stat().st_mode)


def test_failure_leaves_nothing_behind(tmp_path):
    points = np.zeros((2, 2))
    with pytest.raises(ValueError, match="positions must have shape"):
        write_trajectory(tmp_path / "bad.xdmf", points, [[0, 1]], [0.0, 1.0], np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="springs must join"):
        write_trajectory(tmp_path / "bad.xdmf", points, [[0, 5]], [0.0], np.zeros((2, 2, 1)))
    with pytest.raises(ValueError, match=".xdmf"):
        write_trajectory(tmp_path / "bad.vtk", points, [[0, 1]], [0.0], np.zeros((2, 2, 1)))
    assert list(tmp_path.iterdir()) == []
