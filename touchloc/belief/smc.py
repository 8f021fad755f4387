"""Sequential Monte Carlo over a static object's pose: tempering and Metropolis moves."""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from .._util import as_poses, as_rng, blas_threads
from .._util import logsumexp1d as _logsumexp
from .._validate import as_count, as_nonnegative_float, as_probability
from ..errors import ValidationError
from ..models import Contacts
from ._common import check_model, check_region, measurement, split_measurements, touch_model
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["SMCFilter", "temper"]


class SMCFilter:
    """Particle belief over a static object's pose, updated measurement by measurement.

    Each :meth:`update` raises the new measurements' likelihood from power 0 to 1 in
    steps that keep the effective sample size at ``ess_fraction`` of the particles (a
    bisection on the power); after each step it resamples (systematic) and moves every
    particle by ``moves`` Metropolis steps whose target is the posterior at that power:
    the region prior times the full likelihood of every earlier measurement times the new
    one's likelihood raised to the power. The belief is equally weighted;
    ``belief.info["map_pose"]`` holds the particle of highest posterior density.

    Why this is not :class:`~touchloc.belief.AnnealedParticleFilter`: both choose
    tempering steps by the effective sample size, but the annealed particle filter is a
    static estimator that anneals the whole likelihood from the uniform prior in one call
    and moves particles by plain diffusion, which does not leave the tempered posterior
    invariant (its output is an approximation whose spread depends on the diffusion).
    This filter is sequential: its prior is the previous posterior, only the new
    measurements are tempered, and its moves are Metropolis-Hastings steps with that
    posterior as their stationary distribution (resample-move SMC, Gilks & Berzuini 2001;
    Del Moral, Doucet & Jasra 2006). Merging them would change the meaning of one of the
    two.

    Parameters
    ----------
    model : MeasurementModel
        Contact model (e.g. :class:`~touchloc.models.ProximityModel`).
    n_particles : int
        At least 10.
    moves : int
        Minimum Metropolis steps per tempering step.
    ess_fraction : float
        Target ESS / N per tempering step, in (0, 1).
    max_stages : int
        Cap on tempering steps per update (the last one jumps to power 1). The steps are
        set by the effective sample size; the cap is a guard, reached only when the
        posterior is extremely narrow compared with the prior (a jump to power 1 then
        collapses the sample on a few particles; ``info["stages"]`` shows it).
    jumps : float
        Accepted Metropolis moves per particle and tempering step to reach (moves go
        on past ``moves`` until then, at most ``10 * moves``); the walk's size adapts to
        the acceptance (see :func:`temper`).
    free_space : subclass of FreeSpaceBase, optional
        Model of the free space swept by executed touches; default
        :class:`~touchloc.models.RayStopModel`.
    rho : float, optional
        Rotation scale of the pose metric (m); default the object's radius.
    rng : None, int or Generator
    **free_kwargs
        Passed to ``free_space.from_results`` (``sigma``, ``eps``, ``margin``).

    Examples
    --------
    >>> f = SMCFilter(model, 2000, rng=0)                  # doctest: +SKIP
    >>> f.initialize(region)                               # doctest: +SKIP
    >>> f.update(world.execute(touch)).map_pose()          # doctest: +SKIP
    """

    def __init__(self, model, n_particles: int = 2000, *, moves: int = 3, ess_fraction: float = 0.5,
                 max_stages: int = 60, jumps: float = 2.0, free_space=None, rho: float | None = None, rng=None,
                 **free_kwargs):
        self.model = check_model(model)
        self.obj = self.model.obj
        n_particles = as_count(n_particles, "n_particles", min=10, max=10_000_000, why="memory: 128 bytes a pose")
        moves = as_count(moves, "moves", min=0, max=1000, why="each move is one likelihood pass over the particles")
        max_stages = as_count(max_stages, "max_stages", max=1000, why="each stage is one likelihood pass")
        ess_fraction = as_probability(ess_fraction, "ess_fraction", open_low=True, open_high=True)
        jumps = as_nonnegative_float(jumps, "jumps")
        if jumps > 100:
            raise ValidationError(f"jumps must be at most 100 accepted moves per particle and step, got {jumps}")
        self.jumps = float(jumps)
        self.n = int(n_particles)
        self.moves, self.ess_fraction, self.max_stages = int(moves), float(ess_fraction), int(max_stages)
        self.free_space, self.free_kwargs = free_space, free_kwargs
        self.rho = rho
        self.rng = as_rng(rng)
        self.region: PoseRegion | None = None
        self._belief: ParticleBelief | None = None
        self.contacts: Contacts | None = None
        self.results: list = []

    def initialize(self, region: PoseRegion, *, poses=None) -> ParticleBelief:
        """Start from the uniform prior over ``region`` (or from given (N, 4, 4) poses)."""
        self.region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        P = self.region.sample(self.n, rng=self.rng) if poses is None else as_poses(poses)
        self.n = len(P)
        self.poses = P
        self.log_w = np.full(len(P), -np.log(len(P)))
        self.ll = np.zeros(len(P))
        self.contacts, self.results = None, []
        self.log_evidence = 0.0
        self.info = {"stages": [], "accept": []}
        self._belief = ParticleBelief(self.poses, self.log_w, region=self.region)
        return self._belief

    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        """Static use: the uniform prior over ``region`` updated once with ``contacts``."""
        self.initialize(region)
        return self.update(contacts)

    def predict(self) -> None:
        """Not available: the filter assumes a static object (every earlier measurement is
        re-scored at the moved particles), so motion would make it wrong."""
        raise ValidationError("SMCFilter tracks a static object and has no predict(); use ParticleFilter or "
                              "ScalingSeries with dynamics= for a moving object")

    @property
    def belief(self) -> ParticleBelief | None:
        """The current ParticleBelief (None before :meth:`initialize`)."""
        return self._belief

    def map_pose(self) -> np.ndarray:
        """(4, 4) the particle of highest posterior density."""
        self._require()
        return self.poses[int(np.argmax(self.ll + self.log_w))].copy()

    def _require(self):
        if self._belief is None:
            raise ValidationError("call initialize(region) first")

    def second_opinion(self, *, rng=None) -> float:
        """Check the belief against an independent run, and keep what both found.

        A resample-move filter can lose a mode of the posterior for good: once every
        particle sits in one basin, later Metropolis moves do not leave it, and the belief
        is confident and wrong. This runs a second filter with the same settings from the
        uniform prior over the region, on every measurement so far in one update, and
        replaces this filter's particles by a draw from the two samples pooled, each
        weighted by its run's evidence estimate (a run that missed a mode has the lower
        evidence by about that mode's share). Where both runs found the same posterior,
        the pool is that posterior; where one found a better-explaining mode, the pool
        holds it in proportion.

        Parameters
        ----------
        rng : None, int or Generator
            For the second run (default: drawn from this filter's generator).

        Returns
        -------
        float
            The log ratio of the second run's evidence to this one's.
        """
        self._require()
        if self.contacts is None and not self.results:
            return 0.0
        rng = as_rng(rng) if rng is not None else np.random.default_rng(self.rng.integers(2**63))
        other = SMCFilter(self.model, self.n, moves=self.moves, ess_fraction=self.ess_fraction,
                          max_stages=self.max_stages, jumps=self.jumps, free_space=self.free_space, rho=self.rho,
                          rng=rng, **self.free_kwargs)
        other.initialize(self.region)
        new = other._loglik(self.contacts, self.results, self.free_space)
        ev = {}
        other.poses, _, l_new, _, _ = temper(other.poses, other.log_w, other.ll, new(other.poses), None, new,
                                             other.region, moves=self.moves, ess_fraction=self.ess_fraction,
                                             max_stages=self.max_stages, jumps=self.jumps, info=ev, rng=other.rng)
        other.ll, other.log_evidence = l_new, ev["log_evidence"]
        ratio = other.log_evidence - self.log_evidence
        w_other = float(expit(ratio))   # share of the second run in the pool
        k = int(self.rng.binomial(self.n, w_other))
        pick_self = self.rng.choice(self.n, self.n - k, replace=False) if k < self.n else np.zeros(0, int)
        pick_other = other.rng.choice(other.n, k, replace=False) if k > 0 else np.zeros(0, int)
        self.poses = np.concatenate([self.poses[pick_self], other.poses[pick_other]])
        self.ll = np.concatenate([self.ll[pick_self], other.ll[pick_other]])
        self.log_evidence = float(np.logaddexp(self.log_evidence, other.log_evidence) - np.log(2.0))
        self._belief = ParticleBelief(self.poses, self.log_w, region=self.region)
        self._belief.info.update(map_pose=self.poses[int(np.argmax(self.ll))].copy(), second_opinion=float(ratio))
        return float(ratio)

    def _scale(self) -> float:
        C = self._belief.covariance()
        return float(max(np.sqrt(np.trace(C) / C.shape[0]), 2e-4))

    def _loglik(self, contacts, results, free_space):
        """(P) -> (N,) log-likelihood of the given contacts and executed touches."""
        free = touch_model(self.model, results, free_space, **self.free_kwargs)

        def ll(P):
            out = np.zeros(len(P))
            if contacts is not None:
                out += self.model.log_likelihood(P, contacts)
            if free is not None:
                out += free.log_likelihood(P)
            return out
        return ll

    @blas_threads
    def update(self, contacts, *, free_space=None) -> ParticleBelief:
        """Fold in new measurements: a :class:`~touchloc.models.Contacts`, or the executed
        touches of an action (a ``planners.TouchResult`` or a list of them; their contacts
        and the free space they swept, hit or miss).

        Returns
        -------
        ParticleBelief
        """
        self._require()
        if isinstance(contacts, (list, tuple)) and len(contacts) == 0:
            return self._belief
        free_space = self.free_space if free_space is None else free_space
        new_c, results = split_measurements(contacts)
        if not results:
            new_c, _ = measurement(self.model, new_c)   # validates plain contacts
        elif new_c is not None and len(new_c) == 0:
            new_c = None
        new = self._loglik(new_c, results, free_space)
        old = self._loglik(self.contacts, self.results, free_space) if (self.contacts is not None or self.results) \
            else None
        l_new = new(self.poses)
        ev = {}
        self.poses, l_old, l_new, stages, acc = temper(
            self.poses, self.log_w, self.ll, l_new, old, new, self.region, moves=self.moves,
            ess_fraction=self.ess_fraction, max_stages=self.max_stages, jumps=self.jumps, info=ev, rng=self.rng)
        self.log_evidence += ev["log_evidence"]
        self.log_w = np.full(self.n, -np.log(self.n))
        self._belief = ParticleBelief(self.poses, self.log_w, region=self.region)
        self.ll = l_old + l_new
        self._belief.info.update(map_pose=self.poses[int(np.argmax(self.ll))].copy(), stages=stages,
                                 acceptance=float(np.mean(acc)) if acc else float("nan"), moves=len(acc))
        if new_c is not None:
            self.contacts = new_c if self.contacts is None else Contacts.concatenate([self.contacts, new_c])
        self.results = self.results + results
        self.info["stages"].append(stages)
        self.info["accept"].append(float(np.mean(acc)) if acc else float("nan"))
        return self._belief


def _ess(lw) -> float:
    """Effective sample size ``(sum w)^2 / sum w^2`` of unnormalised log-weights (0 when none
    is finite). The bisection on the tempering power calls it about 30 times per stage: plain
    numpy, without logsumexp's checks, is several times cheaper."""
    top = lw.max()
    if not np.isfinite(top):
        return 0.0 if top == -np.inf else float("nan")
    w = np.exp(lw - top)
    s = w.sum()
    return float(s * s / np.dot(w, w))


def _scale(P, log_w, region) -> float:
    """Root-mean-square spread (m, pose metric) of a weighted particle set."""
    C = ParticleBelief._trusted(P, log_w, region=region).covariance()
    return float(max(np.sqrt(np.trace(C) / C.shape[0]), 2e-4))


def temper(poses, log_w, l_old, l_new, old, new, region, *, moves: int = 3, ess_fraction: float = 0.5,
           max_stages: int = 60, jumps: float = 2.0, max_moves: int | None = None, target_accept: float = 0.3,
           info: dict | None = None, rng=None, new_above=None):
    """Resample-move SMC from ``prior x exp(old)`` to ``prior x exp(old + new)``.

    The power of the new term rises from 0 to 1 in steps that keep the effective sample
    size at ``ess_fraction`` of the particles (bisection on the power), all the way to 1
    unless ``max_stages`` is reached (the last step then jumps to 1, and the output is
    no longer a sample of the posterior: ``stages == max_stages`` says so). After each
    step the particles are resampled (systematic) and moved by Metropolis steps that
    leave the tempered target invariant: symmetric random walks in the region's metric,
    rejected outside the region (the prior is uniform over it).

    The walk's size adapts: each particle's step is drawn log-uniformly from 3 % to 2
    times a scale ``s`` that starts at the particles' spread and, after each move, is
    re-centred on the steps that were accepted (the scale of a multimodal or ring-shaped
    posterior is far larger than the width of its modes, so a fixed fraction of the
    spread is rejected nearly always and leaves resampled duplicates where they are).
    Moves continue past ``moves`` until the particles have made ``jumps`` accepted moves
    each on average (at most ``max_moves``, default ``10 * moves``), so that the
    duplicates of a resampling separate.

    Parameters
    ----------
    poses : (N, 4, 4) float
        Particles weighted by ``log_w`` that represent ``prior x exp(old)``.
    log_w : (N,) float
    l_old, l_new : (N,) float
        ``old(poses)`` and ``new(poses)``.
    old : callable or None
        ``old(P) -> (M,)`` log-density already in the target (None: zero).
    new : callable
        ``new(P) -> (M,)`` log-likelihood being tempered in.
    region : PoseRegion
    moves : int
        Minimum Metropolis steps per tempering step (0: no moves at all).
    ess_fraction : float
    max_stages : int
    jumps : float
        Accepted moves per particle and tempering step to reach before stopping.
    max_moves : int, optional
    target_accept : float
        Acceptance rate the scale aims at.
    info : dict, optional
        Receives ``log_evidence``: the log of the standard SMC estimate of
        ``E_{prior x exp(old)}[exp(new)]`` (the product over steps of the mean incremental
        weight), with which posteriors of separate runs on the same data can be pooled.
    rng : None, int or Generator
    new_above : callable, optional
        ``new_above(P, t) -> (M,)``: ``new(P)`` where it exceeds ``t`` (M,), and ``-inf``
        where it is sure not to (a likelihood that can stop early). A move is accepted only
        if its proposal's ``new`` exceeds the threshold that the move's uniform draw sets,
        so with it each proposal is evaluated only until it is sure to be rejected; the
        moves, and the result, are those of ``new`` (up to rounding at the threshold).

    Returns
    -------
    poses : (N, 4, 4) float
        Equally weighted particles of the final target.
    l_old, l_new : (N,) float
    stages : int
    acceptance : list of float
        Fraction of accepted moves, per move.
    """
    rng = as_rng(rng)
    if new_above is not None and not callable(new_above):
        raise ValidationError(f"new_above must be a callable or None, got {type(new_above).__name__}")
    # checked once here: the moves below make rigid poses from rigid poses
    P = as_poses(poses, "poses")
    n = len(P)
    lw0 = np.asarray(log_w, dtype=float)
    l_old, l_new = np.asarray(l_old, dtype=float), np.asarray(l_new, dtype=float)
    beta, stages, acc = 0.0, 0, []
    target = ess_fraction * n
    max_moves = 10 * int(moves) if max_moves is None else int(max_moves)
    scale, log_z = None, 0.0
    while beta < 1.0 and stages < max_stages:
        stages += 1

        def ess(d):
            return _ess(lw0 + d * l_new)
        # largest step keeping the ESS above the target (bisection on the power)
        lo, hi = 0.0, 1.0 - beta
        if ess(hi) >= target or stages == max_stages:
            d = hi
        else:
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if ess(mid) >= target else (lo, mid)
            d = max(lo, 1e-6)
        beta = 1.0 if d >= 1.0 - beta else beta + d
        lw = lw0 + d * l_new
        log_z += _logsumexp(lw) - _logsumexp(lw0)
        lw -= _logsumexp(lw)
        spread = _scale(P, lw, region)
        scale = spread if scale is None else min(scale, 2.0 * spread)
        keep = np.searchsorted(np.cumsum(np.exp(lw)), (rng.random() + np.arange(n)) / n)
        keep = np.clip(keep, 0, n - 1)
        P, lo_, ln_ = P[keep], l_old[keep], l_new[keep]
        done, m = 0.0, 0
        while m < moves or (done < jumps and m < max_moves):
            m += 1
            s = scale * 10 ** rng.uniform(-1.5, 0.3, n)
            Q = region._perturb(P, s, rng, False)
            inside = region._contains(Q)
            lq_old = np.zeros(n)
            lq_new = np.full(n, -np.inf)
            log_u = np.log(rng.random(n))  # drawn before the proposals are scored, which draw nothing
            if inside.any():
                if old is not None:
                    lq_old[inside] = old(Q[inside])
                if new_above is not None and beta > 0:
                    # accepted only if lq_new > t: below it, how far below does not matter
                    with np.errstate(invalid="ignore"):
                        t = (log_u - lq_old + lo_ + beta * ln_) / beta
                    t = np.where(np.isnan(t), -np.inf, t)
                    lq_new[inside] = new_above(Q[inside], t[inside])
                else:
                    lq_new[inside] = new(Q[inside])
            a = (lq_old + beta * lq_new) - (lo_ + beta * ln_)
            ok = inside & (log_u < a)
            P = np.where(ok[:, None, None], Q, P)
            lo_, ln_ = np.where(ok, lq_old, lo_), np.where(ok, lq_new, ln_)
            rate = float(ok.mean())
            acc.append(rate)
            done += rate
            # re-centre the scale on the accepted steps (their geometric middle sits at
            # about a quarter of the scale); grow it when most steps are accepted
            if ok.any():
                scale = 4.0 * float(np.exp(np.mean(np.log(s[ok]))))
                if rate > target_accept:
                    scale *= 1.0 + (rate - target_accept)
            else:
                scale *= 0.1
            scale = float(np.clip(scale, 1e-6, 2.0 * spread))
        l_old, l_new = lo_, ln_
        lw0 = np.full(n, -np.log(n))
    if info is not None:
        info["log_evidence"] = float(log_z)
    return P, l_old, l_new, stages, acc
