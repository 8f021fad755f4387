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
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError
from .kinematics import SDH2Kinematics
from .tactile import find_blobs

__all__ = ["rotation_plane_angles", "blob_normals", "frame_normal_angles", "CurvedPadKinematics",
           "emulated_rotation"]


def _unit(v, name):
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
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
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
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
    if not blobs:
        return np.zeros((0, 3))
    base = np.stack([b.normal for b in blobs])
    if pad_radius is None:
        return base
    if not (np.isfinite(pad_radius) and pad_radius > 0):
        raise ValidationError(f"pad_radius must be a positive length in m, got {pad_radius!r}")
    kin = kinematics or SDH2Kinematics()
    T = None if hand_pose is None else np.asarray(hand_pose, dtype=np.float64)
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


def frame_normal_angles(frame, angles, *, axis, reference, kinematics: SDH2Kinematics | None = None,
                        threshold: int = 100, min_texels: int = 1, pad_radius: float | None = 0.02,
                        hand_pose=None, min_in_plane: float = 0.3):
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

    Returns
    -------
    normal_angles : (K,) float
        One angle per blob (rad), ready for ``tracker.step(normal_angles, odometry)``;
        empty when nothing touches (a valid tracker input).
    finger : (K,) int
        The finger (0, 1, 2) of each angle.
    """
    blobs = find_blobs(frame, angles, kinematics, threshold=threshold, min_texels=min_texels,
                       hand_pose=hand_pose)
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


def _rz(a: float, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    T[:2, :2] = [[c, -s], [s, c]]
    T[2, 3] = z
    return T


def _close_on(world, angles, depth: float) -> np.ndarray:
    """Close each finger (proximal +a, distal -a: the distal pad stays parallel to the axis)
    until its distal pad presses ``depth`` into the object: a guarded grasp."""
    out = angles.copy()
    for f, (p, d) in enumerate(((1, 2), (3, 4), (5, 6))):
        lo, hi = np.radians(-6.0), np.radians(12.0)
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            out[p], out[d] = mid, -mid
            if float(world.penetration(out, (2 * f + 1,))[0].max()) > depth:
                hi = mid
            else:
                lo = mid
        out[p], out[d] = lo, -lo
    return out


def emulated_rotation(n_sides: int, *, turns: float = 4.0, inradius: float = 0.018, step: float = np.radians(4.0),
                      stroke=(np.radians(25.0), np.radians(40.0)), under_estimate: float = 0.06, depth: float = 0.0008,
                      slip_std: float = 0.0, pad_radius: float = 0.02, rate_hz: float = 2.5,
                      name: str = "", rng=None):
    """Record seed 000's rotation experiment from the emulated hand's tactile bytes.

    An extruded n-gon (a round cylinder for 0) stands on the hand's axis between the three
    distal pads (base angle 60 degrees, distal links parallel to the axis), which are
    curved across the finger with radius ``pad_radius`` (:class:`CurvedPadKinematics`).
    At every grasp each finger closes until its pad presses ``depth`` into the object.
    The hand turns it in strokes: during a stroke the fingers turn with the object
    about its axis, then they let go and regrasp at their starting place, the object
    keeping its rotation (plus an unobserved ``N(0, slip_std)``). Every sample the
    :class:`~touchloc.hardware.emulator.DSACON32mEmulator` renders the pads' pressure
    into bytes, the :class:`~touchloc.hardware.DSACON32m` driver reads them over a
    loopback TCP socket, and :func:`frame_normal_angles` turns the frame into world-frame
    normal angles about the axis. The odometry is the hand's turn under-estimated by
    ``under_estimate`` (seed 000, II-B).

    A finger that lands on a side keeps the side's normal through the stroke (it turns
    with the object); one that lands on a corner rocks on it. On a round cylinder the
    fingers, turning with the object, also keep their normal through a stroke, so the
    round object looks like a many-sided one to this set-up.

    Parameters
    ----------
    n_sides : int
        Number of sides (>= 3), or 0 for a round cylinder.
    turns : float
        Total rotation, turns.
    inradius : float
        Distance of the sides from the axis, m.
    depth : float
        How far each pad presses into the object at a grasp, m.
    step : float
        Mean rotation per sample, rad (each drawn within +-30 %).
    stroke : (float, float)
        Range of the rotation per stroke, rad.
    under_estimate : float
        Relative under-estimate of the odometry.
    slip_std : float
        Unobserved rotation at each regrasp, rad.
    pad_radius : float
        Radius of the pads' curvature across the finger (m), in the emulated world and
        in :func:`frame_normal_angles`.
    rate_hz : float
        Sampling rate (for the time stamps).
    name : str
    rng : None, int or numpy Generator

    Returns
    -------
    touchloc.dnf.RotationDataset
        With ``true_orientation`` and ``n_surfaces``.
    """
    import serial
    import trimesh

    from .._util import as_rng
    from ..dnf.data import RotationDataset
    from ..models import MeshObject
    from .dsacon import DSACON32m
    from .emulator import DSACON32mEmulator, SimWorld, TCPServer

    if not isinstance(n_sides, (int, np.integer)) or (n_sides != 0 and n_sides < 3):
        raise ValidationError(f"n_sides must be 0 (round) or an int >= 3, got {n_sides!r}")
    if not (np.isfinite(turns) and 0 < turns <= 20):
        raise ValidationError(f"turns must be in (0, 20], got {turns!r}")
    if not (np.isfinite(inradius) and 0.012 <= inradius <= 0.03):
        raise ValidationError(f"inradius must lie in [0.012, 0.03] m (the fingers' reach), got {inradius!r}")
    if not (np.isfinite(depth) and 0 < depth <= 0.002):
        raise ValidationError(f"depth must lie in (0, 2 mm] (m), got {depth!r}")
    if not (np.isfinite(step) and 0 < step < np.radians(20)):
        raise ValidationError(f"step must be in (0, 20 deg) rad, got {step!r}")
    lo, hi = (float(x) for x in stroke)
    if not (0 < lo <= hi < np.pi):
        raise ValidationError(f"stroke must be (lo, hi) rad with 0 < lo <= hi < pi, got {stroke!r}")
    if not (np.isfinite(under_estimate) and -0.5 < under_estimate < 0.5):
        raise ValidationError(f"under_estimate must be in (-0.5, 0.5), got {under_estimate!r}")
    rng = as_rng(rng)
    th = np.radians(4.0)
    angles = np.array([np.radians(60.0), th, -th, th, -th, th, -th])
    diameter = 2 * inradius / np.cos(np.pi / n_sides) if n_sides else 2 * inradius
    mesh = trimesh.creation.cylinder(radius=diameter / 2, height=0.06, sections=int(n_sides) if n_sides else 96)
    obj = MeshObject(mesh, name=f"{n_sides}-gon prism" if n_sides else "round cylinder")
    z = 0.136                                    # middle of the distal pads
    kin = CurvedPadKinematics(pad_radius)
    state = {"world": SimWorld(obj, _rz(0.0, z), kinematics=kin)}
    grasp = angles
    emu = DSACON32mEmulator(frame_source=lambda: state["world"].pressures(grasp))
    srv = TCPServer(emu).start()
    port = serial.serial_for_url(srv.url, timeout=0.05)
    seqs, odo, truth = [], [], []
    theta = est = 0.0
    try:
        dev = DSACON32m(port, timeout=1.0, open_timeout=1.0)
        while theta < turns * 2 * np.pi:
            theta += rng.normal(0.0, slip_std) if slip_std > 0 else 0.0
            rot, phi = rng.uniform(lo, hi), 0.0
            grasp = _close_on(SimWorld(obj, _rz(theta, z), kinematics=kin), angles, depth)
            while phi < rot and theta < turns * 2 * np.pi:
                H = _rz(phi)
                state["world"] = SimWorld(obj, _rz(theta, z), H, kinematics=kin)
                frame = dev.read_frame()
                a, _ = frame_normal_angles(frame, grasp, axis=[0.0, 0.0, 1.0], reference=[1.0, 0.0, 0.0],
                                           pad_radius=pad_radius, hand_pose=H)
                seqs.append(a)
                odo.append(est)
                truth.append(theta)
                d = step * rng.uniform(0.7, 1.3)
                phi += d
                theta += d
                est += d * (1.0 - under_estimate)
    finally:
        port.close()
        srv.close()
    T = len(seqs)
    index = np.concatenate([np.full(a.size, i) for i, a in enumerate(seqs)]).astype(np.int64)
    return RotationDataset(np.arange(T) / rate_hz, np.array(odo), np.concatenate(seqs), index,
                           true_orientation=np.array(truth), n_surfaces=int(n_sides),
                           name=name or (f"{n_sides}-gon (emulated hand)" if n_sides else "round (emulated hand)"))
