import atexit
import os
import shutil
import tempfile
import warnings

import numpy as np
import pytest

from touchloc.data import load_object

# Per-mesh structures built by the tests go to a cache directory of this run (shared by
# its subprocesses), never to the user's cache; removed at exit.
if "TOUCHLOC_CACHE_DIR" not in os.environ:
    os.environ["TOUCHLOC_CACHE_DIR"] = tempfile.mkdtemp(prefix="touchloc-test-cache-")
    atexit.register(shutil.rmtree, os.environ["TOUCHLOC_CACHE_DIR"], ignore_errors=True)


@pytest.fixture(scope="session")
def objects():
    """Bundled real meshes, loaded once (repair warnings silenced: tested elsewhere)."""
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in ["mug", "milk", "lemon", "can", "cereal", "bread"]:
            out[name] = load_object(name)
    return out


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
