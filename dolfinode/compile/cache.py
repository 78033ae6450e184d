"""On-disk cache of compiled kernel libraries, keyed by a hash of the expressions.

A second run with the same expressions neither generates nor compiles anything. Files are
written under temporary names and renamed, so an interrupted run never leaves a half-written
source or library behind.
"""
import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: Bump when the generated code changes meaning, so stale kernels are not reused.
CODEGEN_VERSION = "4"
_FLAGS = ["-O2", "-fPIC", "-shared", "-fno-math-errno", "-std=c99"]


def cache_directory():
    """The kernel cache folder: $DOLFINODE_CACHE_DIR or ~/.cache/dolfinode."""
    root = os.environ.get("DOLFINODE_CACHE_DIR") or os.path.join(
        os.path.expanduser("~"), ".cache", "dolfinode")
    return Path(root) / "kernels"


def signature(*parts):
    """Hash of the textual representation of the expressions (UFL-style form signature)."""
    h = hashlib.sha256(CODEGEN_VERSION.encode())
    h.update(sys.platform.encode())
    for part in parts:
        h.update(b"\0")
        h.update(part.encode())
    return h.hexdigest()[:24]


def c_compiler():
    """The C compiler: $CC, else cc, gcc or clang on the PATH."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    raise RuntimeError("dolfinode compiles right-hand sides to C and found no C compiler: "
                       "install gcc or clang (e.g. apt-get install gcc), or set CC")


def _write_atomic(path, write):
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_library(key, make_source):
    """The shared library for ``key``, generated with ``make_source()`` and compiled if absent.

    Returns (ctypes.CDLL, was_cached).
    """
    folder = cache_directory()
    folder.mkdir(parents=True, exist_ok=True)
    library = folder / f"dn_{key}.so"
    cached = library.exists()
    if not cached:
        source = folder / f"dn_{key}.c"
        if not source.exists():
            text = make_source()
            _write_atomic(source, lambda tmp: Path(tmp).write_text(text))

        def build(tmp):
            command = [c_compiler(), *_FLAGS, "-o", tmp, str(source), "-lm"]
            result = subprocess.run(command, check=False, capture_output=True, text=True)
            if result.returncode != 0:
                # a source that does not compile is not kept: the next run (with a fixed
                # dolfinode) generates it again instead of failing on the same file
                text = source.read_text()
                source.unlink(missing_ok=True)
                raise RuntimeError(f"compiling the kernels of {source.name} failed:\n"
                                   f"{result.stderr}\n(source, removed from the cache:)\n"
                                   f"{text[:4000]}")

        _write_atomic(library, build)
    return ctypes.CDLL(str(library)), cached
