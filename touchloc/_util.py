"""Small internal helpers shared by every subpackage (random state, validation, progress)."""

from __future__ import annotations

import sys
from typing import Iterable

import numpy as np

from .errors import ValidationError


def as_rng(rng=None) -> np.random.Generator:
    """Normalise ``rng`` (None, int seed or Generator) to a numpy Generator."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer)):
        return np.random.default_rng(rng)
    if isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    raise ValidationError(f"rng must be None, an int seed or a numpy Generator, got {type(rng).__name__}")


def as_points(x, name: str, *, allow_empty: bool = False) -> np.ndarray:
    """Validate an (M, 3) finite float array and return it as a float64 copy-free view."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be an (M, 3) array of finite floats: {exc}") from None
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


def as_poses(x, name: str = "poses") -> np.ndarray:
    """Validate an (N, 4, 4) (or (4, 4)) batch of rigid transforms; returns (N, 4, 4) float64."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be (N, 4, 4) homogeneous matrices: {exc}") from None
    if a.shape == (4, 4):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ValidationError(f"{name} must be (N, 4, 4) homogeneous matrices, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValidationError(f"{name} must be finite")
    return a


def progress(iterable: Iterable, *, total=None, desc=None, enabled=None, leave=False, interval: float = 5.0):
    """Wrap ``iterable`` in a tqdm bar when ``enabled`` (default: stderr is a TTY).

    With ``enabled=None`` and stderr not a TTY (a log file, a job scheduler), a plain
    line ``desc: i/total (elapsed)`` goes to stderr at most every ``interval`` seconds
    instead; ``enabled=False`` prints nothing.
    """
    if enabled is None and not sys.stderr.isatty():
        return _log_progress(iterable, total, desc, interval)
    if not enabled:
        return iterable
    from tqdm.auto import tqdm

    return tqdm(iterable, total=total, desc=desc, leave=leave)


def _log_progress(iterable, total, desc, interval):
    import time

    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)
    t0 = last = time.monotonic()
    for i, item in enumerate(iterable):
        now = time.monotonic()
        if now - last >= interval:
            last = now
            print(f"{desc or 'progress'}: {i}{'' if total is None else f'/{total}'} ({now - t0:.0f} s)",
                  file=sys.stderr, flush=True)
        yield item
