"""A Rao-Blackwellised particle filter for the rotation problem of seed 000.

The state is the orientation offset ``delta`` (rad) between the odometry and the true
rotation - ``orientation = odometry + delta`` - and a map of the object's surface
orientations. As in FastSLAM, particles sample ``delta`` and each carries its own map,
conditioned on its own trajectory: a histogram of object-frame normal orientations
(``n_bins`` bins over ``[0, 2 pi)``, normals split linearly between the two nearest bins).

Per sample:

predict
    ``delta += N(0, drift_std)`` (the odometry's drift and regrasp slips);
update
    each normal ``a`` is scored by the particle's map density at ``a - odometry - delta``
    (Dirichlet-smoothed: ``(c_b + alpha) / (sum c + n_bins alpha)``, relative to uniform);
    the normals of one sample come from one contact and are correlated, so the summed
    log-likelihood is tempered by ``power``;
resample
    systematic, when the effective sample size drops below half the particles;
map update
    each particle adds the sample's normals to its own map (after an optional forgetting
    factor).

The estimate is the heaviest particle (its offset and map): the maps of different
particles live in frames that may differ by a symmetry of the object, so averaging them
would blur the sides.
"""

from __future__ import annotations

import numpy as np

from .._util import as_rng
from .._validate import as_count, as_nonnegative_float, as_positive_float, as_probability
from ..errors import ValidationError
from .tracker import as_angles, as_odometry

__all__ = ["ParticleOrientationEstimator"]

TWO_PI = 2.0 * np.pi


class ParticleOrientationEstimator:
    """Joint orientation offset and surface-orientation map, Rao-Blackwellised.

    Parameters
    ----------
    n_particles : int
    n_bins : int
        Bins of each particle's map over ``[0, 2 pi)``.
    drift_std : float
        Standard deviation of the offset's random walk per sample, rad.
    alpha : float
        Dirichlet pseudo-count per bin (how much an empty map tolerates).
    power : float
        Tempering exponent of a sample's joint likelihood (normals of one contact are
        not independent).
    forget : float
        Fraction of each map forgotten per sample (0: none).
    contrast : float
        Density contrast (relative to uniform, minus 1) at which :attr:`memory` reaches
        ``1 - 1/e``.
    scale_range : (float, float)
        Range of each particle's odometry scale error ``k`` (drawn uniformly at reset):
        the offset then also moves by ``k * (change of odometry)`` per sample, modelling
        a systematic under-estimate of rotation. Default (0, 0): off - on the simulated
        data sets, ``(0, 0.15)`` with ``scale_std=0.001`` helped on one set of seeds and
        hurt on another.
    scale_std : float
        Random walk of ``k`` per sample.
    rng : None, int or numpy Generator

    Attributes
    ----------
    offsets : (N,) float
        Particles' orientation offsets, rad.
    scales : (N,) float
        Particles' odometry scale errors.
    log_weights : (N,) float
        Normalised log-weights.
    maps : (N, n_bins) float
        Particles' histograms of object-frame normal orientations.
    """

    def __init__(self, n_particles: int = 400, n_bins: int = 120, *, drift_std: float = np.radians(0.5),
                 alpha: float = 0.05, power: float = 0.25, forget: float = 0.0, contrast: float = 2.0,
                 scale_range=(0.0, 0.0), scale_std: float = 0.0, rng=None):
        if not isinstance(n_particles, (int, np.integer)) or n_particles < 1:
            raise ValidationError(f"n_particles must be a positive int, got {n_particles!r}")
        if not isinstance(n_bins, (int, np.integer)) or n_bins < 8:
            raise ValidationError(f"n_bins must be an int >= 8, got {n_bins!r}")
        n_particles = as_count(n_particles, "n_particles", max=1_000_000, why="memory: n_particles x n_bins floats")
        n_bins = as_count(n_bins, "n_bins", min=8, max=100_000, why="memory: n_particles x n_bins floats")
        if n_particles * n_bins > 100_000_000:
            raise ValidationError(f"n_particles x n_bins = {n_particles * n_bins} exceeds 1e8 (memory: 800 MB)")
        drift_std, alpha = as_positive_float(drift_std, "drift_std"), as_positive_float(alpha, "alpha")
        power, contrast = as_positive_float(power, "power"), as_positive_float(contrast, "contrast")
        forget = as_probability(forget, "forget", open_high=True)
        scale_std = as_nonnegative_float(scale_std, "scale_std")
        self.n_particles, self.n_bins = int(n_particles), int(n_bins)
        self.drift_std, self.alpha, self.power, self.forget = float(drift_std), float(alpha), float(power), float(forget)
        self.contrast = float(contrast)
        try:
            lo, hi = (float(v) for v in scale_range)
        except (TypeError, ValueError):
            raise ValidationError(f"scale_range must be (low, high), got {scale_range!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise ValidationError(f"scale_range must be finite (low, high) with low <= high, got {scale_range!r}")
        if not (np.isfinite(scale_std) and scale_std >= 0):
            raise ValidationError(f"scale_std must be a non-negative finite number, got {scale_std!r}")
        self.scale_range, self.scale_std = (lo, hi), float(scale_std)
        self.rng = as_rng(rng)
        self.reset()

    def reset(self) -> None:
        """All particles at offset 0 with empty maps."""
        N, B = self.n_particles, self.n_bins
        self.offsets = np.zeros(N)
        self.scales = self.rng.uniform(*self.scale_range, N) if self.scale_range[1] > self.scale_range[0] \
            else np.full(N, float(self.scale_range[0]))
        self._last_odometry = None
        self.log_weights = np.full(N, -np.log(N))
        self.maps = np.zeros((N, B))
        self.odometry = 0.0
        self.n_steps = 0
        self._rows = (np.arange(N) * B)[:, None]

    @property
    def best(self) -> int:
        """Index of the heaviest particle."""
        return int(np.argmax(self.log_weights))

    @property
    def orientation(self) -> float:
        """Estimated accumulated rotation (odometry + the heaviest particle's offset), rad."""
        return self.odometry + float(self.offsets[self.best])

    @property
    def memory(self) -> np.ndarray:
        """The heaviest particle's map as a side strength in [0, 1), (n_bins,) float.

        With ``r`` the map's density relative to uniform, the strength is
        ``1 - exp(-max(r - 1, 0) / contrast)``: a uniform map (round object) stays near 0,
        sides visited more or less often all saturate (a plain max-normalised histogram
        lets rarely touched sides fall below the counting threshold).
        """
        m = self.maps[self.best]
        mean = m.mean()
        if mean <= 0:
            return np.zeros(self.n_bins)
        return 1.0 - np.exp(-np.maximum(m / mean - 1.0, 0.0) / self.contrast)

    def ess(self) -> float:
        """Effective sample size of the weights."""
        w = np.exp(self.log_weights)
        return float(1.0 / np.sum(w * w))

    def step(self, normal_angles, odometry: float) -> float:
        """Process one sample ((K,) normal angles, rad, world frame; odometry, rad)."""
        a = as_angles(normal_angles, allow_empty=True)
        self.odometry = as_odometry(odometry)
        self._step(a)
        return self.orientation

    def _bins(self, a: np.ndarray):
        """Object-frame positions of the normals in every particle's map, for linear
        interpolation: fractions (N, K) and flat indices of the two neighbouring bins."""
        B = self.n_bins
        x = ((a[None, :] - self.odometry - self.offsets[:, None]) % TWO_PI) * (B / TWO_PI)
        i0 = np.floor(x).astype(np.int64)
        fr = x - i0
        i0 %= B
        i1 = (i0 + 1) % B
        return fr, (self._rows + i0).ravel(), (self._rows + i1).ravel()

    def _step(self, a: np.ndarray) -> None:
        N, B = self.n_particles, self.n_bins
        d_odo = 0.0 if self._last_odometry is None else self.odometry - self._last_odometry
        self._last_odometry = self.odometry
        self.offsets += self.scales * d_odo + self.rng.normal(0.0, self.drift_std, N)
        if self.scale_std:
            self.scales += self.rng.normal(0.0, self.scale_std, N)
        fr, flat0, flat1 = self._bins(a)
        m = self.maps.ravel()
        dens = (1.0 - fr.ravel()) * m[flat0] + fr.ravel() * m[flat1]
        tot = self.maps.sum(axis=1)
        if self.n_steps:
            ll = np.log((dens.reshape(N, -1) + self.alpha) * (B / (tot[:, None] + B * self.alpha))).sum(axis=1)
            lw = self.log_weights + self.power * ll
            lw -= np.logaddexp.reduce(lw)
            self.log_weights = lw
            if self.ess() < 0.5 * N:
                self._resample()
                fr, flat0, flat1 = self._bins(a)
        if self.forget:
            self.maps *= 1.0 - self.forget
        add = np.bincount(flat0, weights=(1.0 - fr).ravel(), minlength=N * B)
        add += np.bincount(flat1, weights=fr.ravel(), minlength=N * B)
        self.maps += add.reshape(N, B)
        self.n_steps += 1

    def _resample(self) -> None:
        N = self.n_particles
        w = np.exp(self.log_weights)
        c = np.cumsum(w)
        c[-1] = 1.0
        idx = np.searchsorted(c, (self.rng.random() + np.arange(N)) / N)
        self.offsets = self.offsets[idx]
        self.scales = self.scales[idx]
        self.maps = self.maps[idx]
        self.log_weights = np.full(N, -np.log(N))
