"""Deprecated home of the touch filter and the touch likelihood.

The estimator is now :class:`touchloc.belief.SMCFilter` and the measurement models live in
:mod:`touchloc.models` (:class:`~touchloc.models.TouchLikelihood`,
:class:`~touchloc.models.RayStopModel`). Every filter of :mod:`touchloc.belief` takes
executed touches in ``update``, so :class:`EstimatorUpdater` is no longer needed. The names
below still work for one release and warn with a ``DeprecationWarning``.
"""

from __future__ import annotations

import warnings

from .._util import as_rng

__all__ = ["TouchLikelihood", "TouchFilter", "EstimatorUpdater"]


def _warn(old: str, new: str) -> None:
    warnings.warn(f"touchloc.planners.{old} is deprecated and will be removed in the next release; "
                  f"use {new}", DeprecationWarning, stacklevel=3)


def _touch_likelihood_class():
    from ..models import TouchLikelihood as _TL

    class TouchLikelihood(_TL):
        """Deprecated: use :class:`touchloc.models.TouchLikelihood`."""

        def __init__(self, *args, **kwargs):
            _warn("TouchLikelihood", "touchloc.models.TouchLikelihood")
            super().__init__(*args, **kwargs)

    return TouchLikelihood


TouchLikelihood = _touch_likelihood_class()


class TouchFilter:
    """Deprecated: use :class:`touchloc.belief.SMCFilter` (``SMCFilter(model, n);
    f.initialize(region)``). ``TouchFilter(model, region, n, **kw)`` builds one, initialised,
    with the old keyword ``sigma_free`` mapped to the free-space model's ``sigma``."""

    def __new__(cls, model, region, n_particles: int = 2000, *, moves: int = 3, ess_fraction: float = 0.5,
                max_stages: int = 60, rng=None, sigma_free=None, **free_kwargs):
        from ..belief import SMCFilter

        _warn("TouchFilter", "touchloc.belief.SMCFilter")
        if sigma_free:
            free_kwargs["sigma"] = float(sigma_free)
        f = SMCFilter(model, n_particles, moves=moves, ess_fraction=ess_fraction, max_stages=max_stages, rng=rng,
                      **free_kwargs)
        f.initialize(region)
        return f


class EstimatorUpdater:
    """Deprecated: pass a filter of :mod:`touchloc.belief` to ``active_localization(updater=...)``,
    e.g. ``ScalingSeries(model)`` (the loop initialises it over the region); its ``update``
    takes executed touches. ``EstimatorUpdater(model, region, make_estimator=None)`` returns
    such a filter, initialised (``make_estimator(model)`` must build one with
    ``initialize``/``update``)."""

    def __new__(cls, model, region, make_estimator=None, *, n_prior: int = 2000, rng=None):
        from ..belief import ScalingSeries

        _warn("EstimatorUpdater", "a touchloc.belief filter (e.g. ScalingSeries) as the loop's updater")
        rng = as_rng(rng)
        est = make_estimator(model) if make_estimator is not None else ScalingSeries(
            model, n_initial=int(n_prior), progress=False, rng=rng)
        est.initialize(region)
        return est
