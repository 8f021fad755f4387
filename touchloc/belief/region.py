"""Pose regions: where the object may be, how to sample it, and how far apart poses are."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .._util import as_poses, as_rng
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_bool, as_count, as_float_array, as_nonnegative_float, as_pose,
                         as_positive_float)
from ..errors import ValidationError
from ..geometry import checked_rotations, make_poses

#: largest perturbation scale (m, pose metric) accepted: beyond it the rotations overflow
MAX_SCALE = 1e6

__all__ = ["PoseRegion"]


def _rz(theta):
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((len(theta), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


class PoseRegion:
    """A box of translations times a set of rotations.

    Build one with :meth:`box` or :meth:`planar`. Poses are compared in a metric that
    makes rotation a length: ``d = sqrt(|dt|^2 + (rho * dtheta)^2)``, with ``rho`` the
    rotation scale (m): a rotation by ``dtheta`` moves points ``rho`` from the origin by
    about ``rho * dtheta``. Estimators set ``rho`` to the object's radius unless given.

    Attributes
    ----------
    center : (3,) float
    half_extent : (3,) float
        Half side lengths of the translation box (m); 0 fixes that coordinate.
    rotation : {"full", "yaw"} or (3, 3) float
        All of SO(3), yaw about world z (times ``base_rotation``), or one fixed rotation.
    base_rotation : (3, 3) float
        For "yaw": rotations are ``Rz(yaw) @ base_rotation``.
    yaw_range : (2,) float
        For "yaw": the interval of yaw (rad).
    """

    def __init__(self, center, half_extent, rotation="full", *, base_rotation=None,
                 yaw_range=(-np.pi, np.pi), rho: float | None = None):
        c = as_float_array(center, "center (m)", finite=False, expected="3 finite numbers").reshape(-1)
        h = as_float_array(half_extent, "half_extent (m)", finite=False, expected="a number or 3 numbers")
        if h.size not in (1, 3):
            raise ValidationError(f"half_extent must be a number or 3 numbers (m), got shape {h.shape}")
        h = np.broadcast_to(h.reshape(-1), (3,)).copy()
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValidationError(f"center must be 3 finite numbers (m), got {center!r}")
        if not np.all(np.isfinite(h)) or np.any(h < 0):
            raise ValidationError(f"half_extent must be finite and >= 0 (m), got {half_extent!r}")
        if isinstance(rotation, str):
            if rotation not in ("full", "yaw"):
                raise ValidationError(f"rotation must be 'full', 'yaw' or a (3, 3) matrix, got {rotation!r}")
            self.rotation = rotation
            self.fixed_rotation = None
        else:
            R = as_float_array(rotation, "rotation", finite=False, expected="'full', 'yaw' or a (3, 3) matrix")
            if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise ValidationError("a fixed rotation must be a proper (3, 3) rotation matrix")
            self.rotation = "fixed"
            self.fixed_rotation = R
        B = np.eye(3) if base_rotation is None else as_float_array(base_rotation, "base_rotation", shape=(3, 3))
        if B.shape != (3, 3) or not np.allclose(B @ B.T, np.eye(3), atol=1e-6):
            raise ValidationError("base_rotation must be a (3, 3) rotation matrix")
        lo, hi = as_float_array(yaw_range, "yaw_range (rad)", shape=(2,), expected="(lo, hi)")
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo and hi - lo <= 2 * np.pi + 1e-12):
            raise ValidationError(f"yaw_range must be (lo, hi) with 0 < hi - lo <= 2 pi, got {yaw_range!r}")
        self.center, self.half_extent, self.base_rotation = c, h, B
        self.yaw_range = (lo, hi)
        self.rho = None if rho is None else as_positive_float(rho, "rho (m)")

    # -- constructors ----------------------------------------------------------------
    @classmethod
    def box(cls, center=(0.0, 0.0, 0.0), half_extent=0.1, rotation="full", **kwargs) -> "PoseRegion":
        """Translations in ``center +- half_extent``; rotation "full", "yaw" or a matrix."""
        return cls(center, half_extent, rotation, **kwargs)

    @classmethod
    def planar(cls, center=(0.0, 0.0), half_extent=0.05, *, z: float = 0.0, yaw_range=(-np.pi, np.pi),
               base_rotation=None, rho: float | None = None) -> "PoseRegion":
        """x, y and yaw on a table at height ``z`` (3 DOF)."""
        c = as_float_array(center, "planar center (m)", shape=(2,), expected="(x, y)")
        h = as_float_array(half_extent, "planar half_extent (m)", expected="a number or (hx, hy)")
        if h.size not in (1, 2):
            raise ValidationError(f"planar half_extent must be a number or (hx, hy), got shape {h.shape}")
        h = np.broadcast_to(h.reshape(-1), (2,))
        z = float(as_float_array(z, "z (m)", shape=()))
        return cls((c[0], c[1], z), (h[0], h[1], 0.0), "yaw", base_rotation=base_rotation,
                   yaw_range=yaw_range, rho=rho)

    def with_rho(self, rho: float) -> "PoseRegion":
        """A copy with the rotation scale set (m)."""
        rho = as_positive_float(rho, "rho (m)")
        r = PoseRegion.__new__(PoseRegion)
        r.__dict__.update(self.__dict__)
        r.rho = rho
        return r

    # -- shape -----------------------------------------------------------------------
    @property
    def free_translation(self) -> np.ndarray:
        """(3,) bool: which translation axes vary."""
        return self.half_extent > 0

    @property
    def rot_dim(self) -> int:
        return {"full": 3, "yaw": 1, "fixed": 0}[self.rotation]

    @property
    def dim(self) -> int:
        """Degrees of freedom of the region."""
        return int(self.free_translation.sum()) + self.rot_dim

    @property
    def yaw_span(self) -> float:
        return self.yaw_range[1] - self.yaw_range[0]

    @property
    def periodic_yaw(self) -> bool:
        return self.rotation == "yaw" and self.yaw_span >= 2 * np.pi - 1e-9

    def _rho(self) -> float:
        if self.rho is None:
            raise ValidationError("this region has no rotation scale rho yet; use region.with_rho(obj.radius)")
        return self.rho

    def radius(self) -> float:
        """Radius of the region in the pose metric (delta_0 of Scaling Series)."""
        t = float(np.linalg.norm(self.half_extent))
        if self.rotation == "full":
            r = np.pi * self._rho()
        elif self.rotation == "yaw":
            r = 0.5 * self.yaw_span * self._rho()
        else:
            r = 0.0
        return float(np.hypot(t, r))

    def volume(self) -> float:
        """Volume in the metric coordinates (m^dim): translations times rho-scaled rotations."""
        v = float(np.prod(2 * self.half_extent[self.free_translation]))
        if self.rotation == "full":
            v *= np.pi**2 * self._rho() ** 3  # SO(3) volume in rotation-vector ball measure
        elif self.rotation == "yaw":
            v *= self.yaw_span * self._rho()
        return v

    def _metric_volume(self) -> float:
        """Volume in the pose metric's own measure, the one a metric ball's volume
        (``ball_volume``) is in: with rotations at rho times their angle apart, SO(3)
        holds 8 pi^2 rho^3 (its Haar measure, which near the identity is the rotation
        vectors' volume). :meth:`volume` gives pi^2 rho^3 for full rotations (the unit
        quaternions' measure, a constant factor 8 below); it is kept, as the particle
        filter's resolution and the evidence's normalisation were set with it (a constant
        factor cancels between objects in :func:`~touchloc.belief.identify`)."""
        return self.volume() * (8.0 if self.rotation == "full" else 1.0)

    def __repr__(self) -> str:
        rot = self.rotation if self.rotation != "yaw" else f"yaw {np.degrees(self.yaw_range).round(1).tolist()} deg"
        return (f"PoseRegion(center={self.center.round(4).tolist()}, half_extent="
                f"{self.half_extent.round(4).tolist()}, rotation={rot}, dim={self.dim})")

    # -- sampling and membership -----------------------------------------------------
    def sample(self, n: int, *, rng=None) -> np.ndarray:
        """n poses drawn uniformly from the region: (n, 4, 4)."""
        n = as_count(n, "n", min=0, max=MAX_PARTICLES, why=WHY_PARTICLES)
        rng = as_rng(rng)
        t = self.center + rng.uniform(-1.0, 1.0, (n, 3)) * self.half_extent
        return make_poses(self._sample_rotations(n, rng), t)

    def _sample_rotations(self, n, rng):
        if self.rotation == "full":
            return Rotation.random(n, random_state=rng).as_matrix()
        if self.rotation == "yaw":
            yaw = rng.uniform(self.yaw_range[0], self.yaw_range[1], n)
            return _rz(yaw) @ self.base_rotation
        return np.repeat(self.fixed_rotation[None], n, axis=0)

    def yaw_of(self, poses) -> np.ndarray:
        """Yaw (rad) of poses of a "yaw" region, in the region's yaw range when periodic."""
        R = as_poses(poses)[:, :3, :3] @ self.base_rotation.T
        yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
        if self.periodic_yaw:
            yaw = (yaw - self.yaw_range[0]) % (2 * np.pi) + self.yaw_range[0]
        return yaw

    def contains(self, poses, *, tol: float = 1e-9) -> np.ndarray:
        """(N,) bool: which poses lie in the region (rotation constraints included)."""
        return self._contains(as_poses(poses), as_nonnegative_float(tol, "tol"))

    def _contains(self, P, tol: float = 1e-9) -> np.ndarray:
        """:meth:`contains` of poses already known to be rigid (an estimator's own)."""
        ok = np.all(np.abs(P[:, :3, 3] - self.center) <= self.half_extent + tol, axis=1)
        R = P[:, :3, :3]
        if self.rotation == "fixed":
            ok &= np.all(np.abs(R - self.fixed_rotation) < 1e-6, axis=(1, 2))
        elif self.rotation == "yaw":
            Rl = R @ self.base_rotation.T
            ok &= np.abs(Rl[:, 2, 2] - 1.0) < 1e-6
            if not self.periodic_yaw:
                y = self.yaw_of(P)
                ok &= (y >= self.yaw_range[0] - tol) & (y <= self.yaw_range[1] + tol)
        return ok

    # -- local coordinates (for neighbourhoods, covariances, MCMC) --------------------
    def to_local(self, poses, ref) -> np.ndarray:
        """Metric coordinates of poses relative to a reference pose: (N, dim) in metres.

        Translation offsets on the free axes, then rho times the rotation offset
        (rotation vector of R R_ref^T; for yaw regions its z component).
        """
        return self._to_local(as_poses(poses), as_pose(ref, "ref"))

    def _to_local(self, P, ref) -> np.ndarray:
        """:meth:`to_local` of checked (N, 4, 4) poses and a checked (4, 4) reference."""
        dt = (P[:, :3, 3] - ref[:3, 3])[:, self.free_translation]
        if self.rotation == "fixed":
            return dt
        w = checked_rotations(P[:, :3, :3] @ ref[:3, :3].T).as_rotvec()
        if self.rotation == "yaw":
            w = w[:, 2:]
        return np.concatenate([dt, self._rho() * w], axis=1)

    def from_local(self, v, ref) -> np.ndarray:
        """Inverse of :meth:`to_local`: (N, dim) metric coordinates -> (N, 4, 4) poses."""
        v = as_float_array(v, "v")
        if v.shape == (self.dim,):
            v = v[None]
        if v.ndim != 2 or v.shape[1] != self.dim:
            raise ValidationError(f"v must be (N, {self.dim}) metric coordinates of this region, got shape {v.shape}")
        ref = as_pose(ref, "ref")
        k = int(self.free_translation.sum())
        t = np.repeat(ref[None, :3, 3], len(v), axis=0)
        t[:, self.free_translation] += v[:, :k]
        if self.rotation == "fixed":
            R = np.repeat(ref[None, :3, :3], len(v), axis=0)
        else:
            w = np.zeros((len(v), 3))
            if self.rotation == "yaw":
                w[:, 2] = v[:, k] / self._rho()
            else:
                w[:] = v[:, k:] / self._rho()
            R = Rotation.from_rotvec(w).as_matrix() @ ref[:3, :3]
        return make_poses(R, t)

    def perturb(self, poses, scale, *, rng=None, ball: bool = True) -> np.ndarray:
        """Move each pose randomly by about ``scale`` in the metric.

        ``ball=True``: uniform in the metric ball of radius ``scale`` (per pose scale
        allowed, (N,)); ``ball=False``: isotropic Gaussian with standard deviation
        ``scale``. Each pose moves in its own local coordinates.
        """
        rng = as_rng(rng)
        P = as_poses(poses)
        ball = as_bool(ball, "ball")
        n, d = len(P), self.dim
        s = as_float_array(scale, "scale", low=0.0, expected="a finite scale >= 0 (or one per pose)")
        if s.size and s.max() > MAX_SCALE:
            raise ValidationError(f"scale must be <= {MAX_SCALE:g} m (a perturbation, not a teleport), got {s.max():g}")
        if s.shape not in ((), (1,), (n,)):
            raise ValidationError(f"scale must be one number or one per pose ({n},), got shape {s.shape}")
        return self._perturb(P, np.broadcast_to(s.reshape(-1) if s.ndim else s, (n,)), rng, ball)

    def _perturb(self, P, s, rng, ball: bool) -> np.ndarray:
        """:meth:`perturb` of rigid poses (N, 4, 4) by checked scales (N,): no validation."""
        n, d = len(P), self.dim
        if ball:
            g = rng.normal(size=(n, d))
            g /= np.linalg.norm(g, axis=1, keepdims=True)
            v = g * (s * rng.random(n) ** (1.0 / d))[:, None]
        else:
            v = rng.normal(size=(n, d)) * s[:, None]
        k = int(self.free_translation.sum())
        out = P.copy()
        out[:, :3, 3][:, self.free_translation] += v[:, :k]
        if self.rotation != "fixed":
            # rotations compose on the left (world axes); for "yaw" about world z only
            w = np.zeros((n, 3))
            if self.rotation == "yaw":
                w[:, 2] = v[:, k] / self._rho()
            else:
                w[:] = v[:, k:] / self._rho()
            out[:, :3, :3] = Rotation.from_rotvec(w).as_matrix() @ P[:, :3, :3]
        return out

    def embed(self, poses) -> np.ndarray:
        """Euclidean embedding approximating the metric locally: (N, D).

        Distances between embedded points equal the metric to second order in the
        rotation angle; for "full" rotations the quaternion sign is fixed, so also
        compare against :meth:`embed_flipped`.
        """
        P = as_poses(poses)
        t = P[:, :3, 3][:, self.free_translation]
        if self.rotation == "fixed":
            return t
        rho = self._rho()
        if self.rotation == "yaw":
            y = self.yaw_of(P)
            return np.concatenate([t, rho * np.cos(y)[:, None], rho * np.sin(y)[:, None]], axis=1)
        q = checked_rotations(P[:, :3, :3]).as_quat()
        q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
        return np.concatenate([t, 2.0 * rho * q], axis=1)

    def embed_flipped(self, poses):
        """The embedding with the other quaternion sign ("full" only; else None)."""
        if self.rotation != "full":
            return None
        e = self.embed(poses)
        e[:, -4:] *= -1.0
        return e
