"""DSACON32m frames -> blobs -> normal angles in the rotation plane (the DNF tracker's input)."""

import numpy as np
import pytest

from touchloc.dnf import OrientationTracker
from touchloc.errors import ValidationError
from touchloc.hardware import SDH2Kinematics
from touchloc.hardware.dnf_features import frame_normal_angles, rotation_plane_angles

ANGLES = np.radians([0, -10, 20, -10, 20, -10, 20])


def _frame(blobs=()):
    kin = SDH2Kinematics()
    mats = [np.zeros((p.cells_y, p.cells_x), dtype=np.uint16) for p in kin.pads]
    for m, x, y in blobs:
        mats[m][y, x] = 800
    return mats


def test_rotation_plane_angles_about_z():
    ang, keep = rotation_plane_angles([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, 0]], [0, 0, 1], [1, 0, 0])
    np.testing.assert_array_equal(keep, [True, True, False, True])      # along the axis: no angle
    np.testing.assert_allclose(ang, [0, np.pi / 2, -3 * np.pi / 4])
    with pytest.raises(ValidationError, match="parallel"):
        rotation_plane_angles([[1, 0, 0]], [0, 0, 1], [0, 0, 2])


def test_curved_pad_gives_each_blob_its_own_normal():
    kin = SDH2Kinematics()
    _, u, k, n = kin.pad_frame(ANGLES, 1)
    frame = _frame([(1, 1, 5), (1, 4, 9)])                  # two blobs on finger 0's distal pad
    flat, f_flat = frame_normal_angles(frame, ANGLES, axis=u, reference=-n, pad_radius=None)
    assert flat.shape == (2,) and np.allclose(flat, 0.0, atol=1e-9)  # one flat normal per pad
    curved, fingers = frame_normal_angles(frame, ANGLES, axis=u, reference=-n, pad_radius=0.02)
    np.testing.assert_array_equal(fingers, [0, 0])
    # three texels (3.4 mm) apart across a 2 cm radius: 0.51 rad apart in the plane
    assert abs(curved[0] - curved[1]) == pytest.approx(3 * 0.0034 / 0.02, rel=1e-9)


def test_no_contact_is_an_empty_valid_tracker_input():
    ang, fingers = frame_normal_angles(_frame(), ANGLES, axis=[0, 0, 1], reference=[1, 0, 0])
    assert ang.shape == (0,) and fingers.shape == (0,)
    tr = OrientationTracker()
    assert tr.step(ang, 0.1) == pytest.approx(0.1)
