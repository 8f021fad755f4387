"""Scaling Series' temperature schedule with many contacts: does the search keep the true mode?

Alg. 1 anneals with tau = (delta / delta*)^2 whatever the number of contacts K, so the
annealed posterior narrows as 1 / sqrt(K) while the cover keeps m particles per delta-ball.
This study runs the calibration benchmark's trials (``bench_calibration.trial``: planar
region, truth drawn from the uniform prior, K contacts uniform over the surface with the
model's own noise), or with ``--region cube`` the localisation benchmark's (6-DOF, a 400 mm
cube, 2 mm / 5 deg contacts, ``ProximityModel(obj, 0.002, np.deg2rad(5))``), with several
schedules (``ScalingSeries(model, anneal=...)``) on the same trials, and reports per
schedule and contact count:

- search failures: trials whose answer (``map_pose``) has a log-likelihood at least 5 nats
  below the truth's, so that the search, not the model, is wrong;
- the truth in the 50 / 90 / 95 % credible regions (``hpd_level``, symmetry-aware);
- median CPU seconds of the localisation (one numba thread per worker).

A schedule written ``auto/off`` or ``auto/2`` also sets ``bound_scales`` (None or 2): which
intermediate scales are scored on the bound table alone. ``auto/2/sampler`` covers every
scale with the rejection sampler, also where the balls hold most of the region (which
``ScalingSeries._region_cover`` draws directly); ``auto/2/steps1`` sets ``bound_steps=1``
(Alg. 1's single steps on the table's scales too).

    cd benchmarks
    OMP_NUM_THREADS=1 ../.venv/bin/python study_anneal.py --contacts 10 30 60 --trials 10 --offset 0
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

ALL_MESHES = ["can", "lemon", "cereal", "mug", "bread", "milk"]  # seed numbering (the calibration benchmark's first)
FAIL_NATS = 5.0
_CACHE: dict = {}


def _init():
    os.environ["NUMBA_NUM_THREADS"] = "1"


def _one(job):
    mesh, k, seed, schedules, sigma, where = job
    warnings.simplefilter("ignore")
    import bench_calibration as BC
    from touchloc.belief import ScalingSeries, hpd_level
    from touchloc.models import ProximityModel

    if mesh not in _CACHE:
        obj = BC.quiet_load(mesh)
        obj.symmetries()
        _CACHE[mesh] = obj
    obj = _CACHE[mesh]
    if where == "cube":
        from bench_localization import trial
        from touchloc.belief import PoseRegion

        region = PoseRegion.box((0, 0, 0), 0.2, "full")
        model = ProximityModel(obj, 0.002, np.deg2rad(5))
        true, c = trial(obj, region, k, seed)
    else:
        BC.SIGMA_POS, BC.SIGMA_NOR = sigma
        region = BC.planar_region(obj)
        model = ProximityModel(obj, *sigma)
        true, c = BC.trial(obj, region, k, seed)
    out = []
    for name in schedules:
        sched, _, bound = name.partition("/")
        bound, _, cover = bound.partition("/")
        anneal = sched if sched in ("alg1", "auto", "contacts") else float(sched)
        extra = {} if not bound else dict(bound_scales=None if bound == "off" else float(bound))
        t0 = time.process_time()
        ss = ScalingSeries(model, anneal=anneal, rng=seed, progress=False, **extra)
        if cover == "sampler":
            ss._REGION_COVER = False
        if cover.startswith("steps"):
            ss.bound_steps = int(cover[5:])
        b = ss.localize(c, region)
        cpu = time.process_time() - t0
        ll_true, ll_map = model.log_likelihood(np.stack([true, b.map_pose()]), c)
        out.append(dict(mesh=mesh, k=k, schedule=name, cpu=cpu, gap=float(ll_true - ll_map),
                        q=float(hpd_level(b, true, obj, rng=seed))))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schedules", nargs="+", default=["alg1", "auto", "contacts"],
                    help="anneal= values: alg1, auto, contacts or a gain; NAME/B also sets bound_scales=B "
                         "(NAME/off: None, every scale scored exactly); NAME/B/sampler: the rejection sampler "
                         "at every scale; NAME/B/stepsK: bound_steps=K")
    ap.add_argument("--contacts", type=int, nargs="+", default=[10, 30, 60])
    ap.add_argument("--meshes", nargs="+", default=ALL_MESHES[:5])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--offset", type=int, default=0, help="seed offset (the calibration benchmark's numbering)")
    ap.add_argument("--sigma", type=float, nargs=2, default=[0.002, 0.1], metavar=("POS", "NOR"),
                    help="sensor noise, also given to the model (planar trials)")
    ap.add_argument("--region", choices=["planar", "cube"], default="planar")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    a = ap.parse_args(argv)
    jobs = [(m, k, 10_000 * k + 100 * ALL_MESHES.index(m) + a.offset + t, a.schedules, tuple(a.sigma), a.region)
            for k in a.contacts for m in a.meshes for t in range(a.trials)]
    os.environ["NUMBA_NUM_THREADS"] = "1"
    t0 = time.time()
    with ProcessPoolExecutor(a.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init) as ex:
        res = [r for rows in ex.map(_one, jobs) for r in rows]
    print(f"{len(res)} localisations in {time.time() - t0:.0f} s wall; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores\n")
    print("| schedule | contacts | trials | search failures | failures per mesh | truth in 50 % | in 90 % | in 95 % "
          "| median CPU s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for k in a.contacts:
        for s in a.schedules:
            r = [x for x in res if x["k"] == k and x["schedule"] == s]
            q = np.array([x["q"] for x in r])
            fails = [x for x in r if x["gap"] >= FAIL_NATS]
            per = ", ".join(f"{m} {sum(x['mesh'] == m for x in fails)}" for m in a.meshes
                            if any(x["mesh"] == m for x in fails)) or "-"
            print(f"| {s} | {k} | {len(r)} | {len(fails)} | {per} | {np.mean(q < 0.5):.0%} | {np.mean(q < 0.9):.0%} "
                  f"| {np.mean(q < 0.95):.0%} | {np.median([x['cpu'] for x in r]):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
