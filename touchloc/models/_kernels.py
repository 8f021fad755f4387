"""Compiled kernels for the joint position/normal nearest-face query.

The query: for points p and (optional) unit normals n in the object frame, find

    cost(p, n) = min_f  |p - closest_f(p)|^2 + w * |n - n_f|^2

over the mesh faces f, where closest_f(p) is the closest point of triangle f and
w = sigma_pos^2 / sigma_nor^2 (w = 0: position only). Dividing by sigma_pos^2 gives
d_M^2 of Petrovskaya's proximity model (eq. 42.4-42.5).

Three evaluators share the triangle routine:

* ``query_bruteforce``: every face, every query (the reference);
* ``query_joint``: a bounding-volume hierarchy with branch-and-bound on a lower bound of
  the joint cost (box distance in position plus box distance in normal space): exact;
* ``query_grid``: a precomputed grid (nested levels, finest near the mesh) whose cells
  list the faces that win at the cell centre for a set of sampled normals (and, in
  position-only mode, every face that can be closest anywhere in the cell); the minimum
  is taken over that list and a greedy walk over neighbouring faces. Near the surface a
  joint query first looks in a shorter list keyed by its normal's cube-map bin as well
  as its cell (:func:`build_near_lists`). Exact in position-only mode, an approximation
  with measured error otherwise.

Every evaluator skips a face whose lower bound (squared distance to its plane plus the
normal term) is already above the best cost, before the closest-point routine; the near
lists use a tighter bound that adds the in-plane distance outside the triangle's edges
and is the cost itself over the triangle (:func:`_face_lb_edges`).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._cache import numba_cache_enabled
from .._util import progress

_LEAF = 4
_STACK = 128
# cache=: compiled code kept on disk when numba has a writable place for it (see touchloc._cache)
_NB = dict(cache=numba_cache_enabled(__file__), fastmath=False, nogil=True)

#: The one-thread kernels are compiled with numba's parallel pipeline too, over a plain
#: ``range``: the same loop compiled without it ran 1.9-2.3x slower on one core (the pose-cost
#: kernel, 100-8000 pose-contact pairs on the mug, numba 0.68; docs/benchmarks.md, "Localisation
#: speed with few contacts").
_SERIAL = dict(_NB, parallel=True)
# ... which makes numba warn, at compile time, that it found nothing to run in parallel there
warnings.filterwarnings("ignore", message=r"(?s).*'parallel=True' was specified but no transformation",
                        category=nb.NumbaPerformanceWarning)

#: Below this many queries the kernels run on one thread: starting the thread pool costs
#: more than it saves (and much more on a loaded machine).
PARALLEL_MIN = 4096


def kernel_array(a, dtype=np.float64):
    """``a`` as the kernels take every array: C-contiguous, ``dtype`` and writeable.

    numba compiles a kernel once per signature, and an array's layout and its read-only
    flag are part of the signature: a read-only input (a :class:`Contacts`' frozen points,
    an array loaded read-only) would compile the whole kernel a second time, which takes
    minutes. Converting here keeps one signature per kernel; a read-only input is copied
    (the arrays passed this way are contacts, poses and per-pose rows, small beside the
    work done on them).
    """
    return np.require(a, dtype, ("C", "W"))


class _ThreadChoice:
    """Picks the one-thread or the parallel version of a kernel for calls of middling size
    by their measured speed.

    Calls of ``low`` to ``high`` items (pose-contact pairs) gain from the thread pool on an
    idle machine and lose on a loaded one, where a parallel region waits for a thread that
    shares its core (docs/benchmarks.md, "Localisation speed with few contacts"). Each
    version's time per item is tracked (an exponential average over such calls); the faster
    one runs, and every ``explore``-th call runs the other, so that a change of load is
    seen. Both versions compute each row alike: the choice changes the time, never the
    result. Races between threads only blur the averages.
    """

    def __init__(self, low: int, high: int, explore: int = 64):
        self.low, self.high, self.explore = int(low), int(high), int(explore)
        self.rate = [None, None]     # seconds per item: one thread, parallel
        self._seen = [0, 0]
        self._calls = 0

    def pick(self, items: int) -> int:
        """0 (one thread) or 1 (parallel)."""
        if items >= self.high:
            return 1
        if items < self.low:
            return 0
        self._calls += 1
        one, par = self.rate
        if one is None or par is None:
            return 0 if one is None else 1
        best = 0 if one <= par else 1
        return 1 - best if self._calls % self.explore == 0 else best

    def record(self, which: int, items: int, seconds: float) -> None:
        if not self.low <= items < self.high:
            return
        self._seen[which] += 1
        if self._seen[which] == 1:
            return    # the first call may have loaded or compiled the kernel
        r = seconds / items
        old = self.rate[which]
        self.rate[which] = r if old is None else 0.8 * old + 0.2 * r


#: the pose-cost kernel's choice: 512 pairs take about 0.15 ms on one thread (mug)
POSE_COSTS_THREADS = _ThreadChoice(512, PARALLEL_MIN)


# ---------------------------------------------------------------------------------------
# geometry
#
# Inlining. The small helpers below are inlined into their callers in numba's IR
# (``inline="always"``): a call that passes arrays costs a reference count on each, which
# made the exact tree's query 1.5-2.4x slower when its descent was a call. The closest
# point on a triangle is the exception: it takes and returns scalars, so a call costs next
# to nothing, while its body, inlined into the five places each likelihood kernel reaches
# it, made the kernels' compilation 1.7x longer (355 s against 209 s for every kernel on
# one core of the reference machine; query times unchanged within the noise).
@nb.njit(**_NB)
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@nb.njit(inline="always", **_NB)
def _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w):
    qx, qy, qz = _closest_on_triangle(
        px, py, pz,
        tri[f, 0, 0], tri[f, 0, 1], tri[f, 0, 2],
        tri[f, 1, 0], tri[f, 1, 1], tri[f, 1, 2],
        tri[f, 2, 0], tri[f, 2, 1], tri[f, 2, 2],
    )
    c = (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2
    if w > 0.0:
        c += w * ((nx - nrm[f, 0]) ** 2 + (ny - nrm[f, 1]) ** 2 + (nz - nrm[f, 2]) ** 2)
    return c, qx, qy, qz


@nb.njit(inline="always", **_NB)
def _face_lb(tri, nrm, f, px, py, pz, nx, ny, nz, w):
    """A lower bound of face f's joint cost that skips the triangle: the squared distance
    to the face's plane plus the normal term. Valid because n_f is the unit normal of the
    face's plane (MeshObject's face normals are; degenerate faces are not queried)."""
    s = ((px - tri[f, 0, 0]) * nrm[f, 0] + (py - tri[f, 0, 1]) * nrm[f, 1]
         + (pz - tri[f, 0, 2]) * nrm[f, 2])
    lb = s * s
    if w > 0.0:
        lb += w * ((nx - nrm[f, 0]) ** 2 + (ny - nrm[f, 1]) ** 2 + (nz - nrm[f, 2]) ** 2)
    return lb


def face_planes(tri: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """(F, 16) per face: its unit normal and plane offset, then for each edge the unit
    normal within the face's plane pointing out of the triangle, and its offset.

    For a point p, ``n . p - d`` is its signed distance to the plane and each edge's
    ``m . p - e`` its in-plane distance outside that edge (negative inside); see
    :func:`_face_lb_edges`.
    """
    tri = np.asarray(tri, dtype=np.float64)
    nrm = np.asarray(nrm, dtype=np.float64)
    out = np.zeros((len(tri), 16))
    out[:, 0:3] = nrm
    out[:, 3] = np.einsum("ij,ij->i", nrm, tri[:, 0])
    for k in range(3):
        a, b, c = tri[:, k], tri[:, (k + 1) % 3], tri[:, (k + 2) % 3]
        m = np.cross(b - a, nrm)
        length = np.linalg.norm(m, axis=1, keepdims=True)
        m = np.divide(m, length, out=np.zeros_like(m), where=length > 0)
        e = np.einsum("ij,ij->i", m, a)
        flip = np.einsum("ij,ij->i", m, c) > e  # the third vertex lies inside
        m[flip] *= -1.0
        e[flip] *= -1.0
        out[:, 4 + 4 * k:7 + 4 * k] = m
        out[:, 7 + 4 * k] = e
    return out


@nb.njit(inline="always", **_NB)
def _plane_cost(planes, f, px, py, pz, nx, ny, nz, w):
    """Face f's plane distance squared plus its normal term (:func:`face_planes`): its cost
    where the point projects into the triangle, and a lower bound of it elsewhere."""
    s = px * planes[f, 0] + py * planes[f, 1] + pz * planes[f, 2] - planes[f, 3]
    return s * s + w * ((nx - planes[f, 0]) ** 2 + (ny - planes[f, 1]) ** 2 + (nz - planes[f, 2]) ** 2)


@nb.njit(inline="always", **_NB)
def _edge_excess(planes, f, px, py, pz):
    """The point's largest in-plane distance outside face f's edge lines (:func:`face_planes`;
    at most 0 where its projection lies in the triangle)."""
    e = px * planes[f, 4] + py * planes[f, 5] + pz * planes[f, 6] - planes[f, 7]
    e1 = px * planes[f, 8] + py * planes[f, 9] + pz * planes[f, 10] - planes[f, 11]
    if e1 > e:
        e = e1
    e2 = px * planes[f, 12] + py * planes[f, 13] + pz * planes[f, 14] - planes[f, 15]
    if e2 > e:
        e = e2
    return e


@nb.njit(inline="always", **_NB)
def _face_lb_edges(planes, f, px, py, pz, nx, ny, nz, w):
    """A lower bound of face f's joint cost from its plane and edge lines
    (:func:`face_planes`), and whether it is the cost itself.

    The point's distance to the triangle is at least its distance to the plane and, within
    the plane, at least its distance outside any one edge; where it is outside none, its
    projection lies in the triangle and the plane's distance is the distance. Returns
    (bound, exact).
    """
    lb = _plane_cost(planes, f, px, py, pz, nx, ny, nz, w)
    e = _edge_excess(planes, f, px, py, pz)
    if e > 0.0:
        return lb + e * e, False
    return lb, True


@nb.njit(inline="always", **_NB)
def _try_face(tri, nrm, f, px, py, pz, nx, ny, nz, w, best, bf):
    """(best cost, its face) after trying face f: its closest point only where its plane's
    bound does not already rule it out."""
    if _face_lb(tri, nrm, f, px, py, pz, nx, ny, nz, w) >= best:
        return best, bf
    c, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w)
    if c < best:
        return c, f
    return best, bf


@nb.njit(inline="always", **_NB)
def _box_d2(x, y, z, lo, hi, i):
    d = 0.0
    if x < lo[i, 0]:
        d += (lo[i, 0] - x) ** 2
    elif x > hi[i, 0]:
        d += (x - hi[i, 0]) ** 2
    if y < lo[i, 1]:
        d += (lo[i, 1] - y) ** 2
    elif y > hi[i, 1]:
        d += (y - hi[i, 1]) ** 2
    if z < lo[i, 2]:
        d += (lo[i, 2] - z) ** 2
    elif z > hi[i, 2]:
        d += (z - hi[i, 2]) ** 2
    return d


# ---------------------------------------------------------------------------------------
# brute force (reference)
@nb.njit(parallel=True, **_NB)
def _bruteforce(tri, nrm, P, N, w, use_n):
    Q = P.shape[0]
    F = tri.shape[0]
    cost = np.empty(Q)
    face = np.empty(Q, np.int64)
    for q in nb.prange(Q):
        px, py, pz = P[q, 0], P[q, 1], P[q, 2]
        nx = ny = nz = 0.0
        if use_n:
            nx, ny, nz = N[q, 0], N[q, 1], N[q, 2]
        best = np.inf
        bf = -1
        for f in range(F):
            c, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w if use_n else 0.0)
            if c < best:
                best = c
                bf = f
        cost[q] = best
        face[q] = bf
    return face, cost


def query_bruteforce(triangles, normals, P, N, w):
    """Reference evaluation over every face. Returns (face (Q,), cost (Q,))."""
    P = kernel_array(P)
    use_n = N is not None and w > 0
    Nn = kernel_array(N if use_n else np.zeros((1, 3)))
    return _bruteforce(kernel_array(triangles), kernel_array(normals), P, Nn, float(w), use_n)


# ---------------------------------------------------------------------------------------
# bounding-volume hierarchy
@dataclass(frozen=True)
class BVH:
    """Flattened BVH over faces. Node i covers faces order[start[i]:start[i]+count[i]]."""

    tri: np.ndarray  # (F, 3, 3) faces in tree order
    nrm: np.ndarray  # (F, 3) normals in tree order
    face_id: np.ndarray  # (F,) original face index of each tree-order face
    plo: np.ndarray  # (M, 3) position box low
    phi: np.ndarray
    nlo: np.ndarray  # (M, 3) normal box low
    nhi: np.ndarray
    left: np.ndarray  # (M,) child index or -1 for leaves
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray


def build_bvh(triangles: np.ndarray, normals: np.ndarray, normal_scale: float) -> BVH:
    """Build a BVH whose splits follow the 6-D key (centroid, normal_scale * normal).

    Splits are at the median of the widest key dimension; leaves hold <= 4 faces. The
    bounds stored per node are exact boxes of the faces' vertices and of their normals,
    so the query's lower bound is valid whatever the split key.
    """
    F = len(triangles)
    key = np.concatenate([triangles.mean(axis=1), normal_scale * normals], axis=1)
    if normal_scale == 0:
        key = key[:, :3]
    vlo = triangles.min(axis=1)
    vhi = triangles.max(axis=1)
    order = np.arange(F)
    # Iterative build: nodes appended as (start, count); children created breadth-first.
    starts, counts, lefts, rights = [0], [F], [-1], [-1]
    todo = [0]
    while todo:
        i = todo.pop()
        s, c = starts[i], counts[i]
        if c <= _LEAF:
            continue
        idx = order[s : s + c]
        k = key[idx]
        dim = int(np.argmax(k.max(axis=0) - k.min(axis=0)))
        half = c // 2
        part = np.argpartition(k[:, dim], half)
        order[s : s + c] = idx[part]
        lefts[i] = len(starts)
        starts.append(s)
        counts.append(half)
        lefts.append(-1)
        rights.append(-1)
        rights[i] = len(starts)
        starts.append(s + half)
        counts.append(c - half)
        lefts.append(-1)
        rights.append(-1)
        todo.extend([lefts[i], rights[i]])
    starts = np.asarray(starts, np.int64)
    counts = np.asarray(counts, np.int64)
    M = len(starts)
    # Boxes: leaves from their faces, then internal nodes bottom-up (children have larger ids).
    plo = np.empty((M, 3))
    phi = np.empty((M, 3))
    nlo = np.empty((M, 3))
    nhi = np.empty((M, 3))
    lefts = np.asarray(lefts, np.int64)
    rights = np.asarray(rights, np.int64)
    for i in range(M - 1, -1, -1):
        if lefts[i] < 0:
            idx = order[starts[i] : starts[i] + counts[i]]
            plo[i] = vlo[idx].min(axis=0)
            phi[i] = vhi[idx].max(axis=0)
            nlo[i] = normals[idx].min(axis=0)
            nhi[i] = normals[idx].max(axis=0)
        else:
            a, b = lefts[i], rights[i]
            plo[i] = np.minimum(plo[a], plo[b])
            phi[i] = np.maximum(phi[a], phi[b])
            nlo[i] = np.minimum(nlo[a], nlo[b])
            nhi[i] = np.maximum(nhi[a], nhi[b])
    return BVH(
        tri=np.ascontiguousarray(triangles[order]),
        nrm=np.ascontiguousarray(normals[order]),
        face_id=order.astype(np.int64),
        plo=plo, phi=phi, nlo=nlo, nhi=nhi,
        left=lefts, right=rights, start=starts, count=counts,
    )


@nb.njit(inline="always", **_NB)
def _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
             px, py, pz, nx, ny, nz, w, best0):
    stack = np.empty(_STACK, np.int64)
    lbs = np.empty(_STACK)
    sp = 0
    stack[0] = 0
    lbs[0] = 0.0
    sp = 1
    best = best0
    bf = -1
    bx = by = bz = 0.0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if lbs[sp] >= best:
            continue
        if left[node] < 0:
            s = start[node]
            for f in range(s, s + count[node]):
                if _face_lb(tri, nrm, f, px, py, pz, nx, ny, nz, w) >= best:
                    continue
                c, qx, qy, qz = _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w)
                if c < best:
                    best = c
                    bf = f
                    bx, by, bz = qx, qy, qz
            continue
        a = left[node]
        b = right[node]
        la = _box_d2(px, py, pz, plo, phi, a)
        lb = _box_d2(px, py, pz, plo, phi, b)
        if w > 0.0:
            la += w * _box_d2(nx, ny, nz, nlo, nhi, a)
            lb += w * _box_d2(nx, ny, nz, nlo, nhi, b)
        # push the farther child first so the nearer one is explored first
        if la < lb:
            if lb < best:
                stack[sp] = b
                lbs[sp] = lb
                sp += 1
            if la < best:
                stack[sp] = a
                lbs[sp] = la
                sp += 1
        else:
            if la < best:
                stack[sp] = a
                lbs[sp] = la
                sp += 1
            if lb < best:
                stack[sp] = b
                lbs[sp] = lb
                sp += 1
    return best, bf, bx, by, bz


@nb.njit(inline="always", **_NB)
def _bvh_row(q, tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n,
             face, cost, closest):
    nx = ny = nz = 0.0
    if use_n:
        nx, ny, nz = N[q, 0], N[q, 1], N[q, 2]
    best, bf, bx, by, bz = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                    P[q, 0], P[q, 1], P[q, 2], nx, ny, nz,
                                    w if use_n else 0.0, np.inf)
    cost[q] = best
    face[q] = bf
    closest[q, 0] = bx
    closest[q, 1] = by
    closest[q, 2] = bz


@nb.njit(parallel=True, **_NB)
def _bvh_query(tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n):
    Q = P.shape[0]
    cost = np.empty(Q)
    face = np.empty(Q, np.int64)
    closest = np.empty((Q, 3))
    for q in nb.prange(Q):
        _bvh_row(q, tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n, face, cost, closest)
    return face, cost, closest


@nb.njit(**_SERIAL)
def _bvh_query_serial(tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n):
    Q = P.shape[0]
    cost = np.empty(Q)
    face = np.empty(Q, np.int64)
    closest = np.empty((Q, 3))
    for q in range(Q):
        _bvh_row(q, tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n, face, cost, closest)
    return face, cost, closest


def query_joint(tree: BVH, P, N, wp: float, wn: float):
    """Exact joint query through the BVH.

    Returns face (Q,) original face indices, cost (Q,) = |p-q|^2 + (wn/wp)|n-n_f|^2 (m^2)
    and closest (Q, 3) closest points on the winning faces.
    """
    P = kernel_array(P).reshape(-1, 3)
    w = 0.0 if (N is None or wn == 0) else float(wn / wp)
    use_n = w > 0
    Nn = kernel_array(N if use_n else np.zeros((1, 3)))
    if len(P) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
    kernel = _bvh_query if len(P) >= PARALLEL_MIN else _bvh_query_serial
    f, c, cl = kernel(tree.tri, tree.nrm, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left,
                          tree.right, tree.start, tree.count, P, Nn, w, use_n)
    return tree.face_id[f], c, cl


# ---------------------------------------------------------------------------------------
# near-surface lists keyed by the query's normal (the fast method's first stop)
#: Normal bins: a cube map of 8 x 8 bins on each of its 6 sides (one 64-bit word a side).
NEAR_BINS = 8
#: Finest-level cells whose centre lies within this many cells of the surface get lists,
#: and at least those that a pair costing less than NEAR_COST can fall in (a point within
#: sqrt(NEAR_COST) sigma of the surface): on a small mesh, whose cells are small, three
#: cells fell short of that (the lemon's 1.9 mm cells: 5.6 mm against 10 mm).
NEAR_REACH = 3.0
#: A (cell, normal bin) gets a list when some sample in it costs less than this (d_M^2):
#: the pairs of poses near a posterior's support. Costlier pairs take the cell's own list.
NEAR_COST = 25.0
#: ... and the list holds the winners of its samples that cost less than this (d_M^2).
NEAR_SAMPLE_COST = 50.0
#: Kinds of packed near lists besides a plain one (:func:`pack_near_lists`): kept apart
#: (too long for its entry), a plane list (one face, into which the whole cell projects)
#: and a coplanar list (faces of one plane: the one that holds a query's projection answers).
NEAR_LONG, NEAR_PLANE, NEAR_COPLANAR = 1, 2, 3

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@nb.njit(inline="always", **_NB)
def _popcount(x):
    """Set bits of a uint64."""
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return np.int64((x * _H01) >> np.uint64(56))


@nb.njit(inline="always", **_NB)
def _cube_bin(nx, ny, nz):
    """The cube-map bin of a direction: (side 0-5, bin within the side 0-63), or (-1, 0)
    for the zero vector. Side 2a / 2a + 1 is the + / - side of axis a."""
    ax, ay, az = abs(nx), abs(ny), abs(nz)
    if ax >= ay and ax >= az:
        side = 0 if nx > 0.0 else 1
        m, u, v = ax, ny, nz
    elif ay >= az:
        side = 2 if ny > 0.0 else 3
        m, u, v = ay, nx, nz
    else:
        side = 4 if nz > 0.0 else 5
        m, u, v = az, nx, ny
    if not m > 0.0:
        return -1, 0
    iu = int((u / m + 1.0) * (0.5 * NEAR_BINS))
    iv = int((v / m + 1.0) * (0.5 * NEAR_BINS))
    iu = min(max(iu, 0), NEAR_BINS - 1)
    iv = min(max(iv, 0), NEAR_BINS - 1)
    return side, iu * NEAR_BINS + iv


def cube_bin_directions():
    """Sample directions of the cube map's bins: (dirs, samples). ``dirs`` holds each bin's
    centre (row = side * 64 + bin, as :func:`_cube_bin` numbers them) and then every
    side's points at half a bin's spacing; ``samples`` (384, 8) are the rows of each bin's
    4 corners and 4 edge midpoints."""
    B = NEAR_BINS
    H = 2 * B + 1  # points per row of a side at half a bin's spacing

    def on_side(side, u, v):
        s = 1.0 if side % 2 == 0 else -1.0
        d = [(s, u, v), (u, s, v), (u, v, s)][side // 2]
        return np.asarray(d) / np.linalg.norm(d)

    centres = [on_side(side, (iu + 0.5) / B * 2 - 1, (iv + 0.5) / B * 2 - 1)
               for side in range(6) for iu in range(B) for iv in range(B)]
    half = [on_side(side, iu / (2 * B) * 2 - 1, iv / (2 * B) * 2 - 1)
            for side in range(6) for iu in range(H) for iv in range(H)]
    n = 6 * B * B
    samples = np.empty((n, 8), np.int64)
    for side in range(6):
        for iu in range(B):
            for iv in range(B):
                k = [(side * H + 2 * iu + a) * H + 2 * iv + b
                     for a, b in ((0, 0), (0, 2), (2, 0), (2, 2), (0, 1), (1, 0), (1, 2), (2, 1))]
                samples[(side * B + iu) * B + iv] = n + np.asarray(k)
    return np.vstack([centres, half]), samples


@nb.njit(inline="always", **_NB)
def _near_face(planes, tri, nrm, f, px, py, pz, nx, ny, nz, w, best, bf):
    """(best cost, its face) after trying face f of a near list: the plane-and-edges bound
    first, which is the cost itself where the point projects into the triangle."""
    lb, exact = _face_lb_edges(planes, f, px, py, pz, nx, ny, nz, w)
    if lb >= best:
        return best, bf
    if exact:
        return lb, f
    c, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w)
    if c < best:
        return c, f
    return best, bf


@nb.njit(inline="always", **_NB)
def _near_list(near, tri, nrm, cell, px, py, pz, nx, ny, nz, w):
    """The best face of the normal-keyed list of a finest-level ``cell`` for this query.

    ``near`` = (cells, entries, over, planes, width) of :class:`CandidateGrid` (see
    :func:`pack_near_lists`). Returns (found, cost, face); ``found`` is False where the
    cell or the query's bin has no list.
    """
    cells, entries, over, planes, width = near
    if cell >= cells.shape[0]:
        return False, np.inf, -1
    side, bit = _cube_bin(nx, ny, nz)
    if side < 0:
        return False, np.inf, -1
    word = cells[cell, side]
    mask = np.uint64(1) << np.uint64(bit)
    if (word & mask) == np.uint64(0):
        return False, np.inf, -1
    e = np.int64(cells[cell, 6]) + _popcount(word & (mask - np.uint64(1)))
    for s in range(side):
        e += _popcount(cells[cell, s])
    best = np.inf
    bf = -1
    v = entries[e]
    b = np.uint64(width)
    empty = (np.uint64(1) << b) - np.uint64(1)
    code = empty - np.uint64(1)
    slots = 64 // width
    if (v & empty) == code:  # a long list, kept apart: its length, then its faces
        o = np.int64(v >> b)
        for j in range(o + 1, o + 1 + np.int64(over[o])):
            best, bf = _near_face(planes, tri, nrm, np.int64(over[j]), px, py, pz, nx, ny, nz, w, best, bf)
        return True, best, bf
    if ((v >> b) & empty) == code:
        # a plane list: the whole cell projects into its one face, so the plane's
        # distance is the distance
        f = np.int64(v & empty)
        return True, _plane_cost(planes, f, px, py, pz, nx, ny, nz, w), f
    if ((v >> (b * np.uint64(slots - 1))) & empty) == code:
        # a coplanar list: the face that holds the point's projection answers (every other
        # face of the plane is farther); where none does, the list as any other
        for s in range(slots - 1):
            f = (v >> (b * np.uint64(s))) & empty
            if f == empty:
                break
            if not _edge_excess(planes, np.int64(f), px, py, pz) > 0.0:
                return True, _plane_cost(planes, np.int64(f), px, py, pz, nx, ny, nz, w), np.int64(f)
    for s in range(slots):
        f = (v >> (b * np.uint64(s))) & empty
        if f >= code:
            break
        best, bf = _near_face(planes, tri, nrm, np.int64(f), px, py, pz, nx, ny, nz, w, best, bf)
    return True, best, bf


def near_width(n_faces: int) -> int:
    """Bits per face id in a packed near-list entry (:func:`pack_near_lists`): room for
    every face id and two codes above them, at least 8."""
    return max(8, int(n_faces + 1).bit_length())


def pack_near_lists(off, ids, n_faces: int, kind=None):
    """The near lists (list e: faces ``ids[off[e]:off[e + 1]]``) packed one uint64 entry a
    list, so that a query reads its faces from the entry it finds (one memory access
    fewer; docs/benchmarks.md, "Localisation speed with few contacts").

    Face ids take ``b = near_width(n_faces)`` bits each. A list of at most ``64 // b``
    faces sits in its entry, slot s in bits [b s, b s + b), its unused slots all ones. A
    longer list sits in ``over`` (int32) as its length and then its faces; its entry holds
    the code (all ones but the lowest bit) in slot 0 and the list's index in ``over`` above
    it. ``kind`` (a list each, :data:`NEAR_PLANE`, :data:`NEAR_COPLANAR` or 0) marks the
    lists that :func:`_plane_faces` found in one plane: a plane list, one face, has the
    code in slot 1; a coplanar list, of 2 to ``64 // b - 1`` faces, in its last slot.
    Returns (entries, over).
    """
    off = np.asarray(off, dtype=np.int64)
    ids = np.asarray(ids, dtype=np.int64)
    kind = np.zeros(len(off) - 1, np.int64) if kind is None else np.asarray(kind, dtype=np.int64)
    b = near_width(n_faces)
    slots = 64 // b
    empty = (1 << b) - 1
    lengths = np.diff(off)
    if (kind.shape != lengths.shape or np.any((kind == NEAR_PLANE) & (lengths != 1))
            or np.any((kind == NEAR_COPLANAR) & ((lengths < 2) | (lengths > slots - 1)))):
        raise ValueError("a plane list holds one face, a coplanar list 2 to 64 // width - 1")
    n = len(lengths)
    owner = np.repeat(np.arange(n), lengths)
    slot = np.arange(len(ids)) - off[owner]
    short = lengths <= slots
    table = np.full((n, slots), empty, np.uint64)
    keep = short[owner]
    table[owner[keep], slot[keep]] = ids[keep].astype(np.uint64)
    table[kind == NEAR_PLANE, 1] = empty - 1
    table[kind == NEAR_COPLANAR, slots - 1] = empty - 1
    entries = np.zeros(n, np.uint64)
    for s in range(slots):
        entries |= table[:, s] << np.uint64(b * s)
    long_ = np.flatnonzero(~short)
    over = np.zeros(0, np.int32)
    if len(long_):
        sizes = lengths[long_] + 1
        at = np.zeros(len(long_) + 1, np.int64)
        np.cumsum(sizes, out=at[1:])
        over = np.empty(int(at[-1]), np.int32)
        over[at[:-1]] = lengths[long_]
        member = ~keep
        over[np.repeat(at[:-1] + 1, lengths[long_]) + slot[member]] = ids[member]
        entries[long_] = np.uint64(empty - 1) | (at[:-1].astype(np.uint64) << np.uint64(b))
    return entries, over


def near_list_kinds(entries, n_faces: int) -> np.ndarray:
    """(E,) int: the kind of each packed entry (:func:`pack_near_lists`): 0 a list of its
    own faces, :data:`NEAR_LONG`, :data:`NEAR_PLANE` or :data:`NEAR_COPLANAR`."""
    b = near_width(n_faces)
    empty = np.uint64((1 << b) - 1)
    code = empty - np.uint64(1)
    entries = np.asarray(entries, dtype=np.uint64)
    out = np.zeros(len(entries), np.int64)
    # in kernel order: slot 0 of a long list's entry is its code, and its index fills the rest
    out[((entries >> np.uint64(b * (64 // b - 1))) & empty) == code] = NEAR_COPLANAR
    out[((entries >> np.uint64(b)) & empty) == code] = NEAR_PLANE
    out[(entries & empty) == code] = NEAR_LONG
    return out


def unpack_near_lists(entries, over, n_faces: int):
    """The lists that :func:`pack_near_lists` packed, as (off, ids): list e holds the
    faces ``ids[off[e]:off[e + 1]]``, in entry order (for tests and diagnostics;
    :func:`near_list_kinds` tells the kinds)."""
    entries = np.asarray(entries, dtype=np.uint64)
    over = np.asarray(over, dtype=np.int64)
    b = near_width(n_faces)
    slots = 64 // b
    empty = (1 << b) - 1
    low = (entries & np.uint64(empty)).astype(np.int64)
    long_ = low == empty - 1
    table = np.stack([(entries >> np.uint64(b * s)) & np.uint64(empty) for s in range(slots)], axis=1).astype(np.int64)
    # a face id is below both codes: a plane or coplanar list's code is no face
    used = (table < empty - 1) & ~long_[:, None]
    at = (entries[long_] >> np.uint64(b)).astype(np.int64)
    lengths = used.sum(axis=1)
    lengths[long_] = over[at]
    off = np.zeros(len(entries) + 1, np.int64)
    np.cumsum(lengths, out=off[1:])
    ids = np.empty(int(off[-1]), np.int64)
    short = np.flatnonzero(~long_)
    ids[(off[short][:, None] + np.arange(slots))[used[short]]] = table[short][used[short]]
    if len(at):
        n = over[at]
        within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # each face's place in its list
        ids[np.repeat(off[:-1][long_], n) + within] = over[np.repeat(at + 1, n) + within]
    return off, ids


#: a sample point with more faces than this within the sample bound queries the tree; a
#: mesh whose sample points mostly are this crowded gets no near lists (below)
_NEAR_CROWD = 256


@nb.njit(inline="always", **_NB)
def _faces_within(tri, nrm, plo, phi, left, right, start, count, px, py, pz, r2, cand, dist):
    """The faces closer to the point than sqrt(r2) into ``cand`` and their squared distances
    into ``dist`` (as many as they hold); returns how many there are, counted up to one more
    than they hold."""
    k = 0
    stack = np.empty(_STACK, np.int64)
    sp = 1
    stack[0] = 0
    while sp > 0 and k <= cand.shape[0]:
        sp -= 1
        node = stack[sp]
        if _box_d2(px, py, pz, plo, phi, node) >= r2:
            continue
        if left[node] < 0:
            for f in range(start[node], start[node] + count[node]):
                d2, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, 0.0, 0.0, 0.0, 0.0)
                if d2 < r2:
                    if k < cand.shape[0]:
                        cand[k] = f
                        dist[k] = d2
                    k += 1
        else:
            stack[sp] = left[node]
            stack[sp + 1] = right[node]
            sp += 2
    return k


@nb.njit(inline="always", **_NB)
def _nearest_first(nrm, cand, dist, order, k, nx, ny, nz, w, best):
    """(cost, face) of the best of ``k`` gathered faces for the normal (n), below ``best``
    (face -1 where none is): ``order`` sorts their squared distances ``dist``, and the scan
    ends where the distance alone reaches the best cost."""
    bf = -1
    for u in range(k):
        i = order[u]
        if dist[i] >= best:
            break
        f = cand[i]
        ex = nx - nrm[f, 0]
        ey = ny - nrm[f, 1]
        ez = nz - nrm[f, 2]
        c = dist[i] + w * (ex * ex + ey * ey + ez * ez)
        if c < best:
            best = c
            bf = f
    return best, bf


@nb.njit(parallel=True, **_NB)
def _near_crowding(tri, nrm, plo, phi, left, right, start, count, pts, r2, out):
    """How many faces lie within sqrt(r2) of each point (up to :data:`_NEAR_CROWD` + 1)."""
    for i in nb.prange(pts.shape[0]):
        cand = np.empty(_NEAR_CROWD, np.int64)
        out[i] = _faces_within(tri, nrm, plo, phi, left, right, start, count, pts[i, 0], pts[i, 1], pts[i, 2],
                               r2, cand, np.empty(_NEAR_CROWD))


@nb.njit(parallel=True, **_NB)
def _near_samples(tri, nrm, plo, phi, nlo, nhi, left, right, start, count, pts, dirs, w, bound, cost, face):
    """Exact joint winners (tree order; -1 with ``cost`` = bound when none is below it) of
    every point for every direction.

    A face farther from the point than sqrt(bound) costs more than the bound, so each
    point first gathers the faces within that distance, sorted by it, and scores every
    direction over them alone, nearest first (:func:`_nearest_first`; the tree's query where
    they are more than :data:`_NEAR_CROWD`). A direction whose normal term to the box of the
    gathered faces' normals, added to the nearest face's distance, reaches the bound has
    no winner and is skipped.
    """
    for i in nb.prange(pts.shape[0]):
        px, py, pz = pts[i, 0], pts[i, 1], pts[i, 2]
        cand = np.empty(_NEAR_CROWD, np.int64)
        dist = np.empty(_NEAR_CROWD)
        k = _faces_within(tri, nrm, plo, phi, left, right, start, count, px, py, pz, bound, cand, dist)
        kk = min(k, _NEAR_CROWD)
        order = np.argsort(dist[:kk], kind="mergesort")
        # the box of the gathered faces' normals: a direction whose normal term alone, from
        # the box, lifts the nearest face's distance to the bound has no winner
        box = np.empty((2, 3))
        box[0, :] = np.inf
        box[1, :] = -np.inf
        for u in range(kk):
            for a in range(3):
                box[0, a] = min(box[0, a], nrm[cand[u], a])
                box[1, a] = max(box[1, a], nrm[cand[u], a])
        dmin = dist[order[0]] if kk > 0 else bound
        for d in range(dirs.shape[0]):
            nx, ny, nz = dirs[d, 0], dirs[d, 1], dirs[d, 2]
            if k > _NEAR_CROWD:
                c, bf, _, _, _ = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                          px, py, pz, nx, ny, nz, w, bound)
            elif dmin + w * _box_d2(nx, ny, nz, box[0:1], box[1:2], 0) >= bound:
                c = bound
                bf = -1
            else:
                c, bf = _nearest_first(nrm, cand, dist, order, k, nx, ny, nz, w, bound)
            cost[i, d] = c
            face[i, d] = bf


@nb.njit(inline="always", **_NB)
def _listed(buf, k, f) -> bool:
    """Whether face ``f`` is among the first ``k`` entries of ``buf``."""
    for u in range(k):
        if buf[u] == f:
            return True
    return False


@nb.njit(inline="always", **_NB)
def _near_gather(ijk, S1, S2, cidx, cost, face, corners, b, relevant, buf, planar):
    """The distinct winners of the samples of one cell and bin (the cell's 8 corners times
    the bin's centre, corners and edge midpoints) costing below the bound, into ``buf``;
    returns their number, or 0 when no sample costs below ``relevant``.

    ``planar`` = (tri, nrm, adj_off, adj, group, lo, h): the coplanar faces
    (:func:`coplanar_groups`) that come within half a cell diagonal of the cell's centre
    projected on their plane, reached from a winner through faces of its plane that do
    (vertex-adjacent, :func:`tree_adjacency`), are listed too. A flat side split into
    triangles is won by whichever holds the query's projection, which the samples at the
    corners may miss (a sliver that crosses the cell between them)."""
    k = 0
    low = np.inf
    for dx in range(2):
        for dy in range(2):
            for dz in range(2):
                ci = cidx[((ijk[0] + dx) * S1 + ijk[1] + dy) * S2 + ijk[2] + dz]
                for t in range(corners.shape[1] + 1):
                    d = b if t == corners.shape[1] else corners[b, t]
                    low = min(low, cost[ci, d])
                    f = face[ci, d]
                    if f >= 0 and not _listed(buf, k, f):
                        buf[k] = f
                        k += 1
    if low >= relevant:
        return 0
    tri, nrm, adj_off, adj, group, lo, h = planar
    if adj_off.shape[0] == 0:
        return k
    cx = lo[0] + (ijk[0] + 0.5) * h
    cy = lo[1] + (ijk[1] + 0.5) * h
    cz = lo[2] + (ijk[2] + 0.5) * h
    r2 = 0.75 * h * h * (1.0 + 1e-9)
    # breadth first from the winners over vertex-adjacent faces of the same plane within
    # reach: the work stays local however many triangles the plane has
    u = 0
    while u < k:
        f = buf[u]
        u += 1
        gr = group[f]
        if gr < 0:
            continue
        for j in range(adj_off[f], adj_off[f + 1]):
            g = adj[j]
            # (a full buffer: the build's check sees the loss)
            if group[g] != gr or k >= buf.shape[0] or _listed(buf, k, g):
                continue
            qx, qy, qz = _closest_on_triangle(cx, cy, cz, tri[g, 0, 0], tri[g, 0, 1], tri[g, 0, 2],
                                              tri[g, 1, 0], tri[g, 1, 1], tri[g, 1, 2],
                                              tri[g, 2, 0], tri[g, 2, 1], tri[g, 2, 2])
            sd = (cx - tri[g, 0, 0]) * nrm[g, 0] + (cy - tri[g, 0, 1]) * nrm[g, 1] + (cz - tri[g, 0, 2]) * nrm[g, 2]
            if (cx - qx) ** 2 + (cy - qy) ** 2 + (cz - qz) ** 2 - sd * sd <= r2:
                buf[k] = g
                k += 1
    return k


def coplanar_groups(tri: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """(F,) int64: for each face, the id of the plane it shares with other faces (unit
    normal and offset equal once rounded to 1e-7), or -1 for a face alone in its plane or
    without a unit normal. Ids run from 0 without gaps."""
    tri = np.asarray(tri, dtype=np.float64)
    nrm = np.asarray(nrm, dtype=np.float64)
    key = np.round(np.concatenate([nrm, np.einsum("ij,ij->i", nrm, tri[:, 0])[:, None]], axis=1) * 1e7)
    unit = np.abs(np.linalg.norm(nrm, axis=1) - 1.0) < 1e-6
    key[~unit] = 0.0
    key[~unit, 0] = 1e12 + np.arange(np.count_nonzero(~unit))   # a key of its own each
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    ids = np.full(len(counts), -1, np.int64)
    big = np.flatnonzero(counts > 1)
    ids[big] = np.arange(len(big))
    return ids[inv.reshape(-1)]


def _near_buffer(corners, group) -> int:
    """Room for one (cell, bin)'s list: its samples' winners and their coplanar faces."""
    shared = group[group >= 0]
    most = int(np.bincount(shared).max()) if len(shared) else 1
    return 8 * (corners.shape[1] + 1) * max(1, min(most, 64))


@nb.njit(parallel=True, **_NB)
def _near_count(cells, S1, S2, cidx, cost, face, corners, relevant, counts, planar, room):
    for r in nb.prange(cells.shape[0]):
        buf = np.empty(room, np.int64)
        for b in range(corners.shape[0]):
            counts[r, b] = _near_gather(cells[r], S1, S2, cidx, cost, face, corners, b, relevant, buf, planar)


@nb.njit(parallel=True, **_NB)
def _near_fill(cells, S1, S2, cidx, cost, face, corners, relevant, start, ids, planar, room):
    for r in nb.prange(cells.shape[0]):
        buf = np.empty(room, np.int64)
        for b in range(corners.shape[0]):
            k = _near_gather(cells[r], S1, S2, cidx, cost, face, corners, b, relevant, buf, planar)
            for u in range(k):
                ids[start[r, b] + u] = buf[u]


#: A plane list's cell projects into its face at least this far (m) inside each of the
#: face's edges, so that a query in the cell, rounded, projects inside too.
PLANE_MARGIN = 1e-9


@nb.njit(parallel=True, **_NB)
def _plane_faces(owner, ijk, off, ids, group, planes, lo, h, face, coplanar):
    """Per near list: whether its faces lie in one plane (:func:`coplanar_groups`; a list of
    one face does) into ``coplanar``, and if so, into ``face``, the listed face whose
    triangle holds the projection of the whole of the list's cell (its 8 corners at least
    :data:`PLANE_MARGIN` inside each edge: the edges' in-plane distances are linear, so
    the whole box is), or -1.

    A point of such a cell is as far from that face as from its plane, and no coplanar
    face is nearer, so the list's answer is that face's plane cost: a plane list
    (:func:`pack_near_lists`)."""
    for e in nb.prange(off.shape[0] - 1):
        face[e] = -1
        a, z = off[e], off[e + 1]
        g0 = group[ids[a]]
        same = True
        for j in range(a + 1, z):
            if g0 < 0 or group[ids[j]] != g0:
                same = False
                break
        coplanar[e] = same
        if not same:
            continue
        r = owner[e]
        for j in range(a, z):
            f = ids[j]
            inside = True
            for c in range(8):
                if _edge_excess(planes, f, lo[0] + (ijk[r, 0] + (c >> 2)) * h, lo[1] + (ijk[r, 1] + ((c >> 1) & 1)) * h,
                                lo[2] + (ijk[r, 2] + (c & 1)) * h) > -PLANE_MARGIN:
                    inside = False
                    break
            if inside:
                face[e] = f
                break


def build_near_lists(tree: BVH, lo, cell: float, shape, w: float, sigma2: float, adjacency=None):
    """The normal-keyed lists of the finest level's cells near the surface.

    A cell whose centre lies within :data:`NEAR_REACH` cells of the surface, or within reach
    of a point costing :data:`NEAR_COST` (``sqrt(NEAR_COST sigma2)`` plus half the cell's
    diagonal), is sampled at
    its 8 corners, each for the centre and 4 corners of every cube-map bin; a (cell, bin)
    in which some sample costs less than :data:`NEAR_COST` (d_M^2 at ``sigma2``) lists the
    distinct winners of its samples costing less than :data:`NEAR_SAMPLE_COST`, and the
    coplanar faces near them that reach the cell (:func:`_near_gather`; ``adjacency`` is
    :func:`tree_adjacency`'s, computed when not given). Returns None
    for a mesh whose sample points mostly have more than :data:`_NEAR_CROWD` faces within
    that cost's reach, else the :class:`CandidateGrid` fields ``near_cells`` (cells, 8) uint64 (per cell of the level:
    6 words, bit b of word s set where side s's bin b has a list, then the entry of its
    first list), ``near_entries`` and ``near_ids`` (the lists of tree-order faces, packed by
    :func:`pack_near_lists`) and
    ``planes`` (:func:`face_planes`). A list whose cell projects, as a whole, into one of
    its faces, all of them in that face's plane, keeps that face alone as a plane list
    (:func:`_plane_faces`): its queries cost one plane distance; any other list in one
    plane is a coplanar list, whose queries test the edges of its faces until one holds
    their projection.
    """
    lo = np.asarray(lo, dtype=np.float64)
    shape = np.asarray(shape, dtype=np.int64)
    g = [lo[d] + (np.arange(shape[d]) + 0.5) * cell for d in range(3)]
    centres = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)
    args = (tree.tri, tree.nrm, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start, tree.count)
    reach = max(NEAR_REACH * cell, float(np.sqrt(NEAR_COST * sigma2)) + 0.5 * np.sqrt(3.0) * cell)
    d2 = np.empty((len(centres), 1))
    _near_samples(*args, centres, np.zeros((1, 3)), 0.0, reach * reach, d2, np.empty((len(centres), 1), np.int64))
    cells = np.flatnonzero(d2[:, 0] < reach * reach)
    ijk = np.stack(np.unravel_index(cells, tuple(shape)), axis=1).astype(np.int64)
    S = shape + 1
    corner_ids = np.unique(np.concatenate([np.ravel_multi_index(tuple((ijk + np.array(o)).T), tuple(S))
                                           for o in np.ndindex(2, 2, 2)])) if len(cells) else np.zeros(0, np.int64)
    cidx = np.full(int(np.prod(S)), -1, np.int64)
    cidx[corner_ids] = np.arange(len(corner_ids))
    pts = np.ascontiguousarray(lo + np.stack(np.unravel_index(corner_ids, tuple(S)), axis=1) * cell)
    # faces small against the cells: too many within a sample's reach, whose winners change
    # between the samples (the lists would fail their check, after a long build)
    crowd = np.empty(min(len(pts), 400), np.int64)
    _near_crowding(tree.tri, tree.nrm, tree.plo, tree.phi, tree.left, tree.right, tree.start, tree.count,
                   pts[np.linspace(0, len(pts) - 1, len(crowd)).astype(np.int64)], NEAR_SAMPLE_COST * sigma2, crowd)
    if len(crowd) and np.median(crowd) > _NEAR_CROWD:
        return None
    dirs, corners = cube_bin_directions()
    cost = np.empty((len(pts), len(dirs)))
    face = np.empty((len(pts), len(dirs)), np.int64)
    _near_samples(*args, pts, dirs, float(w), NEAR_SAMPLE_COST * sigma2, cost, face)
    relevant = NEAR_COST * sigma2
    counts = np.zeros((len(cells), len(corners)), np.int64)
    group = coplanar_groups(tree.tri, tree.nrm)
    if not np.any(group >= 0):
        adj_off, adj = np.zeros(0, np.int64), np.zeros(0, np.int64)
    else:
        adj_off, adj = tree_adjacency(tree) if adjacency is None else adjacency
    planar = (tree.tri, tree.nrm, adj_off, adj, group, lo, float(cell))
    room = _near_buffer(corners, group)
    _near_count(ijk, S[1], S[2], cidx, cost, face, corners, relevant, counts, planar, room)
    # entries in (cell, bin) order; per cell one cache line: its 6 words (bit b of word s:
    # side s's bin b has a list), the entry of its first list, and padding
    has = counts > 0
    lengths = counts[has]
    off = np.zeros(len(lengths) + 1, np.int64)
    np.cumsum(lengths, out=off[1:])
    start = np.zeros_like(counts)
    start[has] = off[:-1]
    ids = np.empty(int(off[-1]), np.int64)
    _near_fill(ijk, S[1], S[2], cidx, cost, face, corners, relevant, start, ids, planar, room)
    table = np.zeros((int(np.prod(shape)), 8), np.uint64)
    if len(cells):
        bits = has.reshape(len(cells), 6, 64).astype(np.uint64) << np.arange(64, dtype=np.uint64)
        table[cells, :6] = np.bitwise_or.reduce(bits, axis=2)
        per_cell = has.sum(axis=1)
        table[cells, 6] = np.concatenate([[0], np.cumsum(per_cell)[:-1]]).astype(np.uint64)
    planes = face_planes(tree.tri, tree.nrm)
    # lists in one plane: a query's answer is the plane cost of the face that holds its
    # projection, and where the whole cell projects into one face, that face alone
    face = np.empty(len(lengths), np.int64)
    coplanar = np.empty(len(lengths), np.bool_)
    _plane_faces(np.repeat(np.arange(len(cells)), has.sum(axis=1)), ijk, off, ids, group, planes,
                 lo, float(cell), face, coplanar)
    flat = face >= 0
    kind = np.where(flat, NEAR_PLANE, 0)
    kind[coplanar & ~flat & (lengths >= 2) & (lengths <= 64 // near_width(len(tree.tri)) - 1)] = NEAR_COPLANAR
    if flat.any():
        lengths = np.where(flat, 1, lengths)
        keep = np.repeat(~flat, np.diff(off))
        pos = np.zeros(len(lengths) + 1, np.int64)
        np.cumsum(lengths, out=pos[1:])
        new_ids = np.empty(int(pos[-1]), np.int64)
        new_ids[pos[:-1][flat]] = face[flat]
        new_ids[np.repeat(~flat, lengths)] = ids[keep]
        off, ids = pos, new_ids
    entries, over = pack_near_lists(off, ids, len(tree.tri), kind=kind)
    return dict(near_cells=table, near_entries=entries, near_ids=over, planes=planes)


@nb.njit(**_NB)
def _near_query(tri, nrm, lo, h, shape, near, P, N, w, found, cost):
    for q in range(P.shape[0]):
        px, py, pz = P[q, 0], P[q, 1], P[q, 2]
        ix = int(np.floor((px - lo[0, 0]) / h[0]))
        iy = int(np.floor((py - lo[0, 1]) / h[0]))
        iz = int(np.floor((pz - lo[0, 2]) / h[0]))
        found[q] = False
        cost[q] = np.inf
        if 0 <= ix < shape[0, 0] and 0 <= iy < shape[0, 1] and 0 <= iz < shape[0, 2]:
            cell = (ix * shape[0, 1] + iy) * shape[0, 2] + iz
            found[q], cost[q], _ = _near_list(near, tri, nrm, cell, px, py, pz, N[q, 0], N[q, 1], N[q, 2], w)


def near_list_costs(grid: CandidateGrid, P, N):
    """The normal-keyed lists' answers alone, for tests and diagnostics: (found, cost), where
    ``found`` marks the queries whose cell and normal bin have a list (cost: m^2, as
    :func:`query_grid`; inf elsewhere)."""
    P = kernel_array(P).reshape(-1, 3)
    N = kernel_array(N).reshape(-1, 3)
    found = np.zeros(len(P), np.bool_)
    cost = np.full(len(P), np.inf)
    _near_query(grid.tri, grid.nrm, grid.lo, grid.h, grid.shape, grid.near, P, N, grid.w, found, cost)
    return found, cost


#: The lists' check: queries at surface points moved by sigma_pos along the normal, with
#: normals sigma_nor off; where more of the near lists' answers exceed the exact cost by
#: more than NEAR_CHECK_ERROR (d_M^2) than NEAR_CHECK_SHARE and than the general lists'
#: answers do, the mesh keeps no near lists.
NEAR_CHECK_QUERIES = 20_000
NEAR_CHECK_ERROR = 0.1
NEAR_CHECK_SHARE = 0.01
#: The fast method as a whole, on the same queries: where more than FAST_CHECK_SHARE of its
#: answers exceed the exact cost by more than FAST_CHECK_ERROR (d_M^2: half a nat of
#: log-likelihood), ``auto`` scores exactly (CandidateGrid.fast_ok)
FAST_CHECK_ERROR = 1.0
FAST_CHECK_SHARE = 0.01


def near_check_queries(tree: BVH, w: float, sigma2: float, n: int = NEAR_CHECK_QUERIES, seed: int = 0):
    """Object-frame queries like those of a pose near the truth: points drawn uniformly on
    the surface and moved by N(0, sigma_pos) along their face's normal, and that normal
    turned by about sigma_nor (sigma_nor^2 = sigma_pos^2 / w)."""
    rng = np.random.default_rng(seed)
    tri = tree.tri
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(tri), n, p=area / area.sum())
    a, b = rng.random((2, n))
    flip = a + b > 1.0
    a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
    P = tri[f, 0] + a[:, None] * (tri[f, 1] - tri[f, 0]) + b[:, None] * (tri[f, 2] - tri[f, 0])
    P = P + tree.nrm[f] * rng.normal(scale=np.sqrt(sigma2), size=(n, 1))
    N = tree.nrm[f] + rng.normal(scale=np.sqrt(sigma2 / w / 2.0), size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return np.ascontiguousarray(P), np.ascontiguousarray(N)


@nb.njit(parallel=True, **_NB)
def _bvh_query_costs(tri, nrm, plo, phi, nlo, nhi, left, right, start, count, P, N, w, out):
    for q in nb.prange(P.shape[0]):
        out[q], _, _, _, _ = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                      P[q, 0], P[q, 1], P[q, 2], N[q, 0], N[q, 1], N[q, 2], w, np.inf)


def _near_tuple(d, n_faces: int):
    return (d["near_cells"], d["near_entries"], d["near_ids"], d["planes"], near_width(n_faces))


def no_near_lists():
    """The near-list fields of a grid without them."""
    return dict(near_cells=np.zeros((0, 8), np.uint64), near_entries=np.zeros(0, np.uint64),
                near_ids=np.zeros(0, np.int32), planes=np.zeros((1, 16)))


# ---------------------------------------------------------------------------------------
# candidate grid (the "fast" method)
@dataclass(frozen=True)
class CandidateGrid:
    """Levels of cells over nested axis-aligned boxes, finest first; cell c of level l
    lists faces ids[offsets[base[l] + c]:offsets[base[l] + c + 1]]."""

    lo: np.ndarray  # (L, 3) origin (corner of cell 0) of each level
    h: np.ndarray  # (L,) cell size of each level (m)
    shape: np.ndarray  # (L, 3) cells per axis of each level
    base: np.ndarray  # (L,) index of each level's first cell
    offsets: np.ndarray  # (C+1,) over the cells of every level
    ids: np.ndarray  # tree-order face ids into tri/nrm below
    tri: np.ndarray
    nrm: np.ndarray
    w: float  # normal weight the lists were built for (0: position-only)
    adj_off: np.ndarray  # (F+1,) CSR offsets of vertex-adjacent faces (tree order)
    adj: np.ndarray
    longest: int  # the longest cell list (the width of a query's scratch row)
    # normal-keyed lists of the finest level's cells near the surface (build_near_lists)
    near_cells: np.ndarray
    near_entries: np.ndarray  # one packed uint64 a list (pack_near_lists)
    near_ids: np.ndarray  # the lists too long to pack: length, then faces
    planes: np.ndarray
    # their check against the exact method (build_candidate_grid): share of the queries
    # answered, share off by more than NEAR_CHECK_ERROR, 99th percentile of the error, the
    # share off for the general lists, whether the near lists were kept (1) or dropped (the
    # first five zero where none were built: faces crowded in a sample's reach), and the
    # share off by more than FAST_CHECK_ERROR for the fast method as it answers (near lists
    # where kept, general lists elsewhere); all zero for position-only grids, which are exact
    near_check: np.ndarray

    @property
    def fast_ok(self) -> bool:
        """Whether the fast method passed its check: at most FAST_CHECK_SHARE of the check's
        queries off by more than FAST_CHECK_ERROR (d_M^2). ``auto`` uses it only then."""
        return bool(self.near_check[5] <= FAST_CHECK_SHARE)

    @property
    def near(self) -> tuple:
        """The near lists as the kernels take them."""
        return _near_tuple(self.__dict__, len(self.tri))

    def scratch(self) -> np.ndarray:
        """One scratch row per numba thread for the lists' bounds (see :func:`_list_best`)."""
        return np.empty((nb.config.NUMBA_NUM_THREADS, max(self.longest, 1)))


@nb.njit(inline="always", **_NB)
def _list_best(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near, px, py, pz, nx, ny, nz, w, descend,
               best, buf):
    """The best face of the point's cell list (and the greedy descent from it) below ``best``.

    The cell is that of the finest level whose box holds the point. In a finest-level cell
    near the surface, with a normal whose bin has a list there (``near``, see
    :func:`build_near_lists`), that short list answers alone. Returns (listed, cost,
    face): ``listed`` is False outside every level or in a cell without a list; ``face``
    is -1 (and ``cost`` the given ``best``) when no listed face is below it. ``buf`` holds
    at least the cell's list length: the first pass keeps each face's bound there for the
    second.
    """
    bf = -1
    cell = -1
    for lvl in range(lo.shape[0]):
        ix = int(np.floor((px - lo[lvl, 0]) / h[lvl]))
        iy = int(np.floor((py - lo[lvl, 1]) / h[lvl]))
        iz = int(np.floor((pz - lo[lvl, 2]) / h[lvl]))
        if 0 <= ix < shape[lvl, 0] and 0 <= iy < shape[lvl, 1] and 0 <= iz < shape[lvl, 2]:
            cell = base[lvl] + (ix * shape[lvl, 1] + iy) * shape[lvl, 2] + iz
            if lvl == 0 and w > 0.0:
                found, c, f = _near_list(near, tri, nrm, cell, px, py, pz, nx, ny, nz, w)
                if found:
                    if c < best:
                        return True, c, f
                    return True, best, bf
            break
    if cell < 0 or offsets[cell + 1] <= offsets[cell]:
        return False, best, bf
    # best first: the face with the lowest bound sets a tight cost, then the bound skips
    # most of the others without their closest-point routine
    lead = -1
    lead_lb = np.inf
    o = offsets[cell]
    for j in range(o, offsets[cell + 1]):
        lb = _face_lb(tri, nrm, ids[j], px, py, pz, nx, ny, nz, w)
        buf[j - o] = lb
        if lb < lead_lb:
            lead_lb = lb
            lead = j
    if lead_lb < best:
        c, _, _, _ = _face_cost(tri, nrm, ids[lead], px, py, pz, nx, ny, nz, w)
        if c < best:
            best = c
            bf = ids[lead]
    for j in range(o, offsets[cell + 1]):
        if j == lead or buf[j - o] >= best:
            continue
        f = ids[j]
        c, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, nx, ny, nz, w)
        if c < best:
            best = c
            bf = f
    if descend and bf >= 0:
        # greedy descent over vertex-adjacent faces: on smooth surfaces the face
        # whose normal best matches lies a few faces away from a sampled winner
        for _ in range(256):
            start_face = bf
            for j in range(adj_off[start_face], adj_off[start_face + 1]):
                best, bf = _try_face(tri, nrm, adj[j], px, py, pz, nx, ny, nz, w, best, bf)
            if bf == start_face:
                break
    return True, best, bf


@nb.njit(inline="always", **_NB)
def _grid_one(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
              plo, phi, nlo, nhi, left, right, start, count, px, py, pz, nx, ny, nz, w, descend, buf):
    listed, best, bf = _list_best(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                                  px, py, pz, nx, ny, nz, w, descend, np.inf, buf)
    if not listed:  # outside the grid, or a cell too crowded to list: exact through the tree
        best, bf, _, _, _ = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                     px, py, pz, nx, ny, nz, w, np.inf)
    return best, bf


@nb.njit(parallel=True, **_NB)
def _grid_query(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n, descend, buf):
    Q = P.shape[0]
    cost = np.empty(Q)
    face = np.empty(Q, np.int64)
    for q in nb.prange(Q):
        nx = ny = nz = 0.0
        if use_n:
            nx, ny, nz = N[q, 0], N[q, 1], N[q, 2]
        row = buf[nb.get_thread_id()]
        cost[q], face[q] = _grid_one(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                                     plo, phi, nlo, nhi, left, right, start, count,
                                     P[q, 0], P[q, 1], P[q, 2], nx, ny, nz, w, descend, row)
    return face, cost


@nb.njit(**_SERIAL)
def _grid_query_serial(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                       plo, phi, nlo, nhi, left, right, start, count, P, N, w, use_n, descend, buf):
    Q = P.shape[0]
    cost = np.empty(Q)
    face = np.empty(Q, np.int64)
    for q in range(Q):
        nx = ny = nz = 0.0
        if use_n:
            nx, ny, nz = N[q, 0], N[q, 1], N[q, 2]
        row = buf[nb.get_thread_id()]
        cost[q], face[q] = _grid_one(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                                     plo, phi, nlo, nhi, left, right, start, count,
                                     P[q, 0], P[q, 1], P[q, 2], nx, ny, nz, w, descend, row)
    return face, cost


@nb.njit(parallel=True, **_NB)
def _grid_lists_position(tri, plo, phi, nlo, nhi, nrm, left, right, start, count,
                         centres, half_diag, out_mask_rows, max_per_cell):
    """Position-only lists: every face whose distance to the centre is within
    dmin(centre) + 2 * half_diag can be the closest face somewhere in the cell."""
    C = centres.shape[0]
    counts = np.zeros(C, np.int64)
    for c in nb.prange(C):
        px, py, pz = centres[c, 0], centres[c, 1], centres[c, 2]
        best, _, _, _, _ = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                    px, py, pz, 0.0, 0.0, 0.0, 0.0, np.inf)
        r = np.sqrt(best) + 2.0 * half_diag
        r2 = r * r
        # range query: faces with distance^2 <= r2
        stack = np.empty(_STACK, np.int64)
        sp = 1
        stack[0] = 0
        k = 0
        while sp > 0:
            sp -= 1
            node = stack[sp]
            if _box_d2(px, py, pz, plo, phi, node) > r2:
                continue
            if left[node] < 0:
                for f in range(start[node], start[node] + count[node]):
                    d2, _, _, _ = _face_cost(tri, nrm, f, px, py, pz, 0.0, 0.0, 0.0, 0.0)
                    if d2 <= r2:
                        if k < max_per_cell:
                            out_mask_rows[c, k] = f
                        k += 1
            else:
                stack[sp] = left[node]
                stack[sp + 1] = right[node]
                sp += 2
        counts[c] = k
    return counts


#: the most faces a centre of the joint lists gathers; beyond, it searches the tree per
#: normal (a dense mesh, whose faces within reach are many)
GATHER_MOST = 4096


@nb.njit(parallel=True, **_NB)
def _grid_lists_joint(tri, nrm, plo, phi, left, right, start, count, centres, d2min, dirs, w, most, out_rows):
    """The exact winner of every centre for every direction (rows of ``dirs``: unit
    normals, or zero for the closest face in position); ``d2min`` holds each centre's
    squared distance to the mesh.

    One gather per centre instead of one search per direction: no face farther than
    sqrt(d^2 + 4 w) wins for any direction (the closest face costs at most d^2 +
    w |n - n_f|^2 <= d^2 + 4 w), so the faces within that reach are gathered once, sorted
    by distance, and each direction scans them nearest first until the distance alone
    passes its best cost. A centre with more than ``most`` faces within reach gets a row
    of -1 (its caller searches the tree per direction). Ties may pick another face of
    equal cost than a search of the tree would.
    """
    C = centres.shape[0]
    D = dirs.shape[0]
    F = tri.shape[0]
    for c in nb.prange(C):
        px, py, pz = centres[c, 0], centres[c, 1], centres[c, 2]
        reach = d2min[c] + 4.0 * w
        reach += 1e-9 * reach  # the gather's strict test must keep a face at exactly the reach
        cand = np.empty(min(F, most), np.int64)
        dist = np.empty(min(F, most))
        k = _faces_within(tri, nrm, plo, phi, left, right, start, count, px, py, pz, reach, cand, dist)
        if k > cand.shape[0]:
            out_rows[c, :] = -1
            continue
        order = np.argsort(dist[:k], kind="mergesort")
        for j in range(D):
            _, out_rows[c, j] = _nearest_first(nrm, cand, dist, order, k, dirs[j, 0], dirs[j, 1], dirs[j, 2], w,
                                               np.inf)


def _joint_winners(tree: BVH, centres, dirs, w: float, out_rows):
    """:func:`_grid_lists_joint` for a slice of centres, with the tree searches it leaves
    (each centre's distance to the mesh; every direction of a centre with too many faces
    within reach) done by the compiled exact query."""
    args = (tree.tri, tree.nrm, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start, tree.count)
    d2min = np.empty(len(centres))
    _bvh_query_costs(*args, centres, np.zeros_like(centres), 0.0, d2min)
    _grid_lists_joint(tree.tri, tree.nrm, tree.plo, tree.phi, tree.left, tree.right, tree.start, tree.count,
                      centres, d2min, dirs, float(w), GATHER_MOST, out_rows)
    over = np.flatnonzero(out_rows[:, 0] < 0)
    if len(over):
        P = np.ascontiguousarray(np.repeat(centres[over], len(dirs), axis=0))
        N = np.ascontiguousarray(np.tile(dirs, (len(over), 1)))
        f, _, _ = (_bvh_query if len(P) >= PARALLEL_MIN else _bvh_query_serial)(*args, P, N, float(w), True)
        out_rows[over] = f.reshape(len(over), len(dirs))


def fibonacci_sphere(n: int) -> np.ndarray:
    """n roughly evenly spread unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (1.0 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def build_candidate_grid(tree: BVH, levels, w: float, n_normals: int = 64,
                         max_list: int = 48, sigma2: float | None = None) -> CandidateGrid:
    """Precompute the candidate lists of every cell of each level.

    ``levels``: (lo, hi, cell) per level, finest first; a query uses the finest level
    whose box holds it. Joint cost (w > 0): a cell lists the winners at its centre for
    ``n_normals`` directions and the closest face; with ``sigma2`` (sigma_pos^2, the unit
    of d_M^2) the finest level's cells near the surface also get lists keyed by the
    query's normal (:func:`build_near_lists`). Position only: every face that can be
    closest in the cell, or an empty list (meaning: use the exact tree) when more than
    ``max_list`` qualify.
    """
    args = (tree.tri, tree.nrm, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start, tree.count)
    los, hs, shapes, counts_all, ids_all = [], [], [], [], []
    for lo, hi, cell in levels:
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        shape = np.maximum(1, np.ceil((hi - lo) / cell)).astype(np.int64)
        g = [lo[d] + (np.arange(shape[d]) + 0.5) * cell for d in range(3)]
        centres = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)
        if w > 0:
            # the sampled normals, plus a zero "normal" whose winner is the closest face in position
            dirs = np.vstack([fibonacci_sphere(n_normals), np.zeros((1, 3))])
            rows = np.empty((len(centres), len(dirs)), np.int64)
            # in slices, so that a long build (a dense mesh: tens of seconds) shows its progress
            cuts = np.linspace(0, len(centres), min(32, len(centres)) + 1).astype(np.int64)
            for a, b in progress(list(zip(cuts[:-1], cuts[1:])), desc=f"likelihood grid, level {len(los) + 1} of "
                                 f"{len(levels)} (built once per mesh, then kept on disk)"):
                _joint_winners(tree, centres[a:b], dirs, w, rows[a:b])
            rows.sort(axis=1)
            keep = np.ones_like(rows, dtype=bool)
            keep[:, 1:] = rows[:, 1:] != rows[:, :-1]
            counts = keep.sum(axis=1)
            ids = rows[keep]
        else:
            rows = np.full((len(centres), max_list), -1, np.int64)
            counts = _grid_lists_position(args[0], args[2], args[3], args[4], args[5], args[1],
                                          args[6], args[7], args[8], args[9], centres,
                                          0.5 * cell * np.sqrt(3.0), rows, max_list)
            counts = np.where(counts > max_list, 0, counts)  # crowded cells: exact fallback
            ids = rows[np.arange(max_list)[None, :] < counts[:, None]]
        los.append(lo)
        hs.append(float(cell))
        shapes.append(shape)
        counts_all.append(counts)
        ids_all.append(ids)
    counts = np.concatenate(counts_all)
    offsets = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    base = np.concatenate([[0], np.cumsum([len(c) for c in counts_all])[:-1]]).astype(np.int64)
    adj_off, adj = tree_adjacency(tree)
    grid = CandidateGrid(lo=np.array(los), h=np.array(hs), shape=np.array(shapes, np.int64), base=base,
                         offsets=offsets, ids=np.concatenate(ids_all).astype(np.int64), tri=tree.tri, nrm=tree.nrm,
                         w=float(w), adj_off=adj_off, adj=adj, longest=int(counts.max()) if len(counts) else 0,
                         **no_near_lists(), near_check=np.zeros(6))
    if w == 0 or sigma2 is None:
        return grid  # position only: exact (or the tree's answer) wherever it lists faces
    near = build_near_lists(tree, los[0], hs[0], shapes[0], w, float(sigma2), adjacency=(adj_off, adj))
    # the check against the exact method, on queries like those of a pose near the truth
    P, N = near_check_queries(tree, w, float(sigma2))
    exact = np.empty(len(P))
    _bvh_query_costs(*args, P, N, float(w), exact)
    _, general = query_grid(grid, tree, P, N)
    general_off = float(np.mean((general - exact) / sigma2 > NEAR_CHECK_ERROR))
    fast_off = float(np.mean((general - exact) / sigma2 > FAST_CHECK_ERROR))
    check = np.array([0.0, 0.0, 0.0, general_off, 0.0, fast_off])
    if near is not None:
        # the near lists beside the general ones: where they are off more often than the
        # general lists (faces small against the cells, whose winners change between the
        # samples) and than NEAR_CHECK_SHARE, they are dropped
        with_near = dataclasses.replace(grid, **near)
        found, cost = near_list_costs(with_near, P, N)
        err = (cost[found] - exact[found]) / sigma2
        near_off = float(np.mean(err > NEAR_CHECK_ERROR)) if found.any() else 0.0
        keep = near_off <= max(NEAR_CHECK_SHARE, general_off)
        if keep:
            grid = with_near
            _, fast = query_grid(grid, tree, P, N)
            fast_off = float(np.mean((fast - exact) / sigma2 > FAST_CHECK_ERROR))
        check = np.array([found.mean(), near_off, np.percentile(err, 99) if found.any() else 0.0, general_off,
                          float(keep), fast_off])
    return dataclasses.replace(grid, near_check=check)


def tree_adjacency(tree: BVH):
    """CSR lists of the faces sharing a vertex with each face, in tree order."""
    tri = tree.tri.reshape(-1, 3)
    _, vid = np.unique(np.round(tri, 12), axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    F = len(vid)
    # vertex -> faces, then face -> faces through its three vertices
    vf_v = vid.ravel()
    vf_f = np.repeat(np.arange(F), 3)
    order = np.argsort(vf_v, kind="stable")
    vf_v, vf_f = vf_v[order], vf_f[order]
    voff = np.searchsorted(vf_v, np.arange(vid.max() + 2))
    pairs_a, pairs_b = [], []
    for k in range(3):
        v = vid[:, k]
        n = voff[v + 1] - voff[v]
        a = np.repeat(np.arange(F), n)
        idx = np.repeat(voff[v], n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
        pairs_a.append(a)
        pairs_b.append(vf_f[idx])
    a = np.concatenate(pairs_a)
    b = np.concatenate(pairs_b)
    keep = a != b
    key = np.unique(a[keep] * F + b[keep])
    a, b = key // F, key % F
    off = np.zeros(F + 1, np.int64)
    np.cumsum(np.bincount(a, minlength=F), out=off[1:])
    return off, b.astype(np.int64)


def query_grid(grid: CandidateGrid, tree: BVH, P, N):
    """Query through the candidate grid (exact BVH fallback outside it).

    Returns face (Q,) original face indices and cost (Q,) as in :func:`query_joint`.
    """
    P = kernel_array(P).reshape(-1, 3)
    use_n = grid.w > 0 and N is not None
    Nn = kernel_array(N if use_n else np.zeros((1, 3)))
    if len(P) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    kernel = _grid_query if len(P) >= PARALLEL_MIN else _grid_query_serial
    f, c = kernel(grid.tri, grid.nrm, grid.lo, grid.h, grid.shape, grid.base, grid.offsets, grid.ids, grid.adj_off,
                  grid.adj, grid.near, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start, tree.count,
                  P, Nn, grid.w if use_n else 0.0, use_n, use_n, grid.scratch())
    return tree.face_id[f], c


# ---------------------------------------------------------------------------------------
# poses x contacts in one pass, with an optional per-pose budget
#: how a pair is evaluated by :func:`pose_costs`
EXACT, GRID = 0, 1


@nb.njit(inline="always", **_NB)
def _pair_cost(mode, tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
               plo, phi, nlo, nhi, left, right, start, count, px, py, pz, nx, ny, nz, w, descend, rem, buf):
    """min(cost, rem) of one object-frame query (rem: what the pose has left of its budget)."""
    if mode == GRID:
        # the list's own answer whatever the budget (the descent starts from its best face)
        listed, best, _ = _list_best(tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                                     px, py, pz, nx, ny, nz, w, descend, np.inf, buf)
        if listed:
            return min(best, rem)
    best, _, _, _, _ = _bvh_one(tri, nrm, plo, phi, nlo, nhi, left, right, start, count,
                                px, py, pz, nx, ny, nz, w, rem)
    return best


@nb.njit(inline="always", **_NB)
def object_frame(poses, i, P, N, k, use_n):
    """Contact k (world point P[k], normal N[k]) in the frame of pose i: R^T (p - t) and
    R^T n (the normal zero when ``use_n`` is False)."""
    dx = P[k, 0] - poses[i, 0, 3]
    dy = P[k, 1] - poses[i, 1, 3]
    dz = P[k, 2] - poses[i, 2, 3]
    px = poses[i, 0, 0] * dx + poses[i, 1, 0] * dy + poses[i, 2, 0] * dz
    py = poses[i, 0, 1] * dx + poses[i, 1, 1] * dy + poses[i, 2, 1] * dz
    pz = poses[i, 0, 2] * dx + poses[i, 1, 2] * dy + poses[i, 2, 2] * dz
    nx = ny = nz = 0.0
    if use_n:
        nx = poses[i, 0, 0] * N[k, 0] + poses[i, 1, 0] * N[k, 1] + poses[i, 2, 0] * N[k, 2]
        ny = poses[i, 0, 1] * N[k, 0] + poses[i, 1, 1] * N[k, 1] + poses[i, 2, 1] * N[k, 2]
        nz = poses[i, 0, 2] * N[k, 0] + poses[i, 1, 2] * N[k, 1] + poses[i, 2, 2] * N[k, 2]
    return px, py, pz, nx, ny, nz


@nb.njit(inline="always", **_NB)
def _pose_row(i, mode, poses, P, N, use_n, w, budget, cap, lower, use_lower, tri, nrm, lo, h, shape, base, offsets,
              ids, adj_off, adj, near, bvh, out, buf):
    """Costs of pose i for every contact, each at most ``cap``, in order, until they reach
    the pose's budget.

    Returns True when every contact was evaluated (their sum is below the budget);
    otherwise the sum of out[i] is at least the budget and the remaining entries are 0.

    With ``use_lower``, ``lower[i]`` holds lower bounds of the pose's costs: the pose
    stops as soon as its costs so far plus the bounds of the contacts after reach the
    budget (at once if the bounds alone do), and the entries not evaluated hold their
    bounds instead of 0 (so each entry is still at most its cost). ``bvh`` holds the tree's
    arrays (plo, phi, nlo, nhi, left, right, start, count) in one tuple: CPython passes a
    call of more than 30 arguments as ``*args``, which numba cannot inline. ``buf`` is
    the calling thread's scratch row (:meth:`CandidateGrid.scratch`).
    """
    plo, phi, nlo, nhi, left, right, start, count = bvh
    K = P.shape[0]
    b = budget[i]
    s = 0.0
    after = 0.0  # the bounds of the contacts after the current one
    for k in range(K):
        out[i, k] = 0.0
    if use_lower:
        for k in range(K):
            after += lower[i, k]
        if after >= b:
            for k in range(K):
                out[i, k] = lower[i, k]
            return False
    for k in range(K):
        if use_lower:
            after -= lower[i, k]
            if after < 0.0:
                after = 0.0
        px, py, pz, nx, ny, nz = object_frame(poses, i, P, N, k, use_n)
        rem = b - s - after
        # a capped pair never needs its search beyond the cap, and never ends the row
        c = _pair_cost(mode, tri, nrm, lo, h, shape, base, offsets, ids, adj_off, adj, near,
                       plo, phi, nlo, nhi, left, right, start, count, px, py, pz, nx, ny, nz,
                       w if use_n else 0.0, use_n, min(rem, cap), buf)
        out[i, k] = c
        if c >= rem:
            if use_lower:
                for j in range(k + 1, K):
                    out[i, j] = lower[i, j]
            return False
        s += c
    return True


@nb.njit(parallel=True, **_NB)
def _pose_costs(mode, poses, P, N, use_n, w, budget, cap, lower, use_lower, tri, nrm, lo, h, shape, base, offsets,
                ids, adj_off, adj, near, plo, phi, nlo, nhi, left, right, start, count, buf):
    n = poses.shape[0]
    out = np.empty((n, P.shape[0]))
    done = np.empty(n, np.bool_)
    bvh = (plo, phi, nlo, nhi, left, right, start, count)
    for i in nb.prange(n):
        done[i] = _pose_row(i, mode, poses, P, N, use_n, w, budget, cap, lower, use_lower, tri, nrm, lo, h, shape,
                            base, offsets, ids, adj_off, adj, near, bvh, out, buf[nb.get_thread_id()])
    return out, done


@nb.njit(**_SERIAL)
def _pose_costs_serial(mode, poses, P, N, use_n, w, budget, cap, lower, use_lower, tri, nrm, lo, h, shape, base,
                       offsets, ids, adj_off, adj, near, plo, phi, nlo, nhi, left, right, start, count, buf):
    n = poses.shape[0]
    out = np.empty((n, P.shape[0]))
    done = np.empty(n, np.bool_)
    bvh = (plo, phi, nlo, nhi, left, right, start, count)
    for i in range(n):
        done[i] = _pose_row(i, mode, poses, P, N, use_n, w, budget, cap, lower, use_lower, tri, nrm, lo, h, shape,
                            base, offsets, ids, adj_off, adj, near, bvh, out, buf[nb.get_thread_id()])
    return out, done


_NO_GRID = None


def _no_grid():
    """Stand-in grid arrays for the exact mode (never read)."""
    global _NO_GRID
    if _NO_GRID is None:
        z = np.zeros(1, np.int64)
        _NO_GRID = (np.zeros((1, 3)), np.ones(1), np.zeros((1, 3), np.int64), z, np.zeros(2, np.int64), z,
                    np.zeros(2, np.int64), z, _near_tuple(no_near_lists(), 0))
    return _NO_GRID


def pose_costs(tree: BVH, poses, P, N, w: float, *, grid: CandidateGrid | None = None, budget=None,
               cap: float = np.inf, lower=None):
    """Joint costs (m^2, as :func:`query_joint`) of world contacts seen from each pose.

    Parameters
    ----------
    tree : BVH
    poses : (n, 4, 4) float
        Rigid T_world_object (trusted: not checked).
    P, N : (K, 3) float
        World contact points and unit normals (N None: position only).
    w : float
        Normal weight sigma_pos^2 / sigma_nor^2 (0: position only).
    grid : CandidateGrid, optional
        The ``fast`` method: the minimum over the cell's candidate list where there is
        one, the tree elsewhere. Without it: exact, through the tree.
    budget : (n,) float, optional
        Per pose: stop evaluating its contacts once their sum reaches this (m^2).
    cap : float
        Each pair's cost is at most this (m^2): beyond it a contact is an outlier.
    lower : (n, K) float, optional
        Lower bounds of the costs (m^2; :func:`touchloc.models._bounds.lower_costs`): a
        pose stops once its costs so far plus the bounds of its other contacts reach its
        budget, and its pairs not evaluated hold their bounds.

    Returns
    -------
    costs : (n, K) float
        Per-pair costs; a pose stopped by its budget has its evaluated pairs (the last
        one capped at what remained) and zeros after (their bounds, with ``lower``), so its
        row sums to at least its budget.
    done : (n,) bool
        False for the poses stopped by their budget.
    """
    poses = kernel_array(poses)
    P = kernel_array(P).reshape(-1, 3)
    use_n = N is not None and w > 0
    Nn = kernel_array(N if use_n else np.zeros((1, 3)))
    n = len(poses)
    b = np.full(n, np.inf) if budget is None else kernel_array(budget).reshape(n)
    if grid is None:
        mode = EXACT
        g = _no_grid()
        buf = np.empty((nb.config.NUMBA_NUM_THREADS, 1))  # never read
    else:
        mode = GRID
        g = (grid.lo, grid.h, grid.shape, grid.base, grid.offsets, grid.ids, grid.adj_off, grid.adj, grid.near)
        buf = grid.scratch()
    if n == 0 or len(P) == 0:
        return np.zeros((n, len(P))), np.ones(n, bool)
    items = n * len(P)
    which = POSE_COSTS_THREADS.pick(items)
    t0 = time.perf_counter()
    use_lower = lower is not None
    lo_arr = kernel_array(lower).reshape(n, len(P)) if use_lower else np.zeros((1, 1))
    out = (_pose_costs if which else _pose_costs_serial)(
        mode, poses, P, Nn, use_n, float(w) if use_n else 0.0, b, float(cap), lo_arr, use_lower, tree.tri, tree.nrm, *g,
        tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start, tree.count, buf)
    POSE_COSTS_THREADS.record(which, items, time.perf_counter() - t0)
    return out
