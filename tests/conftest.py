import os
import tempfile

# Kernels compiled by the tests go to a private cache unless the caller chose one.
os.environ.setdefault("DOLFINODE_CACHE_DIR", os.path.join(tempfile.gettempdir(), "dolfinode-test-cache"))
