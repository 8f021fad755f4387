"""The planners' test case: a 6 x 4 x 3 cm box whose pose is unknown along x only."""

import warnings

import numpy as np
import trimesh

from touchloc.belief import PoseRegion
from touchloc.geometry import make_poses
from touchloc.models import MeshObject, ProximityModel


def make_box():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.box((0.06, 0.04, 0.03)), name="box")


def make_model(box):
    return ProximityModel(box, 0.002, 0.15)


def x_region(box):
    """Translation in [-4, 4] cm along x, rotation known."""
    return PoseRegion.box((0, 0, 0), (0.04, 0, 0), rotation=np.eye(3)).with_rho(box.radius)


def at_x(x):
    """(N, 4, 4) poses of the box shifted by x along the x axis."""
    x = np.atleast_1d(x)
    return make_poses(np.repeat(np.eye(3)[None], len(x), 0), np.c_[x, 0 * x, 0 * x])
