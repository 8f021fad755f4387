"""Active exploration: choose guarded touches that teach the map the most, execute, update.

Three strategies (Handbook of Robotics ch. 42.2.1, "Autonomous Exploration"):

- ``"random"``: a touch from outside the box aimed at a random point inside it;
- ``"lattice"``: the exhaustive strategy, touches aimed at the box centre from directions
  on a near-uniform (Fibonacci) lattice of the sphere, taken in an order whose every
  prefix is spread out;
- ``"uncertainty"``: of a pool of random touches, the one expected to stop where the
  shape is least known: sum over samples k along the ray of P(stop at k) sd_k^2, with
  P(stop at k) = p_k prod_{j<k} (1 - p_j), p_k the probability that sample k is inside
  the object and sd_k the map's uncertainty there (``score="entropy"`` instead sums the
  binary entropy of inside/outside over the samples the probe is expected to reach; it
  prefers long grazing paths, which miss thin objects, and maps worse).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from .._util import as_rng, blas_threads, progress_keyword
from .._util import progress as show_progress
from .._validate import as_bool, as_callable, as_nonnegative_float
from ..errors import ValidationError
from ..planners import GuardedTouch, HandTouch, TouchResult
from .shape_map import ShapeMap, as_bounds
from .slam import _pose_jacobian

__all__ = ["PLANNERS", "ExplorationRun", "box_pool", "hand_pool", "lattice_pool", "explore", "ray_information"]

PLANNERS = ("random", "lattice", "uncertainty")

_MAX_TOUCHES = 100_000


def _reach(lo, hi, margin):
    margin = as_nonnegative_float(margin, "margin (m)")
    c = 0.5 * (lo + hi)
    return c, 0.5 * float(np.linalg.norm(hi - lo)) + margin


def box_pool(bounds, n: int = 60, *, rng=None, margin: float = 0.02, probe_radius: float = 0.0) -> list:
    """Touches from a sphere around the box, each aimed at a random point inside it.

    Parameters
    ----------
    bounds : (lo (3,), hi (3,)) float
    n : int
        Number of touches (1 to 100000).
    margin : float
        Gap between the box's circumscribed sphere and the start points (m).

    Returns
    -------
    list of GuardedTouch
        Each long enough to cross the whole box.
    """
    lo, hi = as_bounds(bounds)
    n = _as_count(n, "n")
    rng = as_rng(rng)
    c, R = _reach(lo, hi, margin)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    O = c + R * u
    tgt = lo + rng.random((n, 3)) * (hi - lo)
    return [GuardedTouch(O[i], tgt[i] - O[i], 2 * R, probe_radius, name=f"random {i}") for i in range(n)]


def hand_pool(bounds, n: int = 20, *, fingers: int = 3, rng=None, margin: float = 0.02,
              probe_radius: float = 0.0, planar: bool = False) -> list:
    """Hands closing on the box: ``fingers`` touches spread evenly in a plane through a
    random point near the box centre, all moving towards it at once.

    ``planar`` keeps the closing planes horizontal (a hand grasping an object on a table).

    Returns
    -------
    list of HandTouch
    """
    from ..planners import HandTouch

    lo, hi = as_bounds(bounds)
    n = _as_count(n, "n")
    fingers = _as_count(fingers, "fingers", 16)
    rng = as_rng(rng)
    c0, R = _reach(lo, hi, margin)
    planar = as_bool(planar, "planar")
    probe_radius = as_nonnegative_float(probe_radius, "probe_radius (m)")   # (the touches are not re-checked)
    out = []
    for i in range(n):
        c = c0 + rng.uniform(-0.25, 0.25, 3) * (hi - lo)
        a = np.array([0.0, 0.0, 1.0]) if planar else rng.normal(size=3)
        a /= np.linalg.norm(a)
        e1 = _cross(a, rng.normal(size=3))
        e1 /= np.linalg.norm(e1)
        e2 = _cross(a, e1)
        phi = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(fingers) / fingers
        touches = []
        for f in phi:
            u = np.cos(f) * e1 + np.sin(f) * e2
            # (made from checked bounds: finite, unit directions; the constructor's checks
            # were a sixth of a pushed run's planning)
            touches.append(GuardedTouch._trusted(c + R * u, -u, 2 * R, probe_radius))
        out.append(HandTouch(tuple(touches), name=f"hand {i}"))
    return out


def _cross(a, b):
    """np.cross of two 3-vectors, in its arithmetic, without its overhead on short arrays."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def lattice_pool(bounds, n: int, *, margin: float = 0.02, probe_radius: float = 0.0) -> list:
    """n touches aimed at the box centre from a Fibonacci lattice of directions.

    The lattice is put in farthest-point order (each next direction is the one farthest
    from all before it), so the first k touches are spread over the sphere for every k.
    """
    lo, hi = as_bounds(bounds)
    n = _as_count(n, "n")
    c, R = _reach(lo, hi, margin)
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    rxy = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    u = np.stack([rxy * np.cos(phi), rxy * np.sin(phi), z], axis=1)
    order = _farthest_point_order(u)
    return [GuardedTouch(c + R * u[k], -u[k], 2 * R, probe_radius, name=f"lattice {k}") for k in order]


def _farthest_point_order(u):
    """Greedy farthest-point ordering of unit vectors (O(n^2), n up to a few thousand)."""
    n = len(u)
    order = np.empty(n, dtype=np.int64)
    order[0] = 0
    d = np.linalg.norm(u - u[0], axis=1)
    for i in range(1, n):
        k = int(np.argmax(d))
        order[i] = k
        d = np.minimum(d, np.linalg.norm(u - u[k], axis=1))
    return order


def _as_count(n, name, hi=_MAX_TOUCHES):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= hi:
        raise ValidationError(f"{name} must be an integer in [1, {hi}], got {n!r}")
    return int(n)


@blas_threads
def ray_information(smap: ShapeMap, touches, *, samples: int = 24, score: str = "variance") -> np.ndarray:
    """(C,) expected shape information along each touch's path (see the module notes).

    Parameters
    ----------
    smap : ShapeMap
    touches : list of GuardedTouch (C)
    samples : int
        Points sampled along each path inside the map's box.
    score : {"variance", "entropy"}
    """
    if not isinstance(smap, ShapeMap):
        raise ValidationError(f"smap must be a ShapeMap, got {type(smap).__name__}")
    if isinstance(touches, GuardedTouch):
        touches = [touches]
    try:
        touches = list(touches)
    except TypeError:
        raise ValidationError(f"touches must be a list of GuardedTouch, got {type(touches).__name__}") from None
    if not touches or not all(isinstance(t, GuardedTouch) for t in touches):
        raise ValidationError("touches must be a non-empty list of GuardedTouch")
    samples = _as_count(samples, "samples", 10_000)
    if not isinstance(score, str) or score not in ("variance", "entropy"):
        raise ValidationError(f"score must be 'variance' or 'entropy', got {score!r}")
    P, ok, mu, sd, p_in, reach = _ray_samples(smap, touches, samples)
    if score == "entropy":
        H = -(p_in * np.log(p_in) + (1 - p_in) * np.log1p(-p_in))
        return np.where(ok, (reach * H).sum(axis=1), 0.0)
    # expected shape variance where the probe stops: sum_k P(stop at k) sd_k^2
    stop = reach * p_in
    return np.where(ok, (stop * sd * sd).sum(axis=1), 0.0)


def _ray_samples(smap, touches, samples):
    """Points along each touch's path inside the map's box, the map there, and the
    probabilities of reaching each point: ``(P (C, S, 3), ok (C,), mu, sd, p_in, reach)``,
    the last four (C, S). ``ok`` is False for paths that miss the box."""
    lo, hi = smap.lo, smap.hi
    O = np.array([t.origin for t in touches])
    D = np.array([t.direction for t in touches])
    # clip each ray to the box (slab method), then sample it evenly
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - O) / D
        t2 = (hi - O) / D
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    tmin = np.maximum(tmin, 0.0)
    ok = tmax > tmin
    s = (np.arange(samples) + 0.5) / samples
    T = tmin[:, None] + s[None, :] * np.where(ok, tmax - tmin, 0.0)[:, None]
    P = O[:, None, :] + T[..., None] * D[:, None, :]
    # the model's own variance, without the calibration scale: the scale is one number for
    # the whole map, so it adds nothing to the ranking but blurs the stop probabilities
    # (with it: median Chamfer 1.48 mm at 100 touches on the bundled meshes; without: 1.11).
    # A GPIS solves in single precision here: twice as fast, and its deviations are off by
    # well under a micrometre, which no ranking of touches notices
    if smap.method == "gpis":
        mu, sd = smap._gp.mean_std(P.reshape(-1, 3), calibrated=False, dtype=np.float32)
    else:
        mu, sd = smap.mean_std(P.reshape(-1, 3), calibrated=False)
    if smap.method == "gpis":
        p_in = ndtr(-mu / sd)
    else:
        p_in = 1.0 / (1.0 + np.exp(mu))
    C = len(touches)
    p_in = np.clip(p_in.reshape(C, samples), 1e-9, 1 - 1e-9)
    reach = np.cumprod(np.concatenate([np.ones((C, 1)), 1 - p_in[:, :-1]], axis=1), axis=1)
    return P, ok, mu.reshape(C, samples), sd.reshape(C, samples), p_in, reach


def _slam_information(smap: ShapeMap, touches, owner, cov, *, samples: int = 24) -> np.ndarray:
    """(A,) expected information (nats) of each action about the shape *and* the object's pose.

    For a moving object a touch is worth what it teaches about both. Each touch of action
    ``a`` (``owner[c] == a``) is expected to stop at sample k of its path with probability
    P_k (as in :func:`ray_information`), where the map's standard deviation is sd_k:

    - shape: sum_k P_k 1/2 log(1 + sd_k^2 / sigma^2), sigma the contacts' noise;
    - pose: a contact at x (object frame), where the map's unit normal is n, measures the
      surface's offset along n, which a pose change xi = (v, w) in the object frame moves
      by J xi, J = [n, x x n]. The action's touches together give the information
      1/2 log det(I + L^T M L), M = sum_c sum_k P_k J_k^T J_k / (sigma^2 + sd_k^2) (the
      expected Fisher information over where each touch may stop), with cov = L L^T the
      pose's covariance (:meth:`TactileSLAM.pose_covariance`).

    A touch on a face that slides along itself (the body of a mug turning about its own
    axis) carries no pose information about that turn; one on the handle does. Touches
    must be given in the map's (object) frame.
    """
    touches = list(touches)
    owner = np.asarray(owner, dtype=np.int64)
    A = int(owner.max()) + 1
    sig2 = smap.sigma_pos**2
    P, ok, _, sd, p_in, reach = _ray_samples(smap, touches, samples)
    stop = np.where(ok[:, None], reach * p_in, 0.0)
    shape = np.bincount(owner, weights=(stop * 0.5 * np.log1p(sd * sd / sig2)).sum(axis=1), minlength=A)
    if smap.method != "gpis":
        return shape
    C, S = stop.shape
    # only samples where the probe may stop matter: the map's gradient there
    use = stop > 1e-3
    n = np.zeros((C, S, 3))
    if np.any(use):
        g = smap._gp.mean_grad(P[use])[1]
        n[use] = g / np.maximum(np.linalg.norm(g, axis=1), 1e-12)[:, None]
    J = _pose_jacobian(P, n, smap.sigma_nor)                        # (C, S, 6)
    lam, V = np.linalg.eigh(0.5 * (cov + cov.T))
    JL = J @ (V * np.sqrt(np.clip(lam, 0.0, None)))
    w = stop / (sig2 + sd * sd)                                     # (C, S)
    M = np.zeros((A, 6, 6))
    np.add.at(M, owner, np.einsum("cs,csi,csj->cij", w, JL, JL))
    return shape + 0.5 * np.linalg.slogdet(np.eye(6) + M)[1]


def _pool(candidates, rng) -> list:
    """The candidates' list of actions for this step, checked."""
    pool = candidates(rng)
    if isinstance(pool, (GuardedTouch, HandTouch)):
        pool = [pool]
    try:
        pool = list(pool)
    except TypeError:
        raise ValidationError(f"candidates must be (or return) a list of GuardedTouch or HandTouch, got "
                              f"{type(pool).__name__}") from None
    if not pool or not all(isinstance(a, (GuardedTouch, HandTouch)) for a in pool):
        raise ValidationError("candidates must be (or return) a non-empty list of GuardedTouch or HandTouch")
    return pool


@dataclass
class ExplorationRun:
    """Record of an exploration: the map, every touch's result and per-touch figures."""

    map: ShapeMap
    results: list
    steps: list = field(default_factory=list)

    @property
    def touches(self) -> int:
        return len(self.steps)

    def table(self) -> str:
        """One line per touch: result, contacts so far, planning and update time."""
        lines = [f"{'touch':>5}  {'result':<6} {'contacts':>8} {'score':>8} {'plan (s)':>9} {'update (s)':>10}"]
        for s in self.steps:
            lines.append(f"{s['touch']:>5}  {'hit' if s['hits'] else 'miss':<6} {s['contacts']:>8} "
                         f"{s['score']:8.3f} {s['plan_time']:9.3f} {s['update_time']:10.3f}")
        return "\n".join(lines)


def _check_map_kwargs(map_kwargs: dict, given: bool) -> None:
    """``explore``'s extra keywords are ShapeMap's, and only for a map it builds itself."""
    import inspect

    if not map_kwargs:
        return
    if given:
        raise ValidationError(f"explore got {sorted(map_kwargs)} for a new ShapeMap, but a map was given "
                              "(smap= or slam=): set them on that map instead")
    known = set(inspect.signature(ShapeMap.__init__).parameters) - {"self", "bounds", "method"}
    unknown = sorted(set(map_kwargs) - known)
    if unknown:
        raise ValidationError(f"explore got unknown keyword arguments {unknown}; besides its own, it "
                              f"takes ShapeMap's: {sorted(known)}")


@blas_threads
def explore(world, bounds, n_touches: int, *, planner: str = "uncertainty", method: str = "gpis",
            smap: ShapeMap | None = None, slam=None, n_candidates: int = 60, probe_radius: float = 0.0,
            fingers: int = 1, candidates=None,
            rng=None, callback=None, progress=None, progress_bar=None, **map_kwargs) -> ExplorationRun:
    """Map an unknown object by touching it ``n_touches`` times.

    Parameters
    ----------
    world : object with ``execute(action) -> list of TouchResult``
        :class:`touchloc.planners.SimulatedWorld`, the real hand's ``HandWorld``, or any
        world that executes guarded touches.
    bounds : (lo (3,), hi (3,)) float
        World box (m) known to hold the object.
    n_touches : int
    planner : {"random", "lattice", "uncertainty"}
    method : {"gpis", "occupancy"}
        Map representation (ignored when ``smap`` is given).
    smap : ShapeMap, optional
        Continue an existing map.
    slam : TactileSLAM, optional
        Map an object that moves: every step's touches go to ``slam.update`` (with the
        world's ``odometry()`` when it has one), and ``run.map`` is the SLAM map (in the
        object frame). The ``"uncertainty"`` planner then scores candidates against
        ``slam.map`` at the pose expected at the touch (``slam.predicted_pose()``: the
        last odometry repeated). While the hand reports its motion (``slam.turning``),
        the score is the information a candidate carries about the shape and the pose
        together (the pose's from ``slam.pose_covariance()``), so that a hand turning a
        mug is sent to the handle when the turn grows uncertain (and, once the handle's
        angle sets the turn, plus the chance of meeting the handle where that filter
        expects it times what a sighting would teach); for an object pushed
        without odometry it is the shape's alone (every touch re-measures a push, and
        seeking the pose took touches from the shape: the pushed bunny mapped to F@5mm
        0.86 / 0.75 against 0.90 / 0.87, seeds 5 / 6).
        ``bounds`` is then the world box the touches aim into.
    n_candidates : int
        Touches scored per step by the ``"uncertainty"`` planner.
    fingers : int
        1: single guarded touches. More: every action is a hand closing with that many
        fingers at once (:func:`hand_pool`); several contacts of one instant pin down a
        moving object's pose far better than one.
    candidates : list of actions, or callable, optional
        The pool the ``"random"`` and ``"uncertainty"`` planners pick from, instead of
        touches from a sphere around the box: a list of actions (GuardedTouch or
        HandTouch), the same at every step, or ``candidates(rng) -> list of actions``,
        called at every step. A real hand can make only some touches: pass its reachable
        ones (e.g. ``lambda rng: executor.touch_pool(24, rng=rng)`` for
        ``HandWorld(executor)``).
    rng : None, int or Generator
    callback : callable, optional
        ``callback(run, step)`` after every touch (e.g. to evaluate the map).
    progress : bool, optional
        A bar over the touches (default: when stderr is a terminal; otherwise a line to
        stderr every few seconds). ``progress_bar=`` is its deprecated old name.
    **map_kwargs
        Passed to :class:`ShapeMap` when ``explore`` builds the map (neither ``smap`` nor
        ``slam`` given); any other keyword raises ``ValidationError``.

    Returns
    -------
    ExplorationRun
    """
    if not callable(getattr(world, "execute", None)):
        raise ValidationError("world must have execute(action) -> list of TouchResult")
    if not isinstance(planner, str) or planner not in PLANNERS:
        raise ValidationError(f"planner must be one of {PLANNERS}, got {planner!r}")
    n_touches = _as_count(n_touches, "n_touches")
    n_candidates = _as_count(n_candidates, "n_candidates", 10_000)
    callback = as_callable(callback, "callback", allow_none=True)
    progress = progress_keyword(progress, progress_bar, "explore")
    _check_map_kwargs(map_kwargs, given=smap is not None or slam is not None)
    rng = as_rng(rng)
    if slam is not None:
        from .slam import TactileSLAM, transform_results

        if not isinstance(slam, TactileSLAM):
            raise ValidationError(f"slam must be a TactileSLAM, got {type(slam).__name__}")
        smap = slam.map
        bounds = as_bounds(bounds)
    elif smap is None:
        smap = ShapeMap(bounds, method=method, **map_kwargs)
    elif not isinstance(smap, ShapeMap):
        raise ValidationError(f"smap must be a ShapeMap, got {type(smap).__name__}")
    if slam is None:
        bounds = (smap.lo, smap.hi)
    odometry = getattr(world, "odometry", None)
    fingers = _as_count(fingers, "fingers", 16)
    if planner == "lattice" and fingers != 1:
        raise ValidationError("the lattice planner makes single touches: use fingers=1")
    if candidates is not None and not callable(candidates):
        fixed = _pool(lambda rng: candidates, None)
        candidates = lambda rng: fixed      # noqa: E731
    if candidates is not None and planner == "lattice":
        raise ValidationError("the lattice planner makes its own touches: leave candidates out")
    lattice = lattice_pool(bounds, n_touches, probe_radius=probe_radius) if planner == "lattice" else None
    run = ExplorationRun(smap, [])
    for i in show_progress(range(n_touches), total=n_touches, desc="touches", enabled=progress):
        t0 = time.perf_counter()
        score = float("nan")
        pool = None if candidates is None else _pool(candidates, rng)
        if planner == "lattice":
            action = lattice[i]
        elif pool is not None and planner == "random":
            action = pool[int(rng.integers(len(pool)))]
        elif planner == "random":
            action = (box_pool(bounds, 1, rng=rng, probe_radius=probe_radius)[0] if fingers == 1 else
                      hand_pool(bounds, 1, fingers=fingers, rng=rng, probe_radius=probe_radius)[0])
        else:
            if pool is not None:
                cands = pool
                flat = [t for c in cands for t in (c.touches if isinstance(c, HandTouch) else (c,))]
                owner = np.repeat(np.arange(len(cands)), [len(c.touches) if isinstance(c, HandTouch) else 1
                                                          for c in cands])
            elif fingers == 1:
                cands = box_pool(bounds, n_candidates, rng=rng, probe_radius=probe_radius)
                flat, owner = cands, np.arange(len(cands))
            else:
                cands = hand_pool(bounds, max(1, n_candidates // fingers), fingers=fingers, rng=rng,
                                  probe_radius=probe_radius)
                flat = [t for h in cands for t in h.touches]
                owner = np.repeat(np.arange(len(cands)), fingers)
            # a moving object's candidates are scored where the object is expected at the touch
            scored = flat if slam is None else [r.touch for r in transform_results(
                [TouchResult(c, 0.0, None) for c in flat], np.linalg.inv(slam.predicted_pose()))]
            if slam is not None and slam.turning:
                # the tracked covariance, and the turn made unseen since the contacts last showed it
                # (an odometry's bias, which the motion model does not know; zero for a box)
                cov = slam.pose_covariance() + slam._unseen_turn_covariance()
                info = _slam_information(smap, scored, owner, cov)
                # the feature that shows an in-hand turn, where its own contacts put it
                p, nats = slam._feature_seeking(scored)
                if nats > 0.0:
                    miss = np.ones(len(cands))
                    np.multiply.at(miss, owner, 1.0 - p)
                    info = info + nats * (1.0 - miss)
            else:
                info = np.bincount(owner, weights=ray_information(smap, scored), minlength=len(cands))
            k = int(np.argmax(info))
            action, score = cands[k], float(info[k])
        t1 = time.perf_counter()
        results = world.execute(action)
        if not isinstance(results, (list, tuple)) or not all(isinstance(r, TouchResult) for r in results):
            raise ValidationError("world.execute must return a list of TouchResult")
        t2 = time.perf_counter()
        if slam is None:
            smap.update(results)
        else:
            slam.update(results, odometry=odometry() if callable(odometry) else None)
        t3 = time.perf_counter()
        run.results.extend(results)
        step = dict(touch=i + 1, hits=sum(r.hit for r in results), contacts=smap.n_contacts, score=score,
                    plan_time=t1 - t0, update_time=t3 - t2)
        run.steps.append(step)
        if callback is not None:
            callback(run, step)
    return run
