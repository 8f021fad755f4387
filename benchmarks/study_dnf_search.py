"""Is there one parameter set of the DNF tracker that passes every cell of the sweep?

Earlier rounds (docs/dnf_rounds.md) moved the tracker's parameters one or two at a time and kept
nothing that held on a second group of data sets. This study moves them *jointly*: it draws
random parameter sets around the defaults and scores each on the development seeds
``[11, cell, object, set]`` (neither the sweep's ``[2, ...]`` nor the held-out ``[3, ...]``
seeds of ``bench_dnf.py``), every data set the same for every parameter set (paired).

Stage 1 scores each parameter set on the objects that fail (6-gon, 8-gon, round) in all 13
cells, data sets 0-7. Stage 2 runs the best ``--confirm`` of them and the defaults on all
five objects and all cells, data sets 8-23, which stage 1 did not see. The score is the mean
over (cell, object) of ``min(right count, 0.9)``: a cell above the goal gains nothing by
rising further, so the score rewards lifting the failing ones. A cell passes when every
object in it reaches 90 %.

``--ascent 1,2`` then runs steps along the steepest ascent of a linear fit of the stage-1
scores on the parameters' moves (:func:`sensitivity`) on the confirmation sets too.

    cd benchmarks
    ../.venv/bin/python study_dnf_search.py --configs 11 --confirm 0 --out wide.json
    ../.venv/bin/python study_dnf_search.py --configs 40 --confirm 4 --scale 0.25 --seed 1 \
        --ascent 1,2 --out quarter.json

The results are written as JSON after every parameter set (``--out``), and a rerun with the
same file skips what is already there (so the ascent can be added later). The figures are
in docs/dnf_rounds.md ("Fifth round"). The second command takes about 50 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dnf import _SWEEP_OBJECTS, sweep_cells  # noqa: E402
from study_dnf_probes import _sets, dev_dataset, second_half_counts  # noqa: E402

#: the parameters moved, how, and how far: "x" multiplies the default by a log-uniform
#: factor in [lo, hi]; "+" adds a uniform amount in [lo, hi]. A dotted name is a field of a
#: field's FieldParams.
SPACE = [
    ("input_gain", "x", 0.75, 1.35),
    ("noise_ref", "x", 0.8, 1.25),
    ("surface.h", "+", -1.0, 1.0),
    ("map.h", "+", -1.0, 1.0),
    ("map.c_inh", "x", 0.6, 1.6),
    ("map.sigma_inh", "x", 0.8, 1.5),
    ("hand.h", "+", -1.0, 1.0),
    ("surface_to_map", "x", 0.75, 1.35),
    ("hand_to_map", "x", 0.6, 1.6),
    ("match_to_map", "x", 0.6, 1.6),
    ("memory_build", "x", 0.6, 1.6),
    ("memory_decay", "x", 0.6, 1.5),
    ("match_width", "x", 0.75, 1.35),
    ("memory_to_match", "x", 0.8, 1.25),
    ("error_window", "x", 0.75, 1.35),
    ("correction_gain", "x", 0.6, 1.6),
    ("rate_prior", "x", 0.5, 3.0),
]
OBJECTS = [o for o, _ in _SWEEP_OBJECTS]
FAILING = ["6-gon", "8-gon", "round"]
CELLS = sweep_cells()


def _default(name: str) -> float:
    """The default of a parameter of SPACE (``"map.h"``: the map field's ``h``)."""
    from touchloc.dnf import TrackerParams

    field, _, sub = name.partition(".")
    d = TrackerParams()
    return getattr(getattr(d, field), sub) if sub else getattr(d, field)


def _unit(how: str, lo: float, hi: float) -> float:
    """A parameter's unit move: the top of its range (log of the factor, or the amount
    added), whichever end is farther."""
    return max(abs(np.log(lo)), abs(np.log(hi))) if how == "x" else max(abs(lo), abs(hi))


def draw(rng, scale: float = 1.0) -> dict:
    """One random parameter set: {name: value} over SPACE, its ranges shrunk by ``scale``
    (the log of a factor's range, or an added range, times ``scale``)."""
    out = {}
    for name, how, lo, hi in SPACE:
        base = _default(name)
        if how == "x":
            out[name] = float(base * np.exp(scale * rng.uniform(np.log(lo), np.log(hi))))
        else:
            out[name] = float(base + scale * rng.uniform(lo, hi))
    return out


def moved(moves: dict, scale: float) -> dict:
    """The parameter set that moves each named parameter by ``moves[name]`` units, a unit
    being the top of its range in SPACE times ``scale`` (as in :func:`sensitivity`)."""
    out = {}
    for name, how, lo, hi in SPACE:
        if name not in moves:
            continue
        base = _default(name)
        step = moves[name] * scale * _unit(how, lo, hi)
        out[name] = float(base * np.exp(step) if how == "x" else base + step)
    return out


def tracker_kwargs(values: dict) -> dict:
    """OrientationTracker keyword arguments for a parameter set (dotted names folded into
    their FieldParams)."""
    from touchloc.dnf import TrackerParams

    d = TrackerParams()
    kw, fields = {}, {}
    for name, v in values.items():
        if "." in name:
            f, p = name.split(".")
            fields.setdefault(f, {})[p] = v
        else:
            kw[name] = v
    for f, ps in fields.items():
        kw[f] = replace(getattr(d, f), **ps)
    return kw


def _one(job):
    import warnings

    warnings.simplefilter("ignore")
    values, ci, obj, s = job
    ds = dev_dataset(ci, obj, s)
    return float(np.mean(second_half_counts(ds, **tracker_kwargs(values)) == ds.n_surfaces))


def evaluate(ex, values, objects, sets, one=_one) -> dict:
    """Right count per (cell, object), the mean over the data sets; ``one((values, cell,
    object, set))`` scores one data set (default: a parameter set's tracker)."""
    keys = [(ci, o, s) for ci in range(len(CELLS)) for o in objects for s in sets]
    right = list(ex.map(one, [(values, *k) for k in keys], chunksize=2))
    table = {}
    for (ci, o, s), r in zip(keys, right):
        table.setdefault(f"{ci}|{o}", []).append(r)
    return {k: float(np.mean(v)) for k, v in table.items()}


def summary(table: dict) -> dict:
    vals = np.array(list(table.values()))
    cells = sum(all(table[k] >= 0.9 for k in table if k.split("|")[0] == str(ci))
                for ci in range(len(CELLS)))
    eight = [v for k, v in table.items() if k.endswith("|8-gon")]
    return {"score": float(np.mean(np.minimum(vals, 0.9))), "mean": float(vals.mean()), "cells": int(cells),
            "8-gon": float(np.mean(eight)) if eight else float("nan")}


def sensitivity(stage1: list, scale: float) -> list[tuple]:
    """Least-squares slopes of the stage-1 score on each parameter's move, the move expressed
    as a fraction of its range in SPACE (-1 .. 1 around the default, times ``scale``): the
    change of the score from the default to the top of the parameter's range. Returns
    ``(name, slope, standard error)``, steepest first."""
    rows, y = [], []
    for r in stage1[1:]:
        u = []
        for name, how, lo, hi in SPACE:
            base, v = _default(name), r["values"][name]
            step = np.log(v / base) if how == "x" else v - base
            u.append(step / (scale * _unit(how, lo, hi)))
        rows.append([1.0] + u)
        y.append(r["score"])
    X, y = np.array(rows), np.array(y)
    if len(y) <= X.shape[1]:
        return []
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    s2 = resid @ resid / (len(y) - X.shape[1])
    se = np.sqrt(np.diag(s2 * np.linalg.pinv(X.T @ X)))
    out = [(name, float(c), float(e)) for (name, *_), c, e in zip(SPACE, coef[1:], se[1:])]
    return sorted(out, key=lambda t: -abs(t[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=60, help="random parameter sets in stage 1 (besides the defaults)")
    ap.add_argument("--confirm", type=int, default=4, help="best parameter sets of stage 1 run in stage 2")
    ap.add_argument("--search-sets", default="0-7")
    ap.add_argument("--confirm-sets", default="8-23")
    ap.add_argument("--seed", type=int, default=0, help="seed of the parameter draws")
    ap.add_argument("--scale", type=float, default=1.0, help="shrink the ranges of SPACE by this factor")
    ap.add_argument("--ascent", default="",
                    help="steps along the stage-1 fit's steepest ascent to run on the confirmation sets, "
                         "in units of the ranges (e.g. 0.5,1,2); only slopes of at least 1.5 standard errors")
    ap.add_argument("--out", default="dnf_search.json")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    a = ap.parse_args(argv)
    out = Path(a.out)
    state = json.loads(out.read_text()) if out.exists() else {"stage1": [], "stage2": []}
    rng = np.random.default_rng(a.seed)
    configs = [{}] + [draw(rng, a.scale) for _ in range(a.configs)]
    search_sets, confirm_sets = _sets(a.search_sets), _sets(a.confirm_sets)
    with ProcessPoolExecutor(a.workers) as ex:
        for i, values in enumerate(configs):
            if i < len(state["stage1"]):
                continue
            t0 = time.perf_counter()
            table = evaluate(ex, values, FAILING, search_sets)
            state["stage1"].append({"values": values, "table": table, **summary(table)})
            out.write_text(json.dumps(state, indent=1))
            r = state["stage1"][-1]
            print(f"stage 1, set {i:3d}: score {r['score']:.4f}  cells {r['cells']:2d}  mean {r['mean']:.3f}  "
                  f"8-gon {r['8-gon']:.3f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
        ranked = sorted(range(1, len(state["stage1"])), key=lambda j: -state["stage1"][j]["score"])
        chosen = [0] + ranked[:a.confirm]
        done = {r["index"] for r in state["stage2"]}
        for j in chosen:
            if j in done:
                continue
            t0 = time.perf_counter()
            table = evaluate(ex, state["stage1"][j]["values"], OBJECTS, confirm_sets)
            state["stage2"].append({"index": j, "table": table, **summary(table)})
            out.write_text(json.dumps(state, indent=1))
            r = state["stage2"][-1]
            print(f"stage 2, set {j:3d}: score {r['score']:.4f}  cells {r['cells']:2d}  mean {r['mean']:.3f}  "
                  f"8-gon {r['8-gon']:.3f}  (stage 1: {state['stage1'][j]['score']:.4f}; "
                  f"{time.perf_counter() - t0:.0f} s)", flush=True)
    slopes = sensitivity(state["stage1"], a.scale)
    if a.ascent and slopes:
        sig = {n: c for n, c, e in slopes if abs(c) >= 1.5 * e}
        norm = max(abs(c) for c in sig.values())
        state.setdefault("ascent", [])
        with ProcessPoolExecutor(a.workers) as ex:
            for step in (float(x) for x in a.ascent.split(",")):
                if any(r["step"] == step for r in state["ascent"]):
                    continue
                values = moved({n: step * c / norm for n, c in sig.items()}, a.scale)
                t0 = time.perf_counter()
                table = evaluate(ex, values, OBJECTS, confirm_sets)
                state["ascent"].append({"step": step, "values": values, "table": table, **summary(table)})
                out.write_text(json.dumps(state, indent=1))
                r = state["ascent"][-1]
                print(f"ascent, step {step:g}: score {r['score']:.4f}  cells {r['cells']:2d}  mean {r['mean']:.3f}  "
                      f"8-gon {r['8-gon']:.3f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    if slopes:
        print("\nStage 1 score against each parameter's move (linear fit, the move -1 .. 1 across its range):")
        for name, c, e in slopes:
            print(f"  {name:16s} {c:+.4f} +- {e:.4f}")
    print("\n| parameter set | stage 1 score, cells (sets " + a.search_sets + ") | stage 2 score, cells, mean, "
          "8-gon (sets " + a.confirm_sets + ") |")
    print("|---|---|---|")
    for r in state["stage2"]:
        s1 = state["stage1"][r["index"]]
        name = "defaults" if r["index"] == 0 else f"#{r['index']}"
        print(f"| {name} | {s1['score']:.4f}, {s1['cells']} | {r['score']:.4f}, {r['cells']}, {r['mean']:.3f}, "
              f"{r['8-gon']:.3f} |")
    for r in state.get("ascent", []):
        print(f"| ascent, step {r['step']:g} | - | {r['score']:.4f}, {r['cells']}, {r['mean']:.3f}, {r['8-gon']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
