"""Pose-error metrics for evaluating estimators."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._util import as_poses, as_rng
from .._validate import (as_bool, as_count, as_float_array, as_instance, as_nonnegative_float, as_pose,
                         as_positive_float)
from .._validate import as_poses as _valid_poses
from ..errors import ValidationError
from ..models import MeshObject
from ..models.symmetry import Symmetry
from ..geometry import rotation_angle

__all__ = ["add_s", "add", "pose_errors", "symmetric_pose_error", "credible_level", "hpd_level",
           "belief_coverage", "pairwise_symmetric_distance"]


def _model_points(obj, n, rng):
    """Surface samples of ``obj``, cached per (n, seed) so repeated scores compare alike."""
    key = ("metric_points", int(n), rng if isinstance(rng, (int, type(None))) else id(rng))
    pts = obj._cache.get(key) if isinstance(rng, int) else None
    if pts is None:
        pts, _, _ = obj.sample_surface(int(n), rng=as_rng(rng))
        if isinstance(rng, int):
            obj._cache[key] = pts
    return pts


def add_s(obj, T_est, T_true, *, n: int = 500, rng=0, surface: bool = True):
    """ADD-S: mean over model points at the estimated pose of the distance to the nearest
    model point at the true pose (m). Symmetric objects score 0 for symmetric poses.

    Parameters
    ----------
    obj : MeshObject
    T_est : (4, 4) or (N, 4, 4) float
    T_true : (4, 4) float
    n : int
        Model points, sampled uniformly by area on the surface.
    rng : None, int or Generator
        For sampling the model points (fixed by default, so errors are comparable).
    surface : bool
        True (default): the nearest model point is the nearest point of the true
        surface (exact, through ``obj.closest_points``), so the score has no floor from
        the sampling density. False: the classic form, the nearest of the same n
        sampled points, which reads millimetres for equivalent poses of a
        few-centimetre object sampled with a few hundred points.

    Returns
    -------
    float, or (N,) float for a batch of estimates
    """
    obj = as_instance(obj, MeshObject, "obj")
    n = as_count(n, "n", max=100_000, why="model points per pose")
    surface = as_bool(surface, "surface")
    single = np.asarray(T_est).shape == (4, 4)
    E = as_poses(T_est, "T_est")
    T = as_pose(T_true, "T_true")
    p = _model_points(obj, n, rng)
    q = p[None] @ np.transpose(E[:, :3, :3], (0, 2, 1)) + E[:, None, :3, 3]  # (N, n, 3) world
    if surface:
        local = (q.reshape(-1, 3) - T[:3, 3]) @ T[:3, :3]
        _, _, d = obj.closest_points(local)
    else:
        d, _ = cKDTree(p @ T[:3, :3].T + T[:3, 3]).query(q.reshape(-1, 3))
    out = d.reshape(len(E), -1).mean(axis=1)
    return float(out[0]) if single else out


def add(obj, T_est, T_true, *, n: int = 500, rng=0) -> float:
    """ADD (m): mean distance between corresponding model points at the two poses."""
    obj = as_instance(obj, MeshObject, "obj")
    n = as_count(n, "n", max=100_000, why="model points per pose")
    T_est = as_pose(T_est, "T_est")
    T_true = as_pose(T_true, "T_true")
    p = _model_points(obj, n, rng)
    a = p @ T_est[:3, :3].T + T_est[:3, 3]
    b = p @ T_true[:3, :3].T + T_true[:3, 3]
    return float(np.linalg.norm(a - b, axis=1).mean())


def pose_errors(T_est, T_true):
    """(translation error (m), rotation error (rad)) between two poses."""
    T_est = as_pose(T_est, "T_est")
    T_true = as_pose(T_true, "T_true")
    return (float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            float(rotation_angle(T_est[:3, :3], T_true[:3, :3])))


def symmetric_pose_error(obj, T_est, T_true, *, symmetry=None):
    """Pose error modulo the object's symmetry.

    The translation error is the distance between the symmetry centre (the surface
    centroid, which every symmetry fixes) at the two poses; the rotation error is the
    smallest angle between ``R_est`` and ``R_true g`` over the symmetries ``g``.

    Parameters
    ----------
    obj : MeshObject
    T_est : (4, 4) or (N, 4, 4) float
    T_true : (4, 4) float
    symmetry : Symmetry, optional
        Default ``obj.symmetries()``.

    Returns
    -------
    translation : float or (N,) float
        Metres.
    rotation : float or (N,) float
        Radians.
    """
    obj = as_instance(obj, MeshObject, "obj")
    symmetry = as_instance(symmetry, Symmetry, "symmetry", allow_none=True)
    single = np.asarray(T_est).shape == (4, 4)
    E = as_poses(T_est, "T_est")
    T = as_pose(T_true, "T_true")
    sym = obj.symmetries() if symmetry is None else symmetry
    c = sym.center
    dt = np.linalg.norm(E[:, :3, :3] @ c + E[:, :3, 3] - (T[:3, :3] @ c + T[:3, 3]), axis=1)
    dr = sym.rotation_error(E[:, :3, :3], T[:3, :3])
    return (float(dt[0]), float(dr[0])) if single else (dt, dr)


def credible_level(belief, T_true, obj, *, radius: float | None = None, rho: float | None = None,
                   symmetry=None) -> float:
    """The smallest credible level whose region holds the true pose, modulo symmetry.

    The level-``a`` credible region is the union of balls of ``radius`` around the
    heaviest particles holding ``a`` of the weight (as in
    :meth:`ParticleBelief.credible_set`), with the distance
    ``sqrt(dt^2 + (rho dr)^2)`` of :func:`symmetric_pose_error`. The truth is inside the
    level-``a`` region exactly when the returned value is below ``a``; ``inf`` when no
    particle is within ``radius``. For a calibrated estimator this is uniform on [0, 1].

    Parameters
    ----------
    belief : ParticleBelief
    T_true : (4, 4) float
    obj : MeshObject
    radius : float, optional
        Ball radius (m, pose metric); default the belief's resolution, else 2 mm.
    rho : float, optional
        Metres per radian; default the belief's ``rho``, else the object's bounding radius.
    """
    from .particles import ParticleBelief

    belief = as_instance(belief, ParticleBelief, "belief")
    obj = as_instance(obj, MeshObject, "obj")
    radius = None if radius is None else as_positive_float(radius, "radius (m)")
    rho = None if rho is None else as_positive_float(rho, "rho (m)")
    r = radius if radius is not None else (belief.resolution or 0.002)
    rho = rho if rho is not None else (belief.rho if belief.rho is not None else obj.radius)
    order = np.argsort(-belief.log_weights, kind="stable")
    dt, dr = symmetric_pose_error(obj, belief.poses[order], T_true, symmetry=symmetry)
    close = np.flatnonzero(dt**2 + (rho * dr) ** 2 <= r * r)
    if len(close) == 0:
        return float("inf")
    w = belief.weights[order]
    return float(w[: close[0]].sum())


def _check_obj(obj, symmetry=None):
    from ..models import MeshObject, Symmetry

    if not isinstance(obj, MeshObject):
        raise ValidationError(f"obj must be a touchloc.models.MeshObject, got {type(obj).__name__}")
    if symmetry is not None and not isinstance(symmetry, Symmetry):
        raise ValidationError(f"symmetry must be None or a touchloc.models.Symmetry, got {type(symmetry).__name__}")


def pairwise_symmetric_distance(obj, poses, *, rho: float, symmetry=None) -> np.ndarray:
    """(N, N) pose-metric distances ``sqrt(dt^2 + (rho dr)^2)`` modulo the object's symmetry.

    ``dt`` and ``dr`` are those of :func:`symmetric_pose_error` for every pair. O(N^2)
    memory: meant for a few hundred poses.
    """
    P = _valid_poses(poses, "poses")
    _check_obj(obj, symmetry)
    rho = as_nonnegative_float(rho, "rho")
    if len(P) > 20_000:
        raise ValidationError(f"pairwise distances of {len(P)} poses need too much memory; at most 20,000")
    sym = obj.symmetries() if symmetry is None else symmetry
    c = P[:, :3, :3] @ sym.center + P[:, :3, 3]
    dt2 = np.sum((c[:, None, :] - c[None, :, :]) ** 2, axis=2)
    rel = np.einsum("nji,mjk->nmik", P[:, :3, :3], P[:, :3, :3]).reshape(-1, 3, 3)  # R_i^T R_j
    dr = sym.rotation_error(rel, np.eye(3)).reshape(len(P), len(P))
    return np.sqrt(dt2 + (float(rho) * dr) ** 2)


def hpd_level(belief, T_true, obj, *, n: int = 200, k: int = 5, radius: float | None = None,
              rho: float | None = None, symmetry=None, rng=0) -> float:
    """Level of the smallest highest-density credible region of the belief that holds the
    true pose, modulo symmetry; uniform on [0, 1] for a calibrated belief.

    The belief is read as a density: ``n`` poses are drawn from it (an equally weighted
    belief, a posterior sample, gives ``n`` of its particles without replacement; a
    weighted one is resampled by weight and each draw moved uniformly within ``radius``,
    the ball each particle stands for). The density at each of the ``n + 1`` poses (the
    draws and the truth) is ranked by the distance to its ``k``-th nearest other pose in
    the symmetric pose metric (:func:`pairwise_symmetric_distance`); the level is the
    fraction of draws denser than the truth (ties count half). Because the estimate at
    every pose leaves that pose out, the ``n + 1`` poses are exchangeable when the truth
    is distributed as the belief, and the level is then uniform whatever ``k`` is:
    ``level < a`` happens with probability ``a`` (simulation-based calibration, Talts et
    al. 2018, with highest-density ranks). ``k`` only sets how sharply a wrong belief is
    seen.

    Parameters
    ----------
    belief : ParticleBelief
    T_true : (4, 4) float
    obj : MeshObject
    n : int
        Draws from the belief (cost O(n^2)).
    k : int
        Neighbour rank of the density estimate (robust to up to k - 1 duplicate particles).
    radius : float, optional
        Ball (m, pose metric) around each draw of a weighted belief; default the belief's
        resolution (0 when it has none). Ignored for equally weighted beliefs.
    rho : float, optional
        Metres per radian; default the belief's ``rho``, else the object's radius.
    symmetry : Symmetry, optional
        Default ``obj.symmetries()``.
    rng : None, int or Generator

    Returns
    -------
    float in [0, 1]
    """
    from .particles import ParticleBelief

    if not isinstance(belief, ParticleBelief):
        raise ValidationError(f"belief must be a ParticleBelief, got {type(belief).__name__}")
    _check_obj(obj, symmetry)
    n = as_count(n, "n", min=2, max=10_000, why="the ranks cost O(n^2) distances")
    k = as_count(k, "k", min=1)
    if k >= n:
        raise ValidationError(f"k must be below n (the draws), got k={k}, n={n}")
    T = as_pose(T_true, "T_true")[None]
    if radius is not None:
        radius = as_nonnegative_float(radius, "radius")
    if rho is not None:
        rho = as_positive_float(rho, "rho")
    rng = as_rng(rng)
    rho = rho if rho is not None else (belief.rho if belief.rho is not None else obj.radius)
    lw = belief.log_weights
    N = len(belief)
    if np.ptp(lw) < 1e-9:  # a sample: use it as it is
        idx = rng.choice(N, size=min(int(n), N), replace=False) if N >= int(n) else rng.choice(N, size=int(n))
        X = belief.poses[idx]
    else:
        idx = rng.choice(N, size=int(n), p=belief.weights)
        X = belief.poses[idx]
        r = belief.resolution if radius is None else float(radius)
        if r:
            reg = belief._region() if belief.region is not None else None
            if reg is None:
                from .region import PoseRegion
                reg = PoseRegion.box((0, 0, 0), 1.0, "full", rho=rho)
            X = reg.perturb(X, r, rng=rng, ball=True)
    k = min(int(k), len(X) - 1)
    D = pairwise_symmetric_distance(obj, np.concatenate([X, T]), rho=rho, symmetry=symmetry)
    np.fill_diagonal(D, np.inf)
    dk = np.partition(D, k - 1, axis=1)[:, k - 1]
    d_true, d_draw = dk[-1], dk[:-1]
    return float((np.sum(d_draw < d_true) + 0.5 * np.sum(d_draw == d_true)) / len(d_draw))


def belief_coverage(belief, T_true, obj, levels=(0.5, 0.9, 0.95), *, method: str = "balls", **kwargs) -> dict:
    """{level: whether the true pose lies in the belief's level credible region}.

    Symmetry-aware. ``method="balls"``: the region of :func:`credible_level` (balls
    around the heaviest particles); ``"hpd"``: the highest-density region of
    :func:`hpd_level`, which is exactly calibrated for a correct belief and is the one
    to average over trials. Keyword arguments go to that function. Averaged over trials,
    the fraction of True at level ``a`` should be close to ``a``.
    """
    lv = as_float_array(levels, "levels", expected="credible levels in (0, 1]").reshape(-1)
    if np.any((lv <= 0) | (lv > 1)):
        raise ValidationError(f"levels must be in (0, 1], got {lv.tolist()}")
    if not isinstance(method, str) or method not in ("balls", "hpd"):
        raise ValidationError(f"method must be 'balls' or 'hpd', got {method!r}")
    q = (credible_level if method == "balls" else hpd_level)(belief, T_true, obj, **kwargs)
    return {float(a): bool(q < a) for a in lv}
