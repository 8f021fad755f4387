"""Guarded touches on the real (or emulated) SDH-2: move, watch the pads, stop at contact.

A :class:`~touchloc.planners.GuardedTouch` is a straight line in the world. On the SDH-2 a
finger's probe point (the centre of its distal pad surface) can follow a line lying in the
finger's plane (the plane through its proximal joint spanned by the hand's z axis and the
closing direction, set by the base angle a0). The executor picks such a finger, solves the
planar inverse kinematics along the line in small steps, and after each step reads a
tactile frame: the touch ends at the first step whose frame shows a pressure blob at or
above the threshold on the moving finger (or whose axes report "blocked").

On any fault the executor sends ``stop`` to the hand and re-raises the typed error. Every
finished touch can be appended to a :class:`~touchloc.hardware.session.SessionLog`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_bool, as_count, as_float_array, as_instance, as_pose, as_positive_float, as_timeout
from ..errors import HardwareError, TouchlocError, ValidationError
from ..models import Contacts
from ..planners import GuardedTouch, HandTouch, TouchResult
from .kinematics import FINGER_AXES, SDH2Kinematics
from .session import SessionLog
from .tactile import blobs_to_contacts, find_blobs

__all__ = ["GuardedTouchExecutor", "TouchPlan", "TouchAborted", "HandWorld"]


class TouchAborted(HardwareError):
    """A touch could not be carried out as planned (e.g. a finger blocked on its way to the start)."""


@dataclass(frozen=True)
class TouchPlan:
    """How a guarded touch is made: the finger, its base angle and the joint path.

    Attributes
    ----------
    finger : int
    a0 : float
        Base angle (rad; 0 for the thumb).
    travel : (M,) float
        Distance along the touch line of each waypoint (m).
    angles : (M, 7) float
        Joint angles (rad) of each waypoint.
    """

    finger: int
    a0: float
    travel: np.ndarray
    angles: np.ndarray


class GuardedTouchExecutor:
    """Runs guarded touches on an SDH-2 with DSACON32m pads.

    Parameters
    ----------
    hand : SDH2
    tactile : DSACON32m
    kinematics : SDH2Kinematics, optional
        Default: the standard kinematics with the pad sizes the controller reported.
    hand_pose : (4, 4) float, optional
        T_world_hand (default identity: the world is the hand frame).
    threshold : int
        Texel value (0..4095) that counts as contact (default 200).
    step : float
        Waypoint spacing along the touch line (m; default 2 mm).
    speed : float
        Joint speed (rad/s) for the steps (default 60 deg/s; clipped to the hand's limits).
    rest_angles : (7,) float, optional
        Open posture the hand passes through before and after each touch (rad). Default:
        proximal joints at -30 deg, distal at +30 deg (fingers opened outwards).
    log : SessionLog or path, optional
        Where every executed touch is appended.
    move_timeout : float
        Shortest time (s) allowed for one move before it counts as stuck (moves whose
        expected duration is long get three times that duration plus a second).
    retreat : bool
        Move the finger back to the start of the line and to the rest posture after
        each touch (default True).
    mode : {"steps", "velocity"}
        ``"steps"``: one position move (``m``) per waypoint, a tactile frame after each.
        ``"velocity"``: the velocity controller (``con=1``): joint velocities towards a
        point a few millimetres ahead on the line are sent with ``tvav`` after every
        tactile frame, until contact; then velocities 0, ``stop`` and ``con=0``.
    probe_speed : float
        Speed of the probe point along the line in velocity mode (m/s).
    """

    def __init__(self, hand, tactile, *, kinematics: SDH2Kinematics | None = None, hand_pose=None,
                 threshold: int = 200, step: float = 0.002, speed: float = math.radians(60),
                 rest_angles=None, log=None, move_timeout: float = 5.0, retreat: bool = True,
                 mode: str = "steps", probe_speed: float = 0.02):
        missing = [m for m in ("actual_angles", "move", "stop", "wait_until_idle") if not hasattr(hand, m)]
        if missing:
            raise ValidationError(f"hand must be an SDH2 (or have {', '.join(missing)}), got {type(hand).__name__}")
        if not callable(getattr(tactile, "read_frame", None)):
            raise ValidationError(f"tactile must be a DSACON32m (or have read_frame()), got {type(tactile).__name__}")
        self.hand = hand
        self.tactile = tactile
        kinematics = as_instance(kinematics, SDH2Kinematics, "kinematics", allow_none=True)
        if kinematics is None:
            kinematics = SDH2Kinematics()
            infos = getattr(tactile, "matrix_infos", None)
            if infos and len(infos) == 6:
                kinematics = kinematics.with_matrix_info(infos)
        self.kinematics = kinematics
        T = np.eye(4) if hand_pose is None else as_pose(hand_pose, "hand_pose (T_world_hand)")
        self.hand_pose = T
        self._hand_from_world = np.linalg.inv(T)
        self.threshold = as_count(threshold, "threshold (texel units)", min=1, max=4095)
        self.step = as_positive_float(step, "step (m)", high=0.1)
        self.speed = as_positive_float(speed, "speed (rad/s)")
        if rest_angles is None:
            rest = np.radians([0.0, -30, 30, -30, 30, -30, 30])
        else:
            rest = as_float_array(rest_angles, "rest_angles", shape=(7,), expected="7 finite joint angles (rad)")
        self.rest_angles = rest
        self.log = SessionLog(log) if log is not None and not isinstance(log, SessionLog) else log
        self.move_timeout = as_timeout(move_timeout, "move_timeout")
        self.retreat = as_bool(retreat, "retreat")
        if not isinstance(mode, str) or mode not in ("steps", "velocity"):
            raise ValidationError(f"mode must be 'steps' or 'velocity', got {mode!r}")
        self.mode = mode
        self.probe_speed = as_positive_float(probe_speed, "probe_speed (m/s)")
        self.stops_sent = 0

    # -- planning (no I/O) ----------------------------------------------------------------
    def finger_touch(self, finger: int, a0: float, start, end, *, name: str = "") -> GuardedTouch:
        """A GuardedTouch (world frame) along a line of a finger's plane.

        Parameters
        ----------
        finger : int
        a0 : float
            Base angle (rad; ignored for the thumb).
        start, end : (2,) float
            (r, z) in the finger plane: along the closing direction and along the hand's
            z axis, from the proximal joint (m).
        """
        kin = self.kinematics
        start = as_float_array(start, "start", shape=(2,), expected="(r, z) in the finger plane (m)")
        end = as_float_array(end, "end", shape=(2,), expected="(r, z) in the finger plane (m)")
        if not isinstance(name, str):
            raise ValidationError(f"name must be a str, got {type(name).__name__}")
        p = kin.plane_to_hand(finger, a0, [start[0], end[0]], [start[1], end[1]])
        pw = p @ self.hand_pose[:3, :3].T + self.hand_pose[:3, 3]
        d = pw[1] - pw[0]
        return GuardedTouch(pw[0], d, float(np.linalg.norm(d)), name=name or f"finger {finger}")

    def touch_pool(self, n: int = 24, *, rng=None, heights=(0.095, 0.125), reach=(-0.03, 0.04)) -> list:
        """``n`` random touches the hand can make: a finger (0 or 2, or the thumb) at a random
        base angle closing along a line of its plane at a random height.

        A candidate pool for planners that pick among touches (``explore(..., candidates=)``),
        for a hand mounted fingers down over the object, as in the examples.

        Parameters
        ----------
        n : int
        rng : None, int or Generator
        heights : (float, float)
            Range of z below the proximal joints (m), along the hand's z axis.
        reach : (float, float)
            Start and end of each line along the closing direction (m).

        Returns
        -------
        list of GuardedTouch
            Each one reachable (checked with :meth:`plan`).
        """
        from .._util import as_rng

        n = as_count(n, "n", max=10_000, why="touches")
        rng = as_rng(rng)
        try:
            z0, z1 = (float(v) for v in heights)
            r0, r1 = (float(v) for v in reach)
        except (TypeError, ValueError):
            raise ValidationError(f"heights and reach must be two numbers each (m), got {heights!r}, {reach!r}") from None
        if not all(np.isfinite(v) for v in (z0, z1, r0, r1)) or not (0 <= z0 <= z1 < 0.3 and r0 < r1):
            raise ValidationError(f"heights must satisfy 0 <= lo <= hi < 0.3 and reach lo < hi (m), got {heights!r}, {reach!r}")
        out, tries = [], 0
        while len(out) < n and tries < 50 * n:
            tries += 1
            f = int(rng.choice([0, 1, 2]))
            a0 = 0.0 if f == 1 else float(rng.uniform(0.0, np.pi / 2))
            z = float(rng.uniform(z0, z1))
            t = self.finger_touch(f, a0, (r0, z), (r1, z), name=f"finger {f} a0={np.degrees(a0):.0f} z={z * 1e3:.0f}mm")
            try:
                self.plan(t, finger=f)
            except ValidationError:
                continue
            out.append(t)
        if not out:
            raise ValidationError("no reachable touch in the given heights and reach")
        return out

    def plan(self, touch: GuardedTouch, *, finger: int | None = None) -> TouchPlan:
        """Choose a finger and the joint path for ``touch`` (raises ValidationError if none can)."""
        if not isinstance(touch, GuardedTouch):
            raise ValidationError(f"touch must be a GuardedTouch, got {type(touch).__name__}")
        kin = self.kinematics
        R, t = self._hand_from_world[:3, :3], self._hand_from_world[:3, 3]
        o = R @ touch.origin + t
        d = R @ touch.direction
        lo, hi = self.hand.angle_limits
        fingers = (1, 0, 2) if finger is None else (kin._finger(finger),)
        reasons = []
        for f in fingers:
            a0 = kin.touch_plane(f, o, d, a0_limits=(lo[0], hi[0]))
            if a0 is None:
                reasons.append(f"finger {f}: the line is not in any of its planes")
                continue
            n = max(2, int(math.ceil(touch.max_travel / self.step)) + 1)
            travel = np.linspace(0.0, touch.max_travel, n)
            pts = o + travel[:, None] * d
            c = kin.closing_direction(f, a0)
            rel = pts - kin.bases[f]
            r, z = rel @ c, rel[:, 2]
            ax = FINGER_AXES[f]
            lim = (np.array([lo[ax[1]], lo[ax[2]]]), np.array([hi[ax[1]], hi[ax[2]]]))
            path = np.tile(self.rest_angles, (n, 1))
            if ax[0] is not None:
                path[:, 0] = a0
            prev = None
            ok = True
            for i in range(n):
                q = kin.planar_ik(f, float(r[i]), float(z[i]), limits=lim, prefer=prev)
                if q is None:
                    reasons.append(f"finger {f}: waypoint {i} ({travel[i] * 1e3:.1f} mm along) is out of reach")
                    ok = False
                    break
                path[i, ax[1]], path[i, ax[2]] = q
                prev = q
            if ok:
                return TouchPlan(f, float(a0), travel, path)
        raise ValidationError(f"touch {touch.name or ''} cannot be made by any finger: " + "; ".join(reasons))

    # -- execution ------------------------------------------------------------------------
    def _stop(self) -> None:
        """Best-effort stop after a fault."""
        try:
            self.hand.stop()
        except Exception:  # a dead link or a garbled answer to stop: the stop went out or could not
            pass
        self.stops_sent += 1

    def execute(self, touch: GuardedTouch, *, finger: int | None = None) -> TouchResult:
        """Run one guarded touch; returns its :class:`TouchResult` (contacts in the world frame).

        Raises
        ------
        ValidationError
            No finger can make the touch (nothing was sent).
        HardwareError
            Any fault of the hand or the pads (after ``stop`` was sent).
        """
        plan = self.plan(touch, finger=finger)
        try:
            result, angles, blobs = self._run(touch, plan)
        except TouchlocError:
            self._stop()
            raise
        except Exception as exc:  # never let a raw error leave a motion command
            self._stop()
            raise HardwareError(f"guarded touch {touch.name!r} failed: {type(exc).__name__}: {exc}") from exc
        except BaseException:  # KeyboardInterrupt, SystemExit: stop, and let them through
            self._stop()
            raise
        if self.log is not None:
            self.log.append(result, finger=plan.finger, angles=angles, hand_pose=self.hand_pose,
                            blobs=[{"matrix": b.matrix, "centroid": b.centroid, "covariance": b.covariance,
                                    "pressure": b.pressure, "n_texels": b.n_texels} for b in blobs])
        return result

    def execute_action(self, action) -> list:
        """Run a GuardedTouch or each touch of a HandTouch in turn; one TouchResult per touch."""
        if isinstance(action, GuardedTouch):
            return [self.execute(action)]
        if isinstance(action, HandTouch):
            return [self.execute(t) for t in action.touches]
        raise ValidationError(f"action must be a GuardedTouch or HandTouch, got {type(action).__name__}")

    def _contact(self, touch, f, angles, blobs):
        kin = self.kinematics
        probe = self.hand_pose[:3, :3] @ kin.probe_point(angles, f) + self.hand_pose[:3, 3]
        travel = float(np.clip((probe - touch.origin) @ touch.direction, 0.0, touch.max_travel))
        if blobs:
            contact = blobs_to_contacts(blobs)
        else:  # blocked without pressure: the probe point is the best guess
            n = -(self.hand_pose[:3, :3] @ kin.finger_chain(angles, f)["n_d"])
            contact = Contacts(probe[None], n[None])
        return TouchResult(touch, travel, contact)

    def _look(self, plan, pads):
        frame = self.tactile.read_frame()
        angles = self.hand.actual_angles()
        blobs = find_blobs(frame, angles, self.kinematics, threshold=self.threshold, matrices=pads,
                           hand_pose=self.hand_pose)
        return angles, blobs

    def _stepped_touch(self, touch, plan, ax, pads, st):
        for i in range(len(plan.travel)):
            if i > 0:
                st = self._move(plan.angles[i])
            angles, blobs = self._look(plan, pads)
            if blobs or np.any(np.isin(st[ax], (4, 5))):
                return self._contact(touch, plan.finger, angles, blobs), angles, blobs
        angles = self.hand.actual_angles()
        return TouchResult(touch, touch.max_travel, None), angles, []

    def _velocity_touch(self, touch, plan, ax, pads):
        hand, kin = self.hand, self.kinematics
        f = plan.finger
        lookahead = max(2.0 * self.step, 0.003)
        horizon = lookahead / self.probe_speed      # s to reach the look-ahead point
        vmax = np.minimum(np.full(7, self.speed), hand.velocity_limits)
        zero = np.zeros(7)
        deadline = time.monotonic() + 3.0 * touch.max_travel / self.probe_speed + self.move_timeout
        hand.controller(1)
        try:
            while True:
                angles, blobs = self._look(plan, pads)
                st = hand.state()
                if blobs or np.any(np.isin(st[ax], (4, 5))):
                    hand.set_velocities_get_actual(zero)
                    self._leave_velocity_mode(vmax)
                    return self._contact(touch, f, angles, blobs), angles, blobs
                probe = self.hand_pose[:3, :3] @ kin.probe_point(angles, f) + self.hand_pose[:3, 3]
                t_cur = float((probe - touch.origin) @ touch.direction)
                if t_cur >= touch.max_travel - 1e-4:
                    hand.set_velocities_get_actual(zero)
                    self._leave_velocity_mode(vmax)
                    return TouchResult(touch, touch.max_travel, None), angles, []
                if time.monotonic() > deadline:
                    raise TouchAborted(f"velocity touch {touch.name!r} made no progress "
                                       f"({t_cur * 1e3:.1f} of {touch.max_travel * 1e3:.1f} mm)")
                t_tgt = min(max(t_cur, 0.0) + lookahead, touch.max_travel)
                q_tgt = np.array([np.interp(t_tgt, plan.travel, plan.angles[:, j]) for j in range(7)])
                v = np.zeros(7)
                v[ax] = np.clip((q_tgt[ax] - angles[ax]) / horizon, -vmax[ax], vmax[ax])
                hand.set_velocities_get_actual(v)
        except BaseException:
            try:  # best effort; the original error is what the caller needs
                hand.stop()
                hand.controller(0)
            except Exception:
                pass
            raise

    def _leave_velocity_mode(self, vmax) -> None:
        self.hand.stop()
        self.hand.controller(0)
        self.hand.set_target_velocities(vmax)  # position moves use them as speeds

    def _move(self, angles) -> np.ndarray:
        duration = self.hand.move(angles)
        return self.hand.wait_until_idle(max(self.move_timeout, 3.0 * duration + 1.0))

    def _run(self, touch: GuardedTouch, plan: TouchPlan):
        hand = self.hand
        f = plan.finger
        ax = [a for a in FINGER_AXES[f] if a is not None]
        pads = (2 * f, 2 * f + 1)
        hand.set_target_velocities(np.minimum(np.full(7, self.speed), hand.velocity_limits))
        rest = self.rest_angles.copy()
        if FINGER_AXES[f][0] is not None:
            rest[0] = plan.a0
        else:  # the thumb leaves the shared base axis of fingers 0 and 2 where it is
            rest[0] = hand.actual_angles()[0]
            path = plan.angles.copy()
            path[:, 0] = rest[0]
            plan = replace(plan, angles=path)
        self._move(rest)
        st = self._move(plan.angles[0])
        if np.any(np.isin(st[ax], (4, 5))):
            raise TouchAborted(f"finger {f} was blocked on its way to the start of touch {touch.name!r}")
        if self.mode == "velocity":
            result, angles, blobs = self._velocity_touch(touch, plan, ax, pads)
        else:
            result, angles, blobs = self._stepped_touch(touch, plan, ax, pads, st)
        if self.retreat:
            self._move(plan.angles[0])
            self._move(rest)
        return result, angles, blobs


class HandWorld:
    """The hand as a "world" for the planners' active-localisation loop.

    ``touchloc.planners.active_localization(HandWorld(executor), model, region, planner,
    candidates)`` plans each touch, runs it on the hand and updates the belief.

    Parameters
    ----------
    executor : GuardedTouchExecutor
    true_pose : (4, 4) float, optional
        Known only with an emulated world; lets the loop report errors.
    """

    def __init__(self, executor: GuardedTouchExecutor, true_pose=None):
        self.executor = as_instance(executor, GuardedTouchExecutor, "executor")
        self.true_pose = None if true_pose is None else as_pose(true_pose, "true_pose")

    def execute(self, action) -> list:
        """One TouchResult per guarded touch of ``action``."""
        return self.executor.execute_action(action)
