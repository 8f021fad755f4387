"""Paired study of what the swept free space adds to GPIS maps (a quick check, not a bench).

Each trial maps one mesh twice with the same seed, pose and noise, with and without free
space, with Chamfer checkpoints every 10 touches. It reports, per trial and summed over
trials, the touches the free-space arm needs to reach the contacts-only arm's Chamfer
distance at ``--ref`` touches and at the last checkpoint, the ratio of the two arms'
Chamfer distances, the hits, and the free-space map's 2-sigma band. Run from the
benchmarks folder:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 ../.venv/bin/python study_free_space.py \\
        --meshes bread can cereal lemon milk mug bunny --seeds 0 1

``--no-normals`` strips the normals from every contact (a sensor that reports where it
touched but not the surface's direction); ``--planner random`` uses random touches, the
same in both arms; ``--oracle`` replaces the free-space arm by a contacts-only one whose planner
is told in advance which candidate touches would miss (by ray casting the hidden object),
the most that free space could tell a planner. Procedural shapes of the bench (e.g. "torus R40 r15") are accepted as
mesh names.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from _common import quiet_load
from bench_mapping import _procedural, touches_to, trial


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["bread", "can", "cereal", "bunny"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--planner", default="uncertainty", choices=["uncertainty", "random", "lattice"])
    ap.add_argument("--touches", type=int, default=60)
    ap.add_argument("--ref", type=int, default=30, help="contacts-only checkpoint to reach")
    ap.add_argument("--no-normals", action="store_true", help="contacts report positions only")
    ap.add_argument("--oracle", action="store_true",
                    help="the first arm maps without free space too, but its planner is told which candidate "
                         "touches would miss (an upper bound on what free space can do for the planner)")
    ap.add_argument("--json", default=None, help="write the per-trial rows here")
    a = ap.parse_args(argv)
    cps = tuple(range(10, a.touches + 1, 10))
    proc = _procedural()
    rows, t0 = [], time.perf_counter()
    for name in a.meshes:
        obj = proc[name] if name in proc else quiet_load(name)
        for s in a.seeds:
            f, n = (trial(obj, s, planner=a.planner, free_space=fs and not a.oracle, touches=a.touches,
                          checkpoints=cps, calib_at=(30, a.touches), normals=not a.no_normals,
                          oracle_hits=fs and a.oracle) for fs in (True, False))
            row = dict(mesh=name, seed=s, reach=touches_to(f["chamfer"], n["chamfer"][a.ref]),
                       reach_last=touches_to(f["chamfer"], n["chamfer"][a.touches]),
                       free={k: round(v * 1e3, 2) for k, v in f["chamfer"].items()},
                       nofree={k: round(v * 1e3, 2) for k, v in n["chamfer"].items()},
                       band_free=f["calib"], band_nofree=n["calib"],
                       hits_free=sum(r.hit for r in f["run"].results),
                       hits_nofree=sum(r.hit for r in n["run"].results))
            rows.append(row)
            print(f"{name:>8} s{s}: reach {row['reach']} (of {a.ref}), {row['reach_last']} (of {a.touches}) | "
                  f"Chamfer mm free {[row['free'][k] for k in cps]} | none {[row['nofree'][k] for k in cps]} | "
                  f"hits {row['hits_free']}/{row['hits_nofree']} | band {f['calib']}", flush=True)
    cap = a.touches + 10
    r = np.minimum([x["reach"] for x in rows], cap)
    rl = np.minimum([x["reach_last"] for x in rows], cap)

    def ratio(k):
        return float(np.exp(np.mean([np.log(x["free"][k] / x["nofree"][k]) for x in rows])))

    print(f"free space reaches the contacts-only {a.ref}-touch accuracy with "
          f"{100 * (1 - r.sum() / (a.ref * len(r))):.0f} % fewer touches in total (median {np.median(r):.0f}), "
          f"the {a.touches}-touch accuracy with {100 * (1 - rl.sum() / (a.touches * len(rl))):.0f} % fewer "
          f"(median {np.median(rl):.0f}; not reached counted as {cap}); Chamfer free / none (geometric mean): "
          f"{ratio(a.ref):.3f} at {a.ref}, {ratio(a.touches):.3f} at {a.touches}; hits "
          f"{sum(x['hits_free'] for x in rows)} / {sum(x['hits_nofree'] for x in rows)}; "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, default=float)


if __name__ == "__main__":
    main()
