"""The kernel cache heals: damaged files are rebuilt before any load, an unwritable folder
falls back with one warning, files are shared-readable; ``dolfinode cache info|clear``."""
import json
import shutil
import stat
import textwrap

import numpy as np
import pytest

from dolfinode.cli import main

#: Lowers the named systems in a fresh process and prints f_2 at one point for each.
_SCRIPT = textwrap.dedent("""
    import json, sys, warnings
    import sympy as sp
    import dolfinode as dn
    from dolfinode.compile import lower

    u, v, k = sp.symbols("u v k")
    shapes = {"A": sp.sin(dn.t), "B": sp.cos(dn.t)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        values = [float(lower(dn.ODE({u: v, v: -k * u * shapes[name]}, [1.0, 0.0], 1.0,
                                     params={k: 2.0})).f([0.5, 2.0], 0.25)[1])
                  for name in sys.argv[1:]]
    print(json.dumps({"values": values, "warnings": [str(w.message) for w in caught]}))
""")
EXPECTED = {"A": -2.0 * 0.5 * np.sin(0.25), "B": -2.0 * 0.5 * np.cos(0.25)}


def lower_in_a_process(run_python, cache_dir, *systems):
    result = run_python(_SCRIPT, *systems, env={"DOLFINODE_CACHE_DIR": str(cache_dir)})
    assert result.returncode == 0, f"exit {result.returncode} (negative: a signal)\n{result.stderr}"
    report = json.loads(result.stdout.strip().splitlines()[-1])
    np.testing.assert_allclose(report["values"], [EXPECTED[s] for s in systems], rtol=1e-14)
    return report


@pytest.fixture(scope="module")
def built(tmp_path_factory, run_python):
    """A cache holding the kernels of systems A and B, and the library of each."""
    root = tmp_path_factory.mktemp("cache")
    libraries = {}
    for name in "AB":
        before = set((root / "kernels").glob("dn_*.so"))
        lower_in_a_process(run_python, root, name)
        (libraries[name],) = set((root / "kernels").glob("dn_*.so")) - before
    return root, libraries


def damaged_copy(built, tmp_path, damage):
    root, libraries = built
    shutil.copytree(root, tmp_path / "cache")
    library = tmp_path / "cache" / "kernels" / libraries["A"].name
    if damage == "truncated":  # mapped by ctypes, this killed the process with SIGBUS
        data = library.read_bytes()
        library.write_bytes(data[:len(data) // 2])
    elif damage == "emptied":
        library.write_bytes(b"")
    elif damage == "swapped":  # another valid kernel under A's name
        shutil.copyfile(libraries["B"], library)
    elif damage == "unrecorded":  # a library left by a version without records
        library.with_suffix(".json").unlink()
    return tmp_path / "cache", library


@pytest.mark.parametrize("damage", ["truncated", "emptied", "swapped", "unrecorded"])
def test_a_damaged_library_is_rebuilt_not_loaded(built, tmp_path, run_python, damage):
    root, library = damaged_copy(built, tmp_path, damage)
    report = lower_in_a_process(run_python, root, "A")  # the right value, no signal
    assert not report["warnings"]
    assert library.read_bytes() == built[1]["A"].read_bytes()  # healed for the next run
    assert json.loads(library.with_suffix(".json").read_text())["size"] == library.stat().st_size


def test_an_unwritable_cache_falls_back_with_one_warning(tmp_path, run_python):
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    report = lower_in_a_process(run_python, blocked, "A", "B")
    (warning,) = report["warnings"]
    assert "not writable" in warning and "DOLFINODE_CACHE_DIR" in warning


def test_cache_files_are_readable_by_all(built):
    root, _ = built
    modes = {path.suffix: stat.S_IMODE(path.stat().st_mode)
             for path in (root / "kernels").glob("dn_*")}
    assert modes == {".so": 0o755, ".c": 0o644, ".json": 0o644}


def test_cache_info_and_clear(built, tmp_path, monkeypatch, capsys):
    root, _ = damaged_copy(built, tmp_path, "emptied")
    (root / "kernels" / "notes.txt").write_text("not the cache's")
    monkeypatch.setenv("DOLFINODE_CACHE_DIR", str(root))
    assert main(["cache", "info"]) == 0
    printed = capsys.readouterr().out
    assert str(root / "kernels") in printed and "libraries  2 (1 valid" in printed
    assert main(["cache", "clear"]) == 0
    assert "removed 6 files" in capsys.readouterr().out
    assert [p.name for p in (root / "kernels").iterdir()] == ["notes.txt"]
