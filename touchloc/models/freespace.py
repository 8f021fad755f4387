"""Negative information: a probe that swept a path without contact rules out poses."""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

from .._util import as_points, as_poses
from ..errors import ValidationError
from .base import MeasurementModel, check_temperature
from .mesh import MeshObject

__all__ = ["FreeSpaceModel"]


class FreeSpaceModel(MeasurementModel):
    """Likelihood that the object at pose X left the swept probe paths untouched.

    Each sweep is a capsule: the segment from ``starts[j]`` to ``ends[j]`` (world frame)
    with the probe radius. For an object pose, the clearance of sweep j is
    ``c_j = min over the segment of distance(point, surface) - radius`` (a point inside a
    closed object counts as negative distance). The model is soft, to tolerate noise
    and missed contacts:

        log p(no contact on j | X) = log(eps + (1 - eps) * Phi(c_j / sigma))

    with Phi the standard normal CDF; it carries its own data, so the ``contacts``
    argument of :meth:`log_likelihood` is ignored.

    Parameters
    ----------
    obj : MeshObject
    starts, ends : (J, 3) float
        Swept segments in the world frame (m).
    radius : float or (J,) float
        Probe radius per sweep (m), >= 0.
    sigma : float
        Softness of the boundary (m), > 0 (use the position noise).
    eps : float
        Probability that a real intersection went undetected, in [0, 1).
    spacing : float, optional
        Sample spacing along each segment (m); default: sigma. Penetrations shallower
        than spacing/2 can be missed.
    """

    def __init__(self, obj: MeshObject, starts, ends, radius=0.0, *, sigma: float = 0.002,
                 eps: float = 1e-3, spacing: float | None = None):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        S = as_points(starts, "starts")
        E = as_points(ends, "ends")
        if S.shape != E.shape:
            raise ValidationError(f"starts {S.shape} and ends {E.shape} must match")
        r = np.broadcast_to(np.asarray(radius, dtype=float), (len(S),)).copy()
        if not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ValidationError("radius must be finite and >= 0")
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValidationError(f"sigma must be > 0 (m), got {sigma}")
        if not (0 <= eps < 1):
            raise ValidationError(f"eps must be in [0, 1), got {eps}")
        self.obj, self.starts, self.ends, self.radius = obj, S, E, r
        self.sigma, self.eps = float(sigma), float(eps)
        self.spacing = float(spacing) if spacing else float(sigma)
        # sample points along every segment (fixed in the world frame)
        pts, owner = [], []
        for j in range(len(S)):
            L = np.linalg.norm(E[j] - S[j])
            n = max(2, int(np.ceil(L / self.spacing)) + 1)
            s = np.linspace(0.0, 1.0, n)[:, None]
            pts.append(S[j] + s * (E[j] - S[j]))
            owner.append(np.full(n, j))
        self._pts = np.concatenate(pts)
        self._owner = np.concatenate(owner)

    @classmethod
    def from_results(cls, obj: MeshObject, results, **kwargs) -> "FreeSpaceModel":
        """Free space from executed touches (:class:`touchloc.planners.TouchResult`)."""
        seg = [r.swept_segment for r in results]
        if not seg:
            raise ValidationError("no touch results given")
        radius = [r.touch.probe_radius for r in results]
        return cls(obj, [s for s, _ in seg], [e for _, e in seg], radius, **kwargs)

    def __repr__(self) -> str:
        return f"FreeSpaceModel({self.obj.name!r}, sweeps={len(self.starts)}, sigma={self.sigma})"

    def clearance(self, poses) -> np.ndarray:
        """(N, J) float: clearance of each sweep for each object pose (m)."""
        poses = as_poses(poses)
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        local = np.einsum("nji,nmj->nmi", R, self._pts[None, :, :] - t[:, None, :])  # (N, M, 3)
        flat = local.reshape(-1, 3)
        _, _, d = self.obj.closest_points(flat)
        # Points inside the object count as negative distance. Only points within the
        # object's bounding box can be inside, so contains() runs on those alone.
        lo, hi = self.obj.bounds
        inbox = np.all((flat >= lo) & (flat <= hi), axis=1)
        inside = np.zeros(len(flat), dtype=bool)
        if np.any(inbox):
            inside[inbox] = self.obj.contains(flat[inbox])
        signed = np.where(inside, -d, d).reshape(len(poses), -1) - self.radius[self._owner][None, :]
        J = len(self.starts)
        out = np.full((len(poses), J), np.inf)
        np.minimum.at(out.T, self._owner, signed.T)
        return out

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log p(no contact along the sweeps | pose) / temperature."""
        T = check_temperature(temperature)
        c = self.clearance(poses)
        lp = np.logaddexp(np.log(self.eps) if self.eps > 0 else -np.inf,
                          np.log1p(-self.eps) + log_ndtr(c / self.sigma))
        return lp.sum(axis=1) / T
