"""Helpers shared by the benchmark modules."""

from __future__ import annotations

import io
import os
import subprocess
import tarfile
import time
import warnings
from pathlib import Path

import numpy as np


def timeit(fn, *, repeat: int = 3, min_time: float = 0.2):
    """Best wall time (s) of ``fn()`` over ``repeat`` rounds (each >= min_time total)."""
    best = np.inf
    for _ in range(repeat):
        n = 0
        t0 = time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_time:
                break
        best = min(best, dt / n)
    return best


def table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(str(x) for x in r) + " |")
    return "\n".join(out)


def quiet_load(name):
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_object(name)


def subdivided_bunny(times: int, name: str | None = None):
    """The bundled bunny (15 cm, 902 faces) subdivided ``times`` times: ~14k faces for 2,
    ~58k for 3."""
    import trimesh

    from touchloc.models import MeshObject

    b = quiet_load("bunny")
    v, f = b.mesh.vertices, b.mesh.faces
    for _ in range(times):
        v, f = trimesh.remesh.subdivide(v, f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.Trimesh(v, f), name=name or f"bunny-{len(f) // 1000}k")


def big_bunny():
    """The bundled bunny subdivided three times: ~58k faces."""
    return subdivided_bunny(3, name="bunny-58k")


# -- sweeps ------------------------------------------------------------------------------
#: how the benchmarks run their trials: ``touchloc.experiments.run_sweep`` on this executor
#: ("processes": a pool of one single-threaded worker per core). benchmarks/run.py sets these
#: from its --executor, --workers and --resume options.
SWEEP = {"executor": os.environ.get("TOUCHLOC_BENCH_EXECUTOR", "processes"),
         "workers": int(os.environ.get("TOUCHLOC_BENCH_WORKERS", "0")) or None,
         "resume": os.environ.get("TOUCHLOC_BENCH_RESUME", "") == "1"}
#: where the tidy results of the benchmark sweeps go (one CSV per benchmark)
RESULTS = Path(__file__).resolve().parent.parent / "out" / "bench"


def run_trials(name: str, trials: list, quick: bool):
    """Run a benchmark's trials as a sweep; returns (rows, a sentence saying how they ran).

    The rows stream to ``out/bench/<name>[-quick].csv``. The file starts afresh unless
    resuming was asked for (``run.py --resume``: continue an interrupted benchmark; rows
    of trials with the same parameters are then taken as they are).
    """
    from touchloc.experiments import read_results, run_sweep

    path = RESULTS / f"{name}{'-quick' if quick else ''}.csv"
    workers = SWEEP["workers"] or (1 if SWEEP["executor"] == "serial" else os.cpu_count())
    ids = {t["trial_id"] for t in trials}
    before = {r["trial_id"] for r in read_results(path)} & ids if SWEEP["resume"] and path.exists() else set()
    t0 = time.perf_counter()
    rows = run_sweep(trials, path, executor_spec=SWEEP["executor"], workers=workers, resume=SWEEP["resume"],
                     parquet=False)
    wall = time.perf_counter() - t0
    rows = [r for r in rows if r["trial_id"] in ids]
    busy = sum(r["time"] for r in rows if r["trial_id"] not in before)
    setup = "; meshes and models built once per worker before the first trial" if "mesh" in trials[0] else ""
    ran = len(rows) - len(before)
    how = (f"{len(rows)} trials run as one sweep (`touchloc.experiments.run_sweep`, executor "
           f"\"{SWEEP['executor']}\", {workers} worker{'s' if workers > 1 else ''}, each on one thread{setup})")
    if before:
        how += f"; {len(before)} of them taken from an earlier, interrupted run (`--resume`)"
    if ran:
        how += (f": {wall:.0f} s wall for {busy:.0f} s of estimator time in the {ran} trials run now "
                f"({busy / wall:.2f} trials' worth of estimator work at once)")
    how += f". Tidy rows: `{path.relative_to(RESULTS.parent.parent)}`" + (" (`touchloc report` draws them)." if setup
                                                                          else ".")
    return rows, how


ROOT = Path(__file__).resolve().parent.parent


def baseline_tree(rev: str, dest) -> Path | None:
    """The touchloc package of commit ``rev``, unpacked under ``dest``, to put on
    PYTHONPATH of a process that measures the baseline in the same run (None without git
    or without that commit)."""
    try:
        data = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "touchloc"],
                              check=True, capture_output=True).stdout
        with tarfile.open(fileobj=io.BytesIO(data)) as tf:
            tf.extractall(Path(dest), filter="data")
    except (OSError, subprocess.CalledProcessError, tarfile.TarError):
        return None
    return Path(dest)


class TreeWorker:
    """A process running ``script --worker`` with the touchloc package of ``path`` first on
    its path (this checkout, or a baseline unpacked by :func:`baseline_tree`), answering
    one JSON request per line; refuses to start if it imported touchloc from elsewhere."""

    def __init__(self, script, path: Path, env: dict | None = None):
        import json
        import sys

        env = dict(os.environ, PYTHONPATH=str(path), PYTHONWARNINGS="ignore", **(env or {}))
        self.p = subprocess.Popen([sys.executable, str(Path(script).resolve()), "--worker"], cwd=str(path),
                                  env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        hello = json.loads(self.p.stdout.readline())
        if not Path(hello["touchloc"]).resolve().is_relative_to(Path(path).resolve()):
            raise RuntimeError(f"benchmark worker imported {hello['touchloc']}, not the tree under {path}")

    def ask(self, **req):
        import json

        self.p.stdin.write(json.dumps(req) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise RuntimeError("benchmark worker died")
        return json.loads(line)

    def close(self):
        self.p.stdin.close()
        self.p.wait(timeout=60)


def workers() -> int:
    """Worker processes for a benchmark's trials: ``TOUCHLOC_BENCH_WORKERS``, else one per core."""
    return int(os.environ.get("TOUCHLOC_BENCH_WORKERS", "0")) or os.cpu_count() or 1


def spawn_map(fn, specs: list, env: dict | None = None) -> list:
    """``[fn(s) for s in specs]`` on :func:`workers` spawned processes with single-threaded BLAS.

    ``fn`` must be a module-level function of a benchmark module; ``env`` adds variables to
    the workers' environment. The workers are spawned, not forked: BLAS reads its thread
    count when numpy is first imported, which in this process has already happened, so
    only a fresh interpreter started with the variables set runs single-threaded (forked
    workers kept two threads each, four busy threads on two cores).
    """
    import multiprocessing
    import sys
    import types
    from concurrent.futures import ProcessPoolExecutor

    # benchmarks/run.py loads a benchmark file without registering it as a module: register
    # it, so that fn pickles by name (the workers import the file as the module of that name)
    name = fn.__module__
    if getattr(sys.modules.get(name), fn.__name__, None) is not fn:
        mod = types.ModuleType(name)
        mod.__dict__.update(fn.__globals__)
        sys.modules[name] = mod
    extra = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    extra.update(env or {})
    saved = {k: os.environ.get(k) for k in extra}
    os.environ.update(extra)       # the spawned workers inherit this process's environment
    try:
        with ProcessPoolExecutor(workers(), mp_context=multiprocessing.get_context("spawn")) as ex:
            return list(ex.map(fn, specs))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
