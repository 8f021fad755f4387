"""A sweep: a grid of trial parameters, declared in TOML or in Python."""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from .._validate import as_count, as_nonnegative_float, as_positive_float
from ..errors import ValidationError

__all__ = ["Sweep", "DNFSweep", "DNF_ESTIMATORS", "ESTIMATORS", "PLANNERS", "MODES", "LOOP_OPTIONS", "trial_id", "bundled_sweeps"]

#: estimator names a passive trial accepts (see touchloc.experiments.trial)
ESTIMATORS = ("ss", "pf", "hf", "apf", "mpf", "smc", "ss+mcmc")
#: planner names an active trial accepts
PLANNERS = ("one-step", "two-step", "random")
#: trial kinds: localise from given contacts, localise by planned touches, tell which mesh was touched
MODES = ("passive", "active", "identify")
REGIONS = ("full", "planar")
#: half-extent (m) of the pose region when the sweep does not give one
DEFAULT_HALF_EXTENT = {"full": 0.2, "planar": 0.05}
#: keyword arguments of touchloc.planners.loop.active_localization an active sweep may set
LOOP_OPTIONS = ("n_particles", "stop_error", "stop_probability", "stop_metric", "confidence", "min_touches")


def trial_id(params: dict) -> str:
    """A stable 16-hex-digit key of a trial's parameters (for resuming)."""
    if not isinstance(params, dict):
        raise ValidationError(f"params must be a dict of plain values, got {type(params).__name__}")
    try:
        blob = json.dumps(params, sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"params must hold plain JSON values (str, numbers, lists, dicts): {exc}") from None
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def bundled_sweeps() -> dict:
    """{name: path} of the sweep files shipped with touchloc (``touchloc sweep NAME`` runs one)."""
    d = Path(__file__).resolve().parent / "sweeps"
    return {p.stem: p for p in sorted(d.glob("*.toml"))}


def _from_dict(d, default_kind="localization"):
    if not isinstance(d, dict):
        raise ValidationError(f"a sweep is declared by a dict of its keys, got {type(d).__name__}")
    d = dict(d)
    kind = d.pop("kind", default_kind)
    if kind not in ("localization", "dnf"):
        raise ValidationError(f"sweep kind must be 'localization' (the default) or 'dnf', got {kind!r}")
    target = DNFSweep if kind == "dnf" else Sweep
    known = set(target.__dataclass_fields__)
    extra = set(d) - known
    if extra:
        raise ValidationError(f"unknown sweep keys {sorted(extra)}; expected some of {sorted(known)}")
    return target(**d)


def _named_choices(value, field_name, what, allowed) -> list:
    """A sweep field of names or ``{"name": ..., **options}`` dicts, as a list of dicts."""
    out = []
    for e in _as_list(value, field_name):
        if not isinstance(e, (str, dict)):
            raise ValidationError(f"sweep {field_name} must be names or dicts, got {type(e).__name__}")
        e = {"name": e} if isinstance(e, str) else dict(e)
        if e.get("name") not in allowed:
            raise ValidationError(f"{what} name must be one of {allowed}, got {e.get('name')!r}")
        out.append(e)
    return out


def _as_list(x, name):
    if isinstance(x, (str, int, float, dict, os.PathLike)):
        x = [x]
    if x is None or isinstance(x, (bool, bytes, complex)) or not hasattr(x, "__iter__"):
        raise ValidationError(f"sweep {name} must be a list (or one value), got {type(x).__name__} {x!r}"[:160])
    x = list(x)
    if not x:
        raise ValidationError(f"sweep {name} must not be empty")
    return x


@dataclass
class Sweep:
    """A grid of localisation trials.

    Every combination of mesh x estimator x contact count x noise x seed (passive
    trials), mesh x planner x touch budget x noise x seed (active trials) and mesh x
    contact count x noise x seed (identification trials) is one trial; a trial is a pure
    function of its parameters (see :func:`run_trial`).

    Parameters
    ----------
    meshes : list of str
        Bundled names or mesh files (in metres; files must be readable by every worker).
    estimators : list of str or dict
        Passive estimators: a name from :data:`ESTIMATORS`, or a dict ``{"name": ...,
        **constructor keyword arguments}``, e.g. ``{"name": "pf", "n_particles": 20000}``.
    contacts : list of int
        Contact counts (passive) and touch budgets (active).
    noise : list of float
        Position noise of the simulated contacts (m, standard deviation); the normal
        noise is ``normal_noise`` radians.
    modes : list of {"passive", "active", "identify"}
        "identify": the hidden object is the trial's mesh; :func:`touchloc.belief.identify`
        names one of ``identities`` from the contacts.
    planners : list of str or dict
        Planners of active trials: a name from :data:`PLANNERS`, or a dict ``{"name":
        ..., **constructor keyword arguments}``, e.g. ``{"name": "two-step", "branch":
        3}``. The loop's own filter estimates.
    loop : dict
        Active trials: keyword arguments of
        :func:`~touchloc.planners.loop.active_localization` (:data:`LOOP_OPTIONS`, e.g.
        ``{"n_particles": 3000, "confidence": 0.003}``).
    identities : list of str, optional
        Identification trials: the meshes to choose from (default: ``meshes``).
    seeds : int or list of int
        Trial seeds; an int n means ``range(n)``.
    region : {"full", "planar"}
        Passive and identification trials: a pose uniform in a cube of half-edge
        ``half_extent`` with any rotation, or x, y in a square of half-edge
        ``half_extent`` with any yaw on a table. Active trials use the planners' "6dof"
        and "planar" scenarios.
    half_extent : float, optional
        Metres; default 0.2 ("full", a 400 mm cube) or 0.05 ("planar"). Active trials
        keep their scenario's own region (see ``touchloc.planners.scenarios.SETTINGS``).
    sigma_pos, sigma_nor : float
        The proximity model's noise.
    normal_noise : float
        Simulated normal noise (rad).
    success : float
        A trial succeeds when the ADD-S of the MAP pose is below this (m).
    """

    meshes: list = field(default_factory=lambda: ["can"])
    estimators: list = field(default_factory=lambda: ["ss"])
    contacts: list = field(default_factory=lambda: [30])
    noise: list = field(default_factory=lambda: [0.002])
    modes: list = field(default_factory=lambda: ["passive"])
    planners: list = field(default_factory=lambda: ["one-step"])
    loop: dict = field(default_factory=dict)
    identities: list = None
    seeds: object = 5
    region: str = "full"
    half_extent: float = None
    sigma_pos: float = 0.002
    sigma_nor: float = 0.1
    normal_noise: float = 0.0873
    success: float = 0.005

    def __post_init__(self):
        meshes = _as_list(self.meshes, "meshes")
        for m in meshes:
            if not isinstance(m, (str, os.PathLike)):
                raise ValidationError(f"sweep meshes must be bundled names or paths, got {type(m).__name__} {m!r}"[:160])
        self.meshes = [os.fspath(m) for m in meshes]
        self.estimators = _named_choices(self.estimators, "estimators", "estimator", ESTIMATORS)
        self.contacts = [as_count(k, "sweep contacts", max=10_000, why="contacts or touches per trial")
                         for k in _as_list(self.contacts, "contacts")]
        if any(k < 1 for k in self.contacts):
            raise ValidationError(f"contact counts must be >= 1, got {self.contacts}")
        self.noise = [as_nonnegative_float(s, "sweep noise (m)") for s in _as_list(self.noise, "noise")]
        if any(s < 0 for s in self.noise):
            raise ValidationError(f"noise levels must be >= 0 m, got {self.noise}")
        self.modes = [str(m) for m in _as_list(self.modes, "modes")]
        bad = set(self.modes) - set(MODES)
        if bad:
            raise ValidationError(f"modes must be among {MODES}, got {sorted(bad)}")
        self.planners = _named_choices(self.planners, "planners", "planner", PLANNERS)
        if not isinstance(self.loop, dict):
            raise ValidationError(f"sweep loop must be a dict of active_localization options, got "
                                  f"{type(self.loop).__name__}")
        bad = set(self.loop) - set(LOOP_OPTIONS)
        if bad:
            raise ValidationError(f"unknown loop options {sorted(bad)}; expected some of {LOOP_OPTIONS}")
        self.loop = dict(self.loop)
        if self.identities is None:
            self.identities = list(self.meshes)
        else:
            cands = _as_list(self.identities, "identities")
            if not all(isinstance(c, (str, os.PathLike)) for c in cands):
                raise ValidationError(f"sweep identities must be bundled names or paths, got {cands!r}"[:160])
            self.identities = [os.fspath(c) for c in cands]
        if "identify" in self.modes:
            missing = [m for m in self.meshes if m not in self.identities]
            if missing:
                raise ValidationError(f"identification trials need every mesh among the identities; "
                                      f"{missing} are not in {self.identities}")
        if isinstance(self.seeds, int) and not isinstance(self.seeds, bool):
            self.seeds = list(range(as_count(self.seeds, "sweep seeds", min=0, max=10_000_000)))
        else:
            self.seeds = [as_count(s, "sweep seed", min=0) for s in _as_list(self.seeds, "seeds")]
        if not self.seeds:
            raise ValidationError("sweep seeds must not be empty")
        self.sigma_pos = as_positive_float(self.sigma_pos, "sigma_pos (m)")
        self.sigma_nor = as_positive_float(self.sigma_nor, "sigma_nor")
        self.normal_noise = as_nonnegative_float(self.normal_noise, "normal_noise (rad)")
        self.success = as_positive_float(self.success, "success (m)")
        if not isinstance(self.region, str) or self.region not in REGIONS:
            raise ValidationError(f"region must be one of {REGIONS}, got {self.region!r}")
        self.half_extent = (DEFAULT_HALF_EXTENT[self.region] if self.half_extent is None
                            else as_positive_float(self.half_extent, "half_extent (m)"))

    # -- construction ------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict):
        """A sweep from its keys; ``kind = "dnf"`` makes a :class:`DNFSweep` instead."""
        return _from_dict(d, "dnf" if cls is DNFSweep else "localization")

    @classmethod
    def from_toml(cls, path):
        """Read a sweep from a TOML file (top-level keys are the constructor's arguments;
        ``kind = "dnf"`` makes a :class:`DNFSweep` of the other keys).

        ``path`` may also be the name of a bundled sweep (:func:`bundled_sweeps`), e.g.
        ``"study600"``, when no file of that name exists.
        """
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        if not isinstance(path, (str, os.PathLike)):
            raise ValidationError(f"sweep file must be a path or a bundled sweep name, got {type(path).__name__}")
        p = Path(path)
        if not p.exists() and os.fspath(path) in bundled_sweeps():
            p = bundled_sweeps()[os.fspath(path)]
        if not p.exists():
            raise ValidationError(f"sweep file not found: {p} (bundled sweeps: {', '.join(bundled_sweeps())})")
        try:
            d = tomllib.loads(p.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise ValidationError(f"{p}: not valid TOML: {exc}") from exc
        except UnicodeDecodeError as exc:
            raise ValidationError(f"{p}: not a UTF-8 text file (byte {exc.start}); a sweep is a TOML file") from None
        except OSError as exc:
            raise ValidationError(f"cannot read the sweep file {p}: {exc}") from None
        return cls.from_dict(d)

    # -- the grid ----------------------------------------------------------------------
    def _common(self):
        return {"region": self.region, "half_extent": self.half_extent, "sigma_pos": self.sigma_pos,
                "sigma_nor": self.sigma_nor, "normal_noise": self.normal_noise, "success_threshold": self.success}

    def trials(self) -> list:
        """Every trial's parameters (dicts of plain values), in a fixed order, with ``trial_id``."""
        out = []
        common = self._common()
        for mode in self.modes:
            if mode == "passive":
                grid = itertools.product(self.meshes, self.estimators, self.contacts, self.noise, self.seeds)
                for mesh, est, k, noise, seed in grid:
                    opts = {k2: v for k2, v in est.items() if k2 != "name"}
                    out.append({"mode": mode, "mesh": mesh, "estimator": est["name"], "planner": "",
                                "options": json.dumps(opts, sort_keys=True), "contacts": k,
                                "noise": noise, "seed": seed, **common})
            elif mode == "active":
                grid = itertools.product(self.meshes, self.planners, self.contacts, self.noise, self.seeds)
                for mesh, planner, k, noise, seed in grid:
                    opts = {}
                    kw = {k2: v for k2, v in planner.items() if k2 != "name"}
                    if kw:
                        opts["planner"] = kw
                    if self.loop:
                        opts["loop"] = self.loop
                    out.append({"mode": mode, "mesh": mesh, "estimator": "smc", "planner": planner["name"],
                                "options": json.dumps(opts, sort_keys=True), "contacts": k, "noise": noise,
                                "seed": seed, **common})
            else:
                grid = itertools.product(self.meshes, self.contacts, self.noise, self.seeds)
                opts = json.dumps({"candidates": self.identities}, sort_keys=True)
                for mesh, k, noise, seed in grid:
                    out.append({"mode": mode, "mesh": mesh, "estimator": "identify", "planner": "",
                                "options": opts, "contacts": k, "noise": noise, "seed": seed, **common})
        for p in out:
            p["trial_id"] = trial_id(p)
        return out

    def __len__(self) -> int:
        return len(self.trials())


#: DNF estimators (names of touchloc.dnf.compare.default_estimators)
DNF_ESTIMATORS = ("histogram", "memory, uncorrected", "DNF, corrected", "particle filter")
_DNF_CELL = {"normals_per_contact": 2, "noise_deg": 3.0, "drop": 0.1, "bias": (0.04, 0.08), "slip_deg": 1.5}


@dataclass
class DNFSweep:
    """A grid of orientation-tracking trials (seed 000): cells x objects x data sets x estimators.

    Each cell is one setting of the rotating-object data generator
    (:func:`touchloc.dnf.generate_rotation_dataset`); every estimator runs on the same
    data sets, the data set of (cell, object, set) drawn from ``[seed, cell, object,
    set]``. Run it with :func:`run_sweep` like a :class:`Sweep`; the results file has
    the columns :data:`~touchloc.experiments.trial.DNF_COLUMNS`.

    Parameters
    ----------
    sides : list of int
        Objects: regular n-gon prisms by their number of sides, 0 for a round one.
    cells : list of dict
        Generator settings, each overriding the base cell: ``normals_per_contact`` (2),
        ``noise_deg`` (3), ``drop`` (0.1), ``bias`` ((0.04, 0.08): the odometry's
        under-estimate, a float or a (lo, hi) range), ``slip_deg`` (1.5).
    sets : int
        Data sets per cell and object.
    estimators : list of str
        Names from :data:`DNF_ESTIMATORS`.
    seed : int
    revolutions : float
    normal_source : str
        See :func:`touchloc.dnf.generate_rotation_dataset` ("pad": blob centroids on the
        curved finger pad).
    """

    sides: list = field(default_factory=lambda: [4, 5, 6, 8, 0])
    cells: list = field(default_factory=lambda: [{}])
    sets: int = 1
    estimators: list = field(default_factory=lambda: list(DNF_ESTIMATORS))
    seed: int = 0
    revolutions: float = 4.0
    normal_source: str = "pad"

    def __post_init__(self):
        self.sides = [as_count(n, "sides", min=0, max=360) for n in _as_list(self.sides, "sides")]
        if any(n in (1, 2) for n in self.sides):
            raise ValidationError(f"sides must be 0 (round) or >= 3, got {self.sides}")
        cells = []
        for c in _as_list(self.cells, "cells"):
            if not isinstance(c, dict) or set(c) - set(_DNF_CELL):
                raise ValidationError(f"cells must be dicts with keys among {sorted(_DNF_CELL)}, got {c!r}"[:160])
            c = dict(_DNF_CELL, **c)
            b = c["bias"]
            b = (b, b) if isinstance(b, (int, float)) and not isinstance(b, bool) else tuple(_as_list(b, "cell bias"))
            if len(b) != 2:
                raise ValidationError(f"cell bias must be a float or a (lo, hi) pair, got {c['bias']!r}")
            c["bias"] = tuple(as_nonnegative_float(x, "cell bias") for x in b)
            c["normals_per_contact"] = as_count(c["normals_per_contact"], "normals_per_contact", min=1, max=1000)
            for k in ("noise_deg", "drop", "slip_deg"):
                c[k] = as_nonnegative_float(c[k], f"cell {k}")
            cells.append(c)
        self.cells = cells
        self.sets = as_count(self.sets, "sets", min=1, max=100_000)
        self.estimators = [str(e) for e in _as_list(self.estimators, "estimators")]
        if set(self.estimators) - set(DNF_ESTIMATORS):
            raise ValidationError(f"DNF estimators must be among {DNF_ESTIMATORS}, got {self.estimators}")
        self.seed = as_count(self.seed, "seed", min=0)
        self.revolutions = as_positive_float(self.revolutions, "revolutions")
        if not isinstance(self.normal_source, str):
            raise ValidationError(f"normal_source must be a str (see generate_rotation_dataset), got "
                                  f"{type(self.normal_source).__name__}")

    from_dict = Sweep.__dict__["from_dict"]
    from_toml = Sweep.__dict__["from_toml"]

    def trials(self) -> list:
        """Every trial's parameters (with ``kind = "dnf"`` and ``trial_id``), in a fixed order."""
        out = []
        for ci, c in enumerate(self.cells):
            for oi, n in enumerate(self.sides):
                for i in range(self.sets):
                    for est in self.estimators:
                        p = {"kind": "dnf", "sides": n, "estimator": est,
                             "normals_per_contact": c["normals_per_contact"], "noise_deg": c["noise_deg"],
                             "drop": c["drop"], "bias_lo": c["bias"][0], "bias_hi": c["bias"][1],
                             "slip_deg": c["slip_deg"], "revolutions": self.revolutions,
                             "normal_source": self.normal_source, "seed": self.seed, "cell": ci, "object": oi,
                             "set": i}
                        p["trial_id"] = trial_id(p)
                        out.append(p)
        return out

    def __len__(self) -> int:
        return len(self.trials())
