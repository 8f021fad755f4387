"""Touches that tell objects apart: candidates scored by expected identity entropy."""

from __future__ import annotations

import time

import numpy as np
from scipy.special import logsumexp

from .._util import as_rng, blas_threads
from .._validate import (as_count, as_mapping, as_nonnegative_float, as_positive_float, as_probability,
                         as_sequence)
from ..errors import PlanningError, ValidationError
from .actions import GuardedTouch, as_cost
from .lookahead import Plan
from .simulate import simulate

__all__ = ["IdentityPlanner"]


class IdentityPlanner:
    """Pick the guarded touch whose outcome best separates candidate objects.

    The state holds the object's identity as well as its pose (Handbook of Robotics
    ch. 42.3.1): each candidate object has a pose belief and a probability (e.g. from
    :func:`touchloc.belief.identify` with ``return_beliefs=True``). For every candidate
    touch, the stopping distance is simulated for every object's particles; outcomes are
    drawn from the mixture over objects and poses, and each drawn outcome updates the
    identity posterior through its likelihood under each object (stopping distance with
    Gaussian noise ``sigma_travel``; a miss against a hit has probability ``eps``). The
    score is ``-E[H(identity | outcome)] - beta * cost`` (eq. 42.12-42.15 with the
    identity in place of the pose).

    Parameters
    ----------
    objects : mapping name -> MeshObject
    sigma_travel : float
        Noise of the measured stopping distance (m).
    eps : float
        Probability of a missed contact or a phantom one.
    n_samples : int
        Simulated outcomes per candidate.
    max_particles : int
        Heaviest particles used per object belief.
    beta : float
        Cost weight; ``cost`` a callable ``cost(action, travel)`` (default: distance).
    """

    def __init__(self, objects, *, sigma_travel: float = 0.003, eps: float = 0.01, n_samples: int = 64,
                 max_particles: int = 200, beta: float = 0.0, cost=None):
        from ..models import MeshObject

        objects = as_mapping(objects, "objects", of=MeshObject, min_len=1, expected="a dict name -> MeshObject")
        sigma_travel = as_positive_float(sigma_travel, "sigma_travel (m)")
        eps = as_probability(eps, "eps", open_low=True, open_high=True)
        n_samples = as_count(n_samples, "n_samples", max=100_000, why="each sample is one simulated outcome per candidate")
        max_particles = as_count(max_particles, "max_particles", max=1_000_000, why="one simulation per particle")
        beta = as_nonnegative_float(beta, "beta")
        self.objects = dict(objects)
        self.sigma_travel, self.eps = float(sigma_travel), float(eps)
        self.n_samples, self.max_particles = int(n_samples), int(max_particles)
        self.beta = float(beta)
        self.cost = as_cost(cost)

    @blas_threads
    def plan(self, beliefs, probabilities, candidates, *, rng=None) -> Plan:
        """Score every candidate.

        Parameters
        ----------
        beliefs : mapping name -> ParticleBelief
        probabilities : mapping name -> float
            Current identity probabilities (need not be normalised).
        candidates : list of GuardedTouch

        Returns
        -------
        Plan
            ``action`` the best candidate; ``scores`` (C,) ``-E[H] - beta * cost``;
            ``details["expected_entropy"]`` (C,).
        """
        t0 = time.perf_counter()
        rng = as_rng(rng)
        cands = as_sequence(candidates, "candidates", expected="a list of GuardedTouch")
        if not cands or not all(isinstance(c, GuardedTouch) for c in cands):
            raise PlanningError("candidates must be a non-empty list of GuardedTouch")
        from ..belief import ParticleBelief

        beliefs = as_mapping(beliefs, "beliefs", of=ParticleBelief, expected="a dict of name -> ParticleBelief")
        probabilities = as_mapping(probabilities, "probabilities", expected="a dict of name -> probability")
        probabilities = {n: as_probability(p, f"probabilities[{n!r}]") for n, p in probabilities.items()}
        missing = [n for n in self.objects if probabilities.get(n, 0.0) > 0 and n not in beliefs]
        if missing:
            raise ValidationError(f"beliefs lacks the objects {missing} that have a positive probability")
        names = [n for n in self.objects if probabilities.get(n, 0.0) > 0]
        if not names:
            raise PlanningError("no object has a positive identity probability")
        pi = np.array([probabilities[n] for n in names], float)
        pi /= pi.sum()
        travel, hit, wts = [], [], []
        for n in names:
            b = beliefs[n]
            idx = np.argsort(-b.log_weights)[: self.max_particles]
            w = b.weights[idx] / b.weights[idx].sum()
            out = simulate(self.objects[n], b.poses[idx], cands)
            travel.append(out.travel)  # (P, C)
            hit.append(out.hit)
            wts.append(w)
        C = len(cands)
        S = self.n_samples
        H = np.zeros(C)
        for c in range(C):
            # draw outcomes from the mixture: object i, then a particle, then noise
            obj_i = rng.choice(len(names), size=S, p=pi)
            obs_t = np.empty(S)
            obs_h = np.empty(S, bool)
            for i in range(len(names)):
                sel = obj_i == i
                if not np.any(sel):
                    continue
                p = rng.choice(len(wts[i]), size=sel.sum(), p=wts[i])
                obs_t[sel] = travel[i][p, c] + rng.normal(scale=self.sigma_travel, size=sel.sum())
                obs_h[sel] = hit[i][p, c]
            # log p(outcome | object i) = log sum_p w_p L(outcome | particle p)
            logp = np.empty((S, len(names)))
            for i in range(len(names)):
                t_i, h_i = travel[i][:, c], hit[i][:, c]
                same = obs_h[:, None] == h_i[None, :]
                gauss = -0.5 * ((obs_t[:, None] - t_i[None, :]) / self.sigma_travel) ** 2
                ll = np.where(same, np.log1p(-self.eps) + np.where(obs_h[:, None], gauss, 0.0), np.log(self.eps))
                logp[:, i] = logsumexp(ll + np.log(wts[i])[None, :], axis=1)
            post = logp + np.log(pi)[None, :]
            post -= logsumexp(post, axis=1, keepdims=True)
            H[c] = float(np.mean(-np.sum(np.exp(post) * post, axis=1)))
        costs = np.array([float(np.sum(self.cost(a, np.array([a.max_travel])))) for a in cands])
        scores = -H - self.beta * costs
        best = int(np.argmax(scores))
        return Plan(action=cands[best], index=best, scores=scores, candidates=cands, utility="identity entropy",
                    details={"expected_entropy": H, "cost": costs},
                    info={"seconds": time.perf_counter() - t0, "objects": names})
