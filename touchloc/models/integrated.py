"""Petrovskaya's integrated proximity model: every surface point may have caused a contact."""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from .._util import as_poses
from .._validate import as_callable, as_count, as_positive_float
from ..errors import ValidationError
from .base import MeasurementModel, check_temperature
from .mesh import MeshObject
from .proximity import _check_contacts, contacts_in_object_frame

__all__ = ["IntegratedProximityModel"]


class IntegratedProximityModel(MeasurementModel):
    """Integrated proximity model (Handbook of Robotics ch. 42.1.2).

    Instead of the single closest surface point, all surface points contribute, each
    weighted by a prior of how likely it is to be touched:

        p(D | X) = sum_s pi_s N(D_pos; X o_s, sigma_pos^2 I) N(D_nor; R n_s, sigma_nor^2 I)

    The surface is represented by ``n_samples`` points drawn uniformly by area; the
    prior ``pi`` is uniform over them unless ``surface_prior`` gives a weight per
    sample (e.g. to favour faces a probe can reach). Cost grows as poses x contacts x
    samples, so it suits refinement and small particle sets, not broad search.

    Parameters
    ----------
    obj : MeshObject
    sigma_pos, sigma_nor : float
        As in :class:`~touchloc.models.ProximityModel` (sigma_nor None ignores normals).
    n_samples : int
        Surface samples.
    surface_prior : callable or None
        ``surface_prior(points (S, 3), normals (S, 3)) -> (S,)`` non-negative weights.
    rng : None, int or Generator
        For drawing the surface samples.
    """

    def __init__(self, obj: MeshObject, sigma_pos: float, sigma_nor: float | None = None, *,
                 n_samples: int = 2000, surface_prior=None, rng=None):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        sigma_pos = as_positive_float(sigma_pos, "sigma_pos (m)")
        if sigma_nor is not None:
            sigma_nor = as_positive_float(sigma_nor, "sigma_nor")
        n_samples = as_count(n_samples, "n_samples", max=1_000_000,
                             why="a likelihood pass holds 256 x contacts x n_samples distances")
        surface_prior = as_callable(surface_prior, "surface_prior", allow_none=True)
        self.obj = obj
        self.sigma_pos = float(sigma_pos)
        self.sigma_nor = None if sigma_nor is None else float(sigma_nor)
        self.points, self.normals, _ = obj.sample_surface(int(n_samples), rng=rng)
        if surface_prior is None:
            w = np.ones(len(self.points))
        else:
            w = np.asarray(surface_prior(self.points, self.normals), dtype=float)
            if w.shape != (len(self.points),) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
                raise ValidationError("surface_prior must return (S,) finite non-negative weights, not all zero")
        with np.errstate(divide="ignore"):
            self.log_prior = np.log(w / w.sum())

    def __repr__(self) -> str:
        return f"IntegratedProximityModel({self.obj.name!r}, sigma_pos={self.sigma_pos}, samples={len(self.points)})"

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0, *, chunk: int = 256) -> np.ndarray:
        """(N,) sum_k log p(D_k | X) / temperature (Gaussian constants included)."""
        T = check_temperature(temperature)
        poses = as_poses(poses)
        contacts = _check_contacts(contacts)
        use_n = contacts.has_normals and self.sigma_nor is not None
        const = -1.5 * np.log(2 * np.pi * self.sigma_pos**2)
        if use_n:
            const += -1.5 * np.log(2 * np.pi * self.sigma_nor**2)
        out = np.empty(len(poses))
        for a in range(0, len(poses), chunk):
            P, Nr = contacts_in_object_frame(poses[a:a + chunk], contacts)  # (n, K, 3)
            d2 = (np.sum(P**2, -1)[..., None] - 2 * P @ self.points.T
                  + np.sum(self.points**2, -1)[None, None, :]) / self.sigma_pos**2
            if use_n:
                d2 = d2 + (2.0 - 2.0 * Nr @ self.normals.T) / self.sigma_nor**2
            lk = logsumexp(self.log_prior[None, None, :] - 0.5 * np.maximum(d2, 0.0), axis=-1) + const
            out[a:a + chunk] = lk.sum(axis=1)
        return out / T
