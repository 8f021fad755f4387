"""MeshObject: a known rigid object as a triangle mesh, with cached geometric queries."""

from __future__ import annotations

import warnings

import numpy as np
import trimesh

from .._util import as_points, as_rng
from .._validate import MAX_PARTICLES, as_bool, as_count, as_name, as_nonnegative_float, as_path, as_positive_float
from ..errors import MeshError, ValidationError

__all__ = ["MeshObject", "MeshRepairWarning", "MeshUnitsWarning"]


class MeshRepairWarning(UserWarning):
    """A mesh was repaired (faces dropped, vertices merged) or is not closed."""


class MeshUnitsWarning(UserWarning):
    """A mesh's size suggests it is not in metres."""


#: Extents (m) outside which a mesh is probably not in metres.
PLAUSIBLE_EXTENT = (0.005, 1.0)
_AREA_EPS = 1e-12  # m^2: faces smaller than this have no usable normal


class MeshObject:
    """A rigid object described by a triangle mesh in its own frame (metres).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface. It is copied, vertices are merged by position (closing texture
        seams), zero-area faces are dropped with a warning, and an open surface is
        accepted with a warning.
    name : str, optional
        A label for printing and for identification among several objects.
    check_units : bool
        Warn when the extents suggest the mesh is not in metres (default True).

    Notes
    -----
    Expensive structures (bounding-volume hierarchies, the ray-casting scene, cost
    fields) are built on first use and cached on the instance; they are never rebuilt
    per query. The object is treated as immutable.
    """

    def __init__(self, mesh, *, name: str | None = None, check_units: bool = True):
        if not isinstance(mesh, trimesh.Trimesh):
            raise MeshError(f"MeshObject needs a trimesh.Trimesh, got {type(mesh).__name__}")
        name = as_name(name, "name")
        check_units = as_bool(check_units, "check_units")
        self.name = name or "mesh"
        self.mesh = _repair(mesh, self.name)
        self.repairs = self.mesh.metadata.pop("touchloc_repairs", [])
        #: indices (into mesh.faces) of the faces with a usable normal; ``triangles``,
        #: ``face_normals`` and the face indices of queries refer to this subset
        self.valid_faces = self.mesh.metadata.pop("touchloc_valid_faces")
        self._cache: dict = {}
        ext = self.mesh.extents
        if check_units and (ext.max() > PLAUSIBLE_EXTENT[1] or ext.max() < PLAUSIBLE_EXTENT[0]):
            warnings.warn(
                f"{self.name}: extents {np.round(ext, 4).tolist()} m are implausible for an "
                f"object touched by a hand ({PLAUSIBLE_EXTENT[0]}-{PLAUSIBLE_EXTENT[1]} m); "
                "is the file in metres? Pass scale= to MeshObject.from_file.",
                MeshUnitsWarning,
                stacklevel=2,
            )

    # -- construction ----------------------------------------------------------------
    @classmethod
    def from_file(cls, path, *, scale: float = 1.0, name: str | None = None, **kwargs) -> "MeshObject":
        """Load a mesh file (any format trimesh reads), scale it to metres and wrap it.

        Parameters
        ----------
        path : str or Path
        scale : float
            Factor applied to the vertices (e.g. 0.001 for a file in millimetres).
        """
        path = as_path(path, "mesh file", must_exist=False)
        if not path.exists():
            raise MeshError(f"mesh file not found: {path}")
        if not path.is_file():
            raise MeshError(f"mesh file must be a regular file, got {path}" + (" (a directory)" if path.is_dir() else ""))
        scale = as_positive_float(scale, "scale")
        name = as_name(name, "name")
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise MeshError(f"could not read mesh {path}: {exc}") from exc
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
            raise MeshError(f"{path} holds no triangles")
        mesh = trimesh.Trimesh(np.asarray(loaded.vertices, dtype=np.float64) * scale, loaded.faces, process=False)
        return cls(mesh, name=name or path.stem, **kwargs)

    # -- basic properties ------------------------------------------------------------
    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float: vertex coordinates of each face with a usable normal."""
        t = self._cache.get("triangles")
        if t is None:
            t = np.ascontiguousarray(self.mesh.triangles[self.valid_faces], dtype=np.float64)
            t.flags.writeable = False
            self._cache["triangles"] = t
        return t

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float: outward unit normal of each face in :attr:`triangles`."""
        n = self._cache.get("face_normals")
        if n is None:
            n = np.ascontiguousarray(self.mesh.face_normals[self.valid_faces], dtype=np.float64)
            n.flags.writeable = False
            self._cache["face_normals"] = n
        return n

    @property
    def n_faces(self) -> int:
        """Number of faces with a usable normal."""
        return len(self.valid_faces)

    @property
    def is_watertight(self) -> bool:
        return bool(self.mesh.is_watertight)

    @property
    def extents(self) -> np.ndarray:
        return self.mesh.extents.copy()

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float: axis-aligned bounds in the object frame."""
        return self.mesh.bounds.copy()

    @property
    def radius(self) -> float:
        """Largest distance from the object-frame origin to a vertex (m)."""
        r = self._cache.get("radius")
        if r is None:
            r = float(np.linalg.norm(self.mesh.vertices, axis=1).max())
            self._cache["radius"] = r
        return r

    def __repr__(self) -> str:
        closed = "watertight" if self.is_watertight else "open"
        return f"MeshObject({self.name!r}, faces={self.n_faces}, extents={np.round(self.extents, 4).tolist()}, {closed})"

    # -- queries ---------------------------------------------------------------------
    def closest_points(self, points):
        """Closest surface points to query points in the object frame.

        Parameters
        ----------
        points : (M, 3) float

        Returns
        -------
        closest : (M, 3) float
        normals : (M, 3) float
            Unit normal of the face the closest point lies on.
        distances : (M,) float
            Euclidean distance from each query to its closest point.
        """
        P = as_points(points, "points", allow_empty=True)
        from ._kernels import query_joint

        tree = self.bvh(0.0)
        face, cost, closest = query_joint(tree, P, None, 1.0, 0.0)
        return closest, self.face_normals[face], np.sqrt(cost)

    def ray_cast(self, origins, directions):
        """First intersection of rays with the surface (embreex).

        Parameters
        ----------
        origins, directions : (M, 3) float
            Directions need not be unit length (they are normalised); zero directions
            are rejected.

        Returns
        -------
        distances : (M,) float
            Distance along the unit direction to the first hit; ``inf`` on a miss.
        points : (M, 3) float
            Hit points (NaN on a miss).
        normals : (M, 3) float
            Unit normal of the hit face (NaN on a miss).
        """
        O = as_points(origins, "origins", allow_empty=True)
        D = as_points(directions, "directions", allow_empty=True)
        if O.shape != D.shape:
            raise ValidationError(f"origins {O.shape} and directions {D.shape} must have the same shape")
        norm = np.linalg.norm(D, axis=1)
        if np.any(norm <= 0):
            raise ValidationError("directions must be non-zero")
        D = D / norm[:, None]
        M = O.shape[0]
        dist = np.full(M, np.inf)
        pts = np.full((M, 3), np.nan)
        nrm = np.full((M, 3), np.nan)
        if M == 0:
            return dist, pts, nrm
        tri = self.mesh.ray.intersects_first(ray_origins=O, ray_directions=D)
        hit = tri >= 0
        if np.any(hit):
            # Exact hit distance in float64 by intersecting the hit face's plane.
            f = tri[hit]
            n = np.asarray(self.mesh.face_normals, dtype=np.float64)[f]
            v0 = np.asarray(self.mesh.vertices, dtype=np.float64)[self.mesh.faces[f, 0]]
            denom = np.einsum("ij,ij->i", D[hit], n)
            t = np.einsum("ij,ij->i", v0 - O[hit], n) / np.where(np.abs(denom) < 1e-15, 1e-15, denom)
            t = np.maximum(t, 0.0)
            dist[hit] = t
            pts[hit] = O[hit] + t[:, None] * D[hit]
            nrm[hit] = n
        return dist, pts, nrm

    def contains(self, points) -> np.ndarray:
        """(M,) bool: whether each object-frame point is inside the closed surface.

        For open meshes (e.g. the mug's handle) the answer near the opening is the ray
        parity trimesh computes and may be wrong; closed meshes are exact up to float32
        ray precision.
        """
        P = as_points(points, "points", allow_empty=True)
        if len(P) == 0:
            return np.zeros(0, dtype=bool)
        return np.asarray(self.mesh.contains(P), dtype=bool)

    def signed_distance(self, points) -> np.ndarray:
        """(M,) float: distance to the surface, negative inside, positive outside (m)."""
        _, _, d = self.closest_points(points)
        inside = self.contains(points)
        return np.where(inside, -d, d)

    def sample_surface(self, n: int, *, rng=None):
        """Sample points uniformly by area on the surface.

        Returns
        -------
        points : (n, 3) float
        normals : (n, 3) float
        faces : (n,) int
            Indices into :attr:`triangles`.
        """
        n = as_count(n, "n", min=0, max=MAX_PARTICLES, why="memory: 1e7 samples take 0.6 GB")
        rng = as_rng(rng)
        area = self.mesh.area_faces[self.valid_faces]
        faces = rng.choice(len(area), size=n, p=area / area.sum())
        u = rng.random((n, 2))
        flip = u.sum(axis=1) > 1.0
        u[flip] = 1.0 - u[flip]
        tri = self.triangles[faces]
        pts = tri[:, 0] + u[:, :1] * (tri[:, 1] - tri[:, 0]) + u[:, 1:] * (tri[:, 2] - tri[:, 0])
        return pts, self.face_normals[faces].copy(), faces

    def symmetries(self, tol: float | None = None):
        """Rotations that map the surface onto itself within ``tol`` (m), cached.

        Returns a :class:`touchloc.models.symmetry.Symmetry`: a finite group, a
        continuous axis (body of revolution) or a sphere. ``tol`` defaults to 2 % of the
        largest extent. See :func:`touchloc.models.symmetry.find_symmetries`.
        """
        from .symmetry import find_symmetries

        key = ("symmetries", None if tol is None else as_positive_float(tol, "tol"))
        sym = self._cache.get(key)
        if sym is None:
            sym = find_symmetries(self, tol)
            self._cache[key] = sym
        return sym

    def _sphere_symmetry(self):
        """:meth:`symmetries` if it is a sphere's, else None: only its first test (cached),
        unless the whole search has run already."""
        full = self._cache.get(("symmetries", None))
        if full is not None:
            return full if full.sphere else None
        if "sphere" not in self._cache:
            from .symmetry import _find_sphere

            self._cache["sphere"] = _find_sphere(self)
        return self._cache["sphere"]

    def _near_sphere(self):
        """The sphere's symmetry at the tolerance this surface passes it with (its
        deviation from a sphere, :func:`touchloc.models.symmetry._near_sphere`; cached)."""
        if "near sphere" not in self._cache:
            from .symmetry import _near_sphere

            self._cache["near sphere"] = _near_sphere(self)
        return self._cache["near sphere"]

    def bvh(self, normal_weight: float):
        """The cached bounding-volume hierarchy used by exact queries.

        ``normal_weight`` is the ratio of the normal to the position term of the joint
        cost (sigma_pos^2 / sigma_nor^2, in m^2); 0 for position-only queries. The tree's
        topology depends on it (rounded to 2 significant digits); its bounds do not.
        """
        # the likelihood asks once per batch of poses: a weight seen before is answered at once
        seen = ("bvh for", normal_weight) if type(normal_weight) is float else None
        tree = self._cache.get(seen)
        if tree is not None:
            return tree
        from .._cache import cached_structure
        from . import _kernels
        from ._kernels import BVH, build_bvh

        key = ("bvh", float(f"{as_nonnegative_float(normal_weight, 'normal_weight'):.2g}"))
        tree = self._cache.get(key)
        if tree is None:
            tree = cached_structure("bvh", self, {"normal_weight": key[1]},  # on disk when slow to build
                                    lambda: build_bvh(self.triangles, self.face_normals, np.sqrt(key[1])),
                                    BVH, code=(_kernels,))
            self._cache[key] = tree
        if seen is not None:
            self._cache[seen] = tree
        return tree


def _repair(mesh: trimesh.Trimesh, name: str) -> trimesh.Trimesh:
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.faces)
    if len(V) == 0 or len(F) == 0:
        raise MeshError(f"{name}: the mesh is empty ({len(V)} vertices, {len(F)} faces)")
    if not np.all(np.isfinite(V)):
        raise MeshError(f"{name}: the mesh has non-finite vertex coordinates")
    if F.min() < 0 or F.max() >= len(V):
        raise MeshError(f"{name}: face indices out of range")
    repairs = []
    m = trimesh.Trimesh(V, F, process=False)
    nv = len(m.vertices)
    m.merge_vertices(merge_tex=True, merge_norm=True)
    if len(m.vertices) < nv:
        repairs.append(f"merged {nv - len(m.vertices)} duplicate vertices")
    area = m.area_faces
    f = m.faces
    bad = ~(area > _AREA_EPS) | (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if bad.all():
        raise MeshError(f"{name}: every face is degenerate (zero area); nothing usable remains")
    if bad.any():
        # A zero-area face has no normal. It is kept in the surface (dropping it would
        # open the mesh along its edges) but ignored by every query that needs normals;
        # its points lie on its neighbours' edges, so distances do not change.
        repairs.append(f"ignoring {int(bad.sum())} zero-area faces (no normal)")
    # Make face winding consistent and outward where trimesh can (closed meshes).
    if m.is_watertight and m.volume < 0:
        m.invert()
        repairs.append("inverted inside-out faces")
    if repairs:
        warnings.warn(f"{name}: repaired mesh: " + "; ".join(repairs), MeshRepairWarning, stacklevel=3)
    if not m.is_watertight:
        warnings.warn(
            f"{name}: the surface is open (not watertight); contains() and free-space "
            "reasoning are approximate near openings",
            MeshRepairWarning,
            stacklevel=3,
        )
    m.metadata["touchloc_repairs"] = repairs
    m.metadata["touchloc_valid_faces"] = np.flatnonzero(~bad)
    return m
