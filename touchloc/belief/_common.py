"""Shared plumbing of the estimators."""

from __future__ import annotations

import warnings

import numpy as np

from .._util import external_stacklevel
from ..errors import BeliefDegenerateError, ValidationError
from ..models import Contacts
from ..models.base import MeasurementModel
from .particles import ParticleBelief
from .region import PoseRegion

#: mean d_M^2 per contact at the MAP pose above which a belief is flagged degenerate
#: (36 = every contact 6 sigma from the surface on average)
DEGENERATE_COST = 36.0


class DegenerateBeliefWarning(UserWarning):
    """The best pose explains the contacts badly: they may be outside the region."""


def check_model(model) -> MeasurementModel:
    if not isinstance(model, MeasurementModel) or getattr(model, "obj", None) is None:
        raise ValidationError(f"model must be a touchloc measurement model, got {type(model).__name__}")
    return model


def check_dynamics(dynamics):
    """None, or an object with ``sample(poses, *, rng)`` (e.g. models.GaussianDynamics)."""
    if dynamics is not None and not callable(getattr(dynamics, "sample", None)):
        raise ValidationError(f"dynamics must be None or a motion model with sample(poses, rng=...) "
                              f"(e.g. GaussianDynamics), got {type(dynamics).__name__}")
    return dynamics


def check_region(region, model) -> PoseRegion:
    if not isinstance(region, PoseRegion):
        raise ValidationError(f"region must be a PoseRegion, got {type(region).__name__}")
    if region.dim == 0:
        raise ValidationError("the region has no free degree of freedom (half_extent 0 and a fixed rotation): "
                              "the pose is already known and there is nothing to estimate")
    if region.rho is None:
        region = region.with_rho(model.obj.radius)
    return region


def check_contacts(contacts) -> Contacts:
    if not isinstance(contacts, Contacts):
        raise ValidationError(f"contacts must be a touchloc.models.Contacts, got {type(contacts).__name__}")
    if len(contacts) == 0:
        raise ValidationError("contacts is empty: localisation needs at least one contact")
    return contacts


def _is_result(r) -> bool:
    return all(hasattr(r, a) for a in ("contact", "touch", "travel"))


def split_measurements(data):
    """Contacts and executed touches of an update's data.

    ``data`` is a :class:`~touchloc.models.Contacts`, an executed touch (anything with
    ``.contact``, ``.touch`` and ``.travel``, like ``planners.TouchResult``), a list of
    them, or None. Returns ``(contacts or None, list of results)``.
    """
    if data is None:
        return None, []
    if isinstance(data, Contacts):
        return data, []
    items = [data] if _is_result(data) else (list(data) if isinstance(data, (list, tuple)) else None)
    if items is None or not all(_is_result(r) for r in items):
        raise ValidationError("an update takes Contacts or executed touches (a list of objects with .contact, "
                              f".touch and .travel, like planners.TouchResult), got {type(data).__name__}")
    hits = [r.contact for r in items if r.contact is not None]
    return (Contacts.concatenate(hits) if hits else None), items


def touch_model(model, results, free_space=None, **kwargs):
    """The free-space model of executed touches for a contact model (None without touches).

    ``free_space`` is a :class:`~touchloc.models.FreeSpaceBase` subclass (default
    :class:`~touchloc.models.RayStopModel`); its boundary softness defaults to
    ``free_space.default_sigma(model)``.
    """
    from ..models import RayStopModel

    if not results:
        return None
    cls = RayStopModel if free_space is None else free_space
    kwargs.setdefault("sigma", cls.default_sigma(model))
    return cls.from_results(model.obj, results, **kwargs)


def measurement(model, data, *, free_space=None, **kwargs):
    """What one filter update scores: ``(contacts or None, model)``.

    Contacts alone give ``(contacts, model)`` unchanged (the update works as it always
    did). Executed touches give their contacts and ``model + free space`` (or the free
    space alone after a miss, with ``contacts`` None): the one place where every filter
    turns touches into measurements.
    """
    contacts, results = split_measurements(data)
    free = touch_model(model, results, free_space, **kwargs)
    if free is None:
        return check_contacts(contacts), model
    if contacts is None or len(contacts) == 0:
        return None, free
    return contacts, model + free


def finite_loglik(ll: np.ndarray) -> np.ndarray:
    ll = np.asarray(ll, dtype=float)
    if np.any(np.isnan(ll)):
        raise BeliefDegenerateError("the measurement model returned NaN log-likelihoods")
    if not np.any(np.isfinite(ll)):
        raise BeliefDegenerateError("every pose has zero likelihood: no pose in the region explains the contacts")
    return ll


def flag_degenerate(belief: ParticleBelief, loglik_map: float, contacts: Contacts) -> ParticleBelief:
    """Mark a belief whose best particle explains the contacts badly (and warn)."""
    mean_cost = -2.0 * loglik_map / max(len(contacts), 1)
    belief.info["mean_cost_at_map"] = float(mean_cost)
    if mean_cost > DEGENERATE_COST:
        belief.degenerate = True
        warnings.warn(
            f"the best pose leaves the contacts {np.sqrt(mean_cost):.1f} sigma from the surface on "
            "average: the object is probably not in the region, or the contacts are not on this "
            "object; the belief is flagged degenerate", DegenerateBeliefWarning, stacklevel=external_stacklevel())
    return belief


def ball_volume(dim: int, r: float) -> float:
    from scipy.special import gammaln

    return float(np.exp(0.5 * dim * np.log(np.pi) - gammaln(0.5 * dim + 1) + dim * np.log(r)))
