"""Dynamic neural fields over a periodic feature dimension (seed 000, eq. 1 and eq. 2).

A field holds an activation ``u`` at ``n`` sites spaced evenly over one period
(``2 pi`` for orientation) and evolves by eq. 1 of seed 000::

    tau du/dt = -u + h + S + sum_x' f(u(x')) w(|x - x'|)

with the sigmoid ``f(u) = 1 / (1 + exp(-beta u))`` and the lateral kernel::

    w(d) = c_exc exp(-d^2 / (2 sigma_exc^2)) - c_inh exp(-d^2 / (2 sigma_inh^2)) - c_glob

(short-range excitation, long-range inhibition and an optional global inhibition).
Distances ``d`` are periodic, so a peak at 359 degrees interacts with one at 1 degree.
The integral of eq. 1 is a sum over sites (``dx`` is one site), so ``c_exc``, ``c_inh`` and
``c_glob`` are weights per active site; widths are in radians. The convolution is computed
with the FFT (exact circular convolution).

Time is integrated with the explicit Euler method: ``u <- u + dt / tau * (...)``. The
step ``dt`` is a constructor argument; the :class:`~touchloc.dnf.OrientationTracker` uses
``dt = 1`` with time measured in samples (one sample of contact normals per step).

The memory trace (eq. 2, after [27] of seed 000) is::

    tau_l dP/dt = lambda_build (-P + f) f - lambda_decay P (1 - f)

so it builds up towards ``f`` where the field's output ``f`` is high (at rate
``lambda_build / tau_l``) and decays where the output is low (at rate
``lambda_decay / tau_l``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_count, as_float, as_float_array, as_instance, as_positive_float
from ..errors import ValidationError

__all__ = [
    "FieldParams",
    "sigmoid",
    "periodic_distance",
    "lateral_kernel",
    "circular_convolve",
    "lateral_inputs",
    "Field1D",
    "Field2D",
    "MemoryTrace",
    "expand",
    "diagonal_sum",
    "site_angles",
]

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class FieldParams:
    """Parameters of one field of eq. 1 (seed 000).

    Attributes
    ----------
    tau : float
        Time constant, in the unit of ``dt``.
    h : float
        Resting level (negative: no output without input).
    beta : float
        Slope of the sigmoid ``f(u) = 1 / (1 + exp(-beta u))``.
    c_exc, sigma_exc : float
        Strength (per active site) and width (rad) of the short-range excitation.
    c_inh, sigma_inh : float
        Strength (per active site) and width (rad) of the long-range inhibition.
    c_glob : float
        Global inhibition per active site (0 for none).
    """

    tau: float = 1.0
    h: float = -5.0
    beta: float = 4.0
    c_exc: float = 0.0
    sigma_exc: float = np.radians(3.0)
    c_inh: float = 0.0
    sigma_inh: float = np.radians(20.0)
    c_glob: float = 0.0

    def __post_init__(self):
        for name in ("tau", "beta", "sigma_exc", "sigma_inh"):
            as_positive_float(getattr(self, name), f"FieldParams.{name}")
        for name in ("h", "c_exc", "c_inh", "c_glob"):
            as_float(getattr(self, name), f"FieldParams.{name}")

    def with_(self, **changes) -> "FieldParams":
        """A copy with some parameters changed."""
        return replace(self, **changes)


def sigmoid(u, beta: float = 4.0):
    """Output non-linearity ``f(u) = 1 / (1 + exp(-beta u))`` (overflow-free, via tanh).

    Parameters
    ----------
    u : (...) float
        Activation.
    beta : float
        Slope.

    Returns
    -------
    (...) float
        Output in [0, 1], same dtype as ``u`` for float inputs. NaN in, NaN out: ``u`` is
        not scanned for NaN, since this runs in every field step.
    """
    if not (type(beta) is float and 0.0 < beta < math.inf):   # a plain float slope needs no more checks
        beta = as_positive_float(beta, "beta")
    u = np.asarray(u)
    if u.dtype.kind not in "biuf":
        raise ValidationError(f"u must be a real array, got dtype {u.dtype}")
    half = u.dtype.type(0.5) if u.dtype.kind == "f" else 0.5
    out = np.tanh(u * (half * beta))
    out *= half
    out += half
    return out


def site_angles(n: int, period: float = TWO_PI) -> np.ndarray:
    """Feature value of each of ``n`` sites: ``period * i / n``; returns (n,) float."""
    return np.arange(n) * (period / n)


def periodic_distance(n: int, period: float = TWO_PI) -> np.ndarray:
    """Periodic distance of site ``i`` from site 0, ``min(i, n - i) * period / n``; (n,) float."""
    i = np.arange(n)
    return np.minimum(i, n - i) * (period / n)


def lateral_kernel(n: int, params: FieldParams, period: float = TWO_PI) -> np.ndarray:
    """Lateral kernel ``w`` of eq. 1 sampled at the periodic distances of ``n`` sites.

    Returns
    -------
    (n,) float
        ``w[i]`` is the weight from a site to the site ``i`` places away (either side).
    """
    n = _check_n(n)
    params = as_instance(params, FieldParams, "params")
    period = as_positive_float(period, "period")
    d = periodic_distance(n, period)
    w = params.c_exc * np.exp(-0.5 * (d / params.sigma_exc) ** 2)
    if params.c_inh:
        w = w - params.c_inh * np.exp(-0.5 * (d / params.sigma_inh) ** 2)
    if params.c_glob:
        w = w - params.c_glob
    return w


def circular_convolve(x, kernel_fft, n: int) -> np.ndarray:
    """Circular convolution of (..., n) ``x`` with a kernel given by its rfft; (..., n).

    NaN in, NaN out: the arrays are not scanned for NaN (this runs in every field step).
    """
    n = _check_n(n)
    x = np.asarray(x)
    k = np.asarray(kernel_fft)
    if x.dtype.kind not in "biuf" or x.ndim < 1 or x.shape[-1] != n:
        raise ValidationError(f"x must be a real (..., {n}) array, got {x.dtype} {x.shape}")
    if k.dtype.kind not in "biufc" or k.shape[-1:] != (n // 2 + 1,):
        raise ValidationError(f"kernel_fft must be the rfft of a length-{n} kernel ({n // 2 + 1} values), got {k.shape}")
    return _convolve(x, kernel_fft, n)


def _convolve(x: np.ndarray, kernel_fft: np.ndarray, n: int) -> np.ndarray:
    """:func:`circular_convolve` without its checks, for the tracker's own arrays. Rows of a
    2-D ``x`` (with one kernel each, or one for all) are transformed in one call, which
    gives the same values as one call per row."""
    return np.fft.irfft(np.fft.rfft(x, axis=-1) * kernel_fft, n=n, axis=-1)


def lateral_inputs(fields) -> np.ndarray:
    """The lateral inputs of several :class:`Field1D` of one size, in one FFT.

    Row ``i`` equals ``fields[i].lateral()`` exactly; each can be handed to
    ``fields[i].step(stimulus, lateral=row)`` as long as that field's activation has not
    changed in between. A field step costs little more than its FFT, so a model that steps
    several fields per sample (the tracker steps five) saves most of that by batching.

    Parameters
    ----------
    fields : sequence of Field1D
        At least one, all with the same number of sites.

    Returns
    -------
    (len(fields), n) float
    """
    fields = list(fields) if isinstance(fields, (list, tuple)) else fields
    if not isinstance(fields, list) or not fields or not all(isinstance(f, Field1D) for f in fields):
        raise ValidationError(f"fields must be a non-empty list of Field1D, got {type(fields).__name__}")
    n = fields[0].n
    if any(f.n != n for f in fields):
        raise ValidationError(f"fields must all have the same number of sites, got {[f.n for f in fields]}")
    beta = fields[0].params.beta
    if all(f.params.beta == beta for f in fields):   # one sigmoid for all (the tracker's case)
        out = sigmoid(np.stack([f.u for f in fields]), beta)
    else:
        out = np.stack([f.output() for f in fields])
    return _convolve(out, np.stack([f._kernel_fft for f in fields]), n)


def _check_n(n) -> int:
    if not isinstance(n, (int, np.integer)) or isinstance(n, (bool, np.bool_)) or n < 3:
        raise ValidationError(f"number of sites must be an int >= 3, got {n!r}")
    return as_count(n, "number of sites", min=3, max=1_000_000, why="a field holds n (1-D) or n0 x n1 (2-D) sites")


class Field1D:
    """A periodic 1-D dynamic neural field (eq. 1 of seed 000), integrated with Euler steps.

    Parameters
    ----------
    n : int
        Number of sites over one period.
    params : FieldParams
        Time constant, resting level, sigmoid slope and kernel.
    dt : float
        Euler time step (same unit as ``params.tau``).
    period : float
        Length of the feature dimension (default ``2 pi``: orientation).

    Attributes
    ----------
    u : (n,) float
        Activation, initially at the resting level ``h``.
    """

    def __init__(self, n: int = 360, params: FieldParams | None = None, *, dt: float = 1.0,
                 period: float = TWO_PI):
        self.n = _check_n(n)
        self.params = FieldParams() if params is None else as_instance(params, FieldParams, "params")
        self.dt = as_positive_float(dt, "dt")
        self.period = as_positive_float(period, "period")
        self.kernel = lateral_kernel(self.n, self.params, self.period)
        self._kernel_fft = np.fft.rfft(self.kernel)
        self._rate = self.dt / self.params.tau
        self.u = np.full(self.n, self.params.h, dtype=np.float64)

    def reset(self) -> None:
        """Set the activation back to the resting level."""
        self.u.fill(self.params.h)

    def output(self) -> np.ndarray:
        """Field output ``f(u)``, (n,) float in [0, 1]."""
        return sigmoid(self.u, self.params.beta)

    def lateral(self, out: np.ndarray | None = None) -> np.ndarray:
        """Lateral input ``sum_x' f(u(x')) w(|x - x'|)``, (n,) float."""
        if out is None:
            return _convolve(self.output(), self._kernel_fft, self.n)
        return circular_convolve(out, self._kernel_fft, self.n)

    def step(self, stimulus=0.0, lateral=None) -> np.ndarray:
        """Advance one Euler step of eq. 1 with external input ``stimulus``.

        Parameters
        ----------
        stimulus : float or (n,) float
            External input ``S``. Checked for type and shape; NaN in, NaN out: it is not
            scanned for NaN (this runs in every step).
        lateral : None or (n,) float
            The lateral input of the current activation if it was already computed (by
            :func:`lateral_inputs`, for several fields at once); None computes it here.

        Returns
        -------
        (n,) float
            The output ``f(u)`` after the step.
        """
        p = self.params
        stimulus = _stimulus(stimulus, (self.n,))
        if lateral is None:
            lateral = self.lateral()
        elif not (isinstance(lateral, np.ndarray) and lateral.dtype.kind == "f" and lateral.shape == (self.n,)):
            raise ValidationError(f"lateral must be a float array of shape ({self.n},) (or None), got "
                                  f"{type(lateral).__name__} {getattr(lateral, 'shape', '')}")
        du = -self.u + p.h + stimulus + lateral
        self.u += self._rate * du
        return self.output()

    def peak_position(self, threshold: float = 0.5):
        """Circular centroid (rad) of the sites whose output exceeds ``threshold``, or None."""
        threshold = as_float(threshold, "threshold")
        f = self.output()
        w = np.where(f > threshold, f, 0.0)
        if not w.any():
            return None
        ang = site_angles(self.n, self.period) * (TWO_PI / self.period)
        z = np.sum(w * np.exp(1j * ang))
        return float(np.angle(z) % TWO_PI) * self.period / TWO_PI


class Field2D:
    """A 2-D dynamic neural field, periodic in both dimensions (eq. 1 with x in R^2).

    The lateral kernel is ``c_exc g_exc(dx) g_exc(dy) - c_inh g_inh(dx) g_inh(dy) - c_glob``
    with Gaussians ``g(d) = exp(-d^2 / (2 sigma^2))`` of periodic distance: every term is
    separable. Two ways to compute the lateral input are offered:

    ``method="fft"``
        exact circular 2-D convolution of the whole output;
    ``method="active"`` (default)
        only the *active block* - the rows and columns that hold a site with output above
        ``eps`` - contributes: the separable Gaussian terms are applied to it as two small
        matrix products, evaluated where they exceed 1e-8 of their peak, and the global
        term uses the block's sum. Every left-out site has output below ``eps``, so the
        lateral input differs from the exact one by at most
        ``eps * (c_exc * G_exc**2 + c_inh * G_inh**2 + c_glob * n0 * n1)`` with
        ``G = sum_d g(d)`` (about ``sqrt(2 pi) sigma`` in sites): below 1e-3 for the
        tracker's comparison field with ``eps = 1e-6``. A step then costs a few passes
        over the field instead of a 2-D FFT; with ``dt == tau`` and an input of two
        expanded 1-D fields it needs no pass at all (the activation is kept as the two
        1-D inputs plus a patch and formed only when :attr:`u` or :meth:`output` is
        read). When more than ``max_active`` rows or columns are active it falls back to
        the FFT.

    Parameters
    ----------
    shape : (int, int)
        Sites along each dimension.
    params : FieldParams
        Time constant, resting level, sigmoid slope and kernel (widths in rad).
    dt : float
        Euler time step.
    period : float
        Length of both dimensions.
    dtype : numpy dtype
        float32 (default, fast) or float64.
    method : {"active", "fft"}
    eps : float
        Output below which a site counts as inactive for ``method="active"``.
    max_active : int
        Largest number of active rows or columns handled by ``method="active"``.

    Attributes
    ----------
    u : shape float
        Activation, initially at the resting level.
    """

    def __init__(self, shape=(360, 360), params: FieldParams | None = None, *, dt: float = 1.0,
                 period: float = TWO_PI, dtype=np.float32, method: str = "active", eps: float = 1e-6,
                 max_active: int = 96):
        if not isinstance(shape, (tuple, list)) or len(shape) != 2:
            raise ValidationError(f"shape must be (n0, n1), got {shape!r}")
        self.shape = (_check_n(shape[0]), _check_n(shape[1]))
        if self.shape[0] * self.shape[1] > 10_000_000:
            raise ValidationError(f"shape {self.shape} holds more than 1e7 sites (memory: several arrays of that size)")
        self.params = FieldParams() if params is None else as_instance(params, FieldParams, "params")
        if not isinstance(method, str) or method not in ("active", "fft"):
            raise ValidationError(f"method must be 'active' or 'fft', got {method!r}")
        dt = as_positive_float(dt, "dt")
        period = as_positive_float(period, "period")
        eps = as_float(eps, "eps", low=0.0, high=0.5, low_open=True, high_open=True)
        max_active = as_count(max_active, "max_active", min=0)
        try:
            if np.dtype(dtype).kind != "f":
                raise TypeError
        except TypeError:
            raise ValidationError(f"dtype must be a float dtype (float32 or float64), got {dtype!r}") from None
        self.method = method
        self.dtype = np.dtype(dtype)
        self.dt = float(dt)
        self.period = float(period)
        self.eps = float(eps)
        self.max_active = int(max_active)
        p = self.params
        self._rate = self.dt / p.tau
        self._h = self.dtype.type(p.h)
        terms = []
        for c, s in ((p.c_exc, p.sigma_exc), (-p.c_inh, p.sigma_inh)):
            if c:
                g0 = np.exp(-0.5 * (periodic_distance(self.shape[0], period) / s) ** 2)
                g1 = np.exp(-0.5 * (periodic_distance(self.shape[1], period) / s) ** 2)
                terms.append((c, g0, g1))
        self._c_glob = p.c_glob
        k = sum(c * np.outer(g0, g1) for c, g0, g1 in terms) if terms else np.zeros(self.shape)
        self.kernel = k - p.c_glob
        self._kernel_fft = np.fft.rfft2(self.kernel)
        # circulant matrices M[i, j] = g[(i - j) % n] and the reach (in sites) beyond which
        # a term is below 1e-8 of its peak
        self._circ = [(self.dtype.type(c), _circulant(g0).astype(self.dtype), _circulant(g1).astype(self.dtype),
                       _reach(g0), _reach(g1)) for c, g0, g1 in terms]
        # the same for the compiled step: each term's Gaussians (zero beyond their reach; the
        # second times the term's strength) and the largest reaches
        self._ridge_terms = (
            np.array([m0[:, 0] for _, m0, _, _, _ in self._circ], dtype=self.dtype).reshape(-1, self.shape[0]),
            np.array([m1[:, 0] * c for c, _, m1, _, _ in self._circ], dtype=self.dtype).reshape(-1, self.shape[1]),
            max([r0 for *_, r0, _ in self._circ], default=0), max([r1 for *_, r1 in self._circ], default=0))
        # f(u) > eps  <=>  u > u_eps
        self._u_eps = self.dtype.type(np.log(self.eps / (1.0 - self.eps)) / p.beta)
        self._u = np.full(self.shape, p.h, dtype=self.dtype)
        self._buf = np.empty(self.shape, dtype=self.dtype)
        self._out = None
        self._block = None
        # after a step driven by two ridges, u = a[:, None] + b[None, :] plus a patch on
        # the window (W0, W1); kept in this form until someone reads u
        self._lazy = None

    # -- state -------------------------------------------------------------------------
    @property
    def u(self) -> np.ndarray:
        """Activation, shape float. Assign a new array (``field.u = a``) rather than
        writing into it in place, so that cached outputs are recomputed."""
        if self._lazy is not None:
            a, b, W0, W1, P = self._lazy
            np.add(a[:, None], b[None, :], out=self._u)
            if W0.size:
                self._u[np.ix_(W0, W1)] += P
            self._lazy = None
        return self._u

    @u.setter
    def u(self, value) -> None:
        value = np.asarray(value, dtype=self.dtype)
        if value.shape != self.shape:
            raise ValidationError(f"u must have shape {self.shape}, got {value.shape}")
        self._u = value.copy()
        self._out = self._block = self._lazy = None

    def reset(self) -> None:
        """Set the activation back to the resting level."""
        self._u.fill(self._h)
        self._out = self._block = self._lazy = None

    def output(self) -> np.ndarray:
        """Field output ``f(u)``, shape float in [0, 1] (computed on demand; read-only)."""
        if self._out is None:
            self._out = sigmoid(self.u, self.params.beta)
            self._out.flags.writeable = False
        return self._out

    def active_block(self):
        """The active block: rows, columns and their output.

        Returns
        -------
        rows : (r,) int
            Rows holding a site with output above ``eps``.
        cols : (c,) int
            Columns holding such a site within those rows.
        out : (r, c) float
            ``f(u)`` on the block; every site outside it has output below ``eps``.
        """
        if self._block is None:
            u = self.u
            rows = np.flatnonzero(u.max(axis=1) > self._u_eps)
            if rows.size:
                cols = np.flatnonzero(u[rows].max(axis=0) > self._u_eps)
                block = sigmoid(u[np.ix_(rows, cols)], self.params.beta)
            else:
                cols = rows
                block = np.zeros((0, 0), dtype=self.dtype)
            self._block = (rows, cols, block)
        return self._block

    # -- dynamics ----------------------------------------------------------------------
    def _use_active(self, method=None) -> bool:
        if method is not None and (not isinstance(method, str) or method not in ("active", "fft")):
            raise ValidationError(f"method must be 'active', 'fft' or None, got {method!r}"[:200])
        if (method or self.method) != "active":
            return False
        rows, cols, _ = self.active_block()
        return rows.size <= self.max_active and cols.size <= self.max_active

    def _add_block_lateral(self, res: np.ndarray) -> None:
        """Add the Gaussian terms of the active block's lateral input into ``res``."""
        rows, cols, block = self.active_block()
        if rows.size == 0:
            return
        for c, m0, m1, r0, r1 in self._circ:
            w0 = _kernels().dilate(rows, r0, self.shape[0])
            w1 = _kernels().dilate(cols, r1, self.shape[1])
            part = (m0[np.ix_(w0, rows)] @ block) @ (m1[np.ix_(cols, w1)] * c)
            # the windows are a few contiguous runs: add run by run with slices
            runs0, runs1 = _runs(w0), _runs(w1)
            if len(runs0) * len(runs1) > 16:
                res[np.ix_(w0, w1)] += part
                continue
            for a0, a1, p0 in runs0:
                for b0, b1, q0 in runs1:
                    res[a0:a1, b0:b1] += part[p0:p0 + a1 - a0, q0:q0 + b1 - b0]

    def lateral(self, method: str | None = None) -> np.ndarray:
        """Lateral input of eq. 1 for the current activation, shape float (see the class
        notes for the methods)."""
        if self._use_active(method):
            block = self.active_block()[2]
            res = np.full(self.shape, -self._c_glob * float(block.sum(dtype=np.float64)), dtype=self.dtype)
            self._add_block_lateral(res)
            return res
        lat = np.fft.irfft2(np.fft.rfft2(self.output()) * self._kernel_fft, s=self.shape)
        return lat.astype(self.dtype, copy=False)

    def step(self, stimulus=0.0) -> None:
        """Advance one Euler step of eq. 1 with external input ``stimulus``.

        Parameters
        ----------
        stimulus : float, array broadcastable to ``shape``, or tuple of them
            External input; a tuple is summed term by term without forming the full sum
            first, e.g. ``(a[:, None], b[None, :])`` for two expanded 1-D fields.
            Checked for type and shape; NaN in, NaN out: not scanned for NaN.

        Use :meth:`output` or :meth:`active_block` for the output after the step.
        """
        terms = [_stimulus(t, self.shape) for t in (stimulus if isinstance(stimulus, tuple) else (stimulus,))]
        ridges = (len(terms) == 2 and np.ndim(terms[0]) == 2 and np.ndim(terms[1]) == 2
                  and np.shape(terms[0]) == (self.shape[0], 1) and np.shape(terms[1]) == (1, self.shape[1]))
        if ridges and self._rate == 1.0 and self._use_active():
            self._step_ridges(np.asarray(terms[0], self.dtype)[:, 0], np.asarray(terms[1], self.dtype)[0])
            return
        u = self.u
        new = self._buf
        if self._use_active():
            const = self._h - self.dtype.type(self._c_glob * float(self.active_block()[2].sum(dtype=np.float64)))
            if ridges:
                np.add(terms[0] + const, terms[1], out=new)      # one pass for two ridges
            else:
                new.fill(const)
                for term in terms:
                    new += term
            self._add_block_lateral(new)
        else:
            new[...] = self.lateral()
            new += self._h
            for term in terms:
                new += term
        if self._rate == 1.0:            # u <- h + S + lateral
            self._buf, self._u = u, new
        else:                            # u <- u + rate (-u + h + S + lateral)
            new -= u
            new *= self.dtype.type(self._rate)
            u += new
        self._out = self._block = None

    def _step_ridges(self, a: np.ndarray, b: np.ndarray) -> None:
        """Euler step with ``dt = tau`` and input ``a[:, None] + b[None, :]`` (active method).

        The new activation is ``h + a(x) + b(y) + lateral``, where the lateral input of the
        active block is non-zero only on a window of rows ``W0`` and columns ``W1``:
        ``u = a'[:, None] + b[None, :] + P`` on the window. Row and column maxima, and so
        the new active block, follow from the 1-D arrays and the window alone; the full
        field is formed only when ``u`` or ``output()`` is read.
        """
        rows0, cols0, block0 = self.active_block()
        a = a + (self._h - self.dtype.type(self._c_glob * float(block0.sum(dtype=np.float64))))
        W0, W1, P, R, C, U = _kernels().ridge_step(a, b, rows0, cols0, block0, *self._ridge_terms, self._u_eps)
        block = sigmoid(U, self.params.beta) if R.size else U
        self._lazy = (a, b, W0, W1, P)
        self._block = (R, C, block)
        self._out = None


def _kernels():
    """The compiled step (imported on first use: numba loads only when a 2-D field steps)."""
    from . import _kernels as k
    return k


def _reach(g: np.ndarray) -> int:
    """Largest site offset at which the periodic Gaussian ``g`` is still above 1e-8."""
    big = np.flatnonzero(g[: g.shape[0] // 2 + 1] > 1e-8)
    return int(big[-1])


def _runs(idx: np.ndarray):
    """Contiguous runs of sorted unique ``idx``: list of (start, stop, offset in idx)."""
    if idx.size == 0:
        return []
    br = np.flatnonzero(np.diff(idx) != 1) + 1
    starts = np.concatenate(([0], br))
    stops = np.concatenate((br, [idx.size]))
    return [(int(idx[a]), int(idx[b - 1]) + 1, int(a)) for a, b in zip(starts, stops)]


def _circulant(g: np.ndarray) -> np.ndarray:
    """``M[i, j] = g[(i - j) % n]``, with the entries beyond :func:`_reach` set to 0."""
    n = g.shape[0]
    i = np.arange(n)
    g = np.where(periodic_distance(n, n) <= _reach(g), g, 0.0)
    return g[(i[:, None] - i[None, :]) % n]


class MemoryTrace:
    """Memory trace of eq. 2 (seed 000) over the sites of a field.

    Parameters
    ----------
    n : int
        Number of sites.
    tau : float
        Time constant ``tau_l``.
    build, decay : float
        Rates ``lambda_build`` and ``lambda_decay``.
    dt : float
        Euler time step.

    Attributes
    ----------
    P : (n,) float
        Strength of the trace, in [0, 1], initially 0.
    """

    def __init__(self, n: int = 360, *, tau: float = 1.0, build: float = 0.05, decay: float = 0.001,
                 dt: float = 1.0):
        self.n = _check_n(n)
        tau, dt = as_positive_float(tau, "tau"), as_positive_float(dt, "dt")
        build, decay = as_float(build, "build", low=0.0), as_float(decay, "decay", low=0.0)
        if dt * max(build, decay) / tau > 1.0:
            raise ValidationError(f"dt * max(build, decay) / tau must be <= 1 for a stable Euler step, "
                                  f"got {dt * max(build, decay) / tau:g}")
        self.tau, self.build, self.decay, self.dt = float(tau), float(build), float(decay), float(dt)
        self.P = np.zeros(self.n)

    def reset(self) -> None:
        """Erase the trace."""
        self.P.fill(0.0)

    def step(self, f, decay_scale=None) -> np.ndarray:
        """One Euler step of eq. 2 given the field output ``f`` ((n,) in [0, 1]); returns ``P``.

        ``decay_scale`` (optional, a number or (n,) >= 0) multiplies the decay per site, for
        variants of the trace whose forgetting depends on something else (the study script
        ``benchmarks/study_dnf_variants.py`` uses it); the tracker does not.

        ``f`` is checked for its shape only; NaN in, NaN out: it is not scanned for NaN (this
        runs in every step of the tracker). ``decay_scale`` must be finite and >= 0."""
        P = self.P
        if not isinstance(f, np.ndarray) or f.dtype.kind != "f":
            f = as_float_array(f, "f", finite=False)
        if f.shape != P.shape:
            raise ValidationError(f"f must be the field output, shape {P.shape}, got {f.shape}")
        forget = self.decay * P * (1.0 - f)
        if decay_scale is not None:
            decay_scale = as_float_array(decay_scale, "decay_scale", low=0.0, expected="a finite scale >= 0 (or one per site)")
            if decay_scale.shape not in ((), P.shape):
                raise ValidationError(f"decay_scale must be a number or one per site, shape {P.shape}, "
                                      f"got {decay_scale.shape}")
            forget = forget * decay_scale
        P += (self.dt / self.tau) * (self.build * (f - P) * f - forget)
        return P


def _stimulus(s, shape):
    """An external input: a float or a float array broadcastable to ``shape`` (checked for
    type and shape only; NaN in, NaN out)."""
    if type(s) is float or (isinstance(s, (int, np.floating, np.integer)) and not isinstance(s, (bool, np.bool_))):
        return s
    if not (isinstance(s, np.ndarray) and s.dtype.kind == "f"):
        s = as_float_array(s, "stimulus", finite=False)
    sh = s.shape
    if sh != shape and (len(sh) > len(shape) or any(a != 1 and a != b for a, b in zip(sh[::-1], shape[::-1]))):
        raise ValidationError(f"stimulus must be a number or an array broadcastable to {tuple(shape)}, "
                              f"got shape {sh}")
    return s


def expand(field, n_other: int, axis: int = 0) -> np.ndarray:
    """Expand a 1-D field along a second dimension (a read-only broadcast view).

    Parameters
    ----------
    field : (n,) float
    n_other : int
        Length of the new dimension.
    axis : {0, 1}
        Which axis of the result ``field`` runs along: 0 gives ``out[i, j] = field[i]``
        (shape (n, n_other)); 1 gives ``out[i, j] = field[j]`` (shape (n_other, n)), i.e.
        the transposed expansion.
    """
    field = np.asarray(field)
    if field.ndim != 1:
        raise ValidationError(f"field must be 1-D, got shape {field.shape}")
    n_other = as_count(n_other, "n_other", max=2**31 - 1, why="numpy's largest dimension")
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)):
        raise ValidationError(f"axis must be 0 or 1, got {axis!r}")
    if axis == 0:
        return np.broadcast_to(field[:, None], (field.shape[0], n_other))
    if axis == 1:
        return np.broadcast_to(field[None, :], (n_other, field.shape[0]))
    raise ValidationError(f"axis must be 0 or 1, got {axis!r}")


def diagonal_sum(F) -> np.ndarray:
    """Sum a square 2-D field along its diagonals with periodic indices.

    ``out[d] = sum_i F[i, (i + d) % n]``: a peak at ``(x, y)`` lands at ``d = y - x``
    (mod n), i.e. the second dimension encoded relative to the first.

    Parameters
    ----------
    F : (n, n) float

    Returns
    -------
    (n,) float
        NaN in, NaN out: ``F`` is not scanned for NaN.
    """
    F = np.asarray(F)
    if F.dtype.kind not in "biuf":
        raise ValidationError(f"F must be a real array, got dtype {F.dtype}")
    if F.ndim != 2 or F.shape[0] != F.shape[1]:
        raise ValidationError(f"F must be a square 2-D array, got shape {F.shape}")
    n = F.shape[0]
    ext = np.concatenate([F, F], axis=1)
    s0, s1 = ext.strides
    view = np.lib.stride_tricks.as_strided(ext, shape=(n, n), strides=(s0 + s1, s1), writeable=False)
    return view.sum(axis=0, dtype=np.float64)
