"""Cold start: kernel compilation, process start and per-mesh set-up, with and without the caches."""

from __future__ import annotations

import os
import re
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from _common import quiet_load, table

TITLE = "Cold start: compiled kernels and per-mesh structures on disk"


def _child_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(cmd, env):
    """Wall and CPU seconds of a fresh process, and its output."""
    c0 = _child_cpu()
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    wall = time.perf_counter() - t0
    if out.returncode not in (0, 1):
        raise RuntimeError(f"{cmd} failed: {out.stderr[-2000:]}")
    return wall, _child_cpu() - c0, out.stdout + out.stderr


def _contacts_csv(path):
    from scipy.spatial.transform import Rotation

    obj = quiet_load("mug")
    rng = np.random.default_rng(7)
    p, n, _ = obj.sample_surface(12, rng=rng)
    R = Rotation.from_euler("z", 0.7).as_matrix()
    P = p @ R.T + [0.03, -0.02, 0.0]
    np.savetxt(path, np.hstack([P, n @ R.T]), delimiter=",", header="x,y,z,nx,ny,nz", comments="")


def _subdivided_bunny(times):
    import trimesh

    from touchloc.models import MeshObject

    b = quiet_load("bunny")
    v, f = b.mesh.vertices, b.mesh.faces
    for _ in range(times):
        v, f = trimesh.remesh.subdivide(v, f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.Trimesh(v, f), name=f"bunny-{len(f) // 1000}k")


def _per_mesh(objs, cache):
    """Set-up of the proximity model's structures per mesh: built (cache off) vs loaded."""
    from touchloc import _cache
    from touchloc.models import MeshObject, ProximityModel

    rows = []
    for obj in objs:
        fresh = lambda: MeshObject(obj.mesh, name=obj.name, check_units=False)  # noqa: E731
        N = np.array([[0.0, 0.0, 1.0]])

        def setup(o):
            t0 = time.perf_counter()
            c0 = time.process_time()
            m = ProximityModel(o, 0.002, 0.1)
            m.query_costs(np.zeros((1, 3)), N, method="fast")
            return time.perf_counter() - t0, time.process_time() - c0

        os.environ["TOUCHLOC_CACHE_DIR"] = "off"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            built = setup(fresh())
            os.environ["TOUCHLOC_CACHE_DIR"] = str(cache)
            setup(fresh())  # writes the files
            loaded = min((setup(fresh()) for _ in range(3)), key=lambda x: x[0])
        size = sum(f.stat().st_size for f in Path(cache).rglob("*.npz") if _cache.mesh_hash(obj)[:16] in f.name)
        rows.append((obj.name, obj.n_faces, f"{built[0]:.2f} ({built[1]:.2f})", f"{loaded[0]:.3f} ({loaded[1]:.3f})",
                     f"{built[0] / loaded[0]:.0f}x", f"{size / 1e6:.1f}"))
    return rows


def run(quick: bool = False) -> str:
    tmp = Path(tempfile.mkdtemp(prefix="touchloc-bench-cold-"))
    csv = tmp / "contacts.csv"
    _contacts_csv(csv)
    script = Path(sys.executable).parent / "touchloc"
    exe = [str(script)] if script.exists() else [sys.executable, "-m", "touchloc.cli"]
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "TOUCHLOC_CACHE_DIR")}
    nb = str(tmp / "numba")
    cache = str(tmp / "touchloc")
    loc = exe + ["localize", "--mesh", "mug", "--contacts", str(csv), "--rotation", "yaw"]
    runs = [
        ("first run after install: compile kernels, build grid", dict(base, NUMBA_CACHE_DIR=nb, TOUCHLOC_CACHE_DIR="off")),
        ("new process, kernels cached, per-mesh cache off (before)", dict(base, NUMBA_CACHE_DIR=nb, TOUCHLOC_CACHE_DIR="off")),
        ("new process, per-mesh cache filled by a first run", dict(base, NUMBA_CACHE_DIR=nb, TOUCHLOC_CACHE_DIR=cache)),
        ("new process, both caches warm", dict(base, NUMBA_CACHE_DIR=nb, TOUCHLOC_CACHE_DIR=cache)),
    ]
    rows = []
    res = []
    for label, env in runs:
        wall, cpu, text = _run(loc, env)
        setup = re.search(r"set-up: ([\d.]+) s", text)
        loc_t = re.search(r"time: ([\d.]+) s localisation", text)
        res.append((wall, cpu))
        rows.append((label, f"{wall:.1f}", f"{cpu:.1f}", setup.group(1) if setup else "-",
                     loc_t.group(1) if loc_t else "-"))
    # process start alone: import and parse, no work
    starts = [_run(exe + ["--version"], runs[-1][1])[:2] for _ in range(3)]
    start = min(starts)
    # kernels alone, in fresh processes
    warm_code = "from touchloc._warmup import warm_kernels; print(warm_kernels())"
    kern = [_run([sys.executable, "-c", warm_code], runs[-1][1])[:2] for _ in range(2)]
    kern_warm = min(kern)

    objs = [quiet_load("mug"), _subdivided_bunny(2)]
    if not quick:
        objs.append(_subdivided_bunny(3))
    mesh_rows = _per_mesh(objs, tmp / "per-mesh")

    cold, before, after = res[0], res[1], res[3]
    text = [
        "`touchloc localize` of the mug (864 faces, 12 contacts, yaw region, Scaling Series) in "
        "fresh processes; numba's cache and the per-mesh cache each start empty in this run. "
        "Wall s on a shared machine, CPU s (user + system of the child) beside it; set-up and "
        "localisation as the command reports them.",
        table(("process", "wall s", "CPU s", "set-up s", "localisation s"), rows),
        f"With both caches warm a new process takes {after[0]:.1f} s instead of {before[0]:.1f} s "
        f"({before[0] / after[0]:.1f}x less; CPU {before[1] / after[1]:.1f}x) and {cold[0] / after[0]:.0f}x less "
        f"than the first run after install. Of that, starting Python and importing the command "
        f"(`touchloc --version`) is {start[0]:.2f} s wall ({start[1]:.2f} s CPU), and loading the kernels "
        f"from numba's cache in a fresh process {kern_warm[0]:.2f} s wall ({kern_warm[1]:.2f} s CPU, "
        "including its own start).",
        "Per-mesh set-up of the proximity model (tree and fast candidate grid, default sigmas and grid), "
        "in this process with the kernels loaded: built with the cache off (what every new process paid "
        "before) vs read from the cache. Wall s (CPU s).",
        table(("mesh", "faces", "built s", "loaded s", "ratio", "cache MB"), mesh_rows),
    ]
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return "\n\n".join(text)
