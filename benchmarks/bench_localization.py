"""Localisation accuracy, time and calibration of every estimator on the bundled meshes.

The trials are one sweep (``touchloc.experiments``): each is a pure function of its
parameters and seed, run on the process pool; the tables are drawn from the tidy rows.
"""

from __future__ import annotations

import json

import numpy as np

from _common import run_trials, table
from touchloc.experiments import Sweep

TITLE = "Localisation: accuracy, time, calibration"

MESHES = ["bread", "can", "cereal", "lemon", "milk", "mug"]
#: the simulated sensor and the model: 2 mm / 5 deg noise, ProximityModel(2 mm, 0.1)
SETTING = dict(noise=[0.002], normal_noise=float(np.radians(5.0)), sigma_pos=0.002, sigma_nor=0.1, success=0.005)

#: 6-DOF alternatives and variants: (label, estimator entry of the sweep)
VARIANTS = [
    ("Scaling Series (defaults)", {"name": "ss"}),
    ("Scaling Series, prune by resampling", {"name": "ss", "prune": "resample"}),
    ("Scaling Series M=12", {"name": "ss", "m_per_delta": 12}),
    ("Scaling Series, Alg. 1's schedule (anneal='alg1')", {"name": "ss", "anneal": "alg1"}),
    ("Scaling Series + MCMC", {"name": "ss+mcmc", "mcmc_n_walkers": 24, "mcmc_n_steps": 100, "mcmc_burn": 100}),
    ("particle filter (IS), 50k", {"name": "pf", "n_particles": 50000}),
    ("annealed PF, 3k", {"name": "apf", "n_particles": 3000}),
    ("manifold PF, 20k", {"name": "mpf", "n_particles": 20000}),
]
#: planar 3-DOF estimators
PLANAR = [
    ("histogram 2 mm / 1.5 deg", {"name": "hf", "resolution": 0.002, "angular_resolution": float(np.radians(1.5))}),
    ("particle filter 50k", {"name": "pf", "n_particles": 50000}),
    ("Scaling Series", {"name": "ss"}),
]


def trial(obj, region, k, seed, noise=(0.002, 5.0)):
    """A hidden pose uniform in the region and k noisy contacts (``noise``: m, deg; 2 mm,
    5 deg by default), from ``seed``.

    Kept for bench_speed and the studies, which time estimators on these contacts; this
    benchmark's own trials draw the same kind of data inside ``touchloc.experiments.run_trial``.
    """
    from touchloc.models import Contacts

    rng = np.random.default_rng(seed)
    true = region.sample(1, rng=rng)[0]
    p, n, _ = obj.sample_surface(k, rng=rng)
    p = p + rng.normal(scale=noise[0], size=p.shape)
    n = n + rng.normal(scale=np.radians(noise[1]) / np.sqrt(2), size=n.shape)
    return true, Contacts(p, n).transform(true)


def _key(est: dict):
    return est["name"], json.dumps({k: v for k, v in est.items() if k != "name"}, sort_keys=True)


def sweeps(quick: bool) -> dict:
    """The benchmark's trials: {table: list of (Sweep, {estimator key: label})}."""
    n_main = 5 if quick else 20
    n_side = 3 if quick else 8
    meshes = MESHES[:2] if quick else MESHES
    ss = {_key({"name": "ss"}): "Scaling Series"}
    main = [(Sweep(meshes=meshes, estimators=["ss"], contacts=[30], seeds=list(range(1000, 1000 + n_main)),
                   **SETTING), ss),
            (Sweep(meshes=meshes, estimators=["ss"], contacts=[10, 5], seeds=list(range(1000, 1000 + n_side)),
                   **SETTING), ss)]
    side = [(Sweep(meshes=["can"] if quick else ["mug", "milk"], estimators=[e for _, e in VARIANTS], contacts=[30],
                   seeds=list(range(2000, 2000 + n_side)), **SETTING), {_key(e): lab for lab, e in VARIANTS})]
    planar = [(Sweep(meshes=["cereal"] if quick else ["cereal", "mug", "milk"], estimators=[e for _, e in PLANAR],
                     contacts=[10, 5], region="planar", seeds=list(range(3000, 3000 + n_side)), **SETTING),
               {_key(e): lab for lab, e in PLANAR})]
    return {"main": main, "side": side, "planar": planar}


HEAD = ("mesh", "estimator / contacts", "trials", "ADD-S < 5 mm", "median ADD-S mm", "p90 mm", "median s",
        "p95 s / median", "truth in 90 % region (pose)", "(modulo symmetry)")


def summary(rows, spec) -> list:
    """One table row per (mesh, estimator, contacts) of ``spec``, in the sweep's order."""
    out = []
    for sweep, labels in spec:
        ids = {t["trial_id"] for t in sweep.trials()}
        mine = [r for r in rows if r["trial_id"] in ids]
        groups: dict = {}
        for t in sweep.trials():  # the sweep's own order: mesh, estimator, contacts
            groups.setdefault((t["mesh"], t["estimator"], t["options"], t["contacts"]), [])
        for r in mine:
            groups[(r["mesh"], r["estimator"], r["options"], r["contacts"])].append(r)
        for (mesh, name, opts, k), g in groups.items():
            if not g:
                continue
            e = np.array([r["add_s"] for r in g])
            out.append((mesh, f"{labels[(name, opts)]}, {k}", len(g), f"{100 * np.mean(e < g[0]['success_threshold']):.0f} %",
                        f"{1e3 * np.median(e):.2f}", f"{1e3 * np.percentile(e, 90):.2f}",
                        f"{np.median([r['time'] for r in g]):.2f}",
                        f"{np.percentile([r['time'] for r in g], 95) / np.median([r['time'] for r in g]):.1f}",
                        f"{100 * np.mean([json.loads(r['metrics'])['in90_pose'] for r in g]):.0f} %",
                        f"{100 * np.mean([r['cov90'] for r in g]):.0f} %"))
    return out


def run(quick: bool = False) -> str:
    spec = sweeps(quick)
    trials = [t for part in spec.values() for sweep, _ in part for t in sweep.trials()]
    rows, how = run_trials("localization", trials, quick)
    main, side, planar = (summary(rows, spec[k]) for k in ("main", "side", "planar"))
    # per mesh: 30, 10, 5 contacts
    main.sort(key=lambda r: (MESHES.index(r[0]), -int(r[1].rsplit(", ", 1)[1])))
    quick_note = ("**Quick run** (`--quick`: fewer meshes and seeds; a smoke test of the benchmark, not its "
                  "result). " if quick else "")
    return "\n\n".join([
        quick_note + "Hidden pose uniform in a 400 mm cube with uniform rotation; k contacts sampled uniformly "
        "over the surface with 2 mm position and 5 deg normal noise; ProximityModel(sigma_pos=2 mm, "
        "sigma_nor=0.1). ADD-S of the MAP pose. 'truth in 90 % region': the true pose lies within "
        "the belief's resolution (Scaling Series: its final delta) of the particles holding 90 % of "
        "the weight, in the plain pose metric ('pose'; a rotationally symmetric object such as the can "
        "is never covered, since any turn about its axis is equally right) or in the pose metric modulo "
        "the object's symmetry group ('modulo symmetry', the `cov90` column of the results). Scaling Series "
        "defaults: M = 6, delta* = 2 sigma_pos, prune by threshold (weights >= 1e-3 of the best), "
        "tau = g (delta/delta*)^2 with g = max(1, k / 15) for k contacts (`anneal='auto'`; at 30 contacts "
        "g = 2, which the 'anneal gain 2' rows of earlier runs measured). Times are per trial, on one core (each pool worker runs the compiled "
        "kernels on one thread, all workers at once); 'p95 s / median' is the 95th percentile of a row's "
        "times over their median.",
        how,
        table(HEAD, main),
        "6-DOF alternatives, 30 contacts (same setting):",
        table(HEAD, side),
        "Planar 3-DOF (x, y in a 100 mm square, any yaw, standing on the table):",
        table(HEAD, planar),
    ])
