"""Which of the DNF sweep's failing cells fail in tracking, and which in mapping.

The DNF tracker (default parameters) runs on the development seeds
``[11, cell, object, set]`` (neither the sweep's nor the held-out seeds of
``bench_dnf.py``) of the chosen cells of the robustness sweep, under four versions of
the same data sets:

* **as generated**;
* **edge landings removed**: ``generate_rotation_dataset(..., edge_normals=False)``, so
  the fingers that landed on an edge report nothing (the random draws are the same);
* **true rotation as odometry**: the data set's odometry replaced by its true rotation,
  regrasp slips included, and the tracker's rate prior set to 0 (nothing to learn);
* **both**.

A cell that passes with the true rotation fails in tracking; a cell that does not fails
in mapping. The table gives the right count in the second half for the 4-, 5-, 6-,
8-gon and the round object (mean over the data sets). ``--counts`` adds, for each
(cell, object) below 90 %, the share of the second half at each count and the right
count of each data set. The figures are in docs/dnf_rounds.md ("Fourth round").

    cd benchmarks
    ../.venv/bin/python study_dnf_probes.py --cells normals_per_contact=1 base noise=6 slip=3 \
        --sets 0-7 --counts
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dnf import _BASE, _SWEEP_OBJECTS, _cell_kwargs, sweep_cells  # noqa: E402

def _cell_name(cell) -> str:
    """'base', or the knob the cell moves from the base cell and its value (``noise=6``)."""
    moved = [(k, v) for k, v in cell.items() if v != _BASE[k]]
    return "base" if not moved else ", ".join(f"{k}={v:g}" for k, v in moved)


#: the sweep's cells by name, with their number in the sweep's order (the seeds use it)
CELLS = {_cell_name(c): (i, c) for i, c in enumerate(sweep_cells())}
PROBES = {"as generated": (True, False), "edge landings removed": (False, False),
          "true rotation as odometry": (True, True), "both": (False, True)}


def dev_dataset(ci: int, obj: str, s: int, edge_normals: bool = True):
    """Development data set ``s`` of the sweep's cell number ``ci`` and object ``obj``
    (seeds ``[11, cell, object, set]``, 4 turns)."""
    from touchloc.dnf import generate_rotation_dataset

    rng = np.random.default_rng([11, ci, [o for o, _ in _SWEEP_OBJECTS].index(obj), s])
    return generate_rotation_dataset(dict(_SWEEP_OBJECTS)[obj], revolutions=4.0, rng=rng,
                                     edge_normals=edge_normals, **_cell_kwargs(sweep_cells()[ci]))


def second_half_counts(ds, **params) -> np.ndarray:
    """The DNF tracker's side counts (``params`` overriding its defaults) in the second
    half of a data set."""
    from touchloc.dnf import OrientationTracker
    from touchloc.dnf.compare import run_estimator

    run = run_estimator("dnf", lambda: OrientationTracker(**params), ds)
    return run.counts[len(run.counts) // 2:]


def _one(job):
    import warnings

    warnings.simplefilter("ignore")
    from touchloc.dnf import RotationDataset

    cell_name, obj, s, edges, true_odo = job
    ds = dev_dataset(CELLS[cell_name][0], obj, s, edge_normals=edges)
    params = {}
    if true_odo:
        ds = RotationDataset(ds.time, ds.true_orientation, ds.normal_angles, ds.sample_index,
                             true_orientation=ds.true_orientation, n_surfaces=ds.n_surfaces, name=ds.name)
        params["rate_prior_mean"] = 0.0
    return job, second_half_counts(ds, **params)


def _sets(spec: str) -> list[int]:
    out = []
    for part in spec.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="+", default=["normals_per_contact=1", "base", "noise=6", "slip=3"],
                    choices=list(CELLS), help="cells by the knob they move (default: the four that the docs show)")
    ap.add_argument("--sets", default="0-7", help="development data sets, e.g. 0-7 or 0,2,5")
    ap.add_argument("--probes", nargs="+", default=list(PROBES), choices=list(PROBES))
    ap.add_argument("--counts", action="store_true", help="count distributions of the (cell, object) below 90 %%")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    a = ap.parse_args(argv)
    sets = _sets(a.sets)
    objects = [o for o, _ in _SWEEP_OBJECTS]
    jobs = [(c, o, s, *PROBES[p]) for p in a.probes for c in a.cells for o in objects for s in sets]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        results = dict(ex.map(_one, jobs, chunksize=4))
    truth = dict(_SWEEP_OBJECTS)
    print(f"Development seeds [11, cell, object, set], sets {a.sets}; right count in the second half, "
          f"{' / '.join(objects)} ({time.perf_counter() - t0:.0f} s, {a.workers} workers)\n")
    print("| data | " + " | ".join(a.cells) + " |")
    print("|---|" + "---|" * len(a.cells))
    for p in a.probes:
        edges, true_odo = PROBES[p]
        row = []
        for c in a.cells:
            right = [np.mean([np.mean(results[(c, o, s, edges, true_odo)] == truth[o]) for s in sets]) for o in objects]
            row.append(" / ".join(f"{100 * r:.0f}" for r in right))
        print(f"| {p} | " + " | ".join(row) + " |")
    if a.counts:
        for p in a.probes:
            edges, true_odo = PROBES[p]
            print(f"\n{p}: (cell, object) below 90 %: share of the second half at each count; right count per data set")
            for c in a.cells:
                for o in objects:
                    runs = [results[(c, o, s, edges, true_odo)] for s in sets]
                    allc = np.concatenate(runs)
                    if np.mean(allc == truth[o]) >= 0.9:
                        continue
                    vals, n = np.unique(allc, return_counts=True)
                    share = ", ".join(f"{v}: {100 * k / allc.size:.0f} %" for v, k in zip(vals, n))
                    per = " ".join(f"{np.mean(r == truth[o]):.2f}" for r in runs)
                    print(f"- {c}, {o}: {share}; {per}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
