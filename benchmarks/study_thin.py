"""Long pushed sessions with and without leaving out the contacts the map already predicts.

    python benchmarks/study_thin.py [--actions 200] [--thin 0 0.3 0.5] [--quick]
    python benchmarks/study_thin.py --static [--thin 0.5]

The SLAM benchmark's pushed world (2 mm / 2 deg per action, no odometry, a three-finger
hand, ``explore`` with ``TactileSLAM``), run for twice the benchmark's 100 actions with
``TactileSLAM(..., thin=t)`` for each ``t`` (passed to :class:`touchloc.mapping.ShapeMap`;
0 keeps every contact). The same world and seed for every ``t``, so the runs are paired
until the first contact left out. Development: milk, cereal, bread and mug, seeds 0-2 (the
settings were looked at on these); held out: can, lemon and bunny, seeds 7-8, and milk and
cereal with 2 mm / 10 deg contacts, seeds 7-8. CPU time of each ``TactileSLAM.update`` and of
the explorer's map queries for its candidates (``_ray_samples``), on two spawned
single-threaded workers. ``--static`` runs the mapping benchmark's static single-probe
worlds instead (``bench_mapping._setup``: mug, bunny, lemon and cereal, seeds 0-1, 200
touches of the uncertainty explorer). Prints Markdown tables; nothing is written to docs/
(docs/benchmarks.md, "Long sessions", quotes it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

PUSH = (0.002, np.deg2rad(2.0))
NOISE = (0.001, np.deg2rad(5.0))


def specs(quick: bool, thins) -> list:
    dev = [("development", m, s, NOISE) for m in (("milk", "mug") if quick else ("milk", "cereal", "bread", "mug"))
           for s in ((0,) if quick else (0, 1, 2))]
    held = [("held out: other meshes, seeds 7-8", m, s, NOISE)
            for m in (("can",) if quick else ("can", "lemon", "bunny")) for s in ((7,) if quick else (7, 8))]
    if not quick:
        held += [("held out: 2 mm / 10 deg contacts, seeds 7-8", m, s, (0.002, np.deg2rad(10.0)))
                 for m in ("milk", "cereal") for s in (7, 8)]
    return [(g, m, s, n, t) for g, m, s, n in dev + held for t in thins]


def one(spec, actions: int = 200) -> dict:
    """One pushed run: accuracy at 100 actions and at the end, and where the time went."""
    import contextlib
    import importlib
    import io
    import warnings

    warnings.simplefilter("ignore")
    from _common import quiet_load

    from touchloc.mapping import MovingWorld, TactileSLAM, chamfer_distance, explore, fscore

    group, mesh, seed, noise, thin = spec
    obj = quiet_load(mesh)
    lo, hi = obj.bounds
    world = MovingWorld(obj, rng=seed, noise_pos=noise[0], noise_nor=noise[1], push=PUSH)
    slam = TactileSLAM((lo - 0.03, hi + 0.03), rng=seed, sigma_pos=noise[0], sigma_nor=noise[1], thin=thin)
    upd, plan = [], []
    update, module = TactileSLAM.update, importlib.import_module("touchloc.mapping.explore")
    samples = module._ray_samples

    def timed_update(self, results, odometry=None):
        t0 = time.process_time()
        out = update(self, results, odometry)
        upd.append((self.map.n_contacts, time.process_time() - t0))
        return out

    def timed_samples(*a, **k):
        t0 = time.process_time()
        out = samples(*a, **k)
        plan.append(time.process_time() - t0)
        return out

    acc = {}

    def cb(run, step):
        if step["touch"] in (100, actions):
            m = run.map.to_mesh()
            drift = [np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(slam.trajectory[1:], world.trajectory[1:])]
            acc[step["touch"]] = (float(fscore(m, obj, 0.005, n=4000)), float(chamfer_distance(m, obj, n=4000)),
                                  float(np.median(drift)))

    TactileSLAM.update, module._ray_samples = timed_update, timed_samples
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            explore(world, (lo - 0.06, hi + 0.06), actions, slam=slam, fingers=3, rng=seed, callback=cb)
    finally:
        TactileSLAM.update, module._ray_samples = update, samples
    u = np.array(upd)
    late = u[:, 0] > 300
    return dict(group=group, mesh=mesh, seed=seed, thin=thin, acc=acc, update=float(u[:, 1].sum()),
                plan=float(np.sum(plan)), update_late=float(np.median(u[late, 1])) if late.any() else float("nan"),
                plan_late=float(np.median(plan[-30:])), rows=slam.map._gp.n, thinned=slam.map.thinned,
                contacts=slam.map.n_contacts)


def static(spec) -> dict:
    """One static single-probe mapping run of the mapping benchmark: accuracy at 100 and 200 touches."""
    import warnings

    warnings.simplefilter("ignore")
    import bench_mapping as B

    from touchloc.mapping import chamfer_distance, explore, fscore

    mesh, seed, thin = spec
    world, bounds, truth, _ = B._setup(B._object(mesh), seed)
    acc = {}

    def cb(run, step):
        if step["touch"] in (100, 200):
            m = run.map.to_mesh()
            acc[step["touch"]] = (float(chamfer_distance(m, truth, n=5000)), float(fscore(m, truth, 0.005, n=5000)))

    t0 = time.process_time()
    run = explore(world, bounds, 200, rng=seed, callback=cb, sigma_pos=0.001, sigma_nor=np.deg2rad(5.0), thin=thin)
    return [mesh, seed, thin, f"{run.map.thinned}/{run.map.n_contacts}", run.map._gp.n,
            f"{1000 * acc[100][0]:.2f} / {acc[100][1]:.3f}", f"{1000 * acc[200][0]:.2f} / {acc[200][1]:.3f}",
            f"{time.process_time() - t0:.1f}"]


def _one(spec):
    return one(spec[:-1], spec[-1])


def report(rows, thins, actions) -> str:
    from _common import table

    out = []
    for group in dict.fromkeys(r["group"] for r in rows):
        sel = [r for r in rows if r["group"] == group]
        base = {(r["mesh"], r["seed"]): r for r in sel if r["thin"] == 0}
        lines = []
        for t in thins:
            rr = [r for r in sel if r["thin"] == t]
            f100 = np.mean([r["acc"][100][0] for r in rr])
            f = np.array([r["acc"][actions][0] for r in rr])
            ch = np.mean([r["acc"][actions][1] for r in rr]) * 1000
            dr = np.median([r["acc"][actions][2] for r in rr]) * 1000
            ru = [base[(r["mesh"], r["seed"])]["update"] / r["update"] for r in rr if (r["mesh"], r["seed"]) in base]
            rp = [base[(r["mesh"], r["seed"])]["plan"] / r["plan"] for r in rr if (r["mesh"], r["seed"]) in base]
            lines.append([t, len(rr), f"{f100:.3f}", f"{f.mean():.3f} ({f.min():.3f})", f"{ch:.2f}", f"{dr:.2f}",
                          f"{np.mean([r['thinned'] / r['contacts'] for r in rr]):.0%}",
                          f"{np.median([r['rows'] for r in rr]):.0f}",
                          f"{1000 * np.median([r['update_late'] for r in rr]):.0f}",
                          f"{1000 * np.median([r['plan_late'] for r in rr]):.0f}",
                          f"{np.median(ru):.2f}x" if ru else "-", f"{np.median(rp):.2f}x" if rp else "-"])
        out.append(f"{group}:\n\n" + table(
            ["thin", "runs", "F@5mm at 100 actions, mean", f"F@5mm at {actions}, mean (lowest)",
             f"Chamfer at {actions}, mean (mm)", "drift, median (mm)", "contacts left out", "map rows at the end",
             "update beyond 300 contacts, median (ms)", "planning, last 30 actions, median (ms)",
             "update CPU, whole run, vs thin 0", "planning CPU vs thin 0"], lines))
    per = [[r["mesh"], r["seed"], r["thin"], f"{r['acc'][actions][0]:.3f}", f"{1000 * r['acc'][actions][1]:.2f}",
            f"{1000 * r['acc'][actions][2]:.2f}", f"{r['thinned']}/{r['contacts']}", f"{r['update']:.1f}",
            f"{r['plan']:.1f}"] for r in rows]
    out.append("Per run:\n\n" + table(["mesh", "seed", "thin", f"F@5mm at {actions}", "Chamfer (mm)", "drift (mm)",
                                        "left out", "update CPU (s)", "planning CPU (s)"], per))
    return "\n\n".join(out)


def main(argv=None) -> int:
    from _common import spawn_map

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--actions", type=int, default=200)
    ap.add_argument("--thin", type=float, nargs="+", default=[0.0, 0.3, 0.5])
    ap.add_argument("--quick", action="store_true", help="three worlds, 120 actions")
    ap.add_argument("--static", action="store_true", help="the mapping benchmark's static worlds instead")
    a = ap.parse_args(argv)
    if a.static:
        from _common import table

        thins = sorted(set(a.thin) | {0.0})
        rows = spawn_map(static, [(m, s, t) for m in ("mug", "bunny", "lemon", "cereal") for s in (0, 1)
                                  for t in thins])
        print(table(["mesh", "seed", "thin", "left out", "map rows", "Chamfer (mm) / F@5mm at 100 touches",
                     "at 200 touches", "CPU (s)"], rows))
        return 0
    actions = 120 if a.quick else a.actions
    thins = sorted(set(a.thin) | {0.0})
    t0 = time.time()
    rows = spawn_map(_one, [s + (actions,) for s in specs(a.quick, thins)])
    print(f"{len(rows)} runs of {actions} actions in {time.time() - t0:.0f} s wall\n")
    print(report(rows, thins, actions))
    return 0


if __name__ == "__main__":
    sys.exit(main())
