"""ShapeMap: the probabilistic shape of one static object, built from guarded touches."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import trimesh

from .._util import as_points, blas_threads
from .._validate import as_bool, as_count, as_float, as_path
from ..errors import MappingError, ValidationError
from .gpis import GPIS, bound_site
from .occupancy import OccupancyGrid

__all__ = ["ShapeMap", "as_bounds", "sphere_prior"]

METHODS = ("gpis", "occupancy")


def as_bounds(bounds) -> tuple:
    """Validate ``(lo (3,), hi (3,))`` in metres with lo < hi on every axis."""
    try:
        lo, hi = bounds
        lo = np.asarray(lo, dtype=float).reshape(-1)
        hi = np.asarray(hi, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValidationError(f"bounds must be (lo (3,), hi (3,)) in metres, got {bounds!r}") from None
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValidationError(f"bounds must be two finite 3-vectors (lo, hi), got {bounds!r}")
    if np.any(hi <= lo):
        raise ValidationError(f"bounds need lo < hi on every axis, got lo={lo.tolist()} hi={hi.tolist()}")
    if np.any(hi - lo > 10.0):
        raise ValidationError(f"bounds span {np.round(hi - lo, 3).tolist()} m: is the box in metres?")
    return lo, hi


def sphere_prior(center, radius):
    """Prior mean m(x) = |x - center| - radius (a signed distance) and its gradient."""
    c = np.asarray(center, float).reshape(3)
    r = float(radius)

    def prior(X):
        d = X - c
        n = np.linalg.norm(d, axis=1)
        g = d / np.maximum(n, 1e-12)[:, None]
        return n - r, g

    prior.params = {"kind": "sphere", "center": c.tolist(), "radius": r}
    return prior


def _fit_sphere(points, normals, lo, hi):
    """Sphere from contacts: each contact (p, n) of a sphere says centre = p - r n."""
    ctr = 0.5 * (lo + hi)
    r0 = 0.25 * float(np.min(hi - lo))
    if len(points) == 0:
        return ctr, r0
    if normals is None or len(points) < 3:
        c = points.mean(axis=0) if len(points) >= 3 else ctr
        return c, float(np.mean(np.linalg.norm(points - c, axis=1))) if len(points) >= 3 else r0
    # least squares in (c, r): p_i = c + r n_i
    K = len(points)
    A = np.zeros((3 * K, 4))
    A[:, :3] = np.tile(np.eye(3), (K, 1))
    A[:, 3] = normals.reshape(-1)
    sol, *_ = np.linalg.lstsq(A, points.reshape(-1), rcond=None)
    c, r = sol[:3], float(sol[3])
    if not (r > 0) or np.any(c < lo) or np.any(c > hi):
        return ctr, r0
    return np.clip(c, lo, hi), float(np.clip(r, 0.02 * np.min(hi - lo), 0.5 * np.max(hi - lo)))


class ShapeMap:
    """The shape of one static object, learned from touches, in a world box known to hold it.

    Parameters
    ----------
    bounds : (lo (3,), hi (3,)) float
        World-frame box (m) that holds the object.
    method : {"gpis", "occupancy"}
        ``"gpis"``: a Gaussian-process implicit surface with contact normals as gradient
        observations; the predictive standard deviation of the implicit function (m) is
        the shape uncertainty. ``"occupancy"``: a log-odds voxel map (contacts raise,
        swept paths lower).
    sigma_pos : float
        Contact position noise (m).
    sigma_nor : float
        Contact normal noise (unit-vector components, about radians).
    lengthscale : float, optional
        GPIS kernel length scale (m); default 1/8 of the box's largest side.
    signal_std : float, optional
        GPIS prior standard deviation about the prior mean (m); default 0.4 lengthscale.
    prior : {"sphere", "superquadric"} or callable
        GPIS prior mean: a sphere fitted to the contacts (default), a superquadric
        fitted to the contacts once there are at least 12, or
        ``prior(points) -> (values, gradients)``.
    free_space : bool
        Use the space the probe swept (default True).
    resolution : int
        Occupancy cells along the longest side of the box (default 64).
    thin : float
        0 (default): every contact becomes observations of the GPIS. Above 0, a contact the
        map already predicts is left out of the GPIS: its predictive standard deviation
        there is below ``thin * sigma_pos``, its mean within two standard deviations (map
        and sensor) of the surface, and its measured normal within ``2 sigma_nor`` of the
        map's. It still counts in :attr:`contacts`, the touches and the calibration. A long
        session then grows the map with the surface it finds, not with the touches that
        land on surface already mapped: the cost of an update and of planning grows with
        the map's rows (docs/mapping.md, "Long sessions").

    Notes
    -----
    Updates are incremental: the GPIS appends rows to its Cholesky factor, the voxel map
    adds log-odds. Free space enters the GPIS as bounds f(x) >= c > 0 at swept points,
    each a moment-matched Gaussian site, added only where the current map gives the bound
    a fair chance of being broken (an active set, so only informative points cost
    anything).
    """

    def __init__(self, bounds, *, method: str = "gpis", sigma_pos: float = 0.001, sigma_nor: float = 0.1,
                 lengthscale: float | None = None, signal_std: float | None = None, prior="sphere",
                 free_space: bool = True, resolution: int = 64, thin: float = 0.0):
        self.lo, self.hi = as_bounds(bounds)
        if not isinstance(method, str) or method not in METHODS:
            raise ValidationError(f"method must be one of {METHODS}, got {method!r}")
        for name, v in (("sigma_pos", sigma_pos), ("sigma_nor", sigma_nor)):
            if not isinstance(v, (int, float, np.floating, np.integer)) or not (np.isfinite(v) and v > 0):
                raise ValidationError(f"{name} must be a positive finite number, got {v!r}")
        self.method = method
        self.sigma_pos, self.sigma_nor = float(sigma_pos), float(sigma_nor)
        ext = float(np.max(self.hi - self.lo))
        self.lengthscale = _positive("lengthscale", lengthscale, ext / 8.0)
        self.signal_std = _positive("signal_std", signal_std, 0.4 * self.lengthscale)
        if not (callable(prior) or (isinstance(prior, str) and prior in ("sphere", "superquadric"))):
            raise ValidationError(f"prior must be 'sphere', 'superquadric' or a callable, got {prior!r}")
        self.prior = prior
        self.free_space = as_bool(free_space, "free_space")
        if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or not 8 <= resolution <= 512:
            raise ValidationError(f"resolution must be an integer in [8, 512], got {resolution!r}")
        self.resolution = int(resolution)
        self.thin = as_float(thin, "thin", low=0.0, high=_THIN_MAX)
        self.thinned = 0                 # contacts left out of the GPIS (see thin)
        self._results: list = []
        self._pending: dict = {}         # batch -> rigid move not yet applied to its stored touches
        self.batches: list = []          # number of results in each update() call
        self._pts = np.zeros((0, 3))
        self._nrm = np.zeros((0, 3))
        self._has_normals = True
        self._free = np.zeros((0, 3))    # swept sample points not yet used
        self._free_c = np.zeros(0)       # their observation values
        # which update() call (batch) each contact, GPIS row and pool point came from, so
        # that relocate() can move a batch's data when its pose is revised
        self._pts_owner = np.zeros(0, dtype=np.int64)
        self._row_owner = np.zeros(0, dtype=np.int64)
        self._free_owner = np.zeros(0, dtype=np.int64)
        # swept points the map puts far outside, set aside (see _activate_free): points,
        # observation values and batches, as for the pool above
        self._asleep = (np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64))
        self.superquadric = None
        if method == "gpis":
            self._gp = GPIS(self.lengthscale, self.signal_std, self._make_prior())
        else:
            self._grid = OccupancyGrid(self.lo, self.hi, self.resolution)

    def __repr__(self) -> str:
        return (f"ShapeMap({self.method!r}, bounds={np.round(self.lo, 3).tolist()}..{np.round(self.hi, 3).tolist()}, "
                f"touches={len(self.results)}, contacts={self.n_contacts})")

    # -- data ------------------------------------------------------------------------
    @property
    def results(self) -> list:
        """Every TouchResult folded in so far, in the map's frame (moved by :meth:`relocate`)."""
        if self._pending:
            from .slam import transform_results

            ends = np.cumsum(self.batches)
            for b, T in self._pending.items():
                sl = slice(int(ends[b]) - self.batches[b], int(ends[b]))
                self._results[sl] = transform_results(self._results[sl], T)
            self._pending = {}
        return self._results

    @property
    def n_contacts(self) -> int:
        return len(self._pts)

    @property
    def contacts(self):
        """All contacts so far (world frame) as :class:`~touchloc.models.Contacts`."""
        from ..models import Contacts

        return Contacts(self._pts, self._nrm if self._has_normals and len(self._pts) else None)

    @blas_threads
    def update(self, results) -> "ShapeMap":
        """Fold in executed touches: every contact and the space every touch swept.

        Parameters
        ----------
        results : TouchResult or list of TouchResult
            From :meth:`touchloc.planners.SimulatedWorld.execute`, the real hand's
            ``HandWorld.execute`` or :func:`touchloc.planners.execute`.

        Returns
        -------
        ShapeMap
            self, for chaining.
        """
        results = _check_results(results)
        pts, nrm, seg = [], [], []
        for i, r in enumerate(results):
            s, e = r.swept_segment
            if r.contact is not None:
                P = np.asarray(r.contact.points, float)
                self._check_inside(P, f"results[{i}].contact")
                pts.append(P)
                nrm.append(None if r.contact.normals is None else np.asarray(r.contact.normals, float))
            seg.append((s, e, float(r.touch.probe_radius), r.contact is not None))
        P = np.concatenate(pts) if pts else np.zeros((0, 3))
        batch = len(self.batches)
        self._pts_owner = np.concatenate([self._pts_owner, np.full(len(P), batch, dtype=np.int64)])
        if any(n is None for n in nrm):
            self._has_normals = False
        N = np.concatenate([n for n in nrm if n is not None]) if (nrm and self._has_normals) else None
        self._results.extend(results)
        self.batches.append(len(results))
        if self.method == "gpis":
            self._update_gpis(list(zip(pts, nrm if N is not None else [None] * len(pts))), seg, batch)
        else:
            self._pts = np.concatenate([self._pts, P])
            if N is not None:
                self._nrm = np.concatenate([self._nrm, N])
            self._grid.add_contacts(P, N)
            if self.free_space and seg:
                S, E, R, H = (np.array(v) for v in zip(*seg))
                self._grid.add_free(S, E, R, H)
        return self

    def _check_inside(self, P, name):
        tol = 1e-9
        bad = np.any((P < self.lo - tol) | (P > self.hi + tol), axis=1)
        if np.any(bad):
            j = int(np.flatnonzero(bad)[0])
            raise ValidationError(f"{name}: contact {np.round(P[j], 4).tolist()} m lies outside the map's bounds "
                                  f"{np.round(self.lo, 4).tolist()}..{np.round(self.hi, 4).tolist()}")

    # -- GPIS internals ------------------------------------------------------------------
    def _make_prior(self):
        if callable(self.prior):
            return _checked_prior(self.prior)
        if self.prior == "superquadric" and self.n_contacts >= 12 and self._has_normals:
            from .superquadric import fit_superquadric

            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self.superquadric = fit_superquadric(self.contacts, bounds=(self.lo, self.hi))
                return self.superquadric.prior()
            except MappingError:
                pass
        c, r = _fit_sphere(self._pts, self._nrm if self._has_normals else None, self.lo, self.hi)
        return sphere_prior(c, r)

    def _update_gpis(self, blocks, seg, batch):
        """Add each touch's contacts in turn, each predicted by the map of the touches
        before it (the prequential calibration), then the free space of all of them."""
        gp = self._gp
        cheap_prior = self.prior != "superquadric"
        for j, (P, N) in enumerate(blocks):
            K = len(P)
            self._pts = np.concatenate([self._pts, P])
            if N is not None:
                self._nrm = np.concatenate([self._nrm, N])
            if K == 0:
                continue
            if gp.n:
                mu, sd = gp.mean_std(P, calibrated=False)
                gp.score_prediction(P, np.zeros(K), np.full(K, self.sigma_pos**2), pred=(mu, sd))
                if self.thin > 0.0:
                    new = ~self._predicted(P, N, mu, sd)
                    self.thinned += int(K - new.sum())
                    P, N, K = P[new], None if N is None else N[new], int(new.sum())
                    if K == 0:
                        continue
            X = [P]
            kind = [np.full(K, -1)]
            y = [np.zeros(K)]
            noise = [np.full(K, self.sigma_pos**2)]
            if N is not None:
                X.append(np.repeat(P, 3, axis=0))
                kind.append(np.tile(np.arange(3), K))
                y.append(N.reshape(-1))
                noise.append(np.full(3 * K, self.sigma_nor**2))
            gp.add(np.concatenate(X), np.concatenate(kind), np.concatenate(y), np.concatenate(noise))
            self._row_owner = np.concatenate([self._row_owner, np.full(gp.n - len(self._row_owner), batch)])
            if cheap_prior or j == len(blocks) - 1:
                gp.set_prior(self._make_prior())
        if self.free_space and seg:
            self._add_free_points(seg, batch)
            self._activate_free()

    def _predicted(self, P, N, mu, sd):
        """(K,) bool: which contacts the map already predicts (see ``thin``)."""
        ok = (sd < self.thin * self.sigma_pos) & (np.abs(mu) < 2.0 * np.sqrt(sd * sd + self.sigma_pos**2))
        if N is not None and ok.any():
            _, G = self._gp.mean_grad(P[ok])
            u = G / np.maximum(np.linalg.norm(G, axis=1, keepdims=True), 1e-12)
            ok[ok] = np.linalg.norm(u - N[ok], axis=1) < 2.0 * self.sigma_nor
        return ok

    def _add_free_points(self, seg, batch):
        """Sample swept paths inside the bounds (skipping the last stretch before a contact)."""
        h = 0.5 * self.lengthscale
        new, val = [], []
        for s, e, r, stop in seg:
            v = e - s
            L = float(np.linalg.norm(v))
            if L <= 0:
                continue
            gap = (r + 3.0 * self.sigma_pos + 0.002) if stop else 0.0
            t = np.arange(L - gap, 0.0, -h)   # from the stop backwards, evenly spaced
            if len(t) == 0:
                continue
            X = s + np.outer(t / L, v)
            inside = np.all((X >= self.lo) & (X <= self.hi), axis=1)
            new.append(X[inside])
            val.append(np.full(int(inside.sum()), r + 0.002))
        if new:
            X, c = np.concatenate(new), np.concatenate(val)
            owner = np.full(len(X), batch, dtype=np.int64)
            self._asleep = tuple(np.concatenate([a, b]) for a, b in zip(self._asleep, (X, c, owner)))
            self._wake()

    _MAX_POOL = 4000
    _FREE_Z = -1.0   # a swept point becomes a bound once the map gives it P(f < c) > Phi(-1) = 16 %
    #: the pool's points set aside while the map's mean there exceeds their bound by more
    #: than this many prior standard deviations, and woken below the first (None: none
    #: set aside); see _activate_free
    _SLEEP = (1.5, 2.5)

    def _wake(self):
        """Track the set-aside swept points whose bound the map's mean no longer clears by
        the margin (the new ones among them)."""
        X, c, owner = self._asleep
        if len(X) == 0:
            return
        wake = np.ones(len(X), bool)
        if self._SLEEP is not None:
            # single precision where its errors (micrometres) are far below the margin
            # between waking and a possible bound (half a prior standard deviation)
            dtype = np.float32 if self.signal_std > 2e-4 else np.float64
            wake = self._gp.mean(X, dtype=dtype) < c + self._SLEEP[0] * self.signal_std
        if np.any(wake):
            self._free = np.concatenate([self._free, X[wake]])
            self._free_c = np.concatenate([self._free_c, c[wake]])
            self._free_owner = np.concatenate([self._free_owner, owner[wake]])
            self._gp.track(X[wake])
            self._asleep = (X[~wake], c[~wake], owner[~wake])

    def _activate_free(self, rounds: int = 2, per_round: int = 64):
        """Add free-space bounds f(x) >= c where the map doubts them (most doubted first).

        A swept point says only that the surface is at least c away, so each becomes a
        moment-matched Gaussian site (:func:`gpis.bound_site`): a bound the map breaks
        pulls the mean up to about c with confidence, one it nearly keeps adds a weak push.
        (Observing f(x) = c outright, the earlier rule, pulls the surface towards swept
        paths that pass far from the object: made random-touch maps of the cereal box 2.5x
        worse when applied beyond outright contradictions, and of the bread 13-27 % worse
        at 20-100 touches even when limited to them.)

        Swept points whose bound the map's mean clears by more than ``_SLEEP[1]`` prior
        standard deviations are set aside untracked, and tracked again once it clears them
        by less than ``_SLEEP[0]`` (checked on every update): they could not become bounds
        meanwhile, so the bounds are the same, and neither a relocation nor an added row
        pays for their columns.
        """
        for r in range(rounds):
            if r:
                self._wake()        # (the first round's bounds changed the map)
            if len(self._free) == 0 or self._gp.n == 0:
                break
            mu, sd = self._gp.tracked_mean(), self._gp.tracked_std()
            viol = (self._free_c - mu) / sd
            idx = np.flatnonzero(viol > self._FREE_Z)
            if len(idx) == 0:
                break
            idx = idx[np.argsort(-viol[idx])][:per_round]
            # keep activated points a quarter length scale apart so the kernel matrix stays well conditioned
            chosen = _spread(self._free[idx], 0.25 * self.lengthscale)
            idx = idx[chosen]
            val, var = bound_site(mu[idx], sd[idx], self._free_c[idx], floor=(2.0 * self.sigma_pos) ** 2)
            self._gp.add(self._free[idx], np.full(len(idx), -1), val, var, scored=False)
            self._row_owner = np.concatenate([self._row_owner, self._free_owner[idx]])
            keep = np.ones(len(self._free), bool)
            keep[idx] = False
            self._drop_free(keep)
        X, c, _ = self._asleep
        if len(self._free) + len(X) > self._MAX_POOL and self._gp.n:
            # bound the pool: forget the points the map puts farthest outside, the least
            # likely ever to contradict it
            mu = np.concatenate([self._gp.tracked_mean() - self._free_c, self._gp.mean(X) - c])
            keep = np.zeros(len(mu), bool)
            keep[np.argsort(mu)[:self._MAX_POOL // 2]] = True
            self._asleep = tuple(a[keep[len(self._free):]] for a in self._asleep)
            self._drop_free(keep[:len(self._free)])
        if self._SLEEP is not None and len(self._free) and self._gp.n:
            # set aside the points whose bound the map's mean clears by far: a bound is only
            # added where the mean is below c + sd (_FREE_Z), and sd never exceeds the prior's
            # s, so these cannot become bounds until they wake (checked before each round).
            # Their columns of the tracked block are what a relocation and every added row
            # pay for: most of a pool (70-88 % on an in-hand mug after 30 actions) lies far outside.
            far = self._gp.tracked_mean() > self._free_c + self._SLEEP[1] * self.signal_std
            if np.any(far):
                self._asleep = tuple(np.concatenate([a, b[far]]) for a, b in
                                     zip(self._asleep, (self._free, self._free_c, self._free_owner)))
                self._drop_free(~far)

    def _drop_free(self, keep):
        self._free, self._free_c, self._free_owner = self._free[keep], self._free_c[keep], self._free_owner[keep]
        self._gp.untrack(keep)

    def _corners(self) -> np.ndarray:
        """(8, 3) the corners of the map's box: they bound how far a rigid move shifts any
        of its points."""
        return np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                         for z in (self.lo[2], self.hi[2])])

    @blas_threads
    def relocate(self, transforms, *, tol: float = 0.0) -> "ShapeMap":
        """Move the data of each past update by a rigid transform, and refit.

        A SLAM back end revises the poses at which earlier touches were made; the touches
        of update call ``b`` (its contacts, their normals, its swept paths and the free-space
        bounds drawn from them) then move by ``transforms[b]``, which maps their old
        map-frame coordinates to the new ones. The GPIS keeps the leading block of its
        factor up to the first moved update and adds the rest back (see
        :meth:`GPIS.relocate`); the occupancy grid is rebuilt from the moved touches.

        Parameters
        ----------
        transforms : list of ((4, 4) float or None)
            One per update call so far (``len(self.batches)``); None leaves it in place.
        tol : float
            Moves that shift no point of the map's box by more than ``tol`` (m) are
            treated as none (saves refitting for corrections below the sensor's noise).

        Returns
        -------
        ShapeMap
            self.
        """
        from .._validate import as_float_array, as_pose, as_poses

        if isinstance(transforms, np.ndarray) and transforms.ndim == 3:
            transforms = list(transforms)
        if not isinstance(transforms, (list, tuple)) or len(transforms) != len(self.batches):
            raise ValidationError(f"transforms must be a list of {len(self.batches)} poses (one per update), "
                                  f"got {type(transforms).__name__} of length {len(transforms) if hasattr(transforms, '__len__') else '?'}")
        if not isinstance(tol, (int, float, np.floating, np.integer)) or isinstance(tol, bool) or not (tol >= 0 and np.isfinite(tol)):
            raise ValidationError(f"tol must be a finite number >= 0 (m), got {tol!r}")
        corners = self._corners()
        given = [b for b, T in enumerate(transforms) if T is not None]
        moves = {}
        if given:
            # each checked for shape and finiteness, then all for rigidity in one batch: a
            # smoothing pass hands in dozens of transforms
            Ts = np.stack([as_float_array(transforms[b], f"transforms[{b}]", shape=(4, 4),
                                          expected="a (4, 4) homogeneous matrix") for b in given])
            try:
                as_poses(Ts, "transforms")
            except ValidationError:
                for b, T in zip(given, Ts):       # name the offender
                    as_pose(T, f"transforms[{b}]")
                raise
            shift = np.max(np.linalg.norm(np.einsum("bij,cj->bci", Ts[:, :3, :3], corners) + Ts[:, None, :3, 3]
                                          - corners, axis=2), axis=1)
            moves = {b: T for b, T, d in zip(given, Ts, shift) if d > tol}
        if not moves:
            return self
        first = min(moves)
        # the stored touches (replayed by save/load) move when they are next read
        for b, T in moves.items():
            self._pending[b] = T @ self._pending[b] if b in self._pending else T

        def moved(X, owner, rotate_only=False):
            X = X.copy()
            for b, T in moves.items():
                sel = owner == b
                if np.any(sel):
                    X[sel] = X[sel] @ T[:3, :3].T + (0.0 if rotate_only else T[:3, 3])
            return X

        self._pts = moved(self._pts, self._pts_owner)
        if self._has_normals and len(self._nrm) == len(self._pts):
            self._nrm = moved(self._nrm, self._pts_owner, rotate_only=True)
        self._free = moved(self._free, self._free_owner)
        self._asleep = (moved(self._asleep[0], self._asleep[2]),) + self._asleep[1:]
        if self.method == "gpis":
            gp = self._gp
            X = moved(gp.X, self._row_owner)
            y = gp.y.copy()
            g = np.flatnonzero(gp.kind == 0)          # gradient rows come as (0, 1, 2) triples
            if len(g):
                G = moved(np.stack([y[g], y[g + 1], y[g + 2]], axis=1), self._row_owner[g], rotate_only=True)
                y[g], y[g + 1], y[g + 2] = G[:, 0], G[:, 1], G[:, 2]
            rows = np.flatnonzero(self._row_owner >= first)
            start = int(rows[0]) if len(rows) else gp.n
            gp.relocate(X, y, self._free, start=start)
            gp.set_prior(self._make_prior())
        else:
            self._grid = OccupancyGrid(self.lo, self.hi, self.resolution)
            i = 0
            for b in self.batches:
                batch = self.results[i:i + b]
                i += b
                P = [r.contact.points for r in batch if r.contact is not None]
                N = [r.contact.normals for r in batch if r.contact is not None]
                if P:
                    self._grid.add_contacts(np.concatenate(P), np.concatenate(N) if self._has_normals else None)
                if self.free_space and batch:
                    S, E = zip(*(r.swept_segment for r in batch))
                    self._grid.add_free(np.array(S), np.array(E), np.array([r.touch.probe_radius for r in batch]),
                                        np.array([r.contact is not None for r in batch]))
        return self

    @blas_threads
    def refit(self) -> "ShapeMap":
        """Refactor the GPIS from its stored observations (a check on the incremental update)."""
        if self.method == "gpis":
            self._gp.refactor()
        return self

    # -- queries ---------------------------------------------------------------------
    @blas_threads
    def signed_distance(self, points) -> np.ndarray:
        """(M,) the map's mean implicit function at world points: negative inside.

        For ``"gpis"`` it approximates the signed distance (m); for ``"occupancy"`` it is
        minus the log-odds of occupancy.
        """
        P = as_points(points, "points", allow_empty=True)
        if self.method == "gpis":
            return self._gp.mean(P)
        p = np.clip(self._grid.probability(P), 1e-12, 1 - 1e-12)
        return -np.log(p / (1 - p))

    @blas_threads
    def surface_std(self, points) -> np.ndarray:
        """(M,) shape uncertainty at world points.

        ``"gpis"``: the predictive standard deviation of the implicit function (m); where
        the surface is well known it is about the contact noise, far from every touch it
        returns to ``signal_std``. ``"occupancy"``: the Bernoulli standard deviation
        sqrt(p (1 - p)) of the cell's occupancy (dimensionless, 0.5 when unknown).
        """
        P = as_points(points, "points", allow_empty=True)
        if self.method == "gpis":
            return self._gp.mean_std(P)[1]
        p = self._grid.probability(P)
        return np.sqrt(p * (1 - p))

    @blas_threads
    def mean_std(self, points, *, calibrated: bool = True):
        """(M,) mean implicit function and (M,) its standard deviation.

        ``calibrated=False`` (GPIS only) leaves out the map's variance scale: the variance
        under the sensor's own noise model.
        """
        P = as_points(points, "points", allow_empty=True)
        calibrated = as_bool(calibrated, "calibrated")
        if self.method != "gpis":
            return self.signed_distance(P), self.surface_std(P)
        return self._gp.mean_std(P, calibrated=calibrated)

    @blas_threads
    def grid(self, resolution: int | None = None):
        """The mean implicit function sampled on a grid over the bounds.

        Returns
        -------
        values : (nx, ny, nz) float
        origin : (3,) float
            World position of ``values[0, 0, 0]``.
        spacing : float
        """
        if self.method == "occupancy" and resolution is None:
            return self._grid.field()
        res = self.resolution if resolution is None else as_count(resolution, "resolution", min=8, max=512)
        h = float(np.max(self.hi - self.lo)) / (res - 1)
        n = np.maximum(np.ceil((self.hi - self.lo) / h).astype(int) + 1, 2)
        axes = [self.lo[i] + h * np.arange(n[i]) for i in range(3)]
        if self.method == "occupancy":
            G = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            return self.signed_distance(G).reshape(tuple(n)), self.lo.copy(), h
        return _coarse_to_fine(lambda Q: self._gp.mean(Q, dtype=np.float32), axes, h), self.lo.copy(), h

    @blas_threads
    def to_mesh(self, resolution: int | None = None, *, name: str = "map"):
        """The mean surface as a :class:`~touchloc.models.MeshObject` (marching cubes).

        Usable at once by ``ProximityModel``, the estimators and the planners.

        Raises
        ------
        MappingError
            When the map has no contact yet, or its mean has no surface in the bounds.
        """
        from skimage.measure import marching_cubes

        from ..models import MeshObject

        if self.n_contacts == 0:
            raise MappingError("the map has no contacts yet: touch the object before asking for a mesh")
        V, origin, h = self.grid(resolution)
        # close the surface at the box: the border counts as outside
        V = np.pad(V, 1, mode="constant", constant_values=max(float(np.max(V)), 1e-3))
        if not (np.min(V) < 0 < np.max(V)):
            raise MappingError("the map's mean has no surface inside the bounds (empty level set)")
        verts, faces, _, _ = marching_cubes(V, level=0.0, spacing=(h, h, h), allow_degenerate=False)
        verts = verts + origin - h
        mesh = trimesh.Trimesh(verts, faces[:, ::-1], process=True)
        mesh = _touched_parts(mesh, self._pts, 2.0 * h)
        if len(mesh.faces) == 0:
            raise MappingError("marching cubes found no surface")
        if mesh.is_watertight and mesh.volume < 0:
            mesh.invert()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return MeshObject(mesh, name=name, check_units=False)

    # -- files -------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the map to ``path`` (.npz): its settings and every touch, replayable."""
        path = as_path(path, "path", must_exist=False)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        rec = _pack_results(self.results)
        settings = dict(method=self.method, sigma_pos=self.sigma_pos, sigma_nor=self.sigma_nor,
                        lengthscale=self.lengthscale, signal_std=self.signal_std,
                        prior=self.prior if isinstance(self.prior, str) else "sphere",
                        free_space=self.free_space, resolution=self.resolution, thin=self.thin)
        try:
            np.savez_compressed(path, lo=self.lo, hi=self.hi, batches=np.array(self.batches, dtype=np.int64),
                                settings=json.dumps(settings), **rec)
        except OSError as exc:
            raise ValidationError(f"cannot write the map file {path}: {exc}") from None
        return path

    @classmethod
    def load(cls, path) -> "ShapeMap":
        """Read a map written by :meth:`save` (replays its touches, so the map is identical)."""
        path = as_path(path, "path", must_exist=False)
        if not path.is_file():
            raise ValidationError(f"no map file at {path}")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
            settings = json.loads(str(data["settings"]))
            m = cls((data["lo"], data["hi"]), **settings)
            results = _unpack_results(data)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValidationError(f"{path} is not a touchloc shape map: {exc}") from None
        i = 0
        for b in data["batches"]:
            m.update(results[i:i + int(b)])
            i += int(b)
        return m


# -- helpers -----------------------------------------------------------------------------
#: largest ``thin`` accepted (times ``sigma_pos``), far beyond any useful value
_THIN_MAX = 1e3


def _positive(name, v, default):
    if v is None:
        return float(default)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (np.isfinite(v) and v > 0):
        raise ValidationError(f"{name} must be a positive finite number (m), got {v!r}")
    return float(v)


def _checked_prior(fn):
    def prior(X):
        out = fn(X)
        try:
            m, g = out
            m = np.asarray(m, float).reshape(len(X))
            g = np.asarray(g, float).reshape(len(X), 3)
        except (TypeError, ValueError):
            raise ValidationError("prior(points) must return (values (M,), gradients (M, 3))") from None
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(g))):
            raise ValidationError("prior(points) returned non-finite values")
        return m, g

    return prior


def _check_results(results) -> list:
    from ..planners import TouchResult

    if isinstance(results, TouchResult):
        return [results]
    try:
        results = list(results)
    except TypeError:
        raise ValidationError(f"results must be a TouchResult or a list of them, got {type(results).__name__}") from None
    for i, r in enumerate(results):
        if not isinstance(r, TouchResult):
            raise ValidationError(f"results[{i}] must be a touchloc.planners.TouchResult, got {type(r).__name__}")
    return results


def _touched_parts(mesh, contacts, reach):
    """The connected parts of ``mesh`` that some contact lies on (within ``reach``).

    Stray pieces (pockets no probe swept, ripples of the mean far from the data) go;
    when no part holds a contact, the part with the most area is kept.
    """
    from scipy.spatial import cKDTree

    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    keep = [p for p in parts if np.any(cKDTree(p.vertices).query(contacts, distance_upper_bound=reach)[0] < np.inf)]
    if not keep:
        return max(parts, key=lambda m: m.area)
    return keep[0] if len(keep) == 1 else trimesh.util.concatenate(keep)


def _spread(X, r):
    """Indices of a greedy subset of X with pairwise distances >= r (in the given order)."""
    keep = []
    for i in range(len(X)):
        if all(np.sum((X[i] - X[j]) ** 2) >= r * r for j in keep):
            keep.append(i)
    return np.asarray(keep, dtype=np.int64)


def _coarse_to_fine(mean, axes, h, factor: int = 4):
    """Evaluate ``mean`` on the full grid only near its zero level set.

    A grid ``factor`` times coarser is evaluated everywhere; fine points are evaluated
    exactly where the interpolated coarse value is within a few fine cells of zero (f is
    about a distance), and trilinearly interpolated elsewhere, where only the sign
    matters to marching cubes.
    """
    from scipy.interpolate import RegularGridInterpolator

    n = [len(a) for a in axes]
    cidx = [np.unique(np.r_[np.arange(0, k, factor), k - 1]) for k in n]
    cax = [axes[i][cidx[i]] for i in range(3)]
    C = np.stack(np.meshgrid(*cax, indexing="ij"), -1).reshape(-1, 3)
    cv = mean(C).reshape([len(c) for c in cax])
    interp = RegularGridInterpolator(cax, cv)
    F = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    fv = interp(F)
    # trilinear interpolation of a function that varies on the kernel's length scale errs
    # by far less than a coarse cell; 2.5 fine cells of margin keeps every sign right
    band = np.abs(fv) < 2.5 * h + 0.25 * factor * h
    if np.any(band):
        fv[band] = mean(F[band])
    return fv.reshape(n)


def _pack_results(results) -> dict:
    K = len(results)
    out = dict(origin=np.zeros((K, 3)), direction=np.zeros((K, 3)), max_travel=np.zeros(K),
               probe_radius=np.zeros(K), travel=np.zeros(K), n_contacts=np.zeros(K, dtype=np.int64))
    pts, nrm = [], []
    for i, r in enumerate(results):
        out["origin"][i], out["direction"][i] = r.touch.origin, r.touch.direction
        out["max_travel"][i], out["probe_radius"][i], out["travel"][i] = (r.touch.max_travel, r.touch.probe_radius,
                                                                          r.travel)
        if r.contact is not None:
            out["n_contacts"][i] = len(r.contact)
            pts.append(r.contact.points)
            nrm.append(r.contact.normals if r.contact.normals is not None else np.full((len(r.contact), 3), np.nan))
    out["points"] = np.concatenate(pts) if pts else np.zeros((0, 3))
    out["normals"] = np.concatenate(nrm) if nrm else np.zeros((0, 3))
    return out


def _unpack_results(d) -> list:
    from ..models import Contacts
    from ..planners import GuardedTouch, TouchResult

    res, j = [], 0
    for i in range(len(d["travel"])):
        t = GuardedTouch(d["origin"][i], d["direction"][i], float(d["max_travel"][i]), float(d["probe_radius"][i]))
        k = int(d["n_contacts"][i])
        c = None
        if k:
            N = d["normals"][j:j + k]
            c = Contacts(d["points"][j:j + k], None if np.any(np.isnan(N)) else N)
            j += k
        res.append(TouchResult(t, float(d["travel"][i]), c))
    return res
