"""Forward and inverse kinematics of the SDH-2 fingers and the placement of the tactile pads.

All lengths are metres and all angles radians. Facts (link lengths, base positions, the
closing direction, the palmar normals, the pad indices) are those of the hand's host
library and robot description, summarised in SCHUNK SDHLibrary-C++ 0.0.2.10 (sdh.cpp, dsa.cpp) and the ROS description schunk_description (sdh.urdf.xacro):

* l1 = 86.5 mm (proximal to distal joint), l2 = 68.5 mm (distal joint to tip);
* proximal joints at (33, 19.053, 17), (0, -38.105, 17), (-33, 19.053, 17) mm in the hand
  frame H (origin at the centre of the base plate, +z along straight fingers);
* closing direction c(a0) = (fac_x sin a0, fac_y cos a0, 0) with (fac_x, fac_y) =
  (-1, -1), (+1, +1), (+1, -1) for fingers 0, 1 (thumb), 2;
* palmar normals n = cos(theta) c - sin(theta) z, theta = a1 (proximal) or a1 + a2 (distal).

Pad geometry that no source confirmed is a parameter of :class:`PadLayout` (texel counts,
pitch, where the pad starts along its link, which end row 0 is at, the 15 mm surface
offset): pass the values the tactile controller reports (:meth:`SDH2Kinematics.with_matrix_info`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .._validate import (as_bool, as_count, as_float, as_float_array, as_nonnegative_float, as_positive_float,
                         as_sequence)
from ..errors import ValidationError

__all__ = ["PadLayout", "SDH2Kinematics", "FINGER_AXES", "DEFAULT_PADS"]

#: joint-angle vector indices (axis numbers) of each finger: (base, proximal, distal);
#: the thumb's base is fixed (None)
FINGER_AXES = ((0, 1, 2), (None, 3, 4), (0, 5, 6))
_BASES = np.array([[33.0, 19.053, 17.0], [0.0, -38.105, 17.0], [-33.0, 19.053, 17.0]]) * 1e-3
_FAC = np.array([[-1.0, -1.0], [1.0, 1.0], [1.0, -1.0]])
_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class PadLayout:
    """Where one tactile matrix sits on its link.

    Parameters
    ----------
    cells_x, cells_y : int
        Texel columns (across the finger) and rows (along the link). Assumed 6 x 14
        (proximal) and 6 x 13 (distal); the controller reports the real values (0x0B).
    texel_width, texel_height : float
        Texel pitch across / along (m). Assumed 3.4 mm; reported by the controller.
    start : float
        Distance (m) from the link's joint to the edge of row 0 (or of the last row when
        ``row0_at_tip``). Unconfirmed.
    surface_offset : float
        Distance (m) of the pad surface from the joint axis line, on the palmar side.
        About 15 mm (estimated from the robot description's meshes).
    row0_at_tip : bool
        Whether row 0 is the row nearest the fingertip. Unconfirmed; default False.
    mirror_x : bool
        Whether column 0 lies on the -k side (k = flexion axis z x c). Unconfirmed.
    """

    cells_x: int
    cells_y: int
    texel_width: float = 0.0034
    texel_height: float = 0.0034
    start: float = 0.02
    surface_offset: float = 0.015
    row0_at_tip: bool = False
    mirror_x: bool = False

    def __post_init__(self):
        # checked, and stored as plain ints, floats and bools (the dataclass is frozen)
        for name in ("cells_x", "cells_y"):
            object.__setattr__(self, name, as_count(getattr(self, name), f"PadLayout.{name}", max=256,
                                                    why="texels of one pad"))
        for name in ("texel_width", "texel_height"):
            object.__setattr__(self, name, as_positive_float(getattr(self, name), f"PadLayout.{name} (m)", high=0.1))
        for name in ("start", "surface_offset"):
            object.__setattr__(self, name, as_float(getattr(self, name), f"PadLayout.{name} (m)", low=-1.0, high=1.0))
        for name in ("row0_at_tip", "mirror_x"):
            object.__setattr__(self, name, as_bool(getattr(self, name), f"PadLayout.{name}"))

    @property
    def n_texels(self) -> int:
        return int(self.cells_x * self.cells_y)

    @property
    def length(self) -> float:
        """Pad length along the link (m)."""
        return self.cells_y * self.texel_height

    def local_coordinates(self, x, y):
        """(along, across) in metres of texel coordinates (column x, row y; may be fractional)."""
        x = as_float_array(x, "x")
        y = as_float_array(y, "y")
        if self.row0_at_tip:
            along = self.start + (self.cells_y - 0.5 - y) * self.texel_height
        else:
            along = self.start + (y + 0.5) * self.texel_height
        across = (x - (self.cells_x - 1) / 2.0) * self.texel_width
        if self.mirror_x:
            across = -across
        return along, across


#: assumed default pads: index m = 2 * finger + part (0 proximal, 1 distal)
DEFAULT_PADS = tuple(
    PadLayout(6, 14, start=0.02) if part == 0 else PadLayout(6, 13, start=0.012)
    for finger in range(3) for part in range(2)
)


class SDH2Kinematics:
    """Kinematics of the three SDH-2 fingers and their six tactile pads.

    Parameters
    ----------
    l1, l2 : float
        Proximal and distal link lengths (m); defaults 0.0865 and 0.0685.
    pads : sequence of 6 PadLayout, optional
        Pad geometry by matrix index (default :data:`DEFAULT_PADS`, partly assumed).

    Notes
    -----
    ``angles`` arguments are the 7 axis angles (rad) in the hand's axis order. Points and
    directions are returned in the hand frame H.
    """

    def __init__(self, *, l1: float = 0.0865, l2: float = 0.0685, pads=None):
        self.l1 = as_positive_float(l1, "l1 (m)", high=1.0)
        self.l2 = as_positive_float(l2, "l2 (m)", high=1.0)
        if pads is None:
            pads = DEFAULT_PADS
        elif isinstance(pads, (list, tuple)) and len(pads) == 6 and all(isinstance(p, PadLayout) for p in pads):
            pads = tuple(pads)
        else:
            raise ValidationError("pads must be 6 PadLayout objects (matrix index = 2 * finger + part), "
                                  f"got {type(pads).__name__}")
        self.pads = pads
        self.bases = _BASES.copy()
        self._cache: dict = {}

    @staticmethod
    def flange_from_hand() -> np.ndarray:
        """(4, 4) T_flange_hand: hand frame H to the robot description's palm (mounting flange) frame.

        ``p_flange = Rz(-90 deg) p_H + (0, 0, 74 mm)`` (sdh2_kinematics.md): on an arm, the
        executor's ``hand_pose`` is ``T_world_flange @ SDH2Kinematics.flange_from_hand()``.
        """
        T = np.eye(4)
        T[:3, :3] = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
        T[2, 3] = 0.074
        return T

    def with_matrix_info(self, infos) -> "SDH2Kinematics":
        """A copy whose pads take cells and texel sizes from the controller's matrix info."""
        infos = as_sequence(infos, "infos", min_len=len(self.pads), max_len=len(self.pads),
                            expected=f"{len(self.pads)} matrix infos (DSACON32m.matrix_info)")
        pads = []
        for m, (pad, info) in enumerate(zip(self.pads, infos)):
            try:
                cx, cy = info.cells_x, info.cells_y
                tw, th = info.texel_width, info.texel_height
            except AttributeError:
                raise ValidationError(f"infos[{m}] must have cells_x, cells_y, texel_width and texel_height, "
                                      f"got {type(info).__name__}") from None
            pads.append(replace(pad, cells_x=as_count(cx, f"infos[{m}].cells_x", max=1024),
                                cells_y=as_count(cy, f"infos[{m}].cells_y", max=1024),
                                texel_width=as_positive_float(tw, f"infos[{m}].texel_width (mm)") * 1e-3,
                                texel_height=as_positive_float(th, f"infos[{m}].texel_height (mm)") * 1e-3))
        return SDH2Kinematics(l1=self.l1, l2=self.l2, pads=pads)

    @staticmethod
    def _angles(angles) -> np.ndarray:
        return as_float_array(angles, "angles", shape=(7,), expected="7 finite joint angles (rad)")

    @staticmethod
    def _finger(finger) -> int:
        return as_count(finger, "finger", min=0, max=2, why="0, 1 (the thumb) or 2")

    def _matrix(self, matrix) -> int:
        return as_count(matrix, "matrix", min=0, max=len(self.pads) - 1, why="2 * finger + part")

    def closing_direction(self, finger: int, a0: float) -> np.ndarray:
        """(3,) unit vector c: the horizontal direction finger ``finger`` closes towards."""
        f = self._finger(finger)
        a0 = 0.0 if f == 1 else as_float(a0, "a0")
        fx, fy = _FAC[f]
        return np.array([fx * math.sin(a0), fy * math.cos(a0), 0.0])

    def finger_chain(self, angles, finger: int) -> dict:
        """Frames of one finger: base, closing direction c, flexion axis k, link directions
        u_p, u_d, palmar normals n_p, n_d, the distal joint and the fingertip (all (3,))."""
        a = self._angles(angles)
        f = self._finger(finger)
        ax = FINGER_AXES[f]
        a0 = 0.0 if ax[0] is None else a[ax[0]]
        a1, a2 = a[ax[1]], a[ax[2]]
        c = self.closing_direction(f, a0)
        th_p, th_d = a1, a1 + a2
        u_p = math.cos(th_p) * _Z + math.sin(th_p) * c
        u_d = math.cos(th_d) * _Z + math.sin(th_d) * c
        n_p = math.cos(th_p) * c - math.sin(th_p) * _Z
        n_d = math.cos(th_d) * c - math.sin(th_d) * _Z
        base = self.bases[f]
        distal = base + self.l1 * u_p
        return {"base": base.copy(), "c": c, "k": np.array([-c[1], c[0], 0.0]), "u_p": u_p, "u_d": u_d,
                "n_p": n_p, "n_d": n_d, "distal_joint": distal, "tip": distal + self.l2 * u_d}

    def fingertips(self, angles) -> np.ndarray:
        """(3, 3) float: fingertip positions (on the link axis) of fingers 0, 1, 2."""
        return np.stack([self.finger_chain(angles, f)["tip"] for f in range(3)])

    def pad_frame(self, angles, matrix: int):
        """(origin (3,), along (3,), across (3,), normal (3,)) of pad ``matrix`` in H.

        ``origin`` is the joint the pad's link starts at, moved onto the pad surface.
        """
        matrix = self._matrix(matrix)
        f, part = divmod(matrix, 2)
        ch = self.finger_chain(angles, f)
        pad = self.pads[matrix]
        joint = ch["base"] if part == 0 else ch["distal_joint"]
        u = ch["u_p"] if part == 0 else ch["u_d"]
        n = ch["n_p"] if part == 0 else ch["n_d"]
        return joint + pad.surface_offset * n, u, ch["k"], n

    def texel_points(self, angles, matrix: int) -> np.ndarray:
        """(cells_y, cells_x, 3) float: texel centres of pad ``matrix`` on its surface (H)."""
        matrix = self._matrix(matrix)
        key = ("texels", matrix)
        grid = self._cache.get(key)
        if grid is None:
            pad = self.pads[matrix]
            y, x = np.mgrid[0:pad.cells_y, 0:pad.cells_x]
            grid = self._cache[key] = pad.local_coordinates(x, y)
        o, u, k, _ = self.pad_frame(angles, matrix)
        along, across = grid
        return o + along[..., None] * u + across[..., None] * k

    def pad_point(self, angles, matrix: int, x, y) -> np.ndarray:
        """(..., 3) float: points on pad ``matrix`` at texel coordinates (x column, y row)."""
        o, u, k, _ = self.pad_frame(angles, matrix)
        along, across = self.pads[self._matrix(matrix)].local_coordinates(x, y)
        return o + along[..., None] * u + across[..., None] * k

    def pad_normal(self, angles, matrix: int) -> np.ndarray:
        """(3,) float: outward normal of pad ``matrix`` (points from the pad towards what it touches)."""
        return self.pad_frame(angles, matrix)[3]

    # -- the probe point and planar inverse kinematics ------------------------------------
    def probe_offset(self, finger: int):
        """(s, off): the probe point (centre of the distal pad, on its surface) along the
        distal link and off its axis (m)."""
        pad = self.pads[2 * self._finger(finger) + 1]
        along, _ = pad.local_coordinates((pad.cells_x - 1) / 2.0, (pad.cells_y - 1) / 2.0)
        return float(along), float(pad.surface_offset)

    def probe_point(self, angles, finger: int) -> np.ndarray:
        """(3,) float: the probe point of a finger (centre of its distal pad surface) in H."""
        ch = self.finger_chain(angles, finger)
        s, off = self.probe_offset(finger)
        return ch["distal_joint"] + s * ch["u_d"] + off * ch["n_d"]

    def plane_to_hand(self, finger: int, a0: float, r, z) -> np.ndarray:
        """(..., 3): points of the finger plane (r along c, z along H's z from the base) in H."""
        c = self.closing_direction(finger, a0)
        r = as_float_array(r, "r")
        z = as_float_array(z, "z")
        return self.bases[self._finger(finger)] + r[..., None] * c + z[..., None] * _Z

    def planar_ik(self, finger: int, r: float, z: float, *, limits=None, prefer=None):
        """Proximal and distal angles (a1, a2) that put the probe point at (r, z) of the plane.

        Parameters
        ----------
        finger : int
        r, z : float
            Target in the finger plane: along the closing direction and along H's z,
            measured from the proximal joint (m).
        limits : (lo (2,), hi (2,)), optional
            Allowed (a1, a2) ranges (rad); default [-pi/2, pi/2] each.
        prefer : (2,) float, optional
            Pick the solution nearest to these angles (default: larger a2, the finger
            curled towards the palm side).

        Returns
        -------
        (a1, a2) or None when unreachable within the limits.
        """
        s, off = self.probe_offset(finger)
        r, z = as_float(r, "r"), as_float(z, "z")
        if limits is not None:
            lim = as_float_array(limits, "limits", shape=(2, 2), expected="(lo (2,), hi (2,)) angles (rad)")
            limits = (lim[0], lim[1])
        if prefer is not None:
            prefer = as_float_array(prefer, "prefer", shape=(2,))
        L2 = math.hypot(s, off)
        phi = math.atan2(off, s)
        l1 = self.l1
        d2 = r * r + z * z
        D = (d2 - l1 * l1 - L2 * L2) / (2 * l1 * L2)
        if not -1.0 <= D <= 1.0:
            return None
        lo, hi = (np.full(2, -math.pi / 2), np.full(2, math.pi / 2)) if limits is None else limits
        sols = []
        for beta in (math.acos(D), -math.acos(D)):
            a1 = math.atan2(r, z) - math.atan2(L2 * math.sin(beta), l1 + L2 * math.cos(beta))
            a2 = beta - phi
            a1 = (a1 + math.pi) % (2 * math.pi) - math.pi
            if lo[0] - 1e-9 <= a1 <= hi[0] + 1e-9 and lo[1] - 1e-9 <= a2 <= hi[1] + 1e-9:
                sols.append((a1, a2))
        if not sols:
            return None
        if prefer is not None:
            p = np.asarray(prefer, dtype=np.float64)
            return min(sols, key=lambda q: float(np.sum((np.array(q) - p) ** 2)))
        return max(sols, key=lambda q: q[1])

    def touch_plane(self, finger: int, origin, direction, *, a0_limits=(0.0, math.pi / 2), tol: float = 1e-3):
        """The base angle a0 whose finger plane contains the line ``origin + t direction``.

        Returns a0 (0 for the thumb) or None when no plane of this finger contains it
        (within ``tol`` metres at the origin and ``tol`` in the direction).
        """
        f = self._finger(finger)
        o = as_float_array(origin, "origin", shape=(3,)) - self.bases[f]
        d = as_float_array(direction, "direction", shape=(3,))
        if not np.linalg.norm(d) > 0:
            raise ValidationError("direction must not be zero")
        d = d / np.linalg.norm(d)
        lim = as_float_array(a0_limits, "a0_limits", shape=(2,))
        a0_limits = (float(lim[0]), float(lim[1]))
        tol = as_nonnegative_float(tol, "tol")
        if f == 1:
            cands = [0.0]
        else:
            h = d[:2] if np.linalg.norm(d[:2]) > 1e-6 else o[:2]
            if np.linalg.norm(h) < 1e-9:
                return None
            fx, fy = _FAC[f]
            base = math.atan2(fx * h[0], fy * h[1])
            cands = [base, base - math.pi, base + math.pi]
        for a0 in cands:
            if f != 1 and not (a0_limits[0] - 1e-9 <= a0 <= a0_limits[1] + 1e-9):
                continue
            c = self.closing_direction(f, a0)
            k = np.array([-c[1], c[0], 0.0])
            if abs(float(o @ k)) <= tol and abs(float(d @ k)) <= tol:
                return float(min(max(a0, a0_limits[0]), a0_limits[1])) if f != 1 else 0.0
        return None
