"""The fast likelihood's finest cell on small meshes: build, memory, accuracy and time.

``ProximityModel``'s default finest cell is a 24th of the mesh's largest extent, but at
least ``GRID_CELL_SIGMAS`` (1.5) times ``sigma_pos`` (up to an 8th of the extent). This
study builds the fast grid of each mesh with the finest cell at ``f * sigma_pos`` (within
the same bounds) for several ``f`` (0: a 24th of the extent, the rule before the floor; a
factor below that rule leaves it) and reports, per mesh and cell:

* the grid's build time with the on-disk cache off, and the near lists' memory (cell
  records, packed entries and long lists) and the general lists';
* the near lists' own check (share answered, share off by more than 0.1 d_M^2);
* the error of ``fast`` against ``exact`` on 3000 poses within about 2 mm / 0.02 rad
  ('close') and 1 cm / 0.1 rad ('near') of the truth at 30 contacts: the share of pairs
  off by more than 0.1 d_M^2 and the largest error;
* the time of the likelihood calls that whole localisations make (three seeds each at 10
  and 30 contacts, recorded with the default cell, replayed with each grid, the fastest of
  three interleaved passes).

The lemon and the bread are the bundled meshes that the floor changes (the rule was set
on them); ``capsule``, ``pebble``, ``box`` and ``cone`` are small shapes made here, held
out. ``--sigma`` sets ``sigma_pos`` (m).

    cd benchmarks
    ../.venv/bin/python study_grid_cell.py --meshes lemon bread capsule pebble box cone \
        --factors 0 1.25 1.5 2
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def shape(name: str):
    """A bundled mesh, or one of the study's held-out small shapes."""
    import trimesh

    from touchloc.data import load_object
    from touchloc.models import MeshObject

    if name == "capsule":  # 60 mm long, 30 mm wide
        return MeshObject(trimesh.creation.capsule(height=0.03, radius=0.015, count=[24, 24]), name=name)
    if name == "box":  # 40 x 30 x 20 mm
        return MeshObject(trimesh.creation.box((0.04, 0.03, 0.02)), name=name)
    if name == "pebble":  # a smooth, lopsided 52 x 40 x 32 mm pebble of 1280 faces
        m = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
        u = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
        m.vertices = u * 0.02 * (1 + 0.15 * u[:, 0] ** 2 - 0.1 * u[:, 2])[:, None] * np.array([1.3, 1.0, 0.8])
        return MeshObject(m, name=name)
    if name == "cone":  # 50 mm across, 50 mm high, 48 sections
        return MeshObject(trimesh.creation.cone(radius=0.025, height=0.05, sections=48), name=name)
    return load_object(name)


def study(name: str, factors, sigma: float):
    from bench_localization import trial

    from touchloc.belief import PoseRegion, ScalingSeries
    from touchloc.models import ProximityModel

    cube = PoseRegion.box((0, 0, 0), 0.2, "full")
    obj = shape(name)
    ext = float(obj.extents.max())
    grids = []
    for f in factors:
        cell = max(ext / 24.0, min(f * sigma, ext / 8.0))  # as the default rule does
        if any(abs(cell - g[1].grid_cell) < 1e-12 for g in grids):
            continue
        m = ProximityModel(obj, sigma, np.deg2rad(5), grid_cell=cell)
        t0 = time.perf_counter()
        g = m._grid(m._weight(True))
        build = time.perf_counter() - t0
        grids.append((f, m, g, build))
    # unbudgeted queries near the truth
    true, c = trial(obj, cube, 30, 1)
    region = cube.with_rho(obj.radius)
    rng = np.random.default_rng(5)
    sets = {lab: region.perturb(np.repeat(true[None], 3000, axis=0), sc, rng=rng, ball=False)
            for lab, sc in (("close", 0.002), ("near", 0.01))}
    exact = {lab: grids[0][1].contact_costs(X, c, method="exact") for lab, X in sets.items()}
    # the calls of whole localisations, recorded with the default cell
    ref = ProximityModel(obj, sigma, np.deg2rad(5))
    calls, costs = [], ref._budget_costs

    def recorded(X, contacts, method=None, budget=None, lower=None):
        calls.append((X.copy(), contacts, budget, lower))
        return costs(X, contacts, method, budget, lower)

    ref._budget_costs = recorded
    try:
        for k in (10, 30):
            for s in range(3):
                _, cc = trial(obj, cube, k, 5000 + 100 * k + s)
                ScalingSeries(ref, rng=s, progress=False).localize(cc, cube)
    finally:
        del ref._budget_costs
    for _, m, _, _ in grids:  # kernels compiled before timing
        X, cc, b, lo = calls[-1]
        m._budget_costs(X, cc, "fast", b, lo)
    spent = {id(m): np.inf for _, m, _, _ in grids}
    for _ in range(3):
        for _, m, _, _ in grids:
            t0 = time.perf_counter()
            for X, cc, b, lo in calls:
                m._budget_costs(X, cc, "fast", b, lo)
            spent[id(m)] = min(spent[id(m)], time.perf_counter() - t0)
    rows = []
    base = spent[id(grids[0][1])]
    for f, m, g, build in grids:
        near_mb = (g.near_cells.nbytes + g.near_entries.nbytes + g.near_ids.nbytes) / 1e6
        err = []
        for lab, X in sets.items():
            e = m.contact_costs(X, c, method="fast") - exact[lab]
            err += [f"{100 * np.mean(e > 0.1):.3f} %", f"{e.max():.2g}"]
        rows.append([name, len(obj.triangles), f"{f:g}" if f else "extent / 24", f"{1e3 * m.grid_cell:.2f}",
                     f"{build:.1f}", f"{near_mb:.1f}", f"{g.ids.nbytes / 1e6:.1f}",
                     f"{g.near_check[0]:.3f} / {100 * g.near_check[1]:.2f} %", *err,
                     f"{1e3 * spent[id(m)]:.0f}", f"{base / spent[id(m)]:.2f}x"])
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["lemon", "bread", "capsule", "pebble", "box", "cone"])
    ap.add_argument("--factors", nargs="+", type=float, default=[0.0, 1.25, 1.5, 2.0])
    ap.add_argument("--sigma", type=float, default=0.002, help="sigma_pos (m)")
    a = ap.parse_args(argv)
    os.environ["TOUCHLOC_CACHE_DIR"] = "off"  # every build timed from scratch
    warnings.simplefilter("ignore")
    from _common import table

    from touchloc.models import ProximityModel

    # the builders' kernels loaded before the first build is timed
    warm = ProximityModel(shape("box"), a.sigma, np.deg2rad(5), grid_cell=0.01)
    warm._grid(warm._weight(True))
    rows = []
    for name in a.meshes:
        rows += study(name, a.factors, a.sigma)
        print(" | ".join(str(x) for x in rows[-1]), file=sys.stderr, flush=True)
    print(f"sigma_pos {1e3 * a.sigma:g} mm, normals 5 deg; cache off; two threads.\n")
    print(table(["mesh", "faces", "finest cell (x sigma_pos)", "cell mm", "build s", "near lists MB",
                 "general lists MB", "check: answered / off", "close: off > 0.1", "close: max",
                 "near: off > 0.1", "near: max", "localisations' calls ms", "vs extent / 24"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
