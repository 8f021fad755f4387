"""Rigid-transform helpers on batches of (N, 4, 4) poses (T_world_object).

Rotations go through :class:`scipy.spatial.transform.Rotation`; everything is vectorised
over the batch.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "make_poses",
    "invert_poses",
    "transform_points",
    "rotvec_to_matrix",
    "matrix_to_rotvec",
    "pose_to_vector",
    "vector_to_pose",
    "rotation_angle",
    "pose_distance",
]


try:  # scipy >= 1.16 can skip its own checks of matrices known to be rotations
    Rotation.from_matrix(np.eye(3), assume_valid=True)
    _CHECKED = {"assume_valid": True}
except TypeError:  # pragma: no cover - older scipy
    _CHECKED = {}


def checked_rotations(R) -> Rotation:
    """:class:`Rotation` of (N, 3, 3) matrices that are already known to be rotations
    (checked by ``as_poses`` or made from such); a single (3, 3) matrix gives a single
    rotation.

    scipy's determinant and orthogonality checks cost about 13 times the conversion on a
    batch of particles. Where they find nothing to correct (deviations from orthogonality
    below 1e-12, as for matrices built from quaternions) skipping them gives the same
    quaternions bit for bit; up to the 1e-6 that pose validation tolerates, they differ by
    that order.
    """
    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R if R.shape == (3, 3) else R.reshape(-1, 3, 3), **_CHECKED)


def make_poses(rotations, translations) -> np.ndarray:
    """Stack (N, 3, 3) rotations and (N, 3) translations into (N, 4, 4) poses."""
    R = np.asarray(rotations, dtype=np.float64)
    t = np.asarray(translations, dtype=np.float64)
    if R.ndim == 2:
        R = R[None]
    t = np.broadcast_to(t.reshape(-1, 3), (R.shape[0], 3))
    out = np.zeros((R.shape[0], 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = t
    out[:, 3, 3] = 1.0
    return out


def invert_poses(T: np.ndarray) -> np.ndarray:
    """Inverse of each rigid transform in an (N, 4, 4) (or (4, 4)) array."""
    T = np.asarray(T, dtype=np.float64)
    single = T.ndim == 2
    T = T.reshape(-1, 4, 4)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.zeros_like(T)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out[0] if single else out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) pose to (M, 3) points, or (N, 4, 4) poses to get (N, M, 3)."""
    T = np.asarray(T, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    if T.ndim == 2:
        return P @ T[:3, :3].T + T[:3, 3]
    return np.einsum("nij,mj->nmi", T[:, :3, :3], P) + T[:, None, :3, 3]


def rotvec_to_matrix(rotvecs: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors (axis * angle, rad) to (N, 3, 3) matrices."""
    return Rotation.from_rotvec(np.asarray(rotvecs, dtype=np.float64).reshape(-1, 3)).as_matrix()


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices to (N, 3) rotation vectors."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)).as_rotvec()


def pose_to_vector(T: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses to (N, 6) vectors [x, y, z, rx, ry, rz] (rotation vector)."""
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    return np.concatenate([T[:, :3, 3], matrix_to_rotvec(T[:, :3, :3])], axis=1)


def vector_to_pose(v: np.ndarray) -> np.ndarray:
    """(N, 6) vectors [x, y, z, rx, ry, rz] to (N, 4, 4) poses."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 6)
    return make_poses(rotvec_to_matrix(v[:, 3:]), v[:, :3])


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad) between rotations, broadcast over leading axes of (…, 3, 3)."""
    Ra = np.asarray(Ra, dtype=np.float64)
    Rb = np.asarray(Rb, dtype=np.float64)
    tr = np.einsum("...ij,...ij->...", Ra, Rb)  # trace(Ra^T Rb)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def pose_distance(Ta: np.ndarray, Tb: np.ndarray, *, radius: float = 1.0) -> np.ndarray:
    """Distance sqrt(|dt|^2 + (radius * dtheta)^2) between poses (broadcast over batches).

    ``radius`` (m) converts the rotation angle to a length: the displacement of a point
    ``radius`` away from the origin of the object frame.
    """
    Ta = np.asarray(Ta, dtype=np.float64)
    Tb = np.asarray(Tb, dtype=np.float64)
    dt = np.linalg.norm(Ta[..., :3, 3] - Tb[..., :3, 3], axis=-1)
    da = rotation_angle(Ta[..., :3, :3], Tb[..., :3, :3])
    return np.sqrt(dt**2 + (radius * da) ** 2)
