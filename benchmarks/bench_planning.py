"""Active touch planning: touches needed to localise, and planning time."""

from __future__ import annotations

import json
import time
import warnings

import numpy as np

from _common import quiet_load, run_trials, table
from touchloc.experiments import Sweep
from touchloc.planners import OneStepPlanner, TwoStepPlanner, simulate
from touchloc.planners.scenarios import SETTINGS, make_scenario

TITLE = "Active touch planning"

MESHES = ["bread", "can", "cereal", "lemon", "milk", "mug", "bunny"]
GOAL = 0.005        # ADD-S (m) that counts as localised
CONFIDENCE = 0.003  # stop when the belief's expected ADD-S is below this (m)


def sweep(setting: str, n_poses: int, max_touches: int, n_particles: int, names) -> Sweep:
    """Every planner on the same hidden poses: ``n_poses`` spread over the meshes, in order."""
    meshes = MESHES[:n_poses] if n_poses < len(MESHES) else MESHES
    planners = [{"name": "two-step", "branch": 3} if n == "two-step" else n for n in names]
    return Sweep(meshes=meshes, modes=["active"], planners=planners, contacts=[max_touches],
                 seeds=max(1, n_poses // len(meshes)), region="planar" if setting == "planar" else "full",
                 loop={"n_particles": n_particles, "confidence": CONFIDENCE},
                 noise=[0.001], normal_noise=0.05, sigma_pos=0.002, sigma_nor=0.15, success=GOAL)


def _records(rows, sw: Sweep, names):
    """Per planner, one record per run (in the sweep's mesh and seed order)."""
    ids = {t["trial_id"] for t in sw.trials()}
    recs = {k: [] for k in names}
    for r in sorted((r for r in rows if r["trial_id"] in ids), key=lambda r: (r["seed"], MESHES.index(r["mesh"]))):
        m = json.loads(r["metrics"])
        recs[r["planner"]].append({"mesh": r["mesh"], "touches": r["touches"], "ok": m["confident"] and r["success"],
                                   "confident": m["confident"], "error": r["add_s"], "add": m["add"],
                                   "time": r["time"], "plan_time": r["plan_time"]})
    return recs


def _touch_table(setting, recs, max_touches):
    rows = []
    base = np.mean([r["touches"] for r in recs["random"]]) if "random" in recs else np.nan
    ref = np.array([r["touches"] for r in recs["one-step"]]) if "one-step" in recs else None
    for name, rs in recs.items():
        t = np.array([r["touches"] for r in rs])
        if ref is not None and name != "one-step":
            dd = t - ref
            paired = f"{dd.mean():+.1f} +- {dd.std(ddof=1) / np.sqrt(len(dd)):.1f}"
        else:
            paired = "-"
        ok = np.array([r["ok"] for r in rs])
        err = np.array([r["error"] for r in rs]) * 1e3
        add = np.array([r["add"] for r in rs]) * 1e3
        rows.append((setting, name, len(rs), f"{ok.mean() * 100:.0f} %", f"{t.mean():.1f}", f"{np.median(t):.0f}",
                     f"{t.mean() / base:.2f}", paired, f"{np.median(err):.2f}", f"{np.median(add):.1f}",
                     f"{np.mean([r['plan_time'] for r in rs]):.2f}", f"{np.mean([r['time'] for r in rs]):.1f}"))
    return rows


def _per_mesh(recs):
    meshes = [m for m in MESHES if any(r["mesh"] == m for r in recs["one-step"])]
    rows = []
    for m in meshes:
        row = [m]
        for name in recs:
            t = [r["touches"] for r in recs[name] if r["mesh"] == m]
            ok = [r["ok"] for r in recs[name] if r["mesh"] == m]
            row.append(f"{np.mean(t):.1f} ({sum(ok)}/{len(ok)})")
        one = [r for r in recs["one-step"] if r["mesh"] == m]
        row.append(f"{np.median([r['error'] for r in one]) * 1e3:.2f} / {np.median([r['add'] for r in one]) * 1e3:.1f}")
        rows.append(row)
    return rows


def _planning_time(quick):
    """One-step planning on 100 candidates x 1000 particles, and what it is made of."""
    sc = make_scenario(quiet_load("mug"), "planar", n_world=60, n_relative=40, seed=0)
    from touchloc.belief import ParticleBelief

    b = ParticleBelief(sc.region.sample(1000, rng=0), region=sc.region)
    cands = sc.candidates(b, 0)
    assert len(cands) == 100
    pl = OneStepPlanner(sc.model)
    pl.plan(b, cands, rng=0)
    reps = 3 if quick else 7
    ts, tsim = [], []
    for r in range(reps):
        p = pl.plan(b, cands, rng=r)
        ts.append(p.info["time"])
        tsim.append(p.info["time_simulate"])
    # baseline in the same run: the same scoring, one candidate per call
    t0 = time.perf_counter()
    k = 20
    for c in cands[:k]:
        pl.plan(b, [c], rng=0)
    per_cand = (time.perf_counter() - t0) / k
    t0 = time.perf_counter()
    simulate(sc.obj, b.poses, cands)
    t_rays = time.perf_counter() - t0
    two = TwoStepPlanner(sc.model, branch=3)
    t2 = [two.plan(b, cands, rng=r).info["time"] for r in range(2 if quick else 3)]
    rows = [
        ("one-step, 100 candidates x 1000 particles", f"{np.median(ts):.3f}", f"{np.min(ts):.3f}",
         f"{np.median(tsim):.3f}", f"{per_cand * 100 / np.median(ts):.1f}"),
        ("two-step (branch 3), 100 candidates x 1000 particles", f"{np.median(t2):.3f}", f"{np.min(t2):.3f}", "-", "-"),
    ]
    note = (f"Ray casting alone (100 x 1000 = 1e5 rays, one embreex call): {t_rays:.3f} s "
            f"({1e5 / t_rays / 1e6:.2f} M rays/s). Baseline: the same planner called once per candidate "
            f"({per_cand * 1e3:.1f} ms per candidate, i.e. {per_cand * 100:.2f} s for 100).")
    return table(["planning", "median (s)", "best (s)", "of which simulation (s)",
                  "speed-up vs one candidate per call"], rows), note


def run(quick: bool = False) -> str:
    warnings.simplefilter("ignore")
    n_poses = 4 if quick else 21
    max_touches = 15 if quick else 20
    names = ["random", "one-step", "two-step"]
    out = []
    rows, mesh_tables = [], []
    sweeps = {setting: sweep(setting, n_poses, max_touches, n_particles, names)
              for setting, n_particles in (("planar", 2000), ("6dof", 2000 if quick else 3000))}
    results, how = run_trials("planning", [t for sw in sweeps.values() for t in sw.trials()], quick)
    for setting, sw in sweeps.items():
        recs = _records(results, sw, names)
        rows += _touch_table(setting, recs, max_touches)
        mesh_tables.append((setting, _per_mesh(recs)))
    ptab, pnote = _planning_time(quick)
    if quick:
        out.append("**Quick run** (`--quick`: 4 hidden poses, at most 15 touches; a smoke test of the "
                   "benchmark, not its result).")
    out.append(
        f"Touches until the belief is confident (its expected ADD-S of the estimate < {CONFIDENCE * 1e3:.0f} mm), "
        f"at most {max_touches}; a run **localises** when it stops confident with a true ADD-S < "
        f"{GOAL * 1e3:.0f} mm (ADD-S to the surface: see `touchloc.belief.add_s`; ADD, the "
        f"plain mean point distance, is reported too but counts symmetric poses of the can, lemon and "
        f"boxes as errors). Hidden poses drawn uniformly from the region, the same number on each "
        f"mesh ({', '.join(MESHES)}; the first four in a quick run); every planner sees the same hidden poses and the same candidates "
        f"(60 world-fixed touches plus 40 aimed at the faces of the current estimate). Simulated sensor: "
        f"1 mm contact noise, 0.05 normal noise; belief: tempered SMC touch filter "
        f"(2000 particles planar, 3000 6-DOF), proximity model sigma 2 mm / 0.15; planners: one-step "
        f"entropy (6 canonical observations, 1000 particles), two-step (the 3 best first touches "
        f"expanded, 6 then 3 canonical observations), random choice among the same candidates. "
        f"Runs that never get "
        f"confident count as {max_touches} touches, so the ratios to random are conservative. "
        f"Settings: " + "; ".join(f"**{k}**: {v}" for k, v in SETTINGS.items()) + ". "
        f"Each run is one active trial of a sweep; times are per run on one core (pool workers run "
        f"the compiled kernels on one thread, all workers at once).")
    out.append(how)
    out.append(table(["setting", "planner", "runs", "localised", "touches (mean)", "touches (median)",
                      "touches / random", "minus one-step, same poses (mean +- s.e.)", "final ADD-S median (mm)", "final ADD median (mm)", "plan time per touch (s)",
                      "run time (s)"], rows))
    for setting, mrows in mesh_tables:
        out.append(f"Per mesh, {setting}: mean touches (localised runs / runs), and the one-step runs' "
                   f"final errors.")
        out.append(table(["mesh"] + names + ["one-step ADD-S / ADD median (mm)"], mrows))
    out.append("Planning time (mug, planar region, uniform belief of 1000 particles, 60 world + 40 relative "
               "candidates; in this process, after the sweep, with the kernels' default threads):")
    out.append(ptab)
    out.append(pnote)
    return "\n\n".join(out)
