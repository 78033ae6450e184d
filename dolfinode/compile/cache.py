"""On-disk cache of generated kernel modules, keyed by a hash of the expressions.

Numba's own cache (``cache=True``) stores the machine code next to each module, so a
second run with the same expressions neither generates nor compiles anything.
"""
import hashlib
import importlib.util
import os
import sys
import tempfile
from pathlib import Path

#: Bump when the generated code changes meaning, so stale kernels are not reused.
CODEGEN_VERSION = "1"


def cache_directory():
    """The kernel cache folder: $DOLFINODE_CACHE_DIR or ~/.cache/dolfinode."""
    root = os.environ.get("DOLFINODE_CACHE_DIR") or os.path.join(
        os.path.expanduser("~"), ".cache", "dolfinode")
    return Path(root) / "kernels"


def signature(*parts):
    """Hash of the textual representation of the expressions (UFL-style form signature)."""
    h = hashlib.sha256(CODEGEN_VERSION.encode())
    for part in parts:
        h.update(b"\0")
        h.update(part.encode())
    return h.hexdigest()[:24]


def load_module(key, make_source):
    """Import the kernel module for ``key``, writing it with ``make_source()`` if absent.

    Returns (module, was_cached). The file is written to a temporary name and renamed, so
    an interrupted run never leaves a half-written module behind.
    """
    folder = cache_directory()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"dn_{key}.py"
    cached = path.exists()
    if not cached:
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        try:
            with os.fdopen(fd, "w") as handle:
                handle.write(make_source())
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    # Numba's cache rebuilds the kernels' environment by importing their module by name,
    # so the module is registered under a top-level name before it executes.
    name = f"dolfinode_kernel_{key}"
    if name in sys.modules:
        return sys.modules[name], True
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module, cached
