"""Tactile SLAM and shape-map updates with BLAS on one thread against BLAS's own default.

    python benchmarks/study_blas_threads.py [--steps 200] [--trials 8]

The mapping package limits BLAS to ``TOUCHLOC_BLAS_THREADS`` threads (1 by default) inside
its calls. This study runs the same worlds in child processes with the process's BLAS
settings left as they are (no ``OMP_NUM_THREADS`` or ``OPENBLAS_NUM_THREADS``), once with
the default limit and once with ``TOUCHLOC_BLAS_THREADS=0`` (no limit: BLAS uses every
core), and reports the wall-clock time of each update, binned by the contacts in the map:

- a pushed run of the milk carton with a three-finger hand (``TactileSLAM``, 2 mm / 2 deg
  per action, as the SLAM benchmark's "update time as the map grows");
- a static map of the mug explored with one probe (``ShapeMap`` via ``explore``);
- Scaling Series localising the mug (the speed benchmark's trials at 5, 10 and 30 contacts,
  ``--trials`` each; "contacts in the map" is then the contacts of a localisation).

The two settings alternate run by run (limited, unlimited, limited, ...) so that both see
the same machine load. Prints a Markdown table; nothing is written to docs/.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BINS = ((0, 100), (100, 200), (200, 400), (400, 600))


def _child(kind: str, steps: int) -> dict:
    """One run in this process: contacts in the map and wall seconds, per update."""
    import warnings

    warnings.simplefilter("ignore")
    sys.path.insert(0, str(HERE))
    from _common import quiet_load

    from touchloc.mapping import MovingWorld, TactileSLAM, explore
    from touchloc.planners import SimulatedWorld

    counts, wall = [], []
    if kind == "localize":
        from bench_localization import trial

        from touchloc.belief import PoseRegion, ScalingSeries
        from touchloc.models import ProximityModel

        model = ProximityModel(quiet_load("mug"), 0.002, np.deg2rad(5.0))
        cube = PoseRegion.box((0, 0, 0), 0.2, "full")
        ScalingSeries(model, rng=0, progress=False).localize(trial(model.obj, cube, 30, 0)[1], cube)  # warm
        for k in (5, 10, 30):
            for s in range(steps):
                c = trial(model.obj, cube, k, 5000 + 100 * k + s)[1]
                t0 = time.perf_counter()
                ScalingSeries(model, rng=5000 + 100 * k + s, progress=False).localize(c, cube)
                wall.append(time.perf_counter() - t0)
                counts.append(k)
    elif kind == "slam":
        obj = quiet_load("milk")
        lo, hi = obj.bounds
        world = MovingWorld(obj, rng=0, push=(0.002, np.deg2rad(2.0)), planar=True)
        slam = TactileSLAM((lo - 0.03, hi + 0.03), planar=True, sigma_pos=0.001, sigma_nor=np.deg2rad(5.0), rng=0)
        orig = slam.update

        def timed(*a, **k):
            t0 = time.perf_counter()
            out = orig(*a, **k)
            wall.append(time.perf_counter() - t0)
            counts.append(slam.map.n_contacts)
            return out

        slam.update = timed
        explore(world, (lo - 0.06, hi + 0.06), steps, slam=slam, fingers=3, rng=0)
    else:
        obj = quiet_load("mug")
        lo, hi = obj.bounds
        def tick(run, step):
            wall.append(step["update_time"])
            counts.append(run.map.n_contacts)

        explore(SimulatedWorld(obj, np.eye(4), rng=0), (lo - 0.03, hi + 0.03), steps, rng=0, callback=tick)
    return {"counts": counts, "wall": wall}


def _run(kind: str, steps: int, limit: str | None) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "TOUCHLOC_BLAS_THREADS")}
    if limit is not None:
        env["TOUCHLOC_BLAS_THREADS"] = limit
    out = subprocess.run([sys.executable, __file__, "--child", kind, "--steps", str(steps)], env=env,
                         capture_output=True, text=True, cwd=str(HERE))
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(steps: int = 200, trials: int = 8) -> str:
    """The study's table (Markdown), with the machine's cores and load."""
    sys.path.insert(0, str(HERE))
    from _common import table

    rows = []
    load = [os.getloadavg()[0]]
    for kind, label in (("slam", "TactileSLAM, milk pushed, 3 fingers"), ("map", "ShapeMap, mug static, 1 probe"),
                        ("localize", "ScalingSeries.localize, mug")):
        one = _run(kind, trials if kind == "localize" else steps, None)
        free = _run(kind, trials if kind == "localize" else steps, "0")
        for lo, hi in (((4, 5), (9, 10), (29, 30)) if kind == "localize" else BINS):
            cells = []
            for r in (one, free):
                c, w = np.array(r["counts"]), 1e3 * np.array(r["wall"])
                sel = (c > lo) & (c <= hi)
                cells.append(None if not np.any(sel) else (int(sel.sum()), np.median(w[sel]), np.percentile(w[sel], 95)))
            if cells[0] is None or cells[1] is None:
                continue
            rows.append([label, f"{hi}" if hi == lo + 1 else f"{lo + 1}-{hi}", cells[0][0], f"{cells[0][1]:.0f} / {cells[0][2]:.0f}",
                         f"{cells[1][1]:.0f} / {cells[1][2]:.0f}", f"{cells[1][1] / cells[0][1]:.1f}x"])
            print(" | ".join(str(x) for x in rows[-1]), file=sys.stderr, flush=True)
    load.append(os.getloadavg()[0])
    return (f"{os.cpu_count()} cores; load average (1 min) before / after: {load[0]:.1f} / {load[1]:.1f}.\n\n"
            + table(["run", "contacts in the map", "updates", "BLAS on 1 thread (default): median / p95 ms",
                     "BLAS unlimited (`TOUCHLOC_BLAS_THREADS=0`): median / p95 ms", "ratio of medians"], rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--trials", type=int, default=8, help="localisations per contact count")
    ap.add_argument("--child", choices=("slam", "map", "localize"))
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(_child(a.child, a.steps)))
        return 0
    print(measure(a.steps, a.trials))
    return 0


if __name__ == "__main__":
    sys.exit(main())
