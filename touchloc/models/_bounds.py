"""Lower bounds of the proximity cost d_M^2 from a table, for pruning without evaluating.

The joint cost of an object-frame query (x, n) is J(x, n) = min_f |x - x_f|^2 + w |n - n_f|^2
(closest point x_f on face f, face normal n_f, w = sigma_pos^2 / sigma_nor^2). Its root is
1-Lipschitz in the metric sqrt(|dx|^2 + w |dn|^2): for each face the root is the norm of a
vector whose parts are 1-Lipschitz in x and in sqrt(w) n, and a minimum keeps that. So one
exact value sqrt(J(c, b)) at a cell centre c and a normal direction b bounds the cost of
every query near them from below:

    J(x, n) >= max(0, sqrt(J(c, b)) - sqrt(|x - c|^2 + w |n - b|^2))^2.

The table holds sqrt(J) at the centres of a grid of cells around the mesh (a twelfth of
its largest extent, out to half an extent beyond it) for the centre directions of a cube
map's bins (three by three per face); a query uses its cell and its normal's bin. Beyond
the grid the bound is the squared distance to the mesh's bounding box. Position-only costs
use one "direction" and w = 0.

Scaling Series uses the bound to drop particles whose bound already exceeds the prune
threshold (no closest-face search at all) and to stop a particle's evaluation as soon as
its exact costs so far plus the bounds of its remaining contacts reach the threshold. At
its wide scales it scores particles on the bounds alone (``ScalingSeries(bound_scales=)``):
a bound is the cost dilated by at most twice the table's slack (:attr:`CostBound.slack`),
no wider than the scale's own radius there.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._cache import numba_cache_enabled
from .._util import progress
from ._kernels import _SERIAL as _SERIAL_PIPELINE
from ._kernels import PARALLEL_MIN, kernel_array, object_frame, query_joint

__all__ = ["CostBound", "build_cost_bound", "lower_costs"]

_NB = dict(cache=numba_cache_enabled(__file__), nogil=True)
#: the one-thread kernel through numba's parallel pipeline, as the likelihood's (see
#: ``_kernels._SERIAL``): 25-33 ns a lookup instead of 55-68 (one thread, 3000 poses x 30
#: contacts near the truth, mug and lemon)
_SERIAL = dict(_SERIAL_PIPELINE, cache=_NB["cache"])

#: cells per largest extent, and the grid's reach beyond the mesh (in largest extents)
CELLS_PER_EXTENT = 12
MARGIN = 0.5
#: bins per cube-map face edge (6 x BINS^2 normal directions)
BINS = 3
#: every bound is scaled by this, so that rounding cannot lift it over the cost it bounds
SAFETY = 1.0 - 1e-6


@dataclass(frozen=True)
class CostBound:
    """A table of sqrt(J) at cell centres and normal directions (see the module)."""

    lo: np.ndarray  # (3,) corner of cell 0
    h: float  # cell size (m)
    shape: np.ndarray  # (3,) cells per axis
    root: np.ndarray  # (cells, bins) float32, sqrt(J) rounded down
    dirs: np.ndarray  # (bins, 3) unit directions (one row of zeros: position only)
    box_lo: np.ndarray  # (3,) the mesh's bounding box
    box_hi: np.ndarray
    w: float  # normal weight (0: position only)

    @property
    def slack(self) -> float:
        """The largest distance (m, in the metric sqrt(|dx|^2 + w |dn|^2)) from a query on
        the grid to the cell centre and bin direction its bound is read at: the half
        diagonal of a cell and the widest bin's reach. With D = sqrt(J) the distance to the
        surface's points (x_f, n_f) in that metric and r a query's distance from its centre,
        D(centre) - r >= D(query) - 2 r, so the bound lies between the query's cost and that
        cost dilated by 2 r <= 2 slack (the smallest cost within 2 r of the query)."""
        half_diagonal = 0.5 * np.sqrt(3.0) * self.h
        return float(np.sqrt(half_diagonal**2 + self.w * bin_reach(BINS) ** 2))


def cube_map_dirs(b: int) -> np.ndarray:
    """(6 b^2, 3) unit directions at the centres of a cube map's bins (face-major, the
    order of :func:`_bin_of`)."""
    t = (np.arange(b) + 0.5) / b * 2.0 - 1.0
    u, v = np.meshgrid(t, t, indexing="ij")
    out = []
    for ax in range(3):
        o0, o1 = [a for a in range(3) if a != ax]
        for sign in (1.0, -1.0):
            d = np.zeros((b * b, 3))
            d[:, ax] = sign
            d[:, o0] = u.ravel()
            d[:, o1] = v.ravel()
            out.append(d)
    d = np.vstack(out)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@functools.lru_cache(maxsize=None)
def bin_reach(b: int) -> float:
    """The largest chord |n - d| between a unit direction n and the centre direction d of
    its cube-map bin (b bins per face edge): a bin's sides are great circles, so its
    farthest points from the centre are its corners."""
    dirs = cube_map_dirs(b).reshape(6, b, b, 3)
    t = np.linspace(-1.0, 1.0, b + 1)
    reach = 0.0
    for f, (ax, sign) in enumerate((a, s) for a in range(3) for s in (1.0, -1.0)):
        o0, o1 = [a for a in range(3) if a != ax]
        for i in range(b):
            for j in range(b):
                for u in t[i:i + 2]:
                    for v in t[j:j + 2]:
                        c = np.zeros(3)
                        c[ax], c[o0], c[o1] = sign, u, v
                        reach = max(reach, float(np.linalg.norm(c / np.linalg.norm(c) - dirs[f, i, j])))
    return reach


@nb.njit(inline="always", **_NB)
def _bin_of(nx, ny, nz, b):
    """The cube-map bin of a direction (any length; its largest component's face)."""
    ax, ay, az = abs(nx), abs(ny), abs(nz)
    if ax >= ay and ax >= az:
        face, m, u, v, neg = 0, ax, ny, nz, nx < 0
    elif ay >= az:
        face, m, u, v, neg = 1, ay, nx, nz, ny < 0
    else:
        face, m, u, v, neg = 2, az, nx, ny, nz < 0
    if m == 0.0:
        return 0
    iu = min(max(int((u / m + 1.0) * 0.5 * b), 0), b - 1)
    iv = min(max(int((v / m + 1.0) * 0.5 * b), 0), b - 1)
    return (2 * face + (1 if neg else 0)) * b * b + iu * b + iv


@nb.njit(inline="always", **_NB)
def _bound_one(px, py, pz, nx, ny, nz, use_n, lo, h, inv_h, shape, root, dirs, box_lo, box_hi, w, b):
    """A lower bound of the cost (m^2) of one object-frame query."""
    # any cell's centre gives a valid bound: the reciprocal's rounding at a cell's face is harmless
    ix = int(np.floor((px - lo[0]) * inv_h))
    iy = int(np.floor((py - lo[1]) * inv_h))
    iz = int(np.floor((pz - lo[2]) * inv_h))
    if not (0 <= ix < shape[0] and 0 <= iy < shape[1] and 0 <= iz < shape[2]):
        dx = max(box_lo[0] - px, 0.0, px - box_hi[0])
        dy = max(box_lo[1] - py, 0.0, py - box_hi[1])
        dz = max(box_lo[2] - pz, 0.0, pz - box_hi[2])
        return (dx * dx + dy * dy + dz * dz) * SAFETY
    cell = (ix * shape[1] + iy) * shape[2] + iz
    ex = px - (lo[0] + (ix + 0.5) * h)
    ey = py - (lo[1] + (iy + 0.5) * h)
    ez = pz - (lo[2] + (iz + 0.5) * h)
    r2 = ex * ex + ey * ey + ez * ez
    k = 0
    if use_n:
        k = _bin_of(nx, ny, nz, b)
        fx, fy, fz = nx - dirs[k, 0], ny - dirs[k, 1], nz - dirs[k, 2]
        r2 += w * (fx * fx + fy * fy + fz * fz)
    v = np.float64(root[cell, k]) - np.sqrt(r2)
    return v * v * SAFETY if v > 0.0 else 0.0


@nb.njit(inline="always", **_NB)
def _bound_row(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, out):
    for k in range(P.shape[0]):
        px, py, pz, nx, ny, nz = object_frame(poses, i, P, N, k, use_n)
        out[i, k] = min(_bound_one(px, py, pz, nx, ny, nz, use_n, lo, h, 1.0 / h, shape, root, dirs, box_lo, box_hi,
                                   w, b), cap)


@nb.njit(parallel=True, **_NB)
def _lower_costs(poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b):
    out = np.empty((poses.shape[0], P.shape[0]))
    for i in nb.prange(poses.shape[0]):
        _bound_row(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, out)
    return out


@nb.njit(**_SERIAL)
def _lower_costs_serial(poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b):
    out = np.empty((poses.shape[0], P.shape[0]))
    for i in range(poses.shape[0]):
        _bound_row(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, out)
    return out


@nb.njit(inline="always", **_NB)
def _bound_row_until(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, order, limit, out):
    total = 0.0
    for j in range(order.shape[0]):
        k = order[j]
        if total >= limit:
            out[i, k] = 0.0
            continue
        px, py, pz, nx, ny, nz = object_frame(poses, i, P, N, k, use_n)
        v = min(_bound_one(px, py, pz, nx, ny, nz, use_n, lo, h, 1.0 / h, shape, root, dirs, box_lo, box_hi, w, b),
                cap)
        out[i, k] = v
        total += v


@nb.njit(parallel=True, **_NB)
def _lower_costs_until(poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, order, limit):
    out = np.empty((poses.shape[0], P.shape[0]))
    for i in nb.prange(poses.shape[0]):
        _bound_row_until(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, order, limit,
                         out)
    return out


@nb.njit(**_SERIAL)
def _lower_costs_until_serial(poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, order,
                              limit):
    out = np.empty((poses.shape[0], P.shape[0]))
    for i in range(poses.shape[0]):
        _bound_row_until(i, poses, P, N, use_n, cap, lo, h, shape, root, dirs, box_lo, box_hi, w, b, order, limit,
                         out)
    return out


def lower_costs(bound: CostBound, poses, P, N, *, cap: float = np.inf, limit: float | None = None,
                order=None) -> np.ndarray:
    """(n, K) lower bounds (m^2, each at most ``cap``) of the joint costs of world contacts
    ``P`` (K, 3), ``N`` (K, 3) or None, seen from each pose (n, 4, 4; trusted).

    With ``limit`` (m^2), each pose takes its contacts in ``order`` (K,) (default: as given)
    until their bounds sum to ``limit`` or more; the pairs not reached hold 0, and a row
    whose sum stays below ``limit`` is the complete row, bit for bit."""
    poses = kernel_array(poses)
    P = kernel_array(P).reshape(-1, 3)
    use_n = N is not None and bound.w > 0
    Nn = kernel_array(N if use_n else np.zeros((1, 3)))
    args = (poses, P, Nn, use_n, float(cap), bound.lo, float(bound.h), bound.shape, bound.root, bound.dirs,
            bound.box_lo, bound.box_hi, float(bound.w), BINS)
    parallel = len(poses) * len(P) >= PARALLEL_MIN
    if limit is None:
        return (_lower_costs if parallel else _lower_costs_serial)(*args)
    order = np.ascontiguousarray(np.arange(len(P)) if order is None else order, dtype=np.int64)
    return (_lower_costs_until if parallel else _lower_costs_until_serial)(*args, order, float(limit))


def build_cost_bound(tree, box_lo, box_hi, w: float) -> CostBound:
    """The table for a mesh (its exact-query tree ``tree`` and bounding box) and weight ``w``."""
    box_lo, box_hi = np.asarray(box_lo, dtype=np.float64), np.asarray(box_hi, dtype=np.float64)
    ext = float(np.max(box_hi - box_lo))
    h = ext / CELLS_PER_EXTENT
    lo = box_lo - MARGIN * ext
    shape = np.maximum(1, np.ceil((box_hi + MARGIN * ext - lo) / h)).astype(np.int64)
    g = [lo[d] + (np.arange(shape[d]) + 0.5) * h for d in range(3)]
    centres = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)
    dirs = cube_map_dirs(BINS) if w > 0 else np.zeros((1, 3))
    root = np.empty((len(centres), len(dirs)), np.float32)
    cuts = np.linspace(0, len(centres), min(16, len(centres)) + 1).astype(np.int64)
    for a, b in progress(list(zip(cuts[:-1], cuts[1:])), desc="likelihood bounds (built once per mesh, then kept "
                         "on disk)"):
        C = centres[a:b]
        _, J, _ = query_joint(tree, np.repeat(C, len(dirs), axis=0), np.tile(dirs, (len(C), 1)) if w > 0 else None,
                              1.0, w)
        r = np.sqrt(np.maximum(J, 0.0)).reshape(len(C), len(dirs))
        r32 = r.astype(np.float32)
        # rounded down, so that the table never exceeds the root it stands for
        root[a:b] = np.where(r32.astype(np.float64) > r, np.nextafter(r32, np.float32(0)), r32)
    return CostBound(lo=lo, h=h, shape=shape, root=root, dirs=dirs, box_lo=box_lo, box_hi=box_hi, w=float(w))
