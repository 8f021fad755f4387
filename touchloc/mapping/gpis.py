"""A Gaussian-process implicit surface with gradient observations, updated incrementally.

The surface is the zero level set of a function f: R^3 -> R that behaves like a signed
distance (negative inside, positive outside, unit gradient). f is a Gaussian process

    f(x) = m(x) + g(x),   g ~ GP(0, k),   k(x, y) = s^2 exp(-|x - y|^2 / (2 l^2))

with a parametric prior mean m (a signed distance to a sphere or a superquadric fitted to
the data). A contact (p, n) gives two observations: f(p) = 0 (value) and grad f(p) = n
(gradient), the second through the derivatives of the kernel (Solak et al., "Derivative
observations in Gaussian process models of dynamic systems", NIPS 2003). Free space gives
bounds f(x) >= c > 0, each entered as a moment-matched Gaussian site (:func:`bound_site`).

The covariance is calibrated by a scale lambda >= 1 (:attr:`GPIS.scale`), the larger of
two estimates of how much the data's errors exceed the model's variance: the leave-one-out
estimate over the contact rows (Rasmussen & Williams, *Gaussian Processes for Machine
Learning*, 2006, sec. 5.4.2), which sees the local fit, and the prequential one (Dawid,
"Present position and potential developments: some personal views", JRSS A 147, 1984):
the mean squared standardised error of each contact predicted before it was added
(:meth:`GPIS.score_prediction`), which sees the fit between touches, where a sparse map
is most wrong.

Observations are kept as scalar rows: a point, a kind (-1 for a value, 0/1/2 for a
component of the gradient) and a noise variance. Adding a block of k rows to n extends
the Cholesky factor of the kernel matrix by a bordered update in O(n^2 k) instead of a
refactorisation in O((n + k)^3). The factor is held in two parts, a contiguous leading
block and the rows added since, in a buffer that grows without copying: a triangular
solve needs its matrix contiguous, and copying the whole factor on every update cost
more than the update's own arithmetic (16 ms of about 30 at 2200 rows). The rows are
merged into the leading block once they pass 64 rows and a quarter of it, so the copy is
paid once per quarter's growth of the map (amortised O(n) per added row).

A set of *tracked* query points (the free-space pool of :class:`ShapeMap`, whose mean is
needed after every update) keeps V = L^-1 K(X, Q), so their mean costs one matrix-vector
product, m(Q) + V^T L^-1 r, instead of a new kernel matrix of M x n exponentials.

V and the explicit inverse L^-1 (whose column norms give diag(K^-1) for the leave-one-out
calibration) are extended lazily: an addition only borders the factor, and the rows added
since V or L^-1 was last read are appended to it in one block when it is read next. Both
extensions are passes over an n x M or n x n matrix, memory-bound at a few rows each, so
one pass per read instead of one per addition is what counts: a map update adds each
touch's rows in turn (3-5 additions) and reads them once or twice.

A contact's four rows (its value and the three gradient components) sit at one point, and
the kernel's exponential depends only on the points: the kernel matrix is one compiled
pass that computes it once per pair of distinct points (:func:`_kernel_matrix`), and the
mean and its gradient at query points sum the rows' weights per point before the
exponentials (:meth:`GPIS._site_weights`, kept until the data change). Against
row-by-row numpy (masks and fancy indexing per block), this made the kernel matrix about
20x faster at 1000 x 600 rows (a one-off timing) and a tactile SLAM update 1.1-1.5x at 101-400 contacts
(docs/benchmarks.md, the A/B section at the top).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from scipy.linalg import blas, lapack, solve_triangular
from scipy.special import log_ndtr

from .._cache import numba_cache_enabled
from ..errors import TouchlocError

__all__ = ["GPIS"]

_CHUNK = 2048


@nb.njit(cache=numba_cache_enabled(__file__), nogil=True)
def _kernel_matrix(X1, k1, X2, k2, l, s2):  # pragma: no cover - compiled
    """The covariance of :meth:`GPIS.kernel` in one pass (see there for the blocks).

    The exponential depends only on the two points, and a contact's value and gradient
    rows share their point: it is computed once per run of equal points in ``X2`` and
    reused across a run of equal points in ``X1``, so a map of contacts pays for a
    sixteenth of the exponentials of a row-by-row kernel.
    """
    n1, n2 = X1.shape[0], X2.shape[0]
    K = np.empty((n1, n2))
    il2 = 1.0 / (l * l)
    fresh = np.empty(n2, np.bool_)
    for j in range(n2):
        fresh[j] = j == 0 or X2[j, 0] != X2[j - 1, 0] or X2[j, 1] != X2[j - 1, 1] or X2[j, 2] != X2[j - 1, 2]
    E = np.empty(n2)
    D = np.empty((n2, 3))
    for i in range(n1):
        if i == 0 or X1[i, 0] != X1[i - 1, 0] or X1[i, 1] != X1[i - 1, 1] or X1[i, 2] != X1[i - 1, 2]:
            e = 0.0
            for j in range(n2):
                d0 = X1[i, 0] - X2[j, 0]
                d1 = X1[i, 1] - X2[j, 1]
                d2 = X1[i, 2] - X2[j, 2]
                D[j, 0] = d0
                D[j, 1] = d1
                D[j, 2] = d2
                if fresh[j]:
                    e = s2 * np.exp(-0.5 * (d0 * d0 + d1 * d1 + d2 * d2) * il2)
                E[j] = e
        a = k1[i]
        for j in range(n2):
            b = k2[j]
            if a < 0:
                K[i, j] = E[j] if b < 0 else E[j] * D[j, b] * il2
            elif b < 0:
                K[i, j] = -E[j] * D[j, a] * il2
            else:
                K[i, j] = E[j] * ((1.0 if a == b else 0.0) - D[j, a] * D[j, b] * il2) * il2
    return K


_LOADED = False


def load_kernels() -> None:
    """Load (or compile, the first time) the compiled kernel matrix, once per process: a
    map pays this at construction (about 0.2 s from numba's cache), not in its first update."""
    global _LOADED
    if not _LOADED:
        X, k = np.zeros((2, 3)), np.array([-1, 0], dtype=np.int64)
        _kernel_matrix(X, k, X, k, 1.0, 1.0)
        _LOADED = True


class GPIS:
    """Gaussian-process implicit surface (internal engine of :class:`ShapeMap`).

    Parameters
    ----------
    lengthscale : float
        l of the squared-exponential kernel (m).
    signal_std : float
        s: prior standard deviation of f about the prior mean (m).
    prior : callable
        ``prior(points (M, 3)) -> (values (M,), gradients (M, 3))``, the prior mean m and
        its gradient. May be replaced later with :meth:`set_prior` (cheap: the kernel
        matrix does not depend on it).
    """

    def __init__(self, lengthscale: float, signal_std: float, prior):
        load_kernels()
        self.l = float(lengthscale)
        self.s2 = float(signal_std) ** 2
        self.prior = prior
        self.X = np.zeros((0, 3))
        self.kind = np.zeros(0, dtype=np.int64)
        self.y = np.zeros(0)
        self.noise = np.zeros(0)
        self._L0 = np.zeros((0, 0))      # contiguous leading block of the Cholesky factor L
        self._Tb = np.zeros((0, 0))      # buffer whose [:n - n0, :n] block holds L's later rows
        self._alpha = None
        self._z = None
        self.scored = np.zeros(0, dtype=bool)   # rows that enter the calibration
        self._Qp = np.zeros((0, 3))      # query points with a column in _Vb, tracked or dropped
        self._live = np.zeros(0, dtype=np.int64)   # the tracked ones, in order
        self._Vb = np.zeros((0, 0))      # buffer whose [:n, :len(_Qp)] block is L^-1 K(X, _Qp)
        self._vv = np.zeros(0)           # its column norms squared (the variance explained)
        self._Lib = np.zeros((0, 0))     # buffer whose [:_nl, :_nl] block is L^-1
        self._dKi_buf = np.zeros(0)      # diag(K^-1) of the leading _nl rows
        self._nv = 0                     # rows of _Vb brought up to date (see _sync_V)
        self._nl = 0                     # rows of _Lib and _dKi_buf brought up to date
        self._scale = None
        self._sites = None               # (X it was made from, first row of each site, site points)
        self._mw = None                  # (alpha they were made from, the mean's weights per site, ...)
        self._preq = [0.0, 0]            # sum of squared standardised one-step-ahead errors, count

    # -- kernel ----------------------------------------------------------------------
    def kernel(self, X1, k1, X2, k2) -> np.ndarray:
        """Covariance between scalar observations (values and gradient components).

        Rows of kind -1 are values f(x), kind b in 0..2 the gradient component df/dx_b:
        cov(f(x), f(y)) = k, cov(f(x), d_b f(y)) = k (x_b - y_b) / l^2,
        cov(d_a f(x), f(y)) = -k (x_a - y_a) / l^2 and
        cov(d_a f(x), d_b f(y)) = k (delta_ab / l^2 - (x_a - y_a)(x_b - y_b) / l^4).
        """
        # one compiled signature: C-ordered, writeable (numba types read-only arrays apart)
        return _kernel_matrix(np.require(X1, float, "CW"), np.require(k1, np.int64, "CW"),
                              np.require(X2, float, "CW"), np.require(k2, np.int64, "CW"), float(self.l), float(self.s2))

    def _cov(self, X, kind, noise) -> np.ndarray:
        """The observations' covariance K(X, X) + diag(noise), the noise added in place (a
        dense diagonal matrix cost two more n^2 passes)."""
        C = self.kernel(X, kind, X, kind)
        C[np.diag_indices(len(C))] += noise
        return C

    # -- data ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.y)

    # -- the factor ----------------------------------------------------------------------
    _TAIL = 64    # rows added since the last merge that the factor keeps apart at least

    @property
    def L(self) -> np.ndarray:
        """(n, n) lower Cholesky factor of the observations' covariance (assembled; a copy)."""
        n, n0 = self.n, len(self._L0)
        L = np.zeros((n, n))
        L[:n0, :n0] = self._L0
        L[n0:, :] = self._Tb[:n - n0, :n]
        return L

    def _blocks(self, dtype=np.float64):
        """(L0, T0, T1): the factor's leading block, and its later rows split at the leading
        block's width, as ``dtype`` arrays (copies in any other type than float64)."""
        n0, n1 = len(self._L0), self.n - len(self._L0)
        T0, T1 = self._Tb[:n1, :n0], self._Tb[:n1, n0:n0 + n1]
        if dtype == np.float64:
            return self._L0, T0, np.ascontiguousarray(T1)
        return self._L0.astype(dtype), T0.astype(dtype), T1.astype(dtype)

    def _solve(self, B, trans: bool = False, blocks=None) -> np.ndarray:
        """L^-1 B, or L^-T B with ``trans``, for (n, k) or (n,) B; with ``blocks`` (from
        :meth:`_blocks`), in their precision."""
        L0, T0, T1 = self._blocks() if blocks is None else blocks
        n0, n1 = len(L0), len(T1)
        B = np.asarray(B, L0.dtype)
        if n1 == 0:
            return solve_triangular(L0, B, lower=True, trans="T" if trans else "N", check_finite=False)
        out = np.empty_like(B)
        if not trans:
            out[:n0] = solve_triangular(L0, B[:n0], lower=True, check_finite=False) if n0 else B[:n0]
            out[n0:] = solve_triangular(T1, B[n0:] - T0 @ out[:n0], lower=True, check_finite=False)
        else:
            out[n0:] = solve_triangular(T1, B[n0:], lower=True, trans="T", check_finite=False)
            if n0:
                out[:n0] = solve_triangular(L0, B[:n0] - T0.T @ out[n0:], lower=True, trans="T",
                                            check_finite=False)
        return out

    def _append_rows(self, W, L2) -> None:
        """Append the bordered factor's new rows [W^T, L2]."""
        n, k, n0 = self.n, len(L2), len(self._L0)
        n1 = n - n0
        if n1 + k > max(self._TAIL, n0 // 4):
            self._L0 = self.L     # merge: the one O(n^2) copy, once per quarter's growth
            n0, n1 = n, 0
        self._Tb = _grown(self._Tb, n1 + k, n + k, n1, n)
        self._Tb[n1:n1 + k, :n] = W.T
        self._Tb[n1:n1 + k, n:n + k] = L2

    def _truncate(self, start: int) -> None:
        """Keep the factor's leading ``start`` rows (the observations must follow)."""
        n0 = len(self._L0)
        if start < n0:
            self._L0 = np.ascontiguousarray(self._L0[:start, :start])

    def _residual(self, X, kind, y):
        m, g = self.prior(X)
        prior = np.where(kind < 0, m, g[np.arange(len(X)), np.maximum(kind, 0)])
        return y - prior

    def _factor_rows(self, a: int, b: int) -> np.ndarray:
        """(b - a, b) rows a..b of the Cholesky factor (assembled; a copy)."""
        n0 = len(self._L0)
        R = np.zeros((b - a, b))
        if a < n0:
            R[:min(n0, b) - a, :min(n0, b)] = self._L0[a:b, :b]
        if b > n0:
            R[max(n0 - a, 0):] = self._Tb[max(a - n0, 0):b - n0, :b]
        return R

    def _sync_V(self, upto: int | None = None, *, by_inverse: bool = False) -> None:
        """Extend the tracked points' columns V = L^-1 K(X, Q) by the rows added since they
        were last needed (up to row ``upto``, default all): one pass over V for all of them
        instead of one per :meth:`add`.

        ``by_inverse`` (with L^-1 brought up to date over those rows) multiplies by the
        inverse's diagonal block instead of solving with the factor's: the same flops, but
        OpenBLAS's triangular product ran 2-2.7x faster than its triangular solve at
        800-1000 rows and 700-1500 points on an Intel Xeon, 1.2x on an AMD EPYC (one-off
        timings, one thread). A relocation re-adds most rows and computes that block anyway.
        """
        a, n, m = self._nv, self.n if upto is None else upto, len(self._Qp)
        if a >= n:
            return
        if m:
            R = self._factor_rows(a, n)
            rhs = self.kernel(self.X[a:n], self.kind[a:n], self._Qp, np.full(m, -1))
            if a:
                rhs -= R[:, :a] @ self._Vb[:a, :m]
            if by_inverse and self._nl >= n:
                # V^T = rhs^T L^-T: the right-side product on the transposes, which are in
                # Fortran order already (neither rhs nor the result is copied between orders)
                Vk = blas.dtrmm(1.0, self._Lib[a:n, a:n].T, rhs.T, side=1, lower=0, overwrite_b=1).T
            else:
                Vk = solve_triangular(R[:, a:], rhs, lower=True, check_finite=False)
            self._reserve(n, m)
            self._Vb[a:n, :m] = Vk
            self._vv = self._vv + np.einsum("ij,ij->j", Vk, Vk)
        self._nv = n

    def _sync_inverse(self, upto: int | None = None) -> None:
        """Extend L^-1 and diag(K^-1) by the rows added since they were last needed (up to
        row ``upto``, default all).

        With R = [T0, T1] the factor's rows a.., L^-1 gains the rows [-T1^-1 T0 L0^-1, T1^-1]
        (the bordered inverse), and diag(K^-1) their column norms squared: one pass over
        L^-1 for every row added since, instead of one per :meth:`add`.
        """
        a, n = self._nl, self.n if upto is None else upto
        if a >= n:
            return
        R = self._factor_rows(a, n)
        T1i = _tri_inv(R[:, a:])
        self._Lib = _grown(self._Lib, n, n, a, a)
        dKi = self._dKi_buf[:a]
        if a:
            left = -_lower_times(T1i, _times_lower(R[:, :a], self._Lib[:a, :a]))
            self._Lib[a:n, :a] = left
            dKi = dKi + np.einsum("ij,ij->j", left, left)
        self._Lib[a:n, a:n] = T1i
        self._dKi_buf = np.concatenate([dKi, np.einsum("ij,ij->j", T1i, T1i)])
        self._nl = n

    @property
    def _dKi(self) -> np.ndarray:
        """diag(K^-1), brought up to date."""
        self._sync_inverse()
        return self._dKi_buf

    def add(self, X, kind, y, noise, *, scored: bool = True) -> None:
        """Append scalar observations and extend the Cholesky factor (bordered update).

        ``scored=False`` keeps the rows out of the variance calibration (pseudo-observations
        such as free-space bounds); a (k,) boolean array sets it per row.
        """
        X = np.asarray(X, float).reshape(-1, 3)
        kind = np.asarray(kind, dtype=np.int64).reshape(-1)
        y = np.asarray(y, float).reshape(-1)
        noise = np.asarray(noise, float).reshape(-1)
        if len(y) == 0:
            return
        C = self._cov(X, kind, noise)
        if self.n == 0:
            L2 = _chol(C)
            W = np.zeros((0, len(y)))
        else:
            W = self._solve(self.kernel(self.X, self.kind, X, kind))
            L2 = _chol(C - W.T @ W)
        self._append_rows(W, L2)
        k = len(y)
        self.scored = np.concatenate([self.scored, np.broadcast_to(np.asarray(scored, bool), (k,))])
        self.X = np.concatenate([self.X, X])
        self.kind = np.concatenate([self.kind, kind])
        self.y = np.concatenate([self.y, y])
        self.noise = np.concatenate([self.noise, noise])
        self._alpha = self._z = self._scale = None

    def refactor(self) -> None:
        """Rebuild the Cholesky factor from scratch (the reference for the incremental one)."""
        self._compact()
        if self.n:
            self._L0 = _chol(self._cov(self.X, self.kind, self.noise))
            self._Lib = _tri_inv(self._L0)
            self._dKi_buf = np.einsum("ij,ij->j", self._Lib, self._Lib)
        self._Vb = self._columns(self._Qp)
        self._vv = np.einsum("ij,ij->j", self._Vb, self._Vb)
        self._nv = self._nl = self.n
        self._alpha = self._z = self._scale = None

    def relocate(self, X, y, Q, start: int = 0) -> None:
        """Replace the observations' points ``X`` (n, 3) and values ``y`` (n,), and the tracked
        points ``Q``, keeping kinds and noise; refactor from row ``start`` on.

        Rows before ``start`` must be unchanged: the leading block of the Cholesky factor
        and of its inverse are kept, and the rest is added back by bordered updates, so
        moving the last rows costs O(n^2 k) rather than a refactorisation. Tracked points
        that moved get new columns; the others keep theirs over the leading rows.
        """
        start = int(np.clip(start, 0, self.n))
        self._compact(start)         # (the columns' rows from start on are recomputed below)
        X = np.asarray(X, float).reshape(self.n, 3)
        y = np.asarray(y, float).reshape(self.n)
        Q = np.asarray(Q, float).reshape(len(self._Qp), 3)
        kind, noise, scored = self.kind, self.noise, self.scored
        moved_q = np.any(Q != self._Qp, axis=1)
        self._sync_V(start)          # the kept rows of V and of L^-1 must be up to date
        self._sync_inverse(start)
        # truncate to the leading rows: every kept factor has them as its leading block
        self._truncate(start)
        self.X, self.kind, self.y, self.noise = X[:start], kind[:start], y[:start], noise[:start]
        self.scored = scored[:start]
        Li = self._Lib[:start, :start]
        self._dKi_buf = np.einsum("ij,ij->j", Li, Li)
        self._nv = self._nl = start
        self._Qp = Q
        if np.any(moved_q):
            self._Vb[:start, np.flatnonzero(moved_q)] = self._columns(Q[moved_q])
        V = self._Vb[:start, :len(Q)]
        self._vv = np.einsum("ij,ij->j", V, V)
        self._alpha = self._z = self._scale = None
        if start < len(y):
            self.add(X[start:], kind[start:], y[start:], noise[start:], scored=scored[start:])
            # bring L^-1 and V up to date now: the relocation's cost stays in its own call
            self._sync_inverse()
            self._sync_V(by_inverse=True)

    def set_prior(self, prior) -> None:
        self.prior = prior
        self._alpha = self._z = self._scale = None

    @property
    def scale(self) -> float:
        """lambda >= 1: the variance scale (see the module notes)."""
        if self._scale is None:
            sel = self.scored
            loo = 1.0
            if np.count_nonzero(sel) >= 2:
                a = self.alpha[sel]
                loo = float(np.mean(a * a / self._dKi[sel]))
            total, count = self._preq
            self._scale = max(1.0, loo, total / count if count else 1.0)
        return self._scale

    def score_prediction(self, X, y, noise, *, pred=None) -> None:
        """Record how well the current map predicts value observations about to be added.

        Parameters
        ----------
        X : (k, 3) float
        y : (k,) float
            The values that will be observed there (0 for contacts).
        noise : (k,) float
            Their noise variances.
        pred : ((k,) float, (k,) float), optional
            ``mean_std(X, calibrated=False)``, if the caller has it already.
        """
        if self.n == 0 or len(X) == 0:
            return
        mu, sd = self.mean_std(X, calibrated=False) if pred is None else pred
        z2 = (np.asarray(y, float) - mu) ** 2 / (sd * sd + np.asarray(noise, float))
        self._preq[0] += float(np.sum(z2))
        self._preq[1] += len(z2)
        self._scale = None

    # -- tracked query points ------------------------------------------------------------
    def _columns(self, Q) -> np.ndarray:
        if self.n == 0 or len(Q) == 0:
            return np.zeros((self.n, len(Q)))
        return self._solve(self._kx(Q))

    @property
    def Q(self) -> np.ndarray:
        """(M, 3) the tracked query points."""
        return self._Qp[self._live]

    @property
    def _V(self) -> np.ndarray:
        """(n, M) L^-1 K(X, Q) for the tracked points (a copy)."""
        self._sync_V()
        return self._Vb[:self.n, self._live]

    def _reserve(self, rows, cols) -> None:
        self._Vb = _grown(self._Vb, rows, cols, self.n, len(self._Qp))

    def _compact(self, rows: int | None = None) -> None:
        """Drop the columns of points no longer tracked, moving only their leading ``rows``
        (default all; a relocation recomputes the rest)."""
        if len(self._live) < len(self._Qp):
            idx = self._live
            r = min(self._nv, self.n if rows is None else rows)
            self._Vb[:r, :len(idx)] = self._Vb[:r, idx]
            self._Qp = self._Qp[idx]
            self._vv = self._vv[idx]
            self._live = np.arange(len(idx))

    def track(self, Q) -> None:
        """Add query points whose posterior mean :meth:`tracked_mean` keeps up to date."""
        Q = np.asarray(Q, float).reshape(-1, 3)
        if len(Q):
            self._sync_V()
            m = len(self._Qp)
            self._reserve(self.n, m + len(Q))
            V = self._columns(Q)
            self._Vb[:self.n, m:m + len(Q)] = V
            self._vv = np.concatenate([self._vv, np.einsum("ij,ij->j", V, V)])
            self._Qp = np.concatenate([self._Qp, Q])
            self._live = np.concatenate([self._live, np.arange(m, m + len(Q))])

    def untrack(self, keep) -> None:
        """Keep only the tracked points where the boolean mask ``keep`` is True.

        The dropped points' columns stay until they are half of all (moving the rest is a
        gather of the whole n x M block, 14 ms at 2200 rows and 2500 points): until then
        the tracked means and deviations are computed for them too and left out.
        """
        keep = np.asarray(keep, bool).reshape(len(self._live))
        self._live = self._live[keep]
        if len(self._Qp) > 2 * len(self._live) + 256:
            self._compact()

    def tracked_mean(self) -> np.ndarray:
        """(len(Q),) posterior mean at the tracked points: equal to ``mean(Q)``."""
        Q = self.Q
        m, _ = self.prior(Q)
        if self.n == 0 or len(Q) == 0:
            return m
        self._sync_V()
        return m + (self._Vb[:self.n, :len(self._Qp)].T @ self.z)[self._live]

    @property
    def z(self) -> np.ndarray:
        """L^-1 (y - m(X)): the whitened residuals; the mean at q is m(q) + (L^-1 k(X, q)) . z."""
        if self._z is None:
            self._z = self._solve(self._residual(self.X, self.kind, self.y))
        return self._z

    def tracked_std(self, *, calibrated: bool = True) -> np.ndarray:
        """(len(Q),) posterior standard deviation at the tracked points: equal to
        ``mean_std(Q, calibrated=calibrated)[1]``."""
        var = np.full(len(self._live), self.s2)
        if self.n and len(self._live):
            self._sync_V()
            var = self.s2 - self._vv[self._live]
        lam = self.scale if calibrated else 1.0
        return np.sqrt(np.minimum(lam * np.maximum(var, 1e-18), self.s2))

    @property
    def alpha(self) -> np.ndarray:
        if self._alpha is None:
            # K^-1 r = L^-T z: one back-substitution from the whitened residuals (often cached)
            self._alpha = self._solve(self.z, trans=True) if self.n else np.zeros(0)
        return self._alpha

    # -- prediction --------------------------------------------------------------------
    def _kx(self, q):
        """Covariance between every observation and f at query points q (M, 3): (n, M)."""
        return self.kernel(self.X, self.kind, q, np.full(len(q), -1))

    def _mean_weights(self):
        """(n,) w0 and (n, 3) wb with mean(q) = m(q) + s^2 sum_j k_j(q) (w0_j + q . wb_j)."""
        a, X, kind, l2 = self.alpha, self.X, self.kind, self.l * self.l
        wb = np.stack([np.where(kind == b, a, 0.0) / l2 for b in range(3)], axis=1)
        return np.where(kind < 0, a, 0.0) - np.einsum("jb,jb->j", wb, X), wb

    def _site_rows(self):
        """(first row of each site, the sites' points): a *site* is a run of consecutive rows
        at one point (a contact's value row and its three gradient rows share one), so that
        the kernel's exponential is computed once per site rather than once per row."""
        if self._sites is None or self._sites[0] is not self.X:
            X = self.X
            new = np.ones(len(X), bool)
            if len(X) > 1:
                new[1:] = np.any(X[1:] != X[:-1], axis=1)
            first = np.flatnonzero(new)
            self._sites = (X, first, X[first])
        return self._sites[1], self._sites[2]

    def _site_weights(self):
        """The weights of :meth:`mean_grad` per site: (sites, 16) the rows' columns
        [w0, wb, x w0, x wb^T] summed over each site's rows (each is linear in rows that
        share their point; :meth:`mean` uses the first 4), the sites' points over l, and
        their squared norms. Kept until the weights change."""
        if self._mw is None or self._mw[0] is not self.alpha:
            X = self.X
            w0, wb = self._mean_weights()
            W = np.concatenate([w0[:, None], wb, X * w0[:, None], (X[:, :, None] * wb[:, None, :]).reshape(-1, 9)], 1)
            first, P = self._site_rows()
            if len(first) < len(W):
                W = np.add.reduceat(W, first, axis=0)
            Xd = P / self.l
            self._mw = (self.alpha, W, Xd, np.sum(Xd * Xd, 1))
        return self._mw[1:]

    def _se(self, q, Xd, xx, dtype):
        """exp(-|q - x_j|^2 / 2 l^2) for a chunk of queries against every observation point
        (``Xd`` = X / l and its squared norms ``xx``), built in place."""
        qd = (q / self.l).astype(dtype)
        K = qd @ Xd.T
        K *= -2.0
        K += xx[None, :]
        K += np.sum(qd * qd, 1)[:, None]
        np.maximum(K, 0.0, out=K)
        K *= -0.5
        np.exp(K, out=K)
        return K

    def mean(self, Q, *, dtype=np.float64) -> np.ndarray:
        """(M,) posterior mean of f at query points.

        ``dtype=np.float32`` halves the time (for grids fed to marching cubes, where
        errors of 1e-6 relative do not matter).
        """
        Q = np.asarray(Q, float).reshape(-1, 3)
        m, _ = self.prior(Q)
        if self.n == 0 or len(Q) == 0:
            return m
        # sum_j K_ij c_ij a_j with c = 1 (values) or (q_ib - x_jb) / l^2 (gradient component b):
        # one kernel matrix, then matrix-vector products only
        W, Xd, xx = self._site_weights()
        W, Xd, xx = W[:, :4].astype(dtype), Xd.astype(dtype), xx.astype(dtype)
        out = np.empty(len(Q))
        for i in range(0, len(Q), _CHUNK):
            q = Q[i:i + _CHUNK]
            KW = (self._se(q, Xd, xx, dtype) @ W).astype(float)
            out[i:i + len(q)] = self.s2 * (KW[:, 0] + np.einsum("ij,ij->i", q, KW[:, 1:]))
        return m + out

    def mean_grad(self, Q):
        """(M,) posterior mean of f and (M, 3) its gradient at query points, in one pass.

        The mean is m(q) + s^2 sum_j k_j(q) (w0_j + q . wb_j) with k_j = exp(-|q - x_j|^2 / 2 l^2)
        (see :meth:`mean`); its gradient, dk_j/dq = -k_j (q - x_j) / l^2, needs the same
        kernel matrix times 16 columns instead of 4, so the gradient costs about what the
        mean does (three central differences would cost six more means).
        """
        Q = np.asarray(Q, float).reshape(-1, 3)
        m, gm = self.prior(Q)
        if self.n == 0 or len(Q) == 0:
            return m, gm
        l2 = self.l * self.l
        W, Xd, xx = self._site_weights()
        mu = np.empty(len(Q))
        grad = np.empty((len(Q), 3))
        for i in range(0, len(Q), _CHUNK):
            q = Q[i:i + _CHUNK]
            A = self._se(q, Xd, xx, np.float64) @ W
            Ab = A[:, 1:4]
            s1 = A[:, 0] + np.einsum("ib,ib->i", q, Ab)                   # sum_j k_j (w0_j + q . wb_j)
            C = A[:, 7:].reshape(-1, 3, 3)                                # sum_j k_j x_j wb_j^T
            mu[i:i + len(q)] = self.s2 * s1
            grad[i:i + len(q)] = self.s2 * (-(q * s1[:, None]) + A[:, 4:7] + np.einsum("iab,ib->ia", C, q)) / l2 \
                + self.s2 * Ab
        return m + mu, gm + grad

    def mean_std(self, Q, *, calibrated: bool = True, dtype=np.float64):
        """(M,) posterior mean and standard deviation of f at query points.

        ``calibrated=False`` leaves out the leave-one-out variance scale (the variance
        under the sensor's own noise model). ``dtype=np.float32`` solves with the factor in
        single precision, 2-3 times faster: the deviation is then off by about 1e-7 m at a
        signal deviation of 1 cm, which ranking a planner's candidates does not notice.
        """
        Q = np.asarray(Q, float).reshape(-1, 3)
        m, _ = self.prior(Q)
        if self.n == 0 or len(Q) == 0:
            return m, np.full(len(Q), np.sqrt(self.s2))
        lam = self.scale if calibrated else 1.0
        mu = np.empty(len(Q))
        var = np.empty(len(Q))
        blocks = self._blocks(dtype)
        z = self.z.astype(dtype)      # the variance needs V = L^-1 k(X, q) anyway: the mean is V^T z
        for i in range(0, len(Q), _CHUNK):
            q = Q[i:i + _CHUNK]
            V = self._solve(self._kx(q), blocks=blocks)
            mu[i:i + len(q)] = V.T @ z
            var[i:i + len(q)] = self.s2 - np.einsum("ij,ij->j", V, V).astype(float)
        return m + mu, np.sqrt(np.minimum(lam * np.maximum(var, 1e-18), self.s2))


def bound_site(mu, sd, c, *, floor: float = 0.0):
    """Gaussian stand-in for the bound f(x) >= c, given the map's belief N(mu, sd^2) at x.

    Moment matching (assumed-density filtering, one expectation-propagation step): the
    site N(value, var) is the Gaussian that, multiplied by N(mu, sd^2), has the mean and
    variance of N(mu, sd^2) truncated to f >= c. A bound the map already keeps gives a
    weak site (large var); one it breaks badly gives value ~ c with small var.

    Parameters
    ----------
    mu, sd : (M,) float
        The map's mean and standard deviation at the points, before the bound.
    c : float or (M,) float
    floor : float
        Smallest site variance (keeps the kernel matrix well conditioned).

    Returns
    -------
    value, var : (M,) float
    """
    mu, sd = np.asarray(mu, float), np.asarray(sd, float)
    v = sd * sd
    z = (mu - c) / sd
    r = np.exp(-0.5 * z * z - 0.5 * np.log(2 * np.pi) - log_ndtr(z))   # phi(z) / Phi(z)
    m_hat = mu + sd * r
    shrink = np.clip(1.0 - r * (z + r), 1e-9, 1.0 - 1e-9)                # v_hat / v
    v_hat = v * shrink
    tau = 1.0 / v_hat - 1.0 / v                                          # site precision
    value = (m_hat / v_hat - mu / v) / tau
    return value, np.maximum(1.0 / tau, floor)


def _grown(buf, rows, cols, used_rows, used_cols):
    """``buf`` with room for (rows, cols), grown geometrically so that appending blocks
    costs no copy of the used [:used_rows, :used_cols] part most of the time."""
    r0, c0 = buf.shape
    if rows <= r0 and cols <= c0:
        return buf
    out = np.zeros((max(rows, r0 + r0 // 2 if rows > r0 else r0), max(cols, c0 + c0 // 2 if cols > c0 else c0)))
    out[:min(r0, used_rows), :min(c0, used_cols)] = buf[:used_rows, :used_cols]
    return out


#: From this many rows of the product on, :func:`_times_lower` and :func:`_lower_times`
#: use BLAS's triangular product.
_TRMM_ROWS = 128


def _times_lower(B, A) -> np.ndarray:
    """B A for a (k, a) B and a lower-triangular (a, a) A (zeros above its diagonal).

    A relocation re-adds hundreds of rows, and their share of L^-1 is this product with
    L^-1's leading block: there ``trmm``, which skips the zero triangle, ran 1.7x faster
    than the general product (550 x 1900 by 1900, one thread). With a dozen rows, as in
    an ordinary update, copying A into Fortran order costs what the triangle saves, so the
    general product stays.
    """
    if len(B) < _TRMM_ROWS:
        return B @ A
    # (B A)^T = A^T B^T: A's transpose is upper, and a C-ordered B's is in Fortran order
    Bc = np.ascontiguousarray(B)
    return blas.dtrmm(1.0, A.T, Bc.T, side=0, lower=0, overwrite_b=int(Bc is not B)).T


def _lower_times(A, B) -> np.ndarray:
    """A B for a lower-triangular (k, k) A (zeros above its diagonal) and a (k, a) B; see
    :func:`_times_lower`."""
    if len(B) < _TRMM_ROWS:
        return A @ B
    # (A B)^T = B^T A^T, A^T upper
    Bc = np.ascontiguousarray(B)
    return blas.dtrmm(1.0, A.T, Bc.T, side=1, lower=0, overwrite_b=int(Bc is not B)).T


def _tri_inv(T) -> np.ndarray:
    """The inverse of a lower-triangular matrix with a positive diagonal (a Cholesky factor).

    LAPACK's ``trtri`` inverts in n^3 / 3 flops; a triangular solve against the identity
    does n^3 (it cannot know that its right-hand side is triangular) and ran 2.5-4x slower
    at 400-800 rows (a one-off timing). The upper triangle of ``T`` must be zero: ``trtri``
    leaves it as it is.
    """
    Ti, info = lapack.dtrtri(np.asarray(T, float), lower=1)
    if info != 0:
        raise TouchlocError(f"the map's covariance factor is singular (trtri info {info})")
    return Ti


def _chol(A):
    """Lower Cholesky factor (C-ordered), with a little jitter if rounding made A indefinite.

    LAPACK's ``potrf`` through scipy, given A's transpose: a C-ordered matrix's transpose is
    in Fortran order already, and its upper triangle is A's lower one, so the factor is read
    from A's lower triangle (as numpy's) and comes back as the transpose of the upper
    factor. The jitter's identity is built only when it is needed. On a mapped mug's kernel
    matrix of 1248 rows (one thread, a one-off timing): 19 ms, against 38 ms for
    ``np.linalg.cholesky(A + 0 * I)`` as before and 22 ms for numpy's routine alone.
    """
    A = np.asarray(A, float)
    n = len(A)
    if n == 0:
        return np.zeros((0, 0))
    jitter = 0.0
    scale = float(np.mean(np.diag(A)))
    for _ in range(6):
        M = A if jitter == 0.0 else A + jitter * np.eye(n)
        U, info = lapack.dpotrf(M.T, lower=0, clean=1)
        if info == 0:
            return U.T
        jitter = max(jitter * 10, 1e-10 * scale)
    raise TouchlocError("the shape map's kernel matrix is not positive definite (duplicate observations?)")
