"""One- and two-step lookahead planners (seed 001, eq. 42.11-42.16, Fig. 42.7).

How a candidate action A is scored, for a belief of weighted particles X_i:

1. Simulation experiments: for every particle, where each finger of A stops and what it
   measures (travel, hit or miss, contact normal); one ray-casting call covers all
   particles and candidates (:func:`~touchloc.planners.simulate.simulate`).
2. Canonical observations: the simulated observations are clustered into a few
   canonical ones D_k, chosen greedily among the outcomes of representative particles
   so that each new one explains the most belief mass the others leave unexplained.
   Every particle is assigned to the canonical observation it explains best; the weight
   w_k of D_k is the belief mass of its particles (eq. 42.14).
3. Simulated beliefs: bel_{A,k}(X_i) ~ w_i p(D_k | X_i, A), with the likelihood of an
   observation given a pose computed in observation space: a Gaussian in travel
   (``sigma_travel``) and normal (``sigma_normal``) when both hit, 1 when both miss, and
   ``eps`` when one hits and the other misses (the simulated counterpart of the
   proximity and free-space models).
4. Utility: U(A) = sum_k w_k [U(bel_{A,k}) - beta C(A, D_k)] (eq. 42.12-42.14), with U
   the negative entropy, the KL divergence from the current belief, or a task-success
   probability. The two-step planner replaces U(bel_{A,k}) by the best one-step utility
   of a second action from bel_{A,k} (eq. 42.16).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._util import as_rng, blas_threads, progress
from .._validate import (as_bool, as_count, as_nonnegative_float, as_positive_float,
                         as_probability, as_sequence)
from ..errors import BeliefDegenerateError, PlanningError, ValidationError
from ..models import MeshObject
from .actions import as_cost
from .simulate import Outcomes, flatten_actions, simulate
from .utilities import Utility, as_utility

__all__ = ["Plan", "OneStepPlanner", "TwoStepPlanner", "RandomPlanner"]


@dataclass
class Plan:
    """A planning decision and everything needed to inspect it.

    Attributes
    ----------
    action : GuardedTouch or HandTouch
        The chosen candidate (one of ``candidates``).
    index : int
        Its position in ``candidates``.
    scores : (C,) float
        Utility of every candidate (higher is better; ``-inf`` for candidates a
        two-step planner pruned before expanding).
    candidates : list
    utility : str
        Name of the utility.
    details : dict of (C,) arrays
        ``value`` (expected utility of the simulated beliefs, before costs),
        ``cost`` (expected cost), ``p_hit`` (probability that the first finger
        touches), ``p_collision`` (probability that a finger starts inside the
        object), ``n_observations`` (canonical observations used).
    info : dict
        Timings (s) and sizes.
    """

    action: object
    index: int
    scores: np.ndarray
    candidates: list
    utility: str
    details: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    def ranking(self, k: int = 10) -> list:
        """The k best candidates as (index, score) pairs, best first."""
        order = np.argsort(-self.scores, kind="stable")[:as_count(k, "k", min=0)]
        return [(int(i), float(self.scores[i])) for i in order]

    def table(self, k: int = 10) -> str:
        """A small text table of the k best candidates."""
        lines = [f"{'rank':>4} {'idx':>4} {'score':>9} {'value':>9} {'cost':>8} {'p_hit':>6}  name"]
        nan = np.full(len(self.scores), np.nan)
        d = {key: self.details.get(key, nan) for key in ("value", "cost", "p_hit")}
        for r, (i, s) in enumerate(self.ranking(k)):
            name = getattr(self.candidates[i], "name", "")
            lines.append(f"{r:>4} {i:>4} {s:9.3f} {d['value'][i]:9.3f} {d['cost'][i]:8.3f} "
                         f"{d['p_hit'][i]:6.2f}  {name}")
        return "\n".join(lines)


class _Context:
    """Particles, their simulated outcomes and the utility context of one planning call."""

    def __init__(self, planner, belief, candidates, rng):
        from ..belief import ParticleBelief

        if not isinstance(belief, ParticleBelief):
            raise ValidationError(f"belief must be a touchloc.belief.ParticleBelief, got {type(belief).__name__}")
        if len(belief) == 0:
            raise ValidationError("the belief has no particles")
        if not isinstance(candidates, (list, tuple)):
            candidates = as_sequence(candidates, "candidates", expected="a list of touches")
        t0 = time.perf_counter()
        self.fingers, self.owner = flatten_actions(candidates)
        self.candidates = list(candidates)
        with np.errstate(all="ignore"):
            w = np.asarray(belief.weights, dtype=np.float64)
            total = float(w.sum()) if np.all(np.isfinite(w)) and np.all(w >= 0) else float("nan")
        if not (np.isfinite(total) and total > 0):
            raise BeliefDegenerateError(
                "the belief's weights are not finite or all underflowed to 0; plan from a belief with "
                "at least one finite log-weight")
        w = w / total  # exact normalisation for rng.choice
        n = planner.max_particles
        if len(belief) > n:
            idx = np.sort(rng.choice(len(belief), size=n, p=w))
            poses, w = belief.poses[idx], np.full(n, 1.0 / n)
        else:
            poses = belief.poses
        self.poses, self.w = poses, w
        self.region = belief.region
        rho = belief.rho if belief.rho is not None else planner.obj.radius
        self.out: Outcomes = simulate(planner.obj, poses, self.candidates)
        self.t_sim = time.perf_counter() - t0
        self.ctx = planner.utility.prepare(poses, w, belief.region, rho)
        C = len(self.candidates)
        self.starts = np.searchsorted(self.owner, np.arange(C))
        # finger data with misses zeroed, laid out finger-first
        self.t = self.out.travel.T.copy()                      # (F, P)
        self.h = self.out.hit.T.copy()                         # (F, P)
        n_ = np.nan_to_num(self.out.normals, nan=0.0)
        self.n = np.ascontiguousarray(np.transpose(n_, (1, 0, 2)))  # (F, P, 3)
        self.utility = planner.utility

    def subset(self, idx) -> "_Context":
        """A view of this context restricted to particles ``idx``."""
        sub = object.__new__(_Context)
        sub.__dict__.update(self.__dict__)
        sub.t, sub.h, sub.n = self.t[:, idx], self.h[:, idx], self.n[:, idx]
        sub.ctx = self.utility.subset(self.ctx, idx)
        sub.w = None
        return sub

    def fingers_subset(self, cand_idx) -> "_Context":
        """A view restricted to the fingers of candidates ``cand_idx`` (one finger each)."""
        sub = object.__new__(_Context)
        sub.__dict__.update(self.__dict__)
        sub.t, sub.h, sub.n = self.t[cand_idx], self.h[cand_idx], self.n[cand_idx]
        sub.starts = np.arange(len(cand_idx))
        return sub


def _obs_costs(planner, ctx: _Context, reps: np.ndarray, cand_idx: np.ndarray) -> np.ndarray:
    """Squared observation distance d (c, s, p) between representative s and particle p."""
    if len(ctx.starts) == ctx.t.shape[0] and len(cand_idx) < len(ctx.starts):
        # single-finger candidates: compute the requested ones only
        ctx = ctx.fingers_subset(cand_idx)
        cand_idx = np.arange(len(cand_idx))
    st, sh, sn = ctx.t[:, reps], ctx.h[:, reps], ctx.n[:, reps]
    pen = -2.0 * np.log(planner.eps)
    dt2 = ((st[:, :, None] - ctx.t[:, None, :]) / planner.sigma_travel) ** 2
    dn2 = (2.0 - 2.0 * (sn @ np.transpose(ctx.n, (0, 2, 1)))) / planner.sigma_normal**2
    both = sh[:, :, None] & ctx.h[:, None, :]
    miss = ~sh[:, :, None] & ~ctx.h[:, None, :]
    d = np.where(both, dt2 + dn2, np.where(miss, 0.0, pen))
    if len(ctx.starts) != d.shape[0]:   # hands: sum over each action's fingers
        d = np.add.reduceat(d, ctx.starts, axis=0)
    return d[cand_idx]


def _one_step(planner, ctx: _Context, w: np.ndarray, cand_idx: np.ndarray, K: int, rng):
    """Canonical observations and simulated beliefs of candidates ``cand_idx`` from weights w.

    Returns
    -------
    W : (C', K) observation weights; post : (C', K, P) simulated beliefs;
    value : (C', K) leaf utilities; cost : (C', K) costs of the canonical observations.
    """
    sub = None
    if np.count_nonzero(w > 1e-6 * w.max()) < 0.8 * len(w):
        # a concentrated simulated belief: drop the particles it gives no weight to
        sub = np.flatnonzero(w > 1e-6 * w.max())
        w_full, w = w, w[sub] / w[sub].sum()
        ctx = ctx.subset(sub)
    S = min(planner.n_representatives, int(np.count_nonzero(w > 0)))
    reps = np.unique(rng.choice(len(w), size=S, p=w))
    L = np.exp(-0.5 * _obs_costs(planner, ctx, reps, cand_idx))   # (C', S, P)
    Cn = len(cand_idx)
    K = min(K, len(reps))
    u = np.broadcast_to(w, (Cn, len(w))).copy()
    chosen = np.zeros((Cn, K), dtype=np.int64)
    ar = np.arange(Cn)
    for k in range(K):
        gain = (L @ u[:, :, None])[:, :, 0]
        j = np.argmax(gain, axis=1)
        chosen[:, k] = j
        u *= 1.0 - L[ar, j]
    Lk = L[ar[:, None], chosen]                                    # (C', K, P)
    assign = np.argmax(Lk, axis=1)                                 # (C', P)
    onehot = assign[:, None, :] == np.arange(K)[None, :, None]
    W = onehot.astype(float) @ w                                   # (C', K)
    post = Lk * w[None, None, :]
    post /= np.maximum(post.sum(axis=2, keepdims=True), 1e-300)
    value = planner.utility.values(ctx.ctx, post.reshape(-1, len(w))).reshape(Cn, K)
    # costs of the canonical observations: the representatives' finger travels
    rep_idx = reps[chosen]                                         # (C', K) particle indices
    cost = np.zeros((Cn, K))
    if planner.beta != 0.0:
        for a, c in enumerate(cand_idx):
            f0 = ctx.starts[c]
            f1 = ctx.starts[c + 1] if c + 1 < len(ctx.starts) else len(ctx.fingers)
            cost[a] = planner.cost(ctx.candidates[c], ctx.t[f0:f1][:, rep_idx[a]].T)
    if sub is not None:
        full = np.zeros(post.shape[:2] + (len(w_full),))
        full[:, :, sub] = post
        post = full
    return W, post, value, cost


_WHY_OBS = "each one is a simulated belief update per candidate"


class OneStepPlanner:
    """Pick the candidate with the highest expected utility after one touch (eq. 42.15).

    Parameters
    ----------
    model : MeasurementModel or MeshObject
        The object (``model.obj``) whose outcomes are simulated; a ProximityModel's
        noise sets the default observation noise.
    utility : {"entropy", "kl"} or Utility
        ``entropy``: minimise expected posterior entropy (eq. 42.11-42.15);
        ``kl``: maximise expected KL divergence from the current belief; a
        :class:`~touchloc.planners.TaskSuccess` instance: maximise the probability
        that a grasp succeeds.
    beta : float
        Cost weight of eq. 42.12 (utility units per cost unit), >= 0.
    cost : callable, optional
        ``cost(action, travel (..., F)) -> (...)``; default
        :class:`~touchloc.planners.TravelDistance`.
    n_observations : int
        Canonical observations per candidate.
    n_representatives : int
        Particles whose outcomes are the candidates for canonical observations.
    max_particles : int
        Beliefs with more particles are resampled to this many for planning.
    sigma_travel : float, optional
        Observation noise in travel (m); default max(2 sigma_pos, 3 mm), wider than
        the sensor so that a few hundred particles still form smooth posteriors.
    sigma_normal : float
        Observation noise of contact normals (unit-vector difference).
    eps : float
        Probability of a hit where a miss was expected, or vice versa.
    max_collision : float
        Candidates that start inside the object with more than this probability under
        the belief are infeasible (score ``-inf``): a guarded touch must begin in free
        space, or the hand knocks the object on its way to the start. If every
        candidate is infeasible, the least likely to collide are kept.
    """

    name = "one-step"

    def __init__(self, model, *, utility="entropy", beta: float = 0.0, cost=None, n_observations: int = 6,
                 n_representatives: int = 24, max_particles: int = 1000, sigma_travel: float | None = None,
                 sigma_normal: float = 0.3, eps: float = 0.01, max_collision: float = 0.02):
        obj = model if isinstance(model, MeshObject) else getattr(model, "obj", None)
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"model must be a measurement model with a MeshObject (.obj) or a MeshObject, "
                                  f"got {type(model).__name__}")
        beta = as_nonnegative_float(beta, "beta")
        n_observations = as_count(n_observations, "n_observations", max=1000, why=_WHY_OBS)
        n_representatives = as_count(n_representatives, "n_representatives", max=100_000, why=_WHY_OBS)
        max_particles = as_count(max_particles, "max_particles", min=2, max=1_000_000,
                                 why="planning simulates every candidate for every particle")
        eps = as_probability(eps, "eps", open_low=True, open_high=True)
        if sigma_travel is not None:
            sigma_travel = as_positive_float(sigma_travel, "sigma_travel (m)")
        sigma_normal = as_positive_float(sigma_normal, "sigma_normal")
        max_collision = as_probability(max_collision, "max_collision")
        self.model, self.obj = model, obj
        self.utility: Utility = as_utility(utility)
        self.beta, self.cost = float(beta), as_cost(cost)
        self.n_observations = int(n_observations)
        self.n_representatives = int(n_representatives)
        self.max_particles = int(max_particles)
        if sigma_travel is None:
            sigma_travel = max(2.0 * getattr(model, "sigma_pos", 0.0), 0.003)
        if not (np.isfinite(sigma_travel) and sigma_travel > 0 and np.isfinite(sigma_normal) and sigma_normal > 0):
            raise ValidationError("sigma_travel and sigma_normal must be > 0")
        self.sigma_travel, self.sigma_normal, self.eps = float(sigma_travel), float(sigma_normal), float(eps)
        if not 0 <= max_collision <= 1:
            raise ValidationError(f"max_collision must be in [0, 1], got {max_collision}")
        self.max_collision = float(max_collision)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(utility={self.utility.name!r}, beta={self.beta})"

    def _details(self, ctx, W, value, cost, K):
        f0 = ctx.starts
        p_hit = ctx.w @ ctx.out.hit[:, f0]
        return {"value": (W * value).sum(axis=1), "cost": (W * cost).sum(axis=1), "p_hit": p_hit,
                "p_collision": self._p_collision(ctx), "n_observations": np.count_nonzero(W > 0, axis=1)}

    def _p_collision(self, ctx) -> np.ndarray:
        """(C,) belief mass for which some finger of each candidate starts inside the object."""
        inside = ctx.out.start_inside.astype(float)
        if len(ctx.starts) != inside.shape[1]:
            inside = np.maximum.reduceat(inside, ctx.starts, axis=1)
        return ctx.w @ inside

    def _feasible(self, ctx) -> np.ndarray:
        """(C,) bool: candidates allowed by ``max_collision`` (the least bad if none is)."""
        pc = self._p_collision(ctx)
        ok = pc <= self.max_collision
        return ok if ok.any() else pc <= pc.min() + 1e-12

    @blas_threads
    def plan(self, belief, candidates, *, rng=None) -> Plan:
        """Score every candidate and choose the best.

        Parameters
        ----------
        belief : ParticleBelief
        candidates : list of GuardedTouch or HandTouch (C)
        rng : None, int or Generator
            For resampling large beliefs and drawing representatives.

        Returns
        -------
        Plan
        """
        rng = as_rng(rng)
        t0 = time.perf_counter()
        ctx = _Context(self, belief, candidates, rng)
        C = len(ctx.candidates)
        W, post, value, cost = _one_step(self, ctx, ctx.w, np.arange(C), self.n_observations, rng)
        scores = (W * (value - self.beta * cost)).sum(axis=1)
        scores = np.where(self._feasible(ctx), scores, -np.inf)
        return self._finish(ctx, scores, self._details(ctx, W, value, cost, self.n_observations), t0)

    def _finish(self, ctx, scores, details, t0, **info):
        if not np.any(np.isfinite(scores)):
            raise PlanningError("no candidate has a finite score (the simulated beliefs are degenerate)")
        i = int(np.nanargmax(np.where(np.isfinite(scores), scores, -np.inf)))
        return Plan(ctx.candidates[i], i, scores, ctx.candidates, self.utility.name, details,
                    {"time": time.perf_counter() - t0, "time_simulate": ctx.t_sim, "n_particles": len(ctx.w),
                     "n_candidates": len(scores), "planner": self.name, **info})


class TwoStepPlanner(OneStepPlanner):
    """Depth-2 search through belief space (Fig. 42.7, eq. 42.16).

    For each first action A1 (the ``branch`` best by one-step utility; all if None) and
    each of its canonical observations D_k, the simulated belief B_k is expanded by
    every candidate as the second action; its utility is the best second action's
    expected utility minus beta C(A1, D_k), and U(A1) is the expectation over k. The
    simulations of the first level are reused: the second level only reweights.

    Parameters
    ----------
    branch : int or None
        First actions expanded (pruned ones score ``-inf``; their one-step score is in
        ``plan.details["one_step"]``).
    n_observations : int
        Canonical observations per first action (default 6).
    n_observations_second : int
        Canonical observations per second action (default 3).
    **kwargs
        As :class:`OneStepPlanner`.
    """

    name = "two-step"

    def __init__(self, model, *, branch: int | None = 4, n_observations: int = 6, n_observations_second: int = 3,
                 progress: bool = False, **kwargs):
        super().__init__(model, n_observations=n_observations, **kwargs)
        n_observations_second = as_count(n_observations_second, "n_observations_second", max=1000, why=_WHY_OBS)
        self.n_observations_second = int(n_observations_second)
        if branch is not None:
            branch = as_count(branch, "branch", max=100_000, why="each branch plans a second step for every outcome")
        progress = as_bool(progress, "progress")
        self.branch = None if branch is None else int(branch)
        self.progress = progress

    @blas_threads
    def plan(self, belief, candidates, *, rng=None) -> Plan:
        rng = as_rng(rng)
        t0 = time.perf_counter()
        ctx = _Context(self, belief, candidates, rng)
        C = len(ctx.candidates)
        all_c = np.arange(C)
        W, post, value, cost = _one_step(self, ctx, ctx.w, all_c, self.n_observations, rng)
        feasible = self._feasible(ctx)
        one = np.where(feasible, (W * (value - self.beta * cost)).sum(axis=1), -np.inf)
        cand = np.flatnonzero(feasible)
        expand = cand if self.branch is None else cand[np.argsort(-one[cand], kind="stable")[: self.branch]]
        scores = np.full(C, -np.inf)
        for c in progress(expand, desc="two-step", enabled=self.progress):
            total = 0.0
            for k in range(W.shape[1]):
                if W[c, k] <= 0:
                    continue
                W2, _, v2, c2 = _one_step(self, ctx, post[c, k], cand, self.n_observations_second, rng)
                best2 = float(np.max((W2 * (v2 - self.beta * c2)).sum(axis=1)))
                total += W[c, k] * (best2 - self.beta * cost[c, k])
            scores[c] = total
        details = self._details(ctx, W, value, cost, self.n_observations)
        details["one_step"] = one
        return self._finish(ctx, scores, details, t0, expanded=len(expand))


class RandomPlanner:
    """Baseline: a uniformly random candidate (scores are random numbers)."""

    name = "random"

    def __init__(self, model=None):
        self.model = model

    @blas_threads
    def plan(self, belief, candidates, *, rng=None) -> Plan:
        rng = as_rng(rng)
        t0 = time.perf_counter()
        cands = as_sequence(candidates, "candidates", expected="a list of touches")
        flatten_actions(cands)  # validates
        s = rng.random(len(cands))
        i = int(np.argmax(s))
        return Plan(cands[i], i, s, cands, "random", {}, {"time": time.perf_counter() - t0, "planner": self.name})
