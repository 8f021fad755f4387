"""Set-up before timed work: compiled kernels and per-mesh structures.

``touchloc warmup`` compiles every numba kernel once (after installing, so that no later
command pays for it) and, given meshes, builds their per-mesh structures into the disk
cache. ``touchloc cache info`` and ``touchloc cache clear`` show and empty that cache.

The commands call :func:`prepare_models` before timing a localisation, and take the time
of per-mesh structures built during it out of the localisation's: the time they report
is the localisation's alone, and set-up is reported on its own line.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

__all__ = ["CompileNotice", "warm_kernels", "compile_in_processes", "prepare_models", "SetUp"]

NOTICE = ("touchloc: compiling the numerical kernels; this happens once per install and takes a few "
          "minutes (`touchloc warmup` does it ahead of time) ...")


class CompileNotice:
    """Context manager: say once on stderr when numba starts compiling touchloc kernels,
    and add up the time spent compiling (``seconds``, ``count`` of kernels compiled).

    Kernels loaded from numba's disk cache are not compiled and print nothing.
    """

    def __init__(self, *, file=None, enabled: bool = True):
        self.file = file
        self.enabled = enabled
        self.seconds = 0.0
        self.count = 0
        self.shown = False
        self._depth = 0
        self._t0 = 0.0
        self._listener = None

    def _start(self, event):
        d = event.data.get("dispatcher") if isinstance(event.data, dict) else None
        mod = getattr(getattr(d, "py_func", None), "__module__", "") or ""
        if not mod.startswith("touchloc"):
            return
        if self._depth == 0:
            self._t0 = time.perf_counter()
            if self.enabled and not self.shown:
                print(NOTICE, file=self.file or sys.stderr, flush=True)
            self.shown = True
        self._depth += 1
        self.count += 1

    def _end(self, event):
        d = event.data.get("dispatcher") if isinstance(event.data, dict) else None
        mod = getattr(getattr(d, "py_func", None), "__module__", "") or ""
        if not mod.startswith("touchloc") or self._depth == 0:
            return
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._t0

    def __enter__(self):
        from numba.core import event

        outer = self

        class _L(event.Listener):
            def on_start(self, ev):
                outer._start(ev)

            def on_end(self, ev):
                outer._end(ev)

        self._listener = _L()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc):
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        return False


def _tetrahedron():
    import trimesh

    from .models import MeshObject

    V = 0.05 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return MeshObject(trimesh.Trimesh(V, F, process=False), name="tetrahedron", check_units=False)


#: the two halves of the kernels that :func:`warm_kernels` may compile in parallel processes
#: (their compile times are about equal: 54 and 67 s on one core each of the reference machine)
PARTS = ("serial", "parallel")


def warm_kernels(*, full: bool = False) -> float:
    """Load (or compile, the first time) the numba kernels on a 4-face mesh; seconds taken.

    ``full=False``: the kernels every localisation uses (exact and fast joint queries, in
    their one-thread and parallel forms, and the ball counts of the Scaling Series
    cover); ``full=True``: every kernel, including position-only grids and the
    brute-force reference. (:func:`compile_in_processes` first compiles them on several
    cores at once.)
    """
    from . import _cache

    t0 = time.perf_counter()
    obj = _tetrahedron()
    _cache.suspended += 1  # nothing of this throw-away mesh goes to disk
    try:
        _warm(obj, full)
    finally:
        _cache.suspended -= 1
    _warm_cover()
    _warm_mapping()
    _warm_dnf()
    return time.perf_counter() - t0


def _ignore_sigint():
    import signal

    # the parent handles Ctrl-C and ends the workers; a worker interrupted inside LLVM code
    # could crash as it exits
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _warm_part(part, full, conn=None) -> int:
    """Compile one of :data:`PARTS` (in a worker process); the number of kernels compiled,
    also sent on ``conn`` when given."""
    from . import _cache

    obj = _tetrahedron()
    _cache.suspended += 1
    with CompileNotice(enabled=False) as cn:
        _warm(obj, full and part == "serial", forms=(part,))
        if part == "serial":
            _warm_cover()
            _warm_mapping()
            _warm_dnf()
    if conn is not None:
        conn.send(cn.count)
        conn.close()
    return cn.count


def _warm_worker(part, full, conn):
    _ignore_sigint()
    _warm_part(part, full, conn)


def compile_in_processes(*, full: bool = False, jobs: int = 2) -> int:
    """Compile the one-thread and the parallel kernels of :func:`warm_kernels` in two
    processes at once; the number of kernels they compiled (0 when nothing was done).

    The kernels reach the calling process through numba's disk cache, so nothing is done
    when that cache is off or ``jobs`` < 2. Each process writes a kernel's cache files
    whole, so two that compile the same helper do no harm. A worker that fails, dies or
    cannot be started leaves its kernels to :func:`warm_kernels`, which compiles whatever
    is not cached. On two cores it nearly halves the first compilation (207 s of CPU in
    120 s wall on a 2-core machine); with the kernels already cached it costs the
    processes' start, a second or two.
    """
    import multiprocessing

    from .models._kernels import _NB

    if jobs < 2 or not _NB["cache"]:
        return 0
    ctx = multiprocessing.get_context("spawn")
    procs, count = [], 0
    try:
        for part in PARTS:
            recv, send = ctx.Pipe(duplex=False)
            p = ctx.Process(target=_warm_worker, args=(part, full, send), name=f"touchloc-warmup-{part}", daemon=True)
            p.start()
            send.close()
            procs.append((p, recv))
        for p, recv in procs:
            p.join()  # a worker that dies ends here too, without a count
            try:
                if recv.poll():
                    count += int(recv.recv())
            except (EOFError, OSError):
                pass
    except OSError:  # no processes here: warm_kernels compiles it all
        pass
    finally:
        for p, recv in procs:
            if p.is_alive():
                p.terminate()
                p.join()
            recv.close()
    return count


def _warm(obj, full, forms=PARTS):
    from .models import ProximityModel
    from .models._kernels import PARALLEL_MIN

    P = np.array([[0.01, 0.01, 0.01], [0.2, 0.0, 0.0]])
    N = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    # enough queries for the parallel kernels too (below PARALLEL_MIN the one-thread ones run)
    PP, NN = np.resize(P, (PARALLEL_MIN, 3)), np.resize(N, (PARALLEL_MIN, 3))
    # a coarse grid: a tiny build, the same compiled code as any mesh's
    model = ProximityModel(obj, 0.002, 0.1, grid_cell=0.02, grid_margin=0.01)
    from .models import Contacts

    one, many = np.eye(4)[None], np.repeat(np.eye(4)[None], PARALLEL_MIN // 2, axis=0)
    queries = dict(serial=(P, N, one), parallel=(PP, NN, many))
    for method in ("exact", "fast"):
        for form in forms:
            Q, QN, poses = queries[form]
            model.query_costs(Q, QN, method=method)
            # the poses x contacts pass of the estimators
            model.contact_costs(poses, Contacts(P, N), method=method)
            # Scaling Series' pruned pass: the bounds, then costs that stop on them
            lower = model._lower_costs(poses, Contacts(P, N))
            model._lower_costs(poses, Contacts(P, N), limit=1.0)
            model._budget_costs(poses, Contacts(P, N), method, budget=np.ones(len(poses)), lower=lower)
    if full:
        model.query_costs(P, None, method="fast")  # position-only grid lists
        model.query_costs(P, N, method="bruteforce")
        obj.closest_points(P)
        from .models import IntegratedProximityModel

        IntegratedProximityModel(obj, 0.002, 0.1, spacing=0.02).query_log_density(P, N)


def _warm_cover():
    """The Scaling Series cover's kernels (ball counts, draws), with the argument types it passes."""
    from .belief import _cover as C

    off, nbr = C._csr(np.array([[0, 1]], dtype=np.int64), 2)
    A = np.zeros((2, 7))
    X = np.zeros((3, 7))
    anchor = np.zeros(3, dtype=np.int64)
    for kernel in (C._count_in_lists, C._count_in_lists_serial):
        kernel(A, off, nbr, X, anchor, 1.0)
    for kernel in (C._count_capped, C._count_capped_serial):
        kernel(A, X, 1.0, 16)
    # the draws of full rotations (one signature, whatever the number of free axes)
    g = np.zeros((1, 6))
    g[0, 0] = 1.0
    args = (g, np.full(1, 0.5), np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), np.zeros(1, dtype=np.int64),
            np.arange(3, dtype=np.int64), 0.01, 0.05, np.empty((1, 3)), np.empty((1, 4)), np.empty((1, 7)))
    for kernel in (C._draw_full_parallel, C._draw_full_serial):
        kernel(*args)
    C.in_box(np.zeros((1, 3)), np.zeros(3), np.ones(3))
    C.quat_poses(np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros(1, dtype=np.int64), np.zeros((1, 3)))
    C.matrix_quats(np.eye(3)[None])
    C._beyond(X, A, anchor, 1.0)


def _warm_mapping():
    """The shape map's kernel matrix (values and gradient components)."""
    from .mapping.gpis import load_kernels

    load_kernels()


def _warm_dnf():
    """The orientation tracker's compiled step of its 2-D comparison field."""
    from .dnf._kernels import load_kernels

    load_kernels()


class SetUp:
    """Set-up time of a command, kept apart from the time of its work.

    Made by :func:`prepare_models`: the kernels are loaded (or compiled) at once; the
    per-mesh structures are built or read from the cache when the work first needs them,
    and :meth:`collect` takes their time out of the work's.
    """

    def __init__(self, kernel_seconds: float, compiled: bool):
        from . import _cache

        self.kernel_seconds = kernel_seconds
        self.compiled = compiled
        self.events = []
        self._mark = len(_cache.events)

    @property
    def seconds(self) -> float:
        """Set-up seconds so far: kernels plus the structures collected."""
        return self.kernel_seconds + sum(e[2] for e in self.events)

    def collect(self) -> float:
        """Take in the structures built or loaded since the last call; returns their seconds."""
        from . import _cache

        new = _cache.events[self._mark:]
        self._mark = len(_cache.events)
        self.events += new
        return sum(e[2] for e in new)

    def line(self) -> str:
        parts = [f"kernels {self.kernel_seconds:.2f} s{' (compiled, once per install)' if self.compiled else ''}"]
        words = {"loaded": "loaded from the cache", "built": "built and cached", "built-unsaved": "built"}
        names = {e[3] for e in self.events}
        for kind, outcome, dt, name in self.events:
            if outcome == "built-unsaved" and dt < 0.05:
                continue  # too quick to matter (small meshes' trees)
            who = f"{name} " if len(names) > 1 else ""
            parts.append(f"{who}{kind.replace('_', ' ')} {dt:.2f} s ({words.get(outcome, outcome)})")
        return f"set-up: {self.seconds:.2f} s: " + "; ".join(parts)


def prepare_models(models=(), contacts=None, *, build: bool = False) -> SetUp:
    """Load (or compile) the kernels now; with ``build=True`` also make the per-mesh
    structures of ``models`` ready (the fast grid too, which a command may never need).

    Parameters
    ----------
    models : ProximityModel or iterable of them (others are skipped)
    contacts : Contacts, optional
        Whether they carry normals decides which structures ``build`` makes.

    Returns
    -------
    SetUp
        Call its ``collect()`` after the timed work to move the time of structures built
        during it into the set-up.
    """
    from .models import ProximityModel

    t0 = time.perf_counter()
    with CompileNotice(enabled=False) as cn:
        warm_kernels()
    setup = SetUp(time.perf_counter() - t0, cn.count > 0)
    if build:
        for m in [models] if isinstance(models, ProximityModel) else models:
            if not isinstance(m, ProximityModel):
                continue
            P = np.zeros((1, 3))
            N = np.array([[0.0, 0.0, 1.0]]) if contacts is None or contacts.normals is not None else None
            if m.method in ("auto", "exact"):
                m.query_costs(P, N, method="exact")
            if m.method in ("auto", "fast"):
                m.query_costs(P, N, method="fast")
            m._bound(m._weight(N is not None))  # Scaling Series' lower bounds
        setup.collect()
    return setup


# -- commands ----------------------------------------------------------------------------

def register(sub):
    p = sub.add_parser("warmup", help="compile the kernels now (once per install), and cache meshes' structures",
                       description="Compile every numerical kernel (once per install; later processes load them "
                                   "from numba's cache in well under a second) and, for each --mesh given, build "
                                   "the per-mesh structures of the proximity model into the touchloc cache.")
    from .cli import add_mesh_argument

    add_mesh_argument(p, name="--mesh", help_extra="; its structures are built for the default sigmas")
    p.set_defaults(func=run_warmup)
    q = sub.add_parser("cache", help="show or empty the per-mesh cache",
                       description="The per-mesh cache holds structures that take seconds to build (the fast "
                                   "likelihood's candidate grid, large meshes' trees). Its directory is "
                                   "$TOUCHLOC_CACHE_DIR, else $XDG_CACHE_HOME/touchloc or ~/.cache/touchloc; "
                                   "TOUCHLOC_CACHE_DIR=off turns it off.")
    q.add_argument("action", choices=("info", "clear"), nargs="?", default="info")
    q.set_defaults(func=run_cache)


def run_warmup(args) -> int:
    import numba

    from .cli import load_mesh
    from .models import ProximityModel

    t0 = time.perf_counter()
    with CompileNotice(enabled=False) as cn:
        # the first time, on every core (two halves at once); later, loaded in a second or two
        count = compile_in_processes(full=True, jobs=os.cpu_count() or 1)
        warm_kernels(full=True)
    dt = time.perf_counter() - t0
    count += cn.count
    how = f"compiled {count} (once per install)" if count else "loaded from numba's cache"
    where = numba.config.CACHE_DIR or "beside the installed sources or numba's per-user cache"
    print(f"kernels: {how} in {dt:.1f} s; kept {where}")
    if args.mesh:
        obj = load_mesh(args.mesh, args.scale)
        prep = prepare_models([ProximityModel(obj, 0.002, 0.1), ProximityModel(obj, 0.002, None)], build=True)
        print(f"{obj.name}: {prep.line()}")
    return 0


def run_cache(args) -> int:
    from . import _cache

    if args.action == "clear":
        n = _cache.clear()
        print(f"removed {n} cached structure{'s' if n != 1 else ''} from {_cache.cache_dir()}")
        return 0
    inf = _cache.info()
    if inf["dir"] is None:
        print(f"the per-mesh cache is off ({_cache.ENV}={__import__('os').environ.get(_cache.ENV)!r})")
        return 0
    print(f"directory: {inf['dir']}")
    if not inf["kinds"]:
        print("empty")
    for kind, (n, size) in inf["kinds"].items():
        print(f"  {kind}: {n} file{'s' if n != 1 else ''}, {size / 1e6:.1f} MB")
    return 0
