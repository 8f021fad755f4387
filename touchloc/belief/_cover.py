"""Ball counting for the even density cover of Scaling Series (Alg. 1).

The cover draws candidates from the delta-balls around the centres and keeps each with
probability 1 / (number of balls that contain it). The count is the expensive part:
with thousands of centres in a 7-D embedding, a KD-tree query per candidate costs a
few microseconds. Every ball that contains a candidate drawn from the ball of centre i
has its centre within 2 delta of centre i, so a candidate only needs to be compared
with the 2-delta neighbours of its own parent. The neighbour lists come from one
KD-tree pair query over the centres (far fewer centres than candidates) and the
comparisons run in a compiled, parallel loop.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from scipy.spatial import cKDTree

from .._cache import numba_cache_enabled

__all__ = ["BallCounter", "ball_counts", "accept_draws", "draw_full", "in_box"]

#: Above this many neighbour pairs (per candidate) the pair lists cost more (in time and
#: memory) than counting otherwise: a capped scan where balls overlap heavily, else a
#: KD-tree query per candidate.
MAX_PAIRS_PER_CANDIDATE = 32

# cache=: compiled code kept on disk when numba has a writable place for it (see touchloc._cache)
_NB = dict(cache=numba_cache_enabled(__file__), nogil=True)


@nb.njit(inline="always", **_NB)
def _d2(A, j, X, q):
    """Squared distance between row j of A and row q of X."""
    d = 0.0
    for k in range(X.shape[1]):
        t = A[j, k] - X[q, k]
        d += t * t
    return d


@nb.njit(inline="always", **_NB)
def _in_list(A, off, nbr, X, q, a, r2):
    c = 0
    for jj in range(off[a], off[a + 1]):
        if _d2(A, nbr[jj], X, q) <= r2:
            c += 1
    return c


@nb.njit(parallel=True, **_NB)
def _count_in_lists(A, off, nbr, X, anchor, r2):
    out = np.zeros(X.shape[0], np.int64)
    for q in nb.prange(X.shape[0]):
        out[q] = _in_list(A, off, nbr, X, q, anchor[q], r2)
    return out


@nb.njit(**_NB)
def _count_in_lists_serial(A, off, nbr, X, anchor, r2):
    out = np.zeros(X.shape[0], np.int64)
    for q in range(X.shape[0]):
        out[q] = _in_list(A, off, nbr, X, q, anchor[q], r2)
    return out


@nb.njit(**_NB)
def _csr(pairs, n):
    """Symmetric neighbour lists (self included) from (P, 2) index pairs i < j."""
    deg = np.ones(n, np.int64)
    for p in range(pairs.shape[0]):
        deg[pairs[p, 0]] += 1
        deg[pairs[p, 1]] += 1
    off = np.zeros(n + 1, np.int64)
    for i in range(n):
        off[i + 1] = off[i] + deg[i]
    fill = off[:-1].copy()
    nbr = np.empty(off[n], np.int64)
    for i in range(n):
        nbr[fill[i]] = i
        fill[i] += 1
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        nbr[fill[a]] = b
        fill[a] += 1
        nbr[fill[b]] = a
        fill[b] += 1
    return off, nbr


@nb.njit(inline="always", **_NB)
def _capped_one(A, X, q, r2, cap):
    c = 0
    for j in range(A.shape[0]):
        if _d2(A, j, X, q) <= r2:
            c += 1
            if c >= cap:
                break
    return c


@nb.njit(parallel=True, **_NB)
def _count_capped(A, X, r2, cap):
    """min(cap, number of rows of A within sqrt(r2) of each row of X), scanning A in order."""
    out = np.zeros(X.shape[0], np.int64)
    for q in nb.prange(X.shape[0]):
        out[q] = _capped_one(A, X, q, r2, cap)
    return out


@nb.njit(**_NB)
def _count_capped_serial(A, X, r2, cap):
    out = np.zeros(X.shape[0], np.int64)
    for q in range(X.shape[0]):
        out[q] = _capped_one(A, X, q, r2, cap)
    return out


@nb.njit(inline="always", **_NB)
def _draw_one(i, g, u, qc, tc, pick, free, r, rho, t, q, emb):
    d = g.shape[1]
    k = free.shape[0]
    nrm = 0.0
    for j in range(d):
        nrm += g[i, j] * g[i, j]
    scale = r * u[i] ** (1.0 / d) / np.sqrt(nrm)
    c = pick[i]
    for j in range(3):
        t[i, j] = tc[c, j]
    for j in range(k):
        t[i, free[j]] += g[i, j] * scale
        emb[i, j] = t[i, free[j]]
    wx = g[i, k] * scale / rho
    wy = g[i, k + 1] * scale / rho
    wz = g[i, k + 2] * scale / rho
    a = np.sqrt(wx * wx + wy * wy + wz * wz)
    sa = np.sin(0.5 * a) / a if a > 1e-6 else 0.5 - a * a / 48.0
    px, py, pz, pw = wx * sa, wy * sa, wz * sa, np.cos(0.5 * a)
    qx, qy, qz, qw = qc[c, 0], qc[c, 1], qc[c, 2], qc[c, 3]
    # Hamilton product p q: the centre's rotation, then the perturbation
    x = pw * qx + qw * px + (py * qz - pz * qy)
    y = pw * qy + qw * py + (pz * qx - px * qz)
    z = pw * qz + qw * pz + (px * qy - py * qx)
    w = pw * qw - (px * qx + py * qy + pz * qz)
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    q[i, 0], q[i, 1], q[i, 2], q[i, 3] = x, y, z, w
    emb[i, k], emb[i, k + 1], emb[i, k + 2], emb[i, k + 3] = 2 * rho * x, 2 * rho * y, 2 * rho * z, 2 * rho * w


@nb.njit(parallel=True, **_NB)
def _draw_full_parallel(g, u, qc, tc, pick, free, r, rho, t, q, emb):
    for i in nb.prange(g.shape[0]):
        _draw_one(i, g, u, qc, tc, pick, free, r, rho, t, q, emb)


@nb.njit(**_NB)
def _draw_full_serial(g, u, qc, tc, pick, free, r, rho, t, q, emb):
    for i in range(g.shape[0]):
        _draw_one(i, g, u, qc, tc, pick, free, r, rho, t, q, emb)


def draw_full(g, u, qc, tc, pick, free, r, rho):
    """Candidates uniform in the metric balls of radius ``r`` around centres (full rotations).

    ``g`` (n, d) standard normals and ``u`` (n,) uniforms (drawn by the caller, so that the
    random stream is numpy's), ``qc`` (C, 4) the centres' unit quaternions (x, y, z, w),
    ``tc`` (C, 3) their translations, ``pick`` (n,) the centre of each draw, ``free`` (k,)
    the free translation axes (d = k + 3), ``rho`` the metric's length scale. Draw i is
    ``v = g_i / |g_i| * r * u_i^(1/d)``, its translation ``tc[pick] + v[:k]`` on the free
    axes, its rotation ``exp(v[k:] / rho) qc[pick]`` with the sign that makes w >= 0
    (as :meth:`PoseRegion.perturb` with ``ball=True``, in quaternions).

    Returns ``t`` (n, 3), ``q`` (n, 4) and the embedding (n, k + 4): free translation,
    then ``2 rho q`` (:meth:`PoseRegion.embed`).
    """
    n, k = g.shape[0], len(free)
    t, q, emb = np.empty((n, 3)), np.empty((n, 4)), np.empty((n, k + 4))
    kernel = _draw_full_parallel if n >= PARALLEL_MIN else _draw_full_serial
    kernel(g, u, qc, tc, pick, free, float(r), float(rho), t, q, emb)
    return t, q, emb


@nb.njit(**_NB)
def in_box(t, center, half_extent):
    """(n,) bool: rows of ``t`` (n, 3) within ``half_extent`` (+1e-9) of ``center`` on every
    axis; the same comparisons as numpy's ``np.all(np.abs(t - center) <= half_extent + 1e-9, 1)``."""
    out = np.empty(t.shape[0], np.bool_)
    for i in range(t.shape[0]):
        ok = True
        for j in range(t.shape[1]):
            if not abs(t[i, j] - center[j]) <= half_extent[j] + 1e-9:
                ok = False
                break
        out[i] = ok
    return out


@nb.njit(**_NB)
def quat_poses(q, idx, t):
    """(len(idx), 4, 4) poses of the rows ``idx`` of quaternions ``q`` (n, 4; x, y, z, w)
    and translations ``t`` (n, 3): the same arithmetic, in the same order, as scipy's
    ``Rotation.from_quat(q).as_matrix()`` (normalised, then the usual products), so bit
    for bit its matrices, without its per-call overhead."""
    out = np.zeros((idx.shape[0], 4, 4))
    for k in range(idx.shape[0]):
        i = idx[k]
        x, y, z, w = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        n = np.sqrt(x * x + y * y + z * z + w * w)
        x /= n
        y /= n
        z /= n
        w /= n
        x2, y2, z2, w2 = x * x, y * y, z * z, w * w
        xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
        out[k, 0, 0] = x2 - y2 - z2 + w2
        out[k, 1, 0] = 2 * (xy + zw)
        out[k, 2, 0] = 2 * (xz - yw)
        out[k, 0, 1] = 2 * (xy - zw)
        out[k, 1, 1] = -x2 + y2 - z2 + w2
        out[k, 2, 1] = 2 * (yz + xw)
        out[k, 0, 2] = 2 * (xz + yw)
        out[k, 1, 2] = 2 * (yz - xw)
        out[k, 2, 2] = -x2 - y2 + z2 + w2
        out[k, 0, 3] = t[i, 0]
        out[k, 1, 3] = t[i, 1]
        out[k, 2, 3] = t[i, 2]
        out[k, 3, 3] = 1.0
    return out


@nb.njit(**_NB)
def matrix_quats(R):
    """(n, 4) unit quaternions (x, y, z, w) of rotation matrices ``R`` (n, 3, 3): the same
    arithmetic, in the same order, as scipy's ``Rotation.from_matrix(R, assume_valid=True)
    .as_quat()`` (the largest of the diagonal and the trace picks the formula), so bit for
    bit its quaternions, without its per-call overhead."""
    out = np.empty((R.shape[0], 4))
    for i in range(R.shape[0]):
        m = R[i]
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        c, best = 0, m[0, 0]
        if m[1, 1] > best:
            c, best = 1, m[1, 1]
        if m[2, 2] > best:
            c, best = 2, m[2, 2]
        if tr > best:
            c = 3
        if c == 3:
            out[i, 0] = m[2, 1] - m[1, 2]
            out[i, 1] = m[0, 2] - m[2, 0]
            out[i, 2] = m[1, 0] - m[0, 1]
            out[i, 3] = 1 + tr
        else:
            a = c
            b = (a + 1) % 3
            k = (b + 1) % 3
            out[i, a] = 1 - tr + 2 * m[a, a]
            out[i, b] = m[b, a] + m[a, b]
            out[i, k] = m[k, a] + m[a, k]
            out[i, 3] = m[k, b] - m[b, k]
        n = np.sqrt(out[i, 0] * out[i, 0] + out[i, 1] * out[i, 1] + out[i, 2] * out[i, 2] + out[i, 3] * out[i, 3])
        for j in range(4):
            out[i, j] /= n
    return out


@nb.njit(**_NB)
def _beyond(X, E, parent, r2):
    """(M,) bool: squared distance from each row of X to its parent's row of E above r2
    (summed in numpy's order for rows this short, so the same test bit for bit)."""
    out = np.empty(X.shape[0], np.bool_)
    for q in range(X.shape[0]):
        p = parent[q]
        d = 0.0
        for k in range(X.shape[1]):
            t = X[q, k] - E[p, k]
            d += t * t
        out[q] = d > r2
    return out


#: Below this many candidates the counts run on one thread (the thread pool's start-up
#: costs more than it saves, and much more on a loaded machine).
PARALLEL_MIN = 4096


def _in_lists(A, off, nbr, X, anchor, r2):
    kernel = _count_in_lists if len(X) >= PARALLEL_MIN else _count_in_lists_serial
    return kernel(A, off, nbr, X, anchor, r2)


#: Each stage of the capped counts caps this many times higher than the one before.
STAGE = 16


def _capped(A, X, r2, cap):
    kernel = _count_capped if len(X) * len(A) >= PARALLEL_MIN * 256 else _count_capped_serial
    return kernel(A, X, r2, cap)


def _flipped_copies(E, rr, flip_dims):
    """Centres plus the flipped copies that can matter, and the row of each centre's copy
    (-1: none). The sign-fixed coordinate of a flipped copy is -s: at distance >= s from
    any sign-fixed point, so only copies of centres with s <= rr can count."""
    near = np.flatnonzero(E[:, -1] <= rr) if flip_dims else np.zeros(0, np.int64)
    if len(near) == 0:
        return E, None
    F = E[near].copy()
    F[:, -flip_dims:] *= -1.0
    flip_of = np.full(len(E), -1, np.int64)
    flip_of[near] = len(E) + np.arange(len(near))
    return np.vstack([E, F]), flip_of


def _plan(tree, n, rr, n_queries, cap):
    """How to count, from the neighbourhoods of a few centres.

    Returns ("lists", (off, nbr)) when the neighbour lists within 2 rr are small,
    ("capped", None) when the balls overlap so much that a capped scan stops early, and
    ("tree", None) otherwise (one KD-tree query per candidate).
    """
    A = tree.data
    probe = A[np.linspace(0, n - 1, min(n, 64)).astype(np.int64)]
    # the probes' squared distances to every centre in one product (an estimate to plan
    # by: where the balls overlap heavily, 128 tree queries of the whole set cost more)
    d2 = np.einsum("ij,ij->i", A, A)[None, :] - 2.0 * (probe @ A.T) + np.einsum("ij,ij->i", probe, probe)[:, None]
    mean_2r = float(np.count_nonzero(d2 <= 4.0 * rr * rr)) / len(probe)
    if mean_2r * n <= MAX_PAIRS_PER_CANDIDATE * max(n_queries, 1) + 1e5:
        pairs = tree.query_pairs(2 * rr, output_type="ndarray")
        return "lists", _csr(np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2), n)
    mean_r = float(np.count_nonzero(d2 <= rr * rr)) / len(probe)
    return ("capped" if mean_r >= cap else "tree"), None


def _tree_counts(tree, X, rr):
    return np.asarray(tree.query_ball_point(X, rr, return_length=True, workers=-1), dtype=np.int64)


class BallCounter:
    """Ball counts for candidates drawn from the balls of radius ``r`` around a set of
    centres: the centres' tree and neighbour lists are built once and serve every batch
    of candidates drawn from these balls.

    ``n_queries`` (the candidates expected in a batch) and ``cap`` choose how to count
    (:func:`_plan`); see :func:`ball_counts` and :func:`accept_draws` for the rest.
    """

    def __init__(self, centres_emb, r, *, flip_dims: int = 0, n_queries: int = 0, cap=16):
        self.E = np.ascontiguousarray(centres_emb, dtype=np.float64)
        self.rr = r * 1.0000001
        self.cap = cap
        self.A, self._flip_of = _flipped_copies(self.E, self.rr, flip_dims)
        self.tree = cKDTree(self.A)
        self.how, self._lists = ("tree", None) if len(self.E) == 0 else _plan(self.tree, len(self.A), self.rr,
                                                                                n_queries, cap)

    def _anchor(self, X, parent):
        """Each candidate's anchor: its parent, or the parent's flipped copy where that is
        the one within ``rr`` of it."""
        anchor = parent.copy()
        if self._flip_of is not None:
            fp = self._flip_of[parent]
            far = _beyond(X, self.E, parent, self.rr * self.rr) & (fp >= 0)
            anchor[far] = fp[far]
        return anchor

    def counts(self, X, parent):
        """(M,) exact counts of the candidates X (M, D) (rows of their parents' balls)."""
        if self.how != "lists":
            return _tree_counts(self.tree, X, self.rr)
        return _in_lists(self.A, self._lists[0], self._lists[1], X, self._anchor(X, parent), self.rr * self.rr)

    def accept(self, cand_emb, parent, rng, mask=None):
        """(M,) bool: each candidate kept with probability 1 / count (see :func:`accept_draws`)."""
        X = np.ascontiguousarray(cand_emb, dtype=np.float64)
        parent = np.asarray(parent, dtype=np.int64)
        M = len(X)
        idx = np.arange(M) if mask is None else np.flatnonzero(mask)
        out = np.zeros(M, dtype=bool)
        # one uniform per candidate, masked or not: the random stream (and so the result)
        # is that of counting every candidate
        u = rng.random(M)[idx]
        if len(idx) == 0 or len(self.E) == 0:
            return out
        X, parent = X[idx], parent[idx]
        rr, cap = self.rr, self.cap
        if self.how != "capped":
            out[idx] = u * np.maximum(self.counts(X, parent), 1) < 1.0
            return out
        cnt = np.maximum(_capped(self.A, X, rr * rr, cap), 1)
        keep = u * cnt < 1.0
        sat = np.flatnonzero(keep & (cnt >= cap))
        # the candidates kept at a saturated cap c are counted again up to STAGE c, and kept
        # with probability c / that count; those that saturate it go on, and the last
        # stage counts fully: 1 / count in all. Where the balls nearly all overlap (the
        # first scales), full counts of every saturated candidate took two thirds of the cover
        while len(sat):
            nxt = cap * STAGE
            if nxt >= len(self.A):
                full = _tree_counts(self.tree, X[sat], rr)
                keep[sat] = rng.random(len(sat)) * full < cap
                break
            cnt = _capped(self.A, X[sat], rr * rr, nxt)
            ok = rng.random(len(sat)) * cnt < cap
            keep[sat] = ok
            sat, cap = sat[ok & (cnt >= nxt)], nxt
        out[idx] = keep
        return out


def ball_counts(centres_emb, cand_emb, parent, r, *, flip_dims: int = 0):
    """Number of balls of radius ``r`` around the centres that contain each candidate.

    Parameters
    ----------
    centres_emb : (C, D) float
        Embedded centres.
    cand_emb : (M, D) float
        Embedded candidates; candidate q lies within ``r`` of the embedded centre
        ``parent[q]`` or (with ``flip_dims``) of its flipped copy.
    parent : (M,) int
    r : float
    flip_dims : int
        The embedding identifies ``e`` with ``e`` whose last ``flip_dims`` coordinates
        are negated (a quaternion and its negative): a centre also contains a candidate
        when its flipped copy is within ``r``. The last coordinate must be the
        sign-fixed one (>= 0 in every embedding).

    Returns
    -------
    (M,) int
        The counts (exact; >= 1 up to rounding).
    """
    X = np.ascontiguousarray(cand_emb, dtype=np.float64)
    counter = BallCounter(centres_emb, r, flip_dims=flip_dims, n_queries=len(X), cap=np.inf)
    return counter.counts(X, np.asarray(parent, dtype=np.int64))


def accept_draws(centres_emb, cand_emb, parent, r, rng, *, flip_dims: int = 0, mask=None, cap: int = 16):
    """Keep each candidate with probability 1 / (number of balls containing it).

    Same parameters as :func:`ball_counts`, plus ``rng`` (numpy Generator) and ``mask``
    (M,) bool: candidates to consider (the others are never kept). When the balls
    overlap heavily (early scales, or many centres), counts are capped at ``cap``: a
    candidate in ``cap`` or more balls is first kept with probability 1 / cap, and
    only those kept are counted again (capped at ``STAGE`` times ``cap``, and so on, the
    last time fully) and kept again with probability cap / count, so each candidate is
    still kept with probability exactly 1 / count.

    Returns
    -------
    (M,) bool
    """
    n = len(cand_emb) if mask is None else int(np.count_nonzero(mask))
    counter = BallCounter(centres_emb, r, flip_dims=flip_dims, n_queries=n, cap=cap)
    return counter.accept(cand_emb, parent, rng, mask)
