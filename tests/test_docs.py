"""The documentation: the Sphinx site builds without warnings, every public object has an API
page, the README's example runs, and the README's figures match the benchmark records."""
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import dolfinode as dn
from dolfinode.bench import report

ROOT = Path(__file__).parents[1]
README = (ROOT / "README.md").read_text()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The HTML site built with warnings as errors from a copy of doc/ (the build writes the
    API pages next to its sources)."""
    work = tmp_path_factory.mktemp("docs")
    shutil.copytree(ROOT / "doc", work / "doc", ignore=shutil.ignore_patterns("_build",
                                                                            "generated"))
    shutil.copy(ROOT / "CHANGELOG.md", work)
    build = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q",
                            "-b", "html", str(work / "doc"), str(work / "html")],
                           capture_output=True, text=True, timeout=900, check=False)
    assert build.returncode == 0, build.stderr[-5000:]
    return work / "html"


def test_the_site_builds_without_warnings(site):
    for page in ("index", "getting-started", "guide/modeling", "gallery", "changelog",
                 "design/index", "api/index"):
        assert (site / f"{page}.html").is_file(), page


def test_every_public_object_has_an_api_page(site):
    for name in dn.__all__:
        page = site / "api" / "generated" / f"{name}.html"
        assert page.is_file(), f"no API page for dolfinode.{name}"
        text = page.read_text()
        assert f"dolfinode.{name}" in text
    solve = (site / "api" / "generated" / "solve.html").read_text()
    for parameter in dn.default_parameters:  # documented, not just listed in a dict
        assert f"<strong>{parameter}</strong>" in solve, parameter


def test_readme_is_short_and_undated():
    assert len(README.splitlines()) <= 120
    assert not re.search(r"20\d\d-\d\d-\d\d", README)
    assert not re.search(r"\b[0-9a-f]{7,40}\b", README)  # no commit hashes
    # .ci/run cites this command
    assert ("python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && "
            ".venv/bin/python -m pytest -q") in README


def test_readme_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README, re.DOTALL)
    assert len(blocks) == 1
    exec(compile(blocks[0], "README.md", "exec"), {})  # noqa: S102 (the README's own code)
    printed = capsys.readouterr().out
    assert "successfully reached the end" in printed
    deviation = float(re.search(r"max \|u1 - \(1 - cos t\)/4\| = (\S+)", printed).group(1))
    assert deviation < 1e-4  # the README says about 1.4e-5
    bound = float(re.search(r"modeling error bound: (\S+)", printed).group(1))
    assert 0 < bound < 1e-5  # the README says about 1e-6


def _ratio_range(names, table="table"):
    """The README's form of the range of time ratios over the given suite problems."""
    heads = json.loads((ROOT / "doc" / "benchmarks" / "suite.json").read_text())["headline"]
    entries = [e for n in names for e in (heads[n][table] if table != "table"
                                          else report._compared(heads[n]))]
    return report._range(entries)


def test_readme_figures_match_the_benchmark_records():
    stiff = ["HIRES", "ROBER", "VDPOL", "VDPOLM", "POLLU", "MEDAKZO"]
    assert f"takes {_ratio_range(stiff)} of the CPU time" in README
    assert f"{_ratio_range(['seed k=1e+08'], 'modeling_table')} of the CPU time" in README
    front = (ROOT / "doc" / "benchmarks" / "reaction_front.md").read_text()
    figure = re.search(r"N = 16000: (\S+) \(errors 1e-05 \.\.\. 1e-09\)", front).group(1)
    assert f"mcG(3) takes {figure} of the CPU time" in README.replace("\n  ", " ")


def test_readme_peer_figures_match_the_peers_record():
    """The LSODA ratios the README quotes are the range of the record's table at 6 and 8
    digits over HIRES, ROBER, VDPOL and POLLU."""
    record = (ROOT / "doc" / "benchmarks" / "peers" / "peers.md").read_text()
    ratios = {6: [], 8: []}
    for name in ("HIRES", "ROBER", "VDPOL", "POLLU"):
        cells = re.search(rf"^\| {name} \|(.*)$", record, re.MULTILINE).group(1).split("|")
        for digits, cell in zip((6, 8), cells[1:3]):
            assert "numbalsoda-LSODA" in cell
            ratios[digits].append(float(cell.split()[0]))
    text = README.replace("\n  ", " ")
    assert (f"{min(ratios[8]):g}-{max(ratios[8]):g}x its time at 8 digits" in text
            and f"{min(ratios[6]):g}-{max(ratios[6]):g}x at 6" in text)


def test_readme_modeling_classes_figures_match_the_record():
    """The README's modeling CPU range over the four classes (1e4 ... 1e12) and its ratios of
    the resolving solvers' CPU at equal accuracy at 1e8 and (numbalsoda) 1e10 (the
    oscillating classes) are the record's."""
    import csv

    with open(ROOT / "doc" / "benchmarks" / "modeling_classes.csv") as fh:
        rows = list(csv.DictReader(fh))
    cpu = [float(r["modeling CPU [s]"]) for r in rows]
    at_1e8 = [r for r in rows if float(r["scale separation"]) == 1e8
              and r["class"] != "michaelis_menten"]
    ratios = {k: [float(r[k]) / float(r["modeling CPU [s]"]) for r in at_1e8]
              for k in ("compiled CPU [s]", "scipy CPU [s]")}
    text = README.replace("\n  ", " ")
    assert f"in {min(cpu):.2g}-{max(cpu):.2g} s of CPU time" in text
    scipy, compiled = ratios["scipy CPU [s]"], ratios["compiled CPU [s]"]
    assert (f"{min(scipy):.0f}-{max(scipy):.0f}x the modeling's CPU time with scipy's DOP853"
            in text)
    assert f"{min(compiled):.2g}-{max(compiled):.2g}x with numbalsoda's" in text
    at_1e10 = [float(r["compiled CPU [s]"]) / float(r["modeling CPU [s]"]) for r in rows
               if float(r["scale separation"]) == 1e10 and r["class"] != "michaelis_menten"]
    as_recorded = [f"{v:.0f}" if v >= 10 else f"{v:.2g}" for v in (min(at_1e10), max(at_1e10))]
    assert "at 1e10, {}-{}x with numbalsoda's".format(*as_recorded) in text
