"""Simulation of guarded touches and one-/two-step planning on cases with known answers."""

import warnings

import numpy as np
import pytest
import trimesh

from touchloc.belief import ParticleBelief, PoseRegion
from touchloc.errors import PlanningError, ValidationError
from touchloc.geometry import make_poses
from touchloc.models import MeshObject
from touchloc.planners import (GuardedTouch, HandTouch, OneStepPlanner, TaskSuccess,
                               TravelDistance, TravelTime, TwoStepPlanner, simulate)
from touchloc.planners.utilities import batched_entropy


@pytest.fixture(scope="module")
def box():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.box((0.06, 0.06, 0.06)), name="box")


@pytest.fixture(scope="module")
def x_belief(box):
    """A 6 cm cube whose position is unknown along x only (+-4 cm)."""
    reg = PoseRegion.box((0, 0, 0), (0.04, 0, 0), rotation=np.eye(3)).with_rho(box.radius)
    return ParticleBelief(reg.sample(400, rng=1), region=reg)


def _axis_touches():
    return [GuardedTouch((0, 0.3, 0), (0, -1, 0), 0.5, name="+y"),
            GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5, name="+x"),
            GuardedTouch((0, 0, 0.3), (0, 0, -1), 0.5, name="+z"),
            GuardedTouch((0, -0.3, 0.01), (0, 1, 0), 0.5, name="-y")]


def test_simulate_matches_box_geometry(box):
    rng = np.random.default_rng(0)
    t = rng.uniform(-0.02, 0.02, (50, 3))
    poses = make_poses(np.repeat(np.eye(3)[None], 50, axis=0), t)
    touches = [GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5), GuardedTouch((0, 0, 0.3), (0, 0, -1), 0.5),
               GuardedTouch((0.3, 0.2, 0), (-1, 0, 0), 0.5)]
    out = simulate(box, poses, touches)
    # +x face of the cube sits at x = t_x + 0.03: the probe travels 0.3 - that
    np.testing.assert_allclose(out.travel[:, 0], 0.3 - (t[:, 0] + 0.03), atol=1e-6)
    np.testing.assert_allclose(out.points[:, 0, 0], t[:, 0] + 0.03, atol=1e-6)
    np.testing.assert_allclose(out.normals[:, 0], np.tile([1.0, 0, 0], (50, 1)), atol=1e-9)
    np.testing.assert_allclose(out.travel[:, 1], 0.3 - (t[:, 2] + 0.03), atol=1e-6)
    assert out.hit[:, :2].all()
    # the third ray passes 0.2 m to the side: a miss, travel = max_travel, NaN point
    assert not out.hit[:, 2].any()
    assert np.all(out.travel[:, 2] == 0.5) and np.isnan(out.points[:, 2]).all()


def test_simulate_rotated_pose_and_sphere_probe(box):
    R = trimesh.transformations.rotation_matrix(np.pi / 4, (0, 0, 1))[:3, :3]
    T = make_poses(R[None], np.zeros((1, 3)))
    # a 45-degree cube: the corner is at sqrt(2) * 0.03 along x
    out = simulate(box, T, [GuardedTouch((0.3, 0, 0.0), (-1, 0, 0), 0.5),
                            GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5, probe_radius=0.01)])
    assert out.travel[0, 0] == pytest.approx(0.3 - np.sqrt(2) * 0.03, abs=1e-6)
    # a flat face met head-on: a sphere stops exactly its radius earlier than a point
    flat = simulate(box, np.eye(4)[None], [GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5),
                                           GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5, probe_radius=0.01)])
    assert flat.travel[0, 1] == pytest.approx(flat.travel[0, 0] - 0.01, abs=1e-6)
    assert flat.points[0, 1, 0] == pytest.approx(0.03, abs=1e-6)  # the contact is on the face


def test_trusted_touches_are_the_checked_constructors_touches():
    # planners build touches from values they computed themselves without the checks: the
    # touch must be the one the constructor makes (normalised direction, read-only arrays)
    rng = np.random.default_rng(3)
    for _ in range(50):
        o, d = rng.normal(size=3), rng.normal(size=3) * rng.uniform(0.1, 10)
        travel, r = rng.uniform(0.01, 1), rng.uniform(0, 0.01)
        a, b = GuardedTouch(o, d, travel, r, name="t"), GuardedTouch._trusted(o, d, travel, r, "t")
        assert np.array_equal(a.origin, b.origin) and np.array_equal(a.direction, b.direction)
        assert (a.max_travel, a.probe_radius, a.name) == (b.max_travel, b.probe_radius, b.name)
        assert a == b and hash(a) == hash(b)
        assert not b.origin.flags.writeable and not b.direction.flags.writeable
        assert type(b.max_travel) is float and type(b.probe_radius) is float


def test_hand_touch_is_several_fingers(box):
    hand = HandTouch((GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5), GuardedTouch((-0.3, 0, 0), (1, 0, 0), 0.5)))
    out = simulate(box, np.eye(4)[None], [GuardedTouch((0, 0.3, 0), (0, -1, 0), 0.5), hand])
    assert out.owner.tolist() == [0, 1, 1]
    np.testing.assert_allclose(out.travel[0], [0.27, 0.27, 0.27], atol=1e-6)
    np.testing.assert_allclose(out.normals[0, 2], [-1, 0, 0], atol=1e-9)


@pytest.mark.parametrize("utility", ["entropy", "kl"])
def test_best_touch_is_along_the_unknown_axis(box, x_belief, utility):
    cands = _axis_touches()
    plan = OneStepPlanner(box, utility=utility).plan(x_belief, cands, rng=0)
    assert plan.action.name == "+x"
    assert plan.action is cands[1]
    assert plan.scores.shape == (4,) and np.all(np.isfinite(plan.scores))
    # touches across x tell nothing: they score as the current belief does (within noise)
    assert plan.scores[1] > max(plan.scores[0], plan.scores[2], plan.scores[3]) + 0.5


def test_expected_entropy_matches_exact_posterior(box, x_belief):
    """The +x touch measures x to ~sigma_travel: expected entropy near that of N(., sigma)."""
    sig = 0.004
    plan = OneStepPlanner(box, sigma_travel=sig, n_observations=12).plan(x_belief, _axis_touches(), rng=0)
    h_exact = 0.5 * np.log(2 * np.pi * np.e * (sig**2 + 5e-4**2))
    # a posterior from a Gaussian likelihood of width sig over a uniform prior of 8 cm:
    # its entropy is that of N(0, sig^2) (plus the floor); canonical observations are
    # particles, so the sampled posterior is within ~0.3 nats
    assert -plan.details["value"][1] == pytest.approx(h_exact, abs=0.3)


def test_two_step_agrees_on_the_known_case(box, x_belief):
    plan = TwoStepPlanner(box, branch=None).plan(x_belief, _axis_touches(), rng=0)
    assert plan.action.name == "+x"
    assert np.all(np.isfinite(plan.scores))
    # two touches can only know more than one
    assert plan.scores[1] >= plan.details["one_step"][1] - 1e-9


def test_two_step_prunes_with_branch(box, x_belief):
    plan = TwoStepPlanner(box, branch=2).plan(x_belief, _axis_touches(), rng=0)
    assert np.isfinite(plan.scores).sum() == 2 and plan.info["expanded"] == 2
    assert plan.action.name == "+x"


def test_large_beta_prefers_the_cheap_touch(box, x_belief):
    far = GuardedTouch((1.0, 0, 0), (-1, 0, 0), 1.5, name="far +x")   # informative, ~1 m of travel
    near = GuardedTouch((0, 0.05, 0), (0, -1, 0), 0.1, name="near +y")  # ~2 cm, says little
    cands = [far, near]
    assert OneStepPlanner(box, beta=0.0).plan(x_belief, cands, rng=0).action is far
    plan = OneStepPlanner(box, beta=20.0, cost=TravelDistance()).plan(x_belief, cands, rng=0)
    assert plan.action is near
    assert plan.details["cost"][0] == pytest.approx(0.97, abs=0.05)
    # near +y: 2 cm when it meets the top face, its full 10 cm when the cube is off to the side
    p_hit = plan.details["p_hit"][1]
    assert 0.5 < p_hit < 1.0
    assert plan.details["cost"][1] == pytest.approx(0.02 * p_hit + 0.1 * (1 - p_hit), abs=1e-3)
    # a time cost works the same way
    plan = OneStepPlanner(box, beta=10.0, cost=TravelTime(speed=0.05, overhead=0.0)).plan(x_belief, cands, rng=0)
    assert plan.action is near


def test_task_success_ignores_unimportant_dimensions(box):
    """Uncertain in x and y; the grasp only needs x: touch along x, not y."""
    reg = PoseRegion.box((0, 0, 0), (0.02, 0.04, 0), rotation=np.eye(3)).with_rho(box.radius)
    b = ParticleBelief(reg.sample(400, rng=2), region=reg)
    cands = [GuardedTouch((0, 0.3, 0), (0, -1, 0), 0.5, name="+y"), GuardedTouch((0.3, 0, 0), (-1, 0, 0), 0.5, name="+x")]
    util = TaskSuccess([0.005, np.inf])
    plan = OneStepPlanner(box, utility=util).plan(b, cands, rng=0)
    assert plan.action.name == "+x"
    assert util.success(b) < 0.4 < plan.scores[1]
    # the entropy utility prefers y here (y is the wider dimension)
    assert OneStepPlanner(box).plan(b, cands, rng=0).action.name == "+y"


def test_batched_entropy_of_gaussian_samples():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(20000, 2)) * [0.01, 0.02]
    w = np.full((1, len(X)), 1 / len(X))
    h = batched_entropy(X, w, 1e-9)[0]
    assert h == pytest.approx(np.log(2 * np.pi * np.e) + np.log(0.01) + np.log(0.02), abs=0.02)


def test_errors_say_what_was_wrong(box, x_belief):
    p = OneStepPlanner(box)
    with pytest.raises(ValidationError, match="empty"):
        p.plan(x_belief, [], rng=0)
    with pytest.raises(ValidationError, match="candidate 1 must be a GuardedTouch or a HandTouch, got str"):
        p.plan(x_belief, [_axis_touches()[0], "touch"], rng=0)
    with pytest.raises(ValidationError, match="ParticleBelief"):
        p.plan(np.eye(4), _axis_touches(), rng=0)
    with pytest.raises(ValidationError, match="beta"):
        OneStepPlanner(box, beta=-1)
    with pytest.raises(ValidationError, match="utility"):
        OneStepPlanner(box, utility="fun")
    with pytest.raises(ValidationError, match="MeshObject"):
        OneStepPlanner(object())
    assert issubclass(PlanningError, Exception)


def test_plan_table_and_ranking(box, x_belief):
    from touchloc.planners import RandomPlanner

    cands = _axis_touches()
    plan = OneStepPlanner(box).plan(x_belief, cands, rng=0)
    rank = plan.ranking(2)
    assert rank[0] == (1, plan.scores[1]) and rank[0][1] >= rank[1][1]
    text = plan.table(3)
    assert len(text.splitlines()) == 4 and "+x" in text.splitlines()[1]
    rnd = RandomPlanner().plan(x_belief, cands, rng=0)
    assert rnd.action in cands and "nan" in rnd.table(1)


def test_travel_time_cost():
    t = GuardedTouch((0.1, 0, 0), (-1, 0, 0), 0.2)
    hand = HandTouch((t, GuardedTouch((-0.1, 0, 0), (1, 0, 0), 0.2)))
    c = TravelTime(speed=0.1, overhead=1.0)
    assert c(t, np.array([[0.05]]))[0] == pytest.approx(1.0 + 2 * 0.05 / 0.1)
    # fingers move at once: the slowest one counts
    assert c(hand, np.array([0.02, 0.08])) == pytest.approx(1.0 + 2 * 0.08 / 0.1)
    assert TravelDistance()(hand, np.array([0.02, 0.08])) == pytest.approx(0.1)
    home = TravelTime(speed=0.1, overhead=0.0, home=(0.1, 0.2, 0), approach_speed=0.5)
    assert home(t, np.array([0.0])) == pytest.approx(2 * 0.2 / 0.5)


def test_two_step_subtracts_first_costs(box, x_belief):
    """Eq. 42.16: with a large beta the two-step planner also takes the cheap touch."""
    far = GuardedTouch((1.0, 0, 0), (-1, 0, 0), 1.5, name="far +x")
    near = GuardedTouch((0, 0.05, 0), (0, -1, 0), 0.1, name="near +y")
    assert TwoStepPlanner(box, branch=None).plan(x_belief, [far, near], rng=0).action is far
    plan = TwoStepPlanner(box, branch=None, beta=20.0).plan(x_belief, [far, near], rng=0)
    assert plan.action is near


def test_touches_that_start_inside_the_object_are_infeasible(box, x_belief):
    # starts inside every box centred within 3 cm of the origin: 75 % of the belief
    inside = GuardedTouch((0.0, 0, 0), (-1, 0, 0), 0.5, name="from the centre")
    cands = _axis_touches() + [inside]
    plan = OneStepPlanner(box).plan(x_belief, cands, rng=0)
    assert plan.details["p_collision"][4] == pytest.approx(0.75, abs=0.06)
    assert plan.details["p_collision"][1] == 0.0
    assert plan.scores[4] == -np.inf and plan.action.name == "+x"
    # inside the boxes centred at x > 0.01 only (3/8 of the belief)
    partly = GuardedTouch((0.04, 0, 0), (-1, 0, 0), 0.5)
    p = OneStepPlanner(box, max_collision=0.5).plan(x_belief, [partly, cands[0]], rng=0)
    assert p.details["p_collision"][0] == pytest.approx(0.375, abs=0.06) and np.isfinite(p.scores[0])
    assert OneStepPlanner(box).plan(x_belief, [partly, cands[0]], rng=0).scores[0] == -np.inf
    # when every candidate collides, the least likely to are kept
    p = OneStepPlanner(box).plan(x_belief, [inside, partly], rng=0)
    assert p.action is partly
    two = TwoStepPlanner(box, branch=None).plan(x_belief, cands, rng=0)
    assert two.scores[4] == -np.inf and two.action.name == "+x"
