"""Rotational symmetries of a mesh, found by testing rather than declared.

A symmetry is a rotation ``g`` about the surface centroid ``c`` (``x -> R (x - c) + c``,
object frame) that maps the surface onto itself within a tolerance. Two poses ``T`` and
``T @ g`` place the same surface in the world, so a pose error that ignores this punishes
an estimator for a question the contacts cannot answer.

Method: the centroid and principal axes of the surface come from exact area moments of
the triangles. Candidate rotations are built on those axes: every turn of 2 pi / n
(n <= 12) about each principal axis, a continuous family about an axis whose two other
moments are equal (a body of revolution), and half-turns about the axes perpendicular to
it. A candidate is accepted when every one of a fixed set of surface samples, moved by
it, lies within ``tol`` of the surface (``MeshObject.closest_points``). Accepted rotations
are closed under composition. Equal moments in all three directions are tested as a
sphere; other shapes with three equal moments (a cube) are only searched about the
principal axes that the eigen-decomposition happens to return, so some of their
symmetries may be missed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from .._validate import as_bool, as_float_array, as_nonnegative_float, as_poses, as_probability
from ..errors import ValidationError

__all__ = ["Symmetry", "find_symmetries", "surface_moments"]

#: angles (rad) tried to accept a continuous axis: irrational fractions of a turn
_CONTINUOUS_TEST = np.array([0.3183, 0.7071, 1.4142, 2.2361, 3.0, 4.1231, 5.5678])


@dataclass(frozen=True)
class Symmetry:
    """The rotational symmetries of a surface.

    Attributes
    ----------
    rotations : (G, 3, 3) float
        A finite group of rotations about ``center`` (identity first). For a continuous
        axis these are the extra discrete elements (identity, and a half-turn about a
        perpendicular axis when the body is also symmetric end to end); the full group is
        every turn about ``axis`` composed with them.
    center : (3,) float
        Object-frame point every symmetry fixes (the area centroid of the surface).
    axis : (3,) float or None
        Unit axis (object frame) of continuous rotational symmetry, or None.
    continuous : bool
        True for a body of revolution or a sphere.
    sphere : bool
        Every rotation about ``center`` is a symmetry.
    tol : float
        The tolerance (m) the rotations were accepted with.
    quantile : float
        The quantile of sample displacements that had to be within ``tol``.
    """

    rotations: np.ndarray
    center: np.ndarray
    axis: np.ndarray | None = None
    continuous: bool = False
    sphere: bool = False
    tol: float = 0.0
    quantile: float = 1.0

    def __post_init__(self):
        rots = as_float_array(self.rotations, "rotations")
        rots = rots[None] if rots.shape == (3, 3) else rots
        if rots.ndim != 3 or rots.shape[1:] != (3, 3) or len(rots) == 0:
            raise ValidationError(f"rotations must be (G, 3, 3) with G >= 1, got shape {rots.shape}")
        T = np.zeros((len(rots), 4, 4))
        T[:, :3, :3], T[:, 3, 3] = rots, 1.0
        as_poses(T, "rotations")   # proper rotations, not reflections
        axis = self.axis
        if axis is not None:
            axis = as_float_array(axis, "axis", shape=(3,))
            if abs(np.linalg.norm(axis) - 1.0) > 1e-6:
                raise ValidationError(f"axis must be a unit vector, got norm {np.linalg.norm(axis):.6g}")
        continuous, sphere = as_bool(self.continuous, "continuous"), as_bool(self.sphere, "sphere")
        if continuous and not sphere and axis is None:
            raise ValidationError("a continuous symmetry that is not a sphere's needs its axis")
        object.__setattr__(self, "rotations", rots)
        object.__setattr__(self, "center", as_float_array(self.center, "center", shape=(3,)))
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "continuous", continuous)
        object.__setattr__(self, "sphere", sphere)
        object.__setattr__(self, "tol", as_nonnegative_float(self.tol, "tol"))
        object.__setattr__(self, "quantile", as_probability(self.quantile, "quantile", open_low=True))

    @property
    def order(self) -> float:
        """Number of symmetries (``inf`` for a continuous family)."""
        return float("inf") if self.continuous else len(self.rotations)

    @property
    def transforms(self) -> np.ndarray:
        """(G, 4, 4) object-frame rigid transforms of :attr:`rotations` (about ``center``)."""
        G = len(self.rotations)
        out = np.zeros((G, 4, 4))
        out[:, :3, :3] = self.rotations
        out[:, :3, 3] = self.center - self.rotations @ self.center
        out[:, 3, 3] = 1.0
        return out

    def canonical(self, quat_xyzw, t):
        """One representative per class of poses that place the surface alike.

        For a continuous symmetry, ``T`` and ``T g`` (``g`` a symmetry) are the same pose
        of the surface; this returns, for every pose, the member of its class whose
        rotation has no turn about the symmetry axis (the swing of a swing-twist
        decomposition about ``axis``; for a sphere, the identity), with the translation
        that keeps the world position of ``center``. Finite groups are returned as they
        are (they cost a constant factor, not a dimension).

        Parameters
        ----------
        quat_xyzw : (N, 4) float
            Unit quaternions of the rotations, scalar last.
        t : (N, 3) float
            Translations.

        Returns
        -------
        quat_xyzw, t : (N, 4), (N, 3) float
            Canonical poses (scalar part >= 0).
        """
        q = as_float_array(quat_xyzw, "quat_xyzw")
        q = q.reshape(1, 4) if q.shape == (4,) else q
        if q.ndim != 2 or q.shape[1] != 4:
            raise ValidationError(f"quat_xyzw must be (N, 4), got shape {q.shape}")
        norm = np.linalg.norm(q, axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-6):
            raise ValidationError(f"quat_xyzw must hold unit quaternions, got norms from "
                                  f"{norm.min():.6g} to {norm.max():.6g}")
        t = as_float_array(t, "t")
        t = t.reshape(1, 3) if t.shape == (3,) else t
        if t.shape != (len(q), 3):
            raise ValidationError(f"t must be ({len(q)}, 3) to match quat_xyzw, got shape {t.shape}")
        return self._canonical(q, t)

    def _canonical(self, q, t):
        """:meth:`canonical` without validation (the estimators' own particles)."""
        q = np.array(q, dtype=float, copy=True).reshape(-1, 4)
        t = np.array(t, dtype=float, copy=True).reshape(-1, 3)
        if not self.continuous:
            return q, t
        c = self.center
        if self.sphere:
            qc = np.zeros_like(q)
            qc[:, 3] = 1.0
        else:
            a = self.axis
            # twist about a: the quaternion's projection on a, normalised; q = swing twist
            p = q[:, :3] @ a
            n = np.hypot(p, q[:, 3])
            ok = n > 1e-9          # a half-turn swing leaves the twist undefined: keep the pose
            tw = np.zeros_like(q)
            tw[:, :3] = np.where(ok, p / np.where(ok, n, 1.0), 0.0)[:, None] * a
            tw[:, 3] = np.where(ok, q[:, 3] / np.where(ok, n, 1.0), 1.0)
            tw[:, :3] *= -1.0      # its inverse
            qc = _qmul(q, tw)
        qc *= np.where(qc[:, 3:] < 0, -1.0, 1.0)
        if not np.any(c):
            return qc, t
        # the world position of the centre stays: R c + t = R_c c + t_c
        t = t + _qrot(q, c) - _qrot(qc, c)
        return qc, t

    def canonical_poses(self, poses) -> np.ndarray:
        """:meth:`canonical` for (N, 4, 4) (or one (4, 4)) rigid poses; returns (N, 4, 4)."""
        return self._canonical_poses(as_poses(poses, "poses"))

    def _canonical_poses(self, P):
        """:meth:`canonical_poses` without validation."""
        P = np.asarray(P, dtype=float).reshape(-1, 4, 4)
        if not self.continuous:
            return P.copy()
        q, t = self._canonical(Rotation.from_matrix(P[:, :3, :3]).as_quat(), P[:, :3, 3])
        out = np.zeros_like(P)
        out[:, :3, :3] = Rotation.from_quat(q).as_matrix()
        out[:, :3, 3] = t
        out[:, 3, 3] = 1.0
        return out

    def rotation_error(self, R_est, R_true) -> np.ndarray:
        """Smallest rotation angle (rad) from ``R_true`` to ``R_est`` over the group.

        Parameters
        ----------
        R_est : (N, 3, 3) or (3, 3) float
        R_true : (3, 3) float

        Returns
        -------
        (N,) float
        """
        Re = as_float_array(R_est, "R_est")
        Re = Re[None] if Re.shape == (3, 3) else Re
        if Re.ndim != 3 or Re.shape[1:] != (3, 3):
            raise ValidationError(f"R_est must be (N, 3, 3) or (3, 3), got shape {Re.shape}")
        Rt = as_float_array(R_true, "R_true", shape=(3, 3))
        if self.sphere:
            return np.zeros(len(Re))
        rel = np.einsum("ji,njk->nik", Rt, Re)  # R_true^T R_est, object frame
        best = np.full(len(Re), np.inf)
        for g in self.rotations:
            m = rel @ g.T  # R_rel g^-1
            if self.continuous:
                # distance to the subgroup of turns about a: the angle between a and m a
                c = np.clip(m @ self.axis @ self.axis, -1.0, 1.0)
                ang = np.arccos(c)
            else:
                ang = np.arccos(np.clip((np.trace(m, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
            best = np.minimum(best, ang)
        return best


def _qmul(p, q):
    """Hamilton products p q of (N, 4) quaternions (x, y, z, w): the rotation q, then p."""
    pv, pw = p[:, :3], p[:, 3:]
    qv, qw = q[:, :3], q[:, 3:]
    return np.concatenate([pw * qv + qw * pv + np.cross(pv, qv), pw * qw - np.sum(pv * qv, axis=1, keepdims=True)],
                          axis=1)


def _qrot(q, v):
    """(N, 3) the vector v (3,) rotated by each unit quaternion of q (N, 4), scalar last."""
    x, y, z, w = q.T
    # u x v, then v + 2 (w (u x v) + u x (u x v)), written out (np.cross is slow on (N, 3))
    a = y * v[2] - z * v[1]
    b = z * v[0] - x * v[2]
    c = x * v[1] - y * v[0]
    return np.stack([v[0] + 2.0 * (w * a + y * c - z * b),
                     v[1] + 2.0 * (w * b + z * a - x * c),
                     v[2] + 2.0 * (w * c + x * b - y * a)], axis=1)


def surface_moments(obj):
    """Area, centroid (3,) and central second moment (3, 3) of the surface (exact)."""
    tri = obj.triangles
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    A = area.sum()
    s = a + b + c
    centroid = (area[:, None] * s).sum(0) / (3.0 * A)
    # integral of x x^T over a triangle: A/12 (s s^T + a a^T + b b^T + c c^T)
    M = np.einsum("f,fi,fj->ij", area, s, s) + sum(np.einsum("f,fi,fj->ij", area, v, v) for v in (a, b, c))
    M = M / (12.0 * A)
    return float(A), centroid, M - np.outer(centroid, centroid)


def _axis_rot(axis, angles):
    return Rotation.from_rotvec(np.outer(np.atleast_1d(angles), axis)).as_matrix()


# a direction no face, vertex or axis of a regular shape lies across: the sign that makes
# an axis' direction positive along it is its one representative
_GENERIC = np.array([0.5773, 0.5774, 0.5775])
_AXIS_SCAN = 4096   # directions of each kind looked at, largest first (a dense mesh's are many)


def _shape_axes(obj, c, n_axes: int = 24):
    """Candidate axes of symmetry through ``c`` for a shape whose second moments are all
    equal: the directions (up to sign, merged within 3 degrees) of the faces' normals
    weighted by area, of the vertices farthest from ``c``, and of the faces' centres,
    the ``n_axes`` of each kind that carry the most area or lie farthest out."""
    tri = obj.triangles
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    kinds = []
    ok = area > 0
    kinds.append((nrm[ok] / (2.0 * area[ok, None]), area[ok]))
    v = obj.mesh.vertices - c
    rv = np.linalg.norm(v, axis=1)
    kinds.append((v[rv > 0] / rv[rv > 0, None], rv[rv > 0]))
    fc = tri.mean(axis=1) - c
    rf = np.linalg.norm(fc, axis=1)
    kinds.append((fc[rf > 0] / rf[rf > 0, None], area[rf > 0] * rf[rf > 0]))
    out = []
    cos_merge = np.cos(np.radians(3.0))
    for d, w in kinds:
        d = np.where((d @ _GENERIC < 0)[:, None], -d, d)   # one sign per axis
        chosen, weight = [], []
        for i in np.argsort(-w, kind="stable")[:_AXIS_SCAN]:
            if chosen:
                cos = np.abs(np.asarray(chosen) @ d[i])
                k = int(np.argmax(cos))
                if cos[k] >= cos_merge:
                    weight[k] += w[i]
                    continue
            chosen.append(d[i])
            weight.append(w[i])
            if len(chosen) >= 4 * n_axes:
                break
        order = np.argsort(-np.asarray(weight), kind="stable")[:n_axes]
        out.extend(np.asarray(chosen)[order])
    return out


def _perpendicular(axis):
    u = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


class _Tester:
    """Worst displacement (m) of surface samples under candidate rotations about c."""

    def __init__(self, obj, center, n, rng, quantile):
        self.obj = obj
        self.quantile = quantile
        self.c = center
        self.p = obj.sample_surface(n, rng=rng)[0] - center

    def __call__(self, R):
        R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
        q = np.einsum("gij,nj->gni", R, self.p) + self.c
        _, _, d = self.obj.closest_points(q.reshape(-1, 3))
        return np.quantile(d.reshape(len(R), -1), self.quantile, axis=1)


_CLOSE_LIMIT = 120     # a closure this large is taken for one that does not close
_MAX_GENERATORS = 24   # candidates _passing_group tries, best first


def _close(rots, limit=_CLOSE_LIMIT):
    """Closure of a set of rotations under composition (deduplicated), identity first; at
    most ``limit`` rotations.

    Near-symmetries of a shape that has none exactly (a mapped, slightly lumpy spheroid
    passes many half-turns within the tolerance) compose into ever new rotations: the set
    stops growing at ``limit``, and the caller keeps only the elements that pass its test.
    Products are made, and checked against the set, one left factor at a time in one
    array operation, in the order of a double loop over the set.
    """
    out = [np.eye(3)]

    def merge(cands):
        for R in cands:
            if len(out) >= limit:
                return
            if np.abs(np.asarray(out) - R).max(axis=(1, 2)).min() >= 1e-6:
                out.append(R)

    merge(rots)
    changed = True
    while changed and len(out) < limit:
        changed = False
        for A in list(out):
            if len(out) >= limit:
                break
            P = A @ np.asarray(out)
            # products already in the set are skipped without a Python loop
            new = cdist(P.reshape(-1, 9), np.asarray(out).reshape(-1, 9), "chebyshev").min(axis=1) >= 1e-6
            n0 = len(out)
            merge(P[new])
            changed = changed or len(out) > n0
    return np.array(out)


_EQ_TOL = 0.03   # second moments this close (relative to the largest) count as equal
# find_symmetries' defaults, which the sphere's test alone (_find_sphere) shares
_QUANTILE, _N_SAMPLES, _RNG = 0.95, 400, 0


def _rel(ev, i, j) -> float:
    """The difference of principal moments i and j relative to the largest."""
    return abs(ev[i] - ev[j]) / max(ev.max(), 1e-30)


def _setup(obj, tol, quantile, n_samples, rng):
    """The tolerance, the surface's centroid and principal moments and axes, and the test
    of candidate rotations, as :func:`find_symmetries` uses them."""
    if tol is None:
        tol = 0.02 * float(obj.extents.max())
    if not (np.isfinite(tol) and tol > 0):
        raise ValidationError(f"tol must be a positive distance in metres, got {tol}")
    _, c, C = surface_moments(obj)
    ev, vec = np.linalg.eigh(C)
    if not 0 < quantile <= 1:
        raise ValidationError(f"quantile must be in (0, 1], got {quantile}")
    return tol, c, ev, vec, _Tester(obj, c, int(n_samples), rng, float(quantile))


def _sphere(tol, c, ev, test, quantile) -> Symmetry | None:
    """A sphere's symmetry if all moments are equal and random rotations fit, else None."""
    if _rel(ev, 0, 2) < _EQ_TOL:
        R = Rotation.random(6, random_state=1).as_matrix()
        if np.all(test(R) <= tol):
            return Symmetry(np.eye(3)[None], c, None, True, True, tol, quantile)
    return None


def _find_sphere(obj, tol: float | None = None) -> Symmetry | None:
    """The first test of :func:`find_symmetries` alone, with its defaults: ``obj``'s
    symmetry if it is a sphere, else None (the same answer as ``find_symmetries(obj,
    tol)`` for a sphere, without the other tests where the object is not one)."""
    tol, c, ev, _, test = _setup(obj, tol, _QUANTILE, _N_SAMPLES, _RNG)
    return _sphere(tol, c, ev, test, _QUANTILE)


#: random rotations the near-sphere's deviation is the worst of
_NEAR_SPHERE_ROTATIONS = 24


def _near_sphere(obj) -> Symmetry:
    """The sphere's symmetry at the tolerance ``obj`` passes it with: the largest, over
    random rotations about the surface centroid, of the sphere test's displacement (the
    :data:`_QUANTILE` of the moved surface samples' distances to the surface), with
    :func:`find_symmetries`' samples. A lemon 45 x 40 x 40 mm deviates 2.5 mm; a box or a
    mug a fifth to two fifths of its size.

    Every rotation about the centroid moves the surface by about ``tol`` or less, so a
    search that resolves no finer than a few times ``tol`` may take the object for a
    sphere (:class:`~touchloc.belief.ScalingSeries`' wide scales); the moments are not
    tested."""
    _, c, _, _, test = _setup(obj, 1.0, _QUANTILE, _N_SAMPLES, _RNG)
    R = Rotation.random(_NEAR_SPHERE_ROTATIONS, random_state=1).as_matrix()
    dev = float(np.max(test(R)))
    return Symmetry(np.eye(3)[None], c, None, True, True, max(dev, 1e-12), _QUANTILE)


def find_symmetries(obj, tol: float | None = None, *, quantile: float = _QUANTILE, n_samples: int = _N_SAMPLES,
                    rng=_RNG, max_order: int = 12) -> Symmetry:
    """The rotations that map ``obj``'s surface onto itself within ``tol``.

    Parameters
    ----------
    obj : MeshObject
    tol : float, optional
        Largest distance (m) of a moved surface sample from the surface; default 2 % of
        the largest extent (this absorbs the facets of a tessellated cylinder).
    quantile : float
        Which quantile of the moved samples' distances must be within ``tol``: 1.0
        demands all of them; the default 0.95 lets small features (a can's pull tab,
        under 5 % of the area) not break a symmetry that the rest of the surface has.
    n_samples : int
        Surface samples used to test each candidate.
    rng : None, int or Generator
        For the samples (fixed by default, so the answer is repeatable).
    max_order : int
        Largest n of the 2 pi / n turns tried about each axis.

    Returns
    -------
    Symmetry
    """
    tol, c, ev, vec, test = _setup(obj, tol, quantile, n_samples, rng)
    rel = lambda i, j: _rel(ev, i, j)  # noqa: E731
    eq_tol = _EQ_TOL
    sphere = _sphere(tol, c, ev, test, quantile)
    if sphere is not None:
        return sphere
    # an axis whose two other moments are equal may be an axis of revolution
    special_i = None
    if rel(0, 1) < eq_tol and rel(1, 2) >= eq_tol:
        special_i = 2
    elif rel(1, 2) < eq_tol and rel(0, 1) >= eq_tol:
        special_i = 0
    special = None if special_i is None else vec[:, special_i]
    if special is not None:
        if np.all(test(_axis_rot(special, _CONTINUOUS_TEST)) <= tol):
            a = special / np.linalg.norm(special)
            u, v = _perpendicular(a)
            phis = np.linspace(0, np.pi, 19)[:-1]
            flips = np.array([_axis_rot(np.cos(p) * u + np.sin(p) * v, np.pi)[0] for p in phis])
            # an end-to-end flip turns about the middle of the body along the axis, which
            # a small feature at one end (a pull tab) moves the area centroid away from
            h = obj.mesh.vertices @ a
            mid = c + a * (0.5 * (h.min() + h.max()) - c @ a)
            best = None
            for centre in (c, mid):
                flip_test = _Tester(obj, centre, int(n_samples), rng, float(quantile))
                ok = flip_test(flips) <= tol
                if ok.any():
                    best = (centre, flips[int(np.argmax(ok))])
                    break
            rots = [np.eye(3)] + ([best[1]] if best else [])
            centre = best[0] if best else c
            return Symmetry(np.array(rots), centre, a, True, False, tol, quantile)
    found = []
    for i in range(3):
        for n in range(2, max_order + 1):
            if n > 2 and i != special_i:
                break  # distinct moments admit only half-turns about a principal axis
            R = _axis_rot(vec[:, i], 2 * np.pi / n)
            if test(R)[0] <= tol:
                found.append(R[0])
    if rel(0, 2) < eq_tol:
        # equal moments without a sphere's symmetry (a cube, a regular tetrahedron,
        # octahedron or icosahedron): the principal axes are arbitrary, and the turns are about axes
        # the surface itself shows, through its faces' normals and its vertices
        # (the rotation groups of the regular solids turn by 2 pi / n, n <= 5, about them)
        for a in _shape_axes(obj, c):
            R = _axis_rot(a, 2 * np.pi / np.arange(2, min(max_order, 6) + 1))
            found.extend(R[test(R) <= tol])
    if special is not None:
        # half-turns about axes perpendicular to the special one, at 1 degree steps
        u, v = _perpendicular(special)
        phis = np.radians(np.arange(0.0, 180.0, 1.0))
        cand = np.array([_axis_rot(np.cos(p) * u + np.sin(p) * v, np.pi)[0] for p in phis])
        d = test(cand)
        for i in np.flatnonzero(d <= tol):
            # keep local minima only (neighbouring angles pass around the same flip)
            if d[i] <= d[(i - 1) % len(d)] and d[i] <= d[(i + 1) % len(d)]:
                found.append(cand[i])
    group = _close(found)
    if len(group) >= _CLOSE_LIMIT or (len(group) > 1 and not np.all(test(group[1:]) <= tol)):
        # near-symmetries that do not compose into a group that passes (a mapped, slightly
        # lumpy shape passes dozens of half-turns whose products do not)
        group = _passing_group(found, test, tol)
    return Symmetry(group, c, None, False, False, tol, quantile)




def _passing_group(found, test, tol):
    """A group of rotations that all pass ``test`` within ``tol``, generated greedily: the
    candidates in ``found`` are tried best first, and each is kept if the closure of the
    kept ones with it is finite (under the limit) and passes in every element."""
    found = np.asarray(found)
    group, gens = np.eye(3)[None], []
    for i in np.argsort(test(found), kind="stable")[:_MAX_GENERATORS]:
        R = found[i]
        if np.abs(group - R).max(axis=(1, 2)).min() < 1e-6:
            continue   # already in the group
        trial = _close(gens + [R])
        if len(trial) < _CLOSE_LIMIT and np.all(test(trial[1:]) <= tol):
            gens.append(R)
            group = trial
    return group
