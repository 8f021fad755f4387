"""Tactile frames to contacts: pressure blobs -> contact points and normals.

Following seed 000 (section II-C, "Computing Haptic Features"): the pressure pattern of each
pad is split into blobs; each blob's zero-, first- and second-order moments give its
total pressure, its centroid and its covariance in tactile coordinates; the forward
kinematics puts the centroid on the pad surface in the hand frame, and the pad's surface
normal gives the contact normal. The covariance's eigenvalue ratio and the angle of its
first eigenvector (seed 000's curvature features) are kept on each :class:`Blob`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validate import as_count, as_float_array, as_instance, as_pose, as_sequence
from ..errors import ValidationError
from ..models import Contacts
from .kinematics import SDH2Kinematics

__all__ = ["Blob", "find_blobs", "frame_to_contacts", "blobs_to_contacts"]

_STRUCT8 = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class Blob:
    """One connected region of pressure on one pad.

    Attributes
    ----------
    matrix : int
        Pad index (2 * finger + part).
    centroid : (2,) float
        Pressure-weighted centre in texel coordinates (x column, y row).
    covariance : (2, 2) float
        Pressure-weighted covariance in texels^2 (x, y order).
    pressure : float
        Sum of the texel values.
    peak : int
        Largest texel value.
    n_texels : int
    point : (3,) float
        Contact point on the pad surface (hand frame, or world when a hand pose was given).
    normal : (3,) float
        Outward normal of the touched object at the contact: minus the pad's normal.
    """

    matrix: int
    centroid: np.ndarray
    covariance: np.ndarray
    pressure: float
    peak: int
    n_texels: int
    point: np.ndarray
    normal: np.ndarray

    @property
    def eigen_ratio(self) -> float:
        """Ratio of the covariance eigenvalues, small / large (1 for a round blob)."""
        w = np.linalg.eigvalsh(self.covariance)
        return float(w[0] / w[1]) if w[1] > 0 else 1.0

    @property
    def angle(self) -> float:
        """Angle (rad) of the covariance's first (largest) eigenvector in texel coordinates."""
        w, v = np.linalg.eigh(self.covariance)
        e = v[:, 1]
        return float(np.arctan2(e[1], e[0]))


def _moments(values: np.ndarray, labels: np.ndarray, n: int):
    """Per-label weighted centroid, covariance, sum, peak and size (vectorised with bincount)."""
    ys, xs = np.nonzero(labels)
    lab = labels[ys, xs] - 1
    w = values[ys, xs].astype(np.float64)
    s = np.bincount(lab, w, n)
    cnt = np.bincount(lab, None, n).astype(int)
    cx = np.bincount(lab, w * xs, n) / s
    cy = np.bincount(lab, w * ys, n) / s
    dx = xs - cx[lab]
    dy = ys - cy[lab]
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0] = np.bincount(lab, w * dx * dx, n) / s
    cov[:, 1, 1] = np.bincount(lab, w * dy * dy, n) / s
    cov[:, 0, 1] = cov[:, 1, 0] = np.bincount(lab, w * dx * dy, n) / s
    peak = np.zeros(n, dtype=np.int64)
    np.maximum.at(peak, lab, values[ys, xs].astype(np.int64))
    return np.stack([cx, cy], axis=1), cov, s, peak, cnt


def find_blobs(frame, angles, kinematics: SDH2Kinematics | None = None, *, threshold: int = 100,
               min_texels: int = 1, matrices=None, hand_pose=None) -> list:
    """Blobs of pressure in a tactile frame, placed on the hand by the joint angles.

    Parameters
    ----------
    frame : TactileFrame or sequence of 6 (cells_y, cells_x) arrays
    angles : (7,) float
        Joint angles (rad) when the frame was taken.
    kinematics : SDH2Kinematics, optional
        Pad geometry (default: the assumed defaults; prefer
        ``SDH2Kinematics().with_matrix_info(tactile.matrix_infos)``).
    threshold : int
        Texels at or above this value (0..4095) belong to blobs.
    min_texels : int
        Smaller blobs are ignored as noise.
    matrices : iterable of int, optional
        Pads to look at (default all six).
    hand_pose : (4, 4) float, optional
        T_world_hand; points and normals are returned in the world frame when given.

    Returns
    -------
    list of Blob, ordered by pad, then by decreasing pressure.
    """
    kin = as_instance(kinematics, SDH2Kinematics, "kinematics", allow_none=True) or SDH2Kinematics()
    mats = as_sequence(getattr(frame, "matrices", frame), "frame", min_len=6, max_len=6,
                       expected="a TactileFrame or 6 (cells_y, cells_x) arrays (2 per finger)")
    angles = kin._angles(angles)
    threshold = as_count(threshold, "threshold", min=0, max=4095)
    min_texels = as_count(min_texels, "min_texels", max=10**4)
    T = None if hand_pose is None else as_pose(hand_pose, "hand_pose")
    which = range(6) if matrices is None else [as_count(m, "matrices[]", min=0, max=5)
                                               for m in as_sequence(matrices, "matrices", max_len=6)]
    out = []
    for m in which:
        pad = kin.pads[m]
        v = as_float_array(mats[m], f"frame matrix {m}", expected="a 2-D array of finite texel values")
        if v.shape != (pad.cells_y, pad.cells_x):
            raise ValidationError(f"matrix {m} is {v.shape}, the kinematics expects "
                                  f"({pad.cells_y}, {pad.cells_x}); build it with with_matrix_info()")
        mask = v >= max(threshold, 1)
        if not mask.any():
            continue
        labels, n = ndimage.label(mask, structure=_STRUCT8)
        cen, cov, s, peak, cnt = _moments(v, labels, n)
        pts = kin.pad_point(angles, m, cen[:, 0], cen[:, 1])
        nrm = -kin.pad_normal(angles, m)
        if T is not None:
            pts = pts @ T[:3, :3].T + T[:3, 3]
            nrm = T[:3, :3] @ nrm
        for i in np.argsort(-s):
            if cnt[i] < min_texels:
                continue
            out.append(Blob(int(m), cen[i], cov[i], float(s[i]), int(peak[i]), int(cnt[i]), pts[i], nrm.copy()))
    return out


def blobs_to_contacts(blobs) -> Contacts:
    """Contacts (points and normals) of a list of blobs (empty Contacts for none)."""
    blobs = as_sequence(blobs, "blobs", of=Blob)
    if not blobs:
        return Contacts(np.zeros((0, 3)), np.zeros((0, 3)))
    return Contacts(np.stack([b.point for b in blobs]), np.stack([b.normal for b in blobs]))


def frame_to_contacts(frame, angles, kinematics: SDH2Kinematics | None = None, *, threshold: int = 100,
                      min_texels: int = 1, hand_pose=None) -> Contacts:
    """Contacts measured by a tactile frame: one per pressure blob (see :func:`find_blobs`)."""
    return blobs_to_contacts(find_blobs(frame, angles, kinematics, threshold=threshold,
                                        min_texels=min_texels, hand_pose=hand_pose))
