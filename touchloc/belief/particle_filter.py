"""Particle filter: importance sampling (static) and resample-move with roughening (dynamic)."""

from __future__ import annotations

import time

import numpy as np

from .._util import as_rng, blas_threads
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_bool, as_count, as_nonnegative_float, as_positive_float,
                         as_probability)
from ..errors import ValidationError
from ._common import check_contacts, check_dynamics, check_model, check_region, finite_loglik, flag_degenerate, measurement
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["ParticleFilter"]


class ParticleFilter:
    """Sampling importance resampling over object poses.

    Parameters
    ----------
    model : MeasurementModel
    dynamics : GaussianDynamics, optional
        Motion between updates (needed by :meth:`predict`).
    n_particles : int
    resample_threshold : float
        Resample when ESS < threshold * N (0..1).
    roughening : float
        After resampling, jitter each particle with a Gaussian of standard deviation
        ``roughening * sd * N^(-1/dim)`` per metric coordinate, sd being the belief's
        spread (Gordon et al. 1993), so duplicates spread over the peak.
    rng : None, int or Generator
    """

    def __init__(self, model, dynamics=None, n_particles: int = 5000, *, resample_threshold: float = 0.5,
                 roughening: float = 0.2, rho: float | None = None, rng=None):
        self.model = check_model(model)
        n_particles = as_count(n_particles, "n_particles", max=MAX_PARTICLES, why=WHY_PARTICLES)
        resample_threshold = as_probability(resample_threshold, "resample_threshold")
        roughening = as_nonnegative_float(roughening, "roughening")
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        self.dynamics = check_dynamics(dynamics)
        self.n_particles = int(n_particles)
        self.resample_threshold = float(resample_threshold)
        self.roughening = float(roughening)
        self.rho = rho
        self.rng = as_rng(rng)
        self.belief: ParticleBelief | None = None
        self.region: PoseRegion | None = None

    def _resolution(self, region):
        return (region.volume() / self.n_particles) ** (1.0 / region.dim)

    # -- static ------------------------------------------------------------------------
    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        """Importance sampling: n_particles uniform poses weighted by the likelihood."""
        t0 = time.perf_counter()
        self.initialize(region)
        b = self.update(contacts, resample=False)
        b.info["seconds"] = time.perf_counter() - t0
        return b

    # -- dynamic -----------------------------------------------------------------------
    def initialize(self, region: PoseRegion) -> None:
        """Uniform particles over the region."""
        region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        self.region = region
        X = region.sample(self.n_particles, rng=self.rng)
        self.belief = ParticleBelief(X, region=region, resolution=self._resolution(region))

    def _require(self):
        if self.belief is None:
            raise ValidationError("call initialize(region) first")

    def predict(self) -> None:
        """Move every particle by a draw from the dynamics."""
        self._require()
        if self.dynamics is None:
            raise ValidationError("predict() needs dynamics=GaussianDynamics(...)")
        X = self.dynamics.sample(self.belief.poses, rng=self.rng)
        self.belief = self.belief.with_particles(X, self.belief.log_weights)

    @blas_threads
    def update(self, contacts, *, model=None, resample: bool = True, free_space=None) -> ParticleBelief:
        """Weight by the likelihood of the new measurements; resample and roughen when the
        ESS drops.

        ``contacts`` is a :class:`~touchloc.models.Contacts`, or the executed touches of
        an action (a list of ``planners.TouchResult``): then their contacts and the free
        space they swept (``free_space``, default :class:`~touchloc.models.RayStopModel`)
        are scored together, and a miss alone updates the belief too. ``model`` replaces
        the filter's model for this update only, e.g. ``proximity +
        FreeSpaceModel.from_results(obj, results)`` (then ``contacts`` may be None).
        """
        self._require()
        resample = as_bool(resample, "resample")
        if model is None:
            contacts, m = measurement(self.model, contacts, free_space=free_space)
        else:
            m = check_model(model)
            if contacts is not None:
                contacts = check_contacts(contacts)
        ll = finite_loglik(m.log_likelihood(self.belief.poses, contacts))
        b = self.belief.with_particles(self.belief.poses, self.belief.log_weights + ll)
        if contacts is not None:
            flag_degenerate(b, float(ll[np.argmax(b.log_weights)]), contacts)
        if resample and b.ess() < self.resample_threshold * len(b):
            b = self._resample_move(b)
        self.belief = b
        return b

    def _resample_move(self, b: ParticleBelief) -> ParticleBelief:
        reg = self.region
        sd = np.sqrt(np.clip(np.diag(b.covariance()), 0, None)).mean()
        scale = self.roughening * max(sd, 1e-9) * len(b) ** (-1.0 / reg.dim)
        r = b.resample(rng=self.rng)
        X = reg.perturb(r.poses, scale, rng=self.rng, ball=False)
        out = r.with_particles(X, None)
        out.degenerate = b.degenerate
        out.info.update(b.info)
        return out
