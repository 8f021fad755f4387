"""A simulated object that moves while it is touched: pushed by each action, or turned in
the hand with a biased odometry (the world :class:`touchloc.mapping.TactileSLAM` is
benchmarked in, and :func:`touchloc.mapping.explore` drives)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .._util import as_rng
from .._validate import as_bool, as_float, as_motion, as_pose
from ..errors import ValidationError

__all__ = ["MovingWorld"]


class MovingWorld:
    """A simulated object that moves while it is touched.

    Every action pushes the object: after its touches are measured, the object moves by
    a random motion (``push`` = translation (m) and rotation (rad) standard deviations,
    about the object's own origin), which the next action finds. In ``inhand`` mode the
    hand also turns it by ``step`` rad about ``axis`` (world frame, through the object's
    origin) before each action, as a hand rotating it between its fingers. The first
    action therefore meets the object at ``initial_pose`` (or turned once, in hand).
    ``odometry()`` returns the hand's estimate of the motion since the last action's
    touches: the commanded turn scaled by ``1 + bias`` (nothing is known of pushes).

    ``trajectory`` holds ``initial_pose`` and then the pose at which each action's
    touches were made.

    Parameters
    ----------
    obj : MeshObject
    initial_pose : (4, 4) float
    push : (float, float)
    planar : bool
        Pushes move x, y and yaw only (an object sliding on a table).
    inhand : bool
    step : float
        Turn per action in ``inhand`` mode (rad).
    axis : (3,) float
    bias : float
        Relative error of the odometry's turn (0.05 = 5 % too much).
    noise_pos, noise_nor : float
        Contact noise, as :class:`touchloc.planners.SimulatedWorld`.
    rng : None, int or Generator
    """

    def __init__(self, obj, initial_pose=None, *, push=(0.002, np.deg2rad(2.0)), planar: bool = False,
                 inhand: bool = False, step: float = np.deg2rad(10.0), axis=(0.0, 0.0, 1.0), bias: float = 0.0,
                 noise_pos: float = 0.001, noise_nor: float = 0.087, rng=None):
        from ..models import GaussianDynamics, MeshObject

        if not isinstance(obj, MeshObject):
            raise ValidationError(f"obj must be a MeshObject, got {type(obj).__name__}")
        self.obj = obj
        self.true_pose = np.eye(4) if initial_pose is None else as_pose(initial_pose, "initial_pose").copy()
        self.push = as_motion(push, "push")
        self.planar, self.inhand = as_bool(planar, "planar"), as_bool(inhand, "inhand")
        self.step = as_float(step, "step", low=-np.pi, high=np.pi)
        try:
            a = np.asarray(axis, dtype=float).reshape(3)
        except (TypeError, ValueError):
            raise ValidationError(f"axis must be a non-zero 3-vector, got {axis!r}") from None
        if not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
            raise ValidationError(f"axis must be a finite non-zero 3-vector, got {axis!r}")
        self.axis = a / np.linalg.norm(a)
        self.bias = as_float(bias, "bias", low=-0.9, high=10.0)
        self.noise_pos = as_float(noise_pos, "noise_pos", low=0.0, high=0.1)
        self.noise_nor = as_float(noise_nor, "noise_nor", low=0.0, high=10.0)
        self.rng = as_rng(rng)
        self._push = GaussianDynamics(*self.push, planar=self.planar)
        self.trajectory = [self.true_pose.copy()]
        self._odo = np.eye(4)

    def odometry(self) -> np.ndarray | None:
        """The hand's estimate of the last motion (world-frame increment), or None."""
        return self._odo.copy() if self.inhand else None

    def execute(self, action) -> list:
        from ..planners.simulate import execute

        T = self.true_pose
        if self.inhand:
            R = Rotation.from_rotvec(self.step * self.axis).as_matrix()
            T = T.copy()
            T[:3, :3] = R @ T[:3, :3]
            Ro = Rotation.from_rotvec(self.step * (1 + self.bias) * self.axis).as_matrix()
            self._odo = np.eye(4)
            self._odo[:3, :3] = Ro
            self._odo[:3, 3] = T[:3, 3] - Ro @ T[:3, 3]   # turn about the object's origin
        self.trajectory.append(T.copy())
        out = execute(self.obj, T, action, noise_pos=self.noise_pos, noise_nor=self.noise_nor, rng=self.rng)
        # the touch disturbs the object: the next action finds it moved
        self.true_pose = self._push.sample(T[None], rng=self.rng)[0]
        return out
