import atexit
import importlib.util
import os
import shutil
import tempfile
import warnings
from pathlib import Path

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


EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def example():
    """``example(name)``: the script ``examples/<name>.py`` loaded as a module (the test is
    skipped where examples/ is not present, as in an installed package's tests)."""
    def load(name):
        path = EXAMPLES / f"{name}.py"
        if not path.exists():
            pytest.skip("examples/ not present")
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    return load
