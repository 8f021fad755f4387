"""Simulated dynamic tactile scans in the manner of seed 002.

A 16 x 16 pressure pad (6 mm pitch, 12-bit readings, 10 Hz) is lowered onto an object
resting on a table until a pressure threshold is reached, tilted to the right about its
leading contact, and then rolled around the object at that tilt while keeping contact.
A scan is the fixed-length recording of 160 frames that starts at first contact; frames
after the motion ends are blank, as in the seed ("If the actual time needed to go around
the object is less, the last frames remain blank").

Geometry of the motion
----------------------
The pad is a rigid plane covered by an elastic layer. A pad "keeping contact" with a
convex surface is a support plane of the object's convex hull pressed in by a fixed
indentation ``delta``: for pad normal ``n`` (pointing from the object to the pad) the pad
plane passes through ``s(n) - delta * n``, where ``s(n)`` is the hull vertex furthest along
``n``. Tilting "about the leading contact" is what a support plane does when its normal
turns: it pivots about ``s(n)`` until a new vertex takes over. The pad rolls without
slipping: the point of the pad touching the object moves over the pad by the in-plane
displacement of ``s(n)`` (so, as the seed notes, a point of the object keeps appearing at
the same sensor location); when that point nears the pad's border the pad slides instead.
Where only an edge or a corner of the object touches and the texels barely feel it,
the pad is pressed further along its normal (up to five times the contact indentation,
within the layer thickness), as a force-controlled arm keeping contact would.
Tilting stops at ``max_tilt`` or when the pad's border would touch the table (the seed's
border-pressure rule); the roll-around keeps the tilt but lowers it where the table
would be touched. Timing follows a robot limited in linear and angular speed, so larger
objects take more frames.

Pressure
--------
Each texel's indentation is the deepest intrusion of the mesh surface into its area, along
the pad normal (``subsamples`` x ``subsamples`` rays per texel and frame), capped at the
layer thickness. The elastic
layer spreads load to neighbouring texels (a Gaussian of ``spread`` texels), the
piezo-resistive response saturates (``1 - exp(-depth / saturation_depth)``), every texel
has its own gain, readings carry Gaussian noise, and readings below a floor are reported
as zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .._util import as_rng, progress_keyword
from .._util import progress as show_progress
from .._validate import as_count, as_float, as_instance, as_nonnegative_float, as_pose, as_positive_float
from ..errors import ValidationError
from ..models import MeshObject

__all__ = ["PadConfig", "Scan", "TactileScanner", "simulate_dataset"]


@dataclass(frozen=True)
class PadConfig:
    """Parameters of the simulated pad, its motion and the scan-to-scan variation.

    Lengths are in metres, angles in radians, readings in counts. The defaults follow
    seed 002 (16 x 16 texels at 6 mm, 12-bit, 10 Hz, 160 frames); the rest are chosen to
    give plausible sequences and are documented in docs/recognition.md.
    """

    n_texels: int = 16
    pitch: float = 0.006
    n_frames: int = 160
    frame_rate: float = 10.0
    max_value: int = 4095
    # elastic layer and transducer
    layer_thickness: float = 0.004
    saturation_depth: float = 0.0015
    spread: float = 0.5
    subsamples: int = 3
    gain_jitter: float = 0.08
    noise: float = 20.0
    floor: float = 60.0
    # motion
    approach_step: float = 0.0004
    contact_threshold: float = 1500.0
    max_tilt: float = np.deg2rad(60.0)
    table_clearance: float = 0.001
    linear_speed: float = 0.04
    angular_speed: float = np.deg2rad(36.0)
    tilt_step: float = np.deg2rad(0.5)
    roll_step: float = np.deg2rad(1.0)
    # variation between scans of one object
    translation_jitter: float = 0.004
    rotation_jitter: float = np.deg2rad(5.0)

    def __post_init__(self):
        for name in ("pitch", "frame_rate", "layer_thickness", "saturation_depth", "approach_step",
                     "linear_speed", "angular_speed", "tilt_step", "roll_step"):
            as_positive_float(getattr(self, name), f"PadConfig.{name}")
        for name in ("spread", "gain_jitter", "noise", "floor", "max_tilt", "table_clearance",
                     "translation_jitter", "rotation_jitter"):
            as_nonnegative_float(getattr(self, name), f"PadConfig.{name}")
        as_count(self.n_texels, "PadConfig.n_texels", min=2, max=1024, why="a pad has n_texels^2 texels")
        as_count(self.subsamples, "PadConfig.subsamples", max=64, why="subsamples^2 rays per texel")
        as_count(self.n_frames, "PadConfig.n_frames", max=100_000, why="every frame of a scan is kept")
        as_positive_float(self.max_value, "PadConfig.max_value")
        as_float(self.contact_threshold, "PadConfig.contact_threshold")
        if int(self.n_texels) != self.n_texels or self.n_texels < 2:
            raise ValidationError(f"PadConfig.n_texels must be an integer >= 2, got {self.n_texels}")
        if int(self.subsamples) != self.subsamples or self.subsamples < 1:
            raise ValidationError(f"PadConfig.subsamples must be a positive integer, got {self.subsamples}")
        if int(self.n_frames) != self.n_frames or self.n_frames < 1:
            raise ValidationError(f"PadConfig.n_frames must be a positive integer, got {self.n_frames}")
        if not 0 < self.contact_threshold < self.max_value:
            raise ValidationError(f"PadConfig.contact_threshold must lie in (0, max_value={self.max_value}), "
                                  f"got {self.contact_threshold}")

    @property
    def half_width(self) -> float:
        """Distance (m) from the pad centre to the centre of its outermost texels."""
        return 0.5 * (self.n_texels - 1) * self.pitch

    @property
    def texel_uv(self) -> np.ndarray:
        """(n_texels**2, 2) float: texel centres in the pad plane (m), row-major (row = v)."""
        c = (np.arange(self.n_texels) - 0.5 * (self.n_texels - 1)) * self.pitch
        v, u = np.meshgrid(c, c, indexing="ij")
        return np.stack([u.ravel(), v.ravel()], axis=1)

    @property
    def subsample_uv(self) -> np.ndarray:
        """(subsamples**2, 2) float: offsets (m) of the depth samples within one texel."""
        m = int(self.subsamples)
        o = ((np.arange(m) + 0.5) / m - 0.5) * self.pitch
        v, u = np.meshgrid(o, o, indexing="ij")
        return np.stack([u.ravel(), v.ravel()], axis=1)


@dataclass
class Scan:
    """One simulated scan and how it was taken.

    Attributes
    ----------
    frames : (n_frames, n_texels, n_texels) uint16
        Readings; row index = pad y, column index = pad x (x points to the tilt side).
    pad_poses : (n_motion, 4, 4) float
        T_world_pad of each recorded frame of motion (the pad's z axis points away from
        the object); frames after ``len(pad_poses)`` are blank.
    object_pose : (4, 4) float
        T_world_object (the object rests on the table z = 0).
    phase : (n_motion,) int
        0 approach, 1 tilt, 2 roll-around.
    depth : (n_motion, n_texels, n_texels) float
        Indentation of each texel (m) before the elastic spread and noise.
    """

    frames: np.ndarray
    pad_poses: np.ndarray
    object_pose: np.ndarray
    phase: np.ndarray
    depth: np.ndarray = field(repr=False)


def _rot_tilt(alpha, phi):
    """(K, 3, 3): Rz(phi) Ry(alpha) Rz(-phi), a tilt by alpha towards azimuth phi."""
    alpha = np.asarray(alpha, dtype=np.float64)
    phi = np.broadcast_to(np.asarray(phi, dtype=np.float64), alpha.shape)
    ca, sa, cp, sp = np.cos(alpha), np.sin(alpha), np.cos(phi), np.sin(phi)
    R = np.empty(alpha.shape + (3, 3))
    R[..., 0, 0] = cp * cp * ca + sp * sp
    R[..., 0, 1] = cp * sp * (ca - 1.0)
    R[..., 0, 2] = cp * sa
    R[..., 1, 0] = cp * sp * (ca - 1.0)
    R[..., 1, 1] = sp * sp * ca + cp * cp
    R[..., 1, 2] = sp * sa
    R[..., 2, 0] = -cp * sa
    R[..., 2, 1] = -sp * sa
    R[..., 2, 2] = ca
    return R


class TactileScanner:
    """Simulate seed 002's scans of any :class:`touchloc.models.MeshObject`.

    Parameters
    ----------
    config : PadConfig, optional
        Pad, motion and variation parameters (defaults follow seed 002).

    Examples
    --------
    >>> from touchloc.data import load_object
    >>> scanner = TactileScanner()
    >>> X = scanner.scan_many(load_object("can"), 3, rng=0)   # doctest: +SKIP
    >>> X.shape                                               # doctest: +SKIP
    (3, 160, 16, 16)
    """

    def __init__(self, config: PadConfig | None = None):
        if config is None:
            config = PadConfig()
        if not isinstance(config, PadConfig):
            raise ValidationError(f"config must be a PadConfig, got {type(config).__name__}")
        self.config = config
        self._hulls: dict = {}

    # -- public ----------------------------------------------------------------------
    def scan(self, obj, *, rng=None, object_pose=None) -> Scan:
        """Take one scan of ``obj``.

        Parameters
        ----------
        obj : MeshObject
            The object, in its own frame; it is placed on the table (lowest point at
            z = 0, bounding box centred on the world origin) and then shifted and turned
            about the vertical by the configured jitter.
        rng : None, int or numpy.random.Generator
        object_pose : (4, 4) float, optional
            T_world_object to use instead of a random one.

        Returns
        -------
        Scan
        """
        obj = as_instance(obj, MeshObject, "obj")
        rng = as_rng(rng)
        cfg = self.config
        if object_pose is None:
            object_pose = self.random_object_pose(obj, rng=rng)
        else:
            object_pose = as_pose(object_pose, "object_pose")
        gain = 1.0 + cfg.gain_jitter * rng.standard_normal((cfg.n_texels, cfg.n_texels))
        hull = self._hull(obj) @ object_pose[:3, :3].T + object_pose[:3, 3]

        # 1) approach: horizontal pad above the table centre, lowered one step per frame
        n_max = int(np.ceil(cfg.layer_thickness / cfg.approach_step)) + 1
        top = hull[:, 2].max()
        delta = (rng.random() + np.arange(n_max)) * cfg.approach_step
        R0 = np.broadcast_to(np.eye(3), (n_max, 3, 3))
        c0 = np.zeros((n_max, 3))
        c0[:, 2] = top - delta
        depth = self._depth(obj, object_pose, R0, c0)
        read = self._readings(depth, gain, rng)
        hit = np.flatnonzero(read.reshape(n_max, -1).max(axis=1) >= cfg.contact_threshold)
        n_app = int(hit[0]) + 1 if len(hit) else n_max
        # frames are recorded from first contact on
        first = np.flatnonzero(depth.reshape(n_max, -1).max(axis=1) > 0)
        i0 = int(first[0]) if len(first) and first[0] < n_app else n_app - 1
        app_R, app_c = R0[i0:n_app], c0[i0:n_app]
        d_contact = float(delta[n_app - 1])

        # 2) tilt and 3) roll-around, on a fine grid, then resampled in time
        R, c, phase = self._motion(hull, d_contact)
        R_all = np.concatenate([app_R, R])
        c_all = np.concatenate([app_c, c])
        ph_all = np.concatenate([np.zeros(len(app_R), int), phase])
        idx = self._timing(R_all, c_all, n_fixed=len(app_R))
        R_all, c_all, ph_all = R_all[idx], c_all[idx], ph_all[idx]

        depth = self._depth(obj, object_pose, R_all, c_all)
        # keeping contact: where an edge or a corner barely touches, press further along
        # the normal (force control), in steps up to the layer thickness
        weak = np.flatnonzero((ph_all > 0) & (depth.reshape(len(idx), -1).max(axis=1) < 0.5 * d_contact))
        for m in (1.5, 2.25, 3.4, 5.0):
            if len(weak) == 0:
                break
            extra = min((m - 1.0) * d_contact, cfg.layer_thickness - d_contact)
            if extra <= 0:
                break
            c_try = c_all[weak] - extra * R_all[weak, :, 2]
            d_try = self._depth(obj, object_pose, R_all[weak], c_try)
            ok = d_try.reshape(len(weak), -1).max(axis=1) >= 0.5 * d_contact
            c_all[weak[ok]] = c_try[ok]
            depth[weak[ok]] = d_try[ok]
            weak = weak[~ok]
        frames = np.zeros((cfg.n_frames, cfg.n_texels, cfg.n_texels), dtype=np.uint16)
        frames[: len(idx)] = self._readings(depth, gain, rng)
        poses = np.tile(np.eye(4), (len(idx), 1, 1))
        poses[:, :3, :3] = R_all
        poses[:, :3, 3] = c_all
        return Scan(frames=frames, pad_poses=poses, object_pose=object_pose, phase=ph_all, depth=depth)

    def scan_many(self, obj, n_scans: int, *, rng=None, progress=None, progress_bar=None) -> np.ndarray:
        """(n_scans, n_frames, n_texels, n_texels) uint16: independent scans of ``obj``
        (``progress``: a bar over the scans, as in :func:`simulate_dataset`)."""
        obj = as_instance(obj, MeshObject, "obj")
        progress = progress_keyword(progress, progress_bar, "scan_many")
        n_scans = as_count(n_scans, "n_scans", max=1_000_000, why="each scan is a simulated grasp sequence")
        rng = as_rng(rng)
        out = [self.scan(obj, rng=rng).frames for _ in show_progress(range(n_scans), desc=getattr(obj, "name", "scan"),
                                                                     enabled=progress)]
        return np.stack(out)

    def random_object_pose(self, obj, *, rng=None) -> np.ndarray:
        """(4, 4) float: the object on the table, shifted and turned by the jitter."""
        obj = as_instance(obj, MeshObject, "obj")
        rng = as_rng(rng)
        cfg = self.config
        b = obj.bounds
        centre = np.array([0.5 * (b[0, 0] + b[1, 0]), 0.5 * (b[0, 1] + b[1, 1]), b[0, 2]])
        yaw = cfg.rotation_jitter * rng.standard_normal()
        t = np.zeros(3)
        t[:2] = cfg.translation_jitter * rng.standard_normal(2)
        cy, sy = np.cos(yaw), np.sin(yaw)
        Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        T = np.eye(4)
        T[:3, :3] = Rz
        T[:3, 3] = t - Rz @ centre
        return T

    # -- internals -------------------------------------------------------------------
    def _hull_edges(self, obj):
        """Vertices (V, 3) and edges (E, 2) of the convex hull, in the object frame."""
        key = ("edges", id(obj))
        h = self._hulls.get(key)
        if h is None or h[0] is not obj:
            try:
                hull = obj.mesh.convex_hull
                h = (obj, np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.edges_unique, dtype=int))
            except Exception:  # degenerate hull: every mesh edge
                h = (obj, np.asarray(obj.mesh.vertices, dtype=np.float64), np.asarray(obj.mesh.edges_unique, dtype=int))
            self._hulls[key] = h
        return h[1], h[2]

    def _hull(self, obj) -> np.ndarray:
        key = id(obj)
        h = self._hulls.get(key)
        if h is None or h[0] is not obj:
            try:
                v = np.asarray(obj.mesh.convex_hull.vertices, dtype=np.float64)
            except Exception:  # degenerate hull: fall back to all vertices
                v = np.asarray(obj.mesh.vertices, dtype=np.float64)
            h = (obj, v)
            self._hulls[key] = h
        return h[1]

    def _motion(self, hull, delta):
        """Fine-grid pad rotations (K, 3, 3), centres (K, 3) and phases (K,) of tilt + roll."""
        cfg = self.config
        L = cfg.half_width
        qmax = L - cfg.pitch
        corners = np.array([[sx * L, sy * L, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        fractions = np.linspace(1.0, 0.0, 11)

        def place(alpha, phi, q_prev, s_prev):
            """Candidate poses for tilts ``alpha`` (C,) at azimuth phi, rolled from q_prev."""
            R = _rot_tilt(alpha, phi)
            n = R[:, :, 2]
            s = hull[np.argmax(n @ hull.T, axis=1)]
            dq = np.einsum("kji,kj->ki", R, s - s_prev)[:, :2]
            q = np.clip(q_prev + dq, -qmax, qmax)
            c = s - delta * n - np.einsum("kij,kj->ki", R[:, :, :2], q)
            low = (c[:, None, :] + np.einsum("kij,cj->kci", R, corners))[..., 2].min(axis=1)
            return R, s, q, c, low

        R0 = np.eye(3)
        s = hull[np.argmax(hull[:, 2])]
        q = s[:2].copy()  # the pad starts centred above the table origin
        Rs, cs, phase = [], [], []
        # tilt to the right (+x), pivoting on the leading contact
        alpha = 0.0
        n_tilt = max(1, int(np.ceil(cfg.max_tilt / cfg.tilt_step)))
        for k in range(1, n_tilt + 1):
            a = min(cfg.max_tilt, k * cfg.tilt_step)
            R, s1, q1, c, low = place(np.array([a]), 0.0, q, s)
            if low[0] < cfg.table_clearance:
                break
            alpha, s, q = a, s1[0], q1[0]
            Rs.append(R[0])
            cs.append(c[0])
            phase.append(1)
        if not Rs:  # no room to tilt: keep the horizontal pose
            Rs.append(R0)
            cs.append(s - delta * R0[:, 2] - np.r_[q, 0.0])
            phase.append(1)
        # roll around: the tilt direction turns through a full circle
        n_roll = max(1, int(np.ceil(2 * np.pi / cfg.roll_step)))
        for phi in np.linspace(0.0, 2 * np.pi, n_roll + 1)[1:]:
            R, s1, q1, c, low = place(alpha * fractions, phi, q, s)
            ok = np.flatnonzero(low >= cfg.table_clearance)
            j = int(ok[0]) if len(ok) else len(fractions) - 1
            s, q = s1[j], q1[j]
            Rs.append(R[j])
            cs.append(c[j])
            phase.append(2)
        return np.stack(Rs), np.stack(cs), np.asarray(phase)

    def _timing(self, R, c, n_fixed):
        """Indices into the fine grid of the recorded frames (speed-limited motion)."""
        cfg = self.config
        dt = 1.0 / cfg.frame_rate
        dc = np.linalg.norm(np.diff(c, axis=0), axis=1)
        cos = (np.einsum("kij,kij->k", R[1:], R[:-1]) - 1.0) / 2.0
        dang = np.arccos(np.clip(cos, -1.0, 1.0))
        step_t = np.maximum(dc / cfg.linear_speed, dang / cfg.angular_speed)
        step_t[: max(n_fixed - 1, 0)] = dt  # approach frames are recorded one by one
        t = np.concatenate([[0.0], np.cumsum(step_t)])
        frame_t = np.arange(cfg.n_frames) * dt
        frame_t = frame_t[frame_t <= t[-1] + 1e-12]
        idx = np.searchsorted(t, frame_t - 1e-9, side="left")
        return np.minimum(idx, len(t) - 1)

    def _depth(self, obj, object_pose, R, c):
        """(K, n, n) float: indentation of every texel for pad rotations R and centres c."""
        cfg = self.config
        K = len(R)
        sub = cfg.subsample_uv
        back = cfg.layer_thickness + 0.002
        # everything in the object frame: rays from just behind the pad, along -normal
        Rw, tw = object_pose[:3, :3], object_pose[:3, 3]
        Ro = np.matmul(Rw.T[None], R)  # (K, 3, 3)
        n = Ro[:, :, 2]
        start = (c - tw) @ Rw + back * n  # (K, 3)
        P = start[:, None, :] + np.matmul(cfg.texel_uv[None], Ro[:, :, :2].transpose(0, 2, 1))  # (K, T, 3)
        # Only the cap of the convex hull in front of the pad surface can indent the pad.
        # Its vertices are the hull vertices in front and the crossings of hull edges with
        # the pad plane; their bounding box in pad coordinates bounds the texels to test.
        hv, he = self._hull_edges(obj)
        level = np.einsum("ki,ki->k", start - back * n, n)  # pad surface along n
        h = n @ hv.T - level[:, None]  # (K, V) height of each hull vertex above the pad
        ha, hb = h[:, he[:, 0]], h[:, he[:, 1]]
        cross = (ha > 0) != (hb > 0)
        f = np.where(cross, ha / np.where(cross, ha - hb, 1.0), 0.0)
        pts_e = hv[he[:, 0]][None] + f[:, :, None] * (hv[he[:, 1]] - hv[he[:, 0]])[None]  # (K, E, 3)
        uv_lo = np.full((K, 2), np.inf)
        uv_hi = np.full((K, 2), -np.inf)
        for pts, mask in ((np.broadcast_to(hv[None], (K,) + hv.shape), h > 0), (pts_e, cross)):
            uv = np.einsum("kpi,kij->kpj", pts - start[:, None, :], Ro[:, :, :2])
            uv_lo = np.minimum(uv_lo, np.where(mask[:, :, None], uv, np.inf).min(axis=1))
            uv_hi = np.maximum(uv_hi, np.where(mask[:, :, None], uv, -np.inf).max(axis=1))
        half = 0.5 * cfg.pitch + 1e-6
        tuv = cfg.texel_uv
        near = ((tuv[None, :, 0] >= uv_lo[:, None, 0] - half) & (tuv[None, :, 0] <= uv_hi[:, None, 0] + half)
                & (tuv[None, :, 1] >= uv_lo[:, None, 1] - half) & (tuv[None, :, 1] <= uv_hi[:, None, 1] + half))
        kk, tt = np.nonzero(near)
        depth = np.zeros((K, cfg.n_texels ** 2))
        if len(kk):
            origins = P[kk, tt][:, None, :] + np.matmul(sub[None], Ro[kk][:, :, :2].transpose(0, 2, 1))
            dirs = np.broadcast_to(-n[kk][:, None, :], origins.shape)
            dist = obj.ray_cast(origins.reshape(-1, 3), dirs.reshape(-1, 3))[0]
            d = np.clip(back - dist, 0.0, cfg.layer_thickness)  # inf (miss) -> 0
            # a texel feels the deepest indentation within its area
            depth[kk, tt] = d.reshape(len(kk), len(sub)).max(axis=1)
        return depth.reshape(K, cfg.n_texels, cfg.n_texels)

    def _readings(self, depth, gain, rng):
        cfg = self.config
        p = ndimage.gaussian_filter(depth, sigma=(0, cfg.spread, cfg.spread), mode="constant") if cfg.spread > 0 else depth
        v = cfg.max_value * (1.0 - np.exp(-p / cfg.saturation_depth)) * gain
        v = v + cfg.noise * rng.standard_normal(v.shape)
        v = np.where(v < cfg.floor, 0.0, v)
        return np.clip(np.rint(v), 0, cfg.max_value).astype(np.uint16)


def simulate_dataset(objects, n_scans: int = 20, *, scanner: TactileScanner | None = None, rng=None,
                     progress=None, progress_bar=None):
    """Scans of several objects, ready for :class:`SequenceClassifier`.

    Parameters
    ----------
    objects : dict of str -> MeshObject, or sequence of MeshObject
        Objects to scan (a sequence is labelled by each object's ``name``).
    n_scans : int
        Scans per object (seed 002: 20).
    scanner : TactileScanner, optional
    rng : None, int or numpy.random.Generator
    progress : bool, optional
        A bar over each object's scans (default: when stderr is a terminal; otherwise a line to stderr every few
        seconds). ``progress_bar=`` is its deprecated old name.

    Returns
    -------
    X : (n_objects * n_scans, n_frames, n_texels, n_texels) uint16
    y : (n_objects * n_scans,) str
        Object name of each scan, grouped by object.
    """
    n_scans = as_count(n_scans, "n_scans", max=100_000, why="every scan (n_frames x texels) is kept in memory")
    if scanner is not None and not isinstance(scanner, TactileScanner):
        raise ValidationError(f"scanner must be a TactileScanner or None, got {type(scanner).__name__}")
    progress = progress_keyword(progress, progress_bar, "simulate_dataset")
    if isinstance(objects, (str, bytes)) or not hasattr(objects, "__iter__"):
        raise ValidationError(f"objects must be a dict name -> MeshObject or a list of MeshObjects, "
                              f"got {type(objects).__name__}")
    if isinstance(objects, dict):
        items = list(objects.items())
    else:
        items = [(getattr(o, "name", str(i)), o) for i, o in enumerate(objects)]
    if not items:
        raise ValidationError("objects must hold at least one object, got none")
    from ..models import MeshObject

    for name, o in items:
        if not isinstance(o, MeshObject):
            raise ValidationError(f"objects[{name!r}] must be a MeshObject, got {type(o).__name__}")
    scanner = scanner or TactileScanner()
    rng = as_rng(rng)
    X = np.concatenate([scanner.scan_many(o, n_scans, rng=rng, progress=progress) for _, o in items])
    y = np.repeat(np.array([name for name, _ in items]), int(n_scans))
    return X, y
