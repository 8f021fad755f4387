"""The rotating n-gon of seed 000 across the layers: mapped in 3-D by tactile SLAM, and recorded
from the emulated hand's tactile bytes.

A third family for the DNF comparison: the rotating n-gon mapped in 3-D by tactile SLAM.

Seed 000 solves one rotational degree of freedom of an n-gon with neural fields. The same
experiment is a special case of tactile SLAM in 3-D (:class:`touchloc.mapping.TactileSLAM`):
an extruded n-gon prism turns about its axis between two fingers, the hand reports its
biased odometry, and the SLAM estimate holds both the object's pose (its orientation
correction) and a shape map in the object frame (its sides).

:class:`MappedPrismEstimator` plays this on the *same* data sets as the other estimators
(:class:`~touchloc.dnf.RotationDataset`): the data set's true rotation turns the prism, its
odometry is the SLAM's odometry prior (so the bias and the regrasp slips are the same),
and the measured normal angles say which of the two fingers (at world angles ``fingers``,
the generator's point-symmetric grasp) are in contact. A sample without normals is a
sample without touch. Each touch is a guarded move of a finger towards the axis, so the
contact wanders over a side while the object turns under the finger, as in the seed's
strokes; it is ray-cast onto the prism at its true pose (:func:`touchloc.planners.simulate.execute`,
with contact noise), so the SLAM sees 3-D contact points and normals where the tracker
sees angles.

Side count. The map's cross-section through the object's centre is traced along rays
from the axis (a few Newton steps on the map's signed distance per ray). The outward
normal direction of each piece of the traced outline, weighted by its length and
smoothed by ``smoothing`` (5 deg), is a density over orientation that is 1 everywhere for
a circle and has one sharp peak per flat side. :attr:`memory` is that density divided by
``flat_ratio`` and clipped to 1, so that :func:`count_surfaces`'s threshold of 0.4 counts
the orientations at which the outline has at least ``0.4 * flat_ratio`` times a circle's
share of its length: the flat faces. The smoothing is wider than the count's own 3 deg
because a mapped face is not quite flat: the map (a Gaussian process with a 12 mm length
scale) often bends a 30 mm face into two facets a few degrees apart, which 3 deg keeps as
two peaks (a seventh side on a 6-gon).

Orientation. :attr:`orientation` is the SLAM pose's rotation about the axis (the map's
frame is the object's frame at the first update, like the tracker's), carried forward
with the odometry between SLAM updates.

:func:`emulated_rotation` records the same experiment through the whole hardware path
(emulator bytes, driver, blobs, normals). Both live here, on top of the layers, because
they join :mod:`touchloc.dnf` with :mod:`touchloc.mapping` and :mod:`touchloc.hardware`.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .._util import as_rng
from ..dnf.compare import MAPPED, default_estimators
from ..dnf.tracker import as_angles, as_odometry
from .._validate import as_count, as_float, as_float_array, as_name
from ..errors import ValidationError

__all__ = ["MappedPrismEstimator", "emulated_rotation", "estimators_with_map", "prism_mesh",
           "section_normal_density"]

TWO_PI = 2.0 * np.pi


def _as_n_sides(n_sides) -> int:
    """A prism's number of sides: 0 (round) or an int in [3, 360]."""
    if isinstance(n_sides, (bool, np.bool_)) or not isinstance(n_sides, (int, np.integer)) \
            or (n_sides != 0 and not 3 <= n_sides <= 360):
        raise ValidationError(f"n_sides must be 0 (round) or an int in [3, 360], got {n_sides!r}")
    return int(n_sides)


def prism_mesh(n_sides: int, *, diameter: float = 0.06, height: float = 0.06):
    """An extruded regular n-gon (a round cylinder for ``n_sides = 0``) about the z axis.

    The corners lie on a circle of ``diameter`` (m); side ``j``'s outward normal points at
    ``pi / n + 2 pi j / n``. Returns a :class:`touchloc.models.MeshObject`.
    """
    import trimesh

    from ..models import MeshObject

    n_sides = _as_n_sides(n_sides)
    diameter = as_float(diameter, "diameter (m)", low=0.0, low_open=True, high=1.0, high_open=True)
    height = as_float(height, "height (m)", low=0.0, low_open=True, high=1.0, high_open=True)
    m = trimesh.creation.cylinder(radius=diameter / 2, height=height, sections=int(n_sides) if n_sides else 96)
    return MeshObject(m, name=f"{n_sides}-gon prism" if n_sides else "round cylinder")




def section_normal_density(radius, n_bins: int = 360, *, sigma: float = np.radians(3.0)) -> np.ndarray:
    """Length of an outline per orientation of its outward normal, relative to a circle's.

    Parameters
    ----------
    radius : (M,) float
        The outline as a radius per ray, rays evenly spaced over ``[0, 2 pi)``
        counter-clockwise (nan: no surface on that ray; such rays are skipped).
    n_bins : int
        Sites of the result over ``[0, 2 pi)``.
    sigma : float
        Periodic Gaussian smoothing, rad.

    Returns
    -------
    (n_bins,) float
        1 everywhere for a circle; a flat side of length ``L`` adds a peak of area
        ``2 pi L / perimeter`` (rad) at its normal's orientation.
    """
    r = as_float_array(radius, "radius (m)", finite=False)
    if r.ndim != 1:
        raise ValidationError(f"radius must be a 1-D array (M,) of radii per ray, got shape {r.shape}")
    n_bins = as_count(n_bins, "n_bins", min=3, max=10_000_000, why="memory: one float per bin")
    sigma = as_float(sigma, "sigma (rad)", low=0.0, high=TWO_PI)
    phi = np.arange(r.size) * (TWO_PI / max(r.size, 1))
    ok = np.isfinite(r) & (r > 0)
    if ok.sum() < 3:
        return np.zeros(n_bins)
    pts = np.stack([np.cos(phi[ok]) * r[ok], np.sin(phi[ok]) * r[ok]], axis=1)
    d = np.roll(pts, -1, axis=0) - pts
    length = np.linalg.norm(d, axis=1)
    normal = np.arctan2(d[:, 1], d[:, 0]) - np.pi / 2      # outward for a counter-clockwise outline
    b = np.floor((normal % TWO_PI) * (n_bins / TWO_PI)).astype(np.int64) % n_bins
    h = np.bincount(b, weights=length, minlength=n_bins)
    if sigma * n_bins / TWO_PI > 1e-3:   # below a thousandth of a bin the smoothing is the identity
        h = gaussian_filter1d(h, sigma * n_bins / TWO_PI, mode="wrap")
    return h * (n_bins / max(length.sum(), 1e-12))


class MappedPrismEstimator:
    """The rotating n-gon of seed 000 mapped in 3-D by :class:`touchloc.mapping.TactileSLAM`.

    Call :meth:`bind` with a data set (:func:`~touchloc.dnf.run_estimator` does), then
    :meth:`step` with each sample, as for any estimator of the comparison.

    Parameters
    ----------
    every : int
        Touch on every ``every``-th sample (the others only advance the odometry): the
        SLAM's cost grows with the number of contacts in its map.
    diameter, height : float
        Size of the prism (m).
    n_particles : int
        Pose particles of the SLAM filter (planar: x, y and the rotation about the axis).
    lengthscale : float
        Length scale of the map (GPIS, m).
    noise_pos, noise_nor : float
        Contact noise of the simulated touches (m; unit-vector components).
    fingers : sequence of float
        World angles (rad) of the fingers' approach directions; a finger touches in a
        sample when one of its normals lies within 90 degrees of it.
    finger_jitter : float
        Standard deviation of each approach direction per touch, rad.
    flat_ratio : float
        Density (relative to a circle) at which :attr:`memory` saturates; see the module
        notes.
    smoothing : float
        Standard deviation (rad) of the periodic Gaussian that smooths the outline's
        normal density before :attr:`memory` is read from it; see the module notes.
    n_sites : int
        Sites of :attr:`memory` over ``[0, 2 pi)``.
    n_rays : int
        Rays of the traced cross-section.
    rng : None, int or numpy Generator
        Seeds both the touch noise and the SLAM filter.
    """

    def __init__(self, *, every: int = 4, diameter: float = 0.06, height: float = 0.06, n_particles: int = 100,
                 lengthscale: float = 0.012, noise_pos: float = 0.0005, noise_nor: float = 0.05,
                 flat_ratio: float = 4.0, smoothing: float = np.radians(5.0), n_sites: int = 360,
                 n_rays: int = 180, fingers=(0.0, np.pi), finger_jitter: float = np.radians(3.0), rng=None):
        self.every = as_count(every, "every", min=1, max=100)
        self.diameter = as_float(diameter, "diameter (m)", low=0.0, low_open=True, high=1.0, high_open=True)
        self.height = as_float(height, "height (m)", low=0.0, low_open=True, high=1.0, high_open=True)
        self.n_particles = as_count(n_particles, "n_particles", min=1, max=100_000,
                                    why="every particle holds a map's pose and is scored per contact")
        self.lengthscale = as_float(lengthscale, "lengthscale (m)", low=0.0, low_open=True, high=1.0)
        self.noise_pos = as_float(noise_pos, "noise_pos (m)", low=0.0, high=0.1)
        self.noise_nor = as_float(noise_nor, "noise_nor", low=0.0, high=1.0)
        # a circle's density is 1, so a flat side must stand out above it
        self.flat_ratio = as_float(flat_ratio, "flat_ratio", low=1.0, low_open=True, high=1e6)
        self.smoothing = as_float(smoothing, "smoothing (rad)", low=0.0, high=np.pi / 4)
        self.n_sites = as_count(n_sites, "n_sites", min=16, max=4096)
        self.n_rays = as_count(n_rays, "n_rays", min=16, max=4096)
        self.fingers = as_angles(fingers, "fingers")
        if self.fingers.size > 64:
            raise ValidationError(f"fingers must hold at most 64 approach angles (one guarded move each per "
                                  f"touch), got {self.fingers.size}")
        self.finger_jitter = as_float(finger_jitter, "finger_jitter (rad)", low=0.0, high=np.pi, high_open=True)
        self.rng = as_rng(rng)
        self.slam = None
        self.odometry = 0.0
        self.n_steps = 0
        self.n_updates = 0
        self._memory = np.zeros(self.n_sites)
        self._dirty = False

    # -- set-up ------------------------------------------------------------------------
    def bind(self, dataset) -> "MappedPrismEstimator":
        """Take the prism's shape and true rotation from a data set and start afresh.

        Parameters
        ----------
        dataset : RotationDataset
            Needs ``n_surfaces`` and ``true_orientation`` (simulated data).
        """
        from ..mapping import TactileSLAM

        if dataset.n_surfaces is None or dataset.true_orientation is None:
            raise ValidationError("the mapped prism needs a data set with n_surfaces and true_orientation "
                                  "(a simulated one); recorded data carry no 3-D contacts")
        self.obj = prism_mesh(int(dataset.n_surfaces), diameter=self.diameter, height=self.height)
        self._truth = np.asarray(dataset.true_orientation, dtype=np.float64)
        half = 0.5 * self.diameter + 0.015
        zh = 0.5 * self.height
        self.slam = TactileSLAM(((-half, -half, -zh - 0.01), (half, half, zh + 0.01)), planar=True,
                                n_particles=self.n_particles, motion=(0.0005, np.radians(0.5)),
                                odometry_noise=(0.0003, np.radians(1.0)), sigma_pos=0.001, sigma_nor=0.1,
                                lengthscale=self.lengthscale, rng=self.rng)
        self.odometry = 0.0
        self._odo_used = 0.0
        self._yaw = 0.0
        self.n_steps = 0
        self.n_updates = 0
        self._memory = np.zeros(self.n_sites)
        self._dirty = False
        return self

    # -- state -------------------------------------------------------------------------
    @property
    def orientation(self) -> float:
        """Rotation about the axis: the SLAM pose's, plus the odometry since its last update (rad)."""
        return self._yaw + (self.odometry - self._odo_used)

    @property
    def correction(self) -> float:
        """Orientation minus odometry, rad."""
        return self.orientation - self.odometry

    @property
    def memory(self) -> np.ndarray:
        """Normal-direction density of the mapped cross-section over ``flat_ratio``, in [0, 1]."""
        if self._dirty:
            density = section_normal_density(self.section(), self.n_sites, sigma=self.smoothing)
            self._memory = np.clip(density / self.flat_ratio, 0.0, 1.0)
            self._dirty = False
        return self._memory

    def section(self) -> np.ndarray:
        """Radius of the mapped outline at height 0 along ``n_rays`` rays (m; nan where none)."""
        phi = np.arange(self.n_rays) * (TWO_PI / self.n_rays)
        u = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
        r = np.full(self.n_rays, 0.5 * self.diameter)
        r_max = float(self.slam.map.hi[0])
        for _ in range(5):             # Newton steps on a signed distance (slope about 1 along the ray)
            r = np.clip(r - self.slam.map.signed_distance(r[:, None] * u), 0.002, r_max)
        miss = np.abs(self.slam.map.signed_distance(r[:, None] * u)) > 0.1 * self.diameter
        r[miss] = np.nan
        return r

    # -- one sample --------------------------------------------------------------------
    def step(self, normal_angles, odometry: float) -> float:
        """One sample: touch where the normals point (every ``every``-th sample) and update the SLAM.

        Parameters
        ----------
        normal_angles : (K,) float
            World-frame normal angles (rad); they say which fingers touch.
        odometry : float
            The hand's estimate of the accumulated rotation, rad.

        Returns
        -------
        float
            The orientation estimate, rad.
        """
        from ..planners import GuardedTouch
        from ..planners.simulate import execute

        if self.slam is None:
            raise ValidationError("call bind(dataset) before step(): the mapped prism needs the data set's "
                                  "shape and true rotation")
        a = as_angles(normal_angles, allow_empty=True)
        self.odometry = as_odometry(odometry)
        t = self.n_steps
        self.n_steps += 1
        if a.size == 0 or t % self.every or t >= self._truth.size:
            return self.orientation
        touching = np.any(np.cos(a[None, :] - self.fingers[:, None]) > 0.0, axis=1)
        angles = self.fingers[touching] + self.rng.normal(0.0, self.finger_jitter, int(touching.sum()))
        pose = _rz(self._truth[t])
        results = []
        reach = 0.5 * self.diameter + 0.012
        for ang in angles:
            d = np.array([np.cos(ang), np.sin(ang), 0.0])
            z = self.rng.uniform(-0.25, 0.25) * self.height
            touch = GuardedTouch(origin=reach * d + [0.0, 0.0, z], direction=-d, max_travel=reach)
            results += execute(self.obj, pose, touch, noise_pos=self.noise_pos, noise_nor=self.noise_nor, rng=self.rng)
        T = self.slam.update(results, odometry=_rz(self.odometry - self._odo_used))
        self._odo_used = self.odometry
        self._yaw = float(np.arctan2(T[1, 0], T[0, 0]))
        # keep the estimate continuous with the odometry (no wrap to (-pi, pi])
        self._yaw = self.odometry + float(np.angle(np.exp(1j * (self._yaw - self.odometry))))
        self.n_updates += 1
        self._dirty = True
        return self.orientation


def emulated_rotation(n_sides: int, *, turns: float = 4.0, inradius: float = 0.018, step: float = np.radians(4.0),
                      stroke=(np.radians(25.0), np.radians(40.0)), under_estimate: float = 0.06, depth: float = 0.0008,
                      slip_std: float = 0.0, pad_radius: float = 0.02, rate_hz: float = 2.5,
                      min_width: float | None = 0.008, name: str = "", rng=None):
    """Record seed 000's rotation experiment from the emulated hand's tactile bytes.

    An extruded n-gon (a round cylinder for 0) stands on the hand's axis between the three
    distal pads (base angle 60 degrees, distal links parallel to the axis), which are
    curved across the finger with radius ``pad_radius`` (:class:`CurvedPadKinematics`).
    At every grasp each finger closes until its pad presses ``depth`` into the object.
    The hand turns it in strokes: during a stroke the fingers turn with the object
    about its axis, then they let go and regrasp at their starting place, the object
    keeping its rotation (plus an unobserved ``N(0, slip_std)``). Every sample the
    :class:`~touchloc.hardware.emulator.DSACON32mEmulator` renders the pads' pressure
    into bytes, the :class:`~touchloc.hardware.DSACON32m` driver reads them over a
    loopback TCP socket, and :func:`frame_normal_angles` turns the frame into world-frame
    normal angles about the axis, keeping only blobs at least ``min_width`` wide across the
    finger: flat sides, not corners. The odometry is the hand's turn under-estimated by
    ``under_estimate`` (seed 000, II-B).

    A finger that lands on a side keeps the side's normal through the stroke (it turns
    with the object); one that lands on a corner keeps the normal of the pad where the
    corner landed, which says nothing about the sides, through the stroke as well. A corner
    touches the pad along a line (one texel column) and a side along a strip (three), so
    the width filter drops the corners. On a round cylinder the fingers, turning with the
    object, also keep their normal through a stroke, so it would look like a many-sided
    object to this set-up; its contact strip (about 8 mm at the default size) is narrower
    than a side's, and the default filter drops it: the tracker then sees no flat side.

    Parameters
    ----------
    n_sides : int
        Number of sides (>= 3), or 0 for a round cylinder.
    turns : float
        Total rotation, turns.
    inradius : float
        Distance of the sides from the axis, m.
    depth : float
        How far each pad presses into the object at a grasp, m.
    step : float
        Mean rotation per sample, rad, in [0.1 deg, 20 deg) (each drawn within +-30 %).
    stroke : (float, float)
        Range of the rotation per stroke, rad.
    under_estimate : float
        Relative under-estimate of the odometry.
    slip_std : float
        Unobserved rotation at each regrasp, rad.
    pad_radius : float
        Radius of the pads' curvature across the finger (m), in the emulated world and
        in :func:`frame_normal_angles`.
    rate_hz : float
        Sampling rate (for the time stamps).
    min_width : float or None
        Narrowest blob kept, m across the finger (see :func:`frame_normal_angles`); None
        keeps every blob, corners included.
    name : str
    rng : None, int or numpy Generator

    Returns
    -------
    touchloc.dnf.RotationDataset
        With ``true_orientation`` and ``n_surfaces``.
    """
    import serial
    import trimesh

    from .._util import as_rng
    from ..dnf.data import RotationDataset
    from ..hardware.dnf_features import CurvedPadKinematics, frame_normal_angles
    from ..hardware.dsacon import DSACON32m
    from ..hardware.emulator import DSACON32mEmulator, SimWorld, TCPServer
    from ..models import MeshObject

    n_sides = _as_n_sides(n_sides)
    turns = as_float(turns, "turns", low=0.0, low_open=True, high=20.0)
    inradius = as_float(inradius, "inradius (m; the fingers' reach)", low=0.012, high=0.03)
    depth = as_float(depth, "depth (m)", low=0.0, low_open=True, high=0.002)
    # at least 0.1 deg: a finer step would take 3600 samples a turn and more
    step = as_float(step, "step (rad)", low=np.radians(0.1), high=np.radians(20.0), high_open=True)
    lo, hi = as_float_array(stroke, "stroke (rad)", shape=(2,))
    if not (0 < lo <= hi < np.pi):
        raise ValidationError(f"stroke must be (lo, hi) rad with 0 < lo <= hi < pi, got {stroke!r}")
    under_estimate = as_float(under_estimate, "under_estimate", low=-0.5, low_open=True, high=0.5, high_open=True)
    slip_std = as_float(slip_std, "slip_std (rad)", low=0.0, high=np.pi)
    pad_radius = as_float(pad_radius, "pad_radius (m)", low=0.0, low_open=True, high=1.0)
    rate_hz = as_float(rate_hz, "rate_hz", low=0.0, low_open=True, high=1e4)
    if min_width is not None:
        min_width = as_float(min_width, "min_width (m)", low=0.0, high=0.1, high_open=True)
    name = as_name(name, "name", allow_none=False)
    rng = as_rng(rng)
    th = np.radians(4.0)
    angles = np.array([np.radians(60.0), th, -th, th, -th, th, -th])
    diameter = 2 * inradius / np.cos(np.pi / n_sides) if n_sides else 2 * inradius
    mesh = trimesh.creation.cylinder(radius=diameter / 2, height=0.06, sections=int(n_sides) if n_sides else 96)
    obj = MeshObject(mesh, name=f"{n_sides}-gon prism" if n_sides else "round cylinder")
    z = 0.136                                    # middle of the distal pads
    kin = CurvedPadKinematics(pad_radius)
    state = {"world": SimWorld(obj, _rz(0.0, z), kinematics=kin)}
    grasp = angles
    emu = DSACON32mEmulator(frame_source=lambda: state["world"].pressures(grasp))
    srv = TCPServer(emu).start()
    port = serial.serial_for_url(srv.url, timeout=0.05)
    seqs, odo, truth = [], [], []
    theta = est = 0.0
    try:
        dev = DSACON32m(port, timeout=1.0, open_timeout=1.0)
        while theta < turns * 2 * np.pi:
            theta += rng.normal(0.0, slip_std) if slip_std > 0 else 0.0
            rot, phi = rng.uniform(lo, hi), 0.0
            grasp = _close_on(SimWorld(obj, _rz(theta, z), kinematics=kin), angles, depth)
            while phi < rot and theta < turns * 2 * np.pi:
                H = _rz(phi)
                state["world"] = SimWorld(obj, _rz(theta, z), H, kinematics=kin)
                frame = dev.read_frame()
                a, _ = frame_normal_angles(frame, grasp, axis=[0.0, 0.0, 1.0], reference=[1.0, 0.0, 0.0],
                                           pad_radius=pad_radius, hand_pose=H, min_width=min_width)
                seqs.append(a)
                odo.append(est)
                truth.append(theta)
                d = step * rng.uniform(0.7, 1.3)
                phi += d
                theta += d
                est += d * (1.0 - under_estimate)
    finally:
        port.close()
        srv.close()
    T = len(seqs)
    index = np.concatenate([np.full(a.size, i) for i, a in enumerate(seqs)]).astype(np.int64)
    return RotationDataset(np.arange(T) / rate_hz, np.array(odo), np.concatenate(seqs), index,
                           true_orientation=np.array(truth), n_surfaces=int(n_sides),
                           name=name or (f"{n_sides}-gon (emulated hand)" if n_sides else "round (emulated hand)"))


def _rz(a: float, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    T[:2, :2] = [[c, -s], [s, c]]
    T[2, 3] = z
    return T


def _close_on(world, angles, depth: float) -> np.ndarray:
    """Close each finger (proximal +a, distal -a: the distal pad stays parallel to the axis)
    until its distal pad presses ``depth`` into the object: a guarded grasp."""
    out = angles.copy()
    for f, (p, d) in enumerate(((1, 2), (3, 4), (5, 6))):
        lo, hi = np.radians(-6.0), np.radians(12.0)
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            out[p], out[d] = mid, -mid
            if float(world.penetration(out, (2 * f + 1,))[0].max()) > depth:
                hi = mid
            else:
                lo = mid
        out[p], out[d] = lo, -lo
    return out


def estimators_with_map(*, particles: int = 400, every: int = 4, rng=None) -> dict:
    """The DNF comparison's estimators plus the third family, the n-gon mapped in 3-D.

    ``every``: the map touches on every ``every``-th sample (seconds per data set, not
    milliseconds; it needs simulated data, whose true rotation turns the prism).
    """
    if isinstance(every, (bool, np.bool_)) or not isinstance(every, (int, np.integer)) or not 1 <= every <= 100:
        raise ValidationError(f"every must be an int in [1, 100] (samples), got {every!r}")
    out = default_estimators(particles=particles, rng=rng)
    out[MAPPED] = lambda: MappedPrismEstimator(every=int(every), rng=rng)
    return out

