"""Belief updates from executed guarded touches: contacts and the free space they swept.

:class:`TouchLikelihood` scores poses given a list of :class:`TouchResult`: each contact
through the proximity model, and each touch's swept ray as negative information (the
object may not lie across the path the probe travelled without contact, whether the
touch hit or missed). :class:`TouchFilter` keeps a particle belief over a static object
and folds each new touch in by tempered importance resampling with Metropolis moves
(sequential Monte Carlo), so that a few thousand particles can follow the belief from a
wide region to millimetres.
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr, logsumexp

from .._util import as_poses, as_rng
from ..errors import ValidationError
from ..models import Contacts, MeasurementModel, ProximityModel
from ..models.base import check_temperature
from .actions import TouchResult
from .simulate import simulate

__all__ = ["TouchLikelihood", "TouchFilter", "EstimatorUpdater"]


class TouchLikelihood(MeasurementModel):
    """Likelihood of a set of executed guarded touches.

    ``log p = proximity log-likelihood of every contact
    + sum_j log(eps + (1 - eps) Phi((s_j(X) - travel_j) / sigma_free + margin))``

    where s_j(X) is where touch j would have stopped (inf if it misses the object at X,
    found by ray casting as in planning) and travel_j how far it really went: poses whose
    surface lies across the travelled path are ruled out, softly. For a miss this is the
    only term (negative information).

    Parameters
    ----------
    model : ProximityModel
    results : list of TouchResult
    sigma_free : float, optional
        Softness of the free-space boundary (m); default 2 model.sigma_pos.
    eps : float
        Probability that a real contact went unnoticed.
    margin : float
        Shift (in sigma_free) so that the true surface, where s_j = travel_j, is not
        penalised.
    use_contacts : bool
        False: the free-space term only (to add to a contact model with ``+``).
    """

    def __init__(self, model: ProximityModel, results, *, sigma_free: float | None = None, eps: float = 1e-3,
                 margin: float = 1.0, use_contacts: bool = True):
        if not isinstance(model, MeasurementModel) or getattr(model, "obj", None) is None:
            raise ValidationError(f"model must be a measurement model of an object, got {type(model).__name__}")
        results = list(results)
        if not all(isinstance(r, TouchResult) for r in results):
            raise ValidationError("results must be TouchResult objects")
        self.model, self.obj, self.results = model, model.obj, results
        sp = getattr(model, "sigma_pos", 0.002)
        self.sigma_free = float(sigma_free) if sigma_free else 2.0 * sp
        self.eps, self.margin = float(eps), float(margin)
        hits = [r.contact for r in results if r.contact is not None]
        self.contacts = Contacts.concatenate(hits) if hits and use_contacts else None
        self.travel = np.array([r.travel for r in results], dtype=float)

    def __repr__(self) -> str:
        return f"TouchLikelihood({len(self.results)} touches, {0 if self.contacts is None else len(self.contacts)} contacts)"

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log-likelihood of the touches for each pose (``contacts`` is ignored)."""
        T = check_temperature(temperature)
        P = as_poses(poses)
        ll = np.zeros(len(P))
        if not self.results:
            return ll
        if self.contacts is not None:
            ll += self.model.log_likelihood(P, self.contacts)
        out = simulate(self.obj, P, [r.touch for r in self.results])
        s = np.where(out.hit, out.travel, np.inf)
        z = (s - self.travel[None, :]) / self.sigma_free + self.margin
        lp = np.logaddexp(np.log(self.eps), np.log1p(-self.eps) + log_ndtr(z))
        ll += lp.sum(axis=1)
        return ll / T


class TouchFilter:
    """Particle belief over a static object's pose, updated touch by touch.

    Each :meth:`update` raises the new touches' likelihood from power 0 to 1 in steps
    that keep the effective sample size at ``ess_fraction`` of the particles; after each
    step it resamples and moves every particle by ``moves`` Metropolis steps whose
    target is the posterior at that power (region prior times all likelihoods so far).

    Parameters
    ----------
    model : ProximityModel
    region : PoseRegion
        The prior: uniform over the region.
    n_particles : int
    moves : int
        Metropolis steps per tempering step.
    ess_fraction : float
    max_stages : int
        Cap on tempering steps per update.
    rng : None, int or Generator
    **likelihood_kwargs
        Passed to :class:`TouchLikelihood`.
    """

    def __init__(self, model: ProximityModel, region, n_particles: int = 2000, *, moves: int = 3,
                 ess_fraction: float = 0.5, max_stages: int = 8, rng=None, **likelihood_kwargs):
        if int(n_particles) < 10:
            raise ValidationError(f"n_particles must be >= 10, got {n_particles}")
        self.model, self.obj = model, model.obj
        self.region = region if region.rho is not None else region.with_rho(model.obj.radius)
        self.n = int(n_particles)
        self.moves, self.ess_fraction, self.max_stages = int(moves), float(ess_fraction), int(max_stages)
        self.rng = as_rng(rng)
        self.kw = likelihood_kwargs
        self.results: list = []
        self.initialize()

    def initialize(self, poses=None):
        """Start from the uniform prior over the region (or from given poses)."""
        from ..belief import ParticleBelief

        P = self.region.sample(self.n, rng=self.rng) if poses is None else as_poses(poses)
        self.poses = P
        self.log_w = np.full(len(P), -np.log(len(P)))
        self.ll = np.zeros(len(P))
        self.results = []
        self.info = {"stages": [], "accept": []}
        self._belief = ParticleBelief(self.poses, self.log_w, region=self.region)
        return self._belief

    @property
    def belief(self):
        """The current ParticleBelief (equally weighted; ``info["map_pose"]`` holds the
        particle of highest posterior density)."""
        return self._belief

    def map_pose(self) -> np.ndarray:
        """(4, 4) the particle of highest posterior density."""
        return self.poses[int(np.argmax(self.ll + self.log_w))].copy()

    def _scale(self) -> float:
        C = self._belief.covariance()
        return float(max(np.sqrt(np.trace(C) / C.shape[0]), 2e-4))

    def update(self, results):
        """Fold in the outcome of one action (a TouchResult or a list of them).

        Returns
        -------
        ParticleBelief
        """
        from ..belief import ParticleBelief

        if isinstance(results, TouchResult):
            results = [results]
        results = list(results)
        if not results:
            return self._belief
        new = TouchLikelihood(self.model, results, **self.kw)
        old_results = list(self.results)
        old = TouchLikelihood(self.model, old_results, **self.kw) if old_results else None
        l_new = new.log_likelihood(self.poses)
        l_old = self.ll
        beta, stages = 0.0, 0
        acc = []
        while beta < 1.0 and stages < self.max_stages:
            stages += 1
            # largest step keeping the ESS above the target (bisection on the power)
            lo, hi = 0.0, 1.0 - beta
            def ess(d):
                lw = self.log_w + d * l_new
                lw = lw - logsumexp(lw)
                return np.exp(-logsumexp(2 * lw))
            if ess(hi) >= self.ess_fraction * self.n or stages == self.max_stages:
                d = hi
            else:
                for _ in range(30):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if ess(mid) >= self.ess_fraction * self.n else (lo, mid)
                d = max(lo, 1e-6)
            beta = min(1.0, beta + d)
            lw = self.log_w + d * l_new
            lw -= logsumexp(lw)
            self._belief = ParticleBelief(self.poses, lw, region=self.region)
            scale = self._scale()
            # resample (systematic)
            keep = np.searchsorted(np.cumsum(np.exp(lw)), (self.rng.random() + np.arange(self.n)) / self.n)
            keep = np.clip(keep, 0, self.n - 1)
            P, lo_, ln_ = self.poses[keep], l_old[keep], l_new[keep]
            # Metropolis moves at power beta
            for _ in range(self.moves):
                s = scale * 10 ** self.rng.uniform(-1.5, 0.3, self.n)
                Q = self.region.perturb(P, s, rng=self.rng, ball=False)
                inside = self.region.contains(Q)
                lq_old = old.log_likelihood(Q) if old is not None else np.zeros(self.n)
                lq_new = new.log_likelihood(Q)
                a = (lq_old + beta * lq_new) - (lo_ + beta * ln_)
                ok = inside & (np.log(self.rng.random(self.n)) < a)
                P = np.where(ok[:, None, None], Q, P)
                lo_, ln_ = np.where(ok, lq_old, lo_), np.where(ok, lq_new, ln_)
                acc.append(float(ok.mean()))
            self.poses, l_old, l_new = P, lo_, ln_
            self.log_w = np.full(self.n, -np.log(self.n))
            self._belief = ParticleBelief(self.poses, self.log_w, region=self.region)
        self.ll = l_old + l_new
        self._belief.info["map_pose"] = self.poses[int(np.argmax(self.ll))].copy()
        self.results = old_results + results
        self.info["stages"].append(stages)
        self.info["accept"].append(float(np.mean(acc)) if acc else float("nan"))
        return self._belief


class EstimatorUpdater:
    """Use a static estimator of touchloc.belief (e.g. ScalingSeries) in the active loop.

    Each update re-localises from scratch with every contact so far and the free space of
    every touch: ``make_estimator(model + free_space).localize(contacts, region)``. Before
    the first contact, the belief is the region's prior sampled with ``n_prior`` particles
    and weighted by the free space of the misses.

    Parameters
    ----------
    model : ProximityModel
    region : PoseRegion
    make_estimator : callable
        ``make_estimator(model) -> estimator`` with ``localize(contacts, region)``;
        default ``ScalingSeries(model, rng=rng)``.
    n_prior : int
    rng : None, int or Generator
    """

    def __init__(self, model, region, make_estimator=None, *, n_prior: int = 2000, rng=None, **likelihood_kwargs):
        from ..belief import ParticleBelief

        self.model, self.obj = model, model.obj
        self.region = region if region.rho is not None else region.with_rho(model.obj.radius)
        self.rng = as_rng(rng)
        if make_estimator is None:
            from ..belief import ScalingSeries

            def make_estimator(m):
                return ScalingSeries(m, rng=self.rng, progress=False)
        self.make_estimator = make_estimator
        self.n_prior, self.kw = int(n_prior), likelihood_kwargs
        self.results: list = []
        self._belief = ParticleBelief(self.region.sample(self.n_prior, rng=self.rng), region=self.region)

    @property
    def belief(self):
        return self._belief

    def update(self, results):
        from ..belief import ParticleBelief

        if isinstance(results, TouchResult):
            results = [results]
        self.results = self.results + list(results)
        free = TouchLikelihood(self.model, self.results, use_contacts=False, **self.kw)
        hits = [r.contact for r in self.results if r.contact is not None]
        if not hits:
            P = self.region.sample(self.n_prior, rng=self.rng)
            self._belief = ParticleBelief(P, free.log_likelihood(P), region=self.region)
            return self._belief
        pts = np.concatenate([c.points for c in hits])
        nrm = None if any(c.normals is None for c in hits) else np.concatenate([c.normals for c in hits])
        b = self.make_estimator(self.model + free).localize(Contacts(pts, nrm), self.region)
        self._belief = b
        return b
