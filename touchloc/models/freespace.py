"""Negative information: a probe that swept a path without contact rules out poses.

Two free-space models share one interface (:class:`FreeSpaceBase`): both carry their own
data, both are built from executed touches with ``from_results(obj, results, ...)``, and
both ignore the ``contacts`` argument of ``log_likelihood`` so that they add to a contact
model with ``+``.

- :class:`FreeSpaceModel`: the swept capsule must stay clear of the surface (closest-point
  clearance along the path; works for any swept segment).
- :class:`RayStopModel`: where would the guarded touch have stopped if the object were at
  X? A pose whose surface lies across the travelled path would have stopped the probe
  early (ray casting, as the planners simulate touches).
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

from .._util import as_points, as_poses
from .._validate import as_float, as_float_array, as_instance, as_positive_float, as_sequence
from ..errors import ValidationError
from .base import MeasurementModel, check_temperature
from .mesh import MeshObject

__all__ = ["FreeSpaceBase", "FreeSpaceModel", "RayStopModel", "TouchLikelihood", "ray_stops"]

#: rays in each ring that approximates a swept sphere (a centre ray, a ring at half the
#: radius and a ring at the full radius: 17 rays per probe with a radius)
_RING = 8


def _results_arrays(results):
    """Touches of executed results (duck-typed: ``.touch`` with origin, direction,
    max_travel, probe_radius; ``.travel``) as arrays."""
    results = as_sequence(results, "results", expected="a list of touch results")
    if not results:
        raise ValidationError("no touch results given")
    try:
        touches = [r.touch for r in results]
        O = np.array([t.origin for t in touches], dtype=float).reshape(-1, 3)
        D = np.array([t.direction for t in touches], dtype=float).reshape(-1, 3)
        maxt = np.array([t.max_travel for t in touches], dtype=float)
        rad = np.array([getattr(t, "probe_radius", 0.0) for t in touches], dtype=float)
        travel = np.array([r.travel for r in results], dtype=float)
    except AttributeError as e:
        raise ValidationError("results must be executed touches with .touch (origin, direction, max_travel, "
                              f"probe_radius) and .travel, like touchloc.planners.TouchResult: {e}") from None
    return O, D, maxt, rad, travel


class FreeSpaceBase(MeasurementModel):
    """Interface of the free-space (negative information) models.

    A free-space model carries the touches it was built from; :meth:`log_likelihood`
    ignores its ``contacts`` argument, so ``contact_model + free_space`` scores contacts
    and free space together.
    """

    #: default softness of the boundary, in units of a contact model's sigma_pos
    sigma_per_sigma_pos = 1.0

    @classmethod
    def from_results(cls, obj: MeshObject, results, **kwargs) -> "FreeSpaceBase":
        """The model of the free space swept by executed touches (``planners.TouchResult``)."""
        raise NotImplementedError

    @classmethod
    def default_sigma(cls, model) -> float:
        """Boundary softness (m) that suits a contact model (its sigma_pos, or 2 mm)."""
        sp = getattr(model, "sigma_pos", None)
        return cls.sigma_per_sigma_pos * (float(sp) if sp else 0.002)


class FreeSpaceModel(FreeSpaceBase):
    """Likelihood that the object at pose X left the swept probe paths untouched.

    Each sweep is a capsule: the segment from ``starts[j]`` to ``ends[j]`` (world frame)
    with the probe radius. For an object pose, the clearance of sweep j is
    ``c_j = min over the segment of distance(point, surface) - radius`` (a point inside a
    closed object counts as negative distance). The model is soft, to tolerate noise
    and missed contacts:

        log p(no contact on j | X) = log(eps + (1 - eps) * Phi(c_j / sigma))

    with Phi the standard normal CDF; it carries its own data, so the ``contacts``
    argument of :meth:`log_likelihood` is ignored.

    Parameters
    ----------
    obj : MeshObject
    starts, ends : (J, 3) float
        Swept segments in the world frame (m).
    radius : float or (J,) float
        Probe radius per sweep (m), >= 0.
    sigma : float
        Softness of the boundary (m), > 0 (use the position noise).
    eps : float
        Probability that a real intersection went undetected, in [0, 1).
    spacing : float, optional
        Sample spacing along each segment (m); default: sigma. Penetrations shallower
        than spacing/2 can be missed.
    """

    def __init__(self, obj: MeshObject, starts, ends, radius=0.0, *, sigma: float = 0.002,
                 eps: float = 1e-3, spacing: float | None = None):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        S = as_points(starts, "starts")
        E = as_points(ends, "ends")
        if S.shape != E.shape:
            raise ValidationError(f"starts {S.shape} and ends {E.shape} must match")
        try:
            r = np.broadcast_to(np.asarray(radius, dtype=float), (len(S),)).copy()
        except (TypeError, ValueError, OverflowError):
            raise ValidationError(f"radius must be a number or {len(S)} numbers >= 0 (m), got {radius!r}") from None
        if not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ValidationError("radius must be finite and >= 0")
        sigma = as_positive_float(sigma, "sigma (m)")
        eps = as_float(eps, "eps", low=0.0, high=1.0, high_open=True)
        if spacing is not None:
            spacing = as_positive_float(spacing, "spacing (m)")
        self.obj, self.starts, self.ends, self.radius = obj, S, E, r
        self.sigma, self.eps = float(sigma), float(eps)
        self.spacing = float(spacing) if spacing else float(sigma)
        n_total = float(np.sum(np.linalg.norm(E - S, axis=1) / self.spacing)) + 2 * len(S)
        if not n_total <= 10_000_000:
            raise ValidationError(f"spacing {self.spacing:g} m would sample {n_total:.3g} points along the swept "
                                  "segments (at most 1e7 fit in memory); use a coarser spacing or sigma")
        # sample points along every segment (fixed in the world frame)
        pts, owner = [], []
        for j in range(len(S)):
            L = np.linalg.norm(E[j] - S[j])
            n = max(2, int(np.ceil(L / self.spacing)) + 1)
            s = np.linspace(0.0, 1.0, n)[:, None]
            pts.append(S[j] + s * (E[j] - S[j]))
            owner.append(np.full(n, j))
        self._pts = np.concatenate(pts)
        self._owner = np.concatenate(owner)

    @classmethod
    def from_results(cls, obj: MeshObject, results, **kwargs) -> "FreeSpaceModel":
        """Free space from executed touches (:class:`touchloc.planners.TouchResult`):
        each touch swept the capsule from its origin to where it stopped."""
        O, D, _, rad, travel = _results_arrays(results)
        return cls(obj, O, O + travel[:, None] * D, rad, **kwargs)

    def __repr__(self) -> str:
        return f"FreeSpaceModel({self.obj.name!r}, sweeps={len(self.starts)}, sigma={self.sigma})"

    def clearance(self, poses) -> np.ndarray:
        """(N, J) float: clearance of each sweep for each object pose (m)."""
        poses = as_poses(poses)
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        local = np.einsum("nji,nmj->nmi", R, self._pts[None, :, :] - t[:, None, :])  # (N, M, 3)
        flat = local.reshape(-1, 3)
        _, _, d = self.obj.closest_points(flat)
        # Points inside the object count as negative distance. Only points within the
        # object's bounding box can be inside, so contains() runs on those alone.
        lo, hi = self.obj.bounds
        inbox = np.all((flat >= lo) & (flat <= hi), axis=1)
        inside = np.zeros(len(flat), dtype=bool)
        if np.any(inbox):
            inside[inbox] = self.obj.contains(flat[inbox])
        signed = np.where(inside, -d, d).reshape(len(poses), -1) - self.radius[self._owner][None, :]
        J = len(self.starts)
        out = np.full((len(poses), J), np.inf)
        np.minimum.at(out.T, self._owner, signed.T)
        return out

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log p(no contact along the sweeps | pose) / temperature."""
        T = check_temperature(temperature)
        c = self.clearance(poses)
        lp = np.logaddexp(np.log(self.eps) if self.eps > 0 else -np.inf,
                          np.log1p(-self.eps) + log_ndtr(c / self.sigma))
        return lp.sum(axis=1) / T


def probe_rays(O, D, rad):
    """The rays that stand for probes of radius ``rad`` moving from ``O`` along ``D``.

    A point probe is its own ray; a spherical one adds 16 parallel rays through its
    cross-section (:func:`_ray_offsets`). Returns the rays' origins (M, 3), directions
    (M, 3), the probe each belongs to (M,) and how far each ray's hit lies behind the
    sphere's leading point along the direction (M,): the probe stops that much earlier.
    """
    F = len(O)
    ray_o, ray_d, ray_f, ray_back = [O], [D], [np.arange(F)], [np.asarray(rad, float).copy()]
    for j in np.flatnonzero(rad > 0):
        offs, r = _ray_offsets(D[j], rad[j])
        ray_o.append(O[j] + offs[1:])
        ray_d.append(np.repeat(D[j][None], len(offs) - 1, axis=0))
        ray_f.append(np.full(len(offs) - 1, j))
        ray_back.append(np.sqrt(np.maximum(rad[j] ** 2 - r[1:] ** 2, 0.0)))
    return np.concatenate(ray_o), np.concatenate(ray_d), np.concatenate(ray_f), np.concatenate(ray_back)


def _ray_offsets(direction, radius):
    """(R, 3) offsets perpendicular to ``direction`` and (R,) their lengths."""
    d = direction / np.linalg.norm(direction)
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    ang = np.linspace(0, 2 * np.pi, _RING, endpoint=False)
    ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    offs = np.concatenate([np.zeros((1, 3)), 0.5 * radius * ring, radius * ring])
    return offs, np.linalg.norm(offs, axis=1)


def _per_ray(x, name: str, n: int) -> np.ndarray:
    """One value or one per ray, as an (n,) float array (finiteness is checked by the caller)."""
    a = as_float_array(x, name, finite=False, expected=f"a number or {n} numbers, one per ray")
    if a.size not in (1, n):
        raise ValidationError(f"{name} must be a number or {n} numbers, one per ray, got shape {a.shape}")
    return np.broadcast_to(a.reshape(-1), (n,)).copy()


def ray_stops(obj: MeshObject, poses, origins, directions, probe_radius=0.0) -> np.ndarray:
    """How far each probe travels before it meets the object at each pose.

    A point probe is one ray; a probe with a radius sweeps a sphere, approximated by 17
    parallel rays (a centre ray and two rings), each set back so that it stops where the
    sphere would. All P x F rays go to embreex in one call. A probe that starts inside
    the object stops at 0.

    Parameters
    ----------
    obj : MeshObject
    poses : (P, 4, 4) float
        T_world_object hypotheses.
    origins, directions : (F, 3) float
        Probe starts and unit directions (world frame).
    probe_radius : float or (F,) float

    Returns
    -------
    (P, F) float
        Stop distance along each direction (m); inf where the probe never meets the object.
    """
    obj = as_instance(obj, MeshObject, "obj")
    T = as_poses(poses)
    O = as_points(origins, "origins")
    D = as_points(directions, "directions")
    F = len(O)
    rad = _per_ray(probe_radius, "probe_radius (m)", F)
    if not (np.all(np.isfinite(rad)) and np.all(rad >= 0) and np.all(rad <= 1.0)):
        raise ValidationError("probe_radius must be finite and in [0, 1] m (a fingertip)")
    RO, RD, RF, RB = probe_rays(O, D, rad)
    R, t = T[:, :3, :3], T[:, :3, 3]
    lo = (RO[None, :, :] - t[:, None, :]) @ R    # (P, M, 3): R^T (o - t) per pose
    ld = RD[None, :, :] @ R
    dist, _, nl = obj.ray_cast(lo.reshape(-1, 3), ld.reshape(-1, 3))
    P, M = len(T), len(RO)
    dist = dist.reshape(P, M)
    with np.errstate(invalid="ignore"):
        inside = np.einsum("pmi,pmi->pm", nl.reshape(P, M, 3), ld) > 0   # leaves through a face
    dist = np.maximum(np.where(inside, 0.0, dist - RB[None, :]), 0.0)
    if M == F:
        return dist
    order = np.argsort(RF, kind="stable")
    starts = np.searchsorted(RF[order], np.arange(F))
    return np.minimum.reduceat(dist[:, order], starts, axis=1)


class RayStopModel(FreeSpaceBase):
    """Free space as ray stops: the object at X must not have stopped a touch early.

    ``log p = sum_j log(eps + (1 - eps) Phi((s_j(X) - travel_j) / sigma + margin))``

    where s_j(X) is where touch j would have stopped for the object at X (inf if it
    would miss it within its maximum travel; :func:`ray_stops`) and travel_j how far it
    really went: poses whose surface lies across the travelled path are ruled out,
    softly. A touch that hit contributes only the path before the contact (its contact
    is scored by a contact model); a miss rules out every pose the full path would meet.

    Parameters
    ----------
    obj : MeshObject
    origins, directions : (J, 3) float
        Touch starts and unit directions (world frame).
    travel : (J,) float
        How far each touch went (m).
    max_travel : (J,) float
        Each touch's maximum travel (m); stops beyond it count as misses.
    probe_radius : float or (J,) float
    sigma : float
        Softness of the boundary (m), > 0; default 4 mm (twice a 2 mm position noise).
    eps : float
        Probability that a real contact went unnoticed, in [0, 1).
    margin : float
        Shift (in sigma) so that the true surface, where s_j = travel_j, is not penalised.
    """

    sigma_per_sigma_pos = 2.0

    def __init__(self, obj: MeshObject, origins, directions, travel, max_travel, probe_radius=0.0, *,
                 sigma: float = 0.004, eps: float = 1e-3, margin: float = 1.0):
        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        O = as_points(origins, "origins")
        D = as_points(directions, "directions")
        J = len(O)
        if D.shape != O.shape:
            raise ValidationError(f"origins {O.shape} and directions {D.shape} must match")
        trav = _per_ray(travel, "travel (m)", J)
        maxt = _per_ray(max_travel, "max_travel (m)", J)
        rad = _per_ray(probe_radius, "probe_radius (m)", J)
        if not (np.all(np.isfinite(trav)) and np.all(trav >= 0) and np.all(np.isfinite(maxt)) and np.all(maxt > 0)):
            raise ValidationError("travel must be finite and >= 0, max_travel finite and > 0 (m)")
        if not (np.all(np.isfinite(rad)) and np.all(rad >= 0) and np.all(rad <= 1.0)):
            raise ValidationError("probe_radius must be finite and in [0, 1] m (a fingertip)")
        sigma = as_positive_float(sigma, "sigma (m)")
        eps = as_float(eps, "eps", low=0.0, high=1.0, high_open=True)
        margin = as_float(margin, "margin", low=0.0)
        self.obj, self.origins, self.directions = obj, O, D
        self.travel, self.max_travel, self.probe_radius = trav, maxt, rad
        self.sigma, self.eps, self.margin = float(sigma), float(eps), float(margin)

    @classmethod
    def from_results(cls, obj: MeshObject, results, **kwargs) -> "RayStopModel":
        """Ray stops of executed touches (:class:`touchloc.planners.TouchResult`, or
        anything with ``.touch`` and ``.travel``)."""
        O, D, maxt, rad, travel = _results_arrays(results)
        return cls(obj, O, D, travel, maxt, rad, **kwargs)

    def __repr__(self) -> str:
        return f"RayStopModel({self.obj.name!r}, touches={len(self.origins)}, sigma={self.sigma})"

    def stops(self, poses) -> np.ndarray:
        """(N, J) where each touch would have stopped for each pose (inf: beyond its max travel)."""
        s = ray_stops(self.obj, poses, self.origins, self.directions, self.probe_radius)
        return np.where(s <= self.max_travel[None, :], s, np.inf)

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log p(each touch travelled as far as it did | pose) / temperature."""
        T = check_temperature(temperature)
        s = self.stops(poses)
        z = (s - self.travel[None, :]) / self.sigma + self.margin
        lp = np.logaddexp(np.log(self.eps) if self.eps > 0 else -np.inf, np.log1p(-self.eps) + log_ndtr(z))
        return lp.sum(axis=1) / T


class TouchLikelihood(MeasurementModel):
    """Likelihood of a set of executed guarded touches: a contact model for every contact
    plus a free-space model for every touch's path (hit or miss).

    A thin composition, ``model(contacts) + free_space.from_results(obj, results)``, that
    carries its own data (the ``contacts`` argument of :meth:`log_likelihood` is ignored).

    Parameters
    ----------
    model : MeasurementModel
        The contact model (e.g. :class:`ProximityModel`).
    results : list of TouchResult
        Executed touches (anything with ``.contact``, ``.touch`` and ``.travel``).
    free_space : subclass of FreeSpaceBase
        Default :class:`RayStopModel`.
    sigma_free : float, optional
        Softness of the free-space boundary (m); default ``free_space.default_sigma(model)``.
    use_contacts : bool
        False: the free-space term only.
    **kwargs
        Passed to ``free_space.from_results`` (e.g. ``eps``, ``margin``).
    """

    def __init__(self, model: MeasurementModel, results, *, free_space=None, sigma_free: float | None = None,
                 use_contacts: bool = True, **kwargs):
        from .contacts import Contacts

        if not isinstance(model, MeasurementModel) or getattr(model, "obj", None) is None:
            raise ValidationError(f"model must be a measurement model of an object, got {type(model).__name__}")
        free_space = RayStopModel if free_space is None else free_space
        if not (hasattr(free_space, "default_sigma") and hasattr(free_space, "from_results")):
            raise ValidationError("free_space must be a free-space model class with default_sigma() and "
                                  f"from_results() (e.g. RayStopModel), got {type(free_space).__name__}")
        if isinstance(results, (str, bytes, dict)) or not hasattr(results, "__iter__"):
            raise ValidationError(f"results must be a list of executed touches, got {type(results).__name__}")
        self.model, self.obj, self.results = model, model.obj, list(results)
        for r in self.results:
            if not all(hasattr(r, a) for a in ("contact", "touch", "travel")):
                raise ValidationError(f"results must be executed touches (.contact, .touch, .travel), "
                                      f"got {type(r).__name__}")
        sigma = (free_space.default_sigma(model) if sigma_free is None
                 else as_positive_float(sigma_free, "sigma_free (m)"))
        self.free = free_space.from_results(model.obj, self.results, sigma=sigma, **kwargs) if self.results else None
        hits = [r.contact for r in self.results if r.contact is not None]
        self.contacts = Contacts.concatenate(hits) if hits and use_contacts else None

    def __repr__(self) -> str:
        k = 0 if self.contacts is None else len(self.contacts)
        return f"TouchLikelihood({len(self.results)} touches, {k} contacts)"

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log-likelihood of the touches for each pose (``contacts`` is ignored)."""
        T = check_temperature(temperature)
        P = as_poses(poses)
        ll = np.zeros(len(P))
        if self.contacts is not None:
            ll += self.model.log_likelihood(P, self.contacts)
        if self.free is not None:
            ll += self.free.log_likelihood(P)
        return ll / T
