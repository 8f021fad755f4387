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
OLD_CONFIDENCE = 0.003  # the previous rule: the belief's expected ADD-S below 3 mm


def runs(setting, n, max_touches, n_particles, rules):
    """Run every rule on the same hidden poses; {rule: list of records}."""
    scen = {m: make_scenario(quiet_load(m), setting, seed=0) for m in MESHES}
    out = {r: [] for r in rules}
    for i in range(n):
        mesh = MESHES[i % len(MESHES)]
        sc = scen[mesh]
        true = sc.hidden_pose(rng=5000 + i)
        for rule in rules:
            kw = {"confidence": OLD_CONFIDENCE} if rule == "old" else {"stop_error": STOP_ERROR,
                                                                     "stop_probability": STOP_P}
            world = SimulatedWorld(sc.obj, true, rng=6000 + i)
            t0 = time.perf_counter()
            res = active_localization(world, sc.model, sc.region, OneStepPlanner(sc.model), sc.candidates,
                                      n_particles=n_particles, max_touches=max_touches, rng=7000 + i, **kw)
            out[rule].append({"mesh": mesh, "touches": res.touches, "confident": res.confident,
                              "error": res.error, "claim": res.steps[-1].p_within,
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
            f"{np.median(t):.0f}", f"{t.mean():.1f}",
            f"{np.median([r['error'] for r in conf]) * 1e3:.2f}" if conf else "-",
            f"{np.mean([r['time'] for r in rs]):.1f}")


def run(quick: bool = False) -> str:
    warnings.simplefilter("ignore")
    n_planar, n_6dof = (7, 7) if quick else (63, 42)
    n_old = 3 if quick else 21       # the old rule, on the first poses only (baseline for touches)
    max_touches = 20
    rows, all_new = [], []
    for setting, n, n_particles in (("planar", n_planar, 2000), ("6dof", n_6dof, 3000)):
        new = runs(setting, n, max_touches, n_particles, ["new"])["new"]
        old = runs(setting, n_old, max_touches, n_particles, ["old"])["old"]
        all_new += new
        rows.append(_row(setting, f"P(ADD-S < {STOP_ERROR * 1e3:.0f} mm) >= {STOP_P}", new))
        rows.append(_row(setting, f"same, first {n_old} poses", new[:n_old]))
        rows.append(_row(setting, f"before: expected ADD-S < {OLD_CONFIDENCE * 1e3:.0f} mm, first {n_old} poses",
                         old))
    rows.append(_row("both", f"P(ADD-S < {STOP_ERROR * 1e3:.0f} mm) >= {STOP_P}", all_new))
    text = (
        f"The active loop (`touchloc.planners.active_localization`, one-step planner, default SMCFilter "
        f"updater: 2000 particles planar, 3000 6-DOF) stops when the belief claims "
        f"P(ADD-S(estimate, truth) < {STOP_ERROR * 1e3:.0f} mm) >= {STOP_P} "
        f"(`touchloc.planners.prob_error_below`), at most {max_touches} touches. A stop is **confident but "
        f"wrong** when the true ADD-S is >= {STOP_ERROR * 1e3:.0f} mm. Hidden poses uniform over the region "
        f"(scenarios of `touchloc.planners.make_scenario`), cycling through {', '.join(MESHES)}; simulated "
        f"sensor 1 mm / 0.05 noise, model 2 mm / 0.15. The rule before (stop when the belief's expected "
        f"ADD-S < {OLD_CONFIDENCE * 1e3:.0f} mm) ran on the first poses of each setting, in the same run, as "
        f"the baseline for the number of touches. '95 % bound': with no wrong stop among n confident ones, "
        f"the rate is below 1 - 0.05^(1/n) with 95 % confidence.")
    return text + "\n\n" + table(["setting", "rule", "runs", "confident stops", "wrong", "wrong / stops",
                                  "95 % bound", "touches (median)", "touches (mean)",
                                  "ADD-S of confident stops, median (mm)", "s per run"], rows)
