"""Recognition by localisation: which bundled mesh explains a few contacts?

The trials are one sweep of identification trials (``touchloc.experiments``, mode
"identify"), run on the process pool; the table is drawn from the tidy rows.
"""

from __future__ import annotations

import json

import numpy as np

from _common import run_trials, table
from touchloc.experiments import Sweep

TITLE = "Identification by localisation (seed 001, 42.3.1)"

NAMES = ["bread", "can", "cereal", "lemon", "milk", "mug"]


def sweep(quick: bool) -> Sweep:
    """The true mesh x contact count x seed; every trial chooses among all six meshes."""
    return Sweep(meshes=NAMES[:2] if quick else NAMES, identities=NAMES, modes=["identify"],
                 contacts=[5, 10] if quick else [5, 10, 20], seeds=1 if quick else 4, half_extent=0.1,
                 noise=[0.002], normal_noise=float(np.radians(5.0)), sigma_pos=0.002, sigma_nor=0.1)


def run(quick: bool = False) -> str:
    sw = sweep(quick)
    rows, how = run_trials("identify", sw.trials(), quick)
    out, confusions = [], []
    for k in sw.contacts:
        g = [r for r in rows if r["contacts"] == k]
        m = [json.loads(r["metrics"]) for r in g]
        p_true = [x["p_true"] for x in m]
        out.append((k, len(g), f"{100 * np.mean([r['success'] for r in g]):.0f} %", f"{np.median(p_true):.3f}",
                    f"{np.min(p_true):.3f}", f"{np.median([r['time'] for r in g]):.1f}"))
        for r, x in sorted(zip(g, m), key=lambda rx: (NAMES.index(rx[0]["mesh"]), rx[0]["seed"])):
            if not r["success"]:
                best = x["best"] or "nothing (no candidate explains the contacts)"
                confusions.append(f"{k} contacts: {r['mesh']} taken for {best} (p = {x['p_best']:.2f})")
    text = [
        ("**Quick run** (`--quick`: two true meshes, one seed; a smoke test of the benchmark, not its result). "
         if quick else "")
        + f"Six candidate meshes ({', '.join(NAMES)}); the true one at a pose uniform in a 200 mm cube "
        "with uniform rotation; k contacts with 2 mm / 5 deg noise; `identify` (Scaling Series "
        "evidence per object, uniform prior; chance level 17 %). Each trial is one identification "
        "trial of a sweep; times are per trial on one core (pool workers run the compiled kernels "
        "on one thread, all workers at once).",
        how,
        table(("contacts", "trials", "correct", "median p(true)", "min p(true)", "median s (6 objects)"), out),
    ]
    if confusions:
        text.append("Mistakes: " + "; ".join(confusions) + ".")
    return "\n\n".join(text)
