"""Shape estimators of seed 000, section V, and the surface-count rule.

Three estimators of the number of flat sides, all fed the same samples:

1. :class:`HistogramEstimator` - the accumulated histogram of all past contact-normal
   orientations in the object frame given by the odometry;
2. the memory trace without correction - ``OrientationTracker(correct=False)``;
3. the full model - ``OrientationTracker()``.

:func:`count_surfaces` applies seed 000's rule to any of them: smooth with a Gaussian,
count the peaks above 0.4.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .._validate import as_count, as_float, as_float_array
from ..errors import ValidationError
from .tracker import as_angles, as_odometry

__all__ = ["count_surfaces", "surface_peaks", "HistogramEstimator", "normalize_max"]

TWO_PI = 2.0 * np.pi


def _as_activation(activation) -> np.ndarray:
    try:
        a = np.asarray(activation, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"activation must be a 1-D array over orientation: {exc}") from None
    if a.ndim != 1 or a.size < 3:
        raise ValidationError(f"activation must be a 1-D array of >= 3 sites over [0, 2 pi), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValidationError("activation must be finite")
    return a


def surface_peaks(activation, *, sigma: float = np.radians(3.0), threshold: float = 0.4) -> np.ndarray:
    """Orientations (rad) of the peaks counted by :func:`count_surfaces`; (n_peaks,) float."""
    a = _as_activation(activation)
    sigma = as_float(sigma, "sigma (rad)", low=0.0, high=TWO_PI)
    threshold = as_float(threshold, "threshold")
    n = a.size
    # below a thousandth of a site the smoothing is the identity (and scipy would divide by ~0)
    s = gaussian_filter1d(a, sigma * n / TWO_PI, mode="wrap") if sigma * n / TWO_PI > 1e-3 else a
    # periodic peaks: find them in three copies and keep those of the middle one
    from scipy.signal import find_peaks  # imported here: scipy.signal costs 0.3 s at start-up

    idx, _ = find_peaks(np.concatenate([s, s, s]), height=threshold)
    idx = idx[(idx >= n) & (idx < 2 * n)] - n
    return idx * (TWO_PI / n)


def count_surfaces(activation, *, sigma: float = np.radians(3.0), threshold: float = 0.4) -> int:
    """Number of flat sides an activation over orientation shows (seed 000, section V).

    The activation is smoothed with a periodic Gaussian of standard deviation ``sigma``
    ("to remove local optima due to small amounts of noise") and its local maxima above
    ``threshold`` (0.4 in seed 000) are counted; a plateau counts once. The input must be
    on the scale of the memory trace (peaks of sides about 0.6-0.8 in seed 000); normalise
    histograms first (:func:`normalize_max`).

    Parameters
    ----------
    activation : (n,) float
        Activation over ``n`` sites evenly spaced over ``[0, 2 pi)``.
    sigma : float
        Smoothing width, rad.
    threshold : float

    Returns
    -------
    int
    """
    return int(surface_peaks(activation, sigma=sigma, threshold=threshold).size)


def normalize_max(a) -> np.ndarray:
    """Scale an activation (..., n) so that each row's maximum is 1 (rows of zeros stay 0)."""
    a = as_float_array(a, "a", expected="a finite (..., n) activation")
    if a.ndim < 1 or a.shape[-1] == 0:
        raise ValidationError(f"a must be a (..., n) activation with n >= 1, got shape {a.shape}")
    m = a.max(axis=-1, keepdims=True)
    return np.divide(a, m, out=np.zeros_like(a), where=m > 0)


class HistogramEstimator:
    """Accumulated histogram of contact-normal orientations in the odometry's object frame.

    Seed 000's first baseline: no memory decay, no correction. :attr:`memory` is the
    histogram scaled to a maximum of 1 ("each row normalized", seed 000, Fig. 5), so
    :func:`count_surfaces` applies unchanged.

    Parameters
    ----------
    n_bins : int
        Bins over ``[0, 2 pi)``.
    """

    def __init__(self, n_bins: int = 360):
        if not isinstance(n_bins, (int, np.integer)) or n_bins < 3:
            raise ValidationError(f"n_bins must be an int >= 3, got {n_bins!r}")
        n_bins = as_count(n_bins, "n_bins", min=3, max=10_000_000, why="memory: one float per bin")
        self.n_bins = int(n_bins)
        self.counts = np.zeros(self.n_bins)
        self.odometry = 0.0
        self.n_steps = 0

    @property
    def orientation(self) -> float:
        """Orientation estimate: the odometry itself, rad."""
        return self.odometry

    @property
    def memory(self) -> np.ndarray:
        """Histogram scaled to a maximum of 1, (n_bins,) float."""
        return normalize_max(self.counts)

    def step(self, normal_angles, odometry: float) -> float:
        """Add one sample's normals ((K,) rad, world frame) at the given odometry (rad)."""
        a = as_angles(normal_angles, allow_empty=True)
        self.odometry = as_odometry(odometry)
        self._step(a)
        return self.odometry

    def _step(self, a: np.ndarray) -> None:
        b = np.floor(((a - self.odometry) % TWO_PI) * (self.n_bins / TWO_PI)).astype(np.int64) % self.n_bins
        self.counts += np.bincount(b, minlength=self.n_bins)
        self.n_steps += 1
