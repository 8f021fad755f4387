"""Simulated outcomes of guarded touches for many object poses at once (embreex rays)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._util import as_poses
from ..errors import ValidationError
from ..models import Contacts, MeshObject
from ..models.freespace import probe_rays  # one definition of the 17-ray probe sphere
from .actions import GuardedTouch, TouchResult, fingers_of

__all__ = ["Outcomes", "simulate", "flatten_actions", "execute"]


def flatten_actions(actions):
    """Fingers of a list of actions, grouped by action.

    Returns
    -------
    fingers : list of GuardedTouch (F)
    owner : (F,) int
        Index of the action each finger belongs to (non-decreasing).
    """
    if isinstance(actions, (GuardedTouch,)) or not hasattr(actions, "__len__"):
        actions = [actions]
    if len(actions) == 0:
        raise ValidationError("the candidate list is empty: give at least one GuardedTouch or HandTouch")
    fingers, owner = [], []
    for i, a in enumerate(actions):
        try:
            f = fingers_of(a)
        except ValidationError:
            raise ValidationError(f"candidate {i} must be a GuardedTouch or a HandTouch, "
                                  f"got {type(a).__name__}") from None
        fingers.extend(f)
        owner.extend([i] * len(f))
    return fingers, np.asarray(owner, dtype=np.int64)


@dataclass
class Outcomes:
    """Noise-free outcomes of F finger touches for P object poses.

    Attributes
    ----------
    travel : (P, F) float
        How far each finger moves before it stops (m); ``max_travel`` on a miss.
    hit : (P, F) bool
        Whether the finger touches the object within ``max_travel``.
    points : (P, F, 3) float
        World-frame contact points (NaN on a miss).
    normals : (P, F, 3) float
        World-frame outward surface normals at the contacts (NaN on a miss).
    fingers : list of GuardedTouch (F)
    owner : (F,) int
        Action index of each finger.
    start_inside : (P, F) bool
        The finger would start inside the object (a collision before the touch; its
        outcome is reported as a contact at travel 0 against the motion).
    """

    travel: np.ndarray
    hit: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    fingers: list
    owner: np.ndarray
    start_inside: np.ndarray = None

    @property
    def n_actions(self) -> int:
        return int(self.owner[-1]) + 1 if len(self.owner) else 0


def simulate(obj: MeshObject, poses, actions) -> Outcomes:
    """Where each finger of each action stops, for the object at each pose.

    Every finger ray is moved into every pose's object frame and all P x F rays (times
    17 for fingers with a probe radius, which sweep a sphere approximated by 17 parallel
    rays) are cast in one embreex call.

    Parameters
    ----------
    obj : MeshObject
    poses : (P, 4, 4) float
        T_world_object hypotheses.
    actions : list of GuardedTouch or HandTouch (C)

    Returns
    -------
    Outcomes
        With F = total number of fingers of the C actions.
    """
    if not isinstance(obj, MeshObject):
        raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
    T = as_poses(poses)
    fingers, owner = flatten_actions(actions)
    P, F = len(T), len(fingers)
    O = np.array([f.origin for f in fingers])
    D = np.array([f.direction for f in fingers])
    maxt = np.array([f.max_travel for f in fingers])
    rad = np.array([f.probe_radius for f in fingers])
    # rays per finger: one for point probes, 17 for spheres
    RO, RD, RF, RB = probe_rays(O, D, rad)
    R, t = T[:, :3, :3], T[:, :3, 3]
    lo = (RO[None, :, :] - t[:, None, :]) @ R    # (P, M, 3): R^T (o - t) per pose
    ld = RD[None, :, :] @ R
    dist, _, nl = obj.ray_cast(lo.reshape(-1, 3), ld.reshape(-1, 3))
    M = len(RO)
    dist = dist.reshape(P, M)
    nl = nl.reshape(P, M, 3)
    # a ray leaving through a face started inside the object: immediate contact
    with np.errstate(invalid="ignore"):
        inside = np.einsum("pmi,pmi->pm", nl, ld) > 0
    dist = np.where(inside, 0.0, dist - RB[None, :])
    dist = np.maximum(dist, 0.0)
    # per finger, the ray that stops first
    best = np.full((P, F), np.inf)
    arg = np.zeros((P, F), dtype=np.int64)
    order = np.argsort(RF, kind="stable")
    sorted_d = dist[:, order]
    starts = np.searchsorted(RF[order], np.arange(F))
    # reduce per finger (most fingers have one ray: a fast path)
    if M == F:
        best, arg = dist, np.broadcast_to(np.arange(F), (P, F)).copy()
    else:
        best = np.minimum.reduceat(sorted_d, starts, axis=1)
        for j in range(F):
            seg = order[starts[j]:(starts[j + 1] if j + 1 < F else M)]
            arg[:, j] = seg[np.argmin(dist[:, seg], axis=1)]
    hit = best <= maxt[None, :]
    travel = np.where(hit, best, maxt[None, :])
    n_loc = np.take_along_axis(nl, arg[:, :, None], axis=1)
    n_loc = np.where(inside[np.arange(P)[:, None], arg][:, :, None], -ld[np.arange(P)[:, None], arg], n_loc)
    normals = n_loc @ np.transpose(R, (0, 2, 1))
    # contact point on the surface: the stopping ray's origin + its hit distance
    ray_hit = RO[arg] + (travel + RB[arg])[:, :, None] * D[None, :, :]
    ray_hit = np.where((rad[None, :] > 0)[:, :, None], ray_hit, O[None] + travel[:, :, None] * D[None])
    points = np.where(hit[:, :, None], ray_hit, np.nan)
    normals = np.where(hit[:, :, None], normals, np.nan)
    return Outcomes(travel, hit, points, normals, list(fingers), owner, inside[:, :F].copy())


def execute(obj: MeshObject, true_pose, action, *, noise_pos: float = 0.0, noise_nor: float = 0.0,
            rng=None) -> list:
    """Execute an action on a simulated world (the object at ``true_pose``).

    Parameters
    ----------
    obj : MeshObject
    true_pose : (4, 4) float
    action : GuardedTouch or HandTouch
    noise_pos : float
        Standard deviation of the Gaussian noise added to contact points (m).
    noise_nor : float
        Standard deviation of the Gaussian noise added to contact normals.
    rng : None, int or Generator

    Returns
    -------
    list of TouchResult
        One per finger.
    """
    from .._util import as_rng

    from .._validate import as_instance, as_nonnegative_float, as_pose

    obj = as_instance(obj, MeshObject, "obj")
    true_pose = as_pose(true_pose, "true_pose")
    noise_pos = as_nonnegative_float(noise_pos, "noise_pos (m)")
    noise_nor = as_nonnegative_float(noise_nor, "noise_nor")
    rng = as_rng(rng)
    out = simulate(obj, true_pose[None], [action])
    res = []
    for j, f in enumerate(out.fingers):
        if out.hit[0, j]:
            p = out.points[0, j] + rng.normal(scale=noise_pos, size=3) if noise_pos > 0 else out.points[0, j]
            n = out.normals[0, j] + (rng.normal(scale=noise_nor, size=3) if noise_nor > 0 else 0.0)
            res.append(TouchResult(f, float(out.travel[0, j]), Contacts(p[None], n[None])))
        else:
            res.append(TouchResult(f, float(out.travel[0, j]), None))
    return res
