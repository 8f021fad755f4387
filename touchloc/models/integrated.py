"""Petrovskaya's integrated proximity model: every surface point may have caused a contact."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._cache import numba_cache_enabled
from .._util import as_poses
from .._validate import as_callable, as_count, as_positive_float
from ..errors import ValidationError
from .base import MeasurementModel, check_temperature
from .mesh import MeshObject
from .proximity import ProximityModel, _check_contacts, _to_object_frame

__all__ = ["IntegratedProximityModel"]

_NB = dict(cache=numba_cache_enabled(__file__), fastmath=False, nogil=True)

#: Terms farther than this many sigma_pos from a contact are left out of its sum.
CUTOFF = 4.0
#: Contacts farther than this many sigma_pos from every quadrature point are scored by the
#: tangent-plane approximation of their best match. Up to here the terms left out are
#: below exp(-(CUTOFF^2 - FAR^2) / 2) = 3 % of a face's share, and at this distance the
#: sum and the approximation agree on a flat face, so the switch is nearly continuous.
FAR = 3.0
#: A contact whose neighbourhood sum falls this many nats below that approximation lies
#: where no nearby surface point explains it (its normal fits only faces beyond the
#: cut-off): the approximation is used there too. Edges and corners, where the two
#: legitimately differ, differ by at most about log 8 = 2.1 nats (a convex corner).
FALLBACK_NATS = 3.0
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
    terms farther than 5 sigma_pos from the contact are left out, and a contact farther
    than 4 sigma_pos from the surface is scored by the tangent-plane
    approximation of its best match: ``-log(area) - 1/2 log(2 pi sigma_pos^2) -
    log(2 pi sigma_nor^2) - d_M^2 / 2`` (:meth:`ProximityModel.log_normalizer` plus the
    proximity cost). A compiled pass over a hash grid of the quadrature points does the
    sums; the cost per pose-contact pair grows with (sigma_pos / spacing)^2.

    Parameters
    ----------
    obj : MeshObject
    sigma_pos, sigma_nor : float
        As in :class:`~touchloc.models.ProximityModel` (sigma_nor None ignores normals).
    spacing : float, optional
        Quadrature: the mesh is subdivided until no edge is longer than ``spacing`` (m),
        and each face's centroid stands for its area (default: sigma_pos, where the
        midpoint rule's error on a face's Gaussian is below 1 %). Deterministic.
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
            self.spacing = (self.sigma_pos if spacing is None
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
        """log p of object-frame measurements (M,) for the object at the identity pose."""
        P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        use_n = normals is not None and self.sigma_nor is not None
        Nr = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3) if use_n else np.zeros((0, 3))
        g = self._grid
        inv_n = 1.0 / self.sigma_nor**2 if use_n else 0.0
        near, dmin2 = _neighbourhood_lse(P, Nr, use_n, g.points, g.normals, g.logw, g.start, g.lo, g.cell,
                                         g.dims, 0.5 / self.sigma_pos**2, inv_n, g.cutoff**2)
        near += self._constant(use_n)
        # the tangent-plane approximation of the best match: where the surface is far, or
        # where no nearby surface point's normal fits
        per = -np.log(self._area()) - 0.5 * np.log(2 * np.pi * self.sigma_pos**2)
        if use_n:
            per -= np.log(2 * np.pi * self.sigma_nor**2)
        far_away = dmin2 > (FAR * self.sigma_pos) ** 2
        cand = np.flatnonzero(far_away | (near < per - 0.5 * FAR**2))
        if len(cand):
            far = per - 0.5 * self._proximity.query_costs(P[cand], Nr[cand] if use_n else None)
            use = far_away[cand] | (far - FALLBACK_NATS > near[cand])
            near[cand[use]] = far[use]
        return near

    def _area(self) -> float:
        return float(self.obj.mesh.area_faces[self.obj.valid_faces].sum())

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
            P, Nr = _to_object_frame(poses[a:a + chunk], contacts)
            ll = self.query_log_density(P.reshape(-1, 3), Nr.reshape(-1, 3) if use_n else None)
            out[a:a + chunk] = ll.reshape(-1, K).sum(axis=1)
        return out / T


def _midpoint_quadrature(obj: MeshObject, spacing: float):
    """Centroids, normals and area weights of the mesh subdivided to edges <= spacing."""
    from trimesh import remesh

    faces = obj.mesh.faces[obj.valid_faces]
    edges = np.linalg.norm(obj.triangles - np.roll(obj.triangles, 1, axis=1), axis=2).max(axis=1)
    # each halving of a face's edges quadruples its count
    halvings = np.ceil(np.log2(np.maximum(edges / spacing, 1.0)))
    expected = float(np.sum(4.0 ** halvings))
    if expected > MAX_POINTS:
        raise ValidationError(
            f"a quadrature with spacing {spacing:.3g} m needs about {expected:.3g} points on this mesh "
            f"(at most {MAX_POINTS}); give a larger spacing or n_samples")
    v, f, idx = remesh.subdivide_to_size(obj.mesh.vertices, faces, spacing, max_iter=int(halvings.max()) + 2,
                                         return_index=True)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    keep = area > 0
    normals = obj.face_normals[idx[keep]]
    return tri[keep].mean(axis=1), np.ascontiguousarray(normals), area[keep]


class _HashGrid:
    """Quadrature points sorted into cubic cells no smaller than the cut-off radius."""

    def __init__(self, points, normals, logw, cutoff):
        lo = points.min(axis=0) - 1e-9
        span = points.max(axis=0) - lo
        cell = max(cutoff, float(span.max()) / 256.0)   # at most 256^3 cells
        dims = np.maximum(np.ceil(span / cell).astype(np.int64), 1)
        ijk = np.minimum((points - lo) // cell, dims - 1).astype(np.int64)
        key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        order = np.argsort(key, kind="stable")
        self.start = np.searchsorted(key[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
        self.points = np.ascontiguousarray(points[order])
        self.normals = np.ascontiguousarray(normals[order])
        self.logw = np.ascontiguousarray(logw[order])
        self.lo, self.cell, self.dims, self.cutoff = lo, float(cell), dims, float(cutoff)


@nb.njit(parallel=True, **_NB)
def _neighbourhood_lse(P, N, use_n, Q, QN, logw, start, lo, cell, dims, inv2s2, inv_n2, cut2):
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
        best = -np.inf
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
                        e = logw[s] - d2 * inv2s2
                        if use_n:
                            # |n - n_s|^2 = 2 - 2 n.n_s for unit vectors
                            e -= (1.0 - (N[i, 0] * QN[s, 0] + N[i, 1] * QN[s, 1] + N[i, 2] * QN[s, 2])) * inv_n2
                        if e > best:
                            acc = acc * np.exp(best - e) + 1.0
                            best = e
                        else:
                            acc += np.exp(e - best)
        out[i] = best + np.log(acc) if acc > 0.0 else -np.inf
        dmin[i] = near2
    return out, dmin
