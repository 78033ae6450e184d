import os
import tempfile

import pytest

# Kernels compiled by the tests go to a private cache unless the caller chose one.
os.environ.setdefault("DOLFINODE_CACHE_DIR", os.path.join(tempfile.gettempdir(), "dolfinode-test-cache"))


def _environment(env=None):
    """os.environ with ``env`` added, for a fresh process that imports this dolfinode."""
    from pathlib import Path

    import dolfinode

    here = str(Path(dolfinode.__file__).parents[1])
    full = dict(os.environ, **(env or {}))
    full["PYTHONPATH"] = os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")]))
    return full


def _run_python(script, *args, env=None, timeout=300):
    """Run ``python -c script args`` in a fresh process that imports this dolfinode (with
    ``env`` added to the environment); returns the CompletedProcess (text output)."""
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-c", script, *map(str, args)],
                          env=_environment(env), capture_output=True, text=True,
                          timeout=timeout, check=False)


def _kill_python(script, *args, started, seconds):
    """Start ``python -c script args``, wait until it creates the file ``started``, let it
    run ``seconds`` more and kill it with SIGKILL (failing if it ended before)."""
    import signal
    import subprocess
    import sys
    import time

    process = subprocess.Popen([sys.executable, "-c", script, *map(str, args)],
                               env=_environment())
    try:
        deadline = time.monotonic() + 120
        while (not os.path.exists(started) and process.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.05)
        time.sleep(seconds)
        assert process.poll() is None, "the process ended before it was killed"
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()


@pytest.fixture(scope="session")
def run_python():
    """:func:`_run_python`: a script in a fresh process (crashes, signals, memory limits)."""
    return _run_python


@pytest.fixture(scope="session")
def kill_python():
    """:func:`_kill_python`: a script killed while it writes."""
    return _kill_python


@pytest.fixture(scope="session")
def stiff_springs():
    """40 masses, two springs 1e4 times stiffer: some multi-adaptive slabs synchronised
    (every component on one interval), the others partitioned."""
    from dolfinode.bench.problems import mass_spring_chain as chain_with_stiff_springs

    return chain_with_stiff_springs(n=40, stiffness=1e4, stiff_springs=2, T=0.1).ode
