"""Where the ``fast`` likelihood's time goes on the pairs localisations ask for.

The likelihood calls of whole localisations (``ScalingSeries(...).localize`` on the speed
benchmark's trials, seeds 1-4) are recorded with their poses, budgets and bounds, then:

* replayed with each method (milliseconds per localisation, the faster of two passes),
  and again with each call's poses sorted along a Morton curve of the contacts' centroid
  seen from each pose (``--sorted``), to test whether the order of the poses matters;
* split by what the fast method does with each object-frame query (every third call,
  every contact, budgets ignored): the finest level's normal-keyed near list, the
  finest level's general list, a coarser level's list, or outside every level (the
  tree); with the share of each and its cost per query on each method, one pose and
  all its queries in one compiled pass;
* the near-listed queries once more in their arrival order and sorted by cell, to tell
  the memory's latency from the arithmetic.

    cd benchmarks
    ../.venv/bin/python study_fast_anatomy.py --meshes bread milk cereal lemon mug --contacts 10 30

Figures and what they mean: docs/benchmarks.md, "Localisation speed with few contacts".
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def morton_order(X, contacts) -> np.ndarray:
    """The poses' order along a Morton curve of the contacts' centroid in each pose's frame."""
    R, t = X[:, :3, :3], X[:, :3, 3]
    q = np.einsum("nji,nj->ni", R, contacts.points.mean(axis=0) - t)
    lo, span = q.min(axis=0), np.maximum(np.ptp(q, axis=0), 1e-12)
    s = ((q - lo) / span * 1023).astype(np.uint64)
    code = np.zeros(len(X), np.uint64)
    for b in range(10):
        for d in range(3):
            code |= ((s[:, d] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + d)
    return np.argsort(code, kind="stable")


def replay(m, calls, n_loc, order=False):
    """ms per localisation of the recorded calls on each method (the faster of two passes)."""
    out = {}
    if order:
        sorted_calls = []
        for X, c, b, lo in calls:
            o = morton_order(X, c)
            sorted_calls.append((X[o], c, None if b is None else np.asarray(b)[o], None if lo is None else lo[o]))
        calls = sorted_calls
    for method in ("fast", "exact", "fast", "exact"):
        t0 = time.perf_counter()
        for X, c, b, lo in calls:
            m._budget_costs(X, c, method, b, lo)
        out[method] = min(out.get(method, np.inf), (time.perf_counter() - t0) / n_loc * 1e3)
    return out


def classify(m, calls):
    """Object-frame queries of every third call and their class (see the module)."""
    import numba as nb

    from touchloc.models import _kernels as K

    w = m._weight(True)
    g = m._grid(w)
    P = np.concatenate([np.einsum("nji,nkj->nki", X[:, :3, :3], c.points[None] - X[:, None, :3, 3]).reshape(-1, 3)
                        for X, c, _, _ in calls[::3]])
    N = np.concatenate([np.einsum("nji,kj->nki", X[:, :3, :3], c.normals).reshape(-1, 3)
                        for X, c, _, _ in calls[::3]])
    level = np.full(len(P), -1)
    cell = np.full(len(P), -1)
    for lvl in range(len(g.h))[::-1]:  # finest last: the finest level that holds a query
        ijk = np.floor((P - g.lo[lvl]) / g.h[lvl]).astype(np.int64)
        ok = np.all((ijk >= 0) & (ijk < g.shape[lvl]), axis=1)
        level[ok] = lvl
        cell[ok] = g.base[lvl] + (ijk[ok, 0] * g.shape[lvl, 1] + ijk[ok, 1]) * g.shape[lvl, 2] + ijk[ok, 2]

    @nb.njit
    def listed(cells, cell, level, N, out):
        for q in range(len(cell)):
            if level[q] == 0 and cell[q] < cells.shape[0]:
                side, bit = K._cube_bin(N[q, 0], N[q, 1], N[q, 2])
                if side >= 0 and (cells[cell[q], side] >> np.uint64(bit)) & np.uint64(1):
                    out[q] = True

    near = np.zeros(len(P), bool)
    listed(g.near_cells, cell, level, N, near)
    classes = {"near list": near, "finest, general list": (level == 0) & ~near,
               "coarser level": level > 0, "outside (tree)": level < 0}
    return P, N, cell, classes, g, w


def per_query(m, g, w, P, N):
    """ns per query on each method: one identity pose, all the queries in one pass."""
    from touchloc.models import _kernels as K

    tree, eye = m.obj.bvh(w), np.eye(4)[None]
    P, N = np.ascontiguousarray(P), np.ascontiguousarray(N)
    out = {}
    for name, grid in (("fast", g), ("exact", None), ("fast", g), ("exact", None)):
        t0 = time.perf_counter()
        K.pose_costs(tree, eye, P, N, w, grid=grid)
        out[name] = min(out.get(name, np.inf), (time.perf_counter() - t0) / max(len(P), 1) * 1e9)
    return out


def study(name: str, k: int, seeds) -> None:
    from bench_speed import _trial, record_calls

    from touchloc.belief import PoseRegion, ScalingSeries
    from touchloc.data import load_object
    from touchloc.models import ProximityModel

    cube = PoseRegion.box((0, 0, 0), 0.2, "full")
    m = ProximityModel(load_object(name), 0.002, np.deg2rad(5))
    _, c = _trial(m.obj, cube, 30, 0)
    ScalingSeries(m, rng=0, progress=False).localize(c, cube)  # kernels compiled, grids built
    calls = record_calls(m, cube, k, seeds)
    plain, ordered = replay(m, calls, len(seeds)), replay(m, calls, len(seeds), order=True)
    print(f"\n{name}, {k} contacts: {len(calls) / len(seeds):.0f} calls a localisation")
    print(f"  replay ms: fast {plain['fast']:.1f}, exact {plain['exact']:.1f} ({plain['exact'] / plain['fast']:.2f}x);"
          f" poses in Morton order: fast {ordered['fast']:.1f}, exact {ordered['exact']:.1f}"
          f" ({ordered['exact'] / ordered['fast']:.2f}x)")
    P, N, cell, classes, g, w = classify(m, calls)
    print(f"  {len(P)} queries | class | share | fast ns | exact ns")
    for label, sel in classes.items():
        if sel.any():
            t = per_query(m, g, w, P[sel], N[sel])
            print(f"  | {label} | {sel.mean():.1%} | {t['fast']:.0f} | {t['exact']:.0f}")
    sel = classes["near list"]
    if sel.any():
        o = np.argsort(cell[sel], kind="stable")
        a, s = per_query(m, g, w, P[sel], N[sel]), per_query(m, g, w, P[sel][o], N[sel][o])
        print(f"  near-listed queries, fast ns: arrival order {a['fast']:.0f}, sorted by cell {s['fast']:.0f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["bread", "milk", "cereal", "lemon", "mug"])
    ap.add_argument("--contacts", nargs="+", type=int, default=[10, 30])
    ap.add_argument("--seeds", type=int, default=4, help="localisations recorded (seeds 1..N)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    for name in args.meshes:
        for k in args.contacts:
            study(name, k, range(1, args.seeds + 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
