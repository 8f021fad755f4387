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

from .._util import as_rng, progress
from ..errors import ValidationError
from ..planners import GuardedTouch, TouchResult
from .shape_map import ShapeMap, as_bounds

__all__ = ["PLANNERS", "ExplorationRun", "box_pool", "lattice_pool", "explore", "ray_information"]

PLANNERS = ("random", "lattice", "uncertainty")

_MAX_TOUCHES = 100_000


def _reach(lo, hi, margin):
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


def ray_information(smap: ShapeMap, touches, *, samples: int = 24, score: str = "variance") -> np.ndarray:
    """(C,) expected shape information along each touch's path (see the module notes)."""
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
    mu, sd = smap.mean_std(P.reshape(-1, 3))
    if smap.method == "gpis":
        p_in = ndtr(-mu / sd)
    else:
        p_in = 1.0 / (1.0 + np.exp(mu))
    p_in = np.clip(p_in.reshape(len(touches), samples), 1e-9, 1 - 1e-9)
    reach = np.cumprod(np.concatenate([np.ones((len(touches), 1)), 1 - p_in[:, :-1]], axis=1), axis=1)
    if score == "entropy":
        H = -(p_in * np.log(p_in) + (1 - p_in) * np.log1p(-p_in))
        return np.where(ok, (reach * H).sum(axis=1), 0.0)
    # expected shape variance where the probe stops: sum_k P(stop at k) sd_k^2
    stop = reach * p_in
    sd = sd.reshape(len(touches), samples)
    return np.where(ok, (stop * sd * sd).sum(axis=1), 0.0)


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


def explore(world, bounds, n_touches: int, *, planner: str = "uncertainty", method: str = "gpis",
            smap: ShapeMap | None = None, n_candidates: int = 60, probe_radius: float = 0.0,
            rng=None, callback=None, progress_bar=None, **map_kwargs) -> ExplorationRun:
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
    n_candidates : int
        Touches scored per step by the ``"uncertainty"`` planner.
    rng : None, int or Generator
    callback : callable, optional
        ``callback(run, step)`` after every touch (e.g. to evaluate the map).
    **map_kwargs
        Passed to :class:`ShapeMap`.

    Returns
    -------
    ExplorationRun
    """
    if not callable(getattr(world, "execute", None)):
        raise ValidationError("world must have execute(action) -> list of TouchResult")
    if planner not in PLANNERS:
        raise ValidationError(f"planner must be one of {PLANNERS}, got {planner!r}")
    n_touches = _as_count(n_touches, "n_touches")
    n_candidates = _as_count(n_candidates, "n_candidates", 10_000)
    rng = as_rng(rng)
    if smap is None:
        smap = ShapeMap(bounds, method=method, **map_kwargs)
    elif not isinstance(smap, ShapeMap):
        raise ValidationError(f"smap must be a ShapeMap, got {type(smap).__name__}")
    bounds = (smap.lo, smap.hi)
    lattice = lattice_pool(bounds, n_touches, probe_radius=probe_radius) if planner == "lattice" else None
    run = ExplorationRun(smap, [])
    for i in progress(range(n_touches), total=n_touches, desc="touches", enabled=progress_bar):
        t0 = time.perf_counter()
        score = float("nan")
        if planner == "lattice":
            action = lattice[i]
        elif planner == "random":
            action = box_pool(bounds, 1, rng=rng, probe_radius=probe_radius)[0]
        else:
            cands = box_pool(bounds, n_candidates, rng=rng, probe_radius=probe_radius)
            info = ray_information(smap, cands)
            k = int(np.argmax(info))
            action, score = cands[k], float(info[k])
        t1 = time.perf_counter()
        results = world.execute(action)
        if not isinstance(results, (list, tuple)) or not all(isinstance(r, TouchResult) for r in results):
            raise ValidationError("world.execute must return a list of TouchResult")
        t2 = time.perf_counter()
        smap.update(results)
        t3 = time.perf_counter()
        run.results.extend(results)
        step = dict(touch=i + 1, hits=sum(r.hit for r in results), contacts=smap.n_contacts, score=score,
                    plan_time=t1 - t0, update_time=t3 - t2)
        run.steps.append(step)
        if callback is not None:
            callback(run, step)
    return run
