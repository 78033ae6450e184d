"""numba's cache of dolfinode's functions is stamped by the whole package (source_stamp)."""
import numba
from numba.core import caching

from dolfinode import adaptivity, source_stamp
from dolfinode.source_stamp import PACKAGE, package_stamp


def test_stamp_changes_with_any_file_of_the_tree(tmp_path):
    """A callee's edit changes the stamp of every function (the caller's file unchanged)."""
    trees = []
    for body in ("def f():\n    return 1\n", "def f():\n    return 2\n"):
        root = tmp_path / str(len(trees))
        (root / "sub").mkdir(parents=True)
        (root / "caller.py").write_text("from sub.callee import f\n")
        (root / "sub" / "callee.py").write_text(body)
        trees.append(root)
    assert package_stamp(trees[0]) != package_stamp(trees[1])
    assert package_stamp(trees[0]) == package_stamp(trees[0])


def test_package_functions_use_the_package_stamp_and_others_numbas():
    locator = adaptivity.initial_step._cache._impl.locator
    assert isinstance(locator, source_stamp._PackageStamped)
    assert locator.get_source_stamp() == package_stamp(PACKAGE)

    @numba.njit(cache=True)
    def outside(x):
        return x + 1

    assert not isinstance(outside._cache._impl.locator, source_stamp._PackageStamped)
    assert isinstance(outside._cache._impl.locator, caching._CacheLocator)
