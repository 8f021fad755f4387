"""touchloc runs its linear algebra with BLAS on the threads TOUCHLOC_BLAS_THREADS allows (one
by default) inside the mapping package's calls and the estimators', and gives the process its own
setting back afterwards."""

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


# -- the estimators --------------------------------------------------------------------
def _recording_model(obj, seen):
    """A proximity model that records BLAS's threads at each likelihood call (a subclass,
    so the estimators call its ``log_likelihood``)."""
    from touchloc.models import ProximityModel

    class Recording(ProximityModel):
        def log_likelihood(self, poses, contacts=None, temperature=1.0):
            seen.append(_blas_threads())
            return super().log_likelihood(poses, contacts, temperature)

    return Recording(obj, 0.002, np.deg2rad(5))


@pytest.fixture
def touched(objects):
    from touchloc.belief import PoseRegion

    obj, rng = objects["milk"], np.random.default_rng(3)
    region = PoseRegion.box((0, 0, 0), 0.03, "yaw")
    true = region.sample(1, rng=rng)[0]
    p, n, _ = obj.sample_surface(8, rng=rng)
    return obj, Contacts(p + rng.normal(scale=0.002, size=p.shape), n).transform(true), region


def test_scaling_series_scales_run_blas_on_one_thread_and_not_between_them(two_threads, monkeypatch, touched):
    from touchloc.belief import ScalingSeries

    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    obj, contacts, region = touched
    seen, between = [], []
    ss = ScalingSeries(_recording_model(obj, seen), rng=0, progress=False)
    steps = 0
    for _ in ss.iterate(contacts, region):
        between.append(_blas_threads())
        steps += 1
    assert steps > 3 and len(seen) >= steps
    assert all(s == [1] for s in seen)
    assert all(s == [2] for s in between)
    # a generator left early gives the setting back too
    it = ss.iterate(contacts, region)
    next(it)
    it.close()
    assert _blas_threads() == [2]


@pytest.mark.parametrize("estimator", ["localize", "smc", "identify"])
def test_the_estimators_run_blas_on_one_thread(two_threads, monkeypatch, touched, estimator):
    from touchloc.belief import ScalingSeries, SMCFilter, identify

    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    obj, contacts, region = touched
    seen = []
    model = _recording_model(obj, seen)
    if estimator == "localize":
        ScalingSeries(model, rng=0, progress=False).localize(contacts, region)
    elif estimator == "smc":
        f = SMCFilter(model, 300, rng=0)
        f.initialize(region)
        f.update(contacts)
    else:
        identify({"milk": model}, contacts, region, rng=0)
    assert seen and all(s == [1] for s in seen)
    assert _blas_threads() == [2]


def test_a_limited_generator_passes_values_returns_and_raises_like_the_plain_one(two_threads, monkeypatch):
    from touchloc._util import blas_threads

    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    inside = []

    @blas_threads
    def gen(n):
        total = 0
        for i in range(n):
            inside.append(_blas_threads())
            got = yield i
            total += got or 0
        if total < 0:
            raise ValueError("negative")
        return total

    g = gen(3)
    assert next(g) == 0
    assert g.send(5) == 1
    assert g.send(6) == 2
    with pytest.raises(StopIteration) as stop:
        g.send(7)
    assert stop.value.value == 18
    assert inside == [[1]] * 3 and _blas_threads() == [2]
    g = gen(1)
    next(g)
    with pytest.raises(ValueError, match="negative"):
        g.send(-1)
    assert _blas_threads() == [2]


def test_explore_runs_blas_on_one_thread_between_the_maps_calls_too(two_threads, monkeypatch):
    """explore's own work (the planner's scoring, the callback after each touch) runs under
    the limit as well, not only the map's methods."""
    import trimesh

    from touchloc.mapping import explore
    from touchloc.models import MeshObject
    from touchloc.planners import SimulatedWorld

    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    sphere = MeshObject(trimesh.creation.icosphere(3, radius=0.03), name="sphere")
    world = SimulatedWorld(sphere, np.eye(4), noise_pos=0.001, noise_nor=0.087, rng=0)
    seen = []
    explore(world, ((-0.06,) * 3, (0.06,) * 3), 3, rng=0, callback=lambda run, step: seen.append(_blas_threads()))
    assert len(seen) == 3 and all(s == [1] for s in seen)
    assert _blas_threads() == [2]
