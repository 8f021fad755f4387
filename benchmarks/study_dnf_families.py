"""How far one cell of the DNF sweep moves from one family of held-out data sets to the next.

The benchmark judges each cell on families of 32 data sets (seeds ``[31, ...]`` and
``[41, ...]``). A family's mean has a spread of its own, so a cell near the goal's 90 %
can pass in one family and fail in the next. This study runs the full DNF (defaults, and
optionally with parameters changed: ``NAME=VALUE``) on more families, ``[SEED, cell,
object, i]`` for i < 32, and prints each family's right count, the pooled mean over all
of them and its 95 % bootstrap interval (over data sets). The figures are in docs/dnf_rounds.md
("Twenty-first round").

    cd benchmarks
    ../.venv/bin/python study_dnf_families.py --cell noise=6 --object 8-gon --seeds 51 61 71 81
    ../.venv/bin/python study_dnf_families.py --cell noise=6 --object 8-gon --seeds 51 61 \\
        --set memory_decay_sides=0
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dnf import _cell_kwargs, sweep_cells  # noqa: E402
from study_dnf_probes import CELLS  # noqa: E402

OBJECTS = {"4-gon": 4, "5-gon": 5, "6-gon": 6, "8-gon": 8, "round": 0}


def _one(job):
    seed, ci, obj, i, params = job
    from touchloc.dnf import OrientationTracker, generate_rotation_dataset
    from touchloc.dnf.compare import run_estimator

    rng = np.random.default_rng([seed, ci, list(OBJECTS).index(obj), i])
    ds = generate_rotation_dataset(OBJECTS[obj], revolutions=4.0, rng=rng, **_cell_kwargs(sweep_cells()[ci]))
    return run_estimator("dnf", lambda: OrientationTracker(**params), ds).accuracy


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", default="noise=6", choices=list(CELLS))
    ap.add_argument("--object", default="8-gon", choices=list(OBJECTS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[51, 61, 71, 81])
    ap.add_argument("--sets", type=int, default=32, help="data sets per family")
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", help="tracker parameters to change")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    params = {k: float(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    ci = CELLS[args.cell][0]
    jobs = [(s, ci, args.object, i, params) for s in args.seeds for i in range(args.sets)]
    with ProcessPoolExecutor(args.workers) as ex:
        acc = np.array(list(ex.map(_one, jobs))).reshape(len(args.seeds), args.sets)
    print(f"{args.cell}, {args.object}, {params or 'defaults'}: right count per family of {args.sets}")
    for s, a in zip(args.seeds, acc):
        print(f"  seeds [{s}, ...]: {100 * a.mean():5.1f} %  ({(a >= 0.9).sum()} sets >= 90 %, "
              f"{(a < 0.6).sum()} below 60 %)")
    flat = acc.ravel()
    boot = np.random.default_rng(0).choice(flat, (4000, flat.size)).mean(axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    print(f"  pooled over {flat.size}: {100 * flat.mean():.1f} % (95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
