"""The session log: every executed touch, appended to disk as it happens, and its replay.

The log is a JSON-lines file. Each touch is one line written with a single ``write``,
flushed and fsync'ed before the executor returns, so that a crash (of the program or the
machine) loses at most the touch in progress.

A crash mid-write leaves a torn line (a fragment of a record). Reading skips every torn line
and reports it (a :class:`TornRecordWarning` naming the lines, and ``torn`` in
:func:`check_session`); a log opened for appending after a crash starts on a fresh line, so
the fragment never merges with the next record; :func:`repair_session` drops the fragments
and keeps every complete record.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from .._validate import as_count, as_float_array, as_pose
from ..errors import ValidationError
from ..models import Contacts
from ..planners import GuardedTouch, TouchResult

__all__ = ["SessionLog", "SessionRecord", "SessionCheck", "TornRecordWarning", "read_session",
           "check_session", "repair_session", "session_contacts", "replay"]

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
        from .._validate import as_count, as_float, as_float_array, as_instance, as_mapping, as_pose

        self.result = as_instance(result, TouchResult, "result")
        self.finger = None if finger is None else as_count(finger, "finger", min=0, max=2)
        self.angles = None if angles is None else as_float_array(angles, "angles", shape=(7,),
                                                                 expected="7 finite joint angles (rad)")
        self.hand_pose = None if hand_pose is None else as_pose(hand_pose, "hand_pose")
        self.time = as_float(time, "time")
        self.extra = {} if extra is None else as_mapping(extra, "extra")

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
        from .._validate import as_bool, as_path

        self.path = as_path(path, "path", must_exist=False)
        self.fsync = as_bool(fsync, "fsync")
        if self.path.is_dir():
            raise ValidationError(f"path must be a file, got the directory {self.path}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a", encoding="utf-8")
        self.count = 0
        # a crash mid-write leaves a last line without its end: start on a fresh line, so that
        # the fragment stays a torn line of its own instead of spoiling the next record
        if self._fh.tell() > 0:
            with open(self.path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                last = fh.read(1)
            if last != b"\n":
                self._fh.write("\n")
                self._fh.flush()
                if self.fsync:
                    os.fsync(self._fh.fileno())

    def append(self, result: TouchResult, *, finger=None, angles=None, hand_pose=None, **extra) -> None:
        """Write one touch and flush it to disk."""
        if not isinstance(result, TouchResult):
            raise ValidationError(f"SessionLog.append needs a TouchResult, got {type(result).__name__}")
        if self._fh.closed:
            raise ValidationError("this SessionLog is closed")
        finger = None if finger is None else as_count(finger, "finger", min=0)
        angles = None if angles is None else as_float_array(angles, "angles", shape=(None,))
        hand_pose = None if hand_pose is None else as_pose(hand_pose, "hand_pose")
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
        try:
            line = json.dumps(rec, separators=(",", ":"), default=_default, allow_nan=False) + "\n"
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"a session record must hold finite numbers, arrays and text only: {exc}") from None
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


class TornRecordWarning(UserWarning):
    """A session log held torn lines (fragments of records cut by a crash); they were skipped."""


class SessionCheck:
    """What :func:`check_session` found: ``records`` (list of SessionRecord) and ``torn``
    (1-based line numbers of the fragments that were skipped)."""

    __slots__ = ("records", "torn")

    def __init__(self, records, torn):
        self.records = records
        self.torn = torn

    def __repr__(self):
        return f"SessionCheck({len(self.records)} records, torn lines {self.torn})"


_START = b'{"format":'


def _parse_line(raw: bytes):
    """A record dict from one line, or None when the line is a fragment."""
    try:
        rec = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    return rec if isinstance(rec, dict) else None


def _split(path: Path):
    """(records as (line number, dict), torn line numbers) of a log file."""
    data = path.read_bytes()
    lines = data.split(b"\n")
    recs, torn = [], []
    for i, raw in enumerate(lines):
        if not raw.strip():
            continue
        rec = _parse_line(raw)  # a whole record cut just before its line end still counts
        if rec is None:
            # a fragment followed, on the same line, by a whole record (a file appended to
            # without a fresh line by an older writer): keep the record
            j = raw.rfind(_START)
            tail = _parse_line(raw[j:]) if j > 0 and i < len(lines) - 1 else None
            torn.append(i + 1)
            if tail is not None:
                recs.append((i + 1, tail))
            continue
        recs.append((i + 1, rec))
    return recs, torn


def _record(path, lineno, rec) -> SessionRecord:
    if rec.get("format") != FORMAT:
        raise ValidationError(f"{path}, line {lineno}: format {rec.get('format')!r}, expected {FORMAT!r}")
    try:
        t = rec["touch"]
        touch = GuardedTouch(t["origin"], t["direction"], t["max_travel"], t.get("probe_radius", 0.0),
                             name=t.get("name", ""))
        contact = None
        if rec["hit"]:
            contact = Contacts(rec["points"], rec["normals"])
        res = TouchResult(touch, rec["travel"], contact)
        return SessionRecord(res, rec.get("finger"),
                             None if rec.get("angles") is None else np.array(rec["angles"], dtype=np.float64),
                             None if rec.get("hand_pose") is None else np.array(rec["hand_pose"], dtype=np.float64),
                             rec.get("time", 0.0), rec.get("extra"))
    except ValidationError as exc:
        raise ValidationError(f"{path}, line {lineno}: {exc}") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValidationError(f"{path}, line {lineno}: not a complete session record "
                              f"({type(exc).__name__}: {exc})") from None


def check_session(path) -> SessionCheck:
    """Read a session log and say which lines were torn (see :class:`SessionCheck`).

    Raises :class:`ValidationError` for a missing file, or a complete line that is not a
    session record (another file, another format).
    """
    from .._validate import as_path

    path = as_path(path, "session log")
    recs, torn = _split(path)
    return SessionCheck([_record(path, i, r) for i, r in recs], torn)


def read_session(path) -> list:
    """Records of a session log, oldest first.

    Torn lines (record fragments left by a crash mid-write, anywhere in the file) are
    skipped with a :class:`TornRecordWarning` naming them; every complete record is kept.
    """
    chk = check_session(path)
    if chk.torn:
        warnings.warn(f"{path}: skipped torn (truncated) line(s) {chk.torn[:10]}{' ...' if len(chk.torn) > 10 else ''} "
                      "(a crash while writing?); repair_session() drops them", TornRecordWarning, stacklevel=2)
    return chk.records


def repair_session(path) -> int:
    """Drop the torn lines of a session log in place, keeping every complete record.

    The repaired file is written beside the log, fsync'ed and renamed over it, so a crash
    during the repair leaves either the old or the new file. Returns the number of torn
    lines dropped (0: the file was not touched).
    """
    from .._validate import as_path

    path = as_path(path, "session log")
    recs, torn = _split(path)
    if not torn:
        return 0
    for i, r in recs:
        _record(path, i, r)  # refuse to rewrite a file that is not a session log
    tmp = path.with_name(path.name + ".repair")
    with open(tmp, "w", encoding="utf-8") as fh:
        for _, r in recs:
            fh.write(json.dumps(r, separators=(",", ":")) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    try:
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:  # pragma: no cover - platforms without directory fsync
        pass
    return len(torn)


def _records(path_or_records) -> list:
    """A session's records: read from a path, or checked as a list of SessionRecord."""
    from .._validate import as_sequence

    if isinstance(path_or_records, (str, os.PathLike)):
        return read_session(path_or_records)
    return as_sequence(path_or_records, "path_or_records", of=SessionRecord,
                       expected="a session log's path or a list of SessionRecord")


def session_contacts(path_or_records) -> Contacts:
    """All contacts of a session, concatenated (world frame)."""
    recs = _records(path_or_records)
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
    recs = _records(path_or_records)
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
