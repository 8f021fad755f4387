"""Calibration with the sensor's own density: proximity against integrated proximity model.

The calibration benchmark draws each contact as the simulated sensor makes it (a surface
point uniform by area, plus Gaussian noise on the point and the normal), so the exact
likelihood of a contact is the integrated proximity model, and a posterior computed
with it is calibrated by construction. The proximity model keeps only the best surface
point. This study runs the calibration benchmark's trials (planar region, truth drawn
from the uniform prior, ``bench_calibration.trial``) with each estimator twice, once per
model, and reports how often the truth lies in the 50 / 90 / 95 % highest-density
regions (``touchloc.belief.hpd_level``, modulo the mesh's symmetries).

    cd benchmarks
    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 8 --offset 100
    # held-out sensor statistics: 1 mm / 0.05, and 3 mm / 0.15
    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 4 --offset 200 \
        --sigma 0.001 0.05 --contacts 10 30

``--twin`` runs each estimator a second time on the same contacts with another seed and
ranks three of the twin's particles in the first run's belief, as the truth is ranked. A
sampler whose runs draw from one distribution puts a twin's particle in its level-a region
a of the time, whatever that distribution; where the truth falls short of that and the
twin does not, the posterior itself misses the truth (docs/localization.md, "Beliefs you
can check: calibration").

    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 8 --offset 50 \
        --models proximity --twin

Seed offsets: the calibration benchmark's tables use offsets 50-52 and the estimators'
settings were chosen on 0-49; the integrated model's quadrature was checked on offsets
0-11 (SMC only). Report other offsets.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

ESTIMATORS = ("SMCFilter", "Scaling Series")
MODELS = ("proximity", "integrated")
_cache: dict = {}


def _models(mesh, sigma_pos, sigma_nor):
    from bench_calibration import quiet_load
    from touchloc.models import IntegratedProximityModel, ProximityModel

    key = (mesh, sigma_pos, sigma_nor)
    if key not in _cache:
        obj = quiet_load(mesh)
        obj.symmetries()
        _cache[key] = (obj, ProximityModel(obj, sigma_pos, sigma_nor),
                       IntegratedProximityModel(obj, sigma_pos, sigma_nor))
    return _cache[key]


def _one(job):
    mesh, k, t, offset, sigma_pos, sigma_nor, estimators, smc_kw, models, twin = job
    warnings.simplefilter("ignore")
    import bench_calibration as B
    from touchloc.belief import ScalingSeries, SMCFilter, hpd_level

    B.SIGMA_POS, B.SIGMA_NOR = sigma_pos, sigma_nor   # the generator's noise
    obj, prox, integ = _models(mesh, sigma_pos, sigma_nor)
    region = B.planar_region(obj)
    seed = 10_000 * k + 100 * (B.MESHES + B.HELD_OUT_MESHES).index(mesh) + offset + t
    true, c = B.trial(obj, region, k, seed)
    out = []
    for est in estimators:
        for name, model in (("proximity", prox), ("integrated", integ)):
            if name not in models:
                continue
            def run(s):
                if est.startswith("SMC"):
                    return SMCFilter(model, rng=s, **smc_kw).localize(c, region)
                # the search on the proximity model; the posterior stage on the model named
                return ScalingSeries(prox, posterior_model=model, rng=s).localize(c, region)

            t0 = time.process_time()
            b = run(seed)
            dt = time.process_time() - t0
            row = dict(estimator=est, model=name, mesh=mesh, k=k, t=t,
                       level=float(hpd_level(b, true, obj, rng=seed)), cpu=dt)
            if twin:
                other = run(seed + 7777)
                pick = np.random.default_rng(seed).choice(len(other), 3, replace=False)
                row["twin"] = [float(hpd_level(b, other.poses[i], obj, rng=seed + int(i))) for i in pick]
            out.append(row)
    return out


def _init(ss_ess=None):
    os.environ["NUMBA_NUM_THREADS"] = "1"
    if ss_ess is not None:
        # Scaling Series' posterior stage tempers through smc.temper, which it looks up
        # when the stage runs: give every call this worker makes the study's ess_fraction
        import functools

        import touchloc.belief.smc as smc

        smc.temper = functools.partial(smc.temper, ess_fraction=ss_ess)


def _table(rows, levels=(0.5, 0.9, 0.95)):
    from _common import table

    meshes = list(dict.fromkeys(r["mesh"] for r in rows))
    twins = all("twin" in r for r in rows)
    ks = sorted({r["k"] for r in rows})
    out = []
    ests = [e for e in ESTIMATORS if any(r["estimator"] == e for r in rows)]
    models = [m for m in MODELS if any(r["model"] == m for r in rows)]
    for est in ests:
        for name in models:
            sel = [r for r in rows if r["estimator"] == est and r["model"] == name]
            for k in ks + ["all"]:
                rr = [r for r in sel if k == "all" or r["k"] == k]
                q = np.array([r["level"] for r in rr])
                twin = [f"{100 * np.mean(qt < a):.0f} %" for qt in [np.array([x for r in rr for x in r["twin"]])]
                        for a in levels] if twins else []
                out.append((est, name, k, len(q), *(f"{100 * np.mean(q < a):.0f} %" for a in levels), *twin,
                            f"{np.median([r['cpu'] for r in rr]):.2f}"))
    per_mesh = []
    for est in ests:
        for name in models:
            row = [est, name]
            for m in meshes:
                q = np.array([r["level"] for r in rows if r["estimator"] == est and r["model"] == name
                              and r["mesh"] == m])
                row.append(f"{100 * np.mean(q < 0.9):.0f} %")
            per_mesh.append(row)
    twin_head = ["a twin run's particle in 50 %", "in 90 %", "in 95 %"] if twins else []
    return (table(["estimator", "likelihood", "contacts", "trials", "truth in 50 % region", "in 90 %", "in 95 %",
                   *twin_head, "median CPU s"], out)
            + "\n\nTruth in the 90 % region, per mesh (all contact counts):\n\n"
            + table(["estimator", "likelihood"] + meshes, per_mesh))


def main(argv=None) -> int:
    import bench_calibration as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=B.MESHES + B.HELD_OUT_MESHES)
    ap.add_argument("--contacts", nargs="+", type=int, default=list(B.CONTACTS))
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--offset", type=int, default=100)
    ap.add_argument("--sigma", nargs=2, type=float, default=[B.SIGMA_POS, B.SIGMA_NOR],
                    metavar=("POS", "NOR"), help="the sensor's noise, which both models are given")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--estimators", nargs="+", choices=["smc", "ss"], default=["smc", "ss"])
    ap.add_argument("--particles", type=int, default=2000, help="SMCFilter's particles")
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--ess", type=float, default=None,
                    help="SMCFilter's ess_fraction: the share of the effective sample size kept per tempering step")
    ap.add_argument("--jumps", type=float, default=None,
                    help="SMCFilter's accepted moves per particle and tempering step (default: its own)")
    ap.add_argument("--ss-ess", type=float, default=None,
                    help="the ess_fraction of Scaling Series' posterior stage (default: temper's, 0.5); "
                         "use with --estimators ss")
    ap.add_argument("--twin", action="store_true",
                    help="also rank three particles of a second run (another seed) in each belief")
    ap.add_argument("--jsonl", help="also write every trial here")
    a = ap.parse_args(argv)
    bad = [m for m in a.meshes if m not in B.MESHES + B.HELD_OUT_MESHES]
    if bad:
        ap.error(f"meshes must be among {B.MESHES + B.HELD_OUT_MESHES}, got {bad}")
    ests = [e for e in ESTIMATORS if ("smc" if e.startswith("SMC") else "ss") in a.estimators]
    smc_kw = {"n_particles": a.particles}
    if a.jumps is not None:
        smc_kw["jumps"] = a.jumps
    if a.ess is not None:
        smc_kw["ess_fraction"] = a.ess
    jobs = [(m, k, t, a.offset, a.sigma[0], a.sigma[1], ests, smc_kw, a.models, a.twin) for t in range(a.trials)
            for k in a.contacts for m in a.meshes]
    rows = []
    w0 = time.time()
    sink = open(a.jsonl, "w") if a.jsonl else None
    if a.ss_ess is not None and "smc" in a.estimators:
        ap.error("--ss-ess changes every tempering in the workers, the SMC filter's too: use --estimators ss")
    with ProcessPoolExecutor(a.workers, initializer=_init, initargs=(a.ss_ess,)) as ex:
        for i, res in enumerate(ex.map(_one, jobs), 1):
            rows.extend(res)
            if sink:
                for r in res:
                    sink.write(json.dumps(r) + "\n")
                sink.flush()
            print(f"\r{i}/{len(jobs)} trials", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    load = os.getloadavg()[0]
    stage = f"Scaling Series' posterior stage ess_fraction {a.ss_ess}; " if a.ss_ess is not None else ""
    print(f"{len(jobs)} trials in {time.time() - w0:.0f} s wall; sensor {a.sigma[0] * 1e3:g} mm / {a.sigma[1]:g}; "
          f"seed offsets {a.offset}-{a.offset + a.trials - 1}; SMCFilter settings {smc_kw}; {stage}"
          f"load average {load:.1f}\n")
    print(_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
