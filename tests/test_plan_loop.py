"""Touch likelihood (contacts and free space), the SMC filter on touches, candidates and the active loop."""

import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from _slab import at_x as _at_x, make_box, make_model, x_region as _x_region
from touchloc.belief import ParticleBelief, PoseRegion, SMCFilter
from touchloc.errors import ValidationError
from touchloc.geometry import make_poses
from touchloc.models import MeshObject, ProximityModel, TouchLikelihood
from touchloc.planners import GuardedTouch, HandTouch, OneStepPlanner, RandomPlanner, simulate
from touchloc.planners.candidates import CandidateGenerator, hand_pool, relative_pool, world_pool
from touchloc.planners.loop import SimulatedWorld, active_localization
from touchloc.planners.metrics import add_s, expected_add_s, prob_error_below


@pytest.fixture(scope="module")
def box():
    return make_box()


@pytest.fixture(scope="module")
def model(box):
    return make_model(box)


def test_a_miss_is_negative_information(box, model):
    """A downward touch at x = 0.02 misses a box whose centre is at x = -0.03."""
    world = SimulatedWorld(box, _at_x(-0.03)[0], noise_pos=0.0, noise_nor=0.0, rng=0)
    touch = GuardedTouch((0.02, 0, 0.1), (0, 0, -1), 0.2)
    res = world.execute(touch)
    assert len(res) == 1 and not res[0].hit and res[0].travel == 0.2
    xs = np.linspace(-0.04, 0.04, 81)
    ll = TouchLikelihood(model, res).log_likelihood(_at_x(xs))
    # boxes reaching x = 0.02 (centre > -0.01) would have stopped the probe: ruled out
    assert np.all(ll[xs > -0.005] < np.log(0.01))
    assert np.all(ll[xs < -0.015] > np.log(0.9))
    f = SMCFilter(model, 400, rng=1)
    f.initialize(_x_region(box))
    b = f.update(res)
    x = b.poses[:, 0, 3]
    assert np.average(x < -0.005, weights=b.weights) > 0.97
    assert f.results == res


def test_filter_localises_from_one_contact(box, model):
    world = SimulatedWorld(box, _at_x(0.013)[0], noise_pos=0.0005, noise_nor=0.02, rng=0)
    res = world.execute(GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5))
    assert res[0].hit and res[0].contact.points[0, 0] == pytest.approx(0.043, abs=0.002)
    f = SMCFilter(model, 500, rng=2)
    f.initialize(_x_region(box))
    b = f.update(res)
    x = b.poses[:, 0, 3]
    m = np.average(x, weights=b.weights)
    sd = np.sqrt(np.average((x - m) ** 2, weights=b.weights))
    assert m == pytest.approx(0.013, abs=0.002)
    assert sd < 0.003
    # the contact explains the true pose better than one shifted by 5 mm
    ll = TouchLikelihood(model, res).log_likelihood(_at_x([0.013, 0.018, 0.008]))
    assert ll[0] > ll[1] + 2 and ll[0] > ll[2] + 2


def test_world_pool_starts_outside_and_aims_in(box):
    reg = PoseRegion.planar((0.0, 0.0), 0.05, z=0.015).with_rho(box.radius)
    pool = world_pool(reg, box, 50, rng=0, top_fraction=0.2)
    assert len(pool) == 50
    side = [t for t in pool if t.name.startswith("side")]
    top = [t for t in pool if t.name.startswith("top")]
    assert len(top) == 10
    r_min = np.linalg.norm(reg.half_extent) + box.radius
    for t in side:
        assert np.linalg.norm(t.origin[:2]) > r_min  # no object pose in the region touches the start
        assert abs(t.direction[2]) < 1e-12          # horizontal
        assert 0.0 < t.origin[2] < 0.03             # within the box's height on the table
    assert all(np.allclose(t.direction, [0, 0, -1]) for t in top)
    # some of them hit a box in the middle of the region
    out = simulate(box, reg.sample(20, rng=1), pool)
    assert 0.1 < out.hit.mean() < 0.9


def test_relative_pool_and_hands_hit_at_the_estimate(box):
    T = make_poses(trimesh.transformations.rotation_matrix(0.4, (0, 0, 1))[None, :3, :3], [[0.01, 0.02, 0.0]])[0]
    rel = relative_pool(T, box, 30, rng=0, standoff=0.03)
    out = simulate(box, T[None], rel)
    assert out.hit.all()
    np.testing.assert_allclose(out.travel[0], 0.03, atol=1e-6)  # they meet the surface where aimed
    hands = hand_pool(T, box, 5, n_fingers=3, rng=0)
    assert all(isinstance(h, HandTouch) and len(h.touches) == 3 for h in hands)
    out = simulate(box, T[None], hands)
    assert out.hit.all() and out.owner.tolist() == sorted(out.owner.tolist())


def test_planner_scores_hands(box):
    reg = PoseRegion.planar((0.0, 0.0), 0.02, z=0.015).with_rho(box.radius)
    b = ParticleBelief(reg.sample(300, rng=0), region=reg)
    T = np.eye(4)
    T[2, 3] = 0.015  # the estimate: the box standing on the table at the region's centre
    cands = hand_pool(T, box, 4, rng=0) + [GuardedTouch((0, 0, 0.3), (0, 0, -1), 0.05)]
    plan = OneStepPlanner(box).plan(b, cands, rng=0)
    # a three-finger closing says more than a touch that cannot reach the object
    assert plan.index < 4 and np.argmin(plan.scores) == 4
    assert np.all(plan.scores[:4] > plan.scores[4] + 1.0)


def test_add_s(box):
    I = np.eye(4)
    assert add_s(box, I, I) == pytest.approx(0.0, abs=1e-12)
    T = I.copy()
    T[0, 3] = 0.01
    assert 0.001 < add_s(box, T, I) <= 0.01 + 1e-9
    # a half turn about z maps the box onto itself: ADD-S sees no error, ADD would
    R = I.copy()
    R[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    p, _, _ = box.sample_surface(500, rng=0)
    add = np.linalg.norm(p @ R[:3, :3].T - p, axis=1).mean()
    assert add_s(box, R, I) < 0.2 * add
    batch = add_s(box, np.stack([I, T, R]), I)
    assert batch.shape == (3,) and batch[0] == pytest.approx(0.0, abs=1e-12)
    # a 1 cm shift along x moves only the points of the two x faces (22 % of the area)
    # off the surface, by 1 cm each
    area_x = 2 * 0.04 * 0.03 / (2 * (0.06 * 0.04 + 0.06 * 0.03 + 0.04 * 0.03))
    assert add_s(box, T, I, n=4000) == pytest.approx(0.01 * area_x, rel=0.1)
    # the classic form (nearest of the sampled points) is never below the surface form
    assert add_s(box, R, I, surface=False) >= add_s(box, R, I) + 1e-4


def test_expected_add_s_of_a_tight_belief(box):
    reg = _x_region(box)
    b = ParticleBelief(_at_x(np.random.default_rng(0).normal(0, 0.001, 200)), region=reg)
    e = expected_add_s(b, box)
    # particles ~N(0, 1 mm) along x: about 22 % of the area moves by E|dx| ~ 1.1 mm
    assert 0.0001 < e < 0.0006


def test_active_loop_localises_and_records(box, model):
    reg = PoseRegion.planar((0.0, 0.0), 0.03, z=0.015).with_rho(box.radius)
    true = reg.sample(1, rng=5)[0]
    world = SimulatedWorld(box, true, rng=0)
    gen = CandidateGenerator(reg, box, n_world=30, n_relative=20, seed=0)
    seen = []
    res = active_localization(world, model, reg, OneStepPlanner(model, max_particles=400), gen, n_particles=600,
                              max_touches=12, rng=0, keep_plans=True, callback=seen.append)
    assert res.confident
    assert res.error < 0.005
    assert len(res.steps) == res.touches + 1 == len(seen)
    # the default stopping rule: the belief claims P(ADD-S < 5 mm) >= 0.95 at the stop, not before
    assert res.steps[-1].p_within >= 0.95
    assert all(s.p_within < 0.95 for s in res.steps[1:-1])
    # the stop was checked by a second, independent run before it was taken
    assert res.steps[-1].verified and "second_opinion" in res.belief.info
    assert all(s.plan is not None and s.plan.scores.shape == (50,) for s in res.steps[1:])
    assert "touch" in res.table() and len(res.table().splitlines()) == res.touches + 3


def test_random_planner_is_uniform(box):
    reg = _x_region(box)
    b = ParticleBelief(reg.sample(10, rng=0), region=reg)
    cands = [GuardedTouch((0.3, y, 0), (-1, 0, 0), 0.5) for y in np.linspace(-0.02, 0.02, 5)]
    picks = [RandomPlanner().plan(b, cands, rng=s).index for s in range(500)]
    counts = np.bincount(picks, minlength=5)
    assert counts.min() > 70  # 100 expected each; 70 is > 3 sd below


def test_outputs_and_cli(tmp_path):
    from touchloc.cli import main

    rc = main(["active", "--mesh", "bread", "--max-touches", "2", "--particles", "300", "--candidates", "20",
               "--out", str(tmp_path), "--name", "t"])
    assert rc == 0
    assert (tmp_path / "t.png").stat().st_size > 10_000
    html = (tmp_path / "t.html").read_text()
    assert "<canvas" in html and '"touches": [' in html and "ADD-S" in html


def test_prob_error_below_counts_the_mass_within_the_threshold(box):
    reg = _x_region(box)
    # 70 % of the weight at the estimate, 30 % displaced by 20 mm along x
    P = _at_x(np.r_[np.zeros(7), np.full(3, 0.02)])
    b = ParticleBelief(P, np.log(np.r_[np.full(7, 0.1), np.full(3, 0.1)]), region=reg)
    assert prob_error_below(b, box, 0.005, ref=P[0]) == pytest.approx(0.7)
    assert prob_error_below(b, box, 0.05, ref=P[0]) == pytest.approx(1.0)


def test_legacy_confidence_rule_and_stop_validation(box, model):
    reg = PoseRegion.planar((0.0, 0.0), 0.03, z=0.015).with_rho(box.radius)
    world = SimulatedWorld(box, reg.sample(1, rng=5)[0], rng=0)
    gen = CandidateGenerator(reg, box, n_world=30, n_relative=20, seed=0)
    res = active_localization(world, model, reg, OneStepPlanner(model, max_particles=400), gen, n_particles=600,
                              max_touches=12, confidence=0.003, rng=0)
    assert res.confident and res.steps[-1].expected_error < 0.003
    assert np.isnan(res.steps[-1].p_within)
    for bad in ({"stop_probability": 1.5}, {"stop_error": -1.0}, {"confidence": 0.0}, {"verify_stop": "yes"}):
        with pytest.raises(ValidationError):
            active_localization(world, model, reg, OneStepPlanner(model), gen, max_touches=1, **bad)


def test_prob_error_below_in_the_pose_metric_modulo_symmetry(box):
    reg = PoseRegion.box((0, 0, 0), 0.05, "full").with_rho(box.radius)
    half = np.eye(4)
    half[:3, :3] = Rotation.from_rotvec([0, 0, np.pi]).as_matrix()   # a symmetry of the box
    quarter = np.eye(4)
    quarter[:3, :3] = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()   # not one
    P = np.stack([np.eye(4), half, quarter, _at_x(0.003)[0]])
    b = ParticleBelief(P, region=reg)
    # the identity, the half-turn and the 3 mm shift are within 5 mm; the quarter turn is not
    assert prob_error_below(b, box, 0.005, ref=np.eye(4), metric="pose") == pytest.approx(0.75)
    assert prob_error_below(b, box, 0.002, ref=np.eye(4), metric="pose") == pytest.approx(0.5)
    with pytest.raises(ValidationError):
        prob_error_below(b, box, 0.005, metric="nope")
