"""Files that appear whole or not at all.

:func:`new_file` writes into a file without a name in the target folder (Linux's O_TMPFILE)
and gives it its name only when complete, so that a failed or killed write (even by SIGKILL)
leaves nothing behind. Where the system cannot make unnamed files, it writes to a temporary
name that says what it is, ``<name>.incomplete-<random>``, removed on any failure.
"""
import contextlib
import os
import tempfile
from pathlib import Path


@contextlib.contextmanager
def new_file(path, mode=0o644):
    """Yield a binary file object (read-write) whose content becomes ``path`` when the block
    ends without an exception (replacing an existing file), readable by all (``mode``).

    Raises
    ------
    OSError
        Naming ``path`` when its folder cannot take the file.
    """
    path = Path(path)
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, name = _unnamed(folder), None
        if fd is None:
            fd, name = tempfile.mkstemp(dir=folder, prefix=f"{path.name}.incomplete-")
    except OSError as error:
        raise OSError(error.errno, f"cannot write {path}: {error.strerror}") from None
    file = os.fdopen(fd, "w+b")
    try:
        yield file
        file.flush()
        os.fchmod(file.fileno(), mode & ~_umask())
        if name is None:  # give the unnamed file a temporary name, then move it in place
            name = _temporary_name(folder, path.name)
            _link(file.fileno(), name)
        os.replace(name, path)
        name = None
    except OSError as error:
        raise OSError(error.errno, f"cannot write {path}: {error.strerror}") from None
    finally:
        file.close()
        if name is not None:
            with contextlib.suppress(OSError):
                os.unlink(name)


def _unnamed(folder):
    """A file descriptor of a new file without a name in ``folder``, or None where the
    system or the file system does not make them."""
    flag = getattr(os, "O_TMPFILE", None)
    if flag is None or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        return os.open(folder, flag | os.O_RDWR, 0o600)
    except OSError:
        return None


def _link(fd, name):
    """Give the unnamed file ``fd`` the name ``name`` (linkat with AT_SYMLINK_FOLLOW, which
    os.link uses only with a directory descriptor)."""
    proc = os.open("/proc/self", os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.link(f"fd/{fd}", name, src_dir_fd=proc, follow_symlinks=True)
    finally:
        os.close(proc)


def _temporary_name(folder, name):
    """A free name for the few system calls between linking and renaming."""
    return os.path.join(folder, f".{name}.incomplete-{os.getpid()}-{os.urandom(4).hex()}")


def _umask():
    current = os.umask(0)
    os.umask(current)
    return current
