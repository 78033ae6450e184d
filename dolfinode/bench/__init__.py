"""The benchmark suite: problem set, runner, scoring and reports (``dolfinode bench``)."""
