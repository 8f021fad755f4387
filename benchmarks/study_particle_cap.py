"""Scaling Series' particle cap: time and accuracy of the quick-start localisation at few contacts.

At 5 contacts the cap on particles per scale (``max_particles``) binds for about half of the
scales, and most of the time goes into particles the prune then drops. This study runs the
localisation benchmark's trials (hidden pose uniform in a 400 mm cube, any rotation, k
contacts with 2 mm / 5 deg noise; ``ProximityModel(obj, 0.002, np.deg2rad(5))``,
``ScalingSeries(model, rng=seed, max_particles=cap).localize``) for several caps on the
same trials, each in a worker process with one numba thread, and reports CPU time and
ADD-S; with ``--coverage``, also how often the truth lies in the belief's 90 % credible
region (``touchloc.belief.hpd_level``, modulo the mesh's symmetries).

    cd benchmarks
    OMP_NUM_THREADS=1 ../.venv/bin/python study_particle_cap.py --caps 20000 6000 \
        --meshes mug can milk lemon bread cereal bunny --seeds 10 11 12 --contacts 5 10
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _one(job):
    mesh, seed, k, cap, coverage = job
    warnings.simplefilter("ignore")
    from bench_localization import trial
    from touchloc.belief import PoseRegion, ScalingSeries, add_s, hpd_level
    from touchloc.data import load_object
    from touchloc.models import ProximityModel

    m = _models.get(mesh)
    if m is None:
        m = _models[mesh] = ProximityModel(load_object(mesh), 0.002, np.deg2rad(5))
        cube = PoseRegion.box((0, 0, 0), 0.2, "full")
        _, c = trial(m.obj, cube, 30, 0)
        ScalingSeries(m, rng=0, progress=False).localize(c, cube)      # compile, build the grids
    cube = PoseRegion.box((0, 0, 0), 0.2, "full")
    true, c = trial(m.obj, cube, k, seed)
    c0 = time.process_time()
    cap, _, draws = str(cap).partition(":")
    kw = dict(max_particles=int(cap)) if not draws else dict(max_particles=int(cap), max_draws=int(draws))
    b = ScalingSeries(m, rng=seed, progress=False, **kw).localize(c, cube)
    cpu = time.process_time() - c0
    level = float(hpd_level(b, true, m.obj, rng=seed)) if coverage else float("nan")
    return dict(mesh=mesh, seed=seed, k=k, cap=job[3], cpu=cpu, adds=float(add_s(m.obj, b.map_pose(), true)),
                level=level)


_models: dict = {}


def _init():
    os.environ["NUMBA_NUM_THREADS"] = "1"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--caps", nargs="+", default=["20000", "6000"],
                    help="particle caps; CAP:DRAWS also sets max_draws (the default is 8 x CAP)")
    ap.add_argument("--meshes", nargs="+", default=["mug", "can", "milk", "lemon", "bread", "cereal", "bunny"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[10, 11, 12])
    ap.add_argument("--contacts", type=int, nargs="+", default=[5, 10])
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--coverage", action="store_true", help="also the truth's credible level in each belief")
    a = ap.parse_args(argv)
    # one job per (mesh, seed, k) with every cap in turn, so that the caps see the same load
    jobs = [(m, s, k, cap, a.coverage) for m in a.meshes for k in a.contacts for s in a.seeds for cap in a.caps]
    os.environ["NUMBA_NUM_THREADS"] = "1"
    t0 = time.time()
    with ProcessPoolExecutor(a.workers, initializer=_init) as ex:
        res = list(ex.map(_one, jobs))
    print(f"{len(res)} localisations in {time.time() - t0:.0f} s wall; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores\n")
    cov = " / truth in 90 % region" if a.coverage else ""
    print("| mesh | contacts | " + " | ".join(f"cap {c}: median CPU s / ADD-S < 5 mm{cov} / median ADD-S mm"
                                             for c in a.caps)
          + " | time ratio (first cap / each other) |")
    print("|---|---|" + "---|" * len(a.caps) + "---|")
    for m in a.meshes + ["all"]:
        for k in a.contacts:
            cells, times = [], {}
            for cap in a.caps:
                r = [x for x in res if x["k"] == k and x["cap"] == cap and (m == "all" or x["mesh"] == m)]
                times[cap] = np.array([x["cpu"] for x in r])
                ok = sum(x["adds"] < 0.005 for x in r)
                cell = f"{np.median(times[cap]):.2f} / {ok}/{len(r)}"
                if a.coverage:
                    cell += f" / {sum(x['level'] < 0.9 for x in r)}/{len(r)}"
                cell += f" / {np.median([x['adds'] for x in r]) * 1e3:.2f}"
                cells.append(cell)
            first = a.caps[0]
            ratio = ", ".join(f"{np.median(times[first] / times[c]):.2f}x" for c in a.caps[1:])
            print(f"| {m} | {k} | " + " | ".join(cells) + f" | {ratio} |")
    worst = {}
    for x in res:
        worst.setdefault((x["cap"], x["k"]), []).append(x["adds"])
    print("\nADD-S of the misses (mm): " + "; ".join(
        f"cap {cap}, {k} contacts: " + (", ".join(f"{v * 1e3:.1f}" for v in sorted(v) if v >= 0.005) or "none")
        for (cap, k), v in sorted(worst.items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
