"""ParticleBelief: a weighted set of object poses, the output of every estimator."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import logsumexp

from .._util import as_poses, as_rng
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_bool, as_count, as_float_array, as_instance,
                         as_mapping, as_pose, as_positive_float, as_probability)
from ..errors import BeliefDegenerateError, ValidationError
from ..geometry import checked_rotations
from .region import PoseRegion

__all__ = ["ParticleBelief", "RESAMPLERS", "register_resampler", "systematic_resample"]

RESAMPLERS = {}


def register_resampler(name: str):
    """Decorator: make ``fn(weights (N,), n, rng) -> indices (n,)`` available by name."""

    def deco(fn):
        RESAMPLERS[name] = fn
        return fn

    return deco


@register_resampler("systematic")
def systematic_resample(weights: np.ndarray, n: int, rng) -> np.ndarray:
    """Systematic resampling: one uniform offset, n evenly spaced pointers (low variance)."""
    weights = as_float_array(weights, "weights", shape=(None,), low=0.0)
    n = as_count(n, "n", max=MAX_PARTICLES, why=WHY_PARTICLES)
    rng = as_rng(rng)
    if not weights.size or not weights.sum() > 0:
        raise BeliefDegenerateError("weights must hold at least one positive entry to resample from")
    total = weights.sum()
    if abs(total - 1.0) > 1e-9:  # normalised weights are used as they are, bit for bit
        weights = weights / total
    cs = np.cumsum(weights)
    cs[-1] = 1.0
    u = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cs, u, side="right").clip(0, len(weights) - 1)


@register_resampler("multinomial")
def multinomial_resample(weights: np.ndarray, n: int, rng) -> np.ndarray:
    return rng.choice(len(weights), size=n, p=weights)


def _normalised(lw: np.ndarray) -> np.ndarray:
    """(N,) log-weights normalised to sum to one in probability, or BeliefDegenerateError."""
    if np.any(np.isnan(lw)) or np.any(lw == np.inf):
        raise BeliefDegenerateError("log_weights contain NaN or +inf: the likelihood is broken")
    top = lw.max()
    if not np.isfinite(top):
        raise BeliefDegenerateError(
            "every particle has zero weight (all log-likelihoods are -inf): no pose in "
            "the region explains the measurements")
    return lw - (top + np.log(np.sum(np.exp(lw - top))))


class ParticleBelief:
    """A belief over object poses represented by weighted particles.

    Parameters
    ----------
    poses : (N, 4, 4) float
        T_world_object of each particle.
    log_weights : (N,) float or None
        Unnormalised log-weights (normalised on construction with logsumexp); uniform
        if None. ``-inf`` entries are allowed (zero weight) as long as one is finite.
    region : PoseRegion, optional
        The region the belief lives in; gives the metric (its ``rho``) for covariances,
        entropy and credible regions.
    resolution : float, optional
        Radius (in the pose metric, m) each particle stands for: the final delta of
        Scaling Series, a histogram cell, a kernel width. Used by credible regions.
    info : dict, optional
        Estimator diagnostics (timings, scales, particle counts).

    Raises
    ------
    BeliefDegenerateError
        When no weight is finite and positive (every likelihood underflowed or is NaN).
    """

    def __init__(self, poses, log_weights=None, *, region: PoseRegion | None = None,
                 resolution: float | None = None, info: dict | None = None,
                 degenerate: bool = False, rho: float | None = None):
        P = as_poses(poses)
        if len(P) == 0:
            raise ValidationError("a belief needs at least one particle")
        if log_weights is None:
            lw = np.full(len(P), -np.log(len(P)))
        else:
            lw = as_float_array(log_weights, "log_weights", finite=False).reshape(-1)
            if lw.shape != (len(P),):
                raise ValidationError(f"log_weights must be ({len(P)},), got {lw.shape}")
            lw = _normalised(lw)
        region = as_instance(region, PoseRegion, "region", allow_none=True)
        resolution = None if resolution is None else as_positive_float(resolution, "resolution")
        info = {} if info is None else as_mapping(info, "info")
        degenerate = as_bool(degenerate, "degenerate")
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        self._set(P, lw, region, resolution, info, degenerate, rho)

    def _set(self, P, lw, region, resolution, info, degenerate, rho):
        self.poses = P
        self.log_weights = lw
        self.region = region
        self.resolution = resolution
        self.info = dict(info or {})
        self.degenerate = bool(degenerate)
        if rho is None and region is not None:
            rho = region.rho
        self.rho = rho

    @classmethod
    def _trusted(cls, poses, log_weights, region=None, resolution=None, info=None):
        """A belief from an estimator's own particles: (N, 4, 4) rigid poses it made, and
        (N,) float log-weights (or None), which are checked and normalised as the constructor
        does. The poses are not re-validated: the estimators build one belief per scale or
        tempering stage, and re-checking every rotation took about a twentieth of a
        30-contact localisation."""
        b = cls.__new__(cls)
        lw = np.full(len(poses), -np.log(len(poses))) if log_weights is None else _normalised(log_weights)
        b._set(poses, lw, region, resolution, info, False, None)
        return b

    # -- basic -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.poses)

    def __repr__(self) -> str:
        flag = ", DEGENERATE" if self.degenerate else ""
        return f"ParticleBelief(N={len(self)}, ess={self.ess():.1f}{flag})"

    @property
    def weights(self) -> np.ndarray:
        """(N,) normalised weights."""
        return np.exp(self.log_weights)

    def ess(self) -> float:
        """Effective sample size 1 / sum w^2."""
        return float(np.exp(-logsumexp(2.0 * self.log_weights)))

    def map_pose(self) -> np.ndarray:
        """(4, 4) the particle of highest weight; for a posterior sample (equal weights),
        the particle of highest posterior density that its estimator left in
        ``info["map_pose"]``, when there is one."""
        T = self.info.get("map_pose")
        if T is not None and np.ptp(self.log_weights) < 1e-12:
            return np.array(T, dtype=float).reshape(4, 4)
        return self.poses[int(np.argmax(self.log_weights))].copy()

    def mean_pose(self) -> np.ndarray:
        """(4, 4) weighted mean: mean translation and the chordal L2 mean rotation."""
        w = self.weights
        out = np.eye(4)
        out[:3, 3] = w @ self.poses[:, :3, 3]
        out[:3, :3] = checked_rotations(self.poses[:, :3, :3]).mean(weights=w).as_matrix()
        return out

    def _rho(self) -> float:
        if self.rho is None:
            raise ValidationError("this belief has no rotation scale rho; pass rho= or a region with rho")
        return float(self.rho)

    def _region(self) -> PoseRegion:
        if self.region is not None:
            return self.region
        return PoseRegion.box((0, 0, 0), 1.0, "full", rho=self._rho())

    def tangent(self, ref=None) -> np.ndarray:
        """Particles in metric coordinates around ``ref`` (default: mean pose): (N, dim)."""
        # the belief's own poses were checked when it was made (or made by an estimator)
        ref = self.mean_pose() if ref is None else as_pose(ref, "ref")
        return self._region()._to_local(self.poses, ref)

    def covariance(self, ref=None) -> np.ndarray:
        """(dim, dim) weighted covariance in the tangent space at the mean.

        Coordinates: free translation axes (m), then rho times the rotation vector (m).
        """
        v = self.tangent(ref)
        w = self.weights
        mu = w @ v
        d = v - mu
        return (d * w[:, None]).T @ d

    def std(self) -> dict:
        """Marginal spreads: translation (m, per free axis) and rotation (rad)."""
        reg = self._region()
        C = self.covariance()
        k = int(reg.free_translation.sum())
        sd = np.sqrt(np.clip(np.diag(C), 0, None))
        rot = sd[k:] / self._rho() if reg.rotation != "fixed" else np.zeros(0)
        return {"translation": sd[:k], "rotation": rot}

    def entropy(self, method: str = "gaussian") -> float:
        """Differential entropy (nats) in the metric coordinates of the region.

        ``gaussian``: entropy of a Gaussian with the belief's covariance, floored at the
        belief's resolution (an upper bound for the true entropy; comparable between
        beliefs of any particle count, cheap). ``kde``: the leave-one-out estimate
        ``-sum_i w_i log p_{-i}(x_i)`` under a Gaussian kernel density (bandwidth: the
        resolution, or else Silverman's rule, which over-smooths well separated modes), which sees multiple modes; O(N^2), so at most
        the 2000 heaviest particles are used.
        """
        d = self._region().dim
        if not isinstance(method, str):
            raise ValidationError(f"entropy method must be 'gaussian' or 'kde', got {type(method).__name__}")
        if method == "gaussian":
            C = self.covariance()
            floor = (self.resolution or 0.0) ** 2 / (d + 2.0)  # variance of a uniform ball
            C = C + np.eye(d) * max(floor, 1e-18)
            sign, logdet = np.linalg.slogdet(C)
            return float(0.5 * (d * np.log(2 * np.pi * np.e) + logdet))
        if method == "kde":
            v = self.tangent()
            w = self.weights
            if len(v) > 2000:
                keep = np.argsort(w)[-2000:]
                v, w = v[keep], w[keep] / w[keep].sum()
            ess = max(self.ess(), 1.0)
            sd = np.sqrt(np.maximum(np.diag(self.covariance()).mean(), 1e-18))
            h = self.resolution or sd * (4.0 / ((d + 2.0) * ess)) ** (1.0 / (d + 4.0))
            d2 = np.sum((v[:, None, :] - v[None, :, :]) ** 2, axis=2)
            logk = -0.5 * d2 / h**2 - 0.5 * d * np.log(2 * np.pi * h**2)
            # leave-one-out: a particle's own kernel would bias the estimate low
            np.fill_diagonal(logk, -np.inf)
            with np.errstate(divide="ignore"):
                logp = logsumexp(logk + np.log(w)[None, :], axis=1) - np.log1p(-np.minimum(w, 1 - 1e-12))
            ok = np.isfinite(logp)
            return float(-(w[ok] * logp[ok]).sum() / w[ok].sum())
        raise ValidationError(f"entropy method must be 'gaussian' or 'kde', got {method!r}")

    # -- operations --------------------------------------------------------------------
    def resample(self, n: int | None = None, *, method: str = "systematic", rng=None) -> "ParticleBelief":
        """A new belief of n equally weighted particles drawn by weight."""
        if not isinstance(method, str) or method not in RESAMPLERS:
            raise ValidationError(f"unknown resampler {method!r}; registered: {sorted(RESAMPLERS)}")
        rng = as_rng(rng)
        n = len(self) if n is None else as_count(n, "n", max=MAX_PARTICLES, why=WHY_PARTICLES)
        idx = RESAMPLERS[method](self.weights, n, rng)
        return self.with_particles(self.poses[idx], None)

    def with_particles(self, poses, log_weights) -> "ParticleBelief":
        """A belief with new particles and the same region, resolution and rho."""
        # the estimator's MAP pose belongs to the old particles
        info = {k: v for k, v in self.info.items() if k != "map_pose"}
        return ParticleBelief(poses, log_weights, region=self.region, resolution=self.resolution,
                              rho=self.rho, info=info)

    def reweighted(self, log_likelihood) -> "ParticleBelief":
        """Bayes update: multiply the weights by exp(log_likelihood) (N,)."""
        ll = as_float_array(log_likelihood, "log_likelihood", finite=False).reshape(-1)
        if ll.shape != (len(self),):
            raise ValidationError(f"log_likelihood must be ({len(self)},), got {ll.shape}")
        return self.with_particles(self.poses, self.log_weights + ll)

    def credible_set(self, level: float = 0.9) -> np.ndarray:
        """Indices of the fewest heaviest particles whose weights add up to ``level``."""
        level = as_probability(level, "level", open_low=True)
        order = np.argsort(-self.log_weights)
        cum = np.cumsum(self.weights[order])
        k = int(np.searchsorted(cum, level - 1e-12) + 1)
        return order[:k]

    def in_credible_region(self, poses, level: float = 0.9, *, radius: float | None = None) -> np.ndarray:
        """(M,) bool: is each pose within ``radius`` (pose metric) of the ``level`` credible set?

        The credible region is the union of balls of ``radius`` (default: the belief's
        resolution) around the heaviest particles holding ``level`` of the weight.
        """
        Q = as_poses(poses)
        r = as_positive_float(radius, "radius") if radius is not None else self.resolution
        if r is None:
            raise ValidationError("no radius: give radius= or build the belief with a resolution")
        S = self.poses[self.credible_set(level)]
        reg = self._region()
        d2 = np.sum((Q[:, None, :3, 3] - S[None, :, :3, 3]) ** 2, axis=2)
        if reg.rotation != "fixed":
            tr = np.einsum("mij,nij->mn", Q[:, :3, :3], S[:, :3, :3])
            d2 = d2 + (reg._rho() * np.arccos(np.clip((tr - 1) / 2, -1, 1))) ** 2
        return np.any(d2 <= r * r, axis=1)

    def summary(self) -> str:
        """One line: MAP pose and spreads (mm, deg)."""
        T = self.map_pose()
        sd = self.std()
        ang = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
        rot = f", rot sd {np.degrees(sd['rotation']).round(2).tolist()} deg" if len(sd["rotation"]) else ""
        return (f"MAP t = {np.round(T[:3, 3] * 1e3, 2).tolist()} mm, rotvec = {np.round(ang, 2).tolist()} deg; "
                f"sd {np.round(sd['translation'] * 1e3, 2).tolist()} mm{rot}; N={len(self)}, ESS={self.ess():.1f}"
                + (" [DEGENERATE]" if self.degenerate else ""))
