"""View-based classification of whole tactile sequences (seed 002).

The pipeline of seed 002 (Fig. 5):

1. align a sequence by its centre of gravity, computed over all frames together, and
   flatten it to one vector x of d = 160 * 16 * 16 = 40960 values;
2. vector quantisation of x with activity equalisation (AEV): ``n_vq`` reference vectors,
   each training sample belongs to the cell of its nearest reference;
3. local PCA: ``n_pc`` principal components per cell, by Sanger's rule (as in the seed) or
   by a direct SVD (the default: the same subspace without iterations);
4. a Local Linear Map per cell (``n_llm`` nodes, each with a linear map) from the
   projection p in R^n_pc to a score per class; the winner class is the arg max.

Beyond the seed, the relative reconstruction error of x against its cell's local PCA
measures how unlike the training data a sequence is; with ``reject_quantile`` set, a threshold is
calibrated on held-out folds of the training set and ``predict(X, reject=True)`` marks
sequences above it as unknown.
"""

from __future__ import annotations

import numpy as np

from .._util import as_rng
from .._validate import (as_bool, as_count, as_float, as_float_array, as_nonnegative_float, as_positive_float,
                         as_probability)
from ..errors import TouchlocError, ValidationError

__all__ = [
    "SequenceClassifier", "NearestNeighbourClassifier", "NotFittedError", "align_sequences",
    "aev_quantize", "sanger_pca", "svd_pca", "LocalLinearMap",
]


class NotFittedError(TouchlocError, AttributeError):
    """A classifier was used before :meth:`fit`."""


# -- input handling ----------------------------------------------------------------------
def _as_sequences(X, name="X") -> np.ndarray:
    """Validate (n, T, H, W) finite non-negative-size input; returns float64."""
    try:
        A = np.asarray(X, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be a numeric (n_scans, n_frames, rows, cols) array: {exc}") from None
    if A.ndim == 3:
        raise ValidationError(f"{name} must be (n_scans, n_frames, rows, cols), got {A.shape}; "
                              "for one scan pass X[None]")
    if A.ndim != 4:
        raise ValidationError(f"{name} must be (n_scans, n_frames, rows, cols), e.g. (n, 160, 16, 16), got {A.shape}")
    if A.shape[0] == 0 or min(A.shape[1:]) == 0:
        raise ValidationError(f"{name} must hold at least one non-empty scan, got {A.shape}")
    if not np.all(np.isfinite(A)):
        bad = int(np.flatnonzero(~np.isfinite(A.reshape(len(A), -1)).all(axis=1))[0])
        raise ValidationError(f"{name} must be finite; scan {bad} holds NaN or inf")
    return A


def align_sequences(X) -> np.ndarray:
    """Shift every sequence so its centre of gravity lies in the middle of the pad.

    As in seed 002, the 2-D centre of gravity is computed over the complete sequence
    (all frames together), and all frames of that sequence are shifted by the same whole
    number of texels; texels shifted in from outside are zero. A blank sequence is left
    as it is.

    Parameters
    ----------
    X : (n, T, H, W) array

    Returns
    -------
    (n, T, H, W) float
    """
    A = _as_sequences(X)
    n, T, H, W = A.shape
    total = np.clip(A, 0.0, None).sum(axis=1)  # (n, H, W)
    mass = total.sum(axis=(1, 2))
    safe = np.where(mass > 0, mass, 1.0)
    cog_r = (total.sum(axis=2) @ np.arange(H)) / safe
    cog_c = (total.sum(axis=1) @ np.arange(W)) / safe
    dr = np.where(mass > 0, np.rint(0.5 * (H - 1) - cog_r), 0).astype(int)
    dc = np.where(mass > 0, np.rint(0.5 * (W - 1) - cog_c), 0).astype(int)
    src_r = np.arange(H)[None, :] - dr[:, None]  # (n, H): source row of each target row
    src_c = np.arange(W)[None, :] - dc[:, None]
    ok_r = (src_r >= 0) & (src_r < H)
    ok_c = (src_c >= 0) & (src_c < W)
    out = A[np.arange(n)[:, None, None, None], np.arange(T)[None, :, None, None],
            np.clip(src_r, 0, H - 1)[:, None, :, None], np.clip(src_c, 0, W - 1)[:, None, None, :]]
    out *= (ok_r[:, None, :, None] & ok_c[:, None, None, :])
    return out


# -- stage 1: vector quantisation with activity equalisation -----------------------------
def aev_quantize(Z, n_ref: int, *, epochs: int = 30, eta=(0.5, 0.01), equalize: float = 0.5, rng=None):
    """Winner-take-all vector quantisation with activity equalisation.

    In the manner of the AEV algorithm cited by seed 002 (Heidemann and Ritter, 2001):
    online winner-take-all learning, with the activity (win count) of every reference
    vector supervised over each epoch; after an epoch, the least active reference is
    moved into the cell of the most active one when its activity is below ``equalize``
    times the mean, so no reference stays an unused outlier. The seed gives no further
    details; these rules are ours.

    Parameters
    ----------
    Z : (n, d) float
    n_ref : int
        Number of reference vectors (capped at n).
    epochs : int
    eta : (float, float)
        Learning rate at the first and the last epoch (geometric decay).
    equalize : float
        Relocate a reference whose activity is below this fraction of the mean.
    rng : None, int or numpy.random.Generator

    Returns
    -------
    refs : (n_ref, d) float
    labels : (n,) int
        Index of the nearest reference of each row of Z.
    """
    Z = _as_rows(Z, "Z")
    n_ref = as_count(n_ref, "n_ref", max=100_000, why="each reference is compared with every sample")
    epochs = as_count(epochs, "epochs", max=100_000, why="each epoch is a pass over the samples")
    eta = _as_rates(eta)
    equalize = as_nonnegative_float(equalize, "equalize")
    rng = as_rng(rng)
    n, d = Z.shape
    k = max(1, min(int(n_ref), n))
    if k == 1:
        return Z.mean(axis=0, keepdims=True), np.zeros(n, dtype=int)
    # Every reference is always an affine combination of samples (they start as samples
    # and move towards samples), so the rule runs exactly on coefficients C with
    # refs = C @ Z, using the Gram matrix: O(k n) instead of O(k d) per step.
    G = Z @ Z.T
    C = np.zeros((k, n))
    C[np.arange(k), rng.choice(n, size=k, replace=False)] = 1.0
    CG = C @ G
    epochs = max(1, int(epochs))
    rates = eta[0] * (eta[1] / eta[0]) ** (np.arange(epochs) / max(epochs - 1, 1))
    for e, rate in enumerate(rates):
        counts = np.zeros(k, dtype=int)
        members = [[] for _ in range(k)]
        rn = np.einsum("ij,ij->i", C, CG)
        for i in rng.permutation(n):
            w = int(np.argmin(rn - 2.0 * CG[:, i]))
            C[w] *= 1.0 - rate
            C[w, i] += rate
            CG[w] = (1.0 - rate) * CG[w] + rate * G[i]
            rn[w] = C[w] @ CG[w]
            counts[w] += 1
            members[w].append(i)
        if e < epochs - 1:
            lo, hi = int(np.argmin(counts)), int(np.argmax(counts))
            if counts[lo] < equalize * n / k and counts[hi] > 1:
                j = members[hi][int(rng.integers(len(members[hi])))]
                C[lo] = 0.5 * C[hi]
                C[lo, j] += 0.5
                CG[lo] = C[lo] @ G
    refs = C @ Z
    return refs, _nearest(Z, refs)


def _as_rows(Z, name, *, allow_empty=False) -> np.ndarray:
    """(n, d) finite float samples."""
    Z = as_float_array(Z, name, shape=(None, None), expected="an (n, d) array of finite samples")
    if not allow_empty and Z.shape[0] == 0:
        raise ValidationError(f"{name} must hold at least one sample, got shape {Z.shape}")
    return Z


def _as_rates(eta) -> tuple:
    """A (first, last) pair of positive learning rates."""
    a, b = as_float_array(eta, "eta", shape=(2,), expected="(first, last) learning rates > 0")
    if not (a > 0 and b > 0):
        raise ValidationError(f"eta must be (first, last) learning rates > 0, got {(float(a), float(b))}")
    return float(a), float(b)


def _nearest(Z, refs, return_dist=False):
    d = (np.einsum("ij,ij->i", Z, Z)[:, None] - 2.0 * Z @ refs.T + np.einsum("ij,ij->i", refs, refs)[None, :])
    lab = np.argmin(d, axis=1)
    if return_dist:
        return lab, np.maximum(d[np.arange(len(Z)), lab], 0.0)
    return lab


# -- stage 2: local PCA ------------------------------------------------------------------
def svd_pca(Zc, n_pc: int) -> np.ndarray:
    """(n_pc, d) float: leading principal directions of centred rows Zc (zero rows pad).

    Computed from the thin SVD of the (n, d) data; directions beyond the rank of the data
    are zero, so a cell with fewer samples than ``n_pc`` projects to zeros there.
    """
    Zc = _as_rows(Zc, "Zc", allow_empty=True)
    n_pc = as_count(n_pc, "n_pc", min=0, max=100_000, why="an (n_pc, d) matrix")
    W = np.zeros((int(n_pc), Zc.shape[1]))
    if len(Zc) == 0:
        return W
    _, s, Vt = np.linalg.svd(Zc, full_matrices=False)
    r = min(int(n_pc), int(np.sum(s > 1e-10 * max(s[0], 1e-300))))
    W[:r] = Vt[:r]
    return W


def _svd_pca_batched(cells, n_pc, d):
    """Local PCA of every cell at once, from the batched Gram matrices of its samples.

    For a cell's centred samples Zc (m, d) with m << d, the right singular vectors are
    ``V = diag(1/s) U^T Zc`` where ``Zc Zc^T = U diag(s^2) U^T``: one batched (m, m)
    eigendecomposition of zero-padded cells replaces d-dimensional work.
    """
    m = max(max(len(c) for c in cells), 1)
    stack = np.zeros((len(cells), m, d))
    for i, c in enumerate(cells):
        stack[i, : len(c)] = c
    G = np.matmul(stack, stack.transpose(0, 2, 1))
    ev, U = np.linalg.eigh(G)  # ascending
    ev, U = ev[:, ::-1], U[:, :, ::-1]
    W = np.zeros((len(cells), int(n_pc), d))
    for i in range(len(cells)):
        top = max(float(ev[i, 0]), 1e-300)
        r = min(int(n_pc), int(np.sum(ev[i] > 1e-12 * top)))
        if r:
            V = (U[i, :, :r].T @ stack[i]) / np.sqrt(ev[i, :r])[:, None]
            W[i, :r] = V / np.linalg.norm(V, axis=1, keepdims=True)
    return W


def sanger_pca(Zc, n_pc: int, *, epochs: int = 300, eta=(0.2, 0.005), rng=None, space: str = "auto",
               W0=None) -> np.ndarray:
    """Leading principal directions by Sanger's rule (the generalised Hebbian algorithm).

    Online updates, one sample at a time in random order, as in seed 002:
    ``W += eta_t * (y x^T - LT(y y^T) W)`` with ``y = W x`` and LT the lower triangle.
    The step ``eta_t`` is the given rate divided by the mean squared norm of the data
    (an upper bound of the largest eigenvalue), decaying geometrically over the epochs,
    and never more than ``0.5 / |x|^2`` for the sample at hand (the rule diverges when
    ``eta |x|^2`` approaches 2).

    When there are fewer samples than dimensions (``space="auto"`` picks this), the rule
    is run on coefficients C with W = C Zc: every update of the rule is a combination of
    samples and rows of W, so W stays in the span of the samples when it starts there,
    and the iterates are exactly those of the rule in R^d at O(n_pc * n) instead of
    O(n_pc * d) per update.

    Parameters
    ----------
    Zc : (n, d) float
        Centred samples.
    n_pc : int
    epochs : int
    eta : (float, float)
        Relative learning rate at the first and the last epoch.
    rng : None, int or numpy.random.Generator
    space : {"auto", "input", "samples"}
    W0 : (n_pc, d) float, optional
        Initial weights (``space="input"`` only); random small weights by default.

    Returns
    -------
    W : (n_pc, d) float
        Rows approximate the leading eigenvectors of the sample covariance (in order of
        decreasing eigenvalue, up to sign), with unit length at convergence.
    """
    Zc = _as_rows(Zc, "Zc", allow_empty=True)
    n_pc = as_count(n_pc, "n_pc", min=0, max=100_000, why="an (n_pc, d) matrix")
    epochs = as_count(epochs, "epochs", max=100_000, why="each epoch is a pass over the samples")
    eta = _as_rates(eta)
    if not isinstance(space, str):
        raise ValidationError(f"space must be 'auto', 'input' or 'samples', got {space!r}")
    if W0 is not None:
        W0 = as_float_array(W0, "W0", shape=(int(n_pc), Zc.shape[1]))
    rng = as_rng(rng)
    n, d = Zc.shape
    k = int(n_pc)
    if n == 0 or k == 0:
        return np.zeros((k, d))
    if space == "auto":
        space = "samples" if n < d and W0 is None else "input"
    if space not in ("input", "samples"):
        raise ValidationError(f"space must be 'auto', 'input' or 'samples', got {space!r}")
    scale = float(np.mean(np.einsum("ij,ij->i", Zc, Zc)))
    if scale <= 0:
        return np.zeros((k, d))
    epochs = max(1, int(epochs))
    rates = (eta[0] * (eta[1] / eta[0]) ** (np.arange(epochs) / max(epochs - 1, 1))) / scale
    tril = np.tril(np.ones((k, k)))
    sq = np.einsum("ij,ij->i", Zc, Zc)
    cap = 0.5 / np.where(sq > 0, sq, np.inf)
    if space == "input":
        W = rng.standard_normal((k, d)) / np.sqrt(d) * 0.1 if W0 is None else np.array(W0, dtype=np.float64)
        for rate in rates:
            for i in rng.permutation(n):
                x = Zc[i]
                y = W @ x
                W += min(rate, cap[i]) * (np.outer(y, x) - (tril * np.outer(y, y)) @ W)
        return W
    # coefficient space: W = C @ Zc, y = C @ G[:, i]
    G = Zc @ Zc.T
    C = rng.standard_normal((k, n)) / np.sqrt(n * scale) * 0.1
    for rate in rates:
        for i in rng.permutation(n):
            r = min(rate, cap[i])
            y = C @ G[:, i]
            C -= r * (tril * np.outer(y, y)) @ C
            C[:, i] += r * y
    return C @ Zc


# -- stage 3: local linear map -----------------------------------------------------------
class LocalLinearMap:
    """A Local Linear Map (Ritter): nodes w_r, each with an output y_r and a matrix A_r.

    The output for p is ``y_r + A_r (p - w_r)`` of the node r nearest p. Nodes are placed
    by :func:`aev_quantize`; each node's (y_r, A_r) is the ridge least-squares fit to the
    targets of the samples in its cell (the batch solution of the LLM's online rule).

    Parameters
    ----------
    n_nodes : int
        Capped at the number of training samples.
    ridge : float
        Penalty on A_r, relative to the mean variance of the inputs.
    """

    def __init__(self, n_nodes: int = 20, *, ridge: float = 1.0, epochs: int = 30, rng=None):
        n_nodes = as_count(n_nodes, "n_nodes", max=100_000, why="one linear map per node")
        ridge = as_nonnegative_float(ridge, "ridge")
        epochs = as_count(epochs, "epochs", max=100_000, why="each epoch is a pass over the samples")
        self.n_nodes = int(n_nodes)
        self.ridge = float(ridge)
        self.epochs = int(epochs)
        self.rng = rng

    def fit(self, P, T):
        """Fit to inputs P (n, k) and targets T (n, m)."""
        P = as_float_array(P, "P", shape=(None, None))
        T = as_float_array(T, "T", shape=(None, None))
        if len(P) == 0 or P.shape[1] == 0:
            raise ValidationError(f"P must hold at least one sample of at least one feature, got shape {P.shape}")
        if len(T) != len(P):
            raise ValidationError(f"T must have one row per sample of P ({len(P)}), got shape {T.shape}")
        rng = as_rng(self.rng)
        self.nodes_, lab = aev_quantize(P, self.n_nodes, epochs=self.epochs, rng=rng)
        k = P.shape[1]
        lam = self.ridge * max(float(np.mean(np.var(P, axis=0))), 1e-12)
        self.outputs_ = np.zeros((len(self.nodes_), T.shape[1]))
        self.maps_ = np.zeros((len(self.nodes_), T.shape[1], k))
        for r in range(len(self.nodes_)):
            sel = lab == r
            if not np.any(sel):
                self.outputs_[r] = T.mean(axis=0)
                continue
            D = np.hstack([np.ones((int(sel.sum()), 1)), P[sel] - self.nodes_[r]])
            pen = lam * np.eye(k + 1)
            pen[0, 0] = 0.0
            B = np.linalg.solve(D.T @ D + pen + 1e-12 * np.eye(k + 1), D.T @ T[sel])
            self.outputs_[r] = B[0]
            self.maps_[r] = B[1:].T
        return self

    def predict(self, P):
        """Outputs (n, m) for inputs P (n, k)."""
        if not hasattr(self, "nodes_"):
            raise NotFittedError("this LocalLinearMap is not fitted yet; call fit(P, T) first")
        P = as_float_array(P, "P", shape=(None, self.nodes_.shape[1]))
        r = _nearest(P, self.nodes_)
        return self.outputs_[r] + np.einsum("nck,nk->nc", self.maps_[r], P - self.nodes_[r])


# -- the classifier ----------------------------------------------------------------------
class _SequenceModel:
    """Shared input handling of the sequence classifiers."""

    def _check_fitted(self):
        if not hasattr(self, "classes_"):
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet; call fit(X, y) before predicting")

    def _features(self, X, *, fitting=False) -> np.ndarray:
        A = align_sequences(X) if self.align else _as_sequences(X)
        if fitting:
            self.input_shape_ = A.shape[1:]
        elif A.shape[1:] != self.input_shape_:
            raise ValidationError(f"X must be (n_scans, {', '.join(map(str, self.input_shape_))}) like the "
                                  f"training data, got {A.shape}")
        return A.reshape(len(A), -1) / self.scale

    def _check_y(self, X, y):
        y = np.asarray(y)
        if y.ndim != 1 or len(y) != len(X):
            raise ValidationError(f"y must be (n_scans,) = ({len(X)},) labels, got {y.shape}")
        classes, yi = np.unique(y, return_inverse=True)
        if len(classes) < 2:
            raise ValidationError(f"y must hold at least two classes, got {classes.tolist()}")
        return classes, yi

    def predict(self, X, *, reject: bool = False):
        """(n,) labels: the class with the highest score for each sequence.

        With ``reject=True`` (needs a calibrated rejection threshold), sequences whose
        novelty score exceeds it get :attr:`unknown_label_` instead.
        """
        reject = as_bool(reject, "reject")
        scores = self.predict_scores(X)
        labels = self.classes_[np.argmax(scores, axis=1)]
        if not reject:
            return labels
        if getattr(self, "rejection_threshold_", None) is None:
            raise NotFittedError("no rejection threshold: fit with reject_quantile set to use reject=True")
        nov = self.novelty_score(X)
        out = np.array(labels.tolist() + [self.unknown_label_])[:-1]
        out[nov > self.rejection_threshold_] = self.unknown_label_
        return out

    def score(self, X, y) -> float:
        """Fraction of sequences classified correctly."""
        pred = self.predict(X)
        y = np.asarray(y)
        if y.shape != pred.shape:
            raise ValidationError(f"y must be ({len(pred)},) labels, one per sequence of X, got shape {y.shape}")
        return float(np.mean(pred == y))

    def _default_unknown(self):
        if self.unknown_label is not None:
            return self.unknown_label
        return -1 if np.issubdtype(self.classes_.dtype, np.number) else "unknown"


class SequenceClassifier(_SequenceModel):
    """Seed 002's view-based classifier of tactile sequences, sklearn-style.

    Parameters
    ----------
    n_vq : int
        Reference vectors of the input-space vector quantisation (seed 002: 6).
    n_pc : int
        Local principal components per cell (seed 002: 8).
    n_llm : int
        Nodes of each cell's Local Linear Map (seed 002: 20).
    pca : {"svd", "sanger"}
        How the local PCs are computed: a direct batched SVD (default; through the
        (m, m) Gram matrices of the cells, exact up to rounding) or Sanger's rule
        as in seed 002 (the same subspace up to convergence, slower).
    align : bool
        Centre-of-gravity alignment of each whole sequence (seed 002).
    scale : float
        Readings are divided by this (12-bit full scale by default).
    vq_epochs, llm_epochs, sanger_epochs : int
        Training epochs of the AEV quantisers and of Sanger's rule.
    ridge : float
        Relative ridge penalty of the local linear maps.
    reject_quantile : float or None
        If set (e.g. 0.95), fit also calibrates a novelty threshold: the given quantile of
        the novelty scores of training sequences held out in ``reject_folds`` folds.
    reject_folds : int
    unknown_label : optional
        Label of rejected sequences (default -1 for numeric classes, "unknown" otherwise).
    novelty : {"relative", "absolute"}
        Novelty score: the local-PCA residual relative to the distance from the cell mean
        (default), or its plain norm.
    rng : None, int or numpy.random.Generator

    Attributes
    ----------
    classes_ : (n_classes,) array
    references_ : (n_cells, d) float
        Reference vectors of the cells.
    means_ : (n_cells, d) float
        Mean of the training sequences of each cell (the origin of its local PCA).
    components_ : (n_cells, n_pc, d) float
        Local principal components.
    llms_ : list of LocalLinearMap
    rejection_threshold_ : float or None

    Examples
    --------
    >>> clf = SequenceClassifier(rng=0).fit(X_train, y_train)   # doctest: +SKIP
    >>> clf.predict(X_test)                                      # doctest: +SKIP
    """

    def __init__(self, n_vq: int = 6, n_pc: int = 8, n_llm: int = 20, *, pca: str = "svd", align: bool = True,
                 scale: float = 4095.0, vq_epochs: int = 30, llm_epochs: int = 30, sanger_epochs: int = 300,
                 ridge: float = 1.0, reject_quantile: float | None = None, reject_folds: int = 10,
                 unknown_label=None, novelty: str = "relative", rng=None):
        for name, v in (("n_vq", n_vq), ("n_pc", n_pc), ("n_llm", n_llm)):
            as_count(v, name, max=100_000, why="each is a set of cells or maps trained on the scans")
        for name, v in (("vq_epochs", vq_epochs), ("llm_epochs", llm_epochs), ("sanger_epochs", sanger_epochs)):
            as_count(v, name, max=100_000, why="each epoch is a pass over the training scans")
        reject_folds = as_count(reject_folds, "reject_folds", min=2, max=1000)
        ridge = as_nonnegative_float(ridge, "ridge")
        align = as_bool(align, "align")
        if not isinstance(pca, str) or pca not in ("svd", "sanger"):
            raise ValidationError(f"pca must be 'svd' or 'sanger', got {pca!r}")
        if not isinstance(novelty, str) or novelty not in ("relative", "absolute"):
            raise ValidationError(f"novelty must be 'relative' or 'absolute', got {novelty!r}")
        scale = as_positive_float(scale, "scale")
        if reject_quantile is not None:
            reject_quantile = as_probability(reject_quantile, "reject_quantile", open_low=True, open_high=True)
        self.n_vq, self.n_pc, self.n_llm = int(n_vq), int(n_pc), int(n_llm)
        self.pca, self.align, self.scale = pca, bool(align), float(scale)
        self.vq_epochs, self.llm_epochs, self.sanger_epochs = int(vq_epochs), int(llm_epochs), int(sanger_epochs)
        self.ridge = float(ridge)
        self.reject_quantile, self.reject_folds = reject_quantile, int(reject_folds)
        self.unknown_label = unknown_label
        self.novelty = novelty
        self.rng = rng

    def __repr__(self):
        return (f"SequenceClassifier(n_vq={self.n_vq}, n_pc={self.n_pc}, n_llm={self.n_llm}, "
                f"pca={self.pca!r})")

    # -- training --------------------------------------------------------------------
    def fit(self, X, y):
        """Train on sequences X (n, T, H, W) with labels y (n,); returns self."""
        A = _as_sequences(X)
        classes, yi = self._check_y(A, y)
        rng = as_rng(self.rng)
        Z = self._features(A, fitting=True)
        self.classes_ = classes
        self.unknown_label_ = self._default_unknown()
        unsup = self._fit_unsupervised(Z, rng)
        self.references_, self.means_, self.components_ = unsup
        cell = _nearest(Z, self.references_)
        P = self._project(Z, cell)
        T = np.eye(len(classes))[yi]
        self.llms_ = []
        for i in range(len(self.references_)):
            sel = cell == i
            llm = LocalLinearMap(self.n_llm, ridge=self.ridge, epochs=self.llm_epochs, rng=rng)
            if np.any(sel):
                llm.fit(P[sel], T[sel])
            else:  # an empty cell (cannot win on training data) answers with the priors
                llm.fit(np.zeros((1, self.n_pc)), T.mean(axis=0, keepdims=True))
            self.llms_.append(llm)
        self.rejection_threshold_ = None
        if self.reject_quantile is not None:
            self.rejection_threshold_ = self._calibrate(Z, rng)
        return self

    def _fit_unsupervised(self, Z, rng):
        refs, cell = aev_quantize(Z, self.n_vq, epochs=self.vq_epochs, rng=rng)
        d = Z.shape[1]
        means = np.stack([Z[cell == i].mean(axis=0) if np.any(cell == i) else refs[i] for i in range(len(refs))])
        centred = [Z[cell == i] - means[i] for i in range(len(refs))]
        if self.pca == "svd":
            comps = _svd_pca_batched(centred, self.n_pc, d)
        else:
            comps = np.stack([sanger_pca(c, self.n_pc, epochs=self.sanger_epochs, rng=rng) for c in centred])
        return refs, means, comps

    def _calibrate(self, Z, rng):
        folds = max(2, min(self.reject_folds, len(Z)))
        part = rng.permutation(len(Z)) % folds
        scores = []
        for f in range(folds):
            refs, means, comps = self._fit_unsupervised(Z[part != f], rng)
            scores.append(_residual(Z[part == f], refs, means, comps, self.novelty == "relative"))
        return float(np.quantile(np.concatenate(scores), self.reject_quantile))

    # -- application -----------------------------------------------------------------
    def _project(self, Z, cell):
        return _project(Z, cell, self.means_, self.components_)

    def transform(self, X):
        """Cell index (n,) and local-PCA feature vectors (n, n_pc) of sequences X."""
        self._check_fitted()
        Z = self._features(X)
        cell = _nearest(Z, self.references_)
        return cell, self._project(Z, cell)

    def predict_scores(self, X) -> np.ndarray:
        """(n, n_classes) float: output vector of the winning cell's local linear map."""
        self._check_fitted()
        Z = self._features(X)
        cell = _nearest(Z, self.references_)
        P = self._project(Z, cell)
        out = np.zeros((len(Z), len(self.classes_)))
        for i, llm in enumerate(self.llms_):
            sel = cell == i
            if np.any(sel):
                out[sel] = llm.predict(P[sel])
        return out

    def novelty_score(self, X) -> np.ndarray:
        """(n,) float: how poorly the cell's local PCA explains each sequence.

        With ``novelty="relative"`` (default), ``|x - m - W^T W (x - m)| / |x - m|`` for
        the winning cell (mean m, components W), in [0, 1]: the fraction of the
        sequence's deviation from its cell mean that the local principal components do
        not reconstruct. With ``novelty="absolute"``, the residual norm itself (in
        readings / ``scale``). Large values mean the sequence is unlike anything the
        classifier was trained on; docs/benchmarks.md compares both on held-back objects.
        """
        self._check_fitted()
        return _residual(self._features(X), self.references_, self.means_, self.components_,
                         self.novelty == "relative")


def _project(Z, cell, means, comps):
    """(n, n_pc) projections of rows of Z onto the local PCs of their cells."""
    P = np.zeros((len(Z), comps.shape[1]))
    for i in np.unique(cell):
        sel = cell == i
        P[sel] = (Z[sel] - means[i]) @ comps[i].T
    return P


def _residual(Z, refs, means, comps, relative=True):
    cell = _nearest(Z, refs)
    out = np.zeros(len(Z))
    for i in np.unique(cell):
        sel = cell == i
        C = Z[sel] - means[i]
        R = C - (C @ comps[i].T) @ comps[i]
        r2 = np.einsum("nd,nd->n", R, R)
        c2 = np.einsum("nd,nd->n", C, C)
        out[sel] = np.sqrt(r2 / np.where(c2 > 0, c2, 1.0)) if relative else np.sqrt(r2)
    return out


class NearestNeighbourClassifier(_SequenceModel):
    """Baseline: the label of the nearest training sequence (Euclidean, after alignment).

    Parameters
    ----------
    align : bool
        Centre-of-gravity alignment as in :class:`SequenceClassifier`.
    scale : float
    reject_quantile : float or None
        As in :class:`SequenceClassifier`, on the distance to the nearest training
        sequence (calibrated by leave-one-out).
    unknown_label : optional
    """

    def __init__(self, *, align: bool = True, scale: float = 4095.0, reject_quantile: float | None = None,
                 unknown_label=None):
        align, scale = as_bool(align, "align"), as_positive_float(scale, "scale")
        if reject_quantile is not None:
            reject_quantile = as_probability(reject_quantile, "reject_quantile", open_low=True, open_high=True)
        self.align, self.scale = bool(align), float(scale)
        self.reject_quantile = reject_quantile
        self.unknown_label = unknown_label

    def fit(self, X, y):
        A = _as_sequences(X)
        classes, yi = self._check_y(A, y)
        self.train_ = self._features(A, fitting=True)
        self.classes_, self.train_labels_ = classes, yi
        self.unknown_label_ = self._default_unknown()
        self.rejection_threshold_ = None
        if self.reject_quantile is not None:
            D = self._sqdist(self.train_)
            np.fill_diagonal(D, np.inf)
            self.rejection_threshold_ = float(np.quantile(np.sqrt(D.min(axis=1)), self.reject_quantile))
        return self

    def _sqdist(self, Z):
        T = self.train_
        return np.maximum(np.einsum("ij,ij->i", Z, Z)[:, None] - 2.0 * Z @ T.T
                          + np.einsum("ij,ij->i", T, T)[None, :], 0.0)

    def predict_scores(self, X) -> np.ndarray:
        """(n, n_classes) float: minus the distance to the nearest sequence of each class."""
        self._check_fitted()
        D = np.sqrt(self._sqdist(self._features(X)))
        out = np.full((len(D), len(self.classes_)), -np.inf)
        for c in range(len(self.classes_)):
            sel = self.train_labels_ == c
            if np.any(sel):
                out[:, c] = -D[:, sel].min(axis=1)
        return out

    def novelty_score(self, X) -> np.ndarray:
        """(n,) float: distance to the nearest training sequence."""
        self._check_fitted()
        return np.sqrt(self._sqdist(self._features(X)).min(axis=1))
