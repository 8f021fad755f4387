"""Tactile SLAM: an object that moves while it is mapped."""

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touchloc.belief import add_s
from touchloc.errors import ValidationError
from touchloc.mapping import MovingWorld, ShapeMap, TactileSLAM, chamfer_distance, explore, hand_pool
from touchloc.mapping._feature_turn import FeatureTurn


@pytest.fixture(scope="module")
def milk():
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_object("milk")


def _box(obj, pad):
    lo, hi = obj.bounds
    return lo - pad, hi + pad


def test_slam_follows_a_pushed_object_where_a_static_map_smears(milk):
    push = dict(push=(0.002, np.deg2rad(2.0)), planar=True)
    slam = TactileSLAM(_box(milk, 0.03), planar=True, sigma_pos=0.001, sigma_nor=0.087, rng=0)
    world = MovingWorld(milk, rng=1, **push)
    run = explore(world, _box(milk, 0.06), 30, slam=slam, fingers=3, rng=0)
    static_world = MovingWorld(milk, rng=1, **push)
    static = explore(static_world, _box(milk, 0.06), 30, fingers=3, rng=0)
    # the SLAM map lives in the object frame; the static map assumes the object never moved
    c_slam = chamfer_distance(run.map.to_mesh(), milk, n=3000)
    c_static = chamfer_distance(static.map.to_mesh(), milk, n=3000)
    assert c_slam < 0.9 * c_static
    # pose error along the whole run (the static map's estimate is the start pose)
    drift_slam = np.median([add_s(milk, a, b) for a, b in zip(slam.trajectory[1:], world.trajectory[1:])])
    drift_static = np.median([add_s(milk, np.eye(4), b) for b in static_world.trajectory[1:]])
    assert drift_slam < drift_static
    assert len(slam.trajectory) == 31 and run.map is slam.map


def test_a_thinned_map_relocates_like_a_refit_and_leaves_out_repeats(milk):
    push = dict(push=(0.002, np.deg2rad(2.0)), planar=True)
    slam = TactileSLAM(_box(milk, 0.03), planar=True, sigma_pos=0.001, sigma_nor=0.087, rng=0, thin=0.5)
    run = explore(MovingWorld(milk, rng=1, **push), _box(milk, 0.06), 40, slam=slam, fingers=3, rng=0)
    smap = run.map
    assert smap.thin == 0.5 and 0 < smap.thinned < smap.n_contacts
    assert len(slam.info["smoothing"]) >= 2                 # relocations ran on the thinned rows
    # every contact is kept in the record; only the rest are rows of the GPIS (one per gradient axis)
    assert len(smap.contacts) == smap.n_contacts
    assert int(np.sum(smap._gp.kind == 0)) == smap.n_contacts - smap.thinned
    q = np.random.default_rng(0).uniform(*_box(milk, 0.01), (200, 3))
    before = smap.signed_distance(q)
    smap.refit()
    assert np.allclose(smap.signed_distance(q), before, atol=1e-9)


def test_odometry_is_used_and_its_bias_corrected(milk):
    kw = dict(push=(0.0, 0.0), inhand=True, step=np.deg2rad(15.0), bias=0.05)
    errs = []
    for seed in (2, 3, 4, 5, 6):
        world = MovingWorld(milk, rng=seed, **kw)
        slam = TactileSLAM(_box(milk, 0.03), motion=(0.0005, np.deg2rad(0.5)),
                           odometry_noise=(0.0005, np.deg2rad(1.5)), sigma_pos=0.001, sigma_nor=0.087, rng=0)
        explore(world, _box(milk, 0.06), 24, slam=slam, fingers=3, rng=0)
        R_est, R_true = slam.pose[:3, :3], world.trajectory[-1][:3, :3]
        errs.append(np.degrees(np.arccos(np.clip((np.trace(R_est.T @ R_true) - 1) / 2, -1, 1))))
        assert world.odometry() is not None
    # integrating the biased odometry alone is off by 24 x 0.75 deg = 18 deg after one turn;
    # single runs scatter (4-16 deg over seeds 2-7), so the claim is on the median of five
    assert np.median(errs) < 12.0


def test_odometry_scale_learned_from_the_map_and_left_alone_without_bias():
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bread = load_object("bread")
    learned = {}
    for bias in (0.05, 0.0):
        world = MovingWorld(bread, rng=1, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0), bias=bias)
        slam = TactileSLAM(_box(bread, 0.03), motion=(0.0005, np.deg2rad(0.5)),
                           odometry_noise=(0.0005, np.deg2rad(1.5)), learn_odometry_scale=True,
                           sigma_pos=0.001, sigma_nor=0.087, rng=1)
        explore(world, _box(bread, 0.06), 72, slam=slam, fingers=3, rng=1)
        assert len(slam.info["odometry_scale"]) > 10   # the guard let it learn
        learned[bias] = slam.odometry_scale
    # the odometry reports 1.05 x the turn: the right scale is 1 / 1.05 = 0.952; the estimate
    # wanders by about 2 % about it (0.93-0.97 over the meshes and seeds of the benchmark)
    assert abs(learned[0.05] - 1 / 1.05) < 0.03
    assert abs(learned[0.0] - 1.0) < 0.03
    assert learned[0.05] < learned[0.0] - 0.02
    fixed = TactileSLAM(_box(bread, 0.03))
    assert fixed.odometry_scale == 1.0 and not fixed.learn_odometry_scale


def test_a_calibrated_odometry_scale_is_applied_and_can_be_held(milk):
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 20.0, degrees=True).as_matrix()
    yaw = {}
    for scale in (1.0, 0.95):
        slam = TactileSLAM(_box(milk, 0.03), odometry_noise=(0.0005, np.deg2rad(1.0)), odometry_scale=scale, rng=0)
        slam.update([], odometry=turn)   # no touches: the pose is the odometry's, scaled
        yaw[scale] = Rotation.from_matrix(slam.pose[:3, :3]).as_euler("xyz", degrees=True)[2]
    # 300 particles spread by 1 deg: their mean is within about 0.1 deg of the scaled turn
    assert abs(yaw[1.0] - 20.0) < 0.3 and abs(yaw[0.95] - 19.0) < 0.3
    # held (prior sd 0) while learning is on: the scale never moves, though the map would move it
    world = MovingWorld(milk, rng=1, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0), bias=0.05)
    held = TactileSLAM(_box(milk, 0.03), motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, np.deg2rad(1.5)),
                       learn_odometry_scale=True, odometry_scale=0.97, odometry_scale_sd=0.0,
                       sigma_pos=0.001, sigma_nor=0.087, rng=1)
    explore(world, _box(milk, 0.06), 30, slam=held, fingers=3, rng=1)
    assert held.map.n_contacts > 30 and held.odometry_scale == 0.97
    assert "odometry_scale" not in held.info


def test_calibrate_odometry_reads_scale_and_noise_off_the_trajectory(milk):
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 20.0, degrees=True).as_matrix()
    for scale in (1.0, 0.95):
        slam = TactileSLAM(_box(milk, 0.03), odometry_noise=(0.0005, np.deg2rad(1.0)), odometry_scale=scale, rng=0)
        for _ in range(3):
            slam.update([], odometry=turn)   # no touches: the trajectory is the scaled odometry
        cal = slam.calibrate_odometry()
        # 300 particles spread by 1 deg a step: their mean is within about 0.1 deg of 20 * scale
        assert abs(cal.scale - scale) < 0.01 and cal.updates == 3
        # sqrt(3) deg of odometry noise (and the tracked turn's own) over 60 deg reported
        assert np.deg2rad(1.0) * np.sqrt(3) / np.deg2rad(60.0) <= cal.scale_sd < 0.1
        # each step turned as reported (scaled), up to the particles' mean
        assert 0.0 <= cal.turn_noise < np.deg2rad(0.3)
    # a biased odometry on a box: the estimated trajectory turns 1 / 1.05 of what was reported,
    # whatever scale the run applied (its own pushes of 0.5 deg a step, and the final turn's
    # error, leave a spread of about 0.6 % over 48 steps of 15 deg)
    for applied in (1.0, 0.97):
        world = MovingWorld(milk, rng=2, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0), bias=0.05)
        slam = TactileSLAM(_box(milk, 0.03), motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, np.deg2rad(1.5)),
                           odometry_scale=applied, sigma_pos=0.001, sigma_nor=0.087, rng=2)
        explore(world, _box(milk, 0.06), 48, slam=slam, fingers=3, rng=2)
        cal = slam.calibrate_odometry()
        assert abs(cal.scale - 1 / 1.05) < 0.02, cal   # (measured: 1.1 % and 0.2 % off)
        assert 0.0 < cal.scale_sd < 0.03 and cal.updates == 48
        # the pushes turn it by 0.5 deg a step beside the odometry; the trajectory's own
        # per-step error adds to that, and the 1.5 deg the run assumed is far above both
        assert np.deg2rad(0.2) < cal.turn_noise < np.deg2rad(1.2), np.degrees(cal.turn_noise)
    # nothing to calibrate from: no update with an odometry, or none that turned
    slam = TactileSLAM(_box(milk, 0.03), rng=0)
    with pytest.raises(ValidationError, match="odometry"):
        slam.calibrate_odometry()
    slam.update([])
    for _ in range(3):
        slam.update([], odometry=np.eye(4))
    slam.update([], odometry=turn)
    with pytest.raises(ValidationError, match="has 1"):
        slam.calibrate_odometry()


def test_calibrate_odometry_refuses_a_turn_the_touches_never_showed():
    """A can turned in the hand: its touches cannot show the turn about its axis, so the
    estimated turns are the odometry's own, and the scale they imply is the prior's. The
    calibration says so instead of returning it with the odometry noise's small spread."""
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        can = load_object("can")
    world = MovingWorld(can, rng=1, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0), bias=0.05)
    slam = TactileSLAM(_box(can, 0.03), motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, np.deg2rad(1.5)),
                       learn_odometry_scale=True, sigma_pos=0.001, sigma_nor=0.087, rng=1)
    explore(world, _box(can, 0.06), 24, slam=slam, fingers=3, rng=1)
    shown = [st["turn_shown"] for st in slam._steps]
    assert shown.count(False) > 18      # the in-hand path ran, and the body hid the turn
    with pytest.raises(ValidationError, match="showed the turn in only"):
        slam.calibrate_odometry()


def test_slam_bad_input(milk):
    with pytest.raises(ValidationError):
        TactileSLAM(((0, 0, 0), (1, 1, np.nan)))
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), n_particles=10**9)
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), motion=(-1.0, 0.0))
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), learn_odometry_scale="yes")
    for bad in (0.5, 2.0, np.nan, True, "1"):
        with pytest.raises(ValidationError, match="odometry_scale"):
            TactileSLAM(_box(milk, 0.02), odometry_scale=bad)
    for bad in (-0.01, 0.6, np.inf, None):
        with pytest.raises(ValidationError, match="odometry_scale_sd"):
            TactileSLAM(_box(milk, 0.02), odometry_scale_sd=bad)
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02)).pose_covariance(predict="yes")
    slam = TactileSLAM(_box(milk, 0.02))
    reflect = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValidationError):
        slam.update([], odometry=reflect)
    with pytest.raises(ValidationError):
        slam.update(["nope"])
    with pytest.raises(ValidationError):
        MovingWorld("milk")
    with pytest.raises(ValidationError):
        explore(MovingWorld(milk), _box(milk, 0.05), 3, slam=ShapeMap(_box(milk, 0.02)))
    assert len(hand_pool(_box(milk, 0.02), 4, fingers=3, rng=0)) == 4


def _walk(n, sigma_t, sigma_r, rng):
    from touchloc.models import GaussianDynamics

    dyn = GaussianDynamics(sigma_t, sigma_r, planar=True)
    T = [np.eye(4)]
    for _ in range(n):
        T.append(dyn.sample(T[-1][None], rng=rng)[0])
    return np.array(T)


def test_smoother_pulls_a_drifted_trajectory_back_onto_one_surface(milk):
    """Contacts made along a pushed trajectory, estimates that drifted away from it: the
    smoother must bring the poses back (the first pose fixes the frame)."""
    from touchloc.mapping.smoother import smooth_trajectory

    rng = np.random.default_rng(0)
    true = _walk(40, 0.002, np.deg2rad(2.0), rng)          # true[0] is the anchor
    pts, nrm, own = [], [], []
    for s in range(40):
        p, n, _ = milk.sample_surface(4, rng=rng)
        T = true[s + 1]
        pts.append(p @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=0.001, size=p.shape))
        nn = n @ T[:3, :3].T + rng.normal(scale=0.05, size=n.shape)
        nrm.append(nn / np.linalg.norm(nn, axis=1, keepdims=True))
        own.append(np.full(4, s))
    # the estimate drifts: its own random walk of errors on top of the truth
    err = _walk(40, 0.0015, np.deg2rad(1.5), rng)
    est = np.array([true[s + 1] @ err[s + 1] for s in range(40)])
    motions = [None] + [(np.eye(4), (0.002, np.deg2rad(2.0)))] * 39
    est[0] = true[1]

    def drift(P):
        return np.median([add_s(milk, a, b) for a, b in zip(P, true[1:])])

    new, info = smooth_trajectory(est, true[0], np.concatenate(pts), np.concatenate(nrm), np.concatenate(own),
                                  motions, planar=True, sigma_pos=0.001, sigma_nor=0.05, radius=0.03)
    assert info["accepted"] and info["pairs"] > 100
    assert info["cost"][1] < info["cost"][0]
    assert drift(new) < 0.5 * drift(est)
    assert np.array_equal(new[0], est[0])                  # the first step is held
    # nothing to gain from the truth: it stays within the noise of the contacts
    back, _ = smooth_trajectory(true[1:], true[0], np.concatenate(pts), np.concatenate(nrm), np.concatenate(own),
                                motions, planar=True, sigma_pos=0.001, sigma_nor=0.05, radius=0.03)
    assert drift(back) < 0.0015


def test_a_touch_where_the_map_is_only_its_prior_says_nothing_about_the_pose(milk):
    from touchloc.planners import GuardedTouch, execute

    slam = TactileSLAM(_box(milk, 0.03), planar=True, sigma_pos=0.001, sigma_nor=0.087, rng=0)
    # map the bottom of one side of the carton (-x), then score a touch there and one at the
    # top of the far side (+x), more than four length scales away
    first = [execute(milk, np.eye(4), GuardedTouch((-0.1, y, z), (1, 0, 0), 0.2), rng=0)[0]
             for y in (-0.01, 0.01) for z in (-0.07, -0.06, -0.05)]
    slam.update(first)
    far = execute(milk, np.eye(4), GuardedTouch((0.1, 0.0, 0.06), (-1, 0, 0), 0.2), rng=1)
    near = execute(milk, np.eye(4), GuardedTouch((-0.1, 0.0, -0.055), (1, 0, 0), 0.2), rng=1)
    P = np.repeat(np.eye(4)[None], 21, axis=0)
    P[:, 0, 3] = np.linspace(-0.005, 0.005, 21)
    ll_far, ll_near = slam._log_likelihood(P, far), slam._log_likelihood(P, near)
    # on the mapped side a 5 mm shift along the normal costs several nats; on the far side,
    # where the map holds only its prior sphere, nothing (scored against the prior as
    # well, it cost 1.9 nats there)
    assert np.ptp(ll_near) > 5.0
    assert np.ptp(ll_far) < 0.1


def test_first_touches_define_the_frame_and_the_world_is_pushed_after_each_action(milk):
    T0 = np.eye(4)
    T0[:3, 3] = (0.01, -0.02, 0.0)
    world = MovingWorld(milk, T0, push=(0.002, np.deg2rad(2.0)), planar=True, rng=0)
    slam = TactileSLAM(_box(milk, 0.03), initial_pose=T0, planar=True, rng=0)
    pool = hand_pool(_box(milk, 0.06), 3, fingers=3, rng=0)
    slam.update(world.execute(pool[0]))
    assert np.array_equal(world.trajectory[1], T0)          # the first action met the object unmoved
    assert np.allclose(slam.pose, T0, atol=1e-12)            # and the map's frame is where it was
    assert not np.allclose(world.true_pose, T0)              # ... which that action then pushed
    world.execute(pool[1])
    assert not np.allclose(world.trajectory[2], T0)


def test_smoothing_keeps_a_pushed_run_within_millimetres(milk):
    """100 three-finger actions on a carton pushed 2 mm / 2 deg per action: the goal's setting."""
    from touchloc.mapping import fscore

    out = {}
    for every in (10, 0):
        world = MovingWorld(milk, rng=0, push=(0.002, np.deg2rad(2.0)), planar=True)
        slam = TactileSLAM(_box(milk, 0.03), planar=True, smooth_every=every, sigma_pos=0.001, sigma_nor=0.087,
                           rng=0)
        run = explore(world, _box(milk, 0.06), 100, slam=slam, fingers=3, rng=0)
        drift = np.median([add_s(milk, a, b) for a, b in zip(slam.trajectory[1:], world.trajectory[1:])])
        out[every] = (fscore(run.map.to_mesh(), milk, 0.005, n=3000), drift)
        if every:
            runs = slam.info["smoothing"]
            assert len(runs) >= 6 and sum(r["accepted"] for r in runs) >= len(runs) - 2
    f, drift = out[10]
    assert f >= 0.9 and drift < 0.003
    assert drift < out[0][1]


def test_slam_maps_an_object_the_emulated_hand_nudges():
    """explore + TactileSLAM through the real hand's path: guarded touches chosen from the
    hand's reachable pool, run by the executor on the emulated SDH-2 (virtual CAN) and
    DSACON32m (pty), each action nudging the object."""
    import trimesh

    from touchloc.hardware import GuardedTouchExecutor, HandWorld
    from touchloc.hardware.emulator import EmulatedRig, SimWorld
    from touchloc.models import GaussianDynamics, MeshObject
    from touchloc.planners import HandTouch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        box = MeshObject(trimesh.creation.box(extents=(0.06, 0.05, 0.15)), name="box")
    hand_pose = np.diag([1.0, -1.0, -1.0, 1.0])
    hand_pose[2, 3] = 0.18
    sim = SimWorld(box, np.eye(4), hand_pose)

    class Nudged(HandWorld):
        """Each action's touches push the box a little (planar) after they are measured."""

        def __init__(self, executor):
            super().__init__(executor)
            self.trajectory = [np.eye(4)]
            self.rng = np.random.default_rng(0)

        def execute(self, action):
            self.trajectory.append(sim.object_pose.copy())
            out = super().execute(action)
            sim.move_object(GaussianDynamics(0.001, np.deg2rad(1.0), planar=True).sample(sim.object_pose[None],
                                                                                         rng=self.rng)[0])
            return out

    with EmulatedRig(sim, hand_transport="can", tactile_transport="pty", time_scale=8.0) as rig:
        # generous reply timeouts: no fault is injected here, and the emulated devices share
        # the CPU with the estimator (a loaded machine once took longer than 1 s to answer)
        ex = GuardedTouchExecutor(rig.open_hand(timeout=5.0), rig.open_tactile(timeout=5.0), hand_pose=hand_pose)
        world = Nudged(ex)
        lo, hi = box.bounds
        slam = TactileSLAM((lo - 0.03, hi + 0.03), planar=True, motion=(0.001, np.deg2rad(1.0)), smooth_every=5,
                           sigma_pos=0.002, sigma_nor=0.15, rng=0)
        def pairs(rng):      # two fingers closing in one action: two contacts per nudge
            pool = ex.touch_pool(24, rng=rng)
            return [HandTouch((a, b)) for a, b in zip(pool[::2], pool[1::2])]

        run = explore(world, (lo - 0.06, hi + 0.06), 15, slam=slam, rng=0, candidates=pairs)
    assert len(slam.trajectory) == 16 and run.map is slam.map and slam.map.n_contacts >= 8
    assert all(s["update_time"] >= 0 for s in run.steps)
    # the mapped contacts lie on the box (object frame), the pose estimate stays within a few
    # millimetres of the nudged box, and the map is a mesh the estimators can use
    d = box.closest_points(slam.map.contacts.points)[2]
    assert np.median(d) < 0.003
    err = [add_s(box, a, b) for a, b in zip(slam.trajectory[1:], world.trajectory[1:])]
    assert max(err) < 0.005
    assert len(slam.map.to_mesh().mesh.faces) > 100


def _milk_map(milk):
    """A GPIS map of the milk carton from contacts sampled at the identity pose."""
    from touchloc.models import Contacts
    from touchloc.planners import GuardedTouch, TouchResult

    pts, idx = milk.mesh.sample(150, return_index=True, seed=0)
    nor = milk.mesh.face_normals[idx]
    smap = ShapeMap(_box(milk, 0.03), sigma_pos=0.001, sigma_nor=0.087)
    smap.update([TouchResult(GuardedTouch(p + 0.03 * n, -n, 0.05), 0.03, Contacts(p[None], n[None]))
                 for p, n in zip(pts, nor)])
    return smap


def test_pose_information_of_a_touch_follows_its_lever_arm(milk):
    """A contact on a side face fixes a turn about the vertical axis by its offset from the
    axis: a touch through the axis carries no yaw information, one off to the side does;
    both fix the translation across the face alike."""
    from touchloc.mapping.explore import _slam_information
    from touchloc.planners import GuardedTouch

    smap = _milk_map(milk)
    lo, hi = milk.bounds
    c = 0.5 * (lo + hi)
    start = hi[0] + 0.05
    through = GuardedTouch((start, c[1], c[2]), (-1.0, 0.0, 0.0), 0.2)
    off = GuardedTouch((start, c[1] + 0.25 * (hi[1] - lo[1]), c[2]), (-1.0, 0.0, 0.0), 0.2)
    yaw = np.zeros((6, 6))
    yaw[5, 5] = np.deg2rad(10.0) ** 2
    tx = np.zeros((6, 6))
    tx[0, 0] = 0.003**2
    none = _slam_information(smap, [through, off], [0, 1], np.zeros((6, 6)))
    iy = _slam_information(smap, [through, off], [0, 1], yaw) - none
    ix = _slam_information(smap, [through, off], [0, 1], tx) - none
    # 11 mm off the axis, 10 deg moves the face by 1.9 mm: about 1/2 log(1 + 1.9^2 / 1.25) nats
    assert iy[0] < 0.05 and 0.3 < iy[1] < 1.0
    # 3 mm across a face measured to 1 mm: 1/2 log(1 + 9) nats, for both touches
    assert np.allclose(ix, 0.5 * np.log(10.0), atol=0.25)
    # the touches of one hand add up to at least the better one
    both = _slam_information(smap, [through, off], [0, 0], yaw) - _slam_information(smap, [through, off], [0, 0], 0 * yaw)
    assert both.shape == (1,) and both[0] >= iy[1] - 1e-9


def test_pose_lever_shrinks_where_the_normal_cannot_support_it():
    from touchloc.mapping.slam import _pose_jacobian

    r = 0.04
    x = np.array([r, 0.0, 0.05])
    sig = np.deg2rad(5.0)
    radial_ish = np.array([np.cos(np.deg2rad(3.0)), np.sin(np.deg2rad(3.0)), 0.0])
    tangential = np.array([0.0, 1.0, 0.0])
    J1 = _pose_jacobian(x, radial_ish, sig)
    J2 = _pose_jacobian(x, tangential, sig)
    # 3 deg off the radius is within a 5 deg normal's noise: no lever about the axis
    assert J1[5] == 0.0 and np.allclose(J1[:3], radial_ish)
    # a normal across the radius keeps nearly all of its lever r about the axis
    assert 0.99 * r < J2[5] <= r
    assert np.allclose(_pose_jacobian(x, tangential, 0.0)[3:], np.cross(x, tangential))
    # batched
    assert _pose_jacobian(np.tile(x, (4, 2, 1)), np.tile(tangential, (4, 2, 1)), sig).shape == (4, 2, 6)


def test_tracked_pose_covariance_sees_what_a_surface_can_show(milk):
    """Turned about its axis, a can's surface cannot show the turn: the tracked yaw variance
    grows with the odometry's noise while the translation stays pinned; a milk carton's
    flat faces show every turn and keep it bounded."""
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        can = load_object("can")
    kw = dict(push=(0.0, 0.0), inhand=True, step=np.deg2rad(15.0))
    out = {}
    for name, obj in (("can", can), ("milk", milk)):
        slam = TactileSLAM(_box(obj, 0.03), motion=(0.0005, np.deg2rad(0.5)),
                           odometry_noise=(0.0005, np.deg2rad(1.5)), sigma_pos=0.001, sigma_nor=0.087, rng=0)
        assert np.allclose(slam.pose_covariance(predict=False), 0.0)
        world = MovingWorld(obj, rng=0, **kw)
        explore(world, _box(obj, 0.06), 30, slam=slam, fingers=3, rng=0)
        assert slam.turning
        # the next touch is expected where the last turn, repeated, takes the object
        D = world.odometry()
        assert np.isclose(Rotation.from_matrix(D[:3, :3]).magnitude(), np.deg2rad(15.0))
        assert np.allclose(slam.predicted_pose(), D @ slam.pose, atol=1e-12)
        C = slam.pose_covariance(predict=False)
        assert np.all(np.linalg.eigvalsh(C) > -1e-12)
        Cp = slam.pose_covariance()
        assert np.all(np.linalg.eigvalsh(Cp - C) > -1e-12) and np.trace(Cp) > np.trace(C)
        out[name] = C
    # 30 turns with 1.5 deg of noise each and nothing to see: up to 8 deg (the can's rims
    # show a little, and its map's body, not yet round, lends the map's normals a lever: 5.5
    # here); the carton's faces hold it at about half that
    yaw_can = np.degrees(np.sqrt(out["can"][5, 5]))
    assert 5.0 < yaw_can < 8.3
    assert np.degrees(np.sqrt(out["milk"][5, 5])) < 0.6 * yaw_can
    assert np.sqrt(np.max(np.diag(out["can"])[:2])) < 0.002


def test_smoother_holds_the_turns_it_is_told_to_hold(milk):
    """In hand, the steps whose contacts did not show the turn keep it through a smoothing
    round: the smoother moves such a pose in every other way, not about its motion's axis."""
    from touchloc.mapping.smoother import smooth_trajectory

    rng = np.random.default_rng(1)
    S, step = 20, np.deg2rad(15.0)
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec([0.0, 0.0, step]).as_matrix()
    true = [np.eye(4)]
    for _ in range(S):
        true.append(D @ true[-1])
    pts, nrm, own = [], [], []
    for s in range(S):
        p, n, _ = milk.sample_surface(4, rng=rng)
        T = true[s + 1]
        pts.append(p @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=0.001, size=p.shape))
        nrm.append(n @ T[:3, :3].T)
        own.append(np.full(4, s))
    err = _walk(S, 0.0015, np.deg2rad(1.5), rng)
    est = np.array([true[s + 1] @ err[s + 1] for s in range(S)])
    motions = [(D, (0.0005, np.deg2rad(1.5)))] * S
    args = (est, true[0], np.concatenate(pts), np.concatenate(nrm), np.concatenate(own), motions)
    kw = dict(planar=False, sigma_pos=0.001, sigma_nor=0.05, radius=0.03)
    free, _ = smooth_trajectory(*args, **kw)
    held, info = smooth_trajectory(*args, fixed_turns=[True] * S, **kw)
    assert info["accepted"]

    def turn(P):
        return np.array([Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).as_rotvec()[2] for a, b in zip(P, est)])

    assert np.max(np.abs(turn(held))) < 1e-3
    assert np.max(np.abs(turn(free))) > 1e-2
    # the rest of the pose still moves
    assert np.max(np.linalg.norm(held[:, :3, 3] - est[:, :3, 3], axis=1)) > 5e-4


def _inhand_mug_run(seed, actions=96, errors=False):
    """The SLAM benchmark's in-hand mug (15 deg turns, an odometry 5 % too large, 96
    three-finger actions, the scale learned): the estimator and its median orientation
    error (deg) within each of the four turns (of the actions run); with ``errors``, also the
    error after each action."""
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mug = load_object("mug")
    world = MovingWorld(mug, rng=seed, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0), bias=0.05,
                        noise_pos=0.001, noise_nor=np.deg2rad(5.0))
    slam = TactileSLAM(_box(mug, 0.03), motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, np.deg2rad(1.5)),
                       learn_odometry_scale=True, sigma_pos=0.001, sigma_nor=np.deg2rad(5.0), rng=seed)
    explore(world, _box(mug, 0.06), actions, slam=slam, fingers=3, rng=seed)
    ang = np.array([np.degrees(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).magnitude())
                    for a, b in zip(slam.trajectory[1:], world.trajectory[1:])])
    per_turn = [np.median(ang[i * 24:(i + 1) * 24]) for i in range(-(-actions // 24))]
    return (slam, per_turn, ang) if errors else (slam, per_turn)


def test_in_hand_turn_search_ignores_contacts_inside_the_body_before_the_feature(monkeypatch):
    """Before the handle's filter has a sighting, a contact well inside the body's radius
    does not show the turn: a mug's inner wall, mapped from a few touches of a thin wall, is
    not yet round, and two such touches once made the turn search move the turn by 45 deg,
    to 68 deg off (the odometry's drift alone was 26 deg there). Where such touches fall in
    a run depends on the last bits of its arithmetic, which differ between CPUs, so here
    every contact that would show the turn before the handle is seen is reported to lie
    inside the body: none may then move the turn."""
    asked = []

    def inside(self, points, q, a):
        asked.append(len(points))
        return np.full(len(points), -2.0 * TactileSLAM._TURN_INSIDE)

    monkeypatch.setattr(FeatureTurn, "radial_offset", inside)
    steps = []
    orig = TactileSLAM._turn_aware

    def spied(self, P, results, D):
        n = len(asked)
        out = orig(self, P, results, D)
        if len(asked) > n:  # contacts that passed the range test were asked about
            steps.append(len(self._steps))
            assert not self._turn_shown
        return out

    monkeypatch.setattr(TactileSLAM, "_turn_aware", spied)
    slam, _, err = _inhand_mug_run(75, actions=34, errors=True)
    # the search was asked about contacts that would have shown the turn, and none moved it
    assert steps and sum(asked) >= 1
    searched = {s["step"] for s in slam.info.get("turn_search", [])}
    assert not searched & set(steps)
    # and before the handle is seen the turn is the odometry's, drifting by its 5 % bias
    # (0.75 deg an action) and the turn noise, never jumping
    if not slam._feature_turn.started:
        assert err[-1] < 40.0 and np.all(np.diff(err[10:]) < 5.0)


def test_in_hand_mug_turn_held_by_its_handle(monkeypatch):
    """A mug turned in hand with an odometry 5 % too large: its body, a surface of revolution
    about the turn's axis, cannot show the turn; the handle can. The error must stay within
    10 degrees in each of four turns, and the learned scale must approach 1 / 1.05. Here
    without the feature's angle filter (the path a run takes until that filter has seen the
    handle, and where the turn is re-anchored)."""
    monkeypatch.setattr(TactileSLAM, "_FEATURE_TURN", False)
    slam, per_turn = _inhand_mug_run(1)
    assert slam._feature_turn is None
    # (integrating the odometry alone: 18 degrees off after the first turn, 72 after four)
    assert max(per_turn) < 10.0 and per_turn[3] - per_turn[0] < 10.0
    assert 0.94 < slam.odometry_scale < 0.975
    # the turn was estimated apart, and some steps showed it (the handle)
    assert slam.info.get("turn_search")
    assert any(st["turn_shown"] is False for st in slam._steps)

    # re-anchoring turns poses and the map's touches together: every touch stays where it
    # was made in the world, and the poses up to the anchor follow the odometry at the scale
    assert slam._anchor is not None and slam.info.get("reanchor")
    slam.odometry_scale *= 1.1
    axis = Rotation.from_matrix(slam._steps[-1]["odometry"][:3, :3]).as_rotvec()
    axis /= np.linalg.norm(axis)

    def anchor_off():
        """The anchor's turn less the odometry's integrated at the scale, about the axis."""
        R = slam.trajectory[0][:3, :3]
        for j in range(slam._anchor + 1):
            D = slam._steps[j]["odometry"]
            if D is not None:
                R = Rotation.from_rotvec(slam.odometry_scale * Rotation.from_matrix(D[:3, :3]).as_rotvec()).as_matrix() @ R
        return abs(Rotation.from_matrix(R @ slam.trajectory[slam._anchor + 1][:3, :3].T).as_rotvec() @ axis)

    off_before = anchor_off()
    before = [T.copy() for T in slam.trajectory]
    pts_before = slam.map._pts.copy()
    T_now = slam._reanchor(slam._steps[-1]["odometry"], slam.trajectory[-1].copy())
    batch_step = {st["batch"]: j for j, st in enumerate(slam._steps) if st["batch"] is not None}
    for b in np.unique(slam.map._pts_owner):
        j = batch_step[int(b)]
        sel = slam.map._pts_owner == b
        P0 = pts_before[sel] @ before[j + 1][:3, :3].T + before[j + 1][:3, 3]
        P1 = slam.map._pts[sel] @ slam.trajectory[j + 1][:3, :3].T + slam.trajectory[j + 1][:3, 3]
        assert np.allclose(P0, P1, atol=1e-9)
    assert off_before > np.deg2rad(2.0) and anchor_off() < 0.2 * off_before
    moved = Rotation.from_matrix(T_now[:3, :3] @ before[-1][:3, :3].T).magnitude()
    assert abs(moved - off_before) < 0.2 * off_before   # the present turns with the anchor



def test_in_hand_mug_turn_held_by_the_scale_its_handle_touches_agree_on(monkeypatch):
    """Without the feature's angle filter: once the handle's touches from different visits
    agree under one scale, that scale holds, and every turn up to the last step that showed
    the turn is the odometry's at it (seed 4 of the same world, where the fit passes its
    gate after 77 actions)."""
    monkeypatch.setattr(TactileSLAM, "_FEATURE_TURN", False)
    slam, per_turn = _inhand_mug_run(4)
    assert slam._feature_turn is None
    # the study's criterion, within 10 degrees in every turn (the run is chaotic: rounding
    # in the map moves this seed's worst turn between about 4 and 5 degrees)
    assert max(per_turn) < 10.0
    assert slam._feature_fit is not None and slam.odometry_scale == slam._feature_fit
    assert abs(slam.odometry_scale - 1 / 1.05) < 0.01
    last = max(j for j, st in enumerate(slam._steps) if st["turn_shown"])
    R = slam.trajectory[0][:3, :3]
    off = []
    for j, st in enumerate(slam._steps[:last + 1]):
        R = Rotation.from_rotvec(slam.odometry_scale * Rotation.from_matrix(st["odometry"][:3, :3]).as_rotvec()).as_matrix() @ R
        off.append(np.degrees(Rotation.from_matrix(R @ slam.trajectory[j + 1][:3, :3].T).as_rotvec()[2]))
    # (the smoother, run since, may revise the turns of steps that showed it by a degree or
    # two: the largest revision was 0.4, 1.3 and 2.1 deg under three roundings of the map)
    assert np.median(np.abs(off)) < 0.1 and np.max(np.abs(off)) < 3.0


def test_in_hand_mug_turn_from_the_handles_angle():
    """The handle's angle as one number: the filter over turn, scale and that angle learns
    the scale, holds the turn within 10 degrees in every turn, sets the current pose's turn,
    and the smoothing rounds put the earlier poses on its smoothed turns (each pose's turn
    about the axis within a degree of them at the median: the filter has learned more since
    the last round)."""
    from touchloc.mapping._feature_turn import wrap

    slam, per_turn = _inhand_mug_run(4)
    ft = slam._feature_turn
    assert ft is not None and ft.started and ft.used >= 10
    assert max(per_turn) < 10.0
    assert abs(slam.odometry_scale - 1 / 1.05) < 0.01
    assert slam.info["feature_turn"] and all(st["turn_held"] for st in slam._steps[-10:])
    a, R0 = slam._turn_axis, slam.trajectory[0][:3, :3]
    turn = np.array([Rotation.from_matrix(T[:3, :3] @ R0.T).as_rotvec() @ a for T in slam.trajectory[1:]])
    th = ft.smoothed()
    steps = slam._turn_steps
    assert len(th) == len(steps) == len(slam._steps)
    assert np.degrees(abs(wrap(turn[steps][-1] - th[-1]))) < 0.5
    assert np.degrees(np.median(np.abs(wrap(turn[steps] - th)))) < 1.0


def test_odometry_scale_posterior_shrugs_off_a_wrong_correction(milk):
    """One handle contact can match the wrong face of the handle: the scale's posterior
    treats each measured scale as right or (one in five) an outlier, so one measurement far
    from six that agree moves the scale little, where their plain mean would follow it."""
    slam = TactileSLAM(_box(milk, 0.03), learn_odometry_scale=True, rng=0)
    agree = [(0.952 + d, 0.03) for d in (-0.01, 0.004, 0.0, 0.008, -0.006, 0.003)]
    slam._scale_obs = list(agree)
    s_agree, var = slam._scale_posterior()
    assert abs(s_agree - 0.952) < 0.01 and 0.0 < np.sqrt(var) < 0.03
    slam._scale_obs = agree + [(1.16, 0.03)]
    s_out, _ = slam._scale_posterior()
    plain = np.average([z for z, _ in slam._scale_obs], weights=[1 / sd**2 for _, sd in slam._scale_obs])
    assert abs(s_out - s_agree) < 0.006 and plain - s_agree > 0.01
    # with no measurement but one, the prior about the start (1, sd 5 %) holds it back
    slam._scale_obs = [(0.90, 0.05)]
    s_one, _ = slam._scale_posterior()
    assert 0.90 < s_one < 0.975


def _turned_mug_steps(S, handle_every, rng):
    """A mug turned 15 deg per step about z with an odometry 5 % too large: the true poses,
    the odometry's increments and each step's world-frame touches (three on the body, one on
    the handle every ``handle_every`` steps)."""
    from touchloc.data import load_object
    from touchloc.models.contacts import Contacts

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mug = load_object("mug")
    p, n, _ = mug.sample_surface(4000, rng=rng)
    rho = np.hypot(p[:, 0], p[:, 1])
    body, handle = np.flatnonzero((rho < 0.042) & (p[:, 2] > 0.01)), np.flatnonzero(rho > 0.058)
    true, odo, touches = [], [], []
    turn = 0.0
    for s in range(S):
        turn += np.deg2rad(15.0)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, turn]).as_matrix()
        D = np.eye(4)
        D[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 1.05 * np.deg2rad(15.0)]).as_matrix()
        idx = list(rng.choice(body, 3))
        if s % handle_every == 0:
            idx.append(rng.choice(handle))
        pts = p[idx] @ T[:3, :3].T + rng.normal(scale=0.001, size=(len(idx), 3))
        true.append(T)
        odo.append(D)
        touches.append(Contacts(pts, n[idx] @ T[:3, :3].T))
    return mug, true, odo, touches


def test_feature_scale_fits_the_odometry_under_which_the_handle_touches_agree():
    """The handle's touches from visits many turns apart land on one handle only under the
    right scale: with the trajectory at the odometry's own turns (5 % too far), the fit
    finds 1 / 1.05, and it abstains when the features cannot tell."""
    def at_odometry(S, handle_every, seed):
        """A SLAM whose trajectory follows the odometry's own turns, and the last step's inputs."""
        mug, true, odo, touches = _turned_mug_steps(S, handle_every, np.random.default_rng(seed))
        slam = TactileSLAM(_box(mug, 0.03), learn_odometry_scale=True, rng=0)
        R = np.eye(3)
        for D, c in zip(odo[:-1], touches[:-1]):
            R = D[:3, :3] @ R
            T = np.eye(4)
            T[:3, :3] = R
            slam.trajectory.append(T)
            slam._steps.append(dict(contacts=c, odometry=D))
        T_now = np.eye(4)
        T_now[:3, :3] = odo[-1][:3, :3] @ R
        return mug, slam, odo, touches, (odo[-1], T_now, touches[-1])

    mug, slam, odo, touches, last = at_odometry(48, 3, 3)
    s = slam._feature_scale(*last)
    assert s is not None and abs(s - 1 / 1.05) < 0.004
    margin = slam.info["feature_scale"][-1][4]
    assert margin > TactileSLAM._FEATURE_MARGIN
    # beyond _FEATURE_MAX features an even subset over the run is fitted
    many, last_many = at_odometry(96, 1, 5)[1::3]
    many._FEATURE_MAX = 40
    s40 = many._feature_scale(*last_many)
    assert many.info["feature_scale"][-1][3] > 80 and s40 is not None and abs(s40 - 1 / 1.05) < 0.004
    # the handle touched in one visit only: no partner from another visit, no fit
    lone = TactileSLAM(_box(mug, 0.03), learn_odometry_scale=True, rng=0)
    lone.trajectory += slam.trajectory[1:5]
    lone._steps = slam._steps[:4]
    assert lone._feature_scale(odo[4], slam.trajectory[5], touches[4]) is None


def test_smoothing_does_not_move_the_touches_of_held_steps(milk, monkeypatch):
    """A held step (outside the smoother's window) keeps its pose. If its batch holds only
    swept free space, its revision (the identity up to rounding) must not move it: the map
    would refit every row from that batch on."""
    world = MovingWorld(milk, rng=3, push=(0.002, np.deg2rad(2.0)), planar=True)
    slam = TactileSLAM(_box(milk, 0.03), planar=True, smooth_every=0, smooth_window=6, sigma_pos=0.001,
                       sigma_nor=0.087, rng=3)
    explore(world, _box(milk, 0.06), 30, slam=slam, fingers=1, rng=3)
    hold = len(slam._steps) - slam.smooth_window
    held_free = [(j, st["batch"]) for j, st in enumerate(slam._steps[:hold])
                 if st["contacts"] is None and st["batch"] is not None]
    # some of them are not the identity in floating point (those the old rule moved)
    assert any(np.any(np.linalg.inv(slam.trajectory[j + 1]) @ slam.trajectory[j + 1] != np.eye(4))
               for j, _ in held_free), "the run must have a held step that swept free space only"
    seen = []
    real = ShapeMap.relocate
    monkeypatch.setattr(ShapeMap, "relocate", lambda self, moves, **kw: (seen.append(list(moves)),
                                                                         real(self, moves, **kw))[1])
    rec = slam.smooth()
    assert rec["accepted"] and seen
    assert all(seen[0][b] is None for _, b in held_free)
    assert any(m is not None for m in seen[0])        # the window's steps did move


def test_free_space_term_in_single_precision_matches_the_exact_one(milk, monkeypatch):
    """The swept free space is scored with the map's mean in single precision (the kernel's
    exponentials at half the cost): against the same term in double precision the
    particles' log-likelihoods agree to 1e-3 nats (9e-5 at most over six batches of two
    pushed runs), far below their spread (0.08-1.9 nats)."""
    from touchloc.mapping.gpis import GPIS

    slam = TactileSLAM(_box(milk, 0.03), planar=True, sigma_pos=0.001, sigma_nor=0.087, rng=0)
    world = MovingWorld(milk, rng=0, push=(0.002, np.deg2rad(2.0)), planar=True)
    run = explore(world, _box(milk, 0.06), 20, slam=slam, fingers=3, rng=0)
    P = slam.particles
    batches = [run.results[-3:], run.results[-6:-3], run.results[-9:-6]]
    single = [slam._ll_free(P, res) for res in batches]
    mean = GPIS.mean
    monkeypatch.setattr(GPIS, "mean", lambda self, Q, dtype=np.float64: mean(self, Q))
    exact = [slam._ll_free(P, res) for res in batches]
    for s, e in zip(single, exact):
        assert not np.array_equal(s, e)                   # the single-precision path ran
        assert np.max(np.abs(s - e)) < 1e-3 < 0.05 * np.ptp(e)
