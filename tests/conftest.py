import os
import tempfile

import pytest

# Kernels compiled by the tests go to a private cache unless the caller chose one.
os.environ.setdefault("DOLFINODE_CACHE_DIR", os.path.join(tempfile.gettempdir(), "dolfinode-test-cache"))


def _run_python(script, *args, env=None, timeout=300, preexec_fn=None):
    """Run ``python -c script args`` in a fresh process that imports this dolfinode (with
    ``env`` added to the environment); returns the CompletedProcess (text output)."""
    import subprocess
    import sys
    from pathlib import Path

    import dolfinode

    here = str(Path(dolfinode.__file__).parents[1])
    full = dict(os.environ, **(env or {}))
    full["PYTHONPATH"] = os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")]))
    return subprocess.run([sys.executable, "-c", script, *map(str, args)], env=full,
                          capture_output=True, text=True, timeout=timeout, check=False,
                          preexec_fn=preexec_fn)


@pytest.fixture(scope="session")
def run_python():
    """:func:`_run_python`: a script in a fresh process (crashes, signals, memory limits)."""
    return _run_python
