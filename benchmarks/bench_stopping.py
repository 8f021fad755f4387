"""The active loop's stopping rule as a calibrated claim: how often is a confident stop wrong?"""

from __future__ import annotations

import time
import warnings

import numpy as np

from _common import quiet_load, table
from touchloc.planners import OneStepPlanner
from touchloc.planners.loop import SimulatedWorld, active_localization
from touchloc.planners.scenarios import make_scenario

TITLE = "Active loop: stopping rule, confident-but-wrong"

MESHES = ["bread", "can", "cereal", "lemon", "milk", "mug", "bunny"]
STOP_ERROR = 0.005     # ADD-S (m) the claim is about
STOP_P = 0.95
# measured at commit 666723a with the same hidden poses and seeds (the previous run of this
# section): SMC tempering capped at 8 steps with 3 fixed-size moves, no second opinion
BEFORE = {"planar": (63, 0, 3), "6dof": (42, 2, 4), "both": (105, 2, 3)}   # runs, wrong stops, median touches


def runs(setting, n, max_touches, n_particles, rules):
    """Run every rule on the same hidden poses; {rule: list of records}."""
    scen = {m: make_scenario(quiet_load(m), setting, seed=0) for m in MESHES}
    out = {r: [] for r in rules}
    for i in range(n):
        mesh = MESHES[i % len(MESHES)]
        sc = scen[mesh]
        true = sc.hidden_pose(rng=5000 + i)
        for rule in rules:
            kw = {"stop_error": STOP_ERROR, "stop_probability": STOP_P, "verify_stop": rule != "unverified"}
            world = SimulatedWorld(sc.obj, true, rng=6000 + i)
            t0 = time.perf_counter()
            res = active_localization(world, sc.model, sc.region, OneStepPlanner(sc.model), sc.candidates,
                                      n_particles=n_particles, max_touches=max_touches, rng=7000 + i, **kw)
            out[rule].append({"mesh": mesh, "touches": res.touches, "confident": res.confident,
                              "error": res.error, "claim": res.steps[-1].p_within,
                              "vetoed": sum(s.verified and s.p_within < STOP_P for s in res.steps),
                              "time": time.perf_counter() - t0})
    return out


def _row(setting, name, rs):
    conf = [r for r in rs if r["confident"]]
    wrong = [r for r in conf if r["error"] >= STOP_ERROR]
    t = np.array([r["touches"] for r in rs])
    n_c = max(len(conf), 1)
    upper = 1 - 0.05 ** (1 / n_c) if not wrong else np.nan  # one-sided 95 % bound with 0 events
    bound = f"{100 * upper:.1f} %" if not wrong else "-"
    return (setting, name, len(rs), len(conf), len(wrong), f"{100 * len(wrong) / n_c:.1f} %", bound,
            sum(r.get("vetoed", 0) for r in rs), f"{np.median(t):.0f}", f"{t.mean():.1f}",
            f"{np.median([r['error'] for r in conf]) * 1e3:.2f}" if conf else "-",
            f"{np.mean([r['time'] for r in rs]):.1f}")


def run(quick: bool = False) -> str:
    warnings.simplefilter("ignore")
    n_planar, n_6dof = (7, 7) if quick else (63, 56)
    n_old = 3 if quick else 21       # the rule without the second opinion, on the first poses only
    max_touches = 20
    rows, all_new = [], []
    claim = f"P(ADD-S < {STOP_ERROR * 1e3:.0f} mm) >= {STOP_P}"
    for setting, n, n_particles in (("planar", n_planar, 2000), ("6dof", n_6dof, 3000)):
        new = runs(setting, n, max_touches, n_particles, ["new"])["new"]
        old = runs(setting, n_old, max_touches, n_particles, ["unverified"])["unverified"]
        all_new += new
        rows.append(_row(setting, f"{claim}, second opinion", new))
        rows.append(_row(setting, f"same, first {n_old} poses", new[:n_old]))
        rows.append(_row(setting, f"{claim}, no second opinion, first {n_old} poses", old))
    rows.append(_row("both", f"{claim}, second opinion", all_new))
    before = "; ".join(f"{k}: {r} runs, {w} wrong ({100 * w / r:.1f} %), median {m} touches"
                       for k, (r, w, m) in BEFORE.items())
    text = (
        f"The active loop (`touchloc.planners.active_localization`, one-step planner, default SMCFilter "
        f"updater: 2000 particles planar, 3000 6-DOF) stops when the belief claims "
        f"P(ADD-S(estimate, truth) < {STOP_ERROR * 1e3:.0f} mm) >= {STOP_P} "
        f"(`touchloc.planners.prob_error_below`), at most {max_touches} touches. Before it stops it asks for a "
        f"second opinion (`verify_stop=True`, `SMCFilter.second_opinion`): an independent run from the prior "
        f"on every touch so far, pooled with the belief by evidence; it stops only if the claim still holds. "
        f"'vetoed': confident claims the second opinion overturned (the run then went on touching). A stop is "
        f"**confident but wrong** when the true ADD-S is >= {STOP_ERROR * 1e3:.0f} mm. Hidden poses uniform "
        f"over the region (scenarios of `touchloc.planners.make_scenario`), cycling through "
        f"{', '.join(MESHES)}; simulated sensor 1 mm / 0.05 noise, model 2 mm / 0.15. None of these poses, "
        f"seeds or meshes were used to tune the filter (its settings were chosen on the calibration "
        f"benchmark's development seeds). The rule without the second opinion ran on the first poses of "
        f"each setting in the same run. '95 % bound': with no wrong stop among n confident ones, the rate is "
        f"below 1 - 0.05^(1/n) with 95 % confidence. Before this change (commit 666723a: tempering capped at "
        f"8 steps with 3 fixed-size moves, no second opinion; the same hidden poses and seeds, previous run "
        f"of this section): {before}.")
    return text + "\n\n" + table(["setting", "rule", "runs", "confident stops", "wrong", "wrong / stops",
                                  "95 % bound", "vetoed", "touches (median)", "touches (mean)",
                                  "ADD-S of confident stops, median (mm)", "s per run"], rows)
