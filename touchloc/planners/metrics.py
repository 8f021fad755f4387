"""Pose-error metrics for localisation: the belief's own expected ADD-S (ADD-S itself lives in
:mod:`touchloc.belief.metrics`, re-exported here)."""

from __future__ import annotations

import numpy as np

from .._validate import as_count, as_instance, as_pose, as_positive_float
from ..belief import ParticleBelief
from ..belief.metrics import add_s
from ..errors import ValidationError

__all__ = ["add_s", "expected_add_s", "best_pose", "prob_error_below"]


def best_pose(belief) -> np.ndarray:
    """(4, 4) the belief's point estimate: ``belief.info["map_pose"]`` if an estimator
    left one there (e.g. the particle of highest posterior density of an equally
    weighted sample), else :meth:`ParticleBelief.map_pose`."""
    belief = as_instance(belief, ParticleBelief, "belief")
    T = belief.info.get("map_pose") if getattr(belief, "info", None) else None
    return np.array(T, dtype=float) if T is not None else belief.map_pose()


def expected_add_s(belief, obj, *, ref=None, n: int = 200, max_particles: int = 300, rng=0) -> float:
    """The belief's own estimate of its error: E_X~belief[ADD-S(ref, X)] (m).

    ``ref`` defaults to :func:`best_pose`. The heaviest particles holding at most
    ``max_particles`` (and 99 % of the weight) are used, their weights renormalised
    (an equally weighted belief contributes an evenly spaced subset).
    """
    belief = as_instance(belief, ParticleBelief, "belief")
    max_particles = as_count(max_particles, "max_particles", max=1_000_000, why="one ADD-S pass per particle")
    ref = None if ref is None else as_pose(ref, "ref")
    idx = belief.credible_set(0.99)
    if len(idx) > max_particles:
        idx = np.sort(idx)[np.linspace(0, len(idx) - 1, max_particles).astype(int)]
    w = belief.weights[idx]
    w = w / w.sum()
    ref = best_pose(belief) if ref is None else ref
    # ADD-S(MAP, X) = mean over model points at MAP of the nearest point at X; swap the
    # roles (tree at MAP, queries from X): the same up to the asymmetry of ADD-S, and one tree.
    d = add_s(obj, belief.poses[idx], ref, n=n, rng=rng)
    return float(w @ d)


def prob_error_below(belief, obj, threshold: float, *, ref=None, metric: str = "add_s", n: int = 200,
                     max_particles: int = 500, rng=0) -> float:
    """The belief's probability that its estimate is within ``threshold`` of the truth:
    P_X~belief[error(ref, X) < threshold].

    ``metric="add_s"``: the error is ADD-S, which forgives the object's symmetries (a
    belief spread along a symmetry is confident) and also faces sliding along themselves
    (a mug whose handle is unresolved may count as found). ``"pose"``: the pose metric
    modulo the object's computed symmetries, ``sqrt(dt^2 + (rho dr)^2)``
    (:func:`touchloc.belief.symmetric_pose_error`, ``rho`` the belief's), which sees every
    rotation the symmetries do not excuse, the handle included. ``ref`` defaults to :func:`best_pose`. The heaviest particles holding 99.9 %
    of the weight (at most ``max_particles`` of them, evenly spaced in weight order) are
    scored; the missing 0.1 % counts as error.

    Parameters
    ----------
    belief : ParticleBelief
    obj : MeshObject
    threshold : float
        Error (m) in the chosen metric.
    metric : {"add_s", "pose"}

    Returns
    -------
    float in [0, 1]
    """
    from ..belief import ParticleBelief
    from ..models import MeshObject

    if not isinstance(belief, ParticleBelief):
        raise ValidationError(f"belief must be a ParticleBelief, got {type(belief).__name__}")
    if not isinstance(obj, MeshObject):
        raise ValidationError(f"obj must be a touchloc.models.MeshObject, got {type(obj).__name__}")
    threshold = as_positive_float(threshold, "threshold")
    if not isinstance(metric, str) or metric not in ("add_s", "pose"):
        raise ValidationError(f"metric must be 'add_s' or 'pose', got {metric!r}")
    n = as_count(n, "n", max=100_000, why="surface points per pose")
    max_particles = as_count(max_particles, "max_particles", max=100_000, why="poses scored")
    if ref is not None:
        ref = as_pose(ref, "ref")
    idx = belief.credible_set(0.999)
    if len(idx) > max_particles:
        idx = idx[np.linspace(0, len(idx) - 1, max_particles).astype(int)]
    w = belief.weights[idx]
    mass = min(float(belief.weights[belief.credible_set(0.999)].sum()), 1.0)
    w = w / w.sum() * mass
    ref = best_pose(belief) if ref is None else np.asarray(ref, dtype=float)
    if metric == "add_s":
        d = add_s(obj, belief.poses[idx], ref, n=n, rng=rng)
    else:
        from ..belief.metrics import symmetric_pose_error

        rho = belief.rho if belief.rho is not None else obj.radius
        dt, dr = symmetric_pose_error(obj, belief.poses[idx], ref)
        d = np.hypot(dt, rho * dr)
    return float(w @ (d < float(threshold)))
