"""Pose-error metrics for localisation: the belief's own expected ADD-S (ADD-S itself lives in
:mod:`touchloc.belief.metrics`, re-exported here)."""

from __future__ import annotations

import numpy as np

from ..belief.metrics import add_s

__all__ = ["add_s", "expected_add_s", "best_pose"]


def best_pose(belief) -> np.ndarray:
    """(4, 4) the belief's point estimate: ``belief.info["map_pose"]`` if an estimator
    left one there (e.g. the particle of highest posterior density of an equally
    weighted sample), else :meth:`ParticleBelief.map_pose`."""
    T = belief.info.get("map_pose") if getattr(belief, "info", None) else None
    return np.array(T, dtype=float) if T is not None else belief.map_pose()


def expected_add_s(belief, obj, *, ref=None, n: int = 200, max_particles: int = 300, rng=0) -> float:
    """The belief's own estimate of its error: E_X~belief[ADD-S(ref, X)] (m).

    ``ref`` defaults to :func:`best_pose`. The heaviest particles holding at most
    ``max_particles`` (and 99 % of the weight) are used, their weights renormalised
    (an equally weighted belief contributes an evenly spaced subset).
    """
    idx = belief.credible_set(0.99)
    if len(idx) > max_particles:
        idx = np.sort(idx)[np.linspace(0, len(idx) - 1, max_particles).astype(int)]
    w = belief.weights[idx]
    w = w / w.sum()
    ref = best_pose(belief) if ref is None else np.asarray(ref, dtype=float)
    # ADD-S(MAP, X) = mean over model points at MAP of the nearest point at X; swap the
    # roles (tree at MAP, queries from X): the same up to the asymmetry of ADD-S, and one tree.
    d = add_s(obj, belief.poses[idx], ref, n=n, rng=rng)
    return float(w @ d)
