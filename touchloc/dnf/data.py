"""Rotation data sets: the simulated experiment of seed 000 (section IV) and recorded data.

A data set is a sequence of ``T`` samples. Sample ``t`` has a time stamp, the hand's
odometry (its own estimate of the object's accumulated rotation, rad) and the angles of
the contact normals measured in that sample (rad, world frame; any number >= 1), such
that ``world angle = object-frame angle + rotation``.

File format
-----------
CSV (long format, one row per contact normal; ``#`` lines are comments)::

    time,odometry,normal_angle[,true_orientation]
    0.0,0.0,1.0472
    0.0,0.0,1.0490
    0.41,0.0698,1.1170
    ...

Rows with the same ``time`` form one sample (they must be consecutive and share the
odometry). A sample without contact is one row with an empty ``normal_angle``. Angles are in radians. ``true_orientation`` (optional) is the ground truth,
used only for error plots.

NPZ: arrays ``time (T,)``, ``odometry (T,)``, ``normal_angles (M,)`` and
``sample_index (M,)`` (int, the sample each normal belongs to, non-decreasing), optionally
``true_orientation (T,)`` and the scalars ``n_surfaces`` and ``name``.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._util import as_rng
from .._validate import (as_bool, as_count, as_float, as_float_array, as_instance, as_name, as_nonnegative_float,
                         as_path, as_positive_float, as_probability, as_sequence)
from ..errors import ValidationError

__all__ = ["RotationDataset", "generate_rotation_dataset", "standard_datasets", "load_recording",
           "save_recording", "OBJECTS", "SEED_FAITHFUL"]

TWO_PI = 2.0 * np.pi

#: the three objects of seed 000, section IV: number of flat sides (0: round cylinder)
OBJECTS = {"6-gon": 6, "8-gon": 8, "round": 0, "4-gon": 4, "5-gon": 5}


@dataclass
class RotationDataset:
    """A sequence of contact-normal samples during in-hand rotation.

    Attributes
    ----------
    time : (T,) float
        Sample times, s.
    odometry : (T,) float
        The hand's estimate of the accumulated rotation, rad.
    normal_angles : (M,) float
        All contact-normal angles, rad, world frame.
    sample_index : (M,) int
        Sample each normal belongs to (non-decreasing). A sample may have none (no
        contact, or a dropped sample): it still carries its time and odometry.
    true_orientation : (T,) float or None
        Ground-truth rotation (simulated data), rad.
    n_surfaces : int or None
        Number of flat sides of the object if known (0 for a round object).
    name : str
    """

    time: np.ndarray
    odometry: np.ndarray
    normal_angles: np.ndarray
    sample_index: np.ndarray
    true_orientation: np.ndarray | None = None
    n_surfaces: int | None = None
    name: str = ""
    _splits: list = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        self.time = as_float_array(self.time, "time", finite=False)
        self.odometry = as_float_array(self.odometry, "odometry", finite=False)
        self.normal_angles = as_float_array(self.normal_angles, "normal_angles", finite=False)
        self.sample_index = np.asarray(self.sample_index)
        if self.n_surfaces is not None:
            self.n_surfaces = as_count(self.n_surfaces, "n_surfaces", min=0, max=10_000)
        self.name = as_name(self.name, "name", allow_none=False)
        T = self.time.shape[0] if self.time.ndim == 1 else -1
        if self.time.ndim != 1 or T == 0:
            raise ValidationError(f"time must be a non-empty 1-D array, got shape {self.time.shape}")
        if self.odometry.shape != (T,):
            raise ValidationError(f"odometry must have shape ({T},) like time, got {self.odometry.shape}")
        if self.normal_angles.ndim != 1 or self.sample_index.shape != self.normal_angles.shape:
            raise ValidationError(f"normal_angles and sample_index must be 1-D of equal length, got "
                                  f"{self.normal_angles.shape} and {self.sample_index.shape}")
        if self.sample_index.size and not np.issubdtype(self.sample_index.dtype, np.integer):
            raise ValidationError(f"sample_index must be integers, got dtype {self.sample_index.dtype}")
        self.sample_index = self.sample_index.astype(np.int64)
        for name in ("time", "odometry", "normal_angles"):
            a = getattr(self, name)
            if not np.all(np.isfinite(a)):
                bad = int(np.flatnonzero(~np.isfinite(a))[0])
                raise ValidationError(f"{name} must be finite, entry {bad} is {a[bad]}")
        if np.any(np.diff(self.sample_index) < 0):
            raise ValidationError("sample_index must be non-decreasing (normals grouped by sample)")
        counts = np.bincount(self.sample_index, minlength=T) if self.sample_index.size else np.zeros(T, int)
        if self.sample_index.size and (self.sample_index[0] < 0 or self.sample_index[-1] >= T):
            raise ValidationError(f"sample_index must lie in [0, {T - 1}]")
        if self.true_orientation is not None:
            self.true_orientation = as_float_array(self.true_orientation, "true_orientation")
            if self.true_orientation.shape != (T,):
                raise ValidationError(f"true_orientation must have shape ({T},), got {self.true_orientation.shape}")
        self._splits = np.split(self.normal_angles, np.cumsum(counts)[:-1])

    def __len__(self) -> int:
        return self.time.shape[0]

    def samples(self):
        """Iterate ``(normal_angles (K_t,), odometry)`` per sample."""
        return zip(self._splits, self.odometry.tolist())

    def angles(self, t: int) -> np.ndarray:
        """Normal angles of sample ``t``, (K_t,) rad (``t`` from 0; negative counts from the end)."""
        t = as_count(t, "t", min=-len(self), max=len(self) - 1, why=f"the dataset has {len(self)} samples")
        return self._splits[t]

    def __repr__(self) -> str:
        return (f"RotationDataset({self.name!r}, {len(self)} samples, {self.normal_angles.size} normals, "
                f"{np.degrees(self.odometry[-1] - self.odometry[0]):.0f} deg odometry)")


#: settings of :func:`generate_rotation_dataset` close to a real SDH-2 with DSACON32m pads
#: (seed 000, II and IV-A): one to two blobs per finger and sample, each giving the normal of
#: the finger's curved pad at the blob centroid, 3 degrees of further angular noise and one
#: sample in ten without contact.
SEED_FAITHFUL = dict(normals_per_contact=(1, 2), noise=np.radians(3.0), drop=0.1, normal_source="pad")


def _range(x, name, low, high, *, low_open=True):
    """A (lo, hi) pair of finite floats with low < lo <= hi <= high (low <= lo when closed)."""
    lo, hi = as_float_array(x, name, shape=(2,), expected="a (low, high) pair of finite numbers")
    if not (lo > low if low_open else lo >= low) or not lo <= hi <= high:
        raise ValidationError(f"{name} must be (low, high) with {low} {'<' if low_open else '<='} low <= high "
                              f"<= {high:g}, got {(float(lo), float(hi))}")
    return float(lo), float(hi)


#: the generator keeps every sample in memory; more than this is a typing error
MAX_SAMPLES = 10_000_000


def _count(spec, name):
    """``normals_per_contact`` as a (lo, hi) int range with 1 <= lo <= hi <= 40."""
    if isinstance(spec, (str, bytes, bool, np.bool_)) or not (np.isscalar(spec) or np.shape(spec) == (2,)):
        raise ValidationError(f"{name} must be an int or an (lo, hi) int range within 1..40, got {spec!r}")
    lo, hi = (spec, spec) if np.isscalar(spec) else tuple(spec)
    lo, hi = as_float(lo, name), as_float(hi, name)
    if int(lo) != lo or int(hi) != hi or not 1 <= lo <= hi <= 40:
        raise ValidationError(f"{name} must be an int or an (lo, hi) int range within 1..40, got {spec!r}")
    return int(lo), int(hi)


def generate_rotation_dataset(n_sides: int, *, revolutions: float = 4.0, rate_hz=(2.0, 3.0),
                              diameter: float = 0.04, under_estimate=(0.04, 0.08),
                              slip_std: float = np.radians(1.5), stroke=(np.radians(25), np.radians(40)),
                              step=np.radians(4.0), face_fraction: float = 0.6,
                              normals_per_contact=None, noise: float = np.radians(2.0), drop: float = 0.0,
                              normal_source: str = "face", pad_radius: float = 0.02,
                              centroid_std: float = 0.001, edge_normals: bool = True, name: str = "",
                              rng=None) -> RotationDataset:
    """Simulate the rotation experiment of seed 000, section IV.

    An object with ``n_sides`` flat sides (a regular n-gon cylinder; 0 for a round one;
    4 cm across as in seed 000) turns on a fixed axis between two curved fingers on
    opposite sides. The hand turns it in strokes: it grasps, turns it by ``stroke`` while
    the fingers roll with it, releases and regrasps at the point-symmetric position
    (seed 000, Fig. 3). Each sample (2-3 Hz) holds the normals measured by the fingers in
    contact.

    With the defaults (``normals_per_contact=None``) it produces the dense data of the
    first version of this generator:

    - a finger that lands on a flat side measures that side's normal, sharply (12
      elements, ``noise`` = 2 degrees spread) - it rotates with the object during the stroke;
    - a finger that lands on an edge rolls over it and measures a broad spread of normals
      (6 elements spread over 80 % of the angle between the two sides);
    - on the round cylinder the contact normal points at the finger (world frame), so
      it sweeps through the object frame; 6 elements, 8 degrees spread.

    With ``normals_per_contact`` set, every finger in contact gives that many normals per
    sample (an int, or a ``(lo, hi)`` range drawn per finger and sample; 1-2 for a real
    hand's blobs), each with ``noise`` (standard deviation, rad), on faces, edges and the
    round object alike. ``normal_source="pad"`` models seed 000, section II: a normal is
    the *sensor surface's* normal at the blob centroid, found by forward kinematics. The
    finger's pad is rigid and curved (radius ``pad_radius``): on a flat side the pad
    touches where its normal opposes the side's, so the measured normal is the side's
    normal turned by the centroid's position error over the pad radius
    (``N(0, centroid_std) / pad_radius`` rad); on an edge the pad rocks and the normal
    lies anywhere between the two sides' normals; on the round object it points at the
    finger. :data:`SEED_FAITHFUL` holds such a setting.

    The odometry under-estimates each stroke's rotation by a factor drawn from
    ``under_estimate`` per data set (seed 000, II-B: "a strong tendency of systematically
    underestimating the object rotation"), and every release/regrasp turns the object by
    an unobserved ``N(0, slip_std)``. A fraction ``drop`` of the samples carries no
    normals (no contact detected); such samples keep their time and odometry.

    Parameters
    ----------
    n_sides : int
        Number of flat sides (>= 3), or 0 for a round cylinder.
    revolutions : float
        Total true rotation in turns (seed 000: four times 360 degrees).
    rate_hz : (float, float)
        Range of the sampling rate; each interval is drawn uniformly from it.
    diameter : float
        Object diameter, m (metadata; the normals do not depend on it).
    under_estimate : (float, float)
        Range of the odometry's relative under-estimate of rotation (the odometry bias).
    slip_std : float
        Standard deviation of the unobserved rotation at each regrasp, rad.
    stroke : (float, float)
        Range of the rotation per stroke, rad.
    step : float
        Mean rotation per sample, rad.
    face_fraction : float
        Fraction of the angle between two side normals in which a finger lands on the
        side rather than on an edge.
    normals_per_contact : None, int or (int, int)
        Normals per finger in contact and sample, 1..40; None for the dense default.
    noise : float
        Angular noise of each normal, rad (standard deviation).
    drop : float
        Probability in [0, 1) that a sample has no normals.
    normal_source : {"face", "pad"}
        Whether a normal is the touched side's normal plus noise, or the curved pad's
        normal at the blob centroid (see above).
    pad_radius, centroid_std : float
        Radius of curvature of the finger pad and standard deviation of the blob
        centroid's position on it, m (``normal_source="pad"`` only).
    edge_normals : bool
        False: a finger that landed on an edge reports no normals (its sample is as it
        would be otherwise, with that finger's normals left out; the random draws are the
        same, so the data set differs from the one with ``True`` only there). A probe of how
        much of a tracker's error comes from edges taken for sides; a real hand cannot do it.
    name : str
        Label of the data set.
    rng : None, int or numpy Generator

    Returns
    -------
    RotationDataset
    """
    if not isinstance(n_sides, (int, np.integer)) or (n_sides != 0 and n_sides < 3):
        raise ValidationError(f"n_sides must be 0 (round) or an int >= 3, got {n_sides!r}")
    revolutions = as_positive_float(revolutions, "revolutions")
    rate_hz = _range(rate_hz, "rate_hz", 0.0, 1e6)
    diameter = as_positive_float(diameter, "diameter (m)")
    under_estimate = _range(under_estimate, "under_estimate", 0.0, 0.99, low_open=False)
    slip_std = as_float(slip_std, "slip_std (rad)", low=0.0, high=np.pi)
    stroke = _range(stroke, "stroke (rad)", 0.0, TWO_PI)
    step = as_float(step, "step (rad)", low=1e-4, high=np.pi)
    face_fraction = as_probability(face_fraction, "face_fraction")
    noise = as_nonnegative_float(noise, "noise (rad)")
    drop = as_probability(drop, "drop", open_high=True)
    pad_radius = as_positive_float(pad_radius, "pad_radius (m)")
    centroid_std = as_nonnegative_float(centroid_std, "centroid_std (m)")
    edge_normals = as_bool(edge_normals, "edge_normals")
    name = as_name(name, "name", allow_none=False)
    n_samples = TWO_PI * revolutions * max(2.0 / stroke[0], 1.3 / step)
    if n_samples > MAX_SAMPLES:
        raise ValidationError(f"revolutions, stroke and step ask for about {n_samples:.3g} samples; at most "
                              f"{MAX_SAMPLES:.0e} are generated (every sample is kept in memory)")
    if not isinstance(normal_source, str) or normal_source not in ("face", "pad"):
        raise ValidationError(f"normal_source must be 'face' or 'pad', got {normal_source!r}")
    if normal_source == "pad" and not (pad_radius > 0 and centroid_std >= 0):
        raise ValidationError(f"pad_radius must be > 0 and centroid_std >= 0 (m), got {pad_radius!r}, "
                              f"{centroid_std!r}")
    dense = normals_per_contact is None
    if not dense:
        k_lo, k_hi = _count(normals_per_contact, "normals_per_contact")
    pad_std = centroid_std / pad_radius if normal_source == "pad" else 0.0
    rng = as_rng(rng)
    bias = rng.uniform(*under_estimate)
    total = TWO_PI * revolutions
    times, odo, truth, angles, index = [], [], [], [], []
    theta, est, t = 0.0, 0.0, 0.0
    k = 0
    half = np.pi / n_sides if n_sides else 0.0
    while theta < total:
        # regrasp: unobserved slip, fingers land near the point-symmetric position
        theta += rng.normal(0.0, slip_std)
        psi = np.array([0.0, np.pi]) + rng.normal(0.0, np.radians(3.0), 2)
        contact = []
        for p in psi:
            if n_sides:
                rel = p - theta
                j = np.round(rel / (2 * half))
                delta = (rel - j * 2 * half + np.pi) % TWO_PI - np.pi
                if abs(delta) < face_fraction * half:
                    contact.append(("face", j * 2 * half))
                else:
                    e = j * 2 * half + np.sign(delta) * half
                    contact.append(("edge", e))
            else:
                contact.append(("round", p))
        rot = rng.uniform(*stroke)
        n_steps = max(2, int(round(rot / step)))
        for s in range(n_steps):
            d = rot / n_steps * rng.uniform(0.7, 1.3) if s else 0.0
            theta += d
            est += d * (1.0 - bias) + rng.normal(0.0, np.radians(0.2)) * (d > 0)
            t += 1.0 / rng.uniform(*rate_hz)
            parts = []
            dropped = drop > 0 and rng.random() < drop
            for kind, a in contact:
                if dense:
                    if kind == "face":
                        tilt = rng.normal(0.0, np.radians(1.0))
                        parts.append(a + theta + tilt + rng.normal(0.0, noise, 12))
                    elif kind == "edge":
                        e = a + theta + rng.uniform(-0.8 * half, 0.8 * half, 6) + rng.normal(0.0, noise, 6)
                        parts.append(e if edge_normals else e[:0])
                    else:
                        parts.append(a + rng.normal(0.0, np.radians(8.0), 6))
                    continue
                m = int(rng.integers(k_lo, k_hi + 1))
                err = rng.normal(0.0, noise, m) + (rng.normal(0.0, pad_std, m) if pad_std else 0.0)
                if kind == "face":
                    parts.append(a + theta + err)
                elif kind == "edge":
                    e = a + theta + rng.uniform(-0.8 * half, 0.8 * half, m) + err
                    parts.append(e if edge_normals else e[:0])
                else:
                    parts.append(a + err)
            a = np.concatenate(parts) if not dropped else np.empty(0)
            angles.append(a)
            index.append(np.full(a.size, k))
            times.append(t)
            odo.append(est)
            truth.append(theta)
            k += 1
    normals = (np.concatenate(angles) + np.pi) % TWO_PI - np.pi
    return RotationDataset(np.array(times), np.array(odo), normals, np.concatenate(index).astype(np.int64),
                           true_orientation=np.array(truth), n_surfaces=int(n_sides),
                           name=name or (f"{n_sides}-gon" if n_sides else "round"))


def standard_datasets(objects=("6-gon", "8-gon", "round"), n_per_object: int = 5, *, seed: int = 0,
                      **kwargs) -> dict:
    """The data sets of seed 000's experiment: ``n_per_object`` per object, different seeds.

    Returns
    -------
    dict
        ``{object name: [RotationDataset, ...]}``; data set ``i`` of object ``o`` uses the
        seed ``(seed, index of o in OBJECTS, i)``.
    """
    names = list(OBJECTS)
    objects = as_sequence(objects, "objects", of=str, expected=f"a list of object names from {names}")
    n_per_object = as_count(n_per_object, "n_per_object", max=10_000, why="each data set is simulated and kept")
    seed = as_count(seed, "seed", min=0)
    out = {}
    for obj in objects:
        if obj not in OBJECTS:
            raise ValidationError(f"unknown object {obj!r}, expected one of {names}")
        out[obj] = [generate_rotation_dataset(OBJECTS[obj], name=f"{obj} #{i + 1}",
                                              rng=np.random.default_rng([seed, names.index(obj), i]), **kwargs)
                    for i in range(n_per_object)]
    return out


def save_recording(ds: RotationDataset, path) -> Path:
    """Write a data set as ``.csv`` or ``.npz`` (chosen by the suffix); returns the path."""
    ds = as_instance(ds, RotationDataset, "ds")
    path = as_path(path, "path", must_exist=False)
    if path.suffix not in (".npz", ".csv"):
        raise ValidationError(f"recording path must end in .csv or .npz, got {path.name!r}")
    try:
        _write_recording(ds, path)
    except OSError as exc:
        raise ValidationError(f"cannot write the recording {path}: {exc}") from None
    return path


def _write_recording(ds, path):
    if path.suffix == ".npz":
        extra = {}
        if ds.true_orientation is not None:
            extra["true_orientation"] = ds.true_orientation
        if ds.n_surfaces is not None:
            extra["n_surfaces"] = np.int64(ds.n_surfaces)
        np.savez(path, time=ds.time, odometry=ds.odometry, normal_angles=ds.normal_angles,
                 sample_index=ds.sample_index, name=np.str_(ds.name), **extra)
    else:
        truth = ds.true_orientation is not None
        with open(path, "w", newline="") as fh:
            if ds.name:
                fh.write(f"# name: {ds.name}\n")
            if ds.n_surfaces is not None:
                fh.write(f"# n_surfaces: {ds.n_surfaces}\n")
            w = csv.writer(fh)
            w.writerow(["time", "odometry", "normal_angle"] + (["true_orientation"] if truth else []))
            for i in range(len(ds)):
                # a sample without normals is one row with an empty normal_angle
                for a in (ds.angles(i).tolist() or [""]):
                    row = [repr(float(ds.time[i])), repr(float(ds.odometry[i])), repr(a) if a != "" else ""]
                    if truth:
                        row.append(repr(float(ds.true_orientation[i])))
                    w.writerow(row)


def load_recording(path) -> RotationDataset:
    """Load a recorded data set from ``.csv`` or ``.npz`` (format in the module docs).

    Raises
    ------
    ValidationError
        If the file is missing, empty, lacks a column or holds non-finite values.
    """
    path = as_path(path, "path", must_exist=False)
    if not path.exists():
        raise ValidationError(f"no recording at {path}")
    if not path.is_file():
        raise ValidationError(f"recording path must be a file, got {path}")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("time", "odometry", "normal_angles", "sample_index") if k not in z]
            if missing:
                raise ValidationError(f"{path.name} lacks arrays {missing}; expected time, odometry, "
                                      "normal_angles, sample_index")
            return RotationDataset(z["time"], z["odometry"], z["normal_angles"], z["sample_index"],
                                   true_orientation=z["true_orientation"] if "true_orientation" in z else None,
                                   n_surfaces=int(z["n_surfaces"]) if "n_surfaces" in z else None,
                                   name=str(z["name"]) if "name" in z else path.stem)
    if path.suffix != ".csv":
        raise ValidationError(f"recording path must end in .csv or .npz, got {path.name!r}")
    meta, lines = {}, []
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            if ":" in line:
                k, v = line[1:].split(":", 1)
                meta[k.strip()] = v.strip()
        elif line.strip():
            lines.append(line)
    if len(lines) < 2:
        raise ValidationError(f"{path.name} holds no samples (expected a header and at least one row)")
    reader = csv.DictReader(io.StringIO("\n".join(lines)))
    cols = [c.strip() for c in (reader.fieldnames or [])]
    for c in ("time", "odometry", "normal_angle"):
        if c not in cols:
            raise ValidationError(f"{path.name} lacks column {c!r}; header is {cols}")
    try:
        records = list(reader)
        # an empty normal_angle marks a sample without contact
        has = np.array([bool((r["normal_angle"] or "").strip()) for r in records], dtype=bool)
        rows = np.array([[float(r[c]) if (c != "normal_angle" or h) else 0.0 for c in cols]
                         for r, h in zip(records, has)], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{path.name}: every value must be a number: {exc}") from None
    col = {c: rows[:, i] for i, c in enumerate(cols)}
    t = col["time"]
    new = np.r_[True, t[1:] != t[:-1]]
    sample_index = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    odo = col["odometry"]
    if np.any(odo != odo[first][sample_index]):
        raise ValidationError(f"{path.name}: rows of one sample (same time) must share the odometry")
    truth = col["true_orientation"][first] if "true_orientation" in col else None
    n_surf = int(meta["n_surfaces"]) if "n_surfaces" in meta else None
    return RotationDataset(t[first], odo[first], col["normal_angle"][has], sample_index[has], true_orientation=truth,
                           n_surfaces=n_surf, name=meta.get("name", path.stem))
