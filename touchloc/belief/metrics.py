"""Pose-error metrics for evaluating estimators."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import rotation_angle, transform_points

__all__ = ["add_s", "add", "pose_errors"]


def _model_points(obj, n, rng):
    key = ("metric_points", n)
    pts = obj._cache.get(key)
    if pts is None:
        pts, _, _ = obj.sample_surface(n, rng=rng)
        obj._cache[key] = pts
    return pts


def add_s(obj, T_est, T_true, *, n_points: int = 1000, rng=0) -> float:
    """ADD-S (m): mean distance from each model point at the estimated pose to the
    nearest model point at the true pose, so symmetric objects are not penalised."""
    pts = _model_points(obj, n_points, rng)
    a = transform_points(np.asarray(T_est, float), pts)
    b = transform_points(np.asarray(T_true, float), pts)
    d, _ = cKDTree(b).query(a)
    return float(d.mean())


def add(obj, T_est, T_true, *, n_points: int = 1000, rng=0) -> float:
    """ADD (m): mean distance between corresponding model points at the two poses."""
    pts = _model_points(obj, n_points, rng)
    a = transform_points(np.asarray(T_est, float), pts)
    b = transform_points(np.asarray(T_true, float), pts)
    return float(np.linalg.norm(a - b, axis=1).mean())


def pose_errors(T_est, T_true):
    """(translation error (m), rotation error (rad)) between two poses."""
    T_est = np.asarray(T_est, float)
    T_true = np.asarray(T_true, float)
    return (float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            float(rotation_angle(T_est[:3, :3], T_true[:3, :3])))
