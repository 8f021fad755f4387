"""The session log: every executed touch, appended to disk as it happens, and its replay.

The log is a JSON-lines file. Each touch is one line written with a single ``write``,
flushed and fsync'ed before the executor returns, so that a crash (of the program or the
machine) loses at most the touch in progress. A truncated last line (a crash mid-write) is
ignored with a warning when reading.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from ..errors import ValidationError
from ..models import Contacts
from ..planners import GuardedTouch, TouchResult

__all__ = ["SessionLog", "SessionRecord", "read_session", "session_contacts", "replay"]

FORMAT = "touchloc-session/1"


class SessionRecord:
    """One logged touch: the :class:`TouchResult` and what was known when it was made.

    Attributes
    ----------
    result : TouchResult
    finger : int or None
    angles : (7,) float or None
        Joint angles (rad) at the end of the touch.
    hand_pose : (4, 4) float or None
    time : float
        UNIX time of the touch.
    extra : dict
        Anything else that was logged (e.g. blob moments).
    """

    __slots__ = ("result", "finger", "angles", "hand_pose", "time", "extra")

    def __init__(self, result, finger=None, angles=None, hand_pose=None, time=0.0, extra=None):
        self.result = result
        self.finger = finger
        self.angles = angles
        self.hand_pose = hand_pose
        self.time = time
        self.extra = extra or {}

    def __repr__(self):
        return f"SessionRecord(hit={self.result.hit}, travel={self.result.travel:.4f}, finger={self.finger})"


def _list(a):
    return None if a is None else np.asarray(a, dtype=np.float64).tolist()


class SessionLog:
    """Append-only log of executed touches.

    Parameters
    ----------
    path : str or Path
        The file; created if missing, appended to if it exists.
    fsync : bool
        Force each record to the disk (default True).
    """

    def __init__(self, path, *, fsync: bool = True):
        self.path = Path(path)
        self.fsync = bool(fsync)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a", encoding="utf-8")
        self.count = 0

    def append(self, result: TouchResult, *, finger=None, angles=None, hand_pose=None, **extra) -> None:
        """Write one touch and flush it to disk."""
        if not isinstance(result, TouchResult):
            raise ValidationError(f"SessionLog.append needs a TouchResult, got {type(result).__name__}")
        t = result.touch
        c = result.contact
        rec = {
            "format": FORMAT,
            "time": time.time(),
            "touch": {"origin": _list(t.origin), "direction": _list(t.direction), "max_travel": t.max_travel,
                      "probe_radius": t.probe_radius, "name": t.name},
            "travel": float(result.travel),
            "hit": c is not None,
            "points": None if c is None else _list(c.points),
            "normals": None if c is None or c.normals is None else _list(c.normals),
            "finger": finger,
            "angles": _list(angles),
            "hand_pose": _list(hand_pose),
            "extra": extra,
        }
        line = json.dumps(rec, separators=(",", ":"), default=_default) + "\n"
        self._fh.write(line)
        self._fh.flush()
        if self.fsync:
            os.fsync(self._fh.fileno())
        self.count += 1

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    raise TypeError(f"cannot log {type(o).__name__}")


def read_session(path) -> list:
    """Records of a session log, oldest first (a truncated last line is skipped with a warning)."""
    path = Path(path)
    if not path.exists():
        raise ValidationError(f"session log {path} does not exist")
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    out = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            if i == len(lines) - 1 and not line.endswith("\n"):
                warnings.warn(f"{path}: last record is truncated (a crash while writing?); skipped", stacklevel=2)
                continue
            raise ValidationError(f"{path}, line {i + 1}: not a session record") from None
        if rec.get("format") != FORMAT:
            raise ValidationError(f"{path}, line {i + 1}: format {rec.get('format')!r}, expected {FORMAT!r}")
        t = rec["touch"]
        touch = GuardedTouch(t["origin"], t["direction"], t["max_travel"], t.get("probe_radius", 0.0),
                             name=t.get("name", ""))
        contact = None
        if rec["hit"]:
            contact = Contacts(rec["points"], rec["normals"])
        res = TouchResult(touch, rec["travel"], contact)
        out.append(SessionRecord(res, rec.get("finger"),
                                 None if rec.get("angles") is None else np.array(rec["angles"]),
                                 None if rec.get("hand_pose") is None else np.array(rec["hand_pose"]),
                                 rec.get("time", 0.0), rec.get("extra")))
    return out


def session_contacts(path_or_records) -> Contacts:
    """All contacts of a session, concatenated (world frame)."""
    recs = read_session(path_or_records) if isinstance(path_or_records, (str, Path)) else list(path_or_records)
    hits = [r.result.contact for r in recs if r.result.contact is not None and len(r.result.contact)]
    return Contacts.concatenate(hits) if hits else Contacts(np.zeros((0, 3)))


def replay(path_or_records, estimator, region=None):
    """Feed a logged session into an estimator.

    Parameters
    ----------
    path_or_records : path or list of SessionRecord
    estimator
        A static estimator with ``localize(contacts, region)`` (all contacts at once;
        used when ``region`` is given), a filter with ``update(contacts)`` and ``belief``
        (each touch's contacts in turn; returns ``estimator.belief``; initialise it
        first), or a callable ``f(contacts) -> anything``.
    region : PoseRegion, optional
        The pose region for static estimators.
    """
    recs = read_session(path_or_records) if isinstance(path_or_records, (str, Path)) else list(path_or_records)
    if region is not None and hasattr(estimator, "localize"):
        return estimator.localize(session_contacts(recs), region)
    if hasattr(estimator, "update") and hasattr(estimator, "belief"):
        for r in recs:
            if r.result.contact is not None and len(r.result.contact):
                estimator.update(r.result.contact)
        return estimator.belief
    if callable(estimator):
        return estimator(session_contacts(recs))
    raise ValidationError("estimator must have localize(contacts, region) (pass region=), "
                          "update(contacts) and belief, or be callable")
