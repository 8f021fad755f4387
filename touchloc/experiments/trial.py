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

__all__ = ["run_trial", "run_dnf_trial", "warm", "RESULT_COLUMNS", "DNF_COLUMNS", "TIME_COLUMNS", "clear_cache",
           "cache_info"]

#: the measured columns of a result row (besides the trial parameters)
RESULT_COLUMNS = ("success", "add_s", "err_t", "err_r", "time", "plan_time", "touches", "credible_level",
                  "cov50", "cov90", "cov95", "degenerate", "metrics")
#: the columns that are wall times: the only ones that differ between two runs of a trial
TIME_COLUMNS = ("time", "plan_time", "time_per_step")
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

    h = float(p["half_extent"])
    if p["region"] == "planar":
        return PoseRegion.planar((0.0, 0.0), h, z=-float(obj.bounds[0][2])).with_rho(obj.radius)
    return PoseRegion.box((0.0, 0.0, 0.0), h, "full")


def _simulated_contacts(p, obj, region, data_rng):
    """A hidden pose uniform in ``region`` and ``contacts`` noisy surface contacts on it."""
    from ..models import Contacts

    true = region.sample(1, rng=data_rng)[0]
    k = int(p["contacts"])
    pts, nrm, _ = obj.sample_surface(k, rng=data_rng)
    pts = pts + data_rng.normal(scale=float(p["noise"]), size=pts.shape)
    nrm = nrm + data_rng.normal(scale=float(p["normal_noise"]) / np.sqrt(2.0), size=nrm.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return true, Contacts(pts, nrm).transform(true)


def _estimate(p, model, contacts, region, rng):
    from ..belief import (MCMC, AnnealedParticleFilter, HistogramFilter, ManifoldParticleFilter, ParticleFilter,
                          ScalingSeries, SMCFilter)

    opts = json.loads(p["options"]) if p["options"] else {}
    name = p["estimator"]
    if name == "ss":
        return ScalingSeries(model, rng=rng, **{"progress": False, **opts}).localize(contacts, region)
    if name == "ss+mcmc":
        mc = {k[len("mcmc_"):]: v for k, v in opts.items() if k.startswith("mcmc_")}
        ss = {k: v for k, v in opts.items() if not k.startswith("mcmc_")}
        b = ScalingSeries(model, rng=rng, **{"progress": False, **ss}).localize(contacts, region)
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
    region = _region(p, obj)
    true, contacts = _simulated_contacts(p, obj, region, data_rng)
    model = _model(p)
    t0 = time.perf_counter()
    belief = _estimate(p, model, contacts, region, est_rng)
    dt = time.perf_counter() - t0
    # the truth within the belief's resolution of the 90 % set in the plain pose metric
    # (no symmetry: a body of revolution is never covered, any turn about its axis fits)
    res = belief.resolution or 2.0 * float(p["sigma_pos"])
    metrics = {"in90_pose": bool(belief.in_credible_region(true, 0.9, radius=res)[0])}
    return true, belief, belief.map_pose(), dt, 0.0, len(contacts), metrics


def _identify(p, obj, data_rng, est_rng):
    """Which of the candidates was touched: :func:`touchloc.belief.identify` on simulated contacts."""
    from ..belief import identify
    from ..errors import BeliefDegenerateError

    region = _region(p, obj)
    true, contacts = _simulated_contacts(p, obj, region, data_rng)
    opts = json.loads(p["options"])
    cands = list(opts.pop("candidates"))
    models = {c: _model(dict(p, mesh=c)) for c in cands}
    t0 = time.perf_counter()
    try:
        post, beliefs = identify(models, contacts, region, rng=est_rng, return_beliefs=True,
                                 **{"progress": False, **opts})
    except BeliefDegenerateError:
        post, beliefs = None, None
    dt = time.perf_counter() - t0
    if post is None:  # no candidate explains the contacts
        return true, None, None, dt, 0.0, len(contacts), {"best": "", "p_true": 0.0, "p_best": 0.0,
                                                                   "correct": False}
    best = max(post, key=post.get)
    metrics = {"best": best, "p_true": float(post[p["mesh"]]), "p_best": float(post[best]),
               "correct": bool(best == p["mesh"])}
    b = beliefs[p["mesh"]]
    return true, b, b.map_pose(), dt, 0.0, len(contacts), metrics


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
    opts = json.loads(p["options"])
    t0 = time.perf_counter()
    res = active_localization(world, sc.model, sc.region, planner(sc.model, **opts.get("planner", {})),
                              sc.candidates, max_touches=int(p["contacts"]), rng=est_rng, progress=False,
                              **opts.get("loop", {}))
    dt = time.perf_counter() - t0
    T = res.steps[-1].map_pose
    # ADD: the plain mean point distance (counts symmetric poses as errors)
    pts = _cached(("points", p["mesh"]), lambda: obj.sample_surface(500, rng=0)[0])
    add = float(np.linalg.norm((pts @ T[:3, :3].T + T[:3, 3]) - (pts @ true[:3, :3].T + true[:3, 3]), axis=1).mean())
    plan_time = float(np.mean([s.plan_time for s in res.steps[1:]])) if res.touches else 0.0
    metrics = {"confident": bool(res.confident), "add": add}
    return true, res.belief, T, dt, plan_time, res.touches, metrics


_TRIAL_KEYS = ("mode", "mesh", "estimator", "planner", "options", "contacts", "noise", "seed", "region",
               "half_extent", "sigma_pos", "sigma_nor", "normal_noise", "success_threshold")
_RUNS = {"passive": _passive, "active": _active, "identify": _identify}


def _check_params(params) -> dict:
    """A trial's parameters as :meth:`Sweep.trials` makes them, checked."""
    p = as_mapping(params, "params", expected="a dict of trial parameters (an element of Sweep.trials())")
    missing = [k for k in _TRIAL_KEYS if k not in p]
    if missing:
        raise ValidationError(f"trial params lack {missing}; pass an element of Sweep.trials()")
    for k in ("mode", "mesh", "estimator", "planner", "options", "region"):
        if not isinstance(p[k], str):
            raise ValidationError(f"trial params[{k!r}] must be a str, got {type(p[k]).__name__}")
    if p["mode"] not in _RUNS:
        raise ValidationError(f"trial mode must be one of {tuple(_RUNS)}, got {p['mode']!r}")
    p["contacts"] = as_count(p["contacts"], "trial contacts", max=10_000)
    p["seed"] = as_count(p["seed"], "trial seed", min=0)
    p["noise"] = as_nonnegative_float(p["noise"], "trial noise (m)")
    p["normal_noise"] = as_nonnegative_float(p["normal_noise"], "trial normal_noise (rad)")
    for k in ("half_extent", "sigma_pos", "sigma_nor", "success_threshold"):
        p[k] = as_positive_float(p[k], f"trial {k}")
    try:
        opts = json.loads(p["options"])
    except ValueError as exc:
        raise ValidationError(f"trial options must be a JSON object: {exc}") from None
    if not isinstance(opts, dict):
        raise ValidationError(f"trial options must be a JSON object, got {p['options']!r}")
    if p["mode"] == "identify" and not (isinstance(opts.get("candidates"), list) and p["mesh"] in opts["candidates"]):
        raise ValidationError(f"identification trial options must list the candidates, the trial's mesh "
                              f"{p['mesh']!r} among them, got {p['options']!r}"[:200])
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
        ``params`` plus ``success``, ``add_s`` (m), ``err_t`` (m) and ``err_r`` (rad)
        modulo the object's symmetry, ``time`` (s, the estimator, loop or
        identification alone), ``plan_time`` (active: mean planning time per touch, s;
        else 0), ``touches``, ``credible_level`` (the smallest level whose
        symmetry-aware credible region holds the truth; ``inf`` if none),
        ``cov50/cov90/cov95``, ``degenerate`` and ``metrics`` (a JSON object of what
        only this kind of trial measures, see below). Everything but the
        :data:`TIME_COLUMNS` is a function of ``params`` alone.

        ``success`` is: ADD-S of the MAP pose below ``success_threshold`` (passive,
        active), or the most probable candidate is the true mesh (identify; its pose
        columns are those of the true mesh's belief). ``metrics``: passive
        ``in90_pose`` (the truth in the 90 % region in the plain pose metric, no
        symmetry); active ``confident`` (the loop's stopping rule was met) and ``add``
        (plain ADD of the MAP pose, m); identify ``best``, ``p_best``, ``p_true``,
        ``correct``.
    """
    from ..belief import add_s, credible_level, symmetric_pose_error

    p = _check_params(params)
    obj = _object(p["mesh"])
    data_rng, est_rng = _streams(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        true, belief, T, dt, plan_time, touches, metrics = _RUNS[p["mode"]](p, obj, data_rng, est_rng)
    row = dict(p)
    if belief is None:  # identification: no candidate explained the contacts
        row.update(success=False, add_s=float("inf"), err_t=float("inf"), err_r=float("inf"), time=float(dt),
                   plan_time=0.0, touches=int(touches), credible_level=float("inf"), degenerate=True,
                   metrics=json.dumps(metrics, sort_keys=True))
        for a in LEVELS:
            row[f"cov{int(round(100 * a))}"] = False
        return row
    err = add_s(obj, T, true)
    et, er = symmetric_pose_error(obj, T, true)
    radius = belief.resolution or 2.0 * float(p["sigma_pos"])
    rho = belief.rho if belief.rho is not None else obj.radius
    q = credible_level(belief, true, obj, radius=radius, rho=rho)
    success = metrics["correct"] if p["mode"] == "identify" else bool(err < float(p["success_threshold"]))
    row.update(success=bool(success), add_s=float(err), err_t=float(et), err_r=float(er), time=float(dt),
               plan_time=float(plan_time), touches=int(touches), credible_level=float(q),
               degenerate=bool(getattr(belief, "degenerate", False)), metrics=json.dumps(metrics, sort_keys=True))
    for a in LEVELS:
        row[f"cov{int(round(100 * a))}"] = bool(q < a)
    return row


def warm(keys) -> dict:
    """Build this process's meshes, models and their structures before any trial is timed.

    Parameters
    ----------
    keys : iterable of (mesh, sigma_pos, sigma_nor)

    Returns
    -------
    dict
        :func:`cache_info` afterwards.
    """
    from .._warmup import prepare_models

    for mesh, sp, sn in keys:
        model = _model({"mesh": mesh, "sigma_pos": float(sp), "sigma_nor": float(sn)})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the compiled kernels, the exact tree, the fast grid and Scaling Series' bound
            # table: everything a trial's first likelihood call would otherwise build
            prepare_models(model, build=True)
    return cache_info()


# -- DNF orientation trials (seed 000) ----------------------------------------------------
#: columns of a DNF results file: parameters, then measurements
DNF_COLUMNS = ("trial_id", "kind", "sides", "estimator", "normals_per_contact", "noise_deg", "drop", "bias_lo",
               "bias_hi", "slip_deg", "revolutions", "normal_source", "seed", "cell", "object", "set",
               "accuracy", "count_mean", "err_rms_deg", "samples", "time", "time_per_step")
_DNF_KEYS = DNF_COLUMNS[1:DNF_COLUMNS.index("accuracy")]


def _rotation_dataset(p):
    from ..dnf import generate_rotation_dataset

    def build():
        rng = np.random.default_rng([p["seed"], p["cell"], p["object"], p["set"]])
        return generate_rotation_dataset(
            p["sides"], revolutions=p["revolutions"], rng=rng, normals_per_contact=p["normals_per_contact"],
            noise=np.radians(p["noise_deg"]), drop=p["drop"], normal_source=p["normal_source"],
            slip_std=np.radians(p["slip_deg"]), under_estimate=(p["bias_lo"], p["bias_hi"]))

    key = ("dataset",) + tuple(p[k] for k in _DNF_KEYS if k != "estimator")
    return _cached(key, build)


def run_dnf_trial(params: dict) -> dict:
    """One orientation estimator on one simulated rotating n-gon: a pure function of ``params``.

    Parameters
    ----------
    params : dict
        One element of :meth:`DNFSweep.trials`: the object (``sides``, 0 for round),
        the estimator (a name of :func:`touchloc.dnf.compare.default_estimators`, made
        with ``rng=0``), the data set's generator settings (``normals_per_contact``,
        ``noise_deg``, ``drop``, odometry under-estimate ``bias_lo..bias_hi``,
        ``slip_deg``, ``revolutions``, ``normal_source``) and its seed
        ``[seed, cell, object, set]``.

    Returns
    -------
    dict
        ``params`` plus ``accuracy`` (fraction of second-half samples with the right
        side count), ``count_mean`` (mean second-half count), ``err_rms_deg``
        (second-half orientation error, wrapped to the symmetry, RMS), ``samples``,
        ``time`` (s, the whole run) and ``time_per_step`` (s). All but the two times are
        a function of ``params`` alone. Data sets are cached per process, so the
        estimators of one data set that meet in a worker share it.
    """
    from ..dnf.compare import default_estimators, run_estimator

    p = as_mapping(params, "params", expected="a dict of DNF trial parameters (an element of DNFSweep.trials())")
    missing = [k for k in _DNF_KEYS if k not in p]
    if missing:
        raise ValidationError(f"DNF trial params lack {missing}; pass an element of DNFSweep.trials()")
    makers = default_estimators(rng=0)
    if p["estimator"] not in makers:
        raise ValidationError(f"DNF trial estimator must be one of {sorted(makers)}, got {p['estimator']!r}")
    p["sides"] = as_count(p["sides"], "sides", min=0, max=360)
    for k in ("normals_per_contact", "seed", "cell", "object", "set"):
        p[k] = as_count(p[k], f"DNF trial {k}", min=0 if k != "normals_per_contact" else 1)
    for k in ("noise_deg", "drop", "bias_lo", "bias_hi", "slip_deg"):
        p[k] = as_nonnegative_float(p[k], f"DNF trial {k}")
    p["revolutions"] = as_positive_float(p["revolutions"], "DNF trial revolutions")
    ds = _rotation_dataset(p)
    t0 = time.perf_counter()
    res = run_estimator(p["estimator"], makers[p["estimator"]], ds)
    dt = time.perf_counter() - t0
    half = len(res.counts) // 2
    err = res.error[half:] if res.error is not None else np.array([np.nan])
    row = dict(p)
    row.update(accuracy=float(res.accuracy), count_mean=float(np.mean(res.second_half)),
               err_rms_deg=float(np.degrees(np.sqrt(np.mean(np.square(err))))), samples=int(len(res.counts)),
               time=float(dt), time_per_step=float(res.seconds_per_step))
    return row
