"""Gaussian pose dynamics (Handbook of Robotics ch. 42, "Dynamics Model")."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .._util import as_poses, as_rng
from .._validate import as_float_array, as_nonnegative_float
from ..errors import ValidationError

__all__ = ["GaussianDynamics"]


class GaussianDynamics:
    """p(X_t | X_{t-1}): Gaussian about the previous pose, isotropic in translation and rotation.

    The object moves by ``X_t = [dR R, t + dt]``: ``dt ~ N(0, sigma_met^2 I_3)`` in the
    world frame and ``dR = exp([w]_x)`` with ``w ~ N(0, sigma_ang^2 I_3)`` (rotation about
    the object's origin, axes in the world frame).

    Parameters
    ----------
    sigma_met : float
        Translation standard deviation per step (m), >= 0.
    sigma_ang : float
        Rotation standard deviation per step (rad), >= 0.
    planar : bool
        Restrict motion to x, y and yaw about world z (objects sliding on a table).
    """

    def __init__(self, sigma_met: float, sigma_ang: float, *, planar: bool = False):
        self.sigma_met = as_nonnegative_float(sigma_met, "sigma_met (m)")
        self.sigma_ang = as_nonnegative_float(sigma_ang, "sigma_ang (rad)")
        if not isinstance(planar, (bool, np.bool_)):
            raise ValidationError(f"planar must be True or False, got {type(planar).__name__}")
        self.planar = bool(planar)

    def __repr__(self) -> str:
        return f"GaussianDynamics(sigma_met={self.sigma_met}, sigma_ang={self.sigma_ang}, planar={self.planar})"

    @property
    def dof(self) -> tuple:
        """(translational, rotational) degrees of freedom."""
        return (2, 1) if self.planar else (3, 3)

    def sample(self, poses, *, rng=None) -> np.ndarray:
        """Draw one next pose for each pose: (N, 4, 4) -> (N, 4, 4)."""
        poses = as_poses(poses)
        rng = as_rng(rng)
        n = len(poses)
        dt = rng.normal(scale=self.sigma_met, size=(n, 3))
        w = rng.normal(scale=self.sigma_ang, size=(n, 3))
        if self.planar:
            dt[:, 2] = 0.0
            w[:, :2] = 0.0
        out = poses.copy()
        out[:, :3, :3] = Rotation.from_rotvec(w).as_matrix() @ poses[:, :3, :3]
        out[:, :3, 3] += dt
        return out

    def _diffs(self, nxt, prev):
        dt = nxt[:, None, :3, 3] - prev[None, :, :3, 3]  # (N, M, 3)
        Rrel = np.einsum("nij,mkj->nmik", nxt[:, :3, :3], prev[:, :3, :3])  # R_n R_m^T
        w = Rotation.from_matrix(Rrel.reshape(-1, 3, 3)).as_rotvec().reshape(len(nxt), len(prev), 3)
        return dt, w

    def log_transition(self, next_poses, prev_poses) -> np.ndarray:
        """log p(next | prev) for every pair: (N, 4, 4), (M, 4, 4) -> (N, M).

        The density is with respect to Lebesgue measure on translations and on the
        rotation vector of ``R_next R_prev^T`` (accurate while sigma_ang is small).
        Components with zero sigma must match exactly (else -inf).
        """
        nxt = as_poses(next_poses, "next_poses")
        prev = as_poses(prev_poses, "prev_poses")
        dt, w = self._diffs(nxt, prev)
        kt, kr = self.dof
        if self.planar:
            dt, w = dt[..., :2], w[..., 2:]
        return _gauss_logpdf(dt, self.sigma_met, kt) + _gauss_logpdf(w, self.sigma_ang, kr)

    def log_prior(self, poses, prev_poses, prev_log_weights=None) -> np.ndarray:
        """log of the predicted prior sum_m w_m p(X | X_m) at each pose (N,).

        This is the dynamics update of a histogram filter or dynamic Scaling Series
        (eq. 42.10 with the integral replaced by a sum over the previous particles).
        """
        from scipy.special import logsumexp

        lt = self.log_transition(poses, prev_poses)
        M = lt.shape[1]
        if prev_log_weights is None:
            lw = np.full(M, -np.log(M))
        else:
            lw = as_float_array(prev_log_weights, "prev_log_weights", finite=False).reshape(-1)
            if lw.shape != (M,):
                raise ValidationError(f"prev_log_weights must be ({M},), one per previous pose, got {lw.shape}")
            if np.any(np.isnan(lw)) or np.any(lw == np.inf) or not np.any(np.isfinite(lw)):
                raise ValidationError("prev_log_weights must be finite or -inf, with at least one finite")
        lw = lw - logsumexp(lw)
        return logsumexp(lt + lw[None, :], axis=1)


def _gauss_logpdf(x, sigma, k):
    sq = np.sum(x * x, axis=-1)
    if sigma == 0:
        return np.where(sq == 0, 0.0, -np.inf)
    return -0.5 * sq / sigma**2 - k * np.log(sigma) - 0.5 * k * np.log(2 * np.pi)
