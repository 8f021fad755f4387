"""Scaling Series (Petrovskaya, Handbook of Robotics ch. 42, Alg. 1), static and dynamic."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._util import as_rng, blas_threads, progress
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_bool, as_count, as_name, as_positive_float,
                         as_probability)
from ..errors import ValidationError
from ..models.proximity import ProximityModel
from ..models.symmetry import Symmetry, _qrot
from ._common import (ball_volume, check_contacts, check_dynamics, check_model, check_region, finite_loglik,
                      flag_degenerate, measurement, split_measurements)
from ._cover import BallCounter, draw_full, in_box, matrix_quats, quat_poses
from .particles import ParticleBelief, systematic_resample
from .region import PoseRegion

__all__ = ["ScalingSeries", "ScaleStep"]


@dataclass
class ScaleStep:
    """One iteration of Scaling Series: the particles at scale ``delta`` and temperature ``tau``."""

    index: int
    delta: float
    tau: float
    n_particles: int
    n_survivors: int
    belief: ParticleBelief
    seconds: float


#: Particles evaluated completely (or looked up completely, at a scale scored on the table)
#: whose best sum bounds the best particle's from above, for the prune's threshold.
_BOUND_PROBE = 32

#: The "auto" schedule's annealed posterior is no narrower than Alg. 1's at this many contacts.
ANNEAL_CONTACTS = 15

#: A near-sphere is searched as a sphere at scales at least this many times as wide as its
#: deviation from one (:meth:`ScalingSeries._near_sphere_for`).
NEAR_SPHERE_SCALES = 2.0
#: ... and at scales where one centre's rotations hold at most this many particles a ball
#: within the particle cap (:meth:`ScalingSeries._orbit_scale`).
NEAR_SPHERE_ORBIT = 1.0


def _anneal_gain(anneal, k: int) -> float:
    """The gain g of the temperature schedule tau = g (delta / delta*)^2 for k contacts
    (see :class:`ScalingSeries`, ``anneal``)."""
    if anneal == "auto":
        return max(1.0, k / ANNEAL_CONTACTS)
    if anneal == "contacts":
        return float(np.sqrt(k))
    if anneal == "alg1":
        return 1.0
    return float(anneal)


class ScalingSeries:
    """Scaling Series: anneal and refine broad particles down to a terminal scale.

    Parameters
    ----------
    model : MeasurementModel
    delta_final : float, optional
        Terminal neighbourhood radius delta* (pose metric, m) of Alg. 1. Default: twice
        the model's sigma_pos (or 4 mm). The temperature at scale delta is
        (delta / delta*)^2 times the gain of ``anneal``.
    m_per_delta : int
        Particles per delta-neighbourhood (M of Alg. 1).
    n_initial : int
        Floor on the particle count of the first cover of the region.
    max_particles : int
        Cap on the particles of one scale (bounds time when the belief is very spread).
        3000 by default: at 5 contacts the cap binds for about half of the scales, and
        most of the particles it lets through are pruned at once. On 126 held-out trials
        per contact count 3000 localised as often as 6000 (the earlier default; 116 at 5
        contacts, all at 10) in 0.59x / 0.82x the time at 5 / 10 contacts, with the truth
        in the 90 % credible region as often (76 and 73 of 84 trials, against 77 and 70)
        and the same median ADD-S; 20000, before, took twice the time of 6000 for no more
        (benchmarks/study_particle_cap.py; docs/benchmarks.md, "Scaling Series' particle
        cap"). At 30 contacts it seldom binds.
    max_draws : int, optional
        Cap on the candidates drawn per scale (default 8 x ``max_particles``, 24000 with
        the default cap). Beyond it each draw's centre is picked at random instead of in
        rounds over the centres. It is kept apart from the particle cap because a smaller
        draw budget loses modes: with 4 x 3000 a planar mug at 30 contacts ended with its
        handle turned away (36-469 nats below the truth's log-likelihood) in 4 of 12
        trials, with 24000 in none.
    min_particles : int
        Floor on the particles of every later scale's cover (at most ``max_particles``;
        reached within the scale's ``max_draws``). Alg. 1's cover keeps m particles per
        delta-ball of the union it covers; where the balls are about as wide as the region
        (the first scales, and a small region such as a 100 mm square with yaw) that is a
        handful of particles, 1-10, and which modes survive the next prunes rests on where
        those few fall. On a planar mug at 30 contacts the series then ended with its
        handle turned away (26-704 nats below the truth's log-likelihood) in 10 of 80 runs
        and 7 of 200 held-out ones; with a floor of 50 in none and 1, for 1.13x the time
        there (100: none in either, 1.5x). The floor draws more of the same even-density
        cover; it does not change what is covered (docs/localization.md).
    prune : {"threshold", "resample"}
        The Prune step of Alg. 1: every particle whose annealed weight is at least
        ``prune_ratio`` times the best ("threshold", default), or the distinct particles
        of a weighted resampling ("resample"; with few particles it keeps so few that
        true modes are lost more often, see docs/benchmarks.md).
    prune_ratio : float
    anneal : {"auto", "alg1", "contacts"} or float
        Temperature schedule tau = g (delta / delta*)^2, floored at 1 during the series;
        the final weights always use tau = 1. The annealed posterior's width shrinks as
        1 / sqrt(K) with K contacts, while the cover keeps m particles per delta-ball; once
        it is much narrower than the particles' spacing, the prune picks between modes
        by which one happens to have a particle near its peak, and can drop the true one.
        "auto" (default): g = max(1, K / 15), which keeps the annealed width at what it is
        for 15 contacts: Alg. 1 as written up to 15 contacts, wider beyond. With 30
        contacts Alg. 1's schedule ended on a pose whose likelihood was 5 nats or more
        below the truth's in 10 of 48 held-out 6-DOF trials and 7 of 60 planar ones (6 of
        12 on the mug, its handle turned away), and the truth was in the 90 % credible
        region in 67 % of the 6-DOF trials; "auto" in none and 1, with 90 % coverage, for
        about twice the time at 30 contacts (docs/benchmarks.md, "Scaling Series' annealing
        with many contacts"). "alg1": g = 1, the faster and less reliable choice beyond 15
        contacts. "contacts": g = sqrt(K), wider still from 2 contacts on. A number sets g
        directly.
    final_moves : int
        The posterior stage after the last scale (0: off, the belief is the weighted
        cover at delta*, as Alg. 1 ends). The weights at tau = 1 are the posterior only
        where the particles are dense compared with its width; with many contacts the
        posterior is far narrower than delta* and a weighted cover then puts nearly all
        its weight on the one or two particles nearest its peak, a few sigma away from
        it. So the final stage takes ``n_posterior`` particles of the last cover (an
        even-density sample of the region the series kept) and tempers the likelihood
        in from power 0 to 1 by resample-move SMC (:func:`touchloc.belief.smc.temper`:
        steps that keep half the effective sample size, at most ``final_stages`` of
        them, each followed by at least ``final_moves`` Metropolis moves whose
        stationary distribution is the tempered posterior, with a walk size that adapts
        to the acceptance, and more moves until each particle has moved about twice).
        The result is an equally weighted posterior sample;
        ``info["cover"]`` keeps the weighted cover at delta* (and ``info`` its
        evidence terms), ``info["map_pose"]`` the sample's pose of highest posterior.
    n_posterior : int
        Particles of the posterior sample.
    final_stages : int
        Cap on the tempering steps of the posterior stage.
    posterior_model : MeasurementModel, optional
        The likelihood of the posterior stage (default: ``model``). The search over
        scales needs a fast model; the posterior sample may want a more faithful one,
        such as an :class:`~touchloc.models.IntegratedProximityModel`, which then costs
        only the stage's few hundred particles. It must describe the same object.
    dynamics : GaussianDynamics, optional
        For the dynamic filter (initialize / predict / update).
    rho : float, optional
        Rotation scale of the pose metric (m); default: the object's radius.
    progress : bool, optional
        tqdm bar over the scales (default: when stderr is a terminal).
    symmetry : "auto", Symmetry or None
        A continuous symmetry of the object (a body of revolution, a sphere) makes every
        turn about it explain the contacts alike: the posterior is a whole orbit, and
        covering it particle by particle fills the cap at every scale. With a symmetry
        every particle is replaced by the one pose of its class without a turn about the
        axis (:meth:`~touchloc.models.symmetry.Symmetry.canonical`), so the search covers
        the poses that place the surface differently and nothing else. The belief then
        holds these representatives (``info["symmetry"]``); any member of a class is as
        good (symmetric errors such as ADD-S do not tell them apart). The search is used
        only when the region's rotation is ``"full"``. ``"auto"`` (default) uses
        ``model.obj.symmetries()`` when it is a sphere's: there it saves 50-80x; for a body
        of revolution the saved evaluations (a third to a half) were eaten by a denser
        cover at 5 contacts (docs/localization.md), so pass ``obj.symmetries()`` to ask
        for it. ``"auto"`` also searches a near-sphere (a lemon, 2.5 mm off a sphere) as a
        sphere at the scales at least twice as wide as its deviation, and every rotation
        from the first narrower scale on, so its belief holds full poses
        (``info["near_sphere_scales"]`` counts those scales; docs/localization.md,
        "Near-spheres"). None searches every pose at every scale. Evidence
        estimates (:func:`identify`) use None.
    bound_scales : float or None
        Intermediate scales whose delta is at least this many times the bound table's
        slack (:attr:`touchloc.models._bounds.CostBound.slack`, 10-15 mm on the bundled
        meshes at 2 mm / 5 deg) score their particles on the table's lower bounds alone,
        a lookup per pair, instead of nearest-face searches. A bound is the cost dilated by
        at most twice the slack (the smallest cost within that distance of the contact),
        so with the default 2 the dilation stays below the scale's own delta, the
        neighbourhood whose best likelihood the annealing stands in for. Only a
        :class:`~touchloc.models.ProximityModel` has the table; the last scale and the
        posterior stage are always exact. None scores every scale exactly. On the speed
        benchmark's 6-DOF trials this made 30 contacts 1.05-1.3x faster, with no
        search failure on development or held-out trials (docs/benchmarks.md, "Scaling
        Series' annealing with many contacts").
    bound_steps : int
        The scales scored on the table zoom by this many of Alg. 1's steps at a time: a
        delta-ball's volume shrinks by 2^bound_steps from one such scale to the next
        instead of by 2 (the scales below ``bound_scales`` slacks keep Alg. 1's single
        steps). There the particles see the cost dilated by up to twice the slack, no
        wider than delta, and the cover, not the scoring, is what each scale costs (about
        25 ms at the particle cap). With the default 2 the search drops half of those
        covers: on 648 development and held-out 6-DOF and planar trials no search failure
        with 1 or 2; the truth in the 90 % region in 265 and 254 of the 288 6-DOF trials
        (92 and 88 %) and in 300 and 303 of the 360 planar ones; CPU time 0.74-0.88x, and
        1.0-1.8x faster on the speed benchmark's trials with the same ones within 5 mm
        (docs/benchmarks.md, "Scaling Series' annealing with many contacts"). 1 is Alg. 1's
        schedule.
    rng : None, int or Generator
    """

    def __init__(self, model, *, delta_final: float | None = None, m_per_delta: int = 6,
                 n_initial: int = 2000, max_particles: int = 3000, max_draws: int | None = None,
                 min_particles: int = 50, prune: str = "threshold",
                 prune_ratio: float = 1e-3, anneal: str | float = "auto", final_moves: int = 3,
                 n_posterior: int = 500, final_stages: int = 60, posterior_model=None, dynamics=None,
                 rho: float | None = None, progress: bool | None = None, symmetry="auto",
                 bound_scales: float | None = 2.0, bound_steps: int = 2, rng=None):
        self.model = check_model(model)
        if not (symmetry is None or isinstance(symmetry, Symmetry) or (isinstance(symmetry, str)
                                                                       and symmetry == "auto")):
            raise ValidationError(f"symmetry must be 'auto', a Symmetry or None, got {symmetry!r}")
        self.symmetry = symmetry
        self.posterior_model = None if posterior_model is None else check_model(posterior_model)
        if self.posterior_model is not None and self.posterior_model.obj is not self.model.obj:
            raise ValidationError("posterior_model must describe the same MeshObject as model")
        delta_final = None if delta_final is None else as_positive_float(delta_final, "delta_final (m)")
        m_per_delta = as_count(m_per_delta, "m_per_delta", max=1000, why="each sub-step is one likelihood pass")
        n_initial = as_count(n_initial, "n_initial", max=MAX_PARTICLES, why=WHY_PARTICLES)
        max_particles = as_count(max_particles, "max_particles", max=MAX_PARTICLES, why=WHY_PARTICLES)
        min_particles = as_count(min_particles, "min_particles", max=MAX_PARTICLES, why=WHY_PARTICLES)
        max_draws = (min(8 * int(max_particles), MAX_PARTICLES) if max_draws is None
                     else as_count(max_draws, "max_draws", max=MAX_PARTICLES, why=WHY_PARTICLES))
        prune = as_name(prune, "prune", allow_none=False)
        prune_ratio = as_probability(prune_ratio, "prune_ratio", open_low=True, open_high=True)
        anneal = anneal if isinstance(anneal, str) else as_positive_float(anneal, "anneal gain")
        dynamics = check_dynamics(dynamics)
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        self.bound_scales = None if bound_scales is None else as_positive_float(bound_scales, "bound_scales")
        self.bound_steps = as_count(bound_steps, "bound_steps", min=1, max=16,
                                    why="each step halves a delta-ball's volume")
        progress = None if progress is None else as_bool(progress, "progress")
        sp = getattr(model, "sigma_pos", None)
        self.delta_final = float(delta_final) if delta_final else (2.0 * sp if sp else 0.004)
        if not (np.isfinite(self.delta_final) and self.delta_final > 0):
            raise ValidationError(f"delta_final must be > 0 (m), got {delta_final}")
        if int(m_per_delta) < 1 or int(max_particles) < 1 or int(n_initial) < 1:
            raise ValidationError("m_per_delta, n_initial and max_particles must be positive integers")
        if prune not in ("threshold", "resample"):
            raise ValidationError(f"prune must be 'threshold' or 'resample', got {prune!r}")
        if not 0 < prune_ratio < 1:
            raise ValidationError(f"prune_ratio must be in (0, 1), got {prune_ratio}")
        self.prune, self.prune_ratio = prune, float(prune_ratio)
        if isinstance(anneal, str) and anneal not in ("auto", "contacts", "alg1"):
            raise ValidationError(f"anneal must be 'auto', 'contacts', 'alg1' or a gain > 0, got {anneal!r}")
        if not isinstance(anneal, str) and not (np.isfinite(anneal) and anneal > 0):
            raise ValidationError(f"anneal gain must be > 0, got {anneal!r}")
        self.anneal = anneal
        self.final_moves = as_count(final_moves, "final_moves", min=0, max=1000,
                                    why="each move is one likelihood pass over the particles")
        self.n_posterior = as_count(n_posterior, "n_posterior", min=10, max=10_000_000,
                                    why="memory: 128 bytes a pose")
        self.final_stages = as_count(final_stages, "final_stages", min=1, max=1000,
                                     why="each stage is final_moves likelihood passes")
        self.m = int(m_per_delta)
        self.n_initial = int(n_initial)
        self.max_particles = int(max_particles)
        self.max_draws = int(max_draws)
        self.min_particles = int(min_particles)
        self._acceptance = None  # the last cover's acceptance rate (sizes the next one's batches)
        self.dynamics = dynamics
        self.rho = rho
        self.progress = progress
        self.rng = as_rng(rng)
        self.belief: ParticleBelief | None = None
        self._region: PoseRegion | None = None
        self._pending_predict = False

    # -- Alg. 1 building blocks -------------------------------------------------------
    def _symmetry_for(self, region: PoseRegion):
        """The continuous symmetry the search uses in ``region``, or None."""
        sym = self.symmetry
        if sym is None or region.rotation != "full":
            return None
        if isinstance(sym, str):
            obj = getattr(self.model, "obj", None)
            if callable(getattr(obj, "_sphere_symmetry", None)):
                return obj._sphere_symmetry()      # (the sphere's test alone)
            if obj is None or not callable(getattr(obj, "symmetries", None)):
                return None
            sym = obj.symmetries()
            return sym if sym.sphere else None
        return sym if sym.continuous else None

    def _canonical(self, region: PoseRegion, sym, X):
        """Canonical representatives of poses X that stay inside ``region``."""
        if sym is None:
            return X
        Y = sym._canonical_poses(X)
        inside = region.contains(Y)
        return Y[inside] if np.any(inside) else X

    #: near-spheres searched as spheres at the wide scales (False: never; for A/B studies)
    _NEAR_SPHERE = True

    def _near_sphere_for(self, region: PoseRegion):
        """The sphere's symmetry that a near-sphere is searched with at wide scales, or None.

        With ``symmetry="auto"``, full rotations and all three translations free, an object
        whose surface every rotation about its centroid moves by at most ``tol`` (its
        deviation from a sphere, ``MeshObject._near_sphere``) is searched as a sphere at
        the scales at least :data:`NEAR_SPHERE_SCALES` times ``tol`` wide: the position of
        its centre and no rotation. At those scales the best centre found with the
        identity rotation lies within about ``tol`` of the true one, inside the next
        scale's balls. The first narrower scale (the last scale at the latest) covers
        every rotation around the centres found (:meth:`_orbit_cover`), and it is never
        narrower than :meth:`_orbit_scale`, where those rotations still hold a particle a
        ball within the cap: a turn the contacts favour is then not missed. Used only
        where it saves: where a single centre's rotations, at twice ``tol``, would fill
        the particle cap at m a ball (a lemon, 12 % off a sphere, but not a box or a mug,
        whose rotations at twice their deviation take 40-150 balls).
        """
        if not (self._NEAR_SPHERE and isinstance(self.symmetry, str) and region.rotation == "full"
                and region.dim == 6):
            return None
        obj = getattr(self.model, "obj", None)
        if not callable(getattr(obj, "_near_sphere", None)):
            return None
        near = obj._near_sphere()
        orbit = self.m * 8.0 * np.pi**2 * region._rho() ** 3 / ball_volume(3, NEAR_SPHERE_SCALES * near.tol)
        return near if orbit >= self.max_particles else None

    def _orbit_scale(self, region: PoseRegion) -> float:
        """The delta at which one centre's rotations (SO(3), 8 pi^2 rho^3 in the pose
        metric) fill ``max_particles`` at :data:`NEAR_SPHERE_ORBIT` particles a ball: 0.18
        rho at the default cap."""
        per = NEAR_SPHERE_ORBIT / self.max_particles
        return float(region._rho() * (8.0 * np.pi**2 * per / ball_volume(3, 1.0)) ** (1.0 / 3.0))

    def _orbit_cover(self, region: PoseRegion, centers, delta_prev: float, delta: float, sym):
        """The cover of a scale after scales searched as a sphere's (``sym``): an even
        density on the poses whose surface centre ``sym.center`` lies within
        ``delta_prev`` of a centre's, at every rotation (the union of the balls around the
        centres' whole orbits), inside the region; m per delta-ball of its volume in the
        pose metric, from the floor up to m times the particle cap (one centre's orbit
        holds at most ``max_particles / NEAR_SPHERE_ORBIT`` balls here, see
        :meth:`_orbit_scale`; capped at ``max_particles`` like the other covers, these
        rotations were too sparse for the annealed posterior at 60 contacts, and a turn
        the contacts favour was lost). Returns poses and the volume.

        The surface centres are drawn uniformly on the union of their 3-D balls, from the
        union's bounding box (kept where a centre is within ``delta_prev``) or from the
        balls (kept with probability 1 / the balls holding the draw), whichever has the
        smaller volume to draw from; the rotations uniformly (Haar), and the translation
        keeps the drawn centre.
        """
        rng = self.rng
        c = sym.center
        P = centers[:, :3, :3] @ c + centers[:, :3, 3]      # the surface centres in the world
        n_c = len(P)
        tree = cKDTree(P)
        r = delta_prev * (1.0 + 1e-9)
        lo, hi = P.min(axis=0) - delta_prev, P.max(axis=0) + delta_prev
        v_box, v_balls = float(np.prod(hi - lo)), n_c * ball_volume(3, delta_prev)
        from_box = v_box <= v_balls
        v_rot = 8.0 * np.pi**2 * region._rho() ** 3        # SO(3) in the pose metric's measure
        box_c = np.asarray(region.center, dtype=np.float64)
        box_h = np.asarray(region.half_extent, dtype=np.float64)
        most = max(self._floor, int(np.ceil(self.m * self.max_particles / NEAR_SPHERE_ORBIT)))
        budget = max(self.max_draws, 4 * most)
        kept_q, kept_t, n_drawn, n_kept, target = [], [], 0, 0, self._floor
        volume = 0.0
        while n_drawn < budget:
            rate = n_kept / n_drawn if n_drawn else 0.5
            n = int(min(budget - n_drawn, max(1024, np.ceil(1.25 * (target - n_kept) / max(rate, 1e-3)))))
            if from_box:
                p = lo + (hi - lo) * rng.random((n, 3))
                ok = tree.query(p, distance_upper_bound=r)[0] <= r
            else:
                g = rng.normal(size=(n, 3))
                g /= np.linalg.norm(g, axis=1, keepdims=True)
                p = P[rng.integers(0, n_c, n)] + g * (delta_prev * rng.random(n) ** (1.0 / 3.0))[:, None]
                ok = rng.random(n) * np.maximum(tree.query_ball_point(p, r, return_length=True), 1) < 1.0
            q = rng.normal(size=(n, 4))
            q /= np.linalg.norm(q, axis=1, keepdims=True)
            q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
            t = p - _qrot(q, c)
            ok &= in_box(t, box_c, box_h)
            kept_q.append(q[ok])
            kept_t.append(t[ok])
            n_drawn, n_kept = n_drawn + n, n_kept + int(ok.sum())
            volume = (v_box if from_box else v_balls) * v_rot * n_kept / n_drawn
            target = int(np.clip(round(self.m * volume / ball_volume(region.dim, delta)), self._floor, most))
            if n_kept >= target:
                break
        self._acceptance = None  # not the rate of ball draws: the next scale measures its own
        if n_kept == 0:
            return centers.copy(), volume
        q, t = np.concatenate(kept_q), np.concatenate(kept_t)
        idx = np.arange(n_kept) if n_kept <= target else np.sort(rng.choice(n_kept, target, replace=False))
        return quat_poses(q, idx.astype(np.int64), t), volume

    def _even_density_cover(self, region: PoseRegion, centers, delta_prev: float, delta: float, sym=None):
        """Sample M particles per delta-neighbourhood of the union of delta_prev balls.

        Rejection sampling: draw from the ball of a random centre, keep a draw with
        probability 1 / (number of balls containing it), and keep draws inside the
        region. Returns poses and the estimated volume of the union.

        The draws for full rotations are made and embedded as quaternions (only the kept
        ones become matrices), and the ball counts compare each draw with the neighbours
        of its own centre only (:class:`touchloc.belief._cover.BallCounter`, set up once
        per scale). Where the particle cap binds, the draws come in batches that stop
        once the cap can be filled (:meth:`_next_batch`). The distribution is that of
        :meth:`_even_density_cover_reference`.

        Where the balls are at least half as wide as the region and hold at least half of
        it by a grid test (:class:`_CellCover`; the first scale after the uniform start),
        the region is drawn instead and each draw kept where it lies in the union
        (:meth:`_region_cover`).
        """
        dim = region.dim
        rng = self.rng
        if self._REGION_COVER and delta_prev >= 0.5 * region.radius():
            cells = _CellCover(region, centers, delta_prev)
            if cells.fraction >= 0.5:
                return self._region_cover(region, centers, delta_prev, delta, sym, cells)
        n_c = len(centers)
        pick, rounds = self._pick_centres(n_c, dim, delta_prev, delta)
        flip = 4 if region.rotation == "full" else 0
        counter, parts = None, []
        n_drawn = n_kept = 0
        start, ratio = 0, self.m * (delta_prev / delta) ** dim
        floor = self._floor
        while start < len(pick):
            stop = self._next_batch(start, len(pick), n_c if rounds else 1, n_drawn, n_kept, n_c * ratio)
            batch = pick[start:stop]
            draws = _Draws(region, centers, batch, delta_prev, rng, sym)
            if counter is None:
                counter = BallCounter(draws.centres_emb, delta_prev, flip_dims=flip,
                                      n_queries=int(np.count_nonzero(draws.inside)))
            keep = counter.accept(draws.emb, batch, rng, mask=draws.inside)
            parts.append((draws, np.flatnonzero(keep)))
            n_drawn, n_kept, start = n_drawn + len(batch), n_kept + len(parts[-1][1]), stop
            if n_kept >= self._target(n_c * ratio * n_kept / n_drawn):
                break
            if start >= len(pick) and n_kept < floor and n_drawn < self.max_draws:
                # fewer than the floor: more draws from centres picked at random (each draw
                # is still uniform on the union), as many as the acceptance so far asks for
                more = int(min(self.max_draws - n_drawn, 20 * floor,
                               np.ceil(1.25 * (floor - n_kept) * n_drawn / max(n_kept, 1))))
                pick = np.concatenate([pick, rng.integers(0, n_c, more)])
        self._acceptance = n_kept / n_drawn
        volume = n_c * ball_volume(dim, delta_prev) * n_kept / n_drawn
        if n_kept == 0:  # every draw fell outside the region: keep the centres
            return centers.copy(), volume
        # at most m per new ball of the kept draws, chosen uniformly among them
        n_target = self._target(n_c * ratio * n_kept / n_drawn)
        chosen = np.arange(n_kept)
        if n_kept > n_target:
            chosen = rng.choice(n_kept, n_target, replace=False)
        bounds = np.cumsum([0] + [len(i) for _, i in parts])
        out = []
        for (draws, idx), lo, hi in zip(parts, bounds[:-1], bounds[1:]):
            mine = chosen[(chosen >= lo) & (chosen < hi)] - lo
            if len(mine):
                out.append(draws.poses(idx[mine]))
        return np.concatenate(out), volume

    #: wide unions that hold most of the region are covered by :meth:`_region_cover`
    #: (False: the rejection sampler at every scale, as before; for A/B studies)
    _REGION_COVER = True

    def _region_cover(self, region: PoseRegion, centers, delta_prev: float, delta: float, sym, cells):
        """The even-density cover of a union of balls that holds most of the region: a
        uniform draw of the region, each pose kept when it lies in the union (at once in
        a covered cell of ``cells``, else where some centre is within ``delta_prev`` of it
        in the embedding the ball counts use), m per delta-ball of the union's volume
        (within the floor and the cap). Returns poses and the estimated volume.

        The rejection sampler of :meth:`_even_density_cover` draws from the balls and keeps
        a draw with probability 1 / (balls containing it), which is uniform on the union.
        Where the balls are about as wide as the region (the first scale, each draw in
        nearly every ball) it kept 3-5 of tens of thousands of draws, every one of them
        counted, so the floor (``min_particles``) was out of reach there. And with full
        rotations such balls are wider than pi rho: a draw's rotation vector wraps around,
        and the counts no longer undo the draw density, so that sampler thinned the
        union's far side (tests/test_belief_cover.py). Here at least half the draws are
        kept, and the particles are uniform on the union.
        """
        rng = self.rng
        tree, flip = None, region.rotation == "full"
        most = self._target(self.m * region._metric_volume() / ball_volume(region.dim, delta))
        kept, n_drawn, n_kept = [], 0, 0
        while True:
            n = min(max(256, int(np.ceil(1.25 * (most - n_kept)))), self.max_draws - n_drawn)
            X = self._canonical(region, sym, region.sample(n, rng=rng))
            c = cells.cells(X)
            ok = c >= 0
            ok[ok] = cells.covered[c[ok]]
            ask = np.flatnonzero(~ok & (c >= 0))
            if len(ask):
                if tree is None:
                    tree = cKDTree(region.embed(centers))
                r = delta_prev * 1.0000001
                d = tree.query(region.embed(X[ask]), distance_upper_bound=r)[0]
                if flip:
                    d = np.minimum(d, tree.query(region.embed_flipped(X[ask]), distance_upper_bound=r)[0])
                ok[ask] = d <= r
            kept.append(X[ok])
            n_drawn, n_kept = n_drawn + len(X), n_kept + int(ok.sum())
            volume = region._metric_volume() * n_kept / n_drawn
            target = self._target(self.m * volume / ball_volume(region.dim, delta))
            if n_kept >= target or n_drawn >= self.max_draws:
                break
        self._acceptance = None  # not the rate of ball draws: the next scale measures its own
        if n_kept == 0:  # (a draw budget of a handful, all outside the union): keep the centres
            return centers.copy(), volume
        X = np.concatenate(kept)
        if len(X) > target:
            X = X[rng.choice(len(X), target, replace=False)]
        return X, volume

    @property
    def _floor(self) -> int:
        """The fewest particles a later cover keeps: ``min_particles``, within the cap."""
        return min(self.min_particles, self.max_particles)

    def _target(self, balls: float) -> int:
        """Particles of a cover whose union is worth ``balls`` new balls: m per ball, capped
        at ``max_particles`` and floored at ``min_particles``."""
        return int(np.clip(round(balls), self._floor, self.max_particles))

    def _next_batch(self, start, total, stride, n_drawn, n_kept, m_balls):
        """End of the next batch of draws: all of them, unless the particle cap will bind.

        Where the cap binds (the kept draws would number ``m_balls`` times the acceptance
        rate, well above ``max_particles``), most draws would be thinned away unseen, so they
        are drawn in batches sized to fill the cap with a fifth to spare, at the acceptance
        rate measured so far in this scale (else at the previous scale's). The batches are
        whole rounds of the centres (``stride``), so each centre keeps its share of draws.
        """
        rate = n_kept / n_drawn if n_drawn else self._acceptance
        if rate is None or rate <= 0 or m_balls * rate <= 1.25 * self.max_particles:
            return total
        need = 1.2 * (self.max_particles - n_kept) / rate
        stop = start + int(np.ceil(max(need, 1.0) / stride)) * stride
        return total if stop >= 0.8 * total else stop

    def _pick_centres(self, n_c, dim, delta_prev, delta):
        """Which centre each draw comes from: m draws per new ball's share of the old one, in
        rounds over the centres (and whether they are rounds); beyond ``max_draws``
        draws, centres drawn at random instead."""
        per = max(1, int(np.ceil(self.m * (delta_prev / delta) ** dim)))
        total = min(n_c * per, self.max_draws)
        if total < n_c * per:
            return self.rng.integers(0, n_c, total), False
        return np.tile(np.arange(n_c), per), True

    def _thin(self, keep, n_c, dim, delta_prev, delta):
        """The reference cover's thinning: the union's volume from the acceptance rate, and
        at most m per new ball of the kept draws."""
        volume = n_c * ball_volume(dim, delta_prev) * keep.mean()
        n_target = self._target(self.m * volume / ball_volume(dim, delta))
        idx = np.flatnonzero(keep)
        if len(idx) == 0:
            return None, volume
        if len(idx) > n_target:
            idx = self.rng.choice(idx, n_target, replace=False)
        return idx, volume

    def _even_density_cover_reference(self, region: PoseRegion, centers, delta_prev: float, delta: float):
        """The cover as first written (one KD-tree query per candidate), kept as the
        reference that tests and benchmarks compare :meth:`_even_density_cover` with.

        Rejection sampling: draw from the ball of a random centre, keep a draw with
        probability 1 / (number of balls containing it), and keep draws inside the
        region. Returns poses and the estimated volume of the union.
        """
        dim = region.dim
        rng = self.rng
        n_c = len(centers)
        pick, _ = self._pick_centres(n_c, dim, delta_prev, delta)
        cand = region.perturb(centers[pick], delta_prev, rng=rng, ball=True)
        inside = region.contains(cand)
        emb_c = region.embed(centers)
        tree = cKDTree(emb_c)
        emb = region.embed(cand)
        count = tree.query_ball_point(emb, r=delta_prev * 1.0000001, return_length=True)
        flip = region.embed_flipped(cand)
        if flip is not None:
            count = count + tree.query_ball_point(flip, r=delta_prev * 1.0000001, return_length=True)
        count = np.maximum(count, 1)
        keep = inside & (rng.random(len(cand)) < 1.0 / count)
        idx, volume = self._thin(keep, n_c, dim, delta_prev, delta)
        if idx is None:  # every draw fell outside the region: keep the centres
            return centers.copy(), volume
        return cand[idx], volume

    def _annealed_loglik(self, X, contacts, tau: float, prune: bool = True, delta: float = 0.0):
        """log p(contacts | X) / tau for one scale of radius ``delta``. With ``prune``
        (intermediate scales), a particle's contacts are evaluated only until the threshold
        prune is sure to drop it whatever its other contacts say; at intermediate scales at
        least ``bound_scales`` times as wide as the bound table's slack the costs are the
        table's bounds alone (see ``bound_scales``).

        Costs are non-negative, so a particle whose cost is sure to exceed the full cost
        of the best particle by 2 tau log(1 / prune_ratio) is pruned. Every pair first
        gets a lower bound from the model's table (:mod:`touchloc.models._bounds`, a lookup
        each); the 32 particles best by their bounds, evaluated completely, bound the best
        cost from above. Every particle then gets its contacts one at a time and stops as
        soon as its costs so far plus the bounds of its remaining contacts reach that
        threshold (at once, when the bounds alone do); each nearest-face search stops as
        soon as no face can be within what the budget leaves it. At scales narrower than
        the table's slack the bounds are nearly all 0 and are skipped: 32 particles spread
        over the batch bound the best cost, and a particle stops on its costs alone. At the
        scales scored on the table alone, the best bound sum of 32 particles spread over
        the batch sets the threshold, and each particle's lookups stop once their sum
        reaches it. The prune keeps exactly the particles it keeps on complete evaluations,
        with the same weights; the dropped ones get a value above the threshold and below
        their full value.
        """
        model = self.model
        K, N = len(contacts), len(X)
        if not _plain_proximity(model):
            return finite_loglik(model.log_likelihood(X, contacts, temperature=tau))
        # the particles are this estimator's own (4, 4) rigid poses: no re-validation
        if prune and self.bound_scales is not None and delta >= self.bound_scales * model._bound_slack(contacts):
            if self.prune != "threshold" or N < 2 * _BOUND_PROBE:
                return finite_loglik(-0.5 * model._lower_costs(X, contacts).sum(axis=1) / tau)
            # the bounds' sums of an even subsample bound the best sum from above; each
            # particle then takes its contacts, those with the subsample's largest bounds
            # first, until its sum is sure to be pruned
            probe = model._lower_costs(X[:: N // _BOUND_PROBE][:_BOUND_PROBE], contacts)
            limit = float(probe.sum(axis=1).min()) + 2.0 * tau * np.log(1.0 / self.prune_ratio)
            limit += 1e-9 * (1.0 + limit)
            order = np.argsort(-probe.mean(axis=0), kind="stable")
            return finite_loglik(-0.5 * model._lower_costs(X, contacts, limit, order).sum(axis=1) / tau)
        method = self._method(model, contacts)
        costs = model._budget_costs
        if not prune or self.prune != "threshold" or N < 2 * _BOUND_PROBE:
            return finite_loglik(-0.5 * costs(X, contacts, method)[0].sum(axis=1) / tau)
        # lower bounds of every pair from a table (a lookup each): the particles best by
        # them, evaluated completely, bound the best cost from above (32 spread over the
        # batch where the bounds are skipped)
        if delta < model._bound_slack(contacts):
            # a bound is the cost dilated by up to twice the slack: at a scale narrower than
            # the slack the particles' contacts lie within it of the surface, and their bounds
            # are nearly all 0 (they would stop next to no particle)
            lower = None
            best = np.arange(0, N, N // _BOUND_PROBE)[:_BOUND_PROBE]
        else:
            lower = model._lower_costs(X, contacts)
            best = np.argsort(lower.sum(axis=1))[:_BOUND_PROBE]
        upper = float(np.min(costs(X[best], contacts, method)[0].sum(axis=1)))
        limit = upper + 2.0 * tau * np.log(1.0 / self.prune_ratio)
        # a stopped particle's value reaches the limit: with this margin, a value strictly
        # above the threshold (beyond rounding) and still below its full cost
        limit += 1e-9 * (1.0 + limit)
        cost, _ = costs(X, contacts, method, budget=np.full(N, limit), lower=lower)
        return finite_loglik(-0.5 * cost.sum(axis=1) / tau)

    def _method(self, model, contacts) -> str:
        """The likelihood method of every call of a run: ``auto`` resolved once, as one
        call over the largest batch the run may score would choose it (a scale of
        ``max_particles`` or the first cover, times the contacts). The first scale builds
        the model's grid, so the run's small batches (the last scales of a narrow belief, a
        symmetric object's few representatives) use it too; on the tree they cost 5-20
        times as much per pair (docs/benchmarks.md, "Localisation speed"). A grid that
        failed its check (a large sigma_pos) leaves ``exact``."""
        return model._resolve(model.method, max(self.n_initial, self.max_particles) * len(contacts),
                              model._weight(model._uses_normals(contacts)))

    def _prune(self, poses, log_w):
        """Drop low-probability regions: "resample" keeps the distinct particles of a
        weighted resampling; "threshold" keeps every particle whose weight is at least
        ``prune_ratio`` times the largest."""
        if self.prune == "threshold":
            return poses[log_w >= log_w.max() + np.log(self.prune_ratio)]
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        idx = np.unique(systematic_resample(w, len(w), self.rng))
        return poses[idx]

    # -- final stage: from a cover to a posterior sample ---------------------------------
    def _posterior(self, cover: ParticleBelief, contacts, region: PoseRegion, log_prior, sym=None) -> ParticleBelief:
        """The posterior stage after the last scale (see ``final_moves``)."""
        from .smc import temper

        X = cover.poses
        # the cover is an even-density sample of its support: a uniform subsample of it
        # stands for the prior restricted to the support
        idx = self.rng.choice(len(X), self.n_posterior, replace=len(X) < self.n_posterior)
        P = X[idx]

        model = self.posterior_model or self.model
        new_above = None
        if _plain_proximity(model):
            # the moves' proposals are this estimator's own rigid poses: no re-validation
            method = self._method(model, contacts)

            def new(Q):
                return finite_loglik(-0.5 * model._contact_costs(Q, contacts, method).sum(axis=1))

            # a cover smaller than the sample is drawn with repeats: each distinct pose is
            # scored once
            u, back = np.unique(idx, return_inverse=True)
            l_first = finite_loglik(-0.5 * model._contact_costs(X[u], contacts, method).sum(axis=1))[back]

            def new_above(Q, t):
                # log-likelihood -cost / 2 above t: a cost below -2 t, so a pose stops once its
                # costs reach that, and is then sure to be rejected (-inf)
                cost, done = model._budget_costs(Q, contacts, method, budget=np.clip(-2.0 * t, 0.0, np.inf))
                out = np.full(len(Q), -np.inf)
                if done.any():
                    out[done] = finite_loglik(-0.5 * cost[done].sum(axis=1))
                return out
        else:
            def new(Q):
                return finite_loglik(model.log_likelihood(Q, contacts))
            l_first = new(P)
        l_old = log_prior(P) if log_prior is not None else np.zeros(len(P))
        P, l_old, l_new, stages, acc = temper(P, l_old, l_old, l_first, log_prior, new, region,
                                              moves=self.final_moves, max_stages=self.final_stages, rng=self.rng,
                                              new_above=new_above)
        if sym is not None:
            # the moves wander along the symmetry, where the likelihood is flat: back to the
            # representatives (the same surfaces, so the same likelihoods)
            P = sym._canonical_poses(P)
        out = ParticleBelief(P, None, region=region, resolution=cover.resolution, info=dict(cover.info),
                             degenerate=cover.degenerate)
        out.info.update(cover=cover, map_pose=P[int(np.argmax(l_old + l_new))].copy(), final_stages=stages,
                        final_acceptance=float(np.mean(acc)) if acc else float("nan"), final_move_count=len(acc))
        return out

    # -- static ------------------------------------------------------------------------
    @blas_threads
    def iterate(self, contacts, region: PoseRegion, *, centers=None, delta0: float | None = None,
                log_prior=None):
        """Run Alg. 1 one scale at a time, yielding a :class:`ScaleStep` per scale.

        The last step (``tau == 1``) holds the final belief. ``centers``/``delta0``
        start from the union of balls around given poses instead of the whole region;
        ``log_prior(poses) -> (N,)`` multiplies the final weights by a prior.
        """
        contacts = check_contacts(contacts)
        region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        dim = region.dim
        if dim == 0:
            raise ValidationError("the region has no free degree of freedom")
        d_star = self.delta_final
        sym = self._symmetry_for(region)
        # a near-sphere is searched as a sphere at the wide scales (global searches only)
        near = self._near_sphere_for(region) if sym is None and centers is None else None
        as_sphere = np.inf if near is None else max(NEAR_SPHERE_SCALES * near.tol, self._orbit_scale(region))

        def sym_at(d, last):
            return near if (near is not None and not last and d >= as_sphere) else sym

        if centers is None:
            delta0 = region.radius()
            n0 = max(self.n_initial, int(self.m * 2))
            sym_prev = sym_at(delta0, False)
            X = self._canonical(region, sym_prev, region.sample(n0, rng=self.rng))
            first = True
            volume = region.volume()
        else:
            X = np.asarray(centers, dtype=float)
            delta0 = float(delta0)
            first = False
            volume = np.nan
            sym_prev = sym
        zoom = 2.0 ** (-1.0 / dim)
        self._acceptance = None
        n_scales = max(0, int(np.floor(dim * np.log2(max(delta0, d_star) / d_star))))
        deltas, d = [], delta0
        for _ in range(n_scales):
            d = zoom * d
            deltas.append(d)
        if self.bound_steps > 1 and self.bound_scales is not None and _plain_proximity(self.model):
            # the scales scored on the table: every bound_steps-th of Alg. 1's
            wide = self.bound_scales * self.model._bound_slack(contacts)
            deltas = [d for i, d in enumerate(deltas) if d < wide or i % self.bound_steps == 0]
            n_scales = len(deltas)
        delta = delta0
        n_near = 0
        steps = progress(range(n_scales + 1), total=n_scales + 1, desc="scaling series", enabled=self.progress)
        for n in steps:
            t0 = time.perf_counter()
            last = n == n_scales
            if last:
                new_delta, tau = d_star, 1.0
            else:
                new_delta = deltas[n]
                gain = _anneal_gain(self.anneal, len(contacts))
                tau = max(gain * (new_delta / d_star) ** 2, 1.0)
            sym_n = sym_at(new_delta, last)
            if first:
                first = False  # the initial uniform draw is the cover of V0
            elif sym_prev is near and sym_n is not near:
                X, volume = self._orbit_cover(region, X, delta, new_delta, near)
            else:
                X, volume = self._even_density_cover(region, X, delta, new_delta, sym_n)
            sym_prev = sym_n
            n_near += near is not None and sym_n is near
            ll = self._annealed_loglik(X, contacts, tau, prune=not last, delta=new_delta)
            lw = ll.copy()
            if last and log_prior is not None:
                lw = lw + log_prior(X)
            belief = ParticleBelief._trusted(X, lw, region=region, resolution=float(new_delta))
            n_part = len(X)
            if last:
                # the final cover's volume (metric units): each particle stands for volume / N,
                # which turns the weights into an evidence estimate (see belief.identify)
                belief.info.update(delta_final=d_star, n_scales=n_scales, cover_volume=float(volume),
                                   log_likelihood=ll, near_sphere_scales=n_near)
                flag_degenerate(belief, float(ll.max()), contacts)
                if self.final_moves > 0:
                    belief = self._posterior(belief, contacts, region, log_prior, sym)
                belief.info["symmetry"] = None if sym is None else ("sphere" if sym.sphere else "axis")
                yield ScaleStep(n, new_delta, tau, n_part, n_part, belief, time.perf_counter() - t0)
                return
            X = self._prune(X, lw)
            delta = new_delta
            yield ScaleStep(n, new_delta, tau, n_part, len(X), belief, time.perf_counter() - t0)

    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        """Static localisation with a uniform prior over ``region`` (Alg. 1).

        Returns
        -------
        ParticleBelief
            Weighted particles; ``info`` holds per-scale particle counts and timings.
        """
        t0 = time.perf_counter()
        history = []
        step = None
        for step in self.iterate(contacts, region):
            history.append((step.delta, step.tau, step.n_particles, step.n_survivors))
        belief = step.belief
        belief.info.update(scales=history, seconds=time.perf_counter() - t0,
                           evaluations=int(sum(h[2] for h in history)))
        return belief

    # -- dynamic -------------------------------------------------------------------------
    def initialize(self, region: PoseRegion) -> None:
        """Start the dynamic filter with a uniform belief over ``region``."""
        self._region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        self.belief = None
        self._pending_predict = False
        self._misses = []

    def predict(self) -> None:
        """Apply the dynamics at the next update (the prior becomes sum_m w_m p(X | X_m))."""
        if self._region is None:
            raise ValidationError("call initialize(region) first")
        if self.dynamics is None:
            raise ValidationError("predict() needs dynamics=GaussianDynamics(...)")
        if self.belief is not None:
            self._pending_predict = True

    @blas_threads
    def update(self, contacts, *, free_space=None) -> ParticleBelief:
        """Measurement update: Scaling Series on the support of the predicted prior, weights
        multiplied by the prior propagated from the previous particle set (ch. 42.1.4).

        ``contacts`` is a :class:`~touchloc.models.Contacts` or the executed touches of an
        action (their contacts and swept free space, see ``belief._common.measurement``).
        Touches that miss before the first contact weight a sample of the region (so the
        belief is defined for planning) and join the first contact's localisation.
        """
        if self._region is None:
            raise ValidationError("call initialize(region) first")
        _, results = split_measurements(contacts)
        if self._misses or (results and self.belief is None):
            # nothing localised yet: every touch so far is scored over the whole region
            pending = self._misses + results
            found, model = measurement(self.model, pending, free_space=free_space)
            if not results:  # plain contacts after misses
                found, model = check_contacts(contacts), self.model + model
            contacts = found
            if contacts is None:
                self._misses = pending
                X = self._region.sample(self.n_initial, rng=self.rng)
                res = (self._region.volume() / len(X)) ** (1.0 / self._region.dim)
                self.belief = ParticleBelief(X, finite_loglik(model.log_likelihood(X)), region=self._region,
                                             resolution=res)
                return self.belief
            self._misses, self.belief = [], None
        else:
            contacts, model = measurement(self.model, contacts, free_space=free_space)
        if contacts is None:  # a miss after localisation: reweight the particles
            self.belief = self.belief.reweighted(finite_loglik(model.log_likelihood(self.belief.poses)))
            return self.belief
        own, self.model = self.model, model
        try:
            return self._update(contacts)
        finally:
            self.model = own

    def _update(self, contacts) -> ParticleBelief:
        prev = self.belief
        if prev is None:
            self.belief = self.localize(contacts, self._region)
            return self.belief
        reg = self._region
        spread = 0.0
        if self._pending_predict:
            spread = 3.0 * np.hypot(self.dynamics.sigma_met, reg.rho * self.dynamics.sigma_ang)
        # start from the previous particles' neighbourhoods, grown by the motion
        keep = prev.credible_set(0.999)
        centers = prev.poses[keep]
        delta0 = (prev.resolution or self.delta_final) + spread
        if self._pending_predict:
            pp, plw = prev.poses[keep], prev.log_weights[keep]

            def log_prior(X):
                return self.dynamics.log_prior(X, pp, plw)
        else:
            log_prior = _kernel_prior(reg, prev.poses[keep], prev.log_weights[keep], delta0)
        step = None
        for step in self.iterate(contacts, reg, centers=centers, delta0=delta0, log_prior=log_prior):
            pass
        self.belief = step.belief
        self._pending_predict = False
        return self.belief


def _plain_proximity(model) -> bool:
    """A :class:`ProximityModel` whose likelihood is the class's own (not overridden): its
    costs can then be evaluated through the unvalidated, budgeted kernel pass."""
    return (isinstance(model, ProximityModel) and type(model).log_likelihood is ProximityModel.log_likelihood
            and type(model).contact_costs is ProximityModel.contact_costs)


class _CellCover:
    """The cells of a grid over a region that lie wholly inside a union of metric balls.

    Each free translation axis of the region, and a yaw range, is cut into ``parts``
    equal cells. A ball around a pose in cell A holds cell B whole when the largest
    distance between their points, summed over the axes in the pose metric, is at most
    r^2 less what the rotation may need ((pi rho)^2 for full rotations: any two rotations
    are at most pi apart). A cell is covered when a cell that holds a centre holds it so:
    a sufficient test, in the metric the balls are drawn in (:meth:`PoseRegion.perturb`).
    """

    def __init__(self, region: PoseRegion, centers, r: float, parts: int = 6):
        self.region, self.parts = region, parts
        free = region.free_translation
        size = 2.0 * np.asarray(region.half_extent, dtype=float)[free] / parts
        reach2 = r * r
        if region.rotation == "full":
            reach2 -= (np.pi * region._rho()) ** 2
        elif region.rotation == "yaw":
            size = np.append(size, region.yaw_span * region._rho() / parts)
        self.k = k = len(size)
        self.covered = np.zeros(parts**k, dtype=bool)
        # (a ball that cannot hold even its own centre's cell covers nothing)
        if len(centers) == 0 or reach2 < float(np.sum(size**2)):
            return
        occupied = np.unique(self.cells(np.asarray(centers)))
        occupied = occupied[occupied >= 0]
        if len(occupied) == 0:
            return
        # the least farthest-point distance^2 from each cell to an occupied one: a sum of one
        # term per axis, so its minimum is taken one axis at a time (as a distance transform)
        D = np.full(parts**k, np.inf)
        D[occupied] = 0.0
        D = D.reshape((parts,) * k, order="F")   # D[i0, i1, ...] is the cell of code sum(i_a parts^a)
        g = np.arange(parts)
        for a in range(k):
            gap = np.abs(g[:, None] - g[None, :])
            if a == k - 1 and region.rotation == "yaw" and region.periodic_yaw:
                gap = np.minimum(gap, parts - gap)
            step = ((gap + 1) * size[a]) ** 2                # (to, from)
            D = np.moveaxis(np.min(np.moveaxis(D, a, -1)[..., None, :] + step, axis=-1), -1, a)
        self.covered = D.reshape(-1, order="F") <= reach2

    @property
    def fraction(self) -> float:
        """The share of the region's volume in covered cells."""
        return float(self.covered.mean())

    def cells(self, P) -> np.ndarray:
        """(N,) the grid cell of each pose of the region (-1: outside it)."""
        region, parts = self.region, self.parts
        free = region.free_translation
        inside = region._contains(P)   # (the series' own rigid poses: no re-validation)
        lo = (region.center - region.half_extent)[free]
        x = (P[:, :3, 3][:, free] - lo) / (2.0 * region.half_extent[free]) * parts
        if region.rotation == "yaw":
            y0, y1 = region.yaw_range
            x = np.column_stack([x, (region.yaw_of(P) - y0) / (y1 - y0) * parts])
        idx = np.clip(np.floor(x), 0, parts - 1).astype(np.int64) @ (parts ** np.arange(self.k, dtype=np.int64))
        return np.where(inside, idx, -1)


class _Draws:
    """Candidates of the cover: uniform in the metric ball of radius ``r`` around
    ``centers[pick]`` (as :meth:`PoseRegion.perturb`), with their embedding
    (:meth:`PoseRegion.embed`) and region membership.

    Full rotations are handled as quaternions (composition ``exp(w) q``), so that only
    the candidates finally kept are turned into (4, 4) matrices.
    """

    def __init__(self, region: PoseRegion, centers, pick, r: float, rng, sym=None):
        self.region = region
        if region.rotation != "full":
            self._poses = region.perturb(centers[pick], r, rng=rng, ball=True)
            self.inside = region.contains(self._poses)
            self.centres_emb = region.embed(centers)
            self.emb = region.embed(self._poses)
            return
        n, d = len(pick), region.dim
        free = region.free_translation
        g = rng.normal(size=(n, d))
        u = rng.random(n)
        rho = region._rho()
        qc = matrix_quats(np.ascontiguousarray(centers[:, :3, :3]))
        qc *= np.where(qc[:, 3:] < 0, -1.0, 1.0)
        # one compiled pass: the draws, their quaternions and their embedding
        t, q, emb = draw_full(g, u, qc, np.ascontiguousarray(centers[:, :3, 3]), np.asarray(pick, dtype=np.int64),
                              np.flatnonzero(free).astype(np.int64), float(r), float(rho))
        if sym is not None:
            q, t = sym._canonical(q, t)
            emb = np.concatenate([t[:, free], 2.0 * rho * q], axis=1)
        self._t, self._q = t, q
        self.inside = in_box(t, np.asarray(region.center, dtype=np.float64),
                             np.asarray(region.half_extent, dtype=np.float64))
        self.centres_emb = np.concatenate([centers[:, :3, 3][:, free], 2.0 * rho * qc], axis=1)
        self.emb = emb

    def poses(self, idx) -> np.ndarray:
        """(len(idx), 4, 4) poses of the chosen candidates."""
        if self.region.rotation != "full":
            return self._poses[idx]
        return quat_poses(self._q, np.asarray(idx, dtype=np.int64).reshape(-1), self._t)


def _kernel_prior(region, poses, log_w, delta):
    """Without motion, the prior is the previous belief: a sum of delta-balls."""
    from scipy.special import logsumexp

    emb_p = region.embed(poses)

    def log_prior(X):
        e = region.embed(X)
        d2 = np.sum((e[:, None, :] - emb_p[None, :, :]) ** 2, axis=2)
        f = region.embed_flipped(X)
        if f is not None:
            d2 = np.minimum(d2, np.sum((f[:, None, :] - emb_p[None, :, :]) ** 2, axis=2))
        return logsumexp(-0.5 * d2 / (delta / 2) ** 2 + log_w[None, :], axis=1)

    return log_prior
