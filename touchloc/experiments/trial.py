"""One trial: a pure function of its parameters, run in whichever process holds the task.

Meshes, measurement models and scenarios are kept in a per-process cache, so a worker
loads a mesh and builds its BVH, grids and symmetry group once, on its first trial of
that mesh; tasks carry only the mesh's name, never the object.
"""

from __future__ import annotations

import json
import time
import warnings
import zlib

import numpy as np

from .._validate import as_count, as_mapping, as_nonnegative_float, as_positive_float
from ..errors import ValidationError

__all__ = ["run_trial", "RESULT_COLUMNS", "clear_cache", "cache_info"]

#: the measured columns of a result row (besides the trial parameters)
RESULT_COLUMNS = ("success", "add_s", "err_t", "err_r", "time", "touches", "credible_level",
                  "cov50", "cov90", "cov95", "degenerate")
LEVELS = (0.5, 0.9, 0.95)

_CACHE: dict = {}


def clear_cache() -> None:
    """Forget this process's meshes, models and scenarios."""
    _CACHE.clear()


def cache_info() -> dict:
    """{kind: number of cached entries} for this process (meshes, models, scenarios)."""
    out: dict = {}
    for key in _CACHE:
        out[key[0]] = out.get(key[0], 0) + 1
    return out


def _cached(key, build):
    v = _CACHE.get(key)
    if v is None:
        v = _CACHE[key] = build()
    return v


def _object(spec: str):
    def build():
        from pathlib import Path

        from ..data import MESHES, load_object
        from ..models import MeshObject

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if spec in MESHES and not Path(spec).exists():
                obj = load_object(spec)
            else:
                obj = MeshObject.from_file(spec)
        obj.symmetries()  # built once per worker, with the mesh
        return obj

    return _cached(("mesh", spec), build)


def _model(p):
    from ..models import ProximityModel

    return _cached(("model", p["mesh"], p["sigma_pos"], p["sigma_nor"]),
                   lambda: ProximityModel(_object(p["mesh"]), p["sigma_pos"], p["sigma_nor"]))


def _streams(p):
    """Independent generators for the simulated data and for the estimator.

    The data stream depends on mesh, contact count, noise and seed only, so every
    estimator of a sweep sees the same hidden pose and contacts.
    """
    key = [int(p["seed"]), zlib.crc32(p["mesh"].encode()), int(p["contacts"]),
           int(round(float(p["noise"]) * 1e9)), zlib.crc32(p["mode"].encode())]
    data, est = np.random.SeedSequence(key).spawn(2)
    return np.random.default_rng(data), np.random.default_rng(est)


def _region(p, obj):
    from ..belief import PoseRegion

    if p["region"] == "planar":
        return PoseRegion.planar((0.0, 0.0), 0.05, z=-float(obj.bounds[0][2])).with_rho(obj.radius)
    return PoseRegion.box((0.0, 0.0, 0.0), 0.2, "full")


def _estimate(p, model, contacts, region, rng):
    from ..belief import (MCMC, AnnealedParticleFilter, HistogramFilter, ManifoldParticleFilter, ParticleFilter,
                          ScalingSeries, SMCFilter)

    opts = json.loads(p["options"]) if p["options"] else {}
    name = p["estimator"]
    if name == "ss":
        return ScalingSeries(model, rng=rng, **opts).localize(contacts, region)
    if name == "ss+mcmc":
        mc = {k[len("mcmc_"):]: v for k, v in opts.items() if k.startswith("mcmc_")}
        ss = {k: v for k, v in opts.items() if not k.startswith("mcmc_")}
        b = ScalingSeries(model, rng=rng, **ss).localize(contacts, region)
        return MCMC(model, rng=rng, **mc).refine(contacts, b)
    if name == "pf":
        return ParticleFilter(model, rng=rng, **opts).localize(contacts, region)
    if name == "hf":
        return HistogramFilter(model, **opts).localize(contacts, region)
    if name == "apf":
        return AnnealedParticleFilter(model, rng=rng, **opts).localize(contacts, region)
    if name == "smc":
        return SMCFilter(model, rng=rng, **opts).localize(contacts, region)
    if name == "mpf":
        return ManifoldParticleFilter(model, rng=rng, **opts).localize(contacts, region)
    raise ValidationError(f"unknown estimator {name!r}")


def _passive(p, obj, data_rng, est_rng):
    from ..models import Contacts

    region = _region(p, obj)
    true = region.sample(1, rng=data_rng)[0]
    k = int(p["contacts"])
    pts, nrm, _ = obj.sample_surface(k, rng=data_rng)
    pts = pts + data_rng.normal(scale=float(p["noise"]), size=pts.shape)
    nrm = nrm + data_rng.normal(scale=float(p["normal_noise"]) / np.sqrt(2.0), size=nrm.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    contacts = Contacts(pts, nrm).transform(true)
    model = _model(p)
    t0 = time.perf_counter()
    belief = _estimate(p, model, contacts, region, est_rng)
    dt = time.perf_counter() - t0
    return true, belief, belief.map_pose(), dt, k


def _active(p, obj, data_rng, est_rng):
    from ..planners import OneStepPlanner, RandomPlanner, TwoStepPlanner
    from ..planners.loop import SimulatedWorld, active_localization
    from ..planners.scenarios import make_scenario

    setting = "6dof" if p["region"] == "full" else "planar"
    sc = _cached(("scenario", p["mesh"], setting, p["sigma_pos"], p["sigma_nor"]),
                 lambda: make_scenario(_object(p["mesh"]), setting, sigma_pos=p["sigma_pos"],
                                       sigma_nor=p["sigma_nor"], seed=0))
    true = sc.hidden_pose(rng=data_rng)
    world = SimulatedWorld(obj, true, noise_pos=float(p["noise"]), noise_nor=float(p["normal_noise"]),
                           rng=data_rng)
    planner = {"one-step": OneStepPlanner, "two-step": TwoStepPlanner, "random": RandomPlanner}[p["planner"]]
    t0 = time.perf_counter()
    res = active_localization(world, sc.model, sc.region, planner(sc.model), sc.candidates,
                              max_touches=int(p["contacts"]), rng=est_rng, progress_bar=False)
    dt = time.perf_counter() - t0
    return true, res.belief, res.steps[-1].map_pose, dt, res.touches


_TRIAL_KEYS = ("mode", "mesh", "estimator", "planner", "options", "contacts", "noise", "seed", "region",
               "sigma_pos", "sigma_nor", "normal_noise", "success_threshold")


def _check_params(params) -> dict:
    """A trial's parameters as :meth:`Sweep.trials` makes them, checked."""
    p = as_mapping(params, "params", expected="a dict of trial parameters (an element of Sweep.trials())")
    missing = [k for k in _TRIAL_KEYS if k not in p]
    if missing:
        raise ValidationError(f"trial params lack {missing}; pass an element of Sweep.trials()")
    for k in ("mode", "mesh", "estimator", "planner", "options", "region"):
        if not isinstance(p[k], str):
            raise ValidationError(f"trial params[{k!r}] must be a str, got {type(p[k]).__name__}")
    if p["mode"] not in ("passive", "active"):
        raise ValidationError(f"trial mode must be 'passive' or 'active', got {p['mode']!r}")
    p["contacts"] = as_count(p["contacts"], "trial contacts", max=10_000)
    p["seed"] = as_count(p["seed"], "trial seed", min=0)
    p["noise"] = as_nonnegative_float(p["noise"], "trial noise (m)")
    p["normal_noise"] = as_nonnegative_float(p["normal_noise"], "trial normal_noise (rad)")
    for k in ("sigma_pos", "sigma_nor", "success_threshold"):
        p[k] = as_positive_float(p[k], f"trial {k}")
    try:
        opts = json.loads(p["options"])
    except ValueError as exc:
        raise ValidationError(f"trial options must be a JSON object: {exc}") from None
    if not isinstance(opts, dict):
        raise ValidationError(f"trial options must be a JSON object, got {p['options']!r}")
    return p


def run_trial(params: dict) -> dict:
    """Run one trial and return its row: the parameters and the measured columns.

    Parameters
    ----------
    params : dict
        One element of :meth:`Sweep.trials`.

    Returns
    -------
    dict
        ``params`` plus ``success`` (ADD-S below the threshold), ``add_s`` (m),
        ``err_t`` (m) and ``err_r`` (rad) modulo the object's symmetry, ``time`` (s, the
        estimator or loop alone), ``touches``, ``credible_level`` (the smallest level
        whose symmetry-aware credible region holds the truth; ``inf`` if none),
        ``cov50/cov90/cov95`` and ``degenerate``. Everything but ``time`` is a function
        of ``params`` alone.
    """
    from ..belief import add_s, credible_level, symmetric_pose_error

    p = _check_params(params)
    obj = _object(p["mesh"])
    data_rng, est_rng = _streams(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = _passive if p["mode"] == "passive" else _active
        true, belief, T, dt, touches = run(p, obj, data_rng, est_rng)
    err = add_s(obj, T, true)
    et, er = symmetric_pose_error(obj, T, true)
    radius = belief.resolution or 2.0 * float(p["sigma_pos"])
    rho = belief.rho if belief.rho is not None else obj.radius
    q = credible_level(belief, true, obj, radius=radius, rho=rho)
    row = dict(p)
    row.update(success=bool(err < float(p["success_threshold"])), add_s=float(err), err_t=float(et),
               err_r=float(er), time=float(dt), touches=int(touches), credible_level=float(q),
               degenerate=bool(getattr(belief, "degenerate", False)))
    for a in LEVELS:
        row[f"cov{int(round(100 * a))}"] = bool(q < a)
    return row
