"""Distances between shapes: Chamfer distance and F-score (metres)."""

from __future__ import annotations

import numpy as np

from .._util import as_rng
from ..errors import ValidationError
from ..models import MeshObject

__all__ = ["chamfer_distance", "fscore", "surface_distances"]


def _as_mesh(m, name):
    if not isinstance(m, MeshObject):
        raise ValidationError(f"{name} must be a touchloc.models.MeshObject, got {type(m).__name__}")
    return m


def _count(n):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 10_000_000:
        raise ValidationError(f"n must be an integer in [1, 1e7] (surface samples), got {n!r}")
    return int(n)


def surface_distances(a: MeshObject, b: MeshObject, *, n: int = 10000, rng=0):
    """Distances from n area-uniform samples of each surface to the other surface (exact).

    Returns
    -------
    d_ab : (n,) float
        From samples of ``a`` to the surface of ``b`` (m).
    d_ba : (n,) float
        From samples of ``b`` to the surface of ``a`` (m).
    """
    a, b = _as_mesh(a, "a"), _as_mesh(b, "b")
    n = _count(n)
    rng = as_rng(rng)
    pa, _, _ = a.sample_surface(n, rng=rng)
    pb, _, _ = b.sample_surface(n, rng=rng)
    return b.closest_points(pa)[2], a.closest_points(pb)[2]


def chamfer_distance(a: MeshObject, b: MeshObject, *, n: int = 10000, rng=0) -> float:
    """Symmetric mean surface distance (m): (mean d(a -> b) + mean d(b -> a)) / 2.

    Points are sampled uniformly by area and measured to the exact closest point of the
    other surface, so the result has no floor from the sample density.
    """
    d_ab, d_ba = surface_distances(a, b, n=n, rng=rng)
    return float(0.5 * (d_ab.mean() + d_ba.mean()))


def fscore(a: MeshObject, b: MeshObject, tau: float = 0.005, *, n: int = 10000, rng=0) -> float:
    """F-score at threshold ``tau`` (m): harmonic mean of precision (share of ``a`` within
    tau of ``b``) and recall (share of ``b`` within tau of ``a``); ``a`` is the estimate."""
    if isinstance(tau, bool) or not isinstance(tau, (int, float, np.floating)) or not (np.isfinite(tau) and tau > 0):
        raise ValidationError(f"tau must be a positive distance (m), got {tau!r}")
    d_ab, d_ba = surface_distances(a, b, n=n, rng=rng)
    p, r = float(np.mean(d_ab <= tau)), float(np.mean(d_ba <= tau))
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)
