"""The turn of a body of revolution in the hand, from one feature's angle about the axis.

An object turned in the hand about a known axis, whose surface is a body of revolution
except for one feature (a mug's handle), shows its turn only where that feature is
touched. The feature's place is then one number: its angle ``phi`` about the axis in the
object frame. Every contact on it measures ``phi`` plus the object's turn, whatever the map
holds, so a Kalman filter over the turn ``theta``, the odometry's scale ``s`` and ``phi``
fits one ``phi`` from every visit instead of mapping the feature again at each visit's
estimated turn (a map drawn at drifting turns agrees with a drifting estimate):

    theta_{t+1} = theta_t + s R_t + w_t,   w_t ~ N(0, turn_sd^2)   (R_t: the reported turn)
    alpha       = phi + theta_t + v,       v ~ N(0, feature_sd^2)  (a feature contact's angle)

with ``theta_0 = 0`` (the gauge: the turn since the first pose), ``s ~ N(scale0, scale_sd^2)``
and ``phi`` unknown (a prior of 100 rad standard deviation) until the first feature
contact. A contact counts as the feature's when its distance from the axis exceeds the
median distance of every contact so far by ``margin`` and it lies at least ``zcut`` inside
the heights touched so far (rims flare); contacts more than ``gate`` standard deviations
from the prediction are left out.

Measured on the in-hand mug's runs (docs/slam.md, "The handle's angle as a landmark";
``benchmarks/study_inhand_landmark.py``).
"""

from __future__ import annotations

import numpy as np


def wrap(a):
    """Angles to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


#: the feature's angle before its first contact: effectively unknown
_PHI_PRIOR_VAR = 1e4


class FeatureTurn:
    """The Kalman filter of the module docstring. Angles in rad, lengths in m."""

    def __init__(self, scale0: float = 1.0, scale_sd: float = 0.05, *, turn_sd: float = np.deg2rad(0.75),
                 feature_sd: float = np.deg2rad(8.0), margin: float = 0.014, zcut: float = 0.012,
                 gate: float = 3.5, min_contacts: int = 20):
        self.x = np.array([0.0, float(scale0), 0.0])
        self.P = np.diag([0.0, float(scale_sd) ** 2, _PHI_PRIOR_VAR])
        # per step: (predicted mean, covariance, filtered mean, covariance, transition), for
        # the smoothed turns (:meth:`smoothed`)
        self.history: list = []
        self.turn_sd, self.feature_sd = float(turn_sd), float(feature_sd)
        self.margin, self.zcut, self.gate = float(margin), float(zcut), float(gate)
        self.min_contacts = int(min_contacts)
        self.started = False      # phi known (a feature contact seen)
        self._rho: list = []
        self._z: list = []
        self.used = 0             # feature contacts taken

    @property
    def turn(self) -> float:
        return float(self.x[0])

    @property
    def scale(self) -> float:
        return float(self.x[1])

    def predict(self, reported: float) -> None:
        """The object turned by ``reported`` (rad) as the hand reports it; starts a step."""
        F = np.array([[1.0, reported, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        self.x = F @ self.x
        self.P = F @ self.P @ F.T
        self.P[0, 0] += self.turn_sd**2
        self.history.append([self.x.copy(), self.P.copy(), self.x, self.P, F])

    def smoothed(self) -> np.ndarray:
        """The turn at every step so far given all the steps' contacts (rad; a
        Rauch-Tung-Striebel pass over :attr:`history`): with the scale learned since, the
        turns before the feature was first touched are the reported ones at that scale."""
        h = self.history
        if not h:
            return np.zeros(0)
        xs = h[-1][2].copy()
        Ps = h[-1][3].copy()
        out = [xs[0]]
        for k in range(len(h) - 2, -1, -1):
            _, _, xf, Pf, _ = h[k]
            xp1, Pp1, _, _, F1 = h[k + 1]
            C = Pf @ F1.T @ np.linalg.inv(Pp1)
            xs = xf + C @ (xs - xp1)
            Ps = Pf + C @ (Ps - Pp1) @ C.T
            out.append(xs[0])
        return np.array(out[::-1])

    def _features(self, points, q, a):
        """The world angles about the axis (through ``q`` along unit ``a``) of the
        feature contacts among ``points`` (k, 3), after counting every contact."""
        y = np.asarray(points, dtype=float) - q
        z = y @ a
        r = y - np.outer(z, a)
        rho = np.linalg.norm(r, axis=1)
        self._rho.extend(rho.tolist())
        self._z.extend(z.tolist())
        if len(self._rho) < self.min_contacts:
            return np.zeros(0)
        lo, hi = np.percentile(self._z, [2.0, 98.0])
        use = (rho > np.median(self._rho) + self.margin) & (z > lo + self.zcut) & (z < hi - self.zcut)
        if not use.any():
            return np.zeros(0)
        # an angle about a: in the plane normal to it, from a fixed reference direction
        e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        return np.arctan2(r[use] @ e2, r[use] @ e1)

    def update(self, points, q, a) -> int:
        """Fold in one step's world contact points; returns how many counted as the feature's."""
        H = np.array([1.0, 0.0, 1.0])
        n = 0
        for alpha in self._features(points, q, a):
            v = float(wrap(alpha - self.x[0] - self.x[2]))
            S = float(H @ self.P @ H) + self.feature_sd**2
            if self.started and v * v > self.gate**2 * S:
                continue
            K = self.P @ H / S
            self.x = self.x + K * v
            self.P = self.P - np.outer(K, H @ self.P)
            self.P = 0.5 * (self.P + self.P.T)
            self.started = True
            n += 1
        if self.history:
            self.history[-1][2:4] = [self.x.copy(), self.P.copy()]
        self.used += n
        return n
