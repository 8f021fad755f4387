"""Utilities of simulated beliefs: negative entropy, KL divergence, task success.

A utility scores a batch of simulated posteriors that share the same particles and
differ only in their weights, so that one call scores every (action, observation) pair
of a planning step.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_float_array, as_instance, as_pose, as_poses, as_positive_float
from ..errors import ValidationError

__all__ = ["Utility", "NegEntropy", "KLDivergence", "TaskSuccess", "pose_features", "batched_entropy",
           "as_utility"]


def pose_features(poses, region, rho: float, kind: str = "embed") -> np.ndarray:
    """Euclidean coordinates of poses in which Gaussian entropies are computed: (N, D).

    ``embed``: free translation axes (m), then rotation as a length that never wraps:
    for yaw regions ``rho * (cos yaw, sin yaw)``, for full rotations the nine entries of
    ``rho * R / sqrt(2)`` (small rotations by theta move them by about ``rho * theta``).
    ``tangent``: the region's local coordinates around the heaviest particle (exact
    metric near it, wraps at pi away from it).

    Parameters
    ----------
    poses : (N, 4, 4) float
    region : PoseRegion or None
        None: all of SE(3) (translation x, y, z and full rotation).
    rho : float
        Rotation scale (m).
    kind : {"embed", "tangent"}
    """
    if region is None:
        free = np.ones(3, dtype=bool)
        rot = "full"
    else:
        free = region.free_translation
        rot = region.rotation
    t = poses[:, :3, 3][:, free]
    if rot == "fixed":
        return t.copy()
    if kind == "tangent":
        if region is None:
            raise ValidationError("tangent features need a region")
        return region.with_rho(rho).to_local(poses, poses[0])
    if kind != "embed":
        raise ValidationError(f"features must be 'embed' or 'tangent', got {kind!r}")
    R = poses[:, :3, :3]
    if rot == "yaw":
        Rl = R @ region.base_rotation.T
        yaw = np.arctan2(Rl[:, 1, 0], Rl[:, 0, 0])
        return np.concatenate([t, rho * np.cos(yaw)[:, None], rho * np.sin(yaw)[:, None]], axis=1)
    return np.concatenate([t, (rho / np.sqrt(2.0)) * R.reshape(len(R), 9)], axis=1)


def batched_entropy(features: np.ndarray, weights: np.ndarray, floor: float) -> np.ndarray:
    """Gaussian entropies (nats) of many weightings of the same points.

    Parameters
    ----------
    features : (P, D) float
    weights : (M, P) float
        Rows sum to one.
    floor : float
        Standard deviation (feature units) added in quadrature to every direction, so
        that beliefs below the resolution that matters are not told apart.

    Returns
    -------
    (M,) float
    """
    X = features - features.mean(axis=0)
    D = X.shape[1]
    mu = weights @ X
    S2 = (weights @ (X[:, :, None] * X[:, None, :]).reshape(len(X), D * D)).reshape(-1, D, D)
    C = S2 - mu[:, :, None] * mu[:, None, :] + np.eye(D) * floor**2
    _, logdet = np.linalg.slogdet(C)
    return 0.5 * (D * np.log(2 * np.pi * np.e) + logdet)


class Utility:
    """Scores simulated beliefs; higher is better.

    Subclasses implement :meth:`prepare` (once per planning call) and :meth:`values`.
    """

    name = "utility"

    def prepare(self, poses, weights, region, rho: float):
        """Precompute what :meth:`values` needs for these particles; returns a context."""
        return None

    def values(self, ctx, weights) -> np.ndarray:
        """(M,) utility of each weighting (M, P) of the particles."""
        raise NotImplementedError

    def subset(self, ctx, idx):
        """The context restricted to particles ``idx``."""
        return ctx[idx]


class NegEntropy(Utility):
    """Negative Gaussian entropy of the belief (eq. 42.11-42.12), in pose features.

    Parameters
    ----------
    floor : float
        Resolution below which spreads do not count (m): the planner stops paying for
        information finer than this.
    features : {"embed", "tangent"}
        See :func:`pose_features`.
    """

    name = "entropy"

    def __init__(self, floor: float = 5e-4, features: str = "embed"):
        floor = as_positive_float(floor, "floor (m)")
        if not isinstance(features, str) or features not in ("embed", "tangent"):
            raise ValidationError(f"features must be 'embed' or 'tangent', got {features!r}")
        self.floor, self.features = floor, features

    def prepare(self, poses, weights, region, rho):
        return pose_features(poses, region, rho, self.features)

    def values(self, ctx, weights):
        return -batched_entropy(ctx, weights, self.floor)


class KLDivergence(Utility):
    """KL divergence of the simulated belief from the current one (nats; higher: more learnt).

    Only meaningful for a static object (the particles do not move between the two).
    """

    name = "kl"

    def prepare(self, poses, weights, region, rho):
        return np.log(np.maximum(weights, 1e-300))

    def values(self, ctx, weights):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(weights > 0, weights * (np.log(np.maximum(weights, 1e-300)) - ctx[None, :]), 0.0)
        return t.sum(axis=1)


class TaskSuccess(Utility):
    """Probability that a grasp planned on the belief succeeds open-loop.

    The grasp is made for one pose hypothesis (the one that maximises the success
    probability); it succeeds for every pose whose offset from that hypothesis lies
    within ``tolerances`` in each dimension of the region (free translation axes in m,
    then rotation in rad: yaw for planar regions, the three rotation-vector components
    for full rotation). Dimensions with an infinite tolerance do not matter (e.g. the
    axial rotation of a cylinder).

    Parameters
    ----------
    tolerances : sequence of float
        One per dimension of the region.
    """

    name = "success"

    def __init__(self, tolerances):
        tol = as_float_array(tolerances, "tolerances", finite=False,
                             expected="positive numbers, one per pose dimension").reshape(-1)
        if tol.size == 0 or np.any(np.isnan(tol)) or np.any(tol <= 0):
            raise ValidationError(f"tolerances must be positive numbers, one per pose dimension, got {tolerances!r}")
        self.tolerances = tol

    def offsets(self, poses, ref_poses, region) -> np.ndarray:
        """(N, M, dim) offsets of poses from reference poses, per region dimension."""
        from ..belief.region import PoseRegion

        region = as_instance(region, PoseRegion, "region", allow_none=True)
        return self._offsets(as_poses(poses, "poses"), as_poses(ref_poses, "ref_poses"), region)

    def _offsets(self, poses, ref_poses, region):
        free = region.free_translation if region is not None else np.ones(3, bool)
        rot = region.rotation if region is not None else "full"
        dt = (poses[:, None, :3, 3] - ref_poses[None, :, :3, 3])[..., free]
        if rot == "fixed":
            return dt
        Rr = np.einsum("nij,mkj->nmik", poses[:, :3, :3], ref_poses[:, :3, :3])
        w = Rotation.from_matrix(Rr.reshape(-1, 3, 3)).as_rotvec().reshape(len(poses), len(ref_poses), 3)
        if rot == "yaw":
            w = w[..., 2:]
        return np.concatenate([dt, w], axis=2)

    def prepare(self, poses, weights, region, rho):
        off = self._offsets(poses, poses, region)
        if off.shape[2] != len(self.tolerances):
            raise ValidationError(f"tolerances must have one entry per pose dimension ({off.shape[2]}), "
                                  f"got {len(self.tolerances)}")
        return np.all(np.abs(off) <= self.tolerances, axis=2).astype(float)  # (P, P): i within tol of j

    def values(self, ctx, weights):
        return (weights @ ctx).max(axis=1)

    def subset(self, ctx, idx):
        return ctx[np.ix_(idx, idx)]

    def success(self, belief, grasp_pose=None) -> float:
        """P(success) of a grasp made for ``grasp_pose`` (default: the best particle)."""
        from ..belief.particles import ParticleBelief

        belief = as_instance(belief, ParticleBelief, "belief")
        w = belief.weights
        if grasp_pose is None:
            ok = self.prepare(belief.poses, w, belief.region, belief.rho or 0.0)
            return float((w @ ok).max())
        off = self._offsets(belief.poses, as_pose(grasp_pose, "grasp_pose")[None], belief.region)[:, 0]
        return float(w @ np.all(np.abs(off) <= self.tolerances, axis=1))


def as_utility(utility) -> Utility:
    """A Utility from a name ("entropy", "kl") or an instance."""
    if isinstance(utility, Utility):
        return utility
    if isinstance(utility, str) and utility == "entropy":
        return NegEntropy()
    if isinstance(utility, str) and utility == "kl":
        return KLDivergence()
    raise ValidationError(f"utility must be 'entropy', 'kl' or a Utility instance (e.g. TaskSuccess), got {utility!r}")
