"""Petrovskaya's integrated proximity model: every surface point may have caused a contact."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._cache import numba_cache_enabled
from .._util import as_poses
from .._validate import as_callable, as_count, as_positive_float
from ..errors import ValidationError
from ._kernels import kernel_array
from .base import MeasurementModel, check_temperature
from .mesh import MeshObject
from .proximity import ProximityModel, _check_contacts, _to_object_frame, check_queries

__all__ = ["IntegratedProximityModel"]

_NB = dict(cache=numba_cache_enabled(__file__), fastmath=False, nogil=True)

#: Terms farther than this many sigma_pos from a contact are left out of its sum.
CUTOFF = 4.0
#: Between BLEND and FAR sigma_pos from the nearest quadrature point the score passes
#: linearly from the sum to the tangent-plane approximation of the contact's best match,
#: which alone scores contacts beyond FAR. Up to FAR the terms left out are below
#: exp(-(CUTOFF^2 - FAR^2) / 2) = 3 % of a face's share, and there the two agree on a
#: flat face; the blend keeps the likelihood continuous where they differ (curved
#: patches, edges).
BLEND, FAR = 2.5, 3.0
#: The approximation, lowered by this many nats, is also added to the sum (log-sum-exp),
#: so that a contact whose normal fits no surface point within the cut-off (only faces
#: beyond it) is still scored by its best match, continuously. Where the sum explains the
#: contact this adds at most exp(-FALLBACK_NATS) = 0.25 % (the sum is computed with it
#: only for contacts it could move by more than 2 %).
FALLBACK_NATS = 6.0
#: Quadrature points at most (memory and time grow with them).
MAX_POINTS = 5_000_000


class IntegratedProximityModel(MeasurementModel):
    """Integrated proximity model (Handbook of Robotics ch. 42.1.2).

    Instead of the single closest surface point, all surface points contribute, each
    weighted by a prior of how likely it is to be touched:

        p(D | X) = integral over the surface of pi(s) N(D_pos; X s, sigma_pos^2 I)
                   N_2(D_nor; R n(s), sigma_nor^2) ds

    with ``N_2`` a Gaussian on the normal's 2-D tangent plane, in |D_nor - R n(s)|. With
    ``pi`` uniform by area this is the exact density of a sensor that touches a point
    drawn uniformly on the surface and adds isotropic noise to it, which is how
    :meth:`MeshObject.sample_surface` plus Gaussian noise simulates contacts; the
    :class:`ProximityModel` keeps only the best surface point, which is the same on the
    inside of a face and differs at edges, corners and curved patches.

    The integral is a quadrature over the surface (see ``spacing`` and ``n_samples``);
    terms farther than 4 sigma_pos from the contact are left out, and a contact farther
    than 3 sigma_pos from the surface (or whose normal no nearby surface point fits) is
    scored by the tangent-plane approximation of its best match, blended in so that the
    likelihood stays continuous: ``-log(area) - 1/2 log(2 pi sigma_pos^2) -
    log(2 pi sigma_nor^2) - d_M^2 / 2`` (:meth:`ProximityModel.log_normalizer` plus the
    proximity cost). A compiled pass over a hash grid of the quadrature points does the
    sums; the cost per pose-contact pair grows with (sigma_pos / spacing)^2.

    Parameters
    ----------
    obj : MeshObject
    sigma_pos, sigma_nor : float
        As in :class:`~touchloc.models.ProximityModel` (sigma_nor None ignores normals).
    spacing : float, optional
        Quadrature: each face is cut into a lattice of triangles with edges of at most
        ``spacing`` (m), whose centroids stand for their areas; on sliver faces the
        points of a face within one cube of side ``spacing`` are merged into their
        area-weighted centroid. Default sigma_pos / 2: the log-density per contact then
        moves by less than 0.03 nats (1st to 99th percentile; mug, lemon and cereal box, 2 mm)
        when the spacing is halved again. Deterministic.
    n_samples : int, optional
        Instead of the subdivided mesh, this many points drawn uniformly by area (drawn
        with ``rng``): Monte Carlo quadrature, noisier for the same count.
    surface_prior : callable or None
        ``surface_prior(points (S, 3), normals (S, 3)) -> (S,)`` non-negative weights per
        quadrature point (e.g. to favour faces a probe can reach), applied on top of the
        area weights.
    rng : None, int or Generator
        For drawing the surface samples (``n_samples`` only).
    """

    def __init__(self, obj: MeshObject, sigma_pos: float, sigma_nor: float | None = None, *,
                 spacing: float | None = None, n_samples: int | None = None, surface_prior=None, rng=None):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        sigma_pos = as_positive_float(sigma_pos, "sigma_pos (m)")
        if sigma_nor is not None:
            sigma_nor = as_positive_float(sigma_nor, "sigma_nor")
        if spacing is not None and n_samples is not None:
            raise ValidationError("give spacing (subdivided mesh) or n_samples (random points), not both")
        surface_prior = as_callable(surface_prior, "surface_prior", allow_none=True)
        self.obj = obj
        self.sigma_pos = float(sigma_pos)
        self.sigma_nor = None if sigma_nor is None else float(sigma_nor)
        self._proximity = ProximityModel(obj, self.sigma_pos, self.sigma_nor)
        if n_samples is not None:
            n_samples = as_count(n_samples, "n_samples", max=MAX_POINTS,
                                 why="every quadrature point is held in memory and visited by nearby contacts")
            self.points, self.normals, _ = obj.sample_surface(int(n_samples), rng=rng)
            w = np.full(len(self.points), 1.0 / len(self.points))
            self.spacing = None
        else:
            self.spacing = (0.5 * self.sigma_pos if spacing is None
                            else as_positive_float(spacing, "spacing (m)"))
            self.points, self.normals, w = _midpoint_quadrature(obj, self.spacing)
        if surface_prior is not None:
            prior = np.asarray(surface_prior(self.points, self.normals), dtype=float)
            if (prior.shape != (len(self.points),) or not np.all(np.isfinite(prior)) or np.any(prior < 0)
                    or prior.sum() <= 0):
                raise ValidationError("surface_prior must return (S,) finite non-negative weights, not all zero")
            w = w * prior
        with np.errstate(divide="ignore"):
            self.log_prior = np.log(w / w.sum())
        self._grid = _HashGrid(self.points, self.normals, self.log_prior, CUTOFF * self.sigma_pos)

    def __repr__(self) -> str:
        return f"IntegratedProximityModel({self.obj.name!r}, sigma_pos={self.sigma_pos}, points={len(self.points)})"

    def _constant(self, use_n: bool) -> float:
        c = -1.5 * np.log(2 * np.pi * self.sigma_pos**2)
        if use_n:
            c -= np.log(2 * np.pi * self.sigma_nor**2)
        return float(c)

    def query_log_density(self, points, normals=None) -> np.ndarray:
        """log p of object-frame measurements (M,) for the object at the identity pose.

        Parameters
        ----------
        points : (M, 3) float
        normals : (M, 3) float or None
            Made unit length; None (or a model without ``sigma_nor``) scores positions only.
        """
        P, Nr = check_queries(points, normals)
        return self._log_density(P, Nr if self.sigma_nor is not None else None)

    def _log_density(self, P, Nr):
        """:meth:`query_log_density` of checked, contiguous queries (``Nr`` None: positions only)."""
        use_n = Nr is not None
        Nr = Nr if use_n else np.zeros((0, 3))
        g = self._grid
        inv_n = 1.0 / self.sigma_nor**2 if use_n else 0.0
        P, Nr = kernel_array(P), kernel_array(Nr)
        near, dmin2 = _neighbourhood_lse(P, Nr, use_n, g.points, g.normals, g.logw_rel, g.wmax, g.start, g.lo, g.cell,
                                         g.dims, 0.5 / self.sigma_pos**2, inv_n, g.cutoff**2)
        near += self._constant(use_n)
        # the tangent-plane approximation of the best match (the proximity cost and its
        # normaliser): where the surface is far, or where no nearby surface point's normal fits
        per = self._proximity._log_normalizer_per_contact(use_n)
        u = np.clip((np.sqrt(dmin2) / self.sigma_pos - BLEND) / (FAR - BLEND), 0.0, 1.0)
        # the approximation is at most `per`: below per - FALLBACK_NATS + 4 it may move
        # the sum by more than exp(-4) = 2 %
        cand = np.flatnonzero((u > 0) | (near < per - FALLBACK_NATS + 4.0))
        if len(cand):
            far = per - 0.5 * self._proximity.query_costs(P[cand], Nr[cand] if use_n else None)
            w = u[cand]
            mixed = np.logaddexp(near[cand], far - FALLBACK_NATS)
            with np.errstate(invalid="ignore"):   # 0 x -inf in the branch not taken
                near[cand] = np.where(w >= 1.0, far, np.where(w <= 0.0, mixed, (1.0 - w) * mixed + w * far))
        return near

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0, *, chunk: int = 4096) -> np.ndarray:
        """(N,) sum_k log p(D_k | X) / temperature (normalised densities: metres^-3 per
        contact, times rad^-2 with normals)."""
        T = check_temperature(temperature)
        poses = as_poses(poses)
        contacts = _check_contacts(contacts)
        chunk = as_count(chunk, "chunk", max=10_000_000, why="poses moved into their frames at once")
        use_n = contacts.has_normals and self.sigma_nor is not None
        out = np.empty(len(poses))
        K = len(contacts)
        for a in range(0, len(poses), chunk):
            P, Nr = _to_object_frame(poses[a:a + chunk], contacts)   # already checked: no second pass
            ll = self._log_density(np.ascontiguousarray(P.reshape(-1, 3)),
                                   np.ascontiguousarray(Nr.reshape(-1, 3)) if use_n else None)
            out[a:a + chunk] = ll.reshape(-1, K).sum(axis=1)
        return out / T


def _midpoint_quadrature(obj: MeshObject, spacing: float):
    """Quadrature points, normals and area weights: each face cut into a regular lattice
    of n^2 congruent triangles, n = ceil(longest edge / spacing), whose centroids are
    then merged per face and cube of side ``spacing``."""
    tri = obj.triangles
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    n_cut = np.maximum(np.ceil(edges / spacing), 1).astype(np.int64)
    expected = float(np.sum(n_cut.astype(float) ** 2))
    if expected > MAX_POINTS:
        raise ValidationError(
            f"a quadrature with spacing {spacing:.3g} m needs about {expected:.3g} points on this mesh "
            f"(at most {MAX_POINTS}); give a larger spacing or n_samples")
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pts, face, w = [], [], []
    for n in np.unique(n_cut):
        f = np.flatnonzero(n_cut == n)
        # barycentric (u, v) of the sub-triangles' centroids: n (n + 1) / 2 pointing one
        # way, n (n - 1) / 2 the other, each of area A / n^2
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        up = (i + j) <= n - 1
        down = (i + j) <= n - 2
        uv = np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], 1),
                             np.stack([i[down] + 2 / 3, j[down] + 2 / 3], 1)]) / n
        t = tri[f]
        q = (t[:, None, 0] + uv[None, :, :1] * (t[:, None, 1] - t[:, None, 0])
             + uv[None, :, 1:] * (t[:, None, 2] - t[:, None, 0]))
        pts.append(q.reshape(-1, 3))
        face.append(np.repeat(f, len(uv)))
        w.append(np.repeat(area[f] / n**2, len(uv)))
    pts, face, w = np.concatenate(pts), np.concatenate(face), np.concatenate(w)
    # a sliver face's lattice is far denser than it needs to be across the sliver: merge
    # the points of one face that share a cube of side `spacing` into their area-weighted
    # centroid, so that no face has more than about one point per spacing^2
    cube = np.floor((pts - pts.min(axis=0)) / spacing).astype(np.int64)
    dims = cube.max(axis=0) + 1
    key = face.astype(np.int64) * int(np.prod(dims)) + (cube[:, 0] * dims[1] + cube[:, 1]) * dims[2] + cube[:, 2]
    _, inv = np.unique(key, return_inverse=True)   # one int64 per point: far faster than rows
    inv = inv.ravel()
    wsum = np.bincount(inv, weights=w)
    cent = np.stack([np.bincount(inv, weights=w * pts[:, d]) for d in range(3)], axis=1)
    first = np.zeros(len(wsum), dtype=np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    keep = wsum > 0
    return (np.ascontiguousarray(cent[keep] / wsum[keep, None]),
            np.ascontiguousarray(obj.face_normals[face[first[keep]]]), wsum[keep])


class _HashGrid:
    """Quadrature points sorted into cubic cells no smaller than the cut-off radius, with
    their log-weights relative to the largest (``logw_rel``, ``wmax``)."""

    def __init__(self, points, normals, logw, cutoff):
        lo = points.min(axis=0) - 1e-9
        span = points.max(axis=0) - lo
        # a query visits the 27 cells around its own (smaller cells, with the ones outside
        # the cut-off ball skipped, visit fewer points but were no faster: the time goes
        # into the terms inside the ball); at most 256^3 cells
        cell = max(cutoff, float(span.max()) / 256.0)
        dims = np.maximum(np.ceil(span / cell).astype(np.int64), 1)
        ijk = np.minimum((points - lo) // cell, dims - 1).astype(np.int64)
        key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        order = np.argsort(key, kind="stable")
        self.start = np.searchsorted(key[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
        self.points = np.ascontiguousarray(points[order])
        self.normals = np.ascontiguousarray(normals[order])
        self.wmax = float(np.max(logw))
        self.logw_rel = np.ascontiguousarray(logw[order] - self.wmax)
        self.lo, self.cell, self.dims, self.cutoff = lo, float(cell), dims, float(cutoff)


@nb.njit(parallel=True, **_NB)
def _neighbourhood_lse(P, N, use_n, Q, QN, logw, wmax, start, lo, cell, dims, inv2s2, inv_n2, cut2):
    """log sum_s w_s exp(-|p - q_s|^2 / (2 s^2) - |n - n_s|^2 / (2 s_n^2)) over the
    quadrature points within the cut-off of p (-inf where there are none), and the squared
    distance to the nearest of them (inf where there are none)."""
    M = P.shape[0]
    out = np.empty(M)
    dmin = np.empty(M)
    for i in nb.prange(M):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        ci = int(np.floor((px - lo[0]) / cell))
        cj = int(np.floor((py - lo[1]) / cell))
        ck = int(np.floor((pz - lo[2]) / cell))
        acc = 0.0
        near2 = np.inf
        for a in range(max(ci - 1, 0), min(ci + 2, dims[0])):
            for b in range(max(cj - 1, 0), min(cj + 2, dims[1])):
                for c in range(max(ck - 1, 0), min(ck + 2, dims[2])):
                    cidx = (a * dims[1] + b) * dims[2] + c
                    for s in range(start[cidx], start[cidx + 1]):
                        dx = px - Q[s, 0]
                        dy = py - Q[s, 1]
                        dz = pz - Q[s, 2]
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 > cut2:
                            continue
                        if d2 < near2:
                            near2 = d2
                        # relative to the largest weight, every term is at most 1: one
                        # exp per term and no rescaling (a sum that underflows, where every
                        # normal is hundreds of sigma off, is -inf and falls back)
                        e = logw[s] - d2 * inv2s2
                        if use_n:
                            # |n - n_s|^2 = 2 - 2 n.n_s for unit vectors
                            e -= (1.0 - (N[i, 0] * QN[s, 0] + N[i, 1] * QN[s, 1] + N[i, 2] * QN[s, 2])) * inv_n2
                        acc += np.exp(e)
        out[i] = wmax + np.log(acc) if acc > 0.0 else -np.inf
        dmin[i] = near2
    return out, dmin
