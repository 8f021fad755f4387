"""Markov chain Monte Carlo refinement through emcee's affine-invariant ensemble sampler."""

from __future__ import annotations

import logging
import time

import numpy as np

from .._util import as_rng, blas_threads
from .._validate import as_bool, as_count
from ..errors import BeliefDegenerateError, ValidationError
from ._common import check_contacts, check_model, check_region
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["MCMC"]


class MCMC:
    """Sample the posterior with emcee, started from another belief.

    The chain lives in the metric tangent coordinates of the region at the starting
    belief's MAP pose (translations in m, rho-scaled rotation vector), so the sampler
    sees a Euclidean space; poses outside the region have zero prior.

    Parameters
    ----------
    model : MeasurementModel
    n_walkers : int
        emcee walkers (>= 2 x dim).
    n_steps : int
        Steps per walker after burn-in.
    burn : int
        Discarded steps per walker.
    thin : int
    """

    def __init__(self, model, *, n_walkers: int = 32, n_steps: int = 300, burn: int = 200, thin: int = 5,
                 rng=None, progress: bool = False):
        self.model = check_model(model)
        n_walkers = as_count(n_walkers, "n_walkers", min=2, max=100_000, why="each walker is one likelihood per step")
        n_steps = as_count(n_steps, "n_steps", max=1_000_000, why="each step is one likelihood pass over the walkers")
        burn = as_count(burn, "burn", min=0, max=1_000_000, why="each step is one likelihood pass over the walkers")
        thin = as_count(thin, "thin", max=n_steps, why="thinning must keep at least one step")
        progress = as_bool(progress, "progress")
        self.n_walkers, self.n_steps, self.burn, self.thin = int(n_walkers), int(n_steps), int(burn), int(thin)
        self.rng = as_rng(rng)
        self.progress = progress

    @blas_threads
    def refine(self, contacts, start: ParticleBelief, region: PoseRegion | None = None) -> ParticleBelief:
        """Run the chain from ``start`` and return its samples as an equally weighted belief.

        ``info`` holds the acceptance fraction and, where the chain is long enough,
        emcee's integrated autocorrelation time per coordinate.
        """
        import emcee

        t0 = time.perf_counter()
        contacts = check_contacts(contacts)
        if not isinstance(start, ParticleBelief):
            raise ValidationError("start must be a ParticleBelief (e.g. a Scaling Series result)")
        region = start.region if region is None else region
        if region is None:
            raise ValidationError("give region= (the start belief has none)")
        region = check_region(region, self.model)
        dim = region.dim
        if self.n_walkers < 2 * dim:
            raise ValidationError(f"n_walkers must be >= 2 * dim = {2 * dim}")
        ref = start.map_pose()
        init = start.resample(self.n_walkers, rng=self.rng).poses
        v0 = region.to_local(init, ref)
        # jitter duplicates so the ensemble spans a volume
        scale = max(start.resolution or 1e-3, 1e-4)
        v0 = v0 + self.rng.normal(scale=0.1 * scale, size=v0.shape)
        model = self.model

        def log_prob(v):
            v = np.atleast_2d(v)
            X = region.from_local(v, ref)
            inside = region.contains(X)
            out = np.full(len(v), -np.inf)
            if np.any(inside):
                out[inside] = model.log_likelihood(X[inside], contacts)
            return out

        sampler = emcee.EnsembleSampler(self.n_walkers, dim, log_prob, vectorize=True)
        sampler.random_state = np.random.RandomState(int(self.rng.integers(2**32 - 1))).get_state()
        if not np.all(np.isfinite(v0)):
            raise BeliefDegenerateError("the start belief maps to non-finite chain coordinates; "
                                        "check its poses, resolution and the region's rho")
        try:
            sampler.run_mcmc(v0, self.burn + self.n_steps, progress=self.progress)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            # emcee checks that the walkers span a volume (an SVD) and that log_prob is not NaN
            raise BeliefDegenerateError(f"the MCMC chain could not run from this start belief: {exc}") from exc
        chain = sampler.get_chain(discard=self.burn, thin=self.thin, flat=True)
        X = region.from_local(chain, ref)
        logger = logging.getLogger("emcee.autocorr")
        level = logger.level
        logger.setLevel(logging.ERROR)  # a short chain's warning: the numbers go to info
        try:
            tau = sampler.get_autocorr_time(discard=self.burn, quiet=True)
        except Exception:  # emcee raises when the chain is far too short
            tau = np.full(dim, np.nan)
        finally:
            logger.setLevel(level)
        b = ParticleBelief(X, None, region=region, resolution=start.resolution)
        b.info.update(acceptance=float(np.mean(sampler.acceptance_fraction)), autocorr=np.asarray(tau),
                      seconds=time.perf_counter() - t0, evaluations=self.n_walkers * (self.burn + self.n_steps))
        return b
