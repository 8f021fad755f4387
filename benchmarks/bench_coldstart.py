"""Cold start: kernel compilation, process start and per-mesh set-up, with and without the caches.

Process start is also measured for the tree of commit ``BASELINE`` (``git archive``, imported
through PYTHONPATH by the same interpreter) in the same run: ``import touchloc``, the
command's start (``touchloc --version``) and a localisation with both caches warm.
"""

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

from _common import ROOT, baseline_tree, quiet_load, subdivided_bunny, table

TITLE = "Cold start: compiled kernels and per-mesh structures on disk"

#: the tree before lazy imports (every subpackage, numba, trimesh and scipy at ``import touchloc``)
BASELINE = "666723a"
#: the tree before the kernels' compilation was cut (the closest point on a triangle inlined
#: into every likelihood kernel; a read-only input compiling a kernel a second time)
COMPILE_BASELINE = "278fccb"


def _child_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: children run here, not in the checkout: ``python -c`` puts the working directory first on
#: sys.path, where a checkout's own touchloc/ would shadow the tree under test
_CWD = tempfile.gettempdir()


def _run(cmd, env):
    """Wall and CPU seconds of a fresh process, and its output."""
    c0 = _child_cpu()
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800, cwd=_CWD)
    wall = time.perf_counter() - t0
    if out.returncode not in (0, 1):
        raise RuntimeError(f"{cmd} failed: {out.stderr[-2000:]}")
    return wall, _child_cpu() - c0, out.stdout + out.stderr


def _cpu_until(cmd, env, marker):
    """CPU s a fresh process has used when ``marker`` appears on its stdout (Linux /proc);
    the process is then stopped. None where /proc is not available."""
    p = subprocess.Popen(cmd, env=dict(env, PYTHONUNBUFFERED="1"), stdout=subprocess.PIPE,
                         stderr=subprocess.DEVNULL, text=True, cwd=_CWD)
    cpu = None
    try:
        for line in p.stdout:
            if marker in line:
                try:
                    with open(f"/proc/{p.pid}/stat") as fh:
                        fields = fh.read().rsplit(")", 1)[1].split()
                    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
                except (OSError, ValueError, IndexError):
                    pass
                break
    finally:
        p.kill()
        p.communicate()
    return cpu


def _best(cmd, env, n=3):
    """Lowest CPU s of n fresh processes (and that run's wall s)."""
    return min((_run(cmd, env)[:2] for _ in range(n)), key=lambda r: r[1])


def _contacts_csv(path):
    from scipy.spatial.transform import Rotation

    obj = quiet_load("mug")
    rng = np.random.default_rng(7)
    p, n, _ = obj.sample_surface(12, rng=rng)
    R = Rotation.from_euler("z", 0.7).as_matrix()
    P = p @ R.T + [0.03, -0.02, 0.0]
    np.savetxt(path, np.hstack([P, n @ R.T]), delimiter=",", header="x,y,z,nx,ny,nz", comments="")


def _per_mesh(objs, cache):
    """Set-up of the proximity model's structures per mesh: built (cache off) vs loaded."""
    from touchloc import _cache
    from touchloc.models import MeshObject, ProximityModel

    # this process's cache setting is changed below and restored after: the benchmarks run
    # after this one in the same process (and their workers) must use the usual cache
    before = os.environ.get("TOUCHLOC_CACHE_DIR")
    try:
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
    finally:
        if before is None:
            os.environ.pop("TOUCHLOC_CACHE_DIR", None)
        else:
            os.environ["TOUCHLOC_CACHE_DIR"] = before
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
    start = _best(exe + ["--version"], runs[-1][1])
    # kernels alone, in fresh processes
    warm_code = "from touchloc._warmup import warm_kernels; print(warm_kernels())"
    kern = [_run([sys.executable, "-c", warm_code], runs[-1][1])[:2] for _ in range(2)]
    kern_warm = min(kern)

    # the same against the baseline tree: import, command start, localisation with warm caches
    base_rows = []
    base_tree = baseline_tree(BASELINE, tmp / "base")
    if base_tree is not None:
        benv = dict(base, NUMBA_CACHE_DIR=str(tmp / "numba-base"), TOUCHLOC_CACHE_DIR=str(tmp / "touchloc-base"),
                    PYTHONPATH=str(base_tree))
        bexe = [sys.executable, "-c", "import sys; from touchloc.cli import main; sys.exit(main())"]
        where = _run([sys.executable, "-c", "import touchloc; print(touchloc.__file__)"], benv)[2]
        if not where.strip().startswith(str(base_tree)):
            raise RuntimeError(f"the baseline run imports {where.strip()}, not the tree in {base_tree}")
        _run(bexe + loc[len(exe):], benv)  # compiles the baseline's kernels, fills its caches
        cenv = runs[-1][1]
        imp = [sys.executable, "-c", "import touchloc"]
        pairs = [
            ("`python -c 'import touchloc'`", _best(imp, benv), _best(imp, cenv)),
            ("`touchloc --version` (start of every command)", _best(bexe + ["--version"], benv),
             _best(exe + ["--version"], cenv)),
            ("`touchloc localize`, both caches warm", _best(bexe + loc[len(exe):], benv, 2), _best(loc, cenv, 2)),
        ]
        for label, (bw, bc), (cw, cc) in pairs:
            base_rows.append((label, f"{bc:.2f} ({bw:.2f})", f"{cc:.2f} ({cw:.2f})", f"{bc / cc:.1f}x"))
        # up to the estimator's first line: mesh and contacts loaded, nothing estimated yet
        bu = [_cpu_until(bexe + loc[len(exe):], benv, "method ss") for _ in range(3)]
        cu = [_cpu_until(loc, cenv, "method ss") for _ in range(3)]
        if None not in bu + cu:
            base_rows.insert(2, ("`touchloc localize` until the estimator starts (mesh and contacts read)",
                                 f"{min(bu):.2f}", f"{min(cu):.2f}", f"{min(bu) / min(cu):.1f}x"))

    # compiling every kernel a localisation uses (`touchloc warmup`, empty numba cache), this
    # tree against COMPILE_BASELINE, each unpacked fresh so that no cache beside its sources
    # exists; the trees run one after the other
    comp_rows = []
    import shutil

    for label, rev in ((f"commit {COMPILE_BASELINE}", COMPILE_BASELINE), ("this tree", "this")):
        if rev == "this":
            tree = tmp / "compile-this"
            shutil.copytree(ROOT / "touchloc", tree / "touchloc", ignore=shutil.ignore_patterns("__pycache__"))
        else:
            tree = baseline_tree(rev, tmp / f"compile-{rev}")
        if tree is None:
            continue
        env = dict(base, NUMBA_CACHE_DIR=str(tmp / f"numba-compile-{rev}"), TOUCHLOC_CACHE_DIR="off",
                   PYTHONPATH=str(tree))
        wall, cpu, text_ = _run([sys.executable, "-c", "import sys; from touchloc.cli import main; "
                                 "sys.exit(main(['warmup']))"], env)
        m = re.search(r"compiled (\d+) .*? in ([\d.]+) s", text_)
        comp_rows.append((label, m.group(1) if m else "-", f"{wall:.1f}", f"{cpu:.1f}"))
    if len(comp_rows) == 2 and comp_rows[1][2] != "-":
        comp_rows.append(("ratio (wall)", "", f"{float(comp_rows[0][2]) / float(comp_rows[1][2]):.2f}x", ""))

    objs = [quiet_load("mug"), subdivided_bunny(2)]
    if not quick:
        objs.append(subdivided_bunny(3))
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
        f"than the first run after install. Of that, starting Python and the command "
        f"(`touchloc --version`) is {start[0]:.2f} s wall ({start[1]:.2f} s CPU), and loading the kernels "
        f"from numba's cache in a fresh process {kern_warm[0]:.2f} s wall ({kern_warm[1]:.2f} s CPU, "
        "including its own start).",
    ]
    if base_rows:
        text += [
            f"Process start against commit {BASELINE} (the tree before lazy imports), measured in this run "
            "with the same interpreter, each with its own warm caches: CPU s of the child (wall s), the lowest "
            "of three processes (two for the localisation). `import touchloc` and the command's start no "
            "longer import numba, scipy and trimesh; a command imports what its work needs when it needs it. "
            "A localisation as a whole changes little: its work needs those libraries and imports them as it "
            "starts (numba, scipy.spatial and trimesh make up most of the CPU before the estimator starts).",
            table(("process", f"{BASELINE} CPU s (wall)", "this tree CPU s (wall)", "CPU ratio"), base_rows),
        ]
    if comp_rows:
        text += [
            "Compiling the kernels once per install (`touchloc warmup`: two processes, one for the "
            "one-thread kernels and one for the parallel ones, then whatever is left; numba's cache "
            f"empty), this tree against commit {COMPILE_BASELINE}, one after the other in this run. Since "
            "that commit the closest point on a triangle is a called function instead of being inlined "
            "in numba's IR into the five places each likelihood kernel reaches it (it takes and returns "
            "scalars, so the call costs next to nothing: query times equal within the noise), and every "
            "kernel's array inputs are made C-contiguous and writeable at the boundary, so that a "
            "read-only input (a `Contacts`' frozen points) no longer compiles the likelihood kernels a "
            "second time (about 3.5 min, paid in the test suite and by any user whose first call of a "
            "position-only model came after the warm-up).",
            table(("tree", "kernels compiled", "wall s", "CPU s"), comp_rows),
            "Whole localisations against 278fccb, from the change's own measurement (`python benchmarks/ab_speed.py 278fccb --contacts 5,10,30 --meshes mug,milk,lemon,can --trials 6`, 2026-11-27): 0.90-1.20x over the 12 cells, level within the noise (a second run of the 10-contact cells with 10 trials: mug 0.92x, milk 1.19x, can 1.09x; the first had 0.96x, 0.90x, 0.90x); every trial within 5 mm as often as before (71 of 72).",
        ]
    text += [
        "Per-mesh set-up of the proximity model (tree and fast candidate grid, default sigmas and grid), "
        "in this process with the kernels loaded: built with the cache off (what every new process paid "
        "before) vs read from the cache. Wall s (CPU s).",
        table(("mesh", "faces", "built s", "loaded s", "ratio", "cache MB"), mesh_rows),
    ]
    shutil.rmtree(tmp, ignore_errors=True)
    return "\n\n".join(text)
