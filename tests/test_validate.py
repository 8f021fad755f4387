"""Unit tests of the boundary validators in touchloc._validate."""

import math
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touchloc import _util
from touchloc._validate import (as_count, as_motion, as_path, as_points, as_pose, as_poses, as_positive_float,
                                as_probability, as_timeout)
from touchloc.errors import TouchlocError, ValidationError


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "1", None, [1.0], True, 1j,
                                 np.array([1.0, 2.0])])
def test_positive_float_rejects(bad):
    with pytest.raises(ValidationError, match="sigma"):
        as_positive_float(bad, "sigma")


def test_positive_float_accepts_numpy_scalars_and_ints():
    assert as_positive_float(np.float32(0.5), "x") == 0.5
    assert as_positive_float(3, "x") == 3.0
    assert isinstance(as_positive_float(np.array(2.0), "x"), float)
    with pytest.raises(ValidationError, match="<= 1"):
        as_positive_float(2.0, "x", high=1.0)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -0.1, "1", None])
def test_timeout_rejects_values_that_would_hang(bad):
    with pytest.raises(ValidationError):
        as_timeout(bad)


def test_timeout_none_only_when_allowed():
    assert as_timeout(None, allow_none=True) is None
    assert as_timeout(0) == 0.0


def test_count():
    assert as_count(3.0, "n") == 3
    assert as_count(np.int64(7), "n") == 7
    for bad in (2.5, float("nan"), float("inf"), True, "3", None, 0, -3):
        with pytest.raises(ValidationError, match="n must"):
            as_count(bad, "n")
    with pytest.raises(ValidationError, match="memory"):
        as_count(10**13, "n", max=10**7, why="memory")
    assert as_count(0, "n", min=0) == 0


def test_probability():
    assert as_probability(0.0, "p") == 0.0 and as_probability(1, "p") == 1.0
    for bad in (1.5, -0.01, float("nan")):
        with pytest.raises(ValidationError):
            as_probability(bad, "p")
    with pytest.raises(ValidationError):
        as_probability(1.0, "p", open_high=True)


def test_poses_accept_rotations_and_reject_reflections_and_shear():
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, :3] = Rotation.random(5, random_state=0).as_matrix()
    T[:, :3, 3] = [0.1, -0.2, 0.3]
    out = as_poses(T)
    assert out.shape == (5, 4, 4) and out.dtype == np.float64
    assert as_pose(T[0]).shape == (4, 4)

    refl = T.copy()
    refl[2, :3, 0] *= -1
    with pytest.raises(ValidationError, match=r"poses\[2\].*det"):
        as_poses(refl)
    shear = T.copy()
    shear[1, 0, 1] += 1e-3
    with pytest.raises(ValidationError, match=r"poses\[1\].*orthonormal"):
        as_poses(shear)
    bottom = T.copy()
    bottom[0, 3, 0] = 1.0
    with pytest.raises(ValidationError, match="bottom row"):
        as_poses(bottom)
    # tolerant to text-file rounding
    assert as_poses(np.round(T, 8)).shape == (5, 4, 4)
    # non-rigid batches pass when asked
    assert as_poses(shear, rigid=False).shape == (5, 4, 4)


@pytest.mark.parametrize("bad", [np.eye(3), np.zeros((2, 4)), "eye", None, [[1, 2], [3]],
                                 np.full((4, 4), np.nan)])
def test_pose_shapes(bad):
    with pytest.raises(ValidationError):
        as_pose(bad)


def test_points():
    assert as_points([1, 2, 3], "p").shape == (1, 3)
    for bad in ([1, 2], np.zeros((0, 3)), [[1, 2, math.inf]], "abc", None):
        with pytest.raises(ValidationError, match="p must"):
            as_points(bad, "p")
    assert as_points(np.zeros((0, 3)), "p", allow_empty=True).shape == (0, 3)


def test_util_reexports_one_implementation():
    assert _util.as_points is as_points and _util.as_poses is as_poses


@pytest.mark.parametrize("bad", [None, 0.1, (0.1,), (0.1, 0.2, 0.3), ("a", 0.1), (np.nan, 0.1), (0.1, np.inf),
                                 (-0.001, 0.1), (0.1, -0.1), (1.0, 0.1), (0.1, math.pi)])
def test_motion_rejects(bad):
    with pytest.raises(ValidationError, match="push"):
        as_motion(bad, "push")


def test_motion_accepts_numbers_and_arrays():
    assert as_motion((0, 0), "push") == (0.0, 0.0)
    a, b = as_motion(np.array([0.002, np.deg2rad(2.0)]), "push")
    assert (a, b) == (0.002, float(np.deg2rad(2.0))) and type(a) is float


def test_path(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("1,2,3\n")
    assert as_path(str(f)) == f
    for bad in (True, 1, None, 3.0, ""):
        with pytest.raises(ValidationError):
            as_path(bad)
    with pytest.raises(ValidationError, match="does not exist"):
        as_path(tmp_path / "missing.csv")
    with pytest.raises(ValidationError, match="directory"):
        as_path(tmp_path)
    assert as_path(tmp_path, kind="dir") == tmp_path
    assert issubclass(ValidationError, TouchlocError)


def test_one_step_planner_refuses_a_degenerate_belief(objects):
    from touchloc.belief import ParticleBelief, PoseRegion
    from touchloc.errors import BeliefDegenerateError
    from touchloc.models import ProximityModel
    from touchloc.planners import GuardedTouch, OneStepPlanner

    obj = objects["can"]
    poses = PoseRegion.box((0, 0, 0), 0.01, "yaw").sample(50, rng=0)
    belief = ParticleBelief(poses)
    belief.log_weights = np.full(50, -1e5)   # unnormalised log-weights edited in place: exp underflows to 0
    touch = GuardedTouch((0, 0, 0.3), (0, 0, -1), 0.5)
    with pytest.raises(BeliefDegenerateError):
        OneStepPlanner(ProximityModel(obj, 0.002, 0.1), max_particles=10).plan(belief, [touch], rng=0)


# -- validators for flags, names, types, callables, containers and arrays ---------------------
def test_as_bool_takes_flags_and_0_1_only():
    from touchloc._validate import as_bool

    assert as_bool(True, "f") is True and as_bool(np.bool_(False), "f") is False
    assert as_bool(1, "f") is True and as_bool(0, "f") is False
    for bad in (2, -1, 0.0, "yes", None, np.array([True, False])):
        with pytest.raises(ValidationError, match="True or False"):
            as_bool(bad, "f")


def test_as_name_and_as_instance_and_as_callable():
    from touchloc._validate import as_callable, as_instance, as_name

    assert as_name("a", "n") == "a" and as_name(None, "n") is None
    with pytest.raises(ValidationError, match="a str"):
        as_name(None, "n", allow_none=False)
    with pytest.raises(ValidationError, match="a str or None"):
        as_name(np.array(["a"]), "n")
    assert as_instance(3, int, "k") == 3
    with pytest.raises(ValidationError, match="k must be a int or float, got str"):
        as_instance("3", (int, float), "k")
    assert as_callable(len, "f") is len and as_callable(None, "f", allow_none=True) is None
    with pytest.raises(ValidationError, match="callable"):
        as_callable(1.0, "f")


def test_as_sequence_and_as_mapping_check_types_of_items():
    from touchloc._validate import as_mapping, as_sequence

    assert as_sequence((1, 2), "xs") == [1, 2]
    assert as_sequence(np.arange(3), "xs", of=np.integer) == [0, 1, 2]
    for bad in ("ab", None, 1.0, {"a": 1}, np.float64(1.0)):
        with pytest.raises(ValidationError, match="xs must be"):
            as_sequence(bad, "xs")
    with pytest.raises(ValidationError, match=r"xs\[1\]"):
        as_sequence([1, "2"], "xs", of=int)
    with pytest.raises(ValidationError, match="at least 1"):
        as_sequence([], "xs", min_len=1)
    assert as_mapping({"a": 1}, "m", of=int) == {"a": 1}
    with pytest.raises(ValidationError, match="m must be a dict"):
        as_mapping([("a", 1)], "m")
    with pytest.raises(ValidationError, match=r"m\['a'\]"):
        as_mapping({"a": "1"}, "m", of=int)


@pytest.mark.parametrize("bad", ["x", None, {}, object(), 1j, [1j], np.array(["a"]), True,
                                 np.array([1.0, np.nan]), [1.0, float("inf")]])
def test_as_float_array_refuses_non_numbers_and_non_finite(bad):
    from touchloc._validate import as_float_array

    with pytest.raises(ValidationError, match="v must be"):
        as_float_array(bad, "v")


def test_as_float_array_shapes_and_bounds():
    from touchloc._validate import as_float_array

    a = as_float_array([[1, 2, 3]], "v", shape=(None, 3))
    assert a.dtype == np.float64 and a.shape == (1, 3)
    with pytest.raises(ValidationError, match=r"shape \(1, 2\)"):
        as_float_array([[1, 2]], "v", shape=(None, 3))
    with pytest.raises(ValidationError, match=">= 0"):
        as_float_array([1.0, -1.0], "v", low=0.0)
    assert np.isinf(as_float_array([np.inf], "v", finite=False)).all()


def test_as_count_refuses_floats_beyond_exact_integers():
    assert as_count(3.0, "n") == 3
    with pytest.raises(ValidationError, match="integer"):
        as_count(1e300, "n")
    with pytest.raises(ValidationError, match="integer"):
        as_count(2.0**60, "n")
