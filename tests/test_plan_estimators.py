"""Any filter of touchloc.belief drives the active loop; free-space models; the old names."""

import warnings

import numpy as np
import pytest
import trimesh
from scipy.special import log_ndtr

from _slab import at_x as _at_x, make_box, make_model, x_region as _x_region
from touchloc.belief import HistogramFilter, ParticleFilter, PoseRegion, ScalingSeries, SMCFilter
from touchloc.errors import ValidationError
from touchloc.geometry import make_poses
from touchloc.models import (Contacts, FreeSpaceBase, FreeSpaceModel, MeshObject, ProximityModel, RayStopModel,
                             TouchLikelihood, ray_stops)
from touchloc.planners import GuardedTouch, OneStepPlanner, TouchResult, simulate
from touchloc.planners.candidates import CandidateGenerator
from touchloc.planners.loop import SimulatedWorld, active_localization


@pytest.fixture(scope="module")
def box():
    return make_box()


@pytest.fixture(scope="module")
def model(box):
    return make_model(box)


FILTERS = {
    "smc": lambda m: SMCFilter(m, 600, rng=0),
    "scaling_series": lambda m: ScalingSeries(m, progress=False, rng=0),
    "particle_filter": lambda m: ParticleFilter(m, n_particles=3000, rng=0),
    "histogram": lambda m: HistogramFilter(m, resolution=0.003, angular_resolution=np.radians(3.0)),
}


@pytest.mark.parametrize("name", list(FILTERS))
def test_every_filter_drives_the_active_loop(box, model, name):
    """Planar box (x, y, yaw), the same hidden pose and candidates for every estimator."""
    reg = PoseRegion.planar((0.0, 0.0), 0.03, z=0.015).with_rho(box.radius)
    true = reg.sample(1, rng=5)[0]
    world = SimulatedWorld(box, true, rng=0)
    gen = CandidateGenerator(reg, box, n_world=30, n_relative=20, seed=0)
    res = active_localization(world, model, reg, OneStepPlanner(model, max_particles=400), gen,
                              updater=FILTERS[name](model), max_touches=8, rng=0)
    errors = [s.error for s in res.steps]
    assert errors[0] > 0.005                # the prior's guess is centimetres off
    assert res.error < 0.005                # a few touches bring it to millimetres
    assert res.error < 0.5 * errors[0]
    assert res.belief is not None and len(res.steps) == res.touches + 1 <= 9


@pytest.mark.parametrize("name", list(FILTERS))
def test_a_miss_updates_every_filter(box, model, name):
    """A downward touch at x = 0.02 misses a box centred at x = -0.03: poses with the
    centre above -0.01 would have stopped it, so each filter moves its mass away."""
    world = SimulatedWorld(box, _at_x(-0.03)[0], noise_pos=0.0, noise_nor=0.0, rng=0)
    miss = world.execute(GuardedTouch((0.02, 0, 0.1), (0, 0, -1), 0.2))
    assert not miss[0].hit
    f = FILTERS[name](model)
    if name == "histogram":
        f = HistogramFilter(model, resolution=0.001)
    f.initialize(_x_region(box))
    b = f.update(miss)
    assert np.average(b.poses[:, 0, 3] < -0.005, weights=b.weights) > 0.97
    # then a contact from the side: the estimate lands on the true pose
    b = f.update(world.execute(GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5)))
    assert np.average(b.poses[:, 0, 3], weights=b.weights) == pytest.approx(-0.03, abs=0.002)


def test_contacts_still_update_as_before(box, model):
    """update(contacts) keeps its meaning: the same result as before the touch interface."""
    c = Contacts(np.array([[0.043, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    reg = _x_region(box)
    pf = ParticleFilter(model, n_particles=500, rng=0)
    pf.initialize(reg)
    prior = pf.belief
    b = pf.update(c, resample=False)
    np.testing.assert_allclose(b.log_weights, prior.reweighted(model.log_likelihood(prior.poses, c)).log_weights)
    with pytest.raises(ValidationError, match="executed touches"):
        pf.update([1, 2])
    with pytest.raises(ValidationError, match="Contacts"):
        pf.update(None)


def _old_ray_stop_loglik(obj, poses, results, sigma, eps=1e-3, margin=1.0):
    """The ray-stop free-space term as planners.update computed it, through planners.simulate."""
    out = simulate(obj, poses, [r.touch for r in results])
    s = np.where(out.hit, out.travel, np.inf)
    z = (s - np.array([r.travel for r in results])[None, :]) / sigma + margin
    return np.logaddexp(np.log(eps), np.log1p(-eps) + log_ndtr(z)).sum(axis=1)


def test_ray_stop_model_matches_the_planners_simulation(box, model):
    """A miss, a point-probe hit and a sphere-probe hit, scored at poses around the truth."""
    true = _at_x(0.013)[0]
    world = SimulatedWorld(box, true, noise_pos=0.0005, noise_nor=0.02, rng=0)
    touches = [GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5), GuardedTouch((0.05, 0, 0.1), (0, 0, -1), 0.2),
               GuardedTouch((0.0, 0.2, 0.0), (0, -1, 0), 0.4, probe_radius=0.004)]
    results = [r for t in touches for r in world.execute(t)]
    assert [r.hit for r in results] == [True, False, True]
    poses = PoseRegion.planar((0.013, 0.0), 0.03, z=0.0).with_rho(box.radius).sample(300, rng=3)
    new = RayStopModel.from_results(box, results, sigma=0.004).log_likelihood(poses)
    old = _old_ray_stop_loglik(box, poses, results, 0.004)
    np.testing.assert_allclose(new, old, rtol=0, atol=1e-12)
    assert np.ptp(new) > 5.0  # the case discriminates between poses
    # the stops are the planners' simulated travels
    out = simulate(box, poses, touches)
    np.testing.assert_allclose(np.where(out.hit, out.travel, np.inf),
                               RayStopModel.from_results(box, results).stops(poses))
    assert np.allclose(ray_stops(box, poses[:5], [[0.3, 0, 0]], [[-1, 0, 0]])[:, 0], out.travel[:5, 0])
    # the composition: contacts through the proximity model plus the ray stops
    tl = TouchLikelihood(model, results)
    c = Contacts.concatenate([r.contact for r in results if r.hit])
    np.testing.assert_allclose(tl.log_likelihood(poses),
                               model.log_likelihood(poses, c) + _old_ray_stop_loglik(box, poses, results, 0.004))


def test_free_space_models_share_one_interface(box, model):
    world = SimulatedWorld(box, _at_x(-0.03)[0], noise_pos=0.0, noise_nor=0.0, rng=0)
    miss = world.execute(GuardedTouch((0.02, 0, 0.1), (0, 0, -1), 0.2))
    xs = np.linspace(-0.04, 0.04, 41)
    for cls in (FreeSpaceModel, RayStopModel):
        assert issubclass(cls, FreeSpaceBase)
        fs = cls.from_results(box, miss, sigma=cls.default_sigma(model))
        ll = fs.log_likelihood(_at_x(xs))
        assert np.all(ll[xs > -0.005] < np.log(0.01)) and np.all(ll[xs < -0.015] > np.log(0.9)), cls
        # it carries its own data: contacts are ignored, so it adds to a contact model
        np.testing.assert_allclose((model + fs).log_likelihood(_at_x(xs), Contacts(np.zeros((1, 3)))),
                                   model.log_likelihood(_at_x(xs), Contacts(np.zeros((1, 3)))) + ll)
    assert RayStopModel.default_sigma(model) == pytest.approx(0.004)
    # any filter can use either model for the swept space
    pf = ParticleFilter(model, n_particles=400, rng=0)
    pf.initialize(_x_region(box))
    b = pf.update(miss, free_space=FreeSpaceModel)
    assert np.average(b.poses[:, 0, 3] < -0.005, weights=b.weights) > 0.97
    with pytest.raises(ValidationError, match="executed touches"):
        RayStopModel.from_results(box, [object()])
    with pytest.raises(ValidationError, match="sigma"):
        RayStopModel(box, [[0, 0, 0.1]], [[0, 0, -1]], 0.1, 0.2, sigma=0.0)


def test_old_names_warn_and_still_work(box, model):
    import touchloc.planners as planners

    for name in ("TouchFilter", "TouchLikelihood", "EstimatorUpdater"):
        with pytest.warns(DeprecationWarning, match=f"planners.{name} is deprecated"):
            getattr(planners, name)
    with pytest.warns(DeprecationWarning):
        from touchloc.planners import TouchFilter, TouchLikelihood as OldTL
    with pytest.warns(DeprecationWarning, match="SMCFilter"):
        f = TouchFilter(model, _x_region(box), 300, rng=1, sigma_free=0.005)
    assert isinstance(f, SMCFilter) and f.belief is not None and f.free_kwargs == {"sigma": 0.005}
    world = SimulatedWorld(box, _at_x(0.013)[0], noise_pos=0.0, noise_nor=0.0, rng=0)
    res = world.execute(GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5))
    with pytest.warns(DeprecationWarning, match="models.TouchLikelihood"):
        old = OldTL(model, res)
    P = _at_x([0.0, 0.013])
    np.testing.assert_array_equal(old.log_likelihood(P), TouchLikelihood(model, res).log_likelihood(P))
    from touchloc.planners.update import EstimatorUpdater

    with pytest.warns(DeprecationWarning, match="EstimatorUpdater"):
        up = EstimatorUpdater(model, _x_region(box), n_prior=300, rng=0)
    assert isinstance(up, ScalingSeries)
    with pytest.raises(AttributeError):
        planners.NoSuchName  # noqa: B018
    assert isinstance(res[0], TouchResult)


def test_smc_filter_static_use_and_validation(box, model):
    true = _at_x(0.013)[0]
    pts, nrm, _ = box.sample_surface(6, rng=4)
    c = Contacts(pts, nrm).transform(true)
    f = SMCFilter(model, 400, rng=0)
    with pytest.raises(ValidationError, match="initialize"):
        f.update(c)
    b = f.localize(c, _x_region(box))
    assert b.info["map_pose"][0, 3] == pytest.approx(0.013, abs=0.002)
    assert f.contacts is c and f.results == [] and len(f.info["stages"]) == 1
    assert f.update([]) is b                       # nothing new: the belief is unchanged
    with pytest.raises(ValidationError, match="static"):
        f.predict()
    with pytest.raises(ValidationError, match="n_particles"):
        SMCFilter(model, 5)
    with pytest.raises(ValidationError, match="ess_fraction"):
        SMCFilter(model, 100, ess_fraction=1.5)
