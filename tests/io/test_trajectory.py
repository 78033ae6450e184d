"""XDMF trajectories: written atomically, read back exactly."""
import os
import stat
import textwrap

import numpy as np
import pytest

from dolfinode.io import read_trajectory, write_trajectory
from dolfinode.io.atomic import _umask


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
    # the heavy data beside it, no temporary file left, both readable by all
    assert sorted(tmp_path.iterdir()) == [tmp_path / "traj.h5", path]
    for written in tmp_path.iterdir():
        assert stat.S_IMODE(written.stat().st_mode) == 0o644 & ~_umask()


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


def test_positions_as_a_function_of_the_time(tmp_path):
    points = np.array([[0.0, 0.0], [1.0, 0.0]])
    times = np.linspace(0.0, 1.0, 4)
    path = write_trajectory(tmp_path / "f.xdmf", points, [[0, 1]], times,
                            lambda t: points + t)
    _, _, T, X = read_trajectory(path)
    np.testing.assert_array_equal(T, times)
    np.testing.assert_array_equal(X[:, :2, 2], points + times[2])
    with pytest.raises(ValueError, match=r"positions\(t\) must return shape \(n, d\) = \(2, 2\)"):
        write_trajectory(tmp_path / "g.xdmf", points, [[0, 1]], times, lambda t: points[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.h5", "f.xdmf"]


def test_an_unwritable_target_is_named(tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    with pytest.raises(OSError, match=f"cannot write {blocked / 'out.xdmf'}"):
        write_trajectory(blocked / "out.xdmf", np.zeros((2, 2)), [[0, 1]], [0.0],
                         np.zeros((2, 2, 1)))


_SLOW_WRITE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    import numpy as np
    from dolfinode.io import write_trajectory

    folder = Path(sys.argv[1])

    def positions(t):
        (folder / "writing").touch()
        time.sleep(0.01)
        return np.zeros((100, 2))

    write_trajectory(folder / "run.xdmf", np.zeros((100, 2)), [[0, 1]], np.arange(10_000.0),
                     positions)
""")


def test_a_killed_write_leaves_no_file(tmp_path, kill_python):
    kill_python(_SLOW_WRITE, tmp_path, started=tmp_path / "writing", seconds=1.0)
    assert [p.name for p in tmp_path.iterdir()] == ["writing"]
