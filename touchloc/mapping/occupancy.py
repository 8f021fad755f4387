"""A log-odds voxel map of one object (Handbook of Robotics ch. 42.2.1, Fig. 42.11).

Cells start at a prior log-odds (slightly occupied: unknown space inside the bounds may
hold the object), are lowered wherever a probe swept through them and raised at and just
behind every contact. The surface is the 0.5 level set of the occupancy probability, so
the map behaves like space carving refined by contacts.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

__all__ = ["OccupancyGrid"]


class OccupancyGrid:
    """Voxel occupancy in log-odds over an axis-aligned box.

    Parameters
    ----------
    lo, hi : (3,) float
        The box (m).
    resolution : int
        Cells along the longest side of the box.
    prior : float
        Probability of occupancy before any data.
    hit, miss : float
        Log-odds added at contacts and removed along swept paths (per touch).
    clamp : float
        Log-odds are kept within +-clamp so the map stays revisable.
    """

    def __init__(self, lo, hi, resolution: int = 64, *, prior: float = 0.6, hit: float = 2.0,
                 miss: float = 1.5, clamp: float = 6.0):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        ext = self.hi - self.lo
        self.voxel = float(ext.max() / int(resolution))
        self.shape = tuple(int(v) for v in np.maximum(np.ceil(ext / self.voxel).astype(int), 2))
        self.l0 = float(np.log(prior / (1 - prior)))
        self.hit, self.miss, self.clamp = float(hit), float(miss), float(clamp)
        self.logodds = np.full(self.shape, self.l0)

    def _index(self, P):
        """Cell index of points (M, 3) and a mask of those inside the grid."""
        ijk = np.floor((P - self.lo) / self.voxel).astype(np.int64)
        ok = np.all((ijk >= 0) & (ijk < np.array(self.shape)), axis=1)
        return ijk, ok

    def _bump(self, P, delta):
        ijk, ok = self._index(P)
        if not np.any(ok):
            return
        flat = np.unique(np.ravel_multi_index(ijk[ok].T, self.shape))
        L = self.logodds.reshape(-1)
        L[flat] = np.clip(L[flat] + delta, -self.clamp, self.clamp)

    def add_contacts(self, points, normals) -> None:
        """Raise the cells at each contact and one and two cells behind it (inside)."""
        pts = [points]
        if normals is not None:
            for k in (1.0, 2.0):
                pts.append(points - k * self.voxel * normals)
        for P in pts:
            self._bump(P, self.hit)

    def add_free(self, starts, ends, radius, stops) -> None:
        """Lower every cell a probe swept, stopping a cell short of each contact.

        ``stops`` (J,) bool: whether segment j ended at a contact.
        """
        for s, e, r, stop in zip(starts, ends, radius, stops):
            v = e - s
            L = float(np.linalg.norm(v))
            keep = L - (self.voxel + r if stop else 0.0)
            if keep <= 0:
                continue
            t = np.arange(0.0, keep, 0.5 * self.voxel)
            P = s + np.outer(t / max(L, 1e-12), v)
            if r > 0.5 * self.voxel:
                d = v / L
                a = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
                u = np.cross(d, a)
                u /= np.linalg.norm(u)
                w = np.cross(d, u)
                ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
                offs = r * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w)
                P = (P[:, None, :] + np.concatenate([np.zeros((1, 3)), offs])[None]).reshape(-1, 3)
            self._bump(P, -self.miss)

    def probability(self, points) -> np.ndarray:
        """(M,) occupancy probability at points (trilinear in log-odds; prior outside)."""
        c = ((np.asarray(points, float) - self.lo) / self.voxel - 0.5).T
        L = map_coordinates(self.logodds, c, order=1, mode="nearest")
        return 1.0 / (1.0 + np.exp(-L))

    def field(self) -> tuple:
        """(values on cell centres, origin of the first centre, spacing): negative inside."""
        return -self.logodds, self.lo + 0.5 * self.voxel, self.voxel
