"""``dolfinode bench``'s outputs: a new folder by default, never over files git tracks without
--force, every default in --help, and ordinary file modes."""
import argparse
import os
import re
import stat
import subprocess

import pytest

from dolfinode.bench import report
from dolfinode.bench.command import OUTPUT_SUFFIXES, add_arguments
from dolfinode.cli import main

TINY_RUN = ["--problems", "decay", "--methods", "dG(1),LSODA", "--tolerances", "1e-3",
            "--repeats", "1", "--no-progress"]


def _git(folder, *args):
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=folder,
                   check=True, capture_output=True)


def test_default_output_is_a_new_folder_with_ordinary_file_modes(tiny_registered, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    old = os.umask(0o022)
    try:
        assert main(["bench", *TINY_RUN]) == 0
    finally:
        os.umask(old)
    (folder,) = tmp_path.iterdir()
    assert re.fullmatch(r"dolfinode-bench-\d{8}-\d{6}", folder.name)
    for suffix in OUTPUT_SUFFIXES:
        mode = stat.S_IMODE((folder / f"suite{suffix}").stat().st_mode)
        assert mode == 0o644, f"suite{suffix}: {oct(mode)}"
    record = (folder / "suite.md").read_text()
    assert "1 timed run" in record and "1 timed repeats" not in record
    # the decay problem is neither stiff nor multiscale: no empty target headings
    assert "Multiscale problems" not in record and "Stiff problems" not in record


def test_refuses_to_overwrite_files_git_tracks_unless_forced(tiny_registered, tmp_path, capsys):
    _git(tmp_path, "init", "-q")
    (tmp_path / "suite.md").write_text("committed record\n")
    _git(tmp_path, "add", "suite.md")
    _git(tmp_path, "commit", "-q", "-m", "record")
    with pytest.raises(SystemExit):
        main(["bench", *TINY_RUN, "--output", str(tmp_path)])
    err = capsys.readouterr().err
    assert "refusing to overwrite" in err and "suite.md" in err and "--force" in err
    assert (tmp_path / "suite.md").read_text() == "committed record\n"
    assert not (tmp_path / "suite.json").exists()  # refused before running anything
    # an untracked README is fine to update; a tracked one is refused as well
    readme = tmp_path / "README.md"
    readme.write_text("# x\n")
    _git(tmp_path, "add", "README.md")
    with pytest.raises(SystemExit):
        main(["bench", *TINY_RUN, "--output", str(tmp_path / "new"), "--update-readme",
              str(readme)])
    assert "README.md" in capsys.readouterr().err
    assert main(["bench", *TINY_RUN, "--output", str(tmp_path), "--force"]) == 0
    assert "decay" in (tmp_path / "suite.md").read_text()


def test_merge_and_report_only_need_an_output_folder(capsys):
    for flag in ("--merge", "--report-only"):
        with pytest.raises(SystemExit):
            main(["bench", flag, "--no-progress"])
        assert "need the --output folder" in capsys.readouterr().err


def test_an_output_folder_that_cannot_be_made_is_refused_before_running(tiny_registered, tmp_path,
                                                                        capsys):
    """--output under a regular file: refused at once; the run went through every problem
    and then failed in mkdir with a traceback."""
    (tmp_path / "file").write_text("")
    with pytest.raises(SystemExit):
        main(["bench", *TINY_RUN, "--output", str(tmp_path / "file" / "out")])
    err = capsys.readouterr().err
    assert "cannot make the output folder" in err and "--output" in err


def test_help_shows_every_default():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    options = [a for a in parser._actions if a.option_strings != ["-h", "--help"]]
    assert {"--output", "--force"} <= {a.option_strings[0] for a in options}
    for action in options:
        assert "default" in action.help, action.option_strings[0]
    assert "dolfinode-bench-YYYYMMDD-HHMMSS" in "".join(parser.format_help().split())


def test_quick_target_section_has_no_empty_heading():
    entry = {"level": 6, "ratio": 0.5, "dolfinode_best": "dG(2)", "scipy_best": "Radau"}
    heads = {"p": {"stiff": True, "multiscale": False, "table": [entry]}}
    section = report.target_section(heads)
    assert "Stiff problems" in section and "Multiscale problems" not in section
