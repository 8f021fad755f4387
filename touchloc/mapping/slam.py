"""Tactile SLAM: map an object that moves while it is touched.

A touch disturbs what it touches: a probe nudges a free-standing object, an in-hand object
slips or is turned. :class:`TactileSLAM` estimates the object's pose trajectory and its
shape together, with one shared map in the object frame and two estimators on it:

1. a *particle filter* over the current pose. Each update moves the particles by the
   odometry (if the hand reports one) or the motion noise (not before the first touches,
   which define the map's frame), weighs them by the new touches against the map, resamples
   when the effective sample size drops below half, and folds the touches into the map at
   the posterior mean. A contact p (normal n) at pose X, with x = X^-1 p, scores
   -1/2 mu(x)^2 / (sd(x)^2 + sigma_pos^2) - 1/2 |u(x) - X^-1 n|^2 / ((sd(x) / l)^2 + sigma_nor^2)
   (mu and sd the map's mean and standard deviation, u the unit gradient of mu, l the
   kernel's length scale) and every swept point y adds log Phi(mu(y) / s), each term less
   the same term scored against the map's prior mean alone: the prior is a placeholder
   shape, not evidence about the pose;
2. a *smoother* (:mod:`touchloc.mapping.smoother`) that every few updates revises the
   recent poses at once, from pairs of nearby contacts made at different steps (they must
   lie on one surface) and the motion model, after which the map moves every past touch
   to its revised pose (:meth:`ShapeMap.relocate`). The filter alone cannot undo a pose
   error made early, when touches land on surface nobody has touched yet; touches made
   later hold the information to correct it, and the smoother uses it.

Beside the particles, a *pose covariance tracked from the contacts' geometry*
(:meth:`TactileSLAM.pose_covariance`): it grows by the motion model and shrinks by what
each contact can show, the lever of the map's normal about each axis, discounted by the
normal's own uncertainty. It does not share a failure of the particles: a map not yet a
solid of revolution lends contacts on a mug's body a grip on its turn that the body does
not have, and the particles shrink in yaw while the true error grows. Before each update
that comes with an odometry the particles are spread to at least this covariance, and
the explorer plans with it (:func:`touchloc.mapping.explore`), so that a turn that grows
uncertain sends the fingers to the feature that shows it.

In hand, while the object touched so far is mostly a surface of revolution about the
odometry's axis (few contacts have a measured normal with a lever about it), the filter
estimates the *turn about that axis apart* (:meth:`TactileSLAM._turn_aware`): only
contacts whose position term changes markedly along the turn (a mapped handle) move it,
on a grid over the turn with a prior wide enough for an odometry's accumulated bias; every
other term is scored at the particles' mean turn. A correction is spread back over the
steps that did not show the turn, and the smoother holds those steps' turns.

Optionally, an *odometry scale*: a hand's reported turns are often off by a constant
factor; the map's correction of each predicted turn, summed with a small gain, estimates
the factor, from the steps whose contacts show the turn (see :meth:`TactileSLAM._learn_scale`;
with the turn estimated apart, a robust posterior over the scale measured by each correction
against the turn made since the surface it met was touched; the poses up to the first such
surface's step then follow the odometry at the learned scale, :meth:`TactileSLAM._reanchor`).

Why a filter and a smoother on one shared map: the pose posterior after one contact is far
from Gaussian (a contact on a face leaves the pose free to slide along it), and a few
hundred particles cost milliseconds against the map's mean, whereas a map per particle
(full Rao-Blackwellisation) would multiply the map's cost by the particle count and
localising against a mesh extracted per step costs an extraction per touch. The smoother
gives the joint correction of many poses that a filter cannot. docs/slam.md has the
measurements behind each choice.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import log_ndtr

from .._util import as_rng, blas_threads, logsumexp1d
from .._validate import as_bool, as_float, as_motion, as_pose
from ..geometry import checked_rotations
from ..errors import ValidationError
from ..models import Contacts
from ..planners import GuardedTouch, TouchResult
from ._feature_turn import FeatureTurn, wrap
from .shape_map import ShapeMap, as_bounds

__all__ = ["TactileSLAM", "transform_results"]


class OdometryCalibration(NamedTuple):
    """What :meth:`TactileSLAM.calibrate_odometry` measured: the odometry's turn scale and
    its standard deviation, the turn noise per update (rad), and the number of updates."""

    scale: float
    scale_sd: float
    turn_noise: float
    updates: int


def transform_results(results, T) -> list:
    """TouchResults expressed in another frame: ``T`` (4, 4) maps their frame to the new one."""
    from .shape_map import _check_results

    results = _check_results(results)
    T = as_pose(T, "T")
    R, t = T[:3, :3], T[:3, 3]
    out = []
    for r in results:
        g = r.touch
        # (a rigid move of a checked touch is a valid one)
        touch = GuardedTouch._trusted(R @ g.origin + t, R @ g.direction, g.max_travel, g.probe_radius, g.name)
        c = None if r.contact is None else r.contact.transform(T)
        out.append(TouchResult(touch, r.travel, c))
    return out


def _perturb(poses, sigma_t, sigma_r, planar, rng):
    """Random motion about each pose: the Gaussian dynamics model of the localisation side."""
    from ..models import GaussianDynamics

    return GaussianDynamics(sigma_t, sigma_r, planar=planar).sample(poses, rng=rng)


#: prior standard deviation of the learned odometry scale's relative error (TactileSLAM)
_SCALE_PRIOR_SD_DEFAULT = 0.05


class TactileSLAM:
    """Joint estimate of a moving object's pose trajectory and its shape.

    Parameters
    ----------
    bounds : (lo (3,), hi (3,)) float
        A box holding the object in its own frame, which is the world frame at the first
        update (the initial pose is the identity unless ``initial_pose`` says otherwise).
        Leave room for the pose error: contacts that land outside are dropped and counted
        in ``info["dropped"]``.
    motion : (float, float)
        Standard deviation of the object's motion per update without odometry:
        translation (m) and rotation (rad).
    odometry_noise : (float, float)
        Standard deviation of the odometry's error per update, when one is given.
    planar : bool
        The object moves on a table: x, y and yaw only.
    n_particles : int
    smooth_every : int
        Every this many updates, revise the whole trajectory at once
        (:func:`touchloc.mapping.smoother.smooth_trajectory`: pairs of nearby contacts
        from different steps must lie on one surface, plus the motion model) and move
        every past touch in the map to its revised pose (:meth:`ShapeMap.relocate`).
        The interval then grows with the trajectory (a quarter of its length), so that
        the smoother's cost stays a small share of the run. 0 turns it off (a pure
        filter). Needs contacts with normals.
    smooth_window : int
        The smoother revises the last this many poses; older ones stay as they are and
        anchor the rest (their touches still enter as partners). 0: all of them.
    learn_odometry_scale : bool
        Learn, online, a scale on the odometry's turn angle (a hand that reports its
        turns a few per cent too large or too small): each step where the map corrects the
        predicted turn moves the scale by a small fraction of that correction. The
        current value is ``.odometry_scale`` (its start until there is a map of 30 contacts).
        On an object whose turn only a small feature shows (a mug's handle), the turn and
        the scale come instead, once the feature has been touched, from a filter over the
        turn, the scale and the feature's one angle about the axis, and every earlier pose
        is turned onto the turn all the contacts so far imply (docs/slam.md, "The handle's
        angle as a landmark" and "Tracks, the object frame, and seeking the handle": on
        held-out runs of the mug 34 of 40 within 10 degrees of growth over four turns,
        against 21 before it; with a calibrated scale held, ``odometry_scale_sd=0``, the
        filter keeps it and still takes the turn from the feature: 39 of 40); with
        ``explore``, the hand then also seeks the feature where the filter expects it.
        Off by default: with an unbiased odometry it only adds noise of about a per cent.
    odometry_scale : float
        The scale on the odometry's turn to start from, in [0.8, 1.25]: a calibration of
        the hand measured beforehand (the turn it reports is multiplied by it, learned or
        not). Default 1.
    odometry_scale_sd : float
        With ``learn_odometry_scale``: the prior standard deviation of the scale's relative
        error, in [0, 0.5] (default 0.05). 0 holds the scale at ``odometry_scale`` while an
        object whose turn only a small feature shows (a mug's handle) still has its turn
        estimated apart from the rest of the pose: the setting for a hand whose scale was
        calibrated. On twenty of the mug's in-hand runs a scale known to 1 % and held kept
        10 within 5 degrees over four turns, where learning it from 1 kept 4 (docs/slam.md,
        "What a known scale is worth"; since then, learning it keeps 6-8 of 20 within 5,
        "Anchored corrections").
    initial_pose : (4, 4) float, optional
        The object's pose when the first update's touches were made: the map's frame.
        (If the object moved before them, pass that motion as the first update's
        odometry.)
    rng : None, int or Generator
    **map_kwargs
        Passed to :class:`ShapeMap` (``method``, ``sigma_pos``, ``sigma_nor``, ...);
        ``thin=0.3`` keeps a long session's updates and planning cheaper by leaving out of
        the map the contacts it already predicts, at a small cost in accuracy (docs/slam.md,
        "Speed").

    Attributes
    ----------
    pose : (4, 4) float
        Current estimate.
    trajectory : list of (4, 4) float
        ``initial_pose``, then one estimate per update (revised by the smoother).
    map : ShapeMap
        The shape, in the object frame.
    turning : bool
        The last update came with an odometry (the hand moves the object); the explorer
        then seeks pose information too.
    info : dict
        ``dropped`` (contacts outside the box), ``ess`` per update, ``smoothing`` (one
        record per smoother run: pairs, iterations, cost before/after, accepted, the
        largest shift of a contact in the map, m). With ``learn_odometry_scale`` on an
        object whose turn only a feature shows, also ``odometry_scale`` (its history),
        ``turn_search`` (one record per step whose contacts moved the turn),
        ``feature_scale`` (one record per fit of the scale to the feature's touches: the
        step, the best scale, the features matched there, the features, the margin over
        any scale 0.01 away), ``reanchor`` (step, anchor, the anchor's correction in
        degrees) and ``feature_turn`` (one record per step whose turn the feature's angle
        set: the step, the correction in degrees, the filter's scale, the feature contacts
        taken so far).
    """

    def __init__(self, bounds, *, motion=(0.002, np.deg2rad(2.0)), odometry_noise=(0.001, np.deg2rad(1.0)),
                 planar: bool = False, n_particles: int = 300, smooth_every: int = 10, smooth_window: int = 60,
                 learn_odometry_scale: bool = False, odometry_scale: float = 1.0,
                 odometry_scale_sd: float = _SCALE_PRIOR_SD_DEFAULT, initial_pose=None, rng=None, **map_kwargs):
        self.bounds = as_bounds(bounds)
        self.motion = as_motion(motion, "motion")
        self.odometry_noise = as_motion(odometry_noise, "odometry_noise")
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or not 10 <= n_particles <= 100_000:
            raise ValidationError(f"n_particles must be an integer in [10, 100000], got {n_particles!r}")
        self.planar = as_bool(planar, "planar")
        if isinstance(smooth_every, bool) or not isinstance(smooth_every, (int, np.integer)) or not 0 <= smooth_every <= 100_000:
            raise ValidationError(f"smooth_every must be an integer >= 0 (0: off), got {smooth_every!r}")
        self.smooth_every = int(smooth_every)
        if isinstance(smooth_window, bool) or not isinstance(smooth_window, (int, np.integer)) or not 0 <= smooth_window <= 10**6:
            raise ValidationError(f"smooth_window must be an integer >= 0 (0: the whole trajectory), got {smooth_window!r}")
        self.smooth_window = int(smooth_window)
        self.learn_odometry_scale = as_bool(learn_odometry_scale, "learn_odometry_scale")
        self.odometry_scale = as_float(odometry_scale, "odometry_scale", low=self._SCALE_RANGE[0],
                                       high=self._SCALE_RANGE[1])
        self.odometry_scale_sd = as_float(odometry_scale_sd, "odometry_scale_sd", low=0.0, high=0.5)
        self.rng = as_rng(rng)
        T0 = np.eye(4) if initial_pose is None else as_pose(initial_pose, "initial_pose")
        self.map = ShapeMap(self.bounds, **map_kwargs)
        self.particles = np.repeat(T0[None], int(n_particles), axis=0)
        self.log_w = np.full(int(n_particles), -np.log(n_particles))
        self.trajectory = [T0.copy()]
        self.info = {"dropped": 0, "ess": [], "smoothing": []}
        # per update: its contacts (world frame), its motion model, its map batch (or None),
        # whether its contacts showed the turn, and the odometry as reported (or None)
        self._steps: list = []
        self._next_smooth = self.smooth_every
        self._last_odometry = None
        # covariance of (pose in the object frame (6), odometry scale) tracked from the
        # contacts' own geometry; see pose_covariance
        self._cov = np.zeros((7, 7))
        # (the usual prior even for a held scale: the turn's prior width and the explorer's
        # pull to the feature that shows the turn rest on it; docs/slam.md, "What a known
        # scale is worth")
        self._cov[6, 6] = _SCALE_PRIOR_SD_DEFAULT**2 if self.learn_odometry_scale else 0.0
        self._unseen_turn = 0.0
        self._unseen_steps = 0
        self._scale_var = self.odometry_scale_sd**2
        self._scale0 = self.odometry_scale
        self._scale_obs: list = []
        self._turn_shown = None
        self._turn_draw = None
        self._turn_unseen = 0.0
        self._lever_count = np.zeros(2, dtype=np.int64)
        self._turn_post_var = 0.0
        self._turn_points = None
        self._anchor = None
        self._feature_fit = None
        # the turn from one feature's angle about the axis (a mug's handle; _feature_turn),
        # on the in-hand path with the scale learned or held (odometry_scale_sd=0)
        self._feature_turn = (FeatureTurn(self.odometry_scale, self.odometry_scale_sd, turn_sd=self.odometry_noise[1])
                              if self._FEATURE_TURN and self.learn_odometry_scale
                              else None)
        self._turn_axis = None
        self._turn_frame = None       # the axis's point and direction in the object frame
        self._turn_last = None        # the last reported turn (rad)
        self._turn_steps: list = []   # the step of each of the feature filter's steps

    @property
    def pose(self) -> np.ndarray:
        """(4, 4) current T_world_object estimate (posterior mean)."""
        return self.trajectory[-1].copy()

    @property
    def turning(self) -> bool:
        """True when the last update came with an odometry (a hand moving the object)."""
        return self._last_odometry is not None

    def predicted_pose(self) -> np.ndarray:
        """(4, 4) the pose expected at the next update: the current estimate moved by the
        last update's odometry (a hand turning an object in steps repeats its turn), or the
        current estimate when the last update had none."""
        T = self.trajectory[-1]
        return T.copy() if self._last_odometry is None else self._last_odometry @ T

    def pose_covariance(self, *, predict: bool = True) -> np.ndarray:
        """(6, 6) covariance of the pose in the object frame, tracked from the touches' geometry.

        A pose ``T`` near the estimate ``T0`` is written ``T = T0 exp(xi)``, ``xi = (v, w)``:
        translation ``v`` (m) and rotation vector ``w`` (rad) in the object frame, so that
        an object point ``x`` moves by ``v + w x x``. The covariance grows by the motion
        model (and, with ``learn_odometry_scale``, by the scale's uncertainty times the
        turn) and shrinks by the Fisher information of each step's contacts: a contact at
        ``x``, where the map's normal is ``n``, fixes ``n . v + (x x n) . w`` to the
        sensor's noise plus the map's uncertainty there, with the lever ``x x n`` shrunk
        by what the normal's own uncertainty can explain. A turn that slides a surface
        along itself (a solid of revolution about its axis) thus stays as uncertain as
        the motion model makes it, however confident the particles are (the particles
        are spread to at least this covariance before each update with an odometry).
        With ``predict`` it is the covariance at the next update (one more step of the
        motion model).
        """
        predict = as_bool(predict, "predict")
        C = self._cov
        if predict and self._steps:
            sig = self.odometry_noise if self._last_odometry is not None else self.motion
            C = self._predict_cov(C, sig, self._last_odometry)
        return 0.5 * (C[:6, :6] + C[:6, :6].T)

    def calibrate_odometry(self) -> OdometryCalibration:
        """The odometry's turn scale and turn noise that the whole estimated trajectory implies.

        For every update that came with an odometry, the turn the estimated trajectory
        made about that odometry's axis is compared with the turn the odometry reported.
        The scale is the ratio of their sums; the turn noise is the spread of each
        update's turn about the scaled report. These are the values to hold on a later
        run with the same hand::

            cal = box_slam.calibrate_odometry()
            TactileSLAM(..., learn_odometry_scale=True, odometry_scale=cal.scale, odometry_scale_sd=0.0,
                        odometry_noise=(translation_sd, cal.turn_noise))

        This is how a biased odometry reaches an object whose turn only a small feature
        shows: calibrate on an object whose touches show the turn at every step (a box),
        then hold the values for a mug, whose turn the online estimate learns too late
        (docs/slam.md, "Calibrating the odometry on another object").

        Returns
        -------
        OdometryCalibration
            ``scale``: estimated turn over reported turn (0.952 for an odometry that
            reports 5 % too much); it does not depend on the scale the run itself
            applied. ``scale_sd``: its standard deviation under this estimator's own noise
            model (the current turn's variance from :meth:`pose_covariance`, plus
            ``odometry_noise``'s rotation variance for each update), over the reported
            turn. ``turn_noise`` (rad): the standard deviation of each update's turn about
            ``scale`` times the reported one (the median absolute deviation, scaled to a
            Gaussian's; the first updates, while the map is a blob, jump far more than the
            rest). It includes the trajectory's own per-update error, so it errs large:
            0.75-0.9 deg where the motion's own was 0.45-0.6 deg, on boxes turned 96 times.
            ``updates``: how many updates it rests on.

        Raises
        ------
        ValidationError
            If fewer than three updates came with an odometry that turned, or if, with
            the scale learned (the in-hand path), the contacts showed the turn in fewer
            than a quarter of them: on a body of revolution (a can) the estimated turns
            are the odometry's own, and the scale they imply would be the prior's, not a
            measurement.
        """
        turned, reported, seen = [], [], []
        axis = None
        for k, st in enumerate(self._steps):
            D = st.get("odometry")
            if D is None:
                continue
            w = checked_rotations(D[:3, :3]).as_rotvec()
            theta = float(np.linalg.norm(w))
            if theta < 1e-9:
                continue
            axis = w / theta
            # trajectory[0] is the initial pose; update k's pose is trajectory[k + 1]
            A, B = self.trajectory[k], self.trajectory[k + 1]
            turned.append(float(checked_rotations(B[:3, :3] @ A[:3, :3].T).as_rotvec() @ axis))
            reported.append(theta)
            # False: on the in-hand path, this step's contacts did not show the turn (a body
            # of revolution's), and no feature's angle set it
            seen.append(st.get("turn_shown") is not False or bool(st.get("turn_held")))
        n = len(turned)
        if n < 3:
            raise ValidationError(f"calibrate_odometry needs at least three updates with an odometry that turned; "
                                  f"this run has {n}")
        if 4 * sum(seen) < n:
            raise ValidationError(
                f"calibrate_odometry: the contacts showed the turn in only {sum(seen)} of the {n} updates that "
                f"turned (the object, as touched, is a body of revolution about the turn's axis, and no feature "
                f"of it was followed), so the trajectory's turns are the odometry's own; calibrate on an object "
                f"whose touches show every turn, such as a box")
        turned, reported = np.array(turned), np.array(reported)
        scale = float(turned.sum() / reported.sum())
        a = self.trajectory[-1][:3, :3].T @ axis   # the last turn's axis in the object frame
        C = self.pose_covariance(predict=False)[3:, 3:]
        var = float(a @ C @ a) + n * self.odometry_noise[1] ** 2
        # a robust spread (the median absolute deviation, scaled to a Gaussian's sd): the
        # first updates, while the map is still a blob, jump by several times the rest
        r = turned - scale * reported
        noise = float(1.4826 * np.median(np.abs(r - np.median(r))))
        return OdometryCalibration(scale, float(np.sqrt(var)) / float(reported.sum()), noise, n)

    def _unseen_turn_covariance(self) -> np.ndarray:
        """(6, 6) the covariance, at the next update, of the turn made since the contacts last
        showed it (``_turn_aware``), at an odometry scale error of ``_TURN_SCALE_ERROR``: a
        bias the motion model does not know. Added to :meth:`pose_covariance` by the
        explorer, so that a turn long unseen sends the hand to the feature that shows it."""
        C = np.zeros((6, 6))
        D = self._last_odometry
        if not self._PLAN_UNSEEN or D is None or self._turn_unseen <= 0:
            return C
        w = checked_rotations(D[:3, :3]).as_rotvec()
        th = float(np.linalg.norm(w))
        if th < 1e-6:
            return C
        T0 = self.trajectory[-1]
        a = T0[:3, :3].T @ (w / th)
        q = np.linalg.lstsq(np.eye(3) - D[:3, :3], D[:3, 3], rcond=None)[0]
        u = np.concatenate([-np.cross(a, T0[:3, :3].T @ (q - T0[:3, 3])), a])
        return (self._TURN_SCALE_ERROR * (self._turn_unseen + th)) ** 2 * np.outer(u, u)

    def _masks(self, R0):
        mt = np.diag([1.0, 1.0, 0.0]) if self.planar else np.eye(3)
        mr = np.diag([0.0, 0.0, 1.0]) if self.planar else np.eye(3)
        return R0.T @ mt @ R0, R0.T @ mr @ R0

    def _predict_cov(self, C, sig, D):
        """The tracked covariance one step on: motion noise, and the scale's share of a turn."""
        R0 = self.trajectory[-1][:3, :3]
        Mt, Mr = self._masks(R0)
        C = C.copy()
        if D is not None and self.learn_odometry_scale:
            # the turn scaled by (s + ds) turns the object further by ds * w (object frame)
            F = np.eye(7)
            F[3:6, 6] = R0.T @ checked_rotations(D[:3, :3]).as_rotvec()
            C = F @ C @ F.T
        C[:3, :3] += sig[0] ** 2 * Mt
        C[3:6, 3:6] += sig[1] ** 2 * Mr
        return C

    def _update_cov(self, C, T, results):
        """The tracked covariance after this step's contacts (Kalman form, at pose T), and the
        contacts' rotation levers and noise variances (``None`` when nothing was learned)."""
        hits = [r.contact for r in results if r.contact is not None]
        if not hits or self.map.n_contacts == 0:
            return C, None
        c = Contacts.concatenate(hits)
        x = (c.points - T[:3, 3]) @ T[:3, :3]
        # the map's normal there, not the measured one: the map's averages many contacts,
        # while a measured normal's noise (5 deg on a mug's 40 mm radius) would lend a
        # contact on a solid of revolution a lever about its axis that it does not have
        if self.map.method == "gpis":
            n = self.map._gp.mean_grad(np.clip(x, self.map.lo, self.map.hi))[1]
        elif c.normals is not None:
            n = c.normals @ T[:3, :3]
        else:
            return C, None
        n = n / np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
        H = np.zeros((len(x), 7))
        H[:, :6] = _pose_jacobian(x, n, self.map.sigma_nor)
        r = self.map.sigma_pos**2 + self.map.surface_std(np.clip(x, self.map.lo, self.map.hi)) ** 2
        S = H @ C @ H.T + np.diag(r)
        K = np.linalg.solve(S, H @ C).T
        C = C - K @ H @ C
        return 0.5 * (C + C.T), (H[:, 3:6], r)

    def _inflate(self, P):
        """Spread the particles, about their mean, to at least the tracked covariance.

        The particles' own spread says how well the map fixed the pose; where the map is
        wrong in a way that looks certain (the body of a mug not yet a solid of revolution
        "fixing" a turn about its axis) it is too small, and a touch that then shows the
        turn (the handle) falls outside it. The shortfall is added as random motion.
        """
        w = np.exp(self.log_w - logsumexp1d(self.log_w))
        xi = self._twists(P, self._mean_pose(P))
        m = w @ xi
        Cp = np.einsum("n,ni,nj->ij", w, xi - m, xi - m)
        lam, V = np.linalg.eigh(self._cov[:6, :6] - Cp)
        keep = lam > 1e-12
        if not np.any(keep):
            return P
        E = self.rng.standard_normal((len(P), int(keep.sum()))) * np.sqrt(lam[keep]) @ V[:, keep].T
        out = P.copy()
        out[:, :3, 3] += np.einsum("nij,nj->ni", P[:, :3, :3], E[:, :3])
        out[:, :3, :3] = P[:, :3, :3] @ Rotation.from_rotvec(E[:, 3:]).as_matrix()
        return out

    # in-hand turns (see _turn_aware)
    _TURN_AWARE = True
    _TURN_MIN_RANGE = 8.0
    _TURN_LEVER_SIGMAS = 3.0
    _TURN_REVOLUTION_SHARE = 0.25
    _TURN_MIN_CONTACTS = 9
    _TURN_RANGE = np.deg2rad(45.0)
    _TURN_STEP = np.deg2rad(1.0)
    _TURN_OUTLIER = 0.05
    _TURN_MAP_SD = 0.002
    _TURN_SCALE_ERROR = 0.1
    _TURN_INSIDE = 0.005
    _PLAN_UNSEEN = True
    _TURN_BACKFILL = True
    _TURN_REF = True
    _SMOOTH_FIX_TURNS = True
    #: the in-hand turn from the feature's angle (_feature_turn.FeatureTurn) once the feature is
    #: seen, instead of the map's corrections and the scale's updates from them
    _FEATURE_TURN = True
    #: the explorer also values a touch by its chance of meeting that feature, where the
    #: filter expects it (_feature_seeking)
    _FEATURE_SEEK = True

    @staticmethod
    def _twists(P, T0):
        """(N, 6) each pose of ``P`` as ``T0 exp(xi)``: translation and rotation vector, object frame."""
        R0, t0 = T0[:3, :3], T0[:3, 3]
        return np.concatenate([(P[:, :3, 3] - t0) @ R0,
                               checked_rotations(np.einsum("ji,njk->nik", R0, P[:, :3, :3])).as_rotvec()], axis=1)

    @staticmethod
    def _from_twists(T0, xi):
        """(N, 4, 4) the poses ``T0 exp(xi)`` of :meth:`_twists`."""
        out = np.repeat(T0[None], len(xi), axis=0)
        out[:, :3, 3] = T0[:3, 3] + xi[:, :3] @ T0[:3, :3].T
        out[:, :3, :3] = T0[:3, :3] @ Rotation.from_rotvec(xi[:, 3:]).as_matrix()
        return out

    def _turn_aware(self, P, results, D):
        """The update's likelihood for a turn the hand reports: ``(particles, (N,) log-likelihood)``,
        or None to score the usual way.

        Used while the object, as touched so far, is mostly a surface of revolution about
        the odometry's axis (a mug's body, a can): no more than ``_TURN_REVOLUTION_SHARE``
        of its contacts (after the first ``_TURN_MIN_CONTACTS``) have a measured normal
        whose lever about the axis exceeds ``_TURN_LEVER_SIGMAS`` times what the normal's
        noise lends any contact (sigma_nor times its distance from the axis). On a box
        most contacts do, every touch shows the turn, and the usual likelihood is sound.

        The turn about the axis is then estimated apart from the rest of the pose, on a
        grid of turns about the axis through the particles' mean, from the contacts'
        position terms alone (each at the map's own standard deviation where the turn
        takes it, plus ``_TURN_MAP_SD`` for the map's own errors: a body mapped at slightly
        wrong poses is not round to better than a millimetre or two). A contact takes part
        only where its term changes along the grid by ``_TURN_MIN_RANGE`` nats or more (on
        a mapped handle: 10-30; on a mug's body: 1-4 for nine in ten), and, until the
        feature's filter has a sighting, lies no more than ``_TURN_INSIDE`` inside the
        median distance from the axis of the contacts so far. The normals' terms,
        the free space and every other contact are scored with each particle's turn set
        to the mean's, so they cannot move the turn: the map's normals on a body not yet
        round lend it a lever about the axis that the body does not have.

        The particles' turns are then drawn anew: from the grid's posterior when some
        contact takes part, with the particles' spread of the turn (at least the tracked
        covariance's) as the prior, widened by a uniform share ``_TURN_OUTLIER`` over the
        turn that an odometry off by ``_TURN_SCALE_ERROR`` could have made unseen since the
        contacts last showed it (a biased odometry's error is not Gaussian), so that a
        handle touched again after many turns of drift corrects it in one step; else from
        the particles' own turns. Either way they are dealt out again after resampling
        (see :meth:`update`), so that resampling on the other components cannot drag the
        turn with it.
        """
        hits = [r.contact for r in results if r.contact is not None]
        w = checked_rotations(D[:3, :3]).as_rotvec()
        if float(np.linalg.norm(w)) < 1e-6 or self.map.method != "gpis":
            return None
        c = Contacts.concatenate(hits) if hits else None
        a_w = w / np.linalg.norm(w)
        q = np.linalg.lstsq(np.eye(3) - D[:3, :3], D[:3, 3], rcond=None)[0]
        if c is not None and c.normals is not None:
            r = c.points - q
            lever = np.cross(r, c.normals) @ a_w
            rho = np.linalg.norm(r - np.outer(r @ a_w, a_w), axis=1)
            shows = np.abs(lever) > self._TURN_LEVER_SIGMAS * self.map.sigma_nor * rho
            self._lever_count += np.array([int(shows.sum()), len(shows)])
        n_lev, n_all = self._lever_count
        if n_all >= self._TURN_MIN_CONTACTS and n_lev > self._TURN_REVOLUTION_SHARE * n_all:
            return None
        T0 = self._mean_pose(P)
        a = T0[:3, :3].T @ a_w
        qo = T0[:3, :3].T @ (q - T0[:3, 3])
        u = np.concatenate([-np.cross(a, qo), a])
        xi = self._twists(P, T0)
        d = xi[:, 3:] @ a
        base = xi - d[:, None] * u
        Pb = self._from_twists(T0, base)
        N = len(P)
        pos, nor = self._contact_terms(Pb, c)
        wt = np.exp(self.log_w - logsumexp1d(self.log_w))
        m = float(wt @ d)
        sd = max(float(np.sqrt(wt @ (d - m) ** 2)), float(np.sqrt(max(u @ self._cov[:6, :6] @ u, 0.0))),
                 self.odometry_noise[1])
        self._turn_unseen += float(np.linalg.norm(w))
        # the turns considered: the prior's spread, and what an odometry whose scale is off by
        # _TURN_SCALE_ERROR could have turned the object unseen since the contacts last showed the turn
        R = min(self._TURN_RANGE, max(3 * sd, self._TURN_SCALE_ERROR * self._turn_unseen))
        grid = m + np.arange(-R, R + 1e-9, self._TURN_STEP)
        use = np.zeros(pos.shape[1], bool)
        if c is not None and len(c):
            gpos = self._contact_terms(self._from_twists(T0, grid[:, None] * u[None]), c, own_sd=True,
                                       floor=self._TURN_MAP_SD, normals=False)[0]
            use = (gpos.max(axis=0) - gpos.min(axis=0)) >= self._TURN_MIN_RANGE
            ft = self._feature_turn
            if self._TURN_INSIDE and ft is not None and not ft.started and self._turn_frame is not None \
                    and use.any():
                # before the feature's filter has a sighting, a contact well inside the body's
                # radius does not show the turn: there the map is the least sure (a mug's inner
                # wall, mapped from a few touches, moved the turn by 18-45 deg)
                off = ft.radial_offset((c.points[use] - T0[:3, 3]) @ T0[:3, :3], *self._turn_frame)
                if off is not None:
                    use[np.flatnonzero(use)[off < -self._TURN_INSIDE]] = False
        ll = pos[:, ~use].sum(axis=1) + nor.sum(axis=1) + self._ll_free(Pb, results)
        self._turn_shown = bool(np.any(use))
        self._turn_points = c.points[use] if self._turn_shown else None
        if not self._turn_shown:
            # the particles' own turns, drawn again after resampling (see update)
            dn = d[self._systematic(wt, N)]
            self._turn_draw = (T0, u, a, dn)
            return self._from_twists(T0, base + dn[:, None] * u), ll
        lg = gpos[:, use].sum(axis=1)
        eps = self._TURN_OUTLIER
        lprior = np.logaddexp(np.log1p(-eps) - 0.5 * ((grid - m) / sd) ** 2 - np.log(np.sqrt(2 * np.pi) * sd),
                              np.log(eps / (2 * R)))
        lp = lprior + lg
        pg = np.exp(lp - logsumexp1d(lp))
        self._turn_post_var = float(pg @ (grid - pg @ grid) ** 2)
        k = self._systematic(pg, N)
        dn = grid[k] + self.rng.uniform(-0.5, 0.5, N) * self._TURN_STEP
        self._turn_draw = (T0, u, a, dn)
        self.info.setdefault("turn_search", []).append(
            dict(step=len(self._steps), contacts=int(use.sum()), prior=(m, sd), mode=float(grid[np.argmax(lp)] - m),
                 gain=float(lg.max() - np.interp(m, grid, lg)), R=R))
        self._turn_unseen = 0.0
        return self._from_twists(T0, base + dn[:, None] * u), ll

    def _turn_since(self, T):
        """The step since which this step's correction of the turn accumulated, or None.

        A correction aligns the contacts that show the turn with the map's surface near
        them, so it measures the odometry's error made since that surface was touched, or
        since a later step whose turn was corrected already, whichever is later: a mug's
        handle first touched at step 12 and touched again at step 19 measures the turn of
        steps 13-19, not the 19 steps since the start. That surface's step is the step of
        the mapped contact nearest to where the corrected pose ``T`` puts each of this
        step's contacts that showed the turn (the latest of them). The earliest such step
        so far is the run's anchor (see :meth:`_reanchor`). None when the map holds no
        contact.
        """
        if not self._TURN_REF:
            # (as before: the last step that showed the turn)
            shown = [i for i, st in enumerate(self._steps) if st.get("turn_shown")]
            return shown[-1] if shown else None
        if self._turn_points is None or self.map.n_contacts == 0:
            return None
        x = (self._turn_points - T[:3, 3]) @ T[:3, :3]
        d2 = ((self.map._pts[None, :, :] - x[:, None, :]) ** 2).sum(axis=2)
        near = np.unique(self.map._pts_owner[np.argmin(d2, axis=1)])
        batch_step = {st["batch"]: i for i, st in enumerate(self._steps) if st["batch"] is not None}
        refs = [batch_step[int(b)] for b in near if int(b) in batch_step]
        if not refs:
            return None
        ref = max(refs)
        self._anchor = ref if self._anchor is None else min(self._anchor, ref)
        shown = [i for i, st in enumerate(self._steps) if st.get("turn_shown")]
        return max(ref, shown[-1]) if shown else ref

    def _turn_made(self, since, theta):
        """(the turn applied over the steps after ``since`` and this one's ``theta``, their count)."""
        turns = [float(np.linalg.norm(checked_rotations(st["motion"][0][:3, :3]).as_rotvec()))
                 for st in self._steps[since + 1:] if st["motion"] is not None]
        return float(np.sum(turns)) + theta, len(self._steps) - since

    _REANCHOR = True
    _REANCHOR_MIN = np.deg2rad(1.0)

    def _reanchor(self, raw, T, anchor=None):
        """Turn the poses so that the feature showing the turn sits where the odometry, at
        the learned scale, puts it; return the current pose so turned.

        On a body of revolution the turn is seen only once a feature (a mug's handle) has
        been mapped, at step ``_anchor``; every later correction aligns the turn with that
        first mapping, so its error then (the odometry's bias over all the turn before it)
        stays in the whole trajectory. Nothing but the odometry tells the turn up to the
        anchor, so with the scale learned since, the poses up to it are turned to the
        odometry integrated at that scale, and every later pose (and the map's touches with
        each, and the particles) by the anchor's correction: a turn about the odometry's
        axis, which leaves the body of revolution where it was.

        ``anchor`` (default ``_anchor``) may be ``len(self._steps)``, the current step: then
        every pose, ``T`` included, is turned onto the scaled odometry (the scale fitted to
        the features' touches, :meth:`_feature_scale`). Nothing moves unless some pose's
        correction (the anchor's alone, for an earlier anchor) reaches ``_REANCHOR_MIN``,
        and the map ignores moves below a tenth of the sensor's noise.
        """
        n = len(self._steps)
        anchor = self._anchor if anchor is None else anchor
        w = checked_rotations(raw[:3, :3]).as_rotvec()
        a = w / np.linalg.norm(w)
        q = np.linalg.lstsq(np.eye(3) - raw[:3, :3], raw[:3, 3], rcond=None)[0]

        R = self.trajectory[0][:3, :3]
        corr = []
        for j in range(anchor + 1):
            D = raw if j == n else self._steps[j]["odometry"]
            if D is not None:
                R = _scaled_turn(D, self.odometry_scale)[:3, :3] @ R
            Tj = T if j == n else self.trajectory[j + 1]
            corr.append(float(checked_rotations(R @ Tj[:3, :3].T).as_rotvec() @ a))
        c_a = corr[-1]
        if max(abs(c) for c in (corr if anchor == n else corr[-1:])) < self._REANCHOR_MIN:
            return T
        moves = [None] * len(self.map.batches)
        for j in range(n):
            old = self.trajectory[j + 1]
            new = _about_axis(corr[j] if j <= anchor else c_a, a, q) @ old
            self.trajectory[j + 1] = new
            if self._steps[j]["batch"] is not None:
                moves[self._steps[j]["batch"]] = np.linalg.inv(new) @ old
        M = _about_axis(c_a, a, q)
        self.particles = np.einsum("ij,njk->nik", M, self.particles)
        self.info.setdefault("reanchor", []).append((n, anchor, float(np.degrees(c_a))))
        if any(m is not None for m in moves):
            # (re-anchoring every step: moves below a tenth of the sensor's noise are none)
            self.map.relocate(moves, tol=0.1 * self.map.sigma_pos if anchor == n else 0.0)
        return M @ T

    _FEATURE_SCALE = True
    _FEATURE_OUT = 0.010
    _FEATURE_BIN = 0.010
    _FEATURE_SIGMA = (0.003, 0.3)
    _FEATURE_GAP = 4
    _FEATURE_MIN = 6
    _FEATURE_MARGIN = 6.0
    _FEATURE_STEP = 0.001
    _FEATURE_MAX = 150

    def _feature_scale(self, raw, T, c_now):
        """The odometry's turn scale under which the touches of the object's features agree.

        A feature is a contact farther from the odometry's axis, by ``_FEATURE_OUT``, than
        the median of the contacts at its height (a mug's handle beside its body). With the
        turn of every step set to the odometry's turn so far times a scale s, each feature
        is placed in the object frame (point and normal), and scored by its nearest feature
        from a step at least ``_FEATURE_GAP`` steps away (squared distance whitened by
        ``_FEATURE_SIGMA``, capped at 9); the cost over s adds the scale's prior. Returns the
        best s, or None unless at least ``_FEATURE_MIN`` features have a partner within the
        cap there and every s more than 0.01 away costs ``_FEATURE_MARGIN`` more (while the
        handle has been touched only 10-20 times, chance alignments under a wrong scale
        score nearly as well as the right one).

        The turn the filter corrected at each step plays no part: only the odometry, the
        scale and the rest of each pose (its position and tilt). A step's turn is placed at
        ``s * (odometry's turn so far) - (the estimate's turn)`` relative to its estimate.
        """
        n = len(self._steps)
        w = checked_rotations(raw[:3, :3]).as_rotvec()
        a = w / np.linalg.norm(w)
        turn = [0.0 if st["odometry"] is None else
                float(checked_rotations(st["odometry"][:3, :3]).as_rotvec() @ a) for st in self._steps]
        Dc = np.cumsum(turn + [float(w @ a)])
        R0 = self.trajectory[0][:3, :3]
        every = []
        for j in range(n + 1):
            c = c_now if j == n else self._steps[j]["contacts"]
            if c is None or c.normals is None:
                continue
            Tj = T if j == n else self.trajectory[j + 1]
            y = c.points - Tj[:3, 3]
            z = y @ a
            every.append((j, Tj, y, c.normals, np.linalg.norm(y - np.outer(z, a), axis=1), np.floor(z / self._FEATURE_BIN)))
        if not every:
            return None
        rho, zb = np.concatenate([e[4] for e in every]), np.concatenate([e[5] for e in every])
        prof = {b: float(np.median(rho[zb == b])) for b in np.unique(zb)}
        sp, sn = self._FEATURE_SIGMA
        u1, u2, u3, A, B, J = [], [], [], [], [], []
        for j, Tj, y, nor, r, b in every:
            out = r > np.array([prof[k] for k in b]) + self._FEATURE_OUT
            if not out.any():
                continue
            v = np.concatenate([y[out] / sp, nor[out] / sn])     # points, then normals
            par = np.outer(v @ a, a)
            m = int(out.sum())
            for lst, x in ((u1, par), (u2, v - par), (u3, np.cross(a, v))):
                x = x @ Tj[:3, :3]
                lst.append(np.concatenate([x[:m], x[m:]], axis=1))
            te = float(checked_rotations(Tj[:3, :3] @ R0.T).as_rotvec() @ a)
            A += [Dc[j]] * m
            B += [te] * m
            J += [j] * m
        if len(J) < self._FEATURE_MIN:
            return None
        u1, u2, u3 = np.concatenate(u1), np.concatenate(u2), np.concatenate(u3)
        A, B, J = np.array(A), np.array(B), np.array(J)
        n_feat = len(J)
        if n_feat > self._FEATURE_MAX:
            # (the cost is quadratic in the features: an even subset over the run)
            keep = np.linspace(0, len(J) - 1, self._FEATURE_MAX).round().astype(int)
            u1, u2, u3, A, B, J = u1[keep], u2[keep], u3[keep], A[keep], B[keep], J[keep]
        far = np.abs(J[:, None] - J[None, :]) >= self._FEATURE_GAP
        lo, hi = self._SCALE_RANGE
        g = np.arange(lo, hi + 1e-9, self._FEATURE_STEP)
        s0, sd0 = self._scale0, max(self.odometry_scale_sd, 1e-6) * self._scale0
        cost = ((g - s0) / sd0) ** 2
        matched = np.zeros(len(g), int)
        for k in range(0, len(g), 32):
            c = g[k:k + 32, None] * A[None] - B[None]
            c = (c + np.pi) % (2 * np.pi) - np.pi
            # each feature turned about the axis (through its step's origin) by c
            x = u1[None] + np.cos(c)[..., None] * u2[None] - np.sin(c)[..., None] * u3[None]
            d2 = np.where(far[None], ((x[:, :, None, :] - x[:, None, :, :]) ** 2).sum(-1), np.inf).min(axis=2)
            cost[k:k + 32] += np.minimum(d2, 9.0).sum(axis=1)
            matched[k:k + 32] = (d2 < 9.0).sum(axis=1)
        i = int(np.argmin(cost))
        away = np.abs(g - g[i]) > 0.01
        margin = float(cost[away].min() - cost[i]) if away.any() else np.inf
        self.info.setdefault("feature_scale", []).append((n, float(g[i]), int(matched[i]), n_feat, margin))
        if matched[i] < self._FEATURE_MIN or margin < self._FEATURE_MARGIN:
            return None
        return float(g[i])

    def _feature_turn_step(self, raw, T, c, aware: bool):
        """The turn of this step from the feature's angle: ``(pose, whether it was set)``.

        The filter (:class:`~touchloc.mapping._feature_turn.FeatureTurn`) turns with every
        reported turn and takes this step's contacts; once it has seen the feature, and
        while the in-hand path runs (``aware``: the object, as touched so far, is a body of
        revolution about the odometry's axis), the pose and the particles are turned about
        the axis onto its turn, and the odometry's scale is its scale. The turn is counted
        from the first pose, about the first odometry's axis.
        """
        ft = self._feature_turn
        w = checked_rotations(raw[:3, :3]).as_rotvec()
        if self._turn_axis is None:
            if float(np.linalg.norm(w)) < 1e-9:
                return T, False
            self._turn_axis = w / np.linalg.norm(w)
        a = self._turn_axis
        # the axis's point: where the reported turn leaves the world fixed
        q = np.linalg.lstsq(np.eye(3) - raw[:3, :3], raw[:3, 3], rcond=None)[0]
        if self._turn_frame is None:
            # the axis in the object frame: the contacts' radii and heights are taken there
            # (the body of revolution stays put in it when the object tilts in the hand)
            self._turn_frame = (T[:3, :3].T @ (q - T[:3, 3]), T[:3, :3].T @ a)
        ft.predict(float(w @ a))
        self._turn_last = float(w @ a)
        self._turn_steps.append(len(self._steps))
        now = self._turn_of(T)
        if c is not None:
            ft.update((c.points - T[:3, 3]) @ T[:3, :3], *self._turn_frame, base=now)
        if not (aware and ft.started):
            return T, False
        corr = float(wrap(ft.turn - now))
        M = _about_axis(corr, a, q)
        self.particles = np.einsum("ij,njk->nik", M, self.particles)
        lo, hi = self._SCALE_RANGE
        self.odometry_scale = float(np.clip(ft.scale, lo, hi))
        self.info.setdefault("feature_turn", []).append((len(self._steps), float(np.degrees(corr)), ft.scale, ft.used))
        return M @ T, True

    def _turn_of(self, T) -> float:
        """The turn (rad) of pose ``T`` from the first pose about the feature filter's axis."""
        return float(checked_rotations(T[:3, :3] @ self.trajectory[0][:3, :3].T).as_rotvec() @ self._turn_axis)

    def _feature_seeking(self, touches):
        """``(p, nats)``: for touches (a list of GuardedTouch) made at the next update, in
        the object frame as the object is expected then (:meth:`predicted_pose`), the
        chance that each meets the feature whose angle sets the turn
        (:meth:`FeatureTurn.hit_probability`), and what meeting it would teach about the
        turn (:meth:`FeatureTurn.information`); zeros before the feature is known or
        before any odometry. The explorer adds it to a hand's score, so that a turn growing
        uncertain between visits sends the hand back to the feature, which the map,
        drawing it anew at each visit, may not show. (On an object turned in the hand that
        is no body of revolution, such as a box, the filter's feature is whatever stands
        out from the axis, its corners: they are sought too, though the turn there comes
        from the map.)"""
        ft = self._feature_turn
        p = np.zeros(len(touches))
        if not self._FEATURE_SEEK or ft is None or not ft.started or self._turn_last is None or not len(touches):
            return p, 0.0
        o = np.array([t.origin for t in touches])
        d = np.array([t.direction for t in touches])
        travel = np.array([t.max_travel for t in touches])
        turn = self._turn_last
        return (ft.hit_probability(o, d, travel, *self._turn_frame, turn, base=self._turn_of(self.predicted_pose())),
                ft.information(turn))

    def _smoothed_turns(self, poses):
        """``poses`` (the trajectory after its first entry, one per step) with each turned
        about the axis (through its own origin) onto the feature filter's smoothed turn,
        when the filter sets the turns and some pose is ``_REANCHOR_MIN`` or more off; else
        None. (The smoothing round's: the relocation of the map's touches that it needs is
        the round's own.)"""
        ft = self._feature_turn
        if ft is None or not ft.started or not any(st.get("turn_held") for st in self._steps):
            return None
        a = self._turn_axis
        d = np.array([float(wrap(t - self._turn_of(poses[j]))) for j, t in zip(self._turn_steps, ft.smoothed())])
        if not len(d) or np.max(np.abs(d)) < self._REANCHOR_MIN:
            return None
        out = np.array(poses, copy=True)
        for j, c in zip(self._turn_steps, d):
            out[j] = _about_axis(c, a, poses[j][:3, 3]) @ poses[j]
        self.info.setdefault("feature_reanchor", []).append((len(self._steps), float(np.degrees(np.max(np.abs(d))))))
        return out

    def _backfill_turn(self, D, T, since):
        """Spread a turn's correction over the steps that did not show the turn.

        When the contacts show the turn again after steps that did not (a handle touched
        again after touches on a mug's body), the correction this step makes is the
        odometry's error accumulated since step ``since`` (:meth:`_turn_since`: the step
        whose mapped surface the correction met, or the last step that showed the turn if
        later; None: nothing to spread); a biased odometry accumulates it in proportion
        to the turn. The poses of those steps are
        turned by their share (about the odometry's axis through their own origin), and
        their touches move with them in the map.
        """
        if since is None:
            return
        seg = list(range(since + 1, len(self._steps)))
        if not seg or any(self._steps[j]["motion"] is None for j in seg):
            return
        w = checked_rotations(D[:3, :3]).as_rotvec()
        a = w / np.linalg.norm(w)
        pred = D @ self.trajectory[-1]
        c = float(checked_rotations(T[:3, :3] @ pred[:3, :3].T).as_rotvec() @ a)
        # the turn made at each step of the segment, as applied
        turns = np.array([float(np.linalg.norm(checked_rotations(self._steps[j]["motion"][0][:3, :3]).as_rotvec()))
                          for j in seg] + [float(np.linalg.norm(w))])
        share = np.cumsum(turns)[:-1] / turns.sum()
        moves = [None] * len(self.map.batches)
        for j, f in zip(seg, share):
            old = self.trajectory[j + 1]
            new = old.copy()
            new[:3, :3] = Rotation.from_rotvec(c * f * a).as_matrix() @ old[:3, :3]
            self.trajectory[j + 1] = new
            if self._steps[j]["batch"] is not None:
                moves[self._steps[j]["batch"]] = np.linalg.inv(new) @ old
        if any(m is not None for m in moves):
            self.map.relocate(moves)

    def _systematic(self, w, n):
        """(n,) indices drawn from the weights ``w`` by systematic resampling."""
        idx = np.searchsorted(np.cumsum(w), (self.rng.random() + np.arange(n)) / n)
        return np.clip(idx, 0, len(w) - 1)

    def _mean_pose(self, P=None):
        """Weighted mean of the particles ``P`` (default: the current ones) under ``log_w``."""
        P = self.particles if P is None else P
        w = np.exp(self.log_w - logsumexp1d(self.log_w))
        T = np.eye(4)
        T[:3, 3] = w @ P[:, :3, 3]
        T[:3, :3] = checked_rotations(P[:, :3, :3]).mean(weights=w).as_matrix()
        return T

    @blas_threads
    def update(self, results, odometry=None) -> np.ndarray:
        """Fold in one step's touches, with an optional odometry prior on the motion.

        Parameters
        ----------
        results : TouchResult or list of TouchResult
            World frame.
        odometry : (4, 4) float, optional
            The hand's estimate of the object's motion since the last update, as a
            world-frame increment: ``T_now = odometry @ T_before``.

        Returns
        -------
        (4, 4) float
            The new pose estimate.
        """
        from .shape_map import _check_results

        results = _check_results(results)
        D = raw = None
        first = not self._steps
        if odometry is not None:
            D = raw = as_pose(odometry, "odometry")
            if self.learn_odometry_scale or self.odometry_scale != 1.0:
                D = _scaled_turn(D, self.odometry_scale)
            P = self.particles.copy()
            P[:, :3, :3] = D[:3, :3] @ P[:, :3, :3]
            P[:, :3, 3] = P[:, :3, 3] @ D[:3, :3].T + D[:3, 3]
            sig = self.odometry_noise
        elif first:
            # the first touches meet the object at initial_pose: it defines the map's frame
            P, sig = self.particles, None
        else:
            P = self.particles
            sig = self.motion
        self._last_odometry = D
        if sig is not None:
            P = _perturb(P, sig[0], sig[1], self.planar, self.rng)
            self._cov = self._predict_cov(self._cov, sig, D)
            if D is not None:
                # a commanded motion's error accumulates unseen (a turn's bias on a round
                # body); a push is re-measured by the touches that follow it
                P = self._inflate(P)
        self._turn_shown = None
        self._turn_draw = None
        got = None
        if self.map.n_contacts > 0:
            # the turn estimated apart is how a biased odometry's turns are learned: with the
            # scale fixed (the odometry trusted) the turn is scored with the rest of the pose
            got = (self._turn_aware(P, results, D)
                   if (D is not None and self._TURN_AWARE and self.learn_odometry_scale) else None)
            if got is None:
                ll = self._log_likelihood(P, results)
            else:
                P, ll = got
            lw = self.log_w + ll
            lw -= logsumexp1d(lw)
        else:
            lw = self.log_w
        ess = float(np.exp(-logsumexp1d(2 * lw)))
        self.info["ess"].append(ess)
        if ess < 0.5 * len(P):
            w = np.exp(lw)
            idx = np.searchsorted(np.cumsum(w), (self.rng.random() + np.arange(len(P))) / len(P))
            P = P[np.clip(idx, 0, len(P) - 1)]
            lw = np.full(len(P), -np.log(len(P)))
        if self._turn_draw is not None:
            # the turns drawn by _turn_aware, dealt out again: resampling on the other
            # components picks few ancestors when the contacts pin them, and their turns
            # would move the mean by the turns' spread over the root of that few
            T0, u, a, dn = self._turn_draw
            xi = self._twists(P, T0)
            P = self._from_twists(T0, xi - (xi[:, 3:] @ a)[:, None] * u + self.rng.permutation(dn)[:, None] * u)
            self._turn_draw = None
        self.particles, self.log_w = P, lw
        T = self._mean_pose()
        fisher = None
        if sig is not None:
            self._cov, fisher = self._update_cov(self._cov, T, results)
        hits = [r.contact for r in results if r.contact is not None]
        c = Contacts.concatenate(hits) if hits else None
        held = False
        if self._feature_turn is not None and raw is not None:
            T, held = self._feature_turn_step(raw, T, c, got is not None)
        shown = D is not None and bool(self._turn_shown) and not held
        if shown and self._FEATURE_SCALE and self.learn_odometry_scale and self.odometry_scale_sd > 0.0:
            fit = self._feature_scale(raw, T, c)
            if fit is not None:
                self._feature_fit = fit
        if shown and self._feature_fit is not None:
            # from the first fit on, the features' agreement holds the scale, and every turn
            # is the odometry's at that scale
            self.odometry_scale = self._feature_fit
            self.info.setdefault("odometry_scale", []).append(self._feature_fit)
            T = self._reanchor(raw, T, anchor=len(self._steps))
        else:
            since = self._turn_since(T) if shown else None
            if D is not None and self.learn_odometry_scale:
                self._learn_scale(D, T, results, fisher, since)
            if shown and self._TURN_BACKFILL:
                self._backfill_turn(D, T, since)
            if (shown and self._REANCHOR and self.learn_odometry_scale and self._anchor is not None
                    and self._scale_obs):
                T = self._reanchor(raw, T)
        self.trajectory.append(T)
        local = transform_results(results, np.linalg.inv(T))
        keep = []
        lo, hi = self.map.lo, self.map.hi
        for r in local:
            if r.contact is not None and np.any((r.contact.points < lo) | (r.contact.points > hi)):
                self.info["dropped"] += 1
                continue
            keep.append(r)
        if keep:
            self.map.update(keep)
        self._steps.append(dict(contacts=c, motion=None if sig is None else (np.eye(4) if D is None else D, sig),
                                batch=len(self.map.batches) - 1 if keep else None, turn_shown=self._turn_shown,
                                odometry=raw, turn_held=held))
        if self.smooth_every and len(self._steps) >= self._next_smooth:
            self.smooth()
            k = len(self._steps)
            # the interval grows with the trajectory (a quarter of its length), so the cost
            # of smoothing, which grows with the map, stays a small share of every update
            self._next_smooth = k + max(self.smooth_every, k // 4)
        return self.trajectory[-1].copy()

    @blas_threads
    def smooth(self) -> dict:
        """Revise the poses at once (the last ``smooth_window`` of them) and move the map's
        touches with them.

        Runs by itself on the schedule set by ``smooth_every``; call it at the end of a
        run for a final pass. Returns the smoother's record (also appended to
        ``info["smoothing"]``); nothing changes when the contacts carry no normals, when
        there are fewer than two steps, or when the revision would not lower the cost.
        """
        from .smoother import smooth_trajectory

        steps = [(i, st["contacts"]) for i, st in enumerate(self._steps) if st["contacts"] is not None]
        rec = dict(pairs=0, iterations=0, cost=(0.0, 0.0), accepted=False, max_change=0.0)
        if len(self._steps) < 2 or not steps or any(c.normals is None for _, c in steps) or self.map.method != "gpis":
            self.info["smoothing"].append(rec)
            return rec
        old = np.array(self.trajectory[1:])
        # with the turn from the feature's angle: every pose onto the filter's smoothed turn
        # first (the turns the smoother then holds), moved in the map with the round's moves
        start = self._smoothed_turns(old)
        new, info = smooth_trajectory(
            old if start is None else start, self.trajectory[0], np.concatenate([c.points for _, c in steps]),
            np.concatenate([c.normals for _, c in steps]), np.concatenate([np.full(len(c), i) for i, c in steps]),
            [st["motion"] for st in self._steps], planar=self.planar, sigma_pos=self.map.sigma_pos,
            sigma_nor=self.map.sigma_nor, radius=self.map.lengthscale,
            hold=max(0, len(self._steps) - self.smooth_window) if self.smooth_window else 0,
            fixed_turns=([st.get("turn_shown") is False or st.get("turn_held", False) for st in self._steps]
                         if self._SMOOTH_FIX_TURNS else None))
        rec.update(info)
        if start is not None and not info["accepted"]:
            new = start       # the smoother's revision refused, the smoothed turns kept
        if info["accepted"] or start is not None:
            # the map moves each step's touches from its old pose to its new one (object frame);
            # steps whose contacts move by less than a tenth of the sensor's noise stay
            # (a step without contacts, whose batch holds only swept free space, is measured
            # at the map box's corners, which bound its points; a held step, whose revision
            # is the identity up to rounding, must not force a refit from its rows on)
            moves = [None] * len(self.map.batches)
            box = self.map._corners()
            for st, a, b in zip(self._steps, new, old):
                A = np.linalg.inv(a) @ b
                if st["contacts"] is not None:
                    x = (st["contacts"].points - b[:3, 3]) @ b[:3, :3]
                    shift = float(np.max(np.linalg.norm(x @ A[:3, :3].T + A[:3, 3] - x, axis=1)))
                    rec["max_change"] = max(rec["max_change"], shift)
                elif st["batch"] is not None:
                    shift = float(np.max(np.linalg.norm(box @ A[:3, :3].T + A[:3, 3] - box, axis=1)))
                if st["batch"] is not None and shift >= 0.1 * self.map.sigma_pos:
                    moves[st["batch"]] = A
            self.map.relocate(moves)
            # the particles follow the correction of the current pose
            C = new[-1] @ np.linalg.inv(old[-1])
            self.particles = np.einsum("ij,njk->nik", C, self.particles)
            self.trajectory = [self.trajectory[0]] + [T.copy() for T in new]
        self.info["smoothing"].append(rec)
        return rec

    # tuning of the odometry-scale estimate (see _learn_scale)
    _SCALE_GAIN = 0.05
    _SCALE_RANGE = (0.8, 1.25)
    _SCALE_MIN_CONTACTS = 30
    _SCALE_MIN_INFO = 0.05
    _SCALE_KALMAN = True
    _SCALE_MEAS_SD = np.deg2rad(3.0)

    _SCALE_MIXTURE = True
    _SCALE_INLIER = 0.8

    def _scale_posterior(self):
        """(median, variance) of the scale's posterior on a grid: the prior, and each
        measured scale z an inlier N(s, sd) or, with probability 1 - _SCALE_INLIER, an
        outlier uniform over the scale's range."""
        lo, hi = self._SCALE_RANGE
        g = np.linspace(lo, hi, 901)
        s0 = self._scale0
        sd0 = max(self.odometry_scale_sd, 1e-6) * s0
        lp = -0.5 * ((g - s0) / sd0) ** 2
        z, zs = (np.array(v) for v in zip(*self._scale_obs))
        dens = np.exp(-0.5 * ((g[:, None] - z) / zs) ** 2) / (np.sqrt(2 * np.pi) * zs)
        lp += np.log(self._SCALE_INLIER * dens + (1 - self._SCALE_INLIER) / (hi - lo)).sum(axis=1)
        p = np.exp(lp - lp.max())
        p /= p.sum()
        med = float(g[np.searchsorted(np.cumsum(p), 0.5)])
        mean = float(p @ g)
        return med, float(p @ (g - mean) ** 2) / s0**2

    def _learn_scale(self, D, T, results, fisher, since=None):
        """Move the odometry's turn scale by a fraction of the turn the map corrected away.

        The map's correction of the predicted pose, projected on the odometry's turn axis,
        is an innovation; a biased odometry makes it consistently one-signed, and its sum
        (an integral term, with a small gain) converges to the scale that makes it zero on
        average. Guards: only with a map of some size and at least two contacts in the
        step (one contact hardly fixes a turn), only from a step whose contacts show the
        turn (``fisher``: their rotation levers and noise variances, from
        :meth:`_update_cov`; a mug's body shows nothing), a small gain, and a clipped
        range. A correction counts against all the turn made since the last step that
        showed one, not this step's alone.

        With the turn estimated apart (:meth:`_turn_aware`), a step shows the turn when
        some contact moved it: the correction c after a turn U made since the surface it
        was measured against was touched (:meth:`_turn_since`) measures the scale's
        relative error e as ``c = e U``, with the odometry's noise over those steps and the
        grid posterior's variance (at least ``_SCALE_MEAS_SD``) as its noise. Each such
        measurement of the scale is kept, and the scale is the median of its posterior on
        a grid (:meth:`_scale_posterior`): the prior of ``odometry_scale_sd`` about the
        start, and every measurement either right, with its noise, or (one in five) an
        outlier, uniform over the scale's range, because one handle contact does match the
        wrong face of a handle. (Before: a Kalman update from each correction, with U the
        turn since the last step that showed one, and corrections beyond three standard
        deviations ignored; ``_TURN_REF`` and ``_SCALE_MIXTURE`` off.)
        """
        w = checked_rotations(D[:3, :3]).as_rotvec()
        theta = float(np.linalg.norm(w))
        # the turn made since the last step that showed one: a correction now is the bias
        # of all of it, not of this step's turn alone
        self._unseen_turn += theta
        self._unseen_steps += 1
        n_hit = sum(len(r.contact) for r in results if r.contact is not None)
        if (self.odometry_scale_sd == 0.0 or theta < 1e-6 or n_hit < 2
                or self.map.n_contacts < self._SCALE_MIN_CONTACTS):
            return   # (a scale held by odometry_scale_sd=0 is not learned)
        # only a step whose contacts show the turn: their Fisher information about it must
        # be worth a twentieth of one step's odometry noise (a mug's body shows nothing)
        if self._turn_shown is not None:
            # the turn was estimated apart (_turn_aware): only a step whose contacts moved it counts
            if not self._turn_shown:
                return
        else:
            if fisher is None:
                return
            lever, r = fisher
            a = self.trajectory[-1][:3, :3].T @ (w / theta)
            if float(np.sum((lever @ a) ** 2 / r)) * self.odometry_noise[1] ** 2 < self._SCALE_MIN_INFO:
                return
        pred = D @ self.trajectory[-1]
        innov = checked_rotations(T[:3, :3] @ pred[:3, :3].T).as_rotvec() @ (w / theta)
        if self._turn_shown is not None and self._SCALE_KALMAN:
            # the correction is the relative scale error times the turn made unseen, U, plus the
            # odometry's noise over those steps and the correction's own error: a Kalman update
            U, n = self._unseen_turn, self._unseen_steps
            if self._TURN_REF:
                if since is None:
                    return
                U, n = self._turn_made(since, theta)
            r = self.odometry_noise[1] ** 2 * n + max(self._turn_post_var, self._SCALE_MEAS_SD**2)
            if self._SCALE_MIXTURE:
                self._scale_obs.append((self.odometry_scale * (1.0 + innov / U), self.odometry_scale * np.sqrt(r) / U))
                s, self._scale_var = self._scale_posterior()
            else:
                S = U * U * self._scale_var + r
                if innov * innov > 9.0 * S:
                    # beyond three standard deviations of what a scale error and the noise explain
                    return
                K = self._scale_var * U / S
                s = self.odometry_scale * (1.0 + K * innov)
                self._scale_var = (1.0 - K * U) * self._scale_var
        else:
            s = self.odometry_scale * (1.0 + self._SCALE_GAIN * innov / self._unseen_turn)
        self._unseen_turn = 0.0
        self._unseen_steps = 0
        self.odometry_scale = float(np.clip(s, *self._SCALE_RANGE))
        self.info.setdefault("odometry_scale", []).append(self.odometry_scale)

    def _log_likelihood(self, P, results):
        """(N,) log-likelihood of world-frame touches for each pose particle, against the map.

        Less the same terms scored against the map's prior mean alone (a sphere fitted to
        the contacts, ``signal_std`` about it): the prior is a placeholder shape, not
        evidence about where the object is, so a touch where the map knows nothing more
        than the prior says nothing about the pose, and one on mapped surface says as much
        as the map adds. (Scored against the prior as well, touches on parts not yet
        mapped pulled the pose towards fitting the sphere: on the milk carton the second
        step's estimate moved 7 mm the wrong way.)
        """
        hits = [r.contact for r in results if r.contact is not None]
        c = Contacts.concatenate(hits) if hits else None
        return self._ll_contacts(P, c) + self._ll_free(P, results)

    def _ll_contacts(self, P, c):
        """(N,) the contacts' share of :meth:`_log_likelihood` (``c`` world-frame Contacts or None)."""
        pos, nor = self._contact_terms(P, c)
        return pos.sum(axis=1) + nor.sum(axis=1)

    def _contact_terms(self, P, c, *, own_sd: bool = False, floor: float = 0.0, normals: bool = True):
        """``(pos (N, K), nor (N, K))``: each contact's position and normal terms of
        :meth:`_log_likelihood` at each pose of ``P``, each less its prior's. The map's
        standard deviation is taken at the mean pose's points, or with ``own_sd`` at each
        pose's own; ``normals=False`` leaves the normal terms at zero (and skips the map's
        gradient)."""
        smap = self.map
        gpis = smap.method == "gpis"
        normals = normals and gpis and c is not None and c.normals is not None
        prior_var = smap.signal_std**2
        N = len(P)
        K = 0 if c is None else len(c)
        pos, nor = np.zeros((N, K)), np.zeros((N, K))
        if K == 0:
            return pos, nor
        Rt = np.transpose(P[:, :3, :3], (0, 2, 1))
        x = np.einsum("nij,nkj->nki", Rt, c.points[None, :, :] - P[:, None, :3, 3]).reshape(-1, 3)
        if normals:
            mu, g = smap._gp.mean_grad(x)
        else:
            mu = smap._gp.mean(x) if gpis else smap.signed_distance(x)
        if own_sd:
            sd = smap.surface_std(np.clip(x, smap.lo, smap.hi))
        else:
            # the map's own uncertainty, evaluated once at the mean pose's points
            T = self._mean_pose()
            sd = np.tile(smap.surface_std((c.points - T[:3, 3]) @ T[:3, :3]), N)
        var = sd**2 + smap.sigma_pos**2 + floor**2
        pos += (-0.5 * mu**2 / var).reshape(N, K)
        if gpis:
            pm, pg = smap._gp.prior(x)
            pos += (0.5 * pm**2 / (prior_var + smap.sigma_pos**2 + floor**2)).reshape(N, K)
        if normals:
            g /= np.maximum(np.linalg.norm(g, axis=1), 1e-9)[:, None]
            n_loc = np.einsum("nij,nkj->nki", Rt, np.broadcast_to(c.normals, (N,) + c.normals.shape)).reshape(-1, 3)
            # the map's normal is as uncertain as its gradient: for the squared-exponential
            # kernel the gradient's standard deviation is about the value's over the length scale
            var_n = (sd / smap.lengthscale) ** 2 + smap.sigma_nor**2
            nor += (-0.5 * np.sum((g - n_loc) ** 2, axis=1) / var_n).reshape(N, K)
            pvar_n = prior_var / smap.lengthscale**2 + smap.sigma_nor**2
            nor += (0.5 * np.sum((pg - n_loc) ** 2, axis=1) / pvar_n).reshape(N, K)
        return pos, nor

    def _ll_free(self, P, results):
        """(N,) the swept free space's share of :meth:`_log_likelihood`."""
        smap = self.map
        prior_var = smap.signal_std**2
        N = len(P)
        ll = np.zeros(N)
        Rt = np.transpose(P[:, :3, :3], (0, 2, 1))
        # free space: swept points should lie outside
        pts = []
        for r in results:
            s, e = r.swept_segment
            L = float(np.linalg.norm(e - s))
            gap = (r.touch.probe_radius + 3 * smap.sigma_pos + 0.002) if r.hit else 0.0
            t = np.arange(L - gap, 0.0, -0.5 * smap.lengthscale)
            if len(t):
                pts.append(s + np.outer(t / L, e - s))
        if pts and smap.method == "gpis":
            Y = np.concatenate(pts)
            Y = Y[np.linspace(0, len(Y) - 1, min(len(Y), 16)).astype(int)]
            y = np.einsum("nij,nkj->nki", Rt, Y[None, :, :] - P[:, None, :3, 3]).reshape(-1, 3)
            inb = np.all((y >= smap.lo) & (y <= smap.hi), axis=1)
            mu = np.full(len(y), 1.0)
            pm = np.full(len(y), 1.0)
            if np.any(inb):
                # the mean in single precision: 2.6x faster (the kernel's exponentials), off by
                # at most a few micrometres against a scale of at least 2 sigma_pos (mm)
                mu[inb] = smap._gp.mean(y[inb], dtype=np.float32)
                pm[inb] = smap._gp.prior(y[inb])[0]
            # where the map is unsure, a swept point inside its mean is weak evidence against the pose
            T = self._mean_pose()
            sd = smap.surface_std(np.clip((Y - T[:3, 3]) @ T[:3, :3], smap.lo, smap.hi))
            scale = np.sqrt(np.tile(sd**2, N) + (2 * smap.sigma_pos + 1e-4) ** 2)
            ll += log_ndtr(mu / scale).reshape(N, -1).sum(axis=1)
            ll -= log_ndtr(pm / np.sqrt(prior_var + (2 * smap.sigma_pos + 1e-4) ** 2)).reshape(N, -1).sum(axis=1)
        return ll


def _pose_jacobian(x, n, sigma_nor):
    """(..., 6) how a contact's offset along the surface normal moves with the pose.

    A contact at ``x`` (object frame) on a surface with unit normal ``n`` measures
    ``n . (v + w x x)`` for a pose change ``(v, w)``: the row is ``[n, x x n]``. The
    lever ``x x n`` is only as good as the normal: a normal off by an angle of
    ``sigma_nor`` moves each of its components (about the object's axes) by up to
    ``sigma_nor`` times the distance of ``x`` from that axis, so each component is
    shrunk by that much (positive-part, as a James-Stein estimate): on a solid of
    revolution, a normal a few degrees off the radius no longer lends a contact a lever
    about the axis that the surface does not have.
    """
    lever = np.cross(x, n)
    x2 = x * x
    dist2 = np.stack([x2[..., 1] + x2[..., 2], x2[..., 0] + x2[..., 2], x2[..., 0] + x2[..., 1]], axis=-1)
    noise2 = sigma_nor**2 * dist2
    shrink = np.clip(1.0 - noise2 / np.maximum(lever * lever, 1e-30), 0.0, None)
    return np.concatenate([n, lever * shrink], axis=-1)


def _about_axis(angle: float, a, p) -> np.ndarray:
    """The rigid turn by ``angle`` (rad) about the unit axis ``a`` through the point ``p``."""
    M = np.eye(4)
    M[:3, :3] = Rotation.from_rotvec(angle * np.asarray(a)).as_matrix()
    M[:3, 3] = p - M[:3, :3] @ p
    return M


def _scaled_turn(D, scale):
    """The rigid motion ``D`` with its turn angle scaled, about the same fixed axis."""
    w = checked_rotations(D[:3, :3]).as_rotvec()
    if np.linalg.norm(w) < 1e-9 or scale == 1.0:
        return D
    R = D[:3, :3]
    # a point c on the turn's axis: (I - R) c = t (least squares; exact for a pure turn)
    c = np.linalg.lstsq(np.eye(3) - R, D[:3, 3], rcond=None)[0]
    Rs = Rotation.from_rotvec(scale * w).as_matrix()
    out = np.eye(4)
    out[:3, :3] = Rs
    out[:3, 3] = c - Rs @ c + (D[:3, 3] - (c - R @ c))   # keep any slide along the axis
    return out
