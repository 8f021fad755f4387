"""Compiled step of a 2-D field driven by two ridges (:meth:`Field2D._step_ridges`).

The tracker's comparison field is a 360 x 360 field of which a block of some 20 x 20 sites
is active. Its step is a few small matrix products and a few dozen index operations on
arrays of 20-100 entries; in numpy each of those costs more in call overhead than in
arithmetic, so the index work runs here, compiled, and the products stay with BLAS
(``np.dot`` on float32 or float64 arrays). Every sum is formed in the field's dtype and in
the order numpy would form it (``(a + b) + P``), so the result equals a numpy version of
the same step to the bit.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._cache import numba_cache_enabled

# cache=: compiled code kept on disk when numba has a writable place for it (see touchloc._cache)
_NB = dict(cache=numba_cache_enabled(__file__), nogil=True)


@nb.njit(**_NB)
def dilate(idx, r, n):
    """Sorted sites within ``r`` (periodic) of any site in ``idx``: the window of an active
    block's lateral input (here and in :meth:`Field2D._add_block_lateral`)."""
    if 2 * r + 1 >= n:
        return np.arange(n)
    mark = np.zeros(n, dtype=np.bool_)
    for i in idx:
        for k in range(i - r, i + r + 1):
            mark[k % n] = True
    return np.flatnonzero(mark)


@nb.njit(**_NB)
def ridge_step(a, b, rows0, cols0, block0, g0, g1, reach0, reach1, ue):
    """The new activation of a field whose lateral input comes from its active block.

    ``u = a[:, None] + b[None, :] + P``, where ``P`` is the block's lateral input on the
    window ``W0 x W1`` (the sites within reach of the block) and zero elsewhere.

    Parameters
    ----------
    a, b : (n0,), (n1,) float
        The two ridges of the input, ``a`` with the resting level and the global term added.
    rows0, cols0 : (r,), (c,) int64
        The active block's rows and columns (sorted); ``block0`` (r, c) its output.
    g0, g1 : (T, n0), (T, n1) float
        Each separable term's Gaussian over the periodic distance, zero beyond its reach;
        ``g1`` carries the term's strength.
    reach0, reach1 : int
        The largest reach of the terms along each dimension, in sites.
    ue : float
        The activation above which a site's output exceeds ``eps``.

    Returns
    -------
    W0, W1, P
        The window and the lateral input on it.
    R, C, U
        The new active block's rows, columns and activation.
    """
    n0, n1 = a.shape[0], b.shape[0]
    if rows0.size:
        W0 = dilate(rows0, reach0, n0)
        W1 = dilate(cols0, reach1, n1)
        P = np.zeros((W0.size, W1.size), dtype=a.dtype)
        A = np.empty((W0.size, rows0.size), dtype=a.dtype)
        B = np.empty((cols0.size, W1.size), dtype=a.dtype)
        for t in range(g0.shape[0]):
            for i in range(W0.size):
                for j in range(rows0.size):
                    A[i, j] = g0[t, (W0[i] - rows0[j]) % n0]
            for j in range(cols0.size):
                for k in range(W1.size):
                    B[j, k] = g1[t, (cols0[j] - W1[k]) % n1]
            P += np.dot(np.dot(A, block0), B)
    else:
        W0 = np.zeros(0, dtype=np.int64)
        W1 = np.zeros(0, dtype=np.int64)
        P = np.zeros((0, 0), dtype=a.dtype)
    in0 = np.full(n0, -1, dtype=np.int64)      # a site's place in W0, or -1
    for i in range(W0.size):
        in0[W0[i]] = i
    in1 = np.full(n1, -1, dtype=np.int64)
    for k in range(W1.size):
        in1[W1[k]] = k
    # row maxima: b's largest entry outside the window, and every sum inside it
    rowmax = a + b.max()
    has_out, b_out = False, b[0]
    for y in range(n1):
        if in1[y] < 0 and (not has_out or b[y] > b_out):
            has_out, b_out = True, b[y]
    for i in range(W0.size):
        x = W0[i]
        best = a[x] + b_out
        for k in range(W1.size):
            v = a[x] + b[W1[k]] + P[i, k]
            if (k == 0 and not has_out) or v > best:
                best = v
        rowmax[x] = best
    R = np.flatnonzero(rowmax > ue)
    if R.size == 0:
        return W0, W1, P, R, R, np.zeros((0, 0), dtype=a.dtype)
    # column maxima over the rows of R: a's largest entry in R outside the window, and
    # every sum inside it
    colmax = b + a[R].max()
    has_out, a_out = False, a[R[0]]
    for x in R:
        if in0[x] < 0 and (not has_out or a[x] > a_out):
            has_out, a_out = True, a[x]
    for k in range(W1.size):
        y = W1[k]
        best = b[y] + a_out
        first = not has_out
        for x in R:
            i = in0[x]
            if i >= 0:
                v = a[x] + b[y] + P[i, k]
                if first or v > best:
                    best, first = v, False
        if not first:
            colmax[y] = best
    C = np.flatnonzero(colmax > ue)
    U = np.empty((R.size, C.size), dtype=a.dtype)
    for p in range(R.size):
        x = R[p]
        i = in0[x]
        for q in range(C.size):
            y = C[q]
            v = a[x] + b[y]
            if i >= 0 and in1[y] >= 0:
                v = v + P[i, in1[y]]
            U[p, q] = v
    return W0, W1, P, R, C, U


def load_kernels() -> None:
    """Compile (the first time after an install) or load :func:`ridge_step` for the argument
    types the tracker passes: a small comparison-like field stepped twice, from rest and
    from an active block. Costs well under a millisecond once loaded."""
    from .fields import Field2D, FieldParams

    field = Field2D((36, 36), FieldParams(h=-8.0, c_exc=0.3, c_glob=0.0005))
    ridge = np.zeros(36, dtype=np.float32)
    ridge[3] = 9.0
    for _ in range(2):
        field.step((ridge[:, None], ridge[None, :]))
