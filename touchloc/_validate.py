"""Validators for values that cross a public boundary.

Each function takes the raw argument and the name the user knows it by, and returns the
value in the library's internal form (float, int, float64 array, :class:`pathlib.Path`), or
raises :class:`~touchloc.errors.ValidationError` with a message that says what was wrong
and what was expected. They are the one implementation of these checks: ``touchloc._util``
re-exports the array validators from here.
"""

from __future__ import annotations

import math
import numbers
import os
import warnings
from pathlib import Path

import numpy as np

from .errors import ValidationError

__all__ = [
    "as_float",
    "as_positive_float",
    "as_nonnegative_float",
    "as_timeout",
    "as_count",
    "as_probability",
    "as_float_array",
    "as_points",
    "as_pose",
    "as_poses",
    "as_motion",
    "as_path",
    "as_bool",
    "as_name",
    "as_instance",
    "as_callable",
    "as_sequence",
    "as_mapping",
    "ORTHO_TOL",
    "MAX_PARTICLES",
    "WHY_PARTICLES",
]

#: Largest deviation allowed in ``R.T @ R - I`` and ``det(R) - 1`` for a pose's rotation.
#: Rotations composed in float64 stay within about 1e-12 of orthonormal; 1e-6 leaves room
#: for poses read from text files with 7-8 significant digits.
ORTHO_TOL = 1e-6

#: Upper limit of a particle, sample or walker count: one pose is 128 bytes, so 1e7 poses
#: hold 1.3 GB before any likelihood work; larger counts are typing errors, not studies.
MAX_PARTICLES = 10_000_000
WHY_PARTICLES = "memory: a pose takes 128 bytes, 1e7 poses 1.3 GB"


def _describe(x) -> str:
    r = repr(x)
    return r if len(r) <= 60 else r[:57] + "..."


def as_float(x, name: str, *, finite: bool = True, low=None, high=None,
             low_open: bool = False, high_open: bool = False) -> float:
    """Return ``x`` as a Python float, checking type, finiteness and an optional range.

    Parameters
    ----------
    x : real number
        bool, str, None, arrays with more than one element and complex numbers are rejected.
    name : str
        The argument's name, used in the error message.
    finite : bool
        Reject NaN and +-inf (NaN is always rejected).
    low, high : float, optional
        Bounds; closed unless ``low_open`` / ``high_open``.
    """
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (numbers.Real, np.ndarray)):
        raise ValidationError(f"{name} must be a real number, got {type(x).__name__} {_describe(x)}")
    if isinstance(x, np.ndarray):
        if x.size != 1 or x.dtype.kind not in "iuf":
            raise ValidationError(f"{name} must be a real number, got array of shape {x.shape}")
        x = x.reshape(()).item()
    try:
        v = float(x)
    except (OverflowError, TypeError, ValueError):
        raise ValidationError(f"{name} must be a real number, got {_describe(x)}") from None
    if math.isnan(v) or (finite and math.isinf(v)):
        raise ValidationError(f"{name} must be finite, got {v}")
    if low is not None and (v < low or (low_open and v == low)):
        op = ">" if low_open else ">="
        raise ValidationError(f"{name} must be {op} {low}, got {v}")
    if high is not None and (v > high or (high_open and v == high)):
        op = "<" if high_open else "<="
        raise ValidationError(f"{name} must be {op} {high}, got {v}")
    return v


def as_positive_float(x, name: str, *, high=None) -> float:
    """A finite float > 0 (and <= ``high`` when given)."""
    return as_float(x, name, low=0.0, low_open=True, high=high)


def as_nonnegative_float(x, name: str, *, high=None) -> float:
    """A finite float >= 0 (and <= ``high`` when given)."""
    return as_float(x, name, low=0.0, high=high)


def as_timeout(x, name: str = "timeout", *, allow_none: bool = False) -> float | None:
    """A finite, non-negative number of seconds (None passes when ``allow_none``).

    An infinite or NaN timeout would make a wait loop forever, so both are rejected.
    """
    if x is None and allow_none:
        return None
    return as_float(x, name, low=0.0)


def as_count(x, name: str, *, min: int = 1, max: int | None = None, why: str = "") -> int:
    """An integer in ``[min, max]``.

    Integral floats (``3.0``) are accepted; bool, fractions, NaN and inf are not. ``max``
    is a sanity limit against counts that would exhaust memory or time; ``why`` is added to
    the error message to say where the limit comes from.
    """
    if isinstance(x, (bool, np.bool_)):
        raise ValidationError(f"{name} must be an integer, got bool {x!r}")
    if isinstance(x, (numbers.Integral, np.integer)):
        v = int(x)
    elif isinstance(x, (numbers.Real, np.floating)):
        f = float(x)
        if not math.isfinite(f) or f != math.floor(f) or abs(f) > 2**53:
            raise ValidationError(f"{name} must be an integer, got {_describe(x)}")
        v = int(f)
    else:
        raise ValidationError(f"{name} must be an integer, got {type(x).__name__} {_describe(x)}")
    if v < min:
        raise ValidationError(f"{name} must be >= {min}, got {v}")
    if max is not None and v > max:
        extra = f" ({why})" if why else ""
        raise ValidationError(f"{name} must be <= {max}{extra}, got {v}")
    return v


def as_probability(x, name: str, *, open_low: bool = False, open_high: bool = False) -> float:
    """A float in [0, 1] (ends excluded on request)."""
    return as_float(x, name, low=0.0, high=1.0, low_open=open_low, high_open=open_high)


def _as_float_array(x, name: str, expected: str) -> np.ndarray:
    if x is None or isinstance(x, (str, bytes, dict, set)):
        raise ValidationError(f"{name} must be {expected}, got {type(x).__name__}")
    if isinstance(x, np.ndarray) and x.dtype.kind in "cUSOV":
        raise ValidationError(f"{name} must be {expected}, got an array of dtype {x.dtype}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", np.exceptions.ComplexWarning)
            a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValidationError(f"{name} must be {expected}: {exc}") from None
    return a


def as_float_array(x, name: str, *, shape=None, finite: bool = True, low=None,
                   expected: str | None = None) -> np.ndarray:
    """A float64 array of the given ``shape`` (``None`` entries match any length).

    Non-numeric input (str, None, dicts, complex, object arrays) is rejected; so are NaN
    and +-inf when ``finite`` (otherwise the caller checks them) and values below ``low``
    when given.
    """
    what = expected or ("a float array" + (f" of shape {tuple('*' if d is None else d for d in shape)}"
                                           if shape is not None else ""))
    if isinstance(x, (bool, np.bool_)) or (isinstance(x, np.ndarray) and x.dtype.kind in "cUSOVb"):
        raise ValidationError(f"{name} must be {what}, got {_describe(x)}")
    if isinstance(x, complex):
        raise ValidationError(f"{name} must be {what}, got complex {x!r}")
    a = _as_float_array(x, name, what)
    if shape is not None and (a.ndim != len(shape) or any(d is not None and d != n for d, n in zip(shape, a.shape))):
        raise ValidationError(f"{name} must be {what}, got shape {a.shape}")
    if finite and not np.all(np.isfinite(a)):
        raise ValidationError(f"{name} must be finite, got {_describe(x)}")
    if low is not None and np.any(a < low):
        raise ValidationError(f"{name} must be >= {low}, got {_describe(x)}")
    return a


def as_points(x, name: str, *, allow_empty: bool = False) -> np.ndarray:
    """Validate an (M, 3) finite float array; a single (3,) point becomes (1, 3)."""
    a = _as_float_array(x, name, "an (M, 3) array of finite floats")
    if a.ndim == 1 and a.shape == (3,):
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValidationError(f"{name} must be (M, 3) finite, got {a.shape}")
    if not allow_empty and a.shape[0] == 0:
        raise ValidationError(f"{name} must hold at least one row, got (0, 3)")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
        raise ValidationError(f"{name} must be (M, 3) finite, row {bad} is {a[bad].tolist()}")
    return a


def _check_rigid(a: np.ndarray, name: str, tol: float) -> None:
    """Raise unless every (4, 4) in ``a`` (N, 4, 4) is a proper rigid transform.

    Column by column, not with batched matrix products: the estimators validate every
    batch of particles they are handed, and for 3 x 3 blocks elementwise arithmetic on
    (N,) arrays is several times faster than ``einsum`` and LAPACK's batched ``det``.
    """
    bottom = a[:, 3, :]
    if np.any(np.abs(bottom - np.array([0.0, 0.0, 0.0, 1.0])) > tol):
        i = int(np.flatnonzero(np.any(np.abs(bottom - [0, 0, 0, 1]) > tol, axis=1))[0])
        raise ValidationError(f"{name}[{i}] must have bottom row [0, 0, 0, 1], got {bottom[i].tolist()}")
    c0, c1, c2 = a[:, :3, 0], a[:, :3, 1], a[:, :3, 2]
    err = np.abs(np.einsum("ni,ni->n", c0, c0) - 1.0)
    for x, y, one in ((c1, c1, 1.0), (c2, c2, 1.0), (c0, c1, 0.0), (c0, c2, 0.0), (c1, c2, 0.0)):
        np.maximum(err, np.abs(np.einsum("ni,ni->n", x, y) - one), out=err)
    if np.any(err > tol):
        i = int(np.flatnonzero(err > tol)[0])
        raise ValidationError(
            f"{name}[{i}] rotation must be orthonormal (|R^T R - I| <= {tol:g}), deviation {err[i]:.3g}"
        )
    # the determinant as the triple product of the columns
    det = np.einsum("ni,ni->n", c0, np.cross(c1, c2))
    if np.any(np.abs(det - 1.0) > 10 * tol):
        i = int(np.flatnonzero(np.abs(det - 1.0) > 10 * tol)[0])
        raise ValidationError(
            f"{name}[{i}] rotation must have det +1 (a reflection is not a pose), got det {det[i]:.6g}"
        )


def as_poses(x, name: str = "poses", *, rigid: bool = True, tol: float = ORTHO_TOL,
             allow_empty: bool = True) -> np.ndarray:
    """Validate an (N, 4, 4) (or one (4, 4)) batch of rigid transforms; returns (N, 4, 4).

    With ``rigid`` (the default) each rotation block must be orthonormal with determinant
    +1 within ``tol`` and the bottom row must be ``[0, 0, 0, 1]``; reflections are rejected.
    """
    a = _as_float_array(x, name, "(N, 4, 4) homogeneous matrices")
    if a.shape == (4, 4):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ValidationError(f"{name} must be (N, 4, 4) homogeneous matrices, got {a.shape}")
    if not allow_empty and a.shape[0] == 0:
        raise ValidationError(f"{name} must hold at least one pose, got (0, 4, 4)")
    if not np.all(np.isfinite(a)):
        raise ValidationError(f"{name} must be finite")
    if rigid and a.shape[0]:
        _check_rigid(a, name, tol)
    return a


def as_pose(x, name: str = "pose", *, tol: float = ORTHO_TOL) -> np.ndarray:
    """Validate one (4, 4) rigid transform; returns a float64 (4, 4) array."""
    a = _as_float_array(x, name, "a (4, 4) homogeneous matrix")
    if a.shape != (4, 4):
        raise ValidationError(f"{name} must be a (4, 4) homogeneous matrix, got {a.shape}")
    return as_poses(a, name, tol=tol)[0]


def as_motion(x, name: str) -> tuple[float, float]:
    """A motion's size as (translation (m), rotation (rad)): two finite numbers >= 0, under
    1 m and pi rad."""
    try:
        a, b = (float(v) for v in x)
    except (TypeError, ValueError):
        raise ValidationError(f"{name} must be (translation (m), rotation (rad)), got {x!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and a >= 0 and b >= 0 and a < 1 and b < np.pi):
        raise ValidationError(f"{name} must be two finite numbers >= 0 (m, rad), got {x!r}")
    return a, b


def as_path(x, name: str = "path", *, must_exist: bool = True, kind: str = "file") -> Path:
    """A filesystem path (str or os.PathLike; not a bool, int or file descriptor).

    With ``must_exist`` the path must exist and be a regular file (``kind="file"``) or a
    directory (``kind="dir"``).
    """
    if isinstance(x, (bool, int, np.integer)) or not isinstance(x, (str, os.PathLike)):
        raise ValidationError(f"{name} must be a path (str or os.PathLike), got {type(x).__name__} {_describe(x)}")
    try:
        p = Path(os.fsdecode(os.fspath(x)))
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} is not a usable path: {exc}") from None
    if str(p) == "" or "\x00" in str(p):
        raise ValidationError(f"{name} must be a non-empty path without NUL bytes, got {_describe(x)}")
    if must_exist:
        if not p.exists():
            raise ValidationError(f"{name} does not exist: {p}")
        if kind == "file" and not p.is_file():
            raise ValidationError(f"{name} must be a regular file, got {p}" + (" (a directory)" if p.is_dir() else ""))
        if kind == "dir" and not p.is_dir():
            raise ValidationError(f"{name} must be a directory, got {p}")
    return p


def as_bytes(x, name: str) -> bytes:
    """Bytes from bytes, bytearray or memoryview (not a str, a number or a list)."""
    if isinstance(x, (bytes, bytearray, memoryview)):
        return bytes(x)
    raise ValidationError(f"{name} must be bytes, got {type(x).__name__} {_describe(x)}")


def as_bool(x, name: str) -> bool:
    """A flag: bool, numpy bool, or the integers 0 and 1."""
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (numbers.Integral, np.integer)) and int(x) in (0, 1):
        return bool(x)
    raise ValidationError(f"{name} must be True or False, got {type(x).__name__} {_describe(x)}")


def as_name(x, name: str, *, allow_none: bool = True) -> str | None:
    """A label: a str (or None when ``allow_none``)."""
    if x is None and allow_none:
        return None
    if not isinstance(x, str):
        expected = "a str or None" if allow_none else "a str"
        raise ValidationError(f"{name} must be {expected}, got {type(x).__name__} {_describe(x)}")
    return x


def as_instance(x, types, name: str, *, allow_none: bool = False, expected: str | None = None):
    """Return ``x`` if it is an instance of ``types`` (or None when ``allow_none``)."""
    if x is None and allow_none:
        return None
    if not isinstance(x, types):
        if expected is None:
            tt = types if isinstance(types, tuple) else (types,)
            expected = " or ".join(t.__name__ for t in tt)
        raise ValidationError(f"{name} must be a {expected}, got {type(x).__name__} {_describe(x)}")
    return x


def as_callable(x, name: str, *, allow_none: bool = False):
    """Return ``x`` if it can be called (or None when ``allow_none``)."""
    if x is None and allow_none:
        return None
    if not callable(x):
        raise ValidationError(f"{name} must be callable, got {type(x).__name__} {_describe(x)}")
    return x


def as_sequence(x, name: str, *, of=None, min_len: int = 0, max_len: int | None = None,
                expected: str | None = None) -> list:
    """A list, tuple or other finite iterable (not a str, bytes, dict or array scalar) as a list.

    With ``of`` (a type or tuple of types) every element must be an instance of it.
    """
    what = expected or ("a list" + (f" of {of.__name__ if isinstance(of, type) else 'items'}" if of else ""))
    if isinstance(x, (str, bytes, dict, set, frozenset)) or x is None or (
            isinstance(x, np.ndarray) and x.ndim == 0):
        raise ValidationError(f"{name} must be {what}, got {type(x).__name__} {_describe(x)}")
    try:
        items = list(x)
    except TypeError:
        raise ValidationError(f"{name} must be {what}, got {type(x).__name__} {_describe(x)}") from None
    if len(items) < min_len:
        raise ValidationError(f"{name} must hold at least {min_len} item(s), got {len(items)}")
    if max_len is not None and len(items) > max_len:
        raise ValidationError(f"{name} must hold at most {max_len} items, got {len(items)}")
    if of is not None:
        for i, e in enumerate(items):
            if not isinstance(e, of):
                raise ValidationError(f"{name}[{i}] must be {what.removeprefix('a list of ')}, "
                                      f"got {type(e).__name__} {_describe(e)}")
    return items


def as_mapping(x, name: str, *, of=None, min_len: int = 0, expected: str | None = None) -> dict:
    """A mapping (dict-like) as a dict; with ``of`` every value must be an instance of it."""
    from collections.abc import Mapping

    what = expected or "a dict"
    if not isinstance(x, Mapping):
        raise ValidationError(f"{name} must be {what}, got {type(x).__name__} {_describe(x)}")
    d = dict(x)
    if len(d) < min_len:
        raise ValidationError(f"{name} must hold at least {min_len} item(s), got {len(d)}")
    if of is not None:
        for k, v in d.items():
            if not isinstance(v, of):
                raise ValidationError(f"{name}[{k!r}] has the wrong type: {type(v).__name__} {_describe(v)}")
    return d
