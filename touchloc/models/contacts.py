"""Contacts: an immutable batch of K measured contacts (points and optional unit normals)."""

from __future__ import annotations

from typing import Iterable, Optional

import numpy as np

from .._util import as_points
from ..errors import ValidationError

__all__ = ["Contacts"]

_NORMAL_MIN = 1e-9


class Contacts:
    """K contacts measured in one frame (world unless stated otherwise).

    Parameters
    ----------
    points : (K, 3) float
        Contact positions in metres. Must be finite.
    normals : (K, 3) float or None
        Outward surface normals of the touched object at the contacts. Non-unit normals
        are normalised; zero or non-finite normals are rejected. ``None`` when the sensor
        measures positions only.

    Notes
    -----
    Instances are immutable: the arrays are read-only copies. An empty batch (K = 0) is
    allowed for bookkeeping (e.g. concatenation), but measurement models reject it.
    """

    __slots__ = ("_points", "_normals")

    def __init__(self, points, normals=None):
        P = as_points(points, "contacts.points", allow_empty=True).copy()
        N = None
        if normals is not None:
            N = as_points(normals, "contacts.normals", allow_empty=True).copy()
            if N.shape != P.shape:
                raise ValidationError(
                    f"contacts.normals must match contacts.points {P.shape}, got {N.shape}"
                )
            norm = np.linalg.norm(N, axis=1)
            if np.any(norm < _NORMAL_MIN):
                bad = int(np.flatnonzero(norm < _NORMAL_MIN)[0])
                raise ValidationError(
                    f"contacts.normals must be non-zero, row {bad} is {N[bad].tolist()}"
                )
            N /= norm[:, None]
            N.flags.writeable = False
        P.flags.writeable = False
        self._points = P
        self._normals = N

    # -- accessors -------------------------------------------------------------------
    @property
    def points(self) -> np.ndarray:
        """(K, 3) float: contact positions (read-only)."""
        return self._points

    @property
    def normals(self) -> Optional[np.ndarray]:
        """(K, 3) float unit normals, or None (read-only)."""
        return self._normals

    @property
    def has_normals(self) -> bool:
        return self._normals is not None

    def __len__(self) -> int:
        return self._points.shape[0]

    def __getitem__(self, idx) -> "Contacts":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return Contacts(self._points[idx], None if self._normals is None else self._normals[idx])

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        kind = "with normals" if self.has_normals else "positions only"
        return f"Contacts(K={len(self)}, {kind})"

    def __eq__(self, other) -> bool:
        if not isinstance(other, Contacts):
            return NotImplemented
        if self.has_normals != other.has_normals:
            return False
        same_p = np.array_equal(self._points, other._points)
        return same_p and (not self.has_normals or np.array_equal(self._normals, other._normals))

    __hash__ = None  # arrays are not hashable by value

    # -- operations ------------------------------------------------------------------
    def transform(self, pose) -> "Contacts":
        """Contacts expressed in another frame: ``pose`` maps the current frame to it.

        Parameters
        ----------
        pose : (4, 4) float
            Rigid transform (rotation part must be orthonormal).
        """
        T = np.asarray(pose, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValidationError(f"pose must be a finite (4, 4) matrix, got {T.shape}")
        R, t = T[:3, :3], T[:3, 3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValidationError("pose rotation must be orthonormal")
        P = self._points @ R.T + t
        N = None if self._normals is None else self._normals @ R.T
        return Contacts(P, N)

    def without_normals(self) -> "Contacts":
        """The same contacts with the normals dropped (position-only measurements)."""
        return Contacts(self._points, None)

    @staticmethod
    def concatenate(items: Iterable["Contacts"]) -> "Contacts":
        """Join batches. Normals are kept only if every batch has them."""
        items = list(items)
        if not items:
            return Contacts(np.zeros((0, 3)))
        for c in items:
            if not isinstance(c, Contacts):
                raise ValidationError(f"can only concatenate Contacts, got {type(c).__name__}")
        P = np.concatenate([c.points for c in items], axis=0)
        if all(c.has_normals for c in items):
            return Contacts(P, np.concatenate([c.normals for c in items], axis=0))
        return Contacts(P, None)

    def __add__(self, other: "Contacts") -> "Contacts":
        return Contacts.concatenate([self, other])

    # -- I/O -------------------------------------------------------------------------
    def to_csv(self, path) -> None:
        """Write ``x,y,z[,nx,ny,nz]`` rows with a header line."""
        if self.has_normals:
            data = np.hstack([self._points, self._normals])
            header = "x,y,z,nx,ny,nz"
        else:
            data, header = self._points, "x,y,z"
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.9g")

    @classmethod
    def from_csv(cls, path) -> "Contacts":
        """Read a CSV of 3 (positions) or 6 (positions and normals) columns; a header is optional."""
        with open(path, "r", encoding="utf-8") as fh:
            first = fh.readline()
        skip = 0 if _is_numeric_row(first) else 1
        data = np.loadtxt(path, delimiter=",", skiprows=skip, ndmin=2)
        if data.shape[1] == 3:
            return cls(data)
        if data.shape[1] == 6:
            return cls(data[:, :3], data[:, 3:])
        raise ValidationError(f"{path}: expected 3 or 6 columns (x,y,z[,nx,ny,nz]), got {data.shape[1]}")


def _is_numeric_row(line: str) -> bool:
    try:
        [float(v) for v in line.strip().split(",") if v.strip()]
        return bool(line.strip())
    except ValueError:
        return False
