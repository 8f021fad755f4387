import warnings

import numpy as np
import pytest

from touchloc.data import load_object


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
