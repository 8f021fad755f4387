"""The mapping package runs its linear algebra with BLAS on the threads TOUCHLOC_BLAS_THREADS
allows (one by default), and gives the process its own setting back afterwards."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from touchloc._util import BLAS_THREADS_ENV
from touchloc.errors import ValidationError
from touchloc.mapping import ShapeMap
from touchloc.models import Contacts
from touchloc.planners import GuardedTouch, TouchResult


def _blas_threads():
    return sorted({m["num_threads"] for m in threadpool_info() if m["user_api"] == "blas"})


def _results(n=6):
    """Touches on a sphere of 30 mm about the origin, from six sides."""
    u = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)[:n]
    out = []
    for d in u:
        touch = GuardedTouch(0.08 * d, -d, 0.1)
        out.append(TouchResult(touch, 0.05, Contacts(0.03 * d[None], d[None])))
    return out


def _recording_map(seen):
    def prior(X):
        seen.append(_blas_threads())
        r = np.linalg.norm(X, axis=1)
        return r - 0.03, X / np.maximum(r, 1e-9)[:, None]

    return ShapeMap(((-0.06,) * 3, (0.06,) * 3), prior=prior)


@pytest.fixture
def two_threads():
    if not _blas_threads():
        pytest.skip("no BLAS library that threadpoolctl can see")
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() != [2]:
            pytest.skip("BLAS here cannot run two threads")
        yield


def test_map_updates_run_blas_on_one_thread_and_restore_the_process_setting(two_threads, monkeypatch):
    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    seen = []
    m = _recording_map(seen)
    m.update(_results())
    m.signed_distance(np.zeros((4, 3)))
    assert seen and all(s == [1] for s in seen)
    assert _blas_threads() == [2]


@pytest.mark.parametrize("value, expect", [("0", [2]), ("3", [3]), ("", [2])])
def test_the_environment_sets_or_lifts_the_limit(two_threads, monkeypatch, value, expect):
    monkeypatch.setenv(BLAS_THREADS_ENV, value)
    seen = []
    _recording_map(seen).update(_results())
    assert seen and all(s == expect for s in seen)
    assert _blas_threads() == [2]


@pytest.mark.parametrize("value", ["two", "-1", "1.5"])
def test_a_bad_thread_count_is_a_clear_error_and_the_map_is_unchanged(monkeypatch, value):
    m = ShapeMap(((-0.06,) * 3, (0.06,) * 3))
    m.update(_results(3))
    monkeypatch.setenv(BLAS_THREADS_ENV, value)
    with pytest.raises(ValidationError, match=BLAS_THREADS_ENV):
        m.update(_results())
    assert m.n_contacts == 3
