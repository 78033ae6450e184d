"""The record file of benchmarks/run_per_call.py: a new "Latest" section, the history kept."""


def test_a_run_replaces_the_latest_section_and_keeps_the_history(tmp_path, benchmark_script):
    """The text before "## Latest" stays, the replaced section becomes "## Earlier", and the
    dated sections after it stay in order; a missing file gets a title."""
    write_latest = benchmark_script("run_per_call").write_latest
    path = tmp_path / "per_call.md"
    path.write_text("# Per-call cost\n\nHow it is measured.\n\n## Latest (git a)\n\nold table\n\n"
                    "## 2026-11-27: the first record\n\nfirst table\n")
    write_latest(path, ["## Latest (git b)", "", "new table"])
    assert path.read_text() == (
        "# Per-call cost\n\nHow it is measured.\n\n## Latest (git b)\n\nnew table\n\n"
        "## Earlier (git a)\n\nold table\n\n## 2026-11-27: the first record\n\nfirst table\n")
    fresh = tmp_path / "new.md"
    write_latest(fresh, ["## Latest (git c)", "", "table"])
    assert fresh.read_text() == "# Per-call cost\n\n## Latest (git c)\n\ntable\n"
