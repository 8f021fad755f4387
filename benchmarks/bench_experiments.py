"""Sweep throughput: serial vs a process pool vs a Dask LocalCluster, and Dask's per-task cost."""

from __future__ import annotations

import concurrent.futures as cf
import os
import pickle
import tempfile
import time
from pathlib import Path

import numba

from _common import table
from touchloc.experiments import Sweep, executor, run_sweep, run_trial

TITLE = "Experiments: sweep throughput on serial, process and Dask executors"


def _warm(ex, workers, trials):
    """Load every mesh, build its structures and load the compiled kernels in every worker.

    Several trials per mesh and worker, so that (with idle workers taking tasks as they
    come) each worker meets each mesh at least once. Returns the wall time (s).
    """
    t0 = time.perf_counter()
    meshes = {}
    for t in trials:
        meshes.setdefault(t["mesh"], t)
    fs = [ex.submit(run_trial, dict(t, seed=10_000 + i)) for t in meshes.values() for i in range(2 * workers)]
    for f in fs:
        f.result()
    return time.perf_counter() - t0


def _noop(x):
    return x


def run(quick: bool = False) -> str:
    workers = os.cpu_count() or 2
    load0 = os.getloadavg()[0]
    seeds = 3 if quick else 10
    sweep = Sweep(meshes=["cereal", "milk", "can"], estimators=[{"name": "pf", "n_particles": 8000}],
                  contacts=[30], seeds=seeds)
    trials = sweep.trials()
    rows, tables = [], {}
    with tempfile.TemporaryDirectory() as d:
        base = None
        for spec in ("serial", "serial, 1 thread", "processes", "dask"):
            n = 1 if spec.startswith("serial") else workers
            numba.set_num_threads(1 if spec == "serial, 1 thread" else numba.config.NUMBA_NUM_THREADS)
            with executor(spec.split(",")[0], n) as ex:
                setup = _warm(ex, n, trials)
                t0 = time.perf_counter()
                out = run_sweep(trials, Path(d) / f"{spec.replace(', ', '-').replace(' ', '_')}.csv", executor_obj=ex, progress=False, parquet=False)
                wall = time.perf_counter() - t0
                busy = sum(r["time"] for r in out)
                if spec == "dask":
                    k = 200
                    t1 = time.perf_counter()
                    for f in cf.as_completed([ex.submit(_noop, t) for t in (trials * k)[:k]]):
                        f.result()
                    per_task = (time.perf_counter() - t1) / k
            tables[spec] = out
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
            thr = len(trials) / wall
            if spec == "serial, 1 thread":
                base = thr
            rows.append([spec, n, len(trials), f"{setup:.1f}", f"{wall:.1f}", f"{thr:.2f}", thr, f"{100 * busy / (wall * n):.0f} %"])
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    for r in rows:
        r[6] = f"{r[6] / base:.2f}"
    same = all(
        all(a[c] == b[c] for c in a if c != "time")
        for spec in tables for a, b in zip(tables["serial"], tables[spec]))
    mean_trial = sum(r["time"] for r in tables["serial"]) / len(trials)
    payload = len(pickle.dumps(trials[0]))
    return "\n\n".join([
        f"{len(trials)} trials (importance-sampling PF, 8000 particles, 30 contacts, cereal / milk / can; "
        f"{mean_trial:.2f} s each on average when run alone), run by `touchloc.experiments.run_sweep` "
        f"through each executor with {workers} workers after a warm-up that loads the meshes, builds their "
        "structures and loads the compiled kernels in every worker ('set-up': done once per worker and "
        "mesh, whatever the number of trials; not in 'wall'). 'busy': the trials' own "
        "estimator time over wall time x workers (the rest is data generation, scoring, scheduling and "
        "writing rows). 'serial' runs the compiled kernels on all cores inside each trial (the library's "
        "default); 'serial, 1 thread' is the per-core baseline; pool and cluster workers run one thread "
        "each. The machine is shared with other jobs, so ratios vary by a few tenths between runs.",
        table(("executor", "workers", "trials", "set-up s", "wall s", "trials / s", "vs serial, 1 thread", "busy"), rows),
        f"The {len(tables)} tables are {'identical' if same else 'NOT identical'} in every column but the wall "
        f"time. Load average (1 min) of the machine: {load0:.1f} before, {os.getloadavg()[0]:.1f} after this "
        f"benchmark on {workers} cores; with other jobs holding the cores, extra workers cannot show "
        "their full speed-up. "
        f"Dask round trip of a no-op task through the executor (200 tasks, 2 workers): "
        f"{1e3 * per_task:.1f} ms per task, {100 * per_task / 1.0:.1f} % of a 1 s trial. A task carries only the "
        f"trial's parameters ({payload} bytes pickled); meshes and their BVHs are built in each worker on "
        "its first trial and kept in a per-process cache.",
    ])
