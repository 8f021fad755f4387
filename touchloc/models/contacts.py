"""Contacts: an immutable batch of K measured contacts (points and optional unit normals)."""

from __future__ import annotations

from typing import Iterable, Optional

import numpy as np

from .._util import as_points
from .._validate import as_path, as_pose, as_sequence
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
        # rows of checked arrays: no new validation, but the same arithmetic as __init__
        # (the normals divided by their norms again), so a subset equals Contacts(rows)
        out = Contacts.__new__(Contacts)
        P = self._points[idx]
        P.flags.writeable = False
        N = None
        if self._normals is not None:
            N = self._normals[idx]
            N /= np.linalg.norm(N, axis=1)[:, None]
            N.flags.writeable = False
        out._points, out._normals = P, N
        return out

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
            Rigid transform: orthonormal rotation with determinant +1.
        """
        T = as_pose(pose, "pose")  # a proper rigid transform: reflections are refused
        R, t = T[:3, :3], T[:3, 3]
        P = self._points @ R.T + t
        N = None if self._normals is None else self._normals @ R.T
        return Contacts(P, N)

    def without_normals(self) -> "Contacts":
        """The same contacts with the normals dropped (position-only measurements)."""
        return Contacts(self._points, None)

    @staticmethod
    def concatenate(items: Iterable["Contacts"]) -> "Contacts":
        """Join batches. Normals are kept only if every batch has them."""
        items = as_sequence(items, "items", of=Contacts)
        if not items:
            return Contacts(np.zeros((0, 3)))
        P = np.concatenate([c.points for c in items], axis=0)
        if all(c.has_normals for c in items):
            return Contacts(P, np.concatenate([c.normals for c in items], axis=0))
        return Contacts(P, None)

    def __add__(self, other: "Contacts") -> "Contacts":
        return Contacts.concatenate([self, other])

    # -- I/O -------------------------------------------------------------------------
    def to_csv(self, path) -> None:
        """Write ``x,y,z[,nx,ny,nz]`` rows with a header line."""
        path = as_path(path, "path", must_exist=False)
        if self.has_normals:
            data = np.hstack([self._points, self._normals])
            header = "x,y,z,nx,ny,nz"
        else:
            data, header = self._points, "x,y,z"
        try:
            np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.9g")
        except OSError as exc:
            raise ValidationError(f"cannot write the contacts file {path}: {exc}") from None

    @classmethod
    def from_csv(cls, path) -> "Contacts":
        """Read contacts from a CSV file (metres, in the frame they were measured in).

        Parameters
        ----------
        path : str or os.PathLike
            A text file (UTF-8) of 3 columns (x, y, z) or 6 (x, y, z, nx, ny, nz). An
            optional header line names the columns; with a header, columns are taken by
            name (any order, case-insensitive, extra columns rejected). Without one, the
            order is x, y, z[, nx, ny, nz]. The separator is sniffed: comma, semicolon,
            tab or runs of spaces. Blank lines and lines starting with ``#`` are skipped.

        Raises
        ------
        ValidationError
            For a path that is not a readable UTF-8 file, an empty file, ragged rows,
            non-numeric or non-finite cells, a wrong column count or unknown header names;
            the message names the file and the line.
        """
        path = as_path(path, "contacts file", must_exist=False)  # never a file descriptor
        try:
            with open(path, "r", encoding="utf-8-sig", newline="") as fh:
                text = fh.read()
        except FileNotFoundError:
            raise ValidationError(f"{path}: no such contacts file") from None
        except IsADirectoryError:
            raise ValidationError(f"{path} is a directory, expected a CSV file of contacts") from None
        except UnicodeDecodeError as exc:
            raise ValidationError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a CSV of "
                                  "contacts x,y,z[,nx,ny,nz]") from None
        except OSError as exc:
            raise ValidationError(f"{path}: cannot read contacts file: {exc.strerror or exc}") from None
        return cls(*_parse_contacts_csv(text, str(path)))


_COLUMNS = ("x", "y", "z", "nx", "ny", "nz")


def _split(line: str, sep):
    return [c.strip() for c in (line.split(sep) if sep else line.split())]


def _sniff(lines) -> str | None:
    """The separator used by the first content line: ',', ';', tab, or None (whitespace)."""
    first = lines[0][1]
    for sep in (",", ";", "\t"):
        if sep in first:
            return sep
    return None


def _is_number(cell: str) -> bool:
    try:
        float(cell)
        return True
    except ValueError:
        return False


def _parse_contacts_csv(text: str, src: str):
    if "\x00" in text:
        raise ValidationError(f"{src}: holds NUL bytes: not a text CSV of contacts")
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines())
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ValidationError(f"{src}: empty: no contacts (expected rows x,y,z[,nx,ny,nz])")
    sep = _sniff(lines)
    order = list(range(6))
    head = _split(lines[0][1], sep)
    if not all(_is_number(c) for c in head):
        lineno = lines[0][0]
        names = [c.strip().strip('"').strip("'").lower() for c in head]
        unknown = [n for n in names if n not in _COLUMNS]
        if unknown:
            raise ValidationError(f"{src}, line {lineno}: unknown column name(s) {unknown}; expected x,y,z "
                                  "and optionally nx,ny,nz, in any order")
        if len(set(names)) != len(names):
            raise ValidationError(f"{src}, line {lineno}: a column name appears twice: {names}")
        if set(names) not in ({"x", "y", "z"}, set(_COLUMNS)):
            raise ValidationError(f"{src}, line {lineno}: header {names} must name x,y,z or x,y,z,nx,ny,nz")
        order = [names.index(n) for n in _COLUMNS[:len(names)]]
        ncol = len(names)
        lines = lines[1:]
        if not lines:
            raise ValidationError(f"{src}: empty: a header line but no contacts")
    else:
        ncol = len(head)
        if ncol not in (3, 6):
            raise ValidationError(f"{src}, line {lines[0][0]}: expected 3 or 6 columns (x,y,z[,nx,ny,nz]), "
                                  f"got {ncol}")
    rows = np.empty((len(lines), ncol))
    for r, (lineno, ln) in enumerate(lines):
        cells = _split(ln, sep)
        if len(cells) != ncol:
            raise ValidationError(f"{src}, line {lineno}: {len(cells)} columns, expected {ncol} like the "
                                  f"first row (ragged row, or a different separator?)")
        for c, cell in enumerate(cells):
            try:
                v = float(cell)
            except ValueError:
                raise ValidationError(f"{src}, line {lineno}, column {c + 1}: {cell!r} is not a number") from None
            if not np.isfinite(v):
                raise ValidationError(f"{src}, line {lineno}, column {c + 1}: {cell!r} is not finite")
            rows[r, c] = v
    data = rows[:, order]
    if ncol == 3:
        return data, None
    bad = np.flatnonzero(np.linalg.norm(data[:, 3:], axis=1) < _NORMAL_MIN)
    if len(bad):
        raise ValidationError(f"{src}, line {lines[int(bad[0])][0]}: the normal is zero; normals must be non-zero")
    return data[:, :3], data[:, 3:]
