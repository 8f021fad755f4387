"""Small internal helpers shared by every subpackage (random state, validation, progress)."""

from __future__ import annotations

import contextlib
import sys
import threading
from typing import Iterable

import numpy as np

from ._validate import as_bool
from ._validate import as_points, as_poses  # noqa: F401  (one implementation, re-exported)
from .errors import ValidationError


def as_rng(rng=None) -> np.random.Generator:
    """Normalise ``rng`` (None, int seed or Generator) to a numpy Generator."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer)) and not isinstance(rng, (bool, np.bool_)):
        if rng is not None and rng < 0:
            raise ValidationError(f"rng seed must be a non-negative integer, got {rng}")
        return np.random.default_rng(rng)
    if isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    raise ValidationError(f"rng must be None, an int seed or a numpy Generator, got {type(rng).__name__}")


def logsumexp1d(a) -> float:
    """scipy's ``logsumexp`` of a 1-D float array, in its arithmetic (the same number bit for
    bit: the maxima taken out of the sum and counted, ``log1p`` of the rest), without its
    array-API overhead (a fifth of a millisecond a call; particle filters call it several
    times per step). Non-finite maxima go to scipy."""
    top = a.max()
    if not np.isfinite(top):
        from scipy.special import logsumexp

        return float(logsumexp(a))
    mask = a == top
    m = float(np.count_nonzero(mask))
    s = np.exp(np.where(mask, -np.inf, a) - top).sum()
    if s != 0:
        s = s / m
    return float(np.log1p(s) + np.log(m) + top)


def progress(iterable: Iterable, *, total=None, desc=None, enabled=None, leave=False, interval: float = 5.0):
    """Wrap ``iterable`` in a tqdm bar when ``enabled`` (default: stderr is a TTY).

    With ``enabled=None`` and stderr not a TTY (a log file, a job scheduler), a plain
    line ``desc: i/total (elapsed)`` goes to stderr at most every ``interval`` seconds
    instead; ``enabled=False`` prints nothing.
    """
    if enabled is not None:
        enabled = as_bool(enabled, "progress")
    if enabled is None and not sys.stderr.isatty():
        return _log_progress(iterable, total, desc, interval)
    if not enabled:
        return iterable
    from tqdm.auto import tqdm

    return tqdm(iterable, total=total, desc=desc, leave=leave)


def progress_keyword(progress, progress_bar, where: str):
    """The checked ``progress=`` flag of ``where``, which took it as ``progress_bar=`` before.

    ``progress_bar=`` still works, with a ``DeprecationWarning``; giving both is a
    ``ValidationError``. Returns None (the default: a bar when stderr is a terminal),
    True or False.
    """
    if progress_bar is not None:
        if progress is not None:
            raise ValidationError(f"{where}: give progress= only (progress_bar= is its old name)")
        import warnings

        warnings.warn(f"{where}(progress_bar=...) is deprecated; use progress=", DeprecationWarning,
                      stacklevel=external_stacklevel())
        progress = progress_bar
    return None if progress is None else as_bool(progress, "progress")


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


def external_stacklevel() -> int:
    """``stacklevel`` for a ``warnings.warn`` made by the caller of this function that names
    the first frame outside touchloc: the user's call, however many of touchloc's own frames
    (wrappers, generators) lie between."""
    import os

    pkg = os.path.dirname(os.path.abspath(__file__)) + os.sep
    f, level = sys._getframe(1), 1
    while f is not None and os.path.abspath(f.f_code.co_filename).startswith(pkg):
        f, level = f.f_back, level + 1
    return level


# -- BLAS threads ------------------------------------------------------------------------
#: environment variable: the BLAS threads the mapping package's work may use ("0": no limit)
BLAS_THREADS_ENV = "TOUCHLOC_BLAS_THREADS"
_BLAS_CONTROLLER = None          # threadpoolctl's controller, made on first use
_BLAS_INSIDE = threading.local()  # .on: this thread is inside a limited call


def _blas_limit():
    """The BLAS thread limit for the mapping package's work: 1 unless ``TOUCHLOC_BLAS_THREADS``
    says otherwise (a positive integer; 0 or an empty value: leave BLAS as it is)."""
    import os

    raw = os.environ.get(BLAS_THREADS_ENV, "1").strip()
    try:
        n = int(raw) if raw else 0
    except ValueError:
        raise ValidationError(f"{BLAS_THREADS_ENV} must be a whole number of threads (0: no limit), "
                              f"got {raw!r}") from None
    if n < 0:
        raise ValidationError(f"{BLAS_THREADS_ENV} must be >= 0 (0: no limit), got {n}")
    return n


@contextlib.contextmanager
def _blas_limited():
    """The body runs with BLAS limited to :func:`_blas_limit` threads; nested uses keep it."""
    global _BLAS_CONTROLLER
    n = _blas_limit()
    if n == 0 or getattr(_BLAS_INSIDE, "on", False):
        yield
        return
    if _BLAS_CONTROLLER is None:
        import scipy.linalg  # noqa: F401  (scipy's own BLAS, loaded before the controller looks)
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER = ThreadpoolController()
    _BLAS_INSIDE.on = True
    try:
        with _BLAS_CONTROLLER.limit(limits=n, user_api="blas"):
            yield
    finally:
        _BLAS_INSIDE.on = False


def blas_threads(fn):
    """Decorator: run ``fn`` with BLAS limited to :func:`_blas_limit` threads (threadpoolctl).

    The shape map's work is many mid-sized products and triangular solves (n observations
    by a dozen new ones) and kernel matrices of a few thousand rows, where a second BLAS
    thread mostly waits: measured on 2 cores with OpenBLAS on both, a tactile SLAM update
    took 1.6-5x longer than on one thread and a static map's update 1.7-10x (docs/benchmarks.md,
    "BLAS threads"). The estimators' work is compiled kernels on numba's threads with small
    products between them, and an idle BLAS pool's threads, which spin for a while after
    each product, took the cores from those kernels: a 5-contact Scaling Series localisation
    of the mug ran 2.1x longer with BLAS's default threads than with one (docs/benchmarks.md,
    "BLAS threads"). The limit is set through threadpoolctl while the call runs, and the
    setting found on entry is restored after; nested calls keep it. Limited calls that
    overlap in several Python threads are not coordinated: each restores what it found (and
    OpenBLAS 0.3.30 was seen to keep a thread's own setting once that thread had set one).
    A generator function is limited while it runs, each time it is resumed, and not between
    its items.
    """
    import functools
    import inspect

    if inspect.isgeneratorfunction(fn):
        @functools.wraps(fn)
        def gen_wrapper(*args, **kwargs):
            it = fn(*args, **kwargs)
            value = None
            try:
                while True:
                    with _blas_limited():
                        try:
                            item = it.send(value)
                        except StopIteration as stop:
                            return stop.value
                    value = yield item
            finally:
                it.close()

        return gen_wrapper

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with _blas_limited():
            return fn(*args, **kwargs)

    return wrapper
