"""Actions a hand can take to gather information: guarded touches."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_float, as_float_array, as_nonnegative_float, as_positive_float, as_sequence
from ..errors import ValidationError

__all__ = ["GuardedTouch", "HandTouch", "TouchResult", "ActionCost", "TravelDistance", "TravelTime", "fingers_of", "as_cost"]


def _vec3(x) -> np.ndarray:
    """x as a flat float64 array (an empty one when it is not numeric: the caller rejects it)."""
    if x is None or isinstance(x, (str, bytes, dict)):
        return np.zeros(0)
    try:
        return np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        return np.zeros(0)


@dataclass(frozen=True)
class GuardedTouch:
    """Move a probe along a straight line until it touches something, or give up.

    Parameters
    ----------
    origin : (3,) float
        Start of the motion in the world frame (m).
    direction : (3,) float
        Direction of motion; normalised on construction.
    max_travel : float
        Length of the motion (m) after which the touch ends without contact.
    probe_radius : float
        Radius of the probe tip (m); 0 for a point probe.
    name : str, optional
        A label for tables and plots.
    """

    origin: np.ndarray
    direction: np.ndarray
    max_travel: float
    probe_radius: float = 0.0
    name: str = field(default="", compare=False)

    def __post_init__(self):
        o = _vec3(self.origin)
        d = _vec3(self.direction)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValidationError(f"GuardedTouch.origin must be 3 finite numbers, got {self.origin!r}")
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-12:
            raise ValidationError(f"GuardedTouch.direction must be 3 finite numbers, not all zero, got {self.direction!r}")
        as_positive_float(self.max_travel, "GuardedTouch.max_travel (m)")
        as_nonnegative_float(self.probe_radius, "GuardedTouch.probe_radius (m)")
        self._store(o, d, self.max_travel, self.probe_radius)

    def _store(self, o, d, max_travel, probe_radius) -> None:
        """Set the fields from checked values: the direction normalised, the arrays read-only."""
        o.flags.writeable = False
        d = d / np.linalg.norm(d)
        d.flags.writeable = False
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "max_travel", float(max_travel))
        object.__setattr__(self, "probe_radius", float(probe_radius))

    @classmethod
    def _trusted(cls, origin, direction, max_travel: float, probe_radius: float, name: str = ""):
        """The touch the constructor makes from values already known to be valid (a finite
        origin, a finite non-zero direction, a positive travel and a radius >= 0, such as
        a planner computes), without its checks: a planner makes hundreds per action, and
        the checks cost ten times the rest."""
        self = object.__new__(cls)
        object.__setattr__(self, "name", name)
        self._store(_vec3(origin), _vec3(direction), max_travel, probe_radius)
        return self

    @property
    def end(self) -> np.ndarray:
        """(3,) float: where the probe stops if it touches nothing."""
        return self.origin + self.max_travel * self.direction

    def point_at(self, travel: float) -> np.ndarray:
        """(3,) float: probe position after ``travel`` metres."""
        return self.origin + as_float(travel, "travel") * self.direction

    def __hash__(self):
        return hash((tuple(self.origin), tuple(self.direction), self.max_travel, self.probe_radius))

    def __eq__(self, other):
        if not isinstance(other, GuardedTouch):
            return NotImplemented
        return (np.array_equal(self.origin, other.origin) and np.array_equal(self.direction, other.direction)
                and self.max_travel == other.max_travel and self.probe_radius == other.probe_radius)


@dataclass(frozen=True)
class HandTouch:
    """Several guarded touches made at once (e.g. the fingers of a hand closing)."""

    touches: tuple
    name: str = field(default="", compare=False)

    def __post_init__(self):
        t = tuple(as_sequence(self.touches, "HandTouch.touches", expected="a list of GuardedTouch"))
        if not isinstance(self.name, str):
            raise ValidationError(f"HandTouch.name must be a str, got {type(self.name).__name__}")
        if not t or not all(isinstance(x, GuardedTouch) for x in t):
            raise ValidationError("HandTouch needs one or more GuardedTouch")
        object.__setattr__(self, "touches", t)


@dataclass(frozen=True)
class TouchResult:
    """What executing a :class:`GuardedTouch` produced (on a real hand or in simulation).

    Parameters
    ----------
    touch : GuardedTouch
    travel : float
        How far the probe moved (m) before it stopped.
    contact : Contacts or None
        The measured contact(s) in the world frame; None when the touch met nothing
        within ``max_travel``.

    The free space swept is the capsule from ``touch.origin`` to
    ``touch.point_at(travel)`` with radius ``touch.probe_radius`` (up to the contact).
    """

    touch: GuardedTouch
    travel: float
    contact: object = None  # touchloc.models.Contacts

    @property
    def hit(self) -> bool:
        return self.contact is not None

    @property
    def swept_segment(self):
        """(start (3,), end (3,)) of the free-space segment the probe travelled."""
        return self.touch.origin.copy(), self.touch.point_at(self.travel)


# -- helpers shared by the simulation and the planners -------------------------------------
def fingers_of(action) -> tuple:
    """The guarded touches an action is made of: ``(touch,)`` or a hand's fingers.

    Raises
    ------
    ValidationError
        When ``action`` is neither a :class:`GuardedTouch` nor a :class:`HandTouch`.
    """
    if isinstance(action, GuardedTouch):
        return (action,)
    if isinstance(action, HandTouch):
        return action.touches
    raise ValidationError(
        f"a candidate action must be a GuardedTouch or a HandTouch, got {type(action).__name__}")


# -- action costs ------------------------------------------------------------------------
class ActionCost:
    """Cost C(A, D) of executing an action that ended with the given finger travels.

    Subclasses implement :meth:`__call__`. Any callable ``cost(action, travel) -> (...)``
    with the same signature works where a cost is expected.
    """

    def __call__(self, action, travel) -> np.ndarray:
        """Cost of ``action`` for each outcome.

        Parameters
        ----------
        action : GuardedTouch or HandTouch
        travel : (..., F) float
            How far each of the action's F fingers moved before stopping (m).

        Returns
        -------
        (...) float
        """
        raise NotImplementedError


class TravelDistance(ActionCost):
    """Total distance moved by the fingers (m), plus an optional fixed ``overhead`` (m)."""

    def __init__(self, overhead: float = 0.0):
        self.overhead = as_nonnegative_float(overhead, "overhead (m)")

    def __call__(self, action, travel) -> np.ndarray:
        return self.overhead + np.sum(np.asarray(travel, dtype=float), axis=-1)

    def __repr__(self) -> str:
        return f"TravelDistance(overhead={self.overhead})"


class TravelTime(ActionCost):
    """Execution time (s): fingers move at once at ``speed`` (m/s), go there and back.

    ``time = overhead + (1 + return_fraction) * max_finger travel / speed``; a
    ``reach`` (m) term adds the distance from ``home`` to the action's start point
    (the mean finger origin), covered at ``approach_speed``.
    """

    def __init__(self, speed: float = 0.05, overhead: float = 1.0, *, return_fraction: float = 1.0,
                 home=None, approach_speed: float = 0.25):
        self.speed = as_positive_float(speed, "speed (m/s)")
        self.overhead = as_nonnegative_float(overhead, "overhead (s)")
        self.return_fraction = as_nonnegative_float(return_fraction, "return_fraction")
        self.home = None if home is None else as_float_array(home, "home (m)", shape=(3,))
        self.approach_speed = as_positive_float(approach_speed, "approach_speed (m/s)")

    def __call__(self, action, travel) -> np.ndarray:
        t = np.asarray(travel, dtype=float)
        out = self.overhead + (1.0 + self.return_fraction) * t.max(axis=-1) / self.speed
        if self.home is not None:
            start = np.mean([f.origin for f in fingers_of(action)], axis=0)
            out = out + 2.0 * np.linalg.norm(start - self.home) / self.approach_speed
        return out

    def __repr__(self) -> str:
        return f"TravelTime(speed={self.speed}, overhead={self.overhead})"


def as_cost(cost) -> ActionCost:
    """None -> :class:`TravelDistance`; a callable is used as it is."""
    if cost is None:
        return TravelDistance()
    if not callable(cost):
        raise ValidationError(f"cost must be callable as cost(action, travel (..., F)) -> (...), got {cost!r}")
    return cost
