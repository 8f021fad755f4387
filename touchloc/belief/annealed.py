"""Annealed particle filter and manifold particle filter (ch. 42.1.4, "Other advanced methods")."""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from .._util import as_rng, blas_threads
from .._validate import (MAX_PARTICLES, WHY_PARTICLES, as_count, as_nonnegative_float, as_positive_float,
                         as_probability)
from ..errors import ValidationError
from ..geometry import make_poses
from ._common import check_contacts, check_model, check_region, finite_loglik, flag_degenerate
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["AnnealedParticleFilter", "ManifoldParticleFilter"]


def _ess_frac(dl):
    w = np.exp(dl - dl.max())
    return (w.sum() ** 2) / (len(w) * (w**2).sum())


class AnnealedParticleFilter:
    """Annealed particle filter (Deutscher et al.): a constant number of particles, layers
    of weighting by L^beta, resampling and diffusion; each layer's beta is chosen so that
    the survival rate (ESS / N) equals ``survival``.

    Parameters
    ----------
    model : MeasurementModel
    n_particles : int
    survival : float
        Target survival rate per layer (0..1); Deutscher uses 0.5.
    max_layers : int
        Upper bound on layers; the last one jumps to beta = 1.
    diffusion : float
        Diffusion standard deviation, as a fraction of the current particle spread.
    """

    def __init__(self, model, n_particles: int = 5000, *, survival: float = 0.5, max_layers: int = 40,
                 diffusion: float = 0.5, rho: float | None = None, rng=None):
        self.model = check_model(model)
        n_particles = as_count(n_particles, "n_particles", max=MAX_PARTICLES, why=WHY_PARTICLES)
        survival = as_probability(survival, "survival", open_low=True, open_high=True)
        max_layers = as_count(max_layers, "max_layers", max=10_000, why="each layer is one likelihood pass")
        diffusion = as_nonnegative_float(diffusion, "diffusion")
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        self.n_particles = int(n_particles)
        self.survival = float(survival)
        self.max_layers = int(max_layers)
        self.diffusion = float(diffusion)
        self.rho = rho
        self.rng = as_rng(rng)

    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        t0 = time.perf_counter()
        contacts = check_contacts(contacts)
        region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        X = region.sample(self.n_particles, rng=self.rng)
        ll = finite_loglik(self.model.log_likelihood(X, contacts))
        beta = 0.0
        betas = []
        for layer in range(self.max_layers):
            # bisection for the increment whose incremental weights keep `survival` alive
            lo, hi = 0.0, 1.0 - beta
            if layer == self.max_layers - 1 or _ess_frac(hi * ll) >= self.survival:
                inc = hi
            else:
                for _ in range(40):
                    mid = 0.5 * (lo + hi)
                    if _ess_frac(mid * ll) >= self.survival:
                        lo = mid
                    else:
                        hi = mid
                inc = max(lo, 1e-12)
            beta = min(1.0, beta + inc)
            betas.append(beta)
            b = ParticleBelief(X, inc * ll, region=region)
            if beta >= 1.0:
                break
            # resample, then diffuse with a spread that shrinks with the particle cloud
            sd = np.sqrt(np.clip(np.diag(b.covariance()), 0, None)).mean()
            r = b.resample(rng=self.rng)
            X = region.perturb(r.poses, self.diffusion * sd * self.survival ** 0.5, rng=self.rng, ball=False)
            X = np.where(region.contains(X)[:, None, None], X, r.poses)
            ll = finite_loglik(self.model.log_likelihood(X, contacts))
        sd = np.sqrt(np.clip(np.diag(b.covariance()), 0, None)).mean()
        b.resolution = max(sd * len(b) ** (-1.0 / region.dim), 1e-6)
        b.info.update(betas=betas, layers=len(betas), seconds=time.perf_counter() - t0)
        flag_degenerate(b, float(ll[np.argmax(b.log_weights)]), contacts)
        return b


class ManifoldParticleFilter:
    """Particles drawn from the contact manifold (Koval et al.; ch. 42.1.4).

    Each particle puts one measured contact exactly on the surface: pick a contact
    (p, n) and a surface point (o, n_o), choose the rotation that turns n_o onto n
    (with a random twist about n; any rotation when the contact has no normal), and
    set the translation so that o lands on p. Particles outside the region are
    dropped; the rest are weighted by the likelihood of all contacts. For regions
    with constrained rotation (yaw, fixed) the rotation is drawn from the region and
    the surface point is chosen among those whose rotated normal agrees with n.

    The weights ignore the proposal density over the manifold (as the method does):
    the belief is an approximation suited to seeding other estimators (e.g. MCMC).
    """

    def __init__(self, model, n_particles: int = 5000, *, rho: float | None = None, rng=None,
                 max_rounds: int = 20):
        self.model = check_model(model)
        n_particles = as_count(n_particles, "n_particles", max=MAX_PARTICLES, why=WHY_PARTICLES)
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        max_rounds = as_count(max_rounds, "max_rounds", max=10_000, why="each round is one likelihood pass")
        self.n_particles = int(n_particles)
        self.rho = rho
        self.rng = as_rng(rng)
        self.max_rounds = int(max_rounds)

    def _propose(self, contacts, region, n):
        rng = self.rng
        obj = self.model.obj
        k = rng.integers(0, len(contacts), n)
        p = contacts.points[k]
        o, no, _ = obj.sample_surface(n, rng=rng)
        if region.rotation == "full" and contacts.has_normals:
            nk = contacts.normals[k]
            # R0 turns n_o onto n_k; then twist about n_k by a uniform angle
            R0 = _align(no, nk)
            tw = Rotation.from_rotvec(nk * rng.uniform(-np.pi, np.pi, n)[:, None]).as_matrix()
            R = tw @ R0
        else:
            R = region._sample_rotations(n, rng)
            if contacts.has_normals:
                # re-choose each surface point among candidates by normal agreement
                cand_o, cand_n, _ = obj.sample_surface(n * 8, rng=rng)
                cand_o = cand_o.reshape(n, 8, 3)
                cand_n = cand_n.reshape(n, 8, 3)
                world_n = np.einsum("nij,nkj->nki", R, cand_n)
                score = np.einsum("nkj,nj->nk", world_n, contacts.normals[k])
                j = np.argmax(score, axis=1)
                o = cand_o[np.arange(n), j]
        t = p - np.einsum("nij,nj->ni", R, o)
        fixed = ~region.free_translation
        t[:, fixed] = region.center[fixed]
        return make_poses(R, t)

    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        t0 = time.perf_counter()
        contacts = check_contacts(contacts)
        region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        kept = []
        total = 0
        for _ in range(self.max_rounds):
            X = self._propose(contacts, region, self.n_particles)
            X = X[region.contains(X)]
            kept.append(X)
            total += len(X)
            if total >= self.n_particles:
                break
        X = np.concatenate(kept)[: self.n_particles]
        if len(X) == 0:
            from ..errors import BeliefDegenerateError

            raise BeliefDegenerateError("no pose on the contact manifold lies in the region")
        ll = finite_loglik(self.model.log_likelihood(X, contacts))
        b = ParticleBelief(X, ll, region=region)
        b.resolution = max(np.sqrt(np.clip(np.diag(b.covariance()), 0, None)).mean() * len(b) ** (-1.0 / region.dim), 1e-6)
        b.info["seconds"] = time.perf_counter() - t0
        flag_degenerate(b, float(ll.max()), contacts)
        return b


def _align(a, b):
    """(N, 3, 3) rotations taking unit vectors a onto unit vectors b (shortest arc)."""
    v = np.cross(a, b)
    c = np.einsum("ij,ij->i", a, b)
    s = np.linalg.norm(v, axis=1)
    axis = np.where(s[:, None] > 1e-9, v / np.maximum(s, 1e-12)[:, None], _perp(a))
    ang = np.arctan2(s, c)
    return Rotation.from_rotvec(axis * ang[:, None]).as_matrix()


def _perp(a):
    x = np.where(np.abs(a[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    p = np.cross(a, x)
    return p / np.linalg.norm(p, axis=1)[:, None]
