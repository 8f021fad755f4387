"""Tactile frames to the DNF tracker's input: per-finger contact-normal angles in the rotation plane.

Seed 000 (section II) computes one feature per tactile blob: the blob's centroid in the
pressure image, placed on the hand by forward kinematics, and the *sensor surface's* normal
there. The tracker (:class:`touchloc.dnf.OrientationTracker`) wants each normal as an angle
in the plane the object turns in. This module goes

    DSACON32m frame -> blobs (:func:`touchloc.hardware.find_blobs`) -> outward object
    normals at the blob centroids -> angles about the rotation axis, grouped by finger.

The pads of the SDH-2 are curved across the finger. :class:`SDH2Kinematics` models each pad
as flat (one normal per pad); with ``pad_radius`` the normal at a centroid is tilted about
the link direction by the centroid's distance from the pad's centre line over the radius,
so two blobs on one pad give two normals, as on the real sensor.

Flat sides and corners. Seed 000 (section II) keeps the blobs' second moments as a
curvature feature. On a pad curved across the finger the width of a blob across the
finger tells the two apart: a flat side pressed ``d`` into a pad of radius ``R`` touches
it along a strip about ``2 sqrt(2 R d)`` wide (11 mm at 0.8 mm on 20 mm), while a corner or
edge parallel to the finger touches it along a line, one texel column wide.
``frame_normal_angles(..., min_width=...)`` drops the narrow blobs (:func:`blob_widths`).
The seed found the moments too distorted by shear on its hardware to help; the emulator
has no shear, so how well the cue holds on a real pad is still to be measured.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_float, as_float_array, as_instance, as_pose, as_positive_float, as_sequence
from ..errors import ValidationError
from .kinematics import SDH2Kinematics
from .tactile import Blob, find_blobs

__all__ = ["rotation_plane_angles", "blob_normals", "blob_widths", "frame_normal_angles", "CurvedPadKinematics"]


def _unit(v, name):
    v = as_float_array(v, name, shape=(3,), expected="a finite non-zero (3,) vector")
    if np.linalg.norm(v) < 1e-9:
        raise ValidationError(f"{name} must be a finite non-zero (3,) vector, got {v!r}")
    return v / np.linalg.norm(v)


def _plane(axis, reference):
    a = _unit(axis, "axis")
    r = _unit(reference, "reference")
    r = r - a * (r @ a)
    if np.linalg.norm(r) < 1e-6:
        raise ValidationError("reference must not be parallel to the rotation axis")
    r /= np.linalg.norm(r)
    return a, r, np.cross(a, r)


def rotation_plane_angles(normals, axis, reference, *, min_in_plane: float = 0.3):
    """Angles of normals about a rotation axis.

    Parameters
    ----------
    normals : (K, 3) float
        Normals (any frame, the same as ``axis`` and ``reference``).
    axis : (3,) float
        Rotation axis of the object (right-handed: angles grow counter-clockwise about it).
    reference : (3,) float
        Direction of angle 0 (projected onto the plane normal to ``axis``).
    min_in_plane : float
        Normals whose component in the plane is shorter than this (relative to their
        length) point along the axis and have no usable angle; they are left out.

    Returns
    -------
    angles : (M,) float
        rad, in (-pi, pi].
    keep : (K,) bool
        Which normals were used.
    """
    n = as_float_array(normals, "normals", expected="a (K, 3) array of finite normals")
    if n.size == 0:
        n = n.reshape(0, 3)
    if n.ndim == 1 and n.shape == (3,):
        n = n[None]
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValidationError(f"normals must be a (K, 3) array, got shape {n.shape}")
    min_in_plane = as_float(min_in_plane, "min_in_plane", low=0.0, high=1.0)
    a, e1, e2 = _plane(axis, reference)
    x, y = n @ e1, n @ e2
    length = np.linalg.norm(n, axis=1)
    keep = np.hypot(x, y) >= min_in_plane * np.maximum(length, 1e-12)
    return np.arctan2(y[keep], x[keep]), keep


def blob_normals(blobs, angles, kinematics: SDH2Kinematics | None = None, *, pad_radius: float | None = None,
                 hand_pose=None) -> np.ndarray:
    """Outward object normals at the blobs' centroids, (K, 3).

    With ``pad_radius`` (m) the pad is taken as a cylinder about the link direction: a
    centroid ``d`` metres across from the pad's centre line sees the normal turned by
    ``d / pad_radius`` rad about the link. Without it each blob gets its pad's flat normal
    (:attr:`Blob.normal`).
    """
    blobs = _check_blobs(blobs)
    kin = as_instance(kinematics, SDH2Kinematics, "kinematics", allow_none=True) or SDH2Kinematics()
    angles = kin._angles(angles)
    if pad_radius is not None:
        pad_radius = as_positive_float(pad_radius, "pad_radius (m)", high=1.0)
    T = None if hand_pose is None else as_pose(hand_pose, "hand_pose")
    if not blobs:
        return np.zeros((0, 3))
    base = np.stack([b.normal for b in blobs])
    if pad_radius is None:
        return base
    out = np.empty_like(base)
    for i, b in enumerate(blobs):
        pad = kin.pads[b.matrix]
        _, across = pad.local_coordinates(b.centroid[0], b.centroid[1])   # from the centre line
        phi = float(across) / pad_radius
        _, _, k, n_pad = kin.pad_frame(angles, b.matrix)
        # the pad's outward normal turns towards +k across a convex pad; the object's is minus it
        v = -(np.cos(phi) * n_pad + np.sin(phi) * k)
        out[i] = v if T is None else T[:3, :3] @ v
    return out


def _check_blobs(blobs) -> list:
    return as_sequence(blobs, "blobs", of=Blob, expected="a list of Blob (from find_blobs)")


def blob_widths(blobs, kinematics: SDH2Kinematics | None = None) -> np.ndarray:
    """Width of each blob across its finger, m, (K,).

    The width of a uniform strip with the blob's pressure-weighted variance across the
    finger: ``texel_width * sqrt(12 var + 1)``, where ``var`` is in texels squared. One
    texel column gives one texel width (3.4 mm), three columns about three.
    """
    blobs = _check_blobs(blobs)
    kin = as_instance(kinematics, SDH2Kinematics, "kinematics", allow_none=True) or SDH2Kinematics()
    if not blobs:
        return np.zeros(0)
    var = np.array([max(float(b.covariance[0, 0]), 0.0) for b in blobs])
    pitch = np.array([kin.pads[b.matrix].texel_width for b in blobs])
    return pitch * np.sqrt(12.0 * var + 1.0)


def frame_normal_angles(frame, angles, *, axis, reference, kinematics: SDH2Kinematics | None = None,
                        threshold: int = 100, min_texels: int = 1, pad_radius: float | None = 0.02,
                        hand_pose=None, min_in_plane: float = 0.3, min_width: float | None = None):
    """One tactile frame to the DNF tracker's input: normal angles in the rotation plane.

    Parameters
    ----------
    frame : TactileFrame or sequence of 6 (cells_y, cells_x) arrays
    angles : (7,) float
        Joint angles (rad) when the frame was taken.
    axis, reference : (3,) float
        The object's rotation axis and the direction of angle 0, in the hand frame (or in
        the world frame when ``hand_pose`` is given).
    kinematics : SDH2Kinematics, optional
    threshold, min_texels : int
        Blob detection (see :func:`touchloc.hardware.find_blobs`).
    pad_radius : float or None
        Radius of the pads' curvature across the finger, m (None: flat pads).
    hand_pose : (4, 4) float, optional
        T_world_hand.
    min_in_plane : float
        See :func:`rotation_plane_angles`.
    min_width : float or None
        Drop blobs narrower than this across the finger (m, :func:`blob_widths`): line
        contacts on corners and edges, whose normal is the pad's wherever the corner
        landed rather than a side's. None keeps every blob. About 8 mm (between one and
        three 3.4 mm texel columns) for the SDH-2's 20 mm pads pressed 0.8-1.2 mm into flat sides
        (docs/dnf.md: shallower presses leave sides too narrow to tell from corners).

    Returns
    -------
    normal_angles : (K,) float
        One angle per blob (rad), ready for ``tracker.step(normal_angles, odometry)``;
        empty when nothing touches (a valid tracker input).
    finger : (K,) int
        The finger (0, 1, 2) of each angle.
    """
    if min_width is not None:
        min_width = as_float(min_width, "min_width (m)", low=0.0, high=0.1, high_open=True)
    blobs = find_blobs(frame, angles, kinematics, threshold=threshold, min_texels=min_texels,
                       hand_pose=hand_pose)
    if min_width is not None and blobs:
        blobs = [b for b, w in zip(blobs, blob_widths(blobs, kinematics)) if w >= min_width]
    normals = blob_normals(blobs, angles, kinematics, pad_radius=pad_radius, hand_pose=hand_pose)
    ang, keep = rotation_plane_angles(normals, axis, reference, min_in_plane=min_in_plane)
    finger = np.array([b.matrix // 2 for b in blobs], dtype=np.int64)[keep] if blobs else np.zeros(0, np.int64)
    return ang, finger


class CurvedPadKinematics(SDH2Kinematics):
    """SDH-2 kinematics whose pads are curved across the finger (for the emulator's world).

    Each pad's texels lie on a cylinder of radius ``pad_radius`` about an axis along the
    link, ``pad_radius`` behind the pad's centre line: a texel ``x`` metres (of arc) across
    the centre line sits at ``R sin(x / R)`` across and ``R (1 - cos(x / R))`` back from
    the flat pad, and its surface normal is turned by ``x / R`` towards the across
    direction - the model :func:`blob_normals` inverts. A flat side pressed on such a pad
    touches it where the pad's normal opposes the side's, so a blob's centroid says the
    side's normal, as on the real fingers (seed 000, section II).

    Parameters
    ----------
    pad_radius : float
        Radius of curvature across the pad, m.
    **kwargs
        Passed to :class:`SDH2Kinematics`.
    """

    def __init__(self, pad_radius: float = 0.02, **kwargs):
        super().__init__(**kwargs)
        if not (np.isfinite(pad_radius) and pad_radius > 0):
            raise ValidationError(f"pad_radius must be a positive length in m, got {pad_radius!r}")
        self.pad_radius = float(pad_radius)

    def texel_points(self, angles, matrix: int) -> np.ndarray:
        """(cells_y, cells_x, 3) float: texel centres on the curved pad surface (H)."""
        flat = super().texel_points(angles, matrix)
        o, u, k, n = self.pad_frame(angles, matrix)
        across = (flat - o) @ k
        R = self.pad_radius
        phi = across / R
        return flat + ((R * np.sin(phi) - across)[..., None] * k + (R * (np.cos(phi) - 1.0))[..., None] * n)
