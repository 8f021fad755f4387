"""The active-localisation loop: plan a touch, execute it, update the belief, repeat."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._util import as_rng, progress_keyword
from .._util import progress as show_progress
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_bool, as_callable, as_count, as_instance,
                         as_nonnegative_float, as_pose, as_positive_float, as_probability, as_sequence)
from ..belief import ParticleBelief, SMCFilter
from ..errors import ValidationError
from .actions import TouchResult
from .metrics import add_s, best_pose, expected_add_s, prob_error_below
from .simulate import execute

__all__ = ["SimulatedWorld", "Step", "ActiveResult", "active_localization"]


class SimulatedWorld:
    """A mesh at a hidden pose that executes guarded touches with sensor noise.

    Parameters
    ----------
    obj : MeshObject
    true_pose : (4, 4) float
    noise_pos : float
        Contact position noise (m, standard deviation per axis).
    noise_nor : float
        Contact normal noise (per component, before renormalising).
    rng : None, int or Generator
    """

    def __init__(self, obj, true_pose, *, noise_pos: float = 0.001, noise_nor: float = 0.05, rng=None):
        from ..models import MeshObject

        self.obj = as_instance(obj, MeshObject, "obj")
        self.true_pose = as_pose(true_pose, "true_pose")
        self.noise_pos = as_nonnegative_float(noise_pos, "noise_pos (m)")
        self.noise_nor = as_nonnegative_float(noise_nor, "noise_nor")
        self.rng = as_rng(rng)

    def execute(self, action) -> list:
        """Run an action; returns one TouchResult per finger."""
        return execute(self.obj, self.true_pose, action, noise_pos=self.noise_pos, noise_nor=self.noise_nor,
                       rng=self.rng)


@dataclass
class Step:
    """One touch of the loop (index 0 is the prior, before any touch)."""

    index: int
    action: object
    results: list
    entropy: float
    expected_error: float
    error: float
    plan_time: float
    update_time: float
    map_pose: np.ndarray
    plan: object = None
    p_within: float = float("nan")
    verified: bool = False

    @property
    def hits(self) -> int:
        return sum(r.hit for r in self.results)


@dataclass
class ActiveResult:
    """Record of an active-localisation run."""

    steps: list
    belief: object
    confident: bool
    true_pose: np.ndarray = None
    info: dict = field(default_factory=dict)

    @property
    def touches(self) -> int:
        """Number of actions executed."""
        return len(self.steps) - 1

    @property
    def error(self) -> float:
        """ADD-S of the final MAP pose (m; NaN without a known true pose)."""
        return self.steps[-1].error

    def table(self) -> str:
        """One line per touch: touch, hit/miss, entropy, expected and true ADD-S, times."""
        lines = [f"{'touch':>5}  {'action':<12} {'result':<8} {'entropy':>8} {'E[ADD-S]':>9} {'ADD-S':>8} "
                 f"{'plan':>6} {'update':>6}",
                 f"{'':>5}  {'':<12} {'':<8} {'(nats)':>8} {'(mm)':>9} {'(mm)':>8} {'(s)':>6} {'(s)':>6}"]
        for s in self.steps:
            name = "prior" if s.action is None else (getattr(s.action, "name", "") or type(s.action).__name__)
            n = len(s.results)
            res = "-" if s.action is None else ("miss" if s.hits == 0 else ("hit" if n == 1 else f"{s.hits}/{n} hit"))
            lines.append(f"{s.index:>5}  {name[:12]:<12} {res:<8} {s.entropy:8.2f} {s.expected_error * 1e3:9.2f} "
                         f"{s.error * 1e3:8.2f} {s.plan_time:6.2f} {s.update_time:6.2f}")
        return "\n".join(lines)


def _belief_of(updater):
    """The updater's belief, or None when it has none yet (not initialised, or a filter
    such as Scaling Series that has no belief before its first contact)."""
    try:
        return updater.belief
    except ValidationError:
        return None


def active_localization(world, model, region, planner, candidates, *, n_particles: int = 2000,
                        max_touches: int = 20, stop_error: float | None = None, stop_probability: float = 0.95,
                        stop_metric: str = "add_s",
                        confidence: float | None = None, min_touches: int = 1,
                        updater=None, verify_stop: bool = True, rng=None, progress=None, progress_bar=None,
                        keep_plans: bool = False, callback=None) -> ActiveResult:
    """Localise an object by touching it where the planner says, until the belief is confident.

    Parameters
    ----------
    world : object with ``execute(action) -> list of TouchResult``
        A :class:`SimulatedWorld` or a real hand's executor; its ``true_pose`` (if
        any) gives the reported errors.
    model : ProximityModel
        Measurement model of the contacts.
    region : PoseRegion
        Where the object may be (the prior).
    planner : OneStepPlanner, TwoStepPlanner, RandomPlanner or anything with ``plan``
    candidates : list or callable
        A fixed list of actions, or ``candidates(belief, rng) -> list`` called each step
        (e.g. a :class:`~touchloc.planners.candidates.CandidateGenerator`).
    n_particles : int
        Particles of the default updater (:class:`~touchloc.belief.SMCFilter`), and of the
        prior sample planned on while an updater has no belief yet.
    max_touches : int
    stop_error, stop_probability : float
        The stopping rule, a claim the belief makes about its own estimate: stop when
        P(ADD-S(estimate, truth) < ``stop_error``) >= ``stop_probability`` under the
        belief (:func:`~touchloc.planners.metrics.prob_error_below`). Defaults: 5 mm and
        0.95. With a calibrated belief (``belief.hpd_level``; the default updater's is
        measured in docs/benchmarks.md) the claim is right in at least that fraction of
        the stops.
    stop_metric : {"add_s", "pose"}
        The error of the claim: ADD-S, or the pose metric modulo the object's
        symmetries, which also requires features such as a mug's handle to be found.
    confidence : float, optional
        The older rule, used instead when given: stop when the belief's expected ADD-S of
        its estimate is below this (m). It is not a probability and is not calibrated.
    updater : filter, optional
        Any estimator with the filter interface: ``update(results)`` taking the executed
        touches of an action (a list of TouchResult) and ``.belief``; e.g.
        :class:`~touchloc.belief.SMCFilter` (the default), ``ScalingSeries``,
        ``ParticleFilter`` or ``HistogramFilter``. If it has ``initialize`` and no belief
        yet, the loop initialises it over ``region``.
    verify_stop : bool
        Before stopping on the claim, ask an updater that can check itself
        (``updater.second_opinion()``, e.g. :class:`~touchloc.belief.SMCFilter`: an
        independent run from the prior on every touch so far, pooled with the current
        belief by evidence) and stop only if the claim still holds on the pooled belief.
        A filter that has lost the true mode is confident and wrong; the check costs one
        more localisation at the confident step and no touch. Default on; ignored with
        ``confidence`` and for updaters without ``second_opinion``.
    rng : None, int or Generator
    keep_plans : bool
        Keep every Plan (with its candidates' scores) in the steps.
    progress : bool, optional
        A bar over the touches (default: when stderr is a terminal; otherwise a line to stderr every few
        seconds). ``progress_bar=`` is its deprecated old name.
    callback : callable, optional
        ``callback(step)`` for the prior (step 0) and after each touch.

    Returns
    -------
    ActiveResult
    """
    if not hasattr(world, "execute"):
        raise ValidationError("world must have execute(action) -> list of TouchResult")
    from ..belief import PoseRegion
    from ..belief._common import check_model

    model = check_model(model)
    region = as_instance(region, PoseRegion, "region")
    if not callable(getattr(planner, "plan", None)):
        raise ValidationError(f"planner must have plan(belief, candidates, rng=...), got {type(planner).__name__}")
    if not callable(candidates):
        candidates = as_sequence(candidates, "candidates", min_len=1, expected="a list of actions or a callable")
    n_particles = as_count(n_particles, "n_particles", min=10, max=MAX_PARTICLES, why=WHY_PARTICLES)
    max_touches = as_count(max_touches, "max_touches", min=0, max=100_000, why="each touch is one plan and update")
    min_touches = as_count(min_touches, "min_touches", min=0)
    progress = progress_keyword(progress, progress_bar, "active_localization")
    keep_plans = as_bool(keep_plans, "keep_plans")
    verify_stop = as_bool(verify_stop, "verify_stop")
    callback = as_callable(callback, "callback", allow_none=True)
    if confidence is None:
        stop_error = 0.005 if stop_error is None else as_positive_float(stop_error, "stop_error")
        stop_probability = as_probability(stop_probability, "stop_probability", open_low=True)
        if not isinstance(stop_metric, str) or stop_metric not in ("add_s", "pose"):
            raise ValidationError(f"stop_metric must be 'add_s' or 'pose', got {stop_metric!r}")
    else:
        confidence = as_positive_float(confidence, "confidence")
    rng = as_rng(rng)
    obj = model.obj
    if updater is None:
        updater = SMCFilter(model, n_particles, rng=rng)
    if not callable(getattr(updater, "update", None)) or "belief" not in dir(updater):
        raise ValidationError(f"updater must have update(results) and .belief, got {type(updater).__name__}")
    if _belief_of(updater) is None and hasattr(updater, "initialize"):
        updater.initialize(region)
    prior = None
    truth = getattr(world, "true_pose", None)

    def current():
        nonlocal prior
        b = _belief_of(updater)
        if b is not None:
            return b
        if prior is None:  # e.g. Scaling Series before its first contact: plan on the region's prior
            reg = region if region.rho is not None else region.with_rho(obj.radius)
            prior = ParticleBelief(reg.sample(int(n_particles), rng=rng), region=reg)
        return prior

    def record(i, action, results, t_plan, t_upd, plan):
        b = current()
        T = best_pose(b)
        err = add_s(obj, T, truth) if truth is not None else float("nan")
        try:
            h = b.entropy("gaussian")
        except Exception:  # noqa: BLE001 - entropy of a degenerate belief
            h = float("nan")
        p_in = prob_error_below(b, obj, stop_error, ref=T, metric=stop_metric) if confidence is None \
            else float("nan")
        return Step(i, action, results, h, expected_add_s(b, obj), err, t_plan, t_upd, T,
                    plan if keep_plans else None, p_in)

    steps = [record(0, None, [], 0.0, 0.0, None)]
    if callback is not None:
        callback(steps[0])
    confident = False
    it = show_progress(range(1, int(max_touches) + 1), desc="touches", enabled=progress)
    for i in it:
        b = current()
        cands = candidates(b, rng) if callable(candidates) else candidates
        t0 = time.perf_counter()
        plan = planner.plan(b, cands, rng=rng)
        t1 = time.perf_counter()
        results = world.execute(plan.action)
        if not all(isinstance(r, TouchResult) for r in results):
            raise ValidationError("world.execute must return TouchResult objects")
        t2 = time.perf_counter()
        updater.update(results)
        t3 = time.perf_counter()
        step = record(i, plan.action, results, t1 - t0, t3 - t2, plan)
        done = step.expected_error < confidence if confidence is not None else step.p_within >= stop_probability
        if done and confidence is None and verify_stop and i >= min_touches \
                and callable(getattr(updater, "second_opinion", None)):
            t4 = time.perf_counter()
            updater.second_opinion()
            step = record(i, plan.action, results, t1 - t0, t3 - t2 + time.perf_counter() - t4, plan)
            step.verified = True
            done = step.p_within >= stop_probability
        steps.append(step)
        if callback is not None:
            callback(step)
        if i >= min_touches and done:
            confident = True
            break
    return ActiveResult(steps, current(), confident, truth,
                        {"planner": getattr(planner, "name", type(planner).__name__)})
