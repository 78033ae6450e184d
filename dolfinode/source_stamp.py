"""numba's on-disk cache of dolfinode's compiled functions, stamped by the whole package.

numba stamps a cached function by the hash of its own file. A loop's machine code also holds
its callees from other files, so after an update that changed only a callee (a new record
field, a new rule) the cached loop would run the old callee, or crash on the new record
layout. Every dolfinode function is therefore stamped by one hash of all the package's
sources: any change to them compiles everything afresh once. Imported by the package before
any compiled function is declared.
"""
import functools
import hashlib
from pathlib import Path

from numba.core import caching

PACKAGE = Path(__file__).resolve().parent


@functools.cache
def package_stamp(root=PACKAGE):
    """SHA-256 of the ``*.py`` files under ``root`` (their paths and contents), once a
    process."""
    digest = hashlib.sha256()
    for path in sorted(Path(root).rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.digest()


class _PackageStamped:
    """A numba cache locator for the package's files, stamped by :func:`package_stamp`."""

    def get_source_stamp(self):
        return package_stamp()

    @classmethod
    def from_function(cls, py_func, py_file):
        if not Path(py_file).resolve().is_relative_to(PACKAGE):
            return None
        return super().from_function(py_func, py_file)


class UserProvidedLocator(_PackageStamped, caching.UserProvidedCacheLocator):
    """In $NUMBA_CACHE_DIR."""


class InTreeLocator(_PackageStamped, caching.InTreeCacheLocator):
    """In the package's ``__pycache__`` folders."""


class UserWideLocator(_PackageStamped, caching.UserWideCacheLocator):
    """In the user's cache folder (a package installed read-only)."""


def register():
    """Put the package's locators first in numba's list (once)."""
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # (older numba)
    classes = impl._locator_classes
    if UserProvidedLocator not in classes:
        classes[:0] = [UserProvidedLocator, InTreeLocator, UserWideLocator]


register()
