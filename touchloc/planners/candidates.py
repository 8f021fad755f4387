"""Candidate actions: world-fixed pools, pools relative to the best pose, closing hands."""

from __future__ import annotations

import numpy as np

from .._util import as_rng
from .._validate import as_count, as_nonnegative_float, as_pose, as_positive_float, as_probability
from ..errors import ValidationError
from .actions import GuardedTouch, HandTouch

#: a candidate pool larger than this is scored by every planner touch by touch: refuse it
MAX_POOL = 100_000
_WHY = "planners score every candidate; split a larger pool"


def _check_obj(obj):
    from ..models import MeshObject

    if not isinstance(obj, MeshObject):
        raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")


def _check_region(region):
    from ..belief import PoseRegion

    if not isinstance(region, PoseRegion):
        raise ValidationError(f"region must be a PoseRegion, got {type(region).__name__}")

__all__ = ["world_pool", "relative_pool", "hand_pool", "CandidateGenerator"]


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _z_range(region, obj):
    """World z interval an upright object of a planar region occupies."""
    pts = obj.mesh.vertices @ region.base_rotation.T
    return region.center[2] + pts[:, 2].min(), region.center[2] + pts[:, 2].max()


def world_pool(region, obj, n: int = 100, *, rng=None, margin: float = 0.05, top_fraction: float = 0.2,
               probe_radius: float = 0.0) -> list:
    """Touches fixed in the world, aimed into the region from outside it.

    For a planar region (rotation "yaw" about z with a fixed height): horizontal touches
    from a circle around the region at heights within the object's vertical extent,
    aimed at random points of the region, and a fraction ``top_fraction`` straight down
    from above. Otherwise: touches from a sphere around the region aimed at random
    points of the region grown by half the object's radius.

    Parameters
    ----------
    region : PoseRegion
    obj : MeshObject
    n : int
        Number of touches.
    margin : float
        Clearance between the swept volume of the object and the start points (m).

    Returns
    -------
    list of GuardedTouch
    """
    _check_region(region)
    _check_obj(obj)
    n = as_count(n, "n", max=MAX_POOL, why=_WHY)
    margin = as_nonnegative_float(margin, "margin (m)")
    top_fraction = as_probability(top_fraction, "top_fraction")
    probe_radius = as_nonnegative_float(probe_radius, "probe_radius (m)")
    rng = as_rng(rng)
    c, h = region.center, region.half_extent
    r_obj = obj.radius
    R = float(np.linalg.norm(h)) + r_obj + margin
    out = []
    planar = region.rotation == "yaw" and h[2] == 0
    if planar:
        z0, z1 = _z_range(region, obj)
        n_top = int(round(top_fraction * n))
        for i in range(n - n_top):
            a = rng.uniform(0, 2 * np.pi)
            tgt = np.r_[c[:2] + rng.uniform(-1, 1, 2) * (h[:2] + 0.3 * r_obj), rng.uniform(z0 + 0.1 * (z1 - z0), z1 - 0.05 * (z1 - z0))]
            o = np.r_[c[:2] + R * np.array([np.cos(a), np.sin(a)]), tgt[2]]
            d = tgt - o
            out.append(GuardedTouch(o, d, 2 * R, probe_radius, name=f"side {i}"))
        for i in range(n_top):
            xy = c[:2] + rng.uniform(-1, 1, 2) * (h[:2] + 0.6 * r_obj)
            o = np.r_[xy, z1 + margin]
            out.append(GuardedTouch(o, (0, 0, -1), z1 - z0 + margin, probe_radius, name=f"top {i}"))
        return out
    for i in range(n):
        u = _unit(rng.normal(size=3))
        o = c + R * u
        tgt = c + rng.uniform(-1, 1, 3) * (h + 0.5 * r_obj)
        out.append(GuardedTouch(o, tgt - o, 2 * R, probe_radius, name=f"world {i}"))
    return out


def relative_pool(pose, obj, n: int = 50, *, rng=None, standoff: float = 0.03, depth: float | None = None,
                  min_normal_z: float | None = None, probe_radius: float = 0.0) -> list:
    """Touches aimed at the object's faces from outside, relative to a pose estimate.

    Surface points are drawn on the object (by area) and placed at ``pose``; each touch
    starts ``standoff`` out along the surface normal and moves against it.

    Parameters
    ----------
    pose : (4, 4) float
        Usually the belief's MAP pose.
    obj : MeshObject
    n : int
    standoff : float
        Start distance from the surface (m).
    depth : float, optional
        How far past the expected surface the touch may go (m); default the object's
        radius, so that a touch still finds the object when the estimate is off.
    min_normal_z : float, optional
        Drop touches whose world surface normal has a smaller z component (e.g. -0.2 on
        a table: never touch from below).

    Returns
    -------
    list of GuardedTouch
    """
    T = as_pose(pose)
    _check_obj(obj)
    n = as_count(n, "n", max=MAX_POOL, why=_WHY)
    standoff = as_nonnegative_float(standoff, "standoff (m)")
    if depth is not None:
        depth = as_positive_float(depth, "depth (m)")
    if min_normal_z is not None:
        from .._validate import as_float

        min_normal_z = as_float(min_normal_z, "min_normal_z", low=-1.0, high=1.0)
    probe_radius = as_nonnegative_float(probe_radius, "probe_radius (m)")
    rng = as_rng(rng)
    depth = obj.radius if depth is None else float(depth)
    out = []
    tries = 0
    while len(out) < n and tries < 5:
        p, nr, _ = obj.sample_surface(2 * n, rng=rng)
        P = p @ T[:3, :3].T + T[:3, 3]
        N = nr @ T[:3, :3].T
        ok = np.ones(len(P), bool) if min_normal_z is None else N[:, 2] >= min_normal_z
        for q, m in zip(P[ok], N[ok]):
            if len(out) >= n:
                break
            out.append(GuardedTouch(q + (standoff + probe_radius) * m, -m, standoff + depth, probe_radius,
                                    name=f"face {len(out)}"))
        tries += 1
    return out


def hand_pool(pose, obj, n: int = 20, *, n_fingers: int = 3, rng=None, standoff: float = 0.03,
              planar: bool = True, probe_radius: float = 0.0) -> list:
    """Hands closing on the object: fingers spread evenly around it, moving to its axis.

    Each hand picks a closing plane through the object's estimated centre (horizontal
    at a random height of the object when ``planar``; random otherwise) and a random
    rotation within it; its ``n_fingers`` fingers start ``standoff`` outside the
    object's bounding sphere and move towards the centre line.

    Returns
    -------
    list of HandTouch
    """
    T = as_pose(pose)
    _check_obj(obj)
    n = as_count(n, "n", max=MAX_POOL, why=_WHY)
    n_fingers = as_count(n_fingers, "n_fingers", max=16, why="a hand has a few fingers")
    standoff = as_nonnegative_float(standoff, "standoff (m)")
    probe_radius = as_nonnegative_float(probe_radius, "probe_radius (m)")
    if not isinstance(planar, (bool, np.bool_)):
        raise ValidationError(f"planar must be True or False, got {type(planar).__name__}")
    rng = as_rng(rng)
    ctr_obj = 0.5 * (obj.bounds[0] + obj.bounds[1])
    ctr = T[:3, :3] @ ctr_obj + T[:3, 3]
    R0 = obj.radius + standoff
    out = []
    for i in range(int(n)):
        if planar:
            zs = (obj.mesh.vertices @ T[:3, :3].T)[:, 2] + T[2, 3]
            z = rng.uniform(zs.min() + 0.15 * np.ptp(zs), zs.max() - 0.1 * np.ptp(zs))
            e1, e2, c = np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.r_[ctr[:2], z]
        else:
            a = _unit(rng.normal(size=3))
            e1 = _unit(np.cross(a, rng.normal(size=3)))
            e2 = np.cross(a, e1)
            c = ctr
        phi = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n_fingers) / n_fingers
        fingers = []
        for f in phi:
            u = np.cos(f) * e1 + np.sin(f) * e2
            fingers.append(GuardedTouch(c + R0 * u, -u, R0, probe_radius))
        out.append(HandTouch(tuple(fingers), name=f"hand {i}"))
    return out


class CandidateGenerator:
    """Candidates for each step of active localisation: ``gen(belief, rng) -> list``.

    A fixed world pool (drawn once) plus a fresh pool relative to the best pose at each
    step (starting ``standoff`` plus twice the belief's translation spread from the
    surface), and optionally closing hands.

    Parameters
    ----------
    region : PoseRegion
    obj : MeshObject
    n_world, n_relative, n_hands : int
    seed : int
        Seed of the world pool (the same pool for every run with this seed).
    """

    def __init__(self, region, obj, *, n_world: int = 60, n_relative: int = 40, n_hands: int = 0,
                 n_fingers: int = 3, seed: int = 0, probe_radius: float = 0.0, standoff: float = 0.03):
        _check_region(region)
        _check_obj(obj)
        n_world = as_count(n_world, "n_world", min=0, max=MAX_POOL, why=_WHY)
        n_relative = as_count(n_relative, "n_relative", min=0, max=MAX_POOL, why=_WHY)
        n_hands = as_count(n_hands, "n_hands", min=0, max=MAX_POOL, why=_WHY)
        n_fingers = as_count(n_fingers, "n_fingers", max=16, why="a hand has a few fingers")
        probe_radius = as_nonnegative_float(probe_radius, "probe_radius (m)")
        standoff = as_nonnegative_float(standoff, "standoff (m)")
        self.region, self.obj = region, obj
        self.planar = region.rotation == "yaw" and region.half_extent[2] == 0
        self.world = world_pool(region, obj, n_world, rng=seed, probe_radius=probe_radius) if n_world else []
        self.n_relative, self.n_hands, self.n_fingers = int(n_relative), int(n_hands), int(n_fingers)
        self.probe_radius = probe_radius
        self.standoff = float(standoff)

    def __call__(self, belief, rng=None) -> list:
        rng = as_rng(rng)
        out = list(self.world)
        from .metrics import best_pose

        T = best_pose(belief)
        if self.n_relative:
            # start further out while the estimate is uncertain, so that the touch begins
            # in free space for most of the belief (the planner drops those that do not)
            t = belief.poses[:, :3, 3]
            w = belief.weights
            spread = float(np.sqrt(w @ np.sum((t - w @ t) ** 2, axis=1)))
            standoff = self.standoff + 2.0 * spread
            out += relative_pool(T, self.obj, self.n_relative, rng=rng, probe_radius=self.probe_radius,
                                 standoff=standoff, depth=self.obj.radius + 2.0 * spread,
                                 min_normal_z=-0.2 if self.planar else None)
        if self.n_hands:
            out += hand_pool(T, self.obj, self.n_hands, n_fingers=self.n_fingers, rng=rng, planar=self.planar,
                             probe_radius=self.probe_radius)
        return out
