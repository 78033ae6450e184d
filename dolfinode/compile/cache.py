"""On-disk cache of compiled kernel libraries, keyed by a hash of the expressions.

A second run with the same expressions neither generates nor compiles anything. Each library
``dn_<key>.so`` has a record ``dn_<key>.json`` of what it was built from (the signature, the
compiler and its flags) and of its own size and SHA-256, checked *before* the library is
loaded: a truncated, empty or swapped file is rebuilt, never loaded (a truncated library
mapped by ctypes kills the process with SIGBUS at the first call into a missing page).
Files are written under temporary names and renamed, so an interrupted run never leaves a
half-written file under a cached name; they are readable by all (0644, libraries 0755), so
one cache can be shared. An unwritable cache folder falls back to a private temporary
folder for the process, with one warning.
"""
import atexit
import ctypes
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

#: Bump when the generated code changes meaning, so stale kernels are not reused.
CODEGEN_VERSION = "5"
_FLAGS = ["-O2", "-fPIC", "-shared", "-fno-math-errno", "-std=c99"]
#: The cache's own files (``dolfinode cache clear`` removes these and nothing else).
_PATTERNS = ("dn_*.so", "dn_*.c", "dn_*.json", "dn_*.tmp")
#: The private folder used when the cache folder is not writable (made once per process).
_fallback = None


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


def _write_atomic(path, write, mode=0o644):
    """Write ``path`` through ``write(temporary name)`` and rename it into place, readable
    by all (``mode``); the temporary file is removed on any failure."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _digest(path):
    h = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _record(key, library):
    """What the library of ``key`` is built from, with its size and hash."""
    return {"key": key, "codegen": CODEGEN_VERSION, "platform": sys.platform,
            "flags": _FLAGS, "compiler": c_compiler(), "size": library.stat().st_size,
            "sha256": _digest(library)}


def _is_valid(key, library):
    """Whether ``library`` is the one its record describes, built for ``key`` by this
    version of the generator (read before any ctypes load)."""
    try:
        record = json.loads(library.with_suffix(".json").read_text())
        size = library.stat().st_size
        return (isinstance(record, dict) and record.get("key") == key
                and record.get("codegen") == CODEGEN_VERSION
                and record.get("platform") == sys.platform and record.get("flags") == _FLAGS
                and record.get("size") == size > 0 and record.get("sha256") == _digest(library))
    except (OSError, ValueError):
        return False


def _writable(folder):
    """``folder``, created if needed, or the reason it cannot hold new files."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix="dn_probe.", suffix=".tmp"):
            pass
    except OSError as exc:
        return f"{type(exc).__name__}: {exc.strerror or exc}"
    return None


def _build_folder(folder):
    """The folder new libraries go to: ``folder`` if writable, else (with one warning per
    process) a private temporary folder removed at exit."""
    global _fallback
    reason = _writable(folder)
    if reason is None:
        return folder
    if _fallback is None:
        _fallback = Path(tempfile.mkdtemp(prefix="dolfinode-kernels-"))
        atexit.register(shutil.rmtree, _fallback, True)
        warnings.warn(f"the dolfinode kernel cache {folder} is not writable ({reason}); kernels "
                      f"are compiled into the private folder {_fallback} for this process only. "
                      "Set DOLFINODE_CACHE_DIR to a writable folder to keep them between runs",
                      RuntimeWarning, stacklevel=4)
    return _fallback


def _build(key, make_source, folder):
    """Generate and compile the library of ``key`` in ``folder``, with its record."""
    source, library = folder / f"dn_{key}.c", folder / f"dn_{key}.so"
    text = make_source()  # generated anew: a source left by another run is not trusted
    _write_atomic(source, lambda tmp: Path(tmp).write_text(text))

    def compile_to(tmp):
        command = [c_compiler(), *_FLAGS, "-o", tmp, str(source), "-lm"]
        result = subprocess.run(command, check=False, capture_output=True, text=True)
        if result.returncode != 0:
            # a source that does not compile is not kept: the next run (with a fixed
            # dolfinode) generates it again instead of failing on the same file
            source.unlink(missing_ok=True)
            raise RuntimeError(f"compiling the kernels of {source.name} failed:\n"
                               f"{result.stderr}\n(source, removed from the cache:)\n"
                               f"{text[:4000]}")

    _write_atomic(library, compile_to, mode=0o755)
    record = json.dumps(_record(key, library), indent=1)
    _write_atomic(library.with_suffix(".json"), lambda tmp: Path(tmp).write_text(record))
    return library


def load_library(key, make_source):
    """The shared library for ``key``, generated with ``make_source()`` and compiled unless
    a valid one is cached (see the module docstring).

    Returns (ctypes.CDLL, was_cached).
    """
    folder = cache_directory()
    for candidate in (folder, _fallback):
        if candidate is not None and _is_valid(key, candidate / f"dn_{key}.so"):
            return ctypes.CDLL(str(candidate / f"dn_{key}.so")), True
    library = _build(key, make_source, _build_folder(folder))
    return ctypes.CDLL(str(library)), False


def cache_info():
    """The cache folder, its libraries (valid ones: with a matching record) and their size.

    Returns
    -------
    dict
        ``folder``, ``libraries``, ``valid``, ``bytes`` (all the cache's files).
    """
    folder = cache_directory()
    libraries = sorted(folder.glob("dn_*.so")) if folder.is_dir() else []
    files = [p for pattern in _PATTERNS for p in folder.glob(pattern)] if folder.is_dir() else []
    return {"folder": str(folder), "libraries": len(libraries),
            "valid": sum(_is_valid(p.stem[3:], p) for p in libraries),
            "bytes": sum(p.stat().st_size for p in files)}


def clear_cache():
    """Remove the cache's files (``dn_*`` libraries, sources, records, temporaries) from the
    cache folder, nothing else; returns how many were removed."""
    folder = cache_directory()
    if not folder.is_dir():
        return 0
    removed = 0
    for pattern in _PATTERNS:
        for path in folder.glob(pattern):
            path.unlink(missing_ok=True)
            removed += 1
    return removed
