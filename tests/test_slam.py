"""Tactile SLAM: an object that moves while it is mapped."""

import warnings

import numpy as np
import pytest

from touchloc.belief import add_s
from touchloc.errors import ValidationError
from touchloc.mapping import MovingWorld, ShapeMap, TactileSLAM, chamfer_distance, explore, hand_pool


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


def test_slam_bad_input(milk):
    with pytest.raises(ValidationError):
        TactileSLAM(((0, 0, 0), (1, 1, np.nan)))
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), n_particles=10**9)
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), motion=(-1.0, 0.0))
    with pytest.raises(ValidationError):
        TactileSLAM(_box(milk, 0.02), learn_odometry_scale="yes")
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
