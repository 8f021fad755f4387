"""Petrovskaya's proximity measurement model (Handbook of Robotics ch. 42, eq. 42.4-42.6)."""

from __future__ import annotations

import numpy as np

from .._cache import cached_structure
from .._util import as_poses
from .._validate import as_count, as_nonnegative_float, as_points, as_positive_float
from ..errors import ValidationError
from . import _bounds
from . import _kernels as K
from .base import MeasurementModel, check_temperature
from .contacts import Contacts
from .mesh import MeshObject

__all__ = ["ProximityModel", "contacts_in_object_frame"]

METHODS = ("exact", "fast", "bruteforce", "auto")

#: ``auto`` switches to the precomputed grid when a call has at least this many
#: pose-contact pairs. One such call does not pay for the grid's one-off build (1-20 s on
#: the bundled meshes, then kept on disk), but an estimator makes tens of them: a Scaling
#: Series posterior stage is 500 poses x K contacts per pass, a 2000-particle filter's
#: update 2000 x K. Smaller calls (a few poses) stay exact and build nothing. Scaling
#: Series resolves ``auto`` once per run by its largest batch, so its small late batches
#: use the grid its first scale built.
AUTO_FAST_PAIRS = 2_000

#: The fast grid's coarser levels: (reach beyond the mesh bounds in largest extents, cell
#: size as a multiple of the finest level's). Queries beyond the last use the exact tree.
COARSE_LEVELS = ((2.0, 4.0), (8.0, 16.0))
#: the default finest cell: a 24th of the largest extent, but at least this many
#: ``sigma_pos`` (up to an 8th of the extent). Cells finer than the noise multiply the
#: near lists (their reach is a few sigma) and their waits on memory without making them
#: shorter: on meshes under 72 mm at sigma_pos = 2 mm, 1.5 sigma gave 1.00-1.27x faster
#: likelihood passes, 2-8x faster builds and 1.5-5x less memory at the same accuracy
#: (docs/benchmarks.md, "Finest cells no finer than the noise (study)")
GRID_CELL_SIGMAS = 1.5


def contacts_in_object_frame(poses: np.ndarray, contacts: Contacts):
    """Contacts seen from each hypothesised object frame.

    Returns points (N, K, 3) and normals (N, K, 3) or None: R^T (p - t) and R^T n.
    """
    if not isinstance(contacts, Contacts):
        raise ValidationError(f"contacts must be a Contacts, got {type(contacts).__name__}")
    return _to_object_frame(as_poses(poses), contacts)


def _to_object_frame(poses, contacts):
    """:func:`contacts_in_object_frame` for already validated poses."""
    R = poses[:, :3, :3]
    t = poses[:, :3, 3]
    # row-vector form: R^T (p - t) for every pose and contact is (p - t) @ R
    P = (contacts.points[None, :, :] - t[:, None, :]) @ R
    Nrm = None
    if contacts.normals is not None:
        Nrm = contacts.normals[None, :, :] @ R
    return P, Nrm


class ProximityModel(MeasurementModel):
    """Proximity model: each contact is explained by the nearest surface point in 6-D.

    For a contact D = (D_pos, D_nor) and the object at pose X,
    ``d_M^2 = min_f |D_pos - o_f|^2 / sigma_pos^2 + |D_nor - n_f|^2 / sigma_nor^2`` where
    the minimum is joint over the faces f (o_f: the point of face f closest to D_pos,
    n_f: its normal), and ``log p(D | X) = -1/2 sum_k d_M^2 / temperature`` (up to a
    pose-independent constant). Without normals (``sigma_nor=None`` or contacts without
    normals) only the position term is used.

    Parameters
    ----------
    obj : MeshObject
    sigma_pos : float
        Position noise (m), > 0.
    sigma_nor : float or None
        Normal noise (unit-vector difference, roughly radians for small angles), > 0;
        None ignores normals.
    method : {"auto", "exact", "fast", "bruteforce"}
        ``exact``: BVH branch-and-bound, equal to brute force to rounding.
        ``fast``: a precomputed candidate grid around the object (see Notes); outside
        it, the exact evaluation. ``bruteforce``: every face (reference, slow).
        ``auto``: ``fast`` for calls with many pose-contact pairs, else ``exact``; and
        ``exact`` throughout where the fast grid fails its check (see Notes).
    grid_cell : float, optional
        Cell size of the fast grid's finest level (m); default: largest extent / 24, but
        at least 1.5 ``sigma_pos`` (:data:`GRID_CELL_SIGMAS`; at most largest extent / 8).
    grid_margin : float, optional
        How far the finest level reaches beyond the mesh bounds (m); default: a quarter of
        the largest extent.
    grid_normals : int
        Sampled normal directions per cell for the fast grid (default 64).
    outlier_distance : float, optional
        A contact farther than this (in d_M, sigmas) from every surface point is an
        outlier: its d_M^2 is capped at ``outlier_distance**2`` (a truncated quadratic,
        the limit of a mixture of this model with a uniform density of stray contacts).
        Default None: no cap, Petrovskaya's model exactly. Use it when the mesh may be
        wrong in places, such as a mesh mapped by touch (7 is a sound choice there; see
        docs/mapping.md), or when stray contacts happen.

    Notes
    -----
    The fast method first looks, for a query near the surface, in a short list keyed by
    both its cell and its normal: the finest level's cells within three cells of the
    surface (and at least within reach of a pair costing 25 d_M^2) list, for each of 384
    normal bins (a cube map) in which the cost can be low
    (below 25 d_M^2 at a sample), the faces that win at the cell's corners for the bin's
    centre, corners and edge midpoints, and those faces' coplanar neighbours that reach
    the cell (on a flat side split into triangles, the one holding the query's projection
    wins). Built once per mesh and ``sigma_pos``, the lists
    check themselves against the exact method on 20,000 queries like those of a pose near
    the truth; where more than 1 % of their answers are off by more than 0.1 d_M^2 (faces
    small against the cells, such as a finely tessellated smooth mesh), the mesh keeps
    none (``_grid(w).near_check`` holds the check). Every other query uses the cell's general list: the faces that minimise the joint
    cost at the cell centre for ``grid_normals`` normal directions (and the closest face
    in position), minimised over, and then a walk to neighbouring faces while the cost
    falls. For joint costs the grid has three nested levels: the finest over the
    mesh bounds plus ``grid_margin``, then cells 4x and 16x as large reaching 2 and 8
    largest extents beyond the bounds (:data:`COARSE_LEVELS`), so that the far-off
    contacts of a wrongly placed pose are listed too; beyond them the exact tree answers. The result
    is never below the exact cost; position-only costs are exact (the lists then hold
    every face that can be closest anywhere in the cell), and joint costs err only when
    the winning face is missing from the list. docs/benchmarks.md reports the measured
    error. The whole fast method is checked on the same queries when its grid is built:
    where more than 1 % of them are off by more than 1 d_M^2 (half a nat of
    log-likelihood), ``auto`` uses ``exact`` for the model (a large ``sigma_pos`` on a
    curved mesh: at 3 cm on the mug 7 % were, by up to 14 d_M^2). ``method="fast"`` still
    uses the grid.
    """

    def __init__(self, obj: MeshObject, sigma_pos: float, sigma_nor: float | None = None,
                 method: str = "auto", *, grid_cell: float | None = None,
                 grid_margin: float | None = None, grid_normals: int = 64,
                 outlier_distance: float | None = None):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        sigma_pos = as_positive_float(sigma_pos, "sigma_pos (m)")
        if sigma_nor is not None:
            sigma_nor = as_positive_float(sigma_nor, "sigma_nor")
        if not isinstance(method, str) or method not in METHODS:
            raise ValidationError(f"method must be one of {METHODS}, got {method!r}")
        self.obj = obj
        self.sigma_pos = float(sigma_pos)
        self.sigma_nor = None if sigma_nor is None else float(sigma_nor)
        self.method = method
        ext = float(obj.extents.max())
        self.grid_cell = (max(ext / 24.0, min(GRID_CELL_SIGMAS * self.sigma_pos, ext / 8.0)) if grid_cell is None
                          else as_positive_float(grid_cell, "grid_cell (m)"))
        self.grid_margin = (0.25 * ext if grid_margin is None
                            else as_nonnegative_float(grid_margin, "grid_margin (m)"))
        self.grid_normals = as_count(grid_normals, "grid_normals", max=100_000,
                                     why="normals sampled per grid cell family; memory grows with it")
        self.outlier_distance = (None if outlier_distance is None
                                 else as_positive_float(outlier_distance, "outlier_distance (sigmas)"))

    def __repr__(self) -> str:
        out = f"sigma_pos={self.sigma_pos}, sigma_nor={self.sigma_nor}, method={self.method!r}"
        if self.outlier_distance is not None:
            out += f", outlier_distance={self.outlier_distance}"
        return f"ProximityModel({self.obj.name!r}, {out})"

    @property
    def cost_cap(self) -> float:
        """The largest d_M^2 a contact can cost (``outlier_distance**2``; inf without it)."""
        return np.inf if self.outlier_distance is None else self.outlier_distance**2

    # -- internals -------------------------------------------------------------------
    def _uses_normals(self, contacts) -> bool:
        """Whether these contacts' normals enter the cost (they have normals and the model
        a sigma_nor)."""
        return contacts.normals is not None and self.sigma_nor is not None

    def _weight(self, use_normals: bool) -> float:
        """Normal weight in the position-scaled cost: sigma_pos^2 / sigma_nor^2."""
        if not use_normals or self.sigma_nor is None:
            return 0.0
        return (self.sigma_pos / self.sigma_nor) ** 2

    def _resolve(self, method: str, pairs: int, w: float) -> str:
        """``auto`` made concrete for a call of ``pairs`` pose-contact pairs: ``fast`` from
        AUTO_FAST_PAIRS pairs on, where the fast grid passed its check against the exact
        method (:attr:`CandidateGrid.fast_ok`; a large sigma_pos can fail it), else
        ``exact``. Other methods are returned as they are."""
        if method != "auto":
            return method
        return "fast" if pairs >= AUTO_FAST_PAIRS and self._grid(w).fast_ok else "exact"

    def _grid_key(self, w: float) -> tuple:
        """The key of :meth:`_grid`'s structure in the mesh's cache (the near lists of a
        joint grid take their costs in d_M^2, so it holds ``sigma_pos`` too)."""
        return ("grid", w, self.grid_cell, self.grid_margin, self.grid_normals, self.sigma_pos if w > 0 else None)

    def _grid(self, w: float) -> K.CandidateGrid:
        key = self._grid_key(w)
        grid = self.obj._cache.get(key)
        if grid is None:
            lo, hi = self.obj.bounds
            ext = float(self.obj.extents.max())
            levels = [(lo - self.grid_margin, hi + self.grid_margin, self.grid_cell)]
            if w > 0:  # position-only lists of large far cells are too crowded to keep
                levels += [(lo - r * ext, hi + r * ext, f * self.grid_cell) for r, f in COARSE_LEVELS]
            tree = self.obj.bvh(w)
            # the lists keyed by the query's normal take their costs in d_M^2
            sigma2 = self.sigma_pos**2 if w > 0 else None
            grid = cached_structure(  # on disk: keyed by mesh content, parameters and builder code
                "candidate_grid", self.obj, dict(w=w, levels=np.array([np.r_[a, b, c] for a, b, c in levels]),
                                                  normals=self.grid_normals, tree_order=tree.face_id,
                                                  sigma2=-1.0 if sigma2 is None else sigma2),
                lambda: K.build_candidate_grid(tree, levels, w, self.grid_normals, sigma2=sigma2),
                K.CandidateGrid, code=(K,))
            self.obj._cache[key] = grid
        return grid

    def _bound(self, w: float):
        """The table of lower bounds of the joint cost for weight ``w`` (built once per
        mesh and weight, kept on disk; see :mod:`touchloc.models._bounds`)."""
        key = ("cost_bound", w)
        bound = self.obj._cache.get(key)
        if bound is None:
            tree = self.obj.bvh(w)
            lo, hi = self.obj.bounds
            bound = cached_structure(
                "cost_bound", self.obj, dict(w=w, cells=_bounds.CELLS_PER_EXTENT, margin=_bounds.MARGIN,
                                             bins=_bounds.BINS, tree_order=tree.face_id),
                lambda: _bounds.build_cost_bound(tree, lo, hi, w), _bounds.CostBound, code=(K, _bounds))
            self.obj._cache[key] = bound
        return bound

    def _bound_slack(self, contacts) -> float:
        """How far (m, in the joint metric) the bound table's lower bound can dilate a
        contact's cost for these contacts (see :attr:`touchloc.models._bounds.CostBound.slack`)."""
        use_n = self._uses_normals(contacts)
        return self._bound(self._weight(use_n)).slack

    def _lower_costs(self, poses, contacts, limit: float | None = None, order=None):
        """(N, K) lower bounds of :meth:`contact_costs` (d_M^2, capped like it) of trusted
        poses, from the table (:mod:`touchloc.models._bounds`): a lookup per pair. With
        ``limit`` (d_M^2), each pose takes its contacts in ``order`` until their bounds sum
        to ``limit`` or more; the pairs not reached hold 0, and a row whose sum stays below
        ``limit`` is the complete row, bit for bit."""
        use_n = self._uses_normals(contacts)
        w = self._weight(use_n)
        s2 = self.sigma_pos**2
        lower = _bounds.lower_costs(self._bound(w), poses, contacts.points, contacts.normals if use_n else None,
                                    cap=self.cost_cap * s2, limit=None if limit is None else limit * s2, order=order)
        return lower / s2

    def query_costs(self, points, normals=None, *, method: str | None = None) -> np.ndarray:
        """d_M^2 of object-frame measurements (M,) for the object at the identity pose.

        Parameters
        ----------
        points : (M, 3) float
        normals : (M, 3) float or None
        """
        P, N = check_queries(points, normals)
        use_n = N is not None and self.sigma_nor is not None
        N = N if use_n else None
        w = self._weight(use_n)
        method = self._resolve(_method(method) or self.method, len(P), w)
        if method == "bruteforce":
            _, c = K.query_bruteforce(self.obj.triangles, self.obj.face_normals, P, N, w)
        elif method == "exact":
            _, c, _ = K.query_joint(self.obj.bvh(w), P, N, 1.0, w)
        elif method == "fast":
            _, c = K.query_grid(self._grid(w), self.obj.bvh(w), P, N)
        else:
            raise ValidationError(f"method must be one of {METHODS}, got {method!r}")
        return np.minimum(c / self.sigma_pos**2, self.cost_cap)

    def contact_costs(self, poses, contacts: Contacts, *, method: str | None = None) -> np.ndarray:
        """Squared Mahalanobis distances d_M^2 per pose and contact.

        Parameters
        ----------
        poses : (N, 4, 4) float
        contacts : Contacts (K contacts, world frame)

        Returns
        -------
        (N, K) float
        """
        return self._contact_costs(as_poses(poses), _check_contacts(contacts), _method(method))

    def _contact_costs(self, poses, contacts, method=None):
        """:meth:`contact_costs` for poses and contacts an estimator has already checked
        (its own particles): no validation of the (N, 4, 4) batch."""
        method = method or self.method
        if method == "bruteforce" or type(self).query_costs is not ProximityModel.query_costs:
            # the reference, or a subclass's own queries: moved into each frame, then queried
            P, Nrm = _to_object_frame(poses, contacts)
            use_n = Nrm is not None and self.sigma_nor is not None
            c = self.query_costs(P.reshape(-1, 3), Nrm.reshape(-1, 3) if use_n else None, method=method)
            return c.reshape(len(poses), len(contacts))
        return self._budget_costs(poses, contacts, method)[0]

    def _budget_costs(self, poses, contacts, method=None, budget=None, lower=None):
        """d_M^2 per pose and contact (N, K) in one compiled pass (the contacts are moved
        into each pose's frame inside it), and which poses were evaluated completely.

        ``budget`` (N,) in d_M^2: a pose stops once the sum of its costs reaches its
        budget; its row then sums to at least the budget (the pairs after the one that
        reached it are 0) and its ``done`` entry is False. Every completed row is what
        :meth:`contact_costs` returns with the same method. ``lower`` (N, K), lower bounds
        of the costs (:meth:`_lower_costs`): a pose stops as soon as its costs so far plus
        the bounds of its other contacts reach its budget, and its pairs not evaluated hold
        their bounds.
        """
        method = method or self.method
        use_n = self._uses_normals(contacts)
        w = self._weight(use_n)
        method = self._resolve(method, len(poses) * len(contacts), w)
        if method not in ("exact", "fast"):
            raise ValidationError(f"method must be 'exact' or 'fast' here, got {method!r}")
        s2 = self.sigma_pos**2
        grid = self._grid(w) if method == "fast" else None
        c, done = K.pose_costs(self.obj.bvh(w), poses, contacts.points, contacts.normals if use_n else None, w,
                               grid=grid, budget=None if budget is None else np.asarray(budget) * s2,
                               cap=self.cost_cap * s2, lower=None if lower is None else np.asarray(lower) * s2)
        return c / s2, done

    def log_likelihood(self, poses, contacts: Contacts = None, temperature: float = 1.0) -> np.ndarray:
        """log p(contacts | pose) / temperature for each pose, (N,).

        Parameters
        ----------
        poses : (N, 4, 4) float (or one (4, 4) pose)
        contacts : Contacts
        temperature : float
            Annealing temperature T > 0: the likelihood is raised to 1/T.
        """
        T = check_temperature(temperature)
        return -0.5 * self.contact_costs(poses, contacts).sum(axis=1) / T

    def log_normalizer(self, contacts: Contacts) -> float:
        """log of the constant that makes exp(log_likelihood) a density over measurements.

        Approximates each contact's density as a surface point drawn uniformly by area,
        blurred by an isotropic Gaussian of sigma_pos across the surface normal and a
        Gaussian of sigma_nor on the normal's 2-D tangent plane:
        ``-log(area) - 1/2 log(2 pi sigma_pos^2) - log(2 pi sigma_nor^2)`` per contact.
        Needed only when comparing evidence between different objects.
        """
        contacts = _check_contacts(contacts)
        return self._log_normalizer_per_contact(contacts.has_normals) * len(contacts)

    def _log_normalizer_per_contact(self, use_normals: bool) -> float:
        """:meth:`log_normalizer` of one contact (with or without its normal)."""
        per = -np.log(self.obj.mesh.area) - 0.5 * np.log(2 * np.pi * self.sigma_pos**2)
        if use_normals and self.sigma_nor is not None:
            per -= np.log(2 * np.pi * self.sigma_nor**2)
        return float(per)


def check_queries(points, normals=None):
    """Object-frame queries: (M, 3) finite points and, if given, (M, 3) finite non-zero
    normals (returned as unit vectors), or a clear error."""
    P = np.ascontiguousarray(as_points(points, "points", allow_empty=True), dtype=np.float64)
    if normals is None:
        return P, None
    N = as_points(normals, "normals", allow_empty=True)
    if len(N) != len(P):
        raise ValidationError(f"normals must have one row per point: {len(N)} normals for {len(P)} points")
    norm = np.linalg.norm(N, axis=1)
    if np.any(norm < 1e-12):
        raise ValidationError(f"normals must be non-zero, row {int(np.flatnonzero(norm < 1e-12)[0])} is zero")
    return P, np.ascontiguousarray(N / norm[:, None])


def _method(method):
    """A likelihood method's name (or None for the model's own)."""
    if method is not None and not isinstance(method, str):
        raise ValidationError(f"method must be one of {METHODS} or None, got {type(method).__name__}")
    return method


def _check_contacts(contacts) -> Contacts:
    if not isinstance(contacts, Contacts):
        raise ValidationError(f"contacts must be a touchloc.models.Contacts, got {type(contacts).__name__}")
    if len(contacts) == 0:
        raise ValidationError("contacts is empty: a measurement model needs at least one contact")
    return contacts
