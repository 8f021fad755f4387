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
the heights touched so far (rims flare). Those statistics need ``min_contacts`` contacts;
the steps before are kept and replayed once there are that many, so that a feature touched
in the first few steps is not lost.

A contact that passes for the feature may be a stray (a rim the axis's estimate makes
look wide), and the first one fixes ``phi``: a stray there would make every true contact
after it look wrong. So the filter keeps a few tracks, each started by a contact that no
track took, and follows the one the feature's contacts support best: each contact scores
a track by the likelihood of its angle under the track's prediction, or by a stray's
(``clutter`` of them spread evenly round the axis) if that is higher, in which case the
track leaves it out (so it does also beyond ``gate`` standard deviations).

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
#: a feature contact's angle measures phi + theta
_H = np.array([1.0, 0.0, 1.0])


class _Track:
    """One hypothesis of the feature's angle: the Kalman filter's mean ``x`` (theta, s,
    phi) and covariance ``P``, its steps (for the smoothed turns), the feature's contacts it
    took (:attr:`FeatureTurn.shape`) and its score (log-likelihood of the feature's
    contacts)."""

    def __init__(self, x, P):
        self.x, self.P = x, P
        self.history: list = []
        self.shape: list = []
        self.used = 0
        self.score = 0.0

    def copy(self):
        t = _Track(self.x.copy(), self.P.copy())
        t.history = [list(h) for h in self.history]
        t.shape, t.used, t.score = list(self.shape), self.used, self.score
        return t


class FeatureTurn:
    """The Kalman filter of the module docstring, over a few tracks of the feature's angle.
    Angles in rad, lengths in m."""

    def __init__(self, scale0: float = 1.0, scale_sd: float = 0.05, *, turn_sd: float = np.deg2rad(0.75),
                 feature_sd: float = np.deg2rad(8.0), margin: float = 0.014, zcut: float = 0.012,
                 gate: float = 3.5, clutter: float = 0.1, max_tracks: int = 6, min_contacts: int = 20):
        # the odometry and the scale's prior alone: where each new track starts from
        self._base = _Track(np.array([0.0, float(scale0), 0.0]), np.diag([0.0, float(scale_sd) ** 2, _PHI_PRIOR_VAR]))
        self._base0 = self._base.copy()
        self.tracks: list = []
        self.turn_sd, self.feature_sd = float(turn_sd), float(feature_sd)
        self.margin, self.zcut, self.gate = float(margin), float(zcut), float(gate)
        self.clutter, self.max_tracks = float(clutter), int(max_tracks)
        self.min_contacts = int(min_contacts)
        self._rho: list = []
        self._z: list = []
        self._seen = 0            # contacts that passed for the feature's
        # the calls before there are min_contacts contacts, replayed in order when there
        # are: (True, reported turn) for predict, (False, (points, q, a, base)) for update
        # (None once replayed)
        self._early: list | None = []

    @property
    def best(self) -> _Track:
        """The track the feature's contacts support best (the odometry alone before any)."""
        return max(self.tracks, key=lambda t: t.score) if self.tracks else self._base

    @property
    def started(self) -> bool:
        """Whether the feature has been seen (its angle is known)."""
        return bool(self.tracks)

    @property
    def history(self) -> list:
        """Per step of the best track: (predicted mean, covariance, filtered mean,
        covariance, transition), for the smoothed turns (:meth:`smoothed`)."""
        return self.best.history

    @property
    def shape(self) -> list:
        """The feature's contacts the best track took, in the feature's own frame: distance
        from the axis, height along it, and angle from phi as estimated when taken (rad);
        see :meth:`hit_probability`."""
        return self.best.shape

    @property
    def used(self) -> int:
        """The feature's contacts the best track took."""
        return self.best.used

    @property
    def turn(self) -> float:
        return float(self.best.x[0])

    @property
    def scale(self) -> float:
        return float(self.best.x[1])

    def predict(self, reported: float) -> None:
        """The object turned by ``reported`` (rad) as the hand reports it; starts a step."""
        if self._early is not None:
            self._early.append((True, float(reported)))
        self._predict(reported)

    def _predict(self, reported: float) -> None:
        for t in [self._base, *self.tracks]:
            t.x, t.P, F = self._step(t.x, t.P, reported)
            t.history.append([t.x.copy(), t.P.copy(), t.x, t.P, F])

    def _step(self, x, P, reported: float):
        """``(mean, covariance, transition)`` one step on, the hand turning by ``reported``."""
        F = np.array([[1.0, reported, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        P = F @ P @ F.T
        P[0, 0] += self.turn_sd**2
        return F @ x, P, F

    def smoothed(self) -> np.ndarray:
        """The turn at every step so far given all the steps' contacts (rad; a
        Rauch-Tung-Striebel pass over the best track's :attr:`history`): with the scale
        learned since, the turns before the feature was first touched are the reported
        ones at that scale."""
        h = self.history
        if not h:
            return np.zeros(0)
        # (a scale held, of zero variance, leaves its row empty: a pseudo-inverse then)
        inv = np.linalg.pinv if self._base.P[1, 1] == 0.0 else np.linalg.inv
        xs = h[-1][2].copy()
        out = [xs[0]]
        for k in range(len(h) - 2, -1, -1):
            _, _, xf, Pf, _ = h[k]
            xp1, Pp1, _, _, F1 = h[k + 1]
            xs = xf + Pf @ F1.T @ inv(Pp1) @ (xs - xp1)
            out.append(xs[0])
        return np.array(out[::-1])

    @staticmethod
    def _frame(a):
        """Two unit vectors completing unit ``a`` to a right-handed frame: angles about
        ``a`` are counted from the first towards the second."""
        e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(a, e1)

    @staticmethod
    def _about(points, q, a):
        """``(r, rho, z)`` of ``points`` (k, 3) about the axis through ``q`` along unit
        ``a``: their offsets across it, distances from it and heights along it."""
        y = np.asarray(points, dtype=float).reshape(-1, 3) - q
        z = y @ a
        r = y - np.outer(z, a)
        return r, np.linalg.norm(r, axis=1), z

    def radial_offset(self, points, q, a):
        """(k,) how far each of ``points`` (k, 3) lies beyond the median distance from the
        axis (through ``q`` along unit ``a``) of the contacts counted so far (m; negative
        inside it); None while fewer than ``min_contacts`` contacts have been counted."""
        if len(self._rho) < self.min_contacts:
            return None
        return self._about(points, q, a)[1] - np.median(self._rho)

    def _features(self, points, q, a):
        """``(angles, rho, z)``: the world angles about the axis (through ``q`` along unit
        ``a``) of the feature contacts among ``points`` (k, 3), their distances from the axis
        and heights along it, by the contacts counted so far (:meth:`update` counts them)."""
        r, rho, z = self._about(points, q, a)
        none = np.zeros(0)
        if len(self._rho) < self.min_contacts:
            return none, none, none
        lo, hi = np.percentile(self._z, [2.0, 98.0])
        use = (rho > np.median(self._rho) + self.margin) & (z > lo + self.zcut) & (z < hi - self.zcut)
        if not use.any():
            return none, none, none
        e1, e2 = self._frame(a)
        return np.arctan2(r[use] @ e2, r[use] @ e1), rho[use], z[use]

    def update(self, points, q, a, base: float = 0.0) -> int:
        """Fold in one step's contact points; returns how many the best track took as the
        feature's (of this step's; the steps before ``min_contacts`` contacts are replayed
        when it is reached).

        ``points`` (k, 3) are given in a frame in which the axis passes through ``q`` along
        unit ``a``, and ``base`` is that frame's own turn about the axis (rad): 0 for the
        world frame, or the turn of the estimated pose for the object frame, in which the
        body of revolution stays put when the object tilts and drifts in the hand (so that
        its radii, which pick the feature's contacts, do not spread with the tilt). A
        contact's world angle is its angle in the frame plus ``base``.
        """
        _, rho, z = self._about(points, q, a)
        self._rho.extend(rho.tolist())
        self._z.extend(z.tolist())
        if self._early is None:
            return self._take(points, q, a, base)
        self._early.append((False, (np.array(points, dtype=float), q, a, base)))
        if len(self._rho) < self.min_contacts:
            return 0
        # enough contacts to tell the feature's: every step so far again, from the start
        early, self._early = self._early, None
        self._base = self._base0.copy()
        took = 0
        for turned, args in early:
            if turned:
                self._predict(args)
            else:
                took = self._take(*args)
        return took

    def _take(self, points, q, a, base) -> int:
        """One step's feature contacts into the tracks (:meth:`update`)."""
        stray = float(np.log(self.clutter / (2.0 * np.pi)))
        first = float(np.log((1.0 - self.clutter) / (2.0 * np.pi)))
        ang, rho, z = self._features(points, q, a)
        taken = {id(t): [] for t in self.tracks}
        for alpha, r, h in zip(ang + base, rho, z):
            took = False
            for t in self.tracks:
                v = float(wrap(alpha - t.x[0] - t.x[2]))
                S = float(_H @ t.P @ _H) + self.feature_sd**2
                ll = float(np.log1p(-self.clutter) - 0.5 * (v * v / S + np.log(2.0 * np.pi * S)))
                if v * v > self.gate**2 * S or ll < stray:
                    t.score += stray
                    continue
                t.score += ll
                self._kalman(t, v, S)
                taken[id(t)].append((alpha, r, h))
                took = True
            if not took:
                # no track explains it: a new one starts here (every contact before was a
                # stray for it)
                t = self._base.copy()
                t.score = self._seen * stray + first
                self._kalman(t, float(wrap(alpha - t.x[0] - t.x[2])), float(_H @ t.P @ _H) + self.feature_sd**2)
                self.tracks.append(t)
                taken[id(t)] = [(alpha, r, h)]
                if len(self.tracks) > self.max_tracks:
                    self.tracks.remove(min(self.tracks[:-1], key=lambda u: u.score))
            self._seen += 1
        for t in self.tracks:
            got = taken.get(id(t), [])
            t.shape.extend((r, h, float(wrap(alpha - t.x[0] - t.x[2]))) for alpha, r, h in got)
            t.used += len(got)
            if t.history:
                t.history[-1][2:4] = [t.x.copy(), t.P.copy()]
        return len(taken.get(id(self.best), [])) if self.tracks else 0

    @staticmethod
    def _kalman(t, v, S):
        """Track ``t`` updated by a feature contact of innovation ``v`` and its variance ``S``."""
        K = t.P @ _H / S
        t.x = t.x + K * v
        t.P = t.P - np.outer(K, _H @ t.P)
        t.P = 0.5 * (t.P + t.P.T)

    def _next(self, reported: float):
        """The best track's mean and covariance one step on, the hand turning by ``reported``."""
        return self._step(self.best.x, self.best.P, reported)[:2]

    def _angle_var(self, reported: float) -> float:
        """The variance (rad^2) of the feature's world angle predicted for the next step."""
        _, P = self._next(reported)
        return float(_H @ P @ _H)

    def information(self, reported: float) -> float:
        """What one more feature contact at the next step, the hand turning by
        ``reported``, would teach about the state (nats: the mutual information, half the
        log of one plus the predicted angle's variance over the contact's); 0 before the
        feature is known. It grows with the turn made since the feature was last touched,
        at the scale's uncertainty: a visit then teaches the scale, and so every later turn."""
        if not self.started:
            return 0.0
        return float(0.5 * np.log1p(self._angle_var(reported) / self.feature_sd**2))

    def targets(self, reported: float, q, a, base: float = 0.0) -> np.ndarray:
        """(n, 3) where the feature's contacts so far (:attr:`shape`) are expected at the
        next step, the hand turning by ``reported``, in a frame as in :meth:`update`;
        empty before the feature is known."""
        if not self.started or not self.shape:
            return np.zeros((0, 3))
        x, _ = self._next(reported)
        rho, z, off = np.array(self.shape).T
        ang = x[0] + x[2] + off - base
        e1, e2 = self._frame(a)
        return q + rho[:, None] * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2) + z[:, None] * a

    def hit_probability(self, origins, directions, travel, q, a, reported: float, base: float = 0.0, *,
                        radius: float = 0.005) -> np.ndarray:
        """(m,) the chance that each straight touch (``origins`` and unit ``directions``
        (m, 3), ``travel`` (m,)) meets the feature first at the next step, the hand turning
        by ``reported``; the touches, the axis (through ``q`` along unit ``a``) and
        ``base`` are given in a frame as in :meth:`update`, as the object will stand then.

        The feature is where its contacts so far (:attr:`shape`) put it, turned to its
        predicted angle: a touch meets it when its line passes within ``radius`` of one of
        them before it would enter the body (a cylinder of the median contact's distance
        from the axis). The predicted angle's uncertainty spreads each point along its
        circle (in proportion to its distance from the axis), and so spreads and lowers
        the chance.
        """
        o = np.asarray(origins, dtype=float).reshape(-1, 3)
        d = np.asarray(directions, dtype=float).reshape(-1, 3)
        out = np.zeros(len(o))
        if not self.started or not self.shape or not len(o):
            return out
        sd = float(np.sqrt(self._angle_var(reported)))
        rho = np.array(self.shape)[:, 0]
        pts = self.targets(reported, q, a, base)
        # where each line enters the body's cylinder (inf: it does not)
        rb = float(np.median(self._rho))
        y = o - q
        yp = y - np.outer(y @ a, a)
        dp = d - np.outer(d @ a, a)
        A = np.einsum("ij,ij->i", dp, dp)
        B = np.einsum("ij,ij->i", yp, dp)
        C = np.einsum("ij,ij->i", yp, yp) - rb * rb
        disc = B * B - A * C
        root = (-B - np.sqrt(np.clip(disc, 0.0, None))) / np.maximum(A, 1e-12)
        enter = np.where((disc > 0) & (A > 1e-12) & (root > 0), root, np.inf)
        t = np.einsum("mj,pj->mp", d, pts) - np.einsum("mj,mj->m", d, o)[:, None]     # (m, p)
        miss2 = (np.einsum("pj,pj->p", pts, pts)[None, :] - 2 * (o @ pts.T) + np.einsum("mj,mj->m", o, o)[:, None]
                 - t * t)
        # the line meets the point's neighbourhood (a disc of ``radius``) where the feature's
        # angle, normal about its prediction, puts the point within ``radius`` of the line
        w2 = radius**2 + (rho * sd) ** 2
        p = np.minimum(1.0, 2.0 * radius / np.sqrt(2.0 * np.pi * w2))[None, :] * np.exp(
            -0.5 * np.clip(miss2, 0.0, None) / w2[None, :])
        reach = np.minimum(enter, np.asarray(travel, dtype=float).reshape(-1))
        p = np.where((t > 0) & (t < reach[:, None]), p, 0.0)
        return p.max(axis=1)
