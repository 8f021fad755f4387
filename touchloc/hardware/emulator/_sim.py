"""The simulated hand behind the emulators: joint motion, a mesh at a hidden pose, pad pressure.

The emulated SDH-2 and DSACON32m share one :class:`SimHand`: the hand emulator moves its
joints, the tactile emulator reads the pressure its pads feel. With a :class:`SimWorld`
attached, a finger stops (its axes report "blocked") when a pad texel of it presses more
than ``block_depth`` into the mesh, and each texel reports a pressure proportional to its
penetration (saturating at ``full_depth``).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from ...errors import ValidationError
from ..kinematics import FINGER_AXES, SDH2Kinematics
from ..sdh2 import DEFAULT_ALIM_DEG, DEFAULT_ANGLE_LIMITS_DEG, DEFAULT_VLIM_DEG

__all__ = ["SimWorld", "SimHand", "GRIP_PRESETS"]

#: open and closed joint angles (deg) of the emulator's preset grasps (its own choice:
#: the firmware's presets are not published)
GRIP_PRESETS = {
    0: (np.array([60.0, -30, 30, -30, 30, -30, 30]), np.array([60.0, 40, 20, 40, 20, 40, 20])),
    1: (np.array([0.0, -30, 30, -30, 30, -30, 30]), np.array([0.0, 40, 20, 40, 20, 40, 20])),
    2: (np.array([0.0, -30, 30, -30, 30, -30, 30]), np.array([0.0, 20, 60, 20, 60, 20, 60])),
    3: (np.array([60.0, -30, 30, -30, 30, -30, 30]), np.array([60.0, 20, 60, 20, 60, 20, 60])),
}


class SimWorld:
    """A mesh at a (hidden) pose in the world, and where the hand is.

    Parameters
    ----------
    obj : touchloc.models.MeshObject
    object_pose : (4, 4) float
        T_world_object.
    hand_pose : (4, 4) float
        T_world_hand: where the hand frame H is in the world.
    kinematics : SDH2Kinematics, optional
    full_depth : float
        Penetration (m) at which a texel saturates (4095). Default 2 mm.
    block_depth : float
        Penetration (m) at which the moving finger is blocked. Default 2.5 mm.
    """

    def __init__(self, obj, object_pose, hand_pose=None, *, kinematics=None,
                 full_depth: float = 0.002, block_depth: float = 0.0025):
        self.obj = obj
        self.object_pose = np.asarray(object_pose, dtype=np.float64)
        self.hand_pose = np.eye(4) if hand_pose is None else np.asarray(hand_pose, dtype=np.float64)
        for name, T in (("object_pose", self.object_pose), ("hand_pose", self.hand_pose)):
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise ValidationError(f"{name} must be a finite (4, 4) matrix, got {T.shape}")
        self.kinematics = kinematics or SDH2Kinematics()
        self.full_depth = float(full_depth)
        self.block_depth = float(block_depth)
        # hand frame -> object frame
        self._T_obj_hand = np.linalg.inv(self.object_pose) @ self.hand_pose
        # points farther than this from the mesh's bounding-box centre cannot touch it
        b = np.asarray(obj.bounds, dtype=np.float64)
        self._center = b.mean(axis=0)
        self._reach2 = (0.5 * float(np.linalg.norm(b[1] - b[0])) + 0.005) ** 2
        # build the mesh's search structure now, not inside the first reply to a command
        self.obj.closest_points(self._center[None])

    def move_object(self, object_pose) -> None:
        """Put the object at a new pose (a push, a slip): the hand senses it from then on."""
        T = np.asarray(object_pose, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValidationError(f"object_pose must be a finite (4, 4) matrix, got {T.shape}")
        self.object_pose = T
        self._T_obj_hand = np.linalg.inv(T) @ self.hand_pose

    def penetration(self, angles_rad, matrices=range(6)):
        """Penetration depth (m, >= 0) of every texel of the given pads: list of (cells_y, cells_x)."""
        kin = self.kinematics
        pts, shapes = [], []
        for m in matrices:
            p = kin.texel_points(angles_rad, m)
            shapes.append(p.shape[:2])
            pts.append(p.reshape(-1, 3))
        P = np.concatenate(pts)
        R, t = self._T_obj_hand[:3, :3], self._T_obj_hand[:3, 3]
        Po = P @ R.T + t
        depth = np.zeros(len(Po))
        near = np.einsum("ij,ij->i", Po - self._center, Po - self._center) <= self._reach2
        if near.any():
            closest, normals, dist = self.obj.closest_points(Po[near])
            inside = np.einsum("ij,ij->i", Po[near] - closest, normals) < 0
            depth[near] = np.where(inside, dist, 0.0)
        out, i = [], 0
        for s in shapes:
            n = s[0] * s[1]
            out.append(depth[i:i + n].reshape(s))
            i += n
        return out

    def pressures(self, angles_rad) -> list:
        """Texel values 0..4095 of the six pads: list of (cells_y, cells_x) uint16."""
        return [np.clip(np.round(d / self.full_depth * 4095.0), 0, 4095).astype(np.uint16)
                for d in self.penetration(angles_rad)]


class SimHand:
    """Joint state of an emulated SDH-2, advanced lazily in (optionally accelerated) time.

    Parameters
    ----------
    world : SimWorld, optional
        What the fingers can touch; None for free motion.
    time_scale : float
        Device seconds per wall-clock second (1 = real time; > 1 runs faster).
    initial_angles_deg : (7,) float, optional
    dt : float
        Integration step (device seconds).

    Axes move towards their targets at their target velocity (constant speed, no
    acceleration ramp); the expected duration reported by ``m`` is the slowest axis'.
    """

    def __init__(self, world: SimWorld | None = None, *, time_scale: float = 1.0,
                 initial_angles_deg=None, dt: float = 0.004):
        if not (time_scale > 0):
            raise ValidationError(f"time_scale must be positive, got {time_scale}")
        self.world = world
        self.time_scale = float(time_scale)
        self.dt = float(dt)
        #: most integration steps per update; beyond it the steps get longer than dt
        self.max_substeps = 100
        self.lock = threading.RLock()
        self.p_min, self.p_max = (x.copy() for x in DEFAULT_ANGLE_LIMITS_DEG)
        self.vlim = DEFAULT_VLIM_DEG.copy()
        self.alim = DEFAULT_ALIM_DEG.copy()
        init = np.zeros(7) if initial_angles_deg is None else np.asarray(initial_angles_deg, dtype=np.float64)
        self.angles = init.copy()         # deg
        self.targets = init.copy()        # deg
        self.velocities = np.full(7, 40.0)   # deg/s, power-on default
        self.accelerations = np.full(7, 100.0)
        self.power = np.ones(7, dtype=bool)
        self.state = np.zeros(7, dtype=np.int64)
        self.actual_vel = np.zeros(7)
        self.controller = 0
        self.vp = 0
        self.grip_preset = 0
        self.temps = np.array([30.0, 31, 31, 32, 32, 31, 31, 45, 38])
        self._last = time.monotonic()

    # -- time -------------------------------------------------------------------------
    def advance(self) -> None:
        """Integrate the motion up to now."""
        with self.lock:
            now = time.monotonic()
            span = (now - self._last) * self.time_scale
            self._last = now
            n = int(math.ceil(span / self.dt))
            if n <= 0:
                return
            if n > self.max_substeps:  # polled rarely (or a slow machine): coarser steps
                n = self.max_substeps
            h = span / n
            for _ in range(n):
                if not self._step(h):
                    break

    def _step(self, h: float) -> bool:
        moving = self.state == 1
        speed = self.state == 2
        if not (moving.any() or speed.any()):
            self.actual_vel[:] = 0
            return False
        prev = self.angles.copy()
        delta = self.targets - self.angles
        stepv = np.abs(self.velocities) * h
        new = self.angles.copy()
        new[moving] = np.where(np.abs(delta[moving]) <= stepv[moving], self.targets[moving],
                               self.angles[moving] + np.sign(delta[moving]) * stepv[moving])
        new[speed] = self.angles[speed] + self.velocities[speed] * h
        over = speed & ((new < self.p_min) | (new > self.p_max))
        new = np.clip(new, self.p_min, self.p_max)
        self.angles = new
        if self.world is not None:
            self._collide(prev, moving | speed)
        self.actual_vel = (self.angles - prev) / h
        done = moving & (self.angles == self.targets)
        self.state[done] = 0
        self.state[over] = 7
        return True

    def _collide(self, prev: np.ndarray, active: np.ndarray) -> None:
        rad = np.radians(self.angles)
        for f, axes in enumerate(FINGER_AXES):
            ax = [a for a in axes if a is not None]
            if not active[ax].any():
                continue
            depth = max(float(d.max()) for d in self.world.penetration(rad, (2 * f, 2 * f + 1)))
            if depth <= self.world.block_depth:
                continue
            before = max(float(d.max()) for d in self.world.penetration(np.radians(prev), (2 * f, 2 * f + 1)))
            if depth > before:  # pressing further in: blocked (moving out is always allowed)
                for a in ax:
                    if active[a]:
                        direction = self.angles[a] - prev[a]
                        self.angles[a] = prev[a]
                        self.state[a] = 4 if direction >= 0 else 5
                        self.targets[a] = prev[a]

    # -- commands (degrees, as on the wire) -----------------------------------------------
    def start_move(self) -> float:
        with self.lock:
            self.advance()
            delta = np.abs(self.targets - self.angles)
            go = self.power & (delta > 1e-9)
            v = np.maximum(np.abs(self.velocities), 1e-6)
            self.state[:] = np.where(self.power, 0, 6)
            self.state[go] = 1
            self._last = time.monotonic()
            return float(np.max(np.where(go, delta / v, 0.0)))

    def start_velocity(self) -> None:
        with self.lock:
            self.advance()
            self.state[:] = np.where(self.power & (self.velocities != 0), 2, np.where(self.power, 0, 6))

    def stop(self) -> None:
        with self.lock:
            self.advance()
            self.targets = self.angles.copy()
            self.state[self.state <= 2] = 0
            self.actual_vel[:] = 0

    def expected_duration(self) -> float:
        with self.lock:
            self.advance()
            delta = np.abs(self.targets - self.angles)
            return float(np.max(delta / np.maximum(np.abs(self.velocities), 1e-6)))

    def grip(self, close: float, velocity: float) -> float:
        lo, hi = GRIP_PRESETS[self.grip_preset]
        with self.lock:
            self.targets = np.clip(lo + close * (hi - lo), self.p_min, self.p_max)
            self.velocities = self.vlim * velocity / 100.0
            return self.start_move()

    def pressures(self) -> list:
        """The six pads' texel values (uint16), or zeros without a world."""
        with self.lock:
            self.advance()
            if self.world is None:
                return None
            return self.world.pressures(np.radians(self.angles))
