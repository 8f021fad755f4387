"""Histogram filter over a grid of up to 3 degrees of freedom (ch. 42.1.3)."""

from __future__ import annotations

import time

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.special import logsumexp

from .._util import blas_threads
from .._validate import as_positive_float
from ..errors import ValidationError
from ._common import check_contacts, check_dynamics, check_model, check_region, finite_loglik, flag_degenerate, measurement
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["HistogramFilter"]


class HistogramFilter:
    """A grid over a region of at most 3 DOF (e.g. x, y, yaw on a table).

    Parameters
    ----------
    model : MeasurementModel
    dynamics : GaussianDynamics, optional
        Prediction convolves the grid with the dynamics' Gaussian (periodic in yaw;
        probability leaving the region is lost).
    resolution : float
        Cell size along translation axes (m).
    angular_resolution : float
        Cell size along yaw (rad).
    """

    def __init__(self, model, dynamics=None, *, resolution: float = 0.002,
                 angular_resolution: float = np.radians(2.0), rho: float | None = None, rng=None):
        self.model = check_model(model)
        resolution = as_positive_float(resolution, "resolution (m)")
        angular_resolution = as_positive_float(angular_resolution, "angular_resolution (rad)")
        rho = None if rho is None else as_positive_float(rho, "rho (m)")
        self.dynamics = check_dynamics(dynamics)
        self.resolution = float(resolution)
        self.angular_resolution = float(angular_resolution)
        self.rho = rho
        self.region: PoseRegion | None = None
        self._log_p = None
        self._poses = None

    def initialize(self, region: PoseRegion) -> None:
        """Lay the grid over ``region`` with a uniform belief."""
        region = check_region(region if self.rho is None else region.with_rho(self.rho), self.model)
        if region.rotation == "full" or region.dim > 3 or region.dim == 0:
            raise ValidationError(f"a histogram filter handles 1 to 3 DOF without full rotation; got {region}")
        axes, spacing = [], []
        for i in np.flatnonzero(region.free_translation):
            n = max(1, int(np.ceil(2 * region.half_extent[i] / self.resolution)))
            step = 2 * region.half_extent[i] / n
            axes.append(region.center[i] - region.half_extent[i] + (np.arange(n) + 0.5) * step)
            spacing.append(step)
        if region.rotation == "yaw":
            lo, hi = region.yaw_range
            n = max(1, int(np.ceil((hi - lo) / self.angular_resolution)))
            step = (hi - lo) / n
            axes.append(lo + (np.arange(n) + 0.5) * step)
            spacing.append(step)
        self.region = region
        self.axes = axes
        self.spacing = np.array(spacing)
        self.shape = tuple(len(a) for a in axes)
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
        ref = np.eye(4)
        ref[:3, 3] = region.center
        if region.rotation == "yaw":
            ref[:3, :3] = region.base_rotation
            grid = grid.copy()
            grid[:, -1] *= region.rho  # yaw in metric units for from_local
        elif region.rotation == "fixed":
            ref[:3, :3] = region.fixed_rotation
        self._poses = region.from_local(self._local(grid, region), ref)
        self._log_p = np.full(self.shape, -np.log(np.prod(self.shape)))

    def _local(self, grid, region):
        g = grid.copy()
        k = int(region.free_translation.sum())
        g[:, :k] -= region.center[region.free_translation]
        return g

    @property
    def cell_radius(self) -> float:
        """Half-diagonal of a cell in the pose metric (m)."""
        s = self.spacing.copy()
        if self.region.rotation == "yaw":
            s[-1] *= self.region.rho
        return float(0.5 * np.linalg.norm(s))

    @property
    def belief(self) -> ParticleBelief:
        if self._log_p is None:
            raise ValidationError("call initialize(region) first")
        return ParticleBelief(self._poses, self._log_p.ravel(), region=self.region, resolution=self.cell_radius)

    def predict(self) -> None:
        """Dynamics update: Gaussian blur of the grid (eq. 42.10 as a convolution)."""
        if self._log_p is None:
            raise ValidationError("call initialize(region) first")
        if self.dynamics is None:
            raise ValidationError("predict() needs dynamics=GaussianDynamics(...)")
        sig, modes = [], []
        k = int(self.region.free_translation.sum())
        for i in range(len(self.shape)):
            if i < k:
                sig.append(self.dynamics.sigma_met / self.spacing[i])
                modes.append("constant")
            else:
                sig.append(self.dynamics.sigma_ang / self.spacing[i])
                modes.append("wrap" if self.region.periodic_yaw else "constant")
        top = self._log_p.max()
        p = gaussian_filter(np.exp(self._log_p - top), sigma=sig, mode=modes, truncate=4.0)
        with np.errstate(divide="ignore"):
            lp = np.log(np.maximum(p, 0.0))
        self._log_p = lp - logsumexp(lp)

    @blas_threads
    def update(self, contacts, *, model=None, free_space=None) -> ParticleBelief:
        """Measurement update at every cell centre (eq. 42.9).

        ``contacts`` is a :class:`~touchloc.models.Contacts` or the executed touches of an
        action (their contacts and swept free space, as in
        :meth:`ParticleFilter.update`); ``model`` replaces the filter's model for this
        update only.
        """
        if self._log_p is None:
            raise ValidationError("call initialize(region) first")
        if model is None:
            contacts, m = measurement(self.model, contacts, free_space=free_space)
        else:
            m = check_model(model)
            contacts = check_contacts(contacts) if contacts is not None else None
        ll = finite_loglik(m.log_likelihood(self._poses, contacts)).reshape(self.shape)
        lp = self._log_p + ll
        self._log_p = lp - logsumexp(lp)
        b = self.belief
        if contacts is not None:
            flag_degenerate(b, float(ll.ravel()[np.argmax(lp)]), contacts)
        return b

    @blas_threads
    def localize(self, contacts, region: PoseRegion) -> ParticleBelief:
        """Static: uniform grid prior times the likelihood."""
        t0 = time.perf_counter()
        self.initialize(region)
        b = self.update(contacts)
        b.info["seconds"] = time.perf_counter() - t0
        return b
