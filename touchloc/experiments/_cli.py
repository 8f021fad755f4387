"""``touchloc sweep`` and ``touchloc report``."""

from __future__ import annotations

import time


def register(sub):
    p = sub.add_parser("sweep", help="run a grid of localisation trials (serial, processes or Dask)",
                       description="Run every trial of a sweep declared in a TOML file and append one row "
                                   "per trial to a CSV file as it finishes. Rerunning the same command "
                                   "skips the trials already in the file, so an interrupted sweep resumes.")
    p.add_argument("spec", help="sweep file (TOML): meshes, estimators, contacts, noise, modes, planners, seeds, ... "
                                "(kind = \"dnf\": sides, cells, sets, estimators, seed, revolutions); "
                                "or a bundled sweep's name (study600: 3 estimators x 4 meshes x 5 contact counts "
                                "x 10 seeds)")
    p.add_argument("-o", "--out", default="results.csv", help="results CSV (default results.csv)")
    p.add_argument("--executor", default="processes",
                   help="serial | processes (default, all cores) | dask (a LocalCluster) | dask://HOST:PORT")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--fresh", action="store_true", help="discard the results file instead of resuming")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_sweep_cmd)

    q = sub.add_parser("report", help="plots and a markdown table from a sweep's results",
                       description="Draw success and time against contacts per estimator and error CDFs "
                                   "(<stem>.png) and write a markdown table (<stem>.md); for a DNF sweep "
                                   "(kind = \"dnf\"), the right side count per cell and object, as tables "
                                   "and heat maps per estimator.")
    q.add_argument("results", help="results CSV written by touchloc sweep")
    q.add_argument("--out-dir", default=None, help="where to write (default: beside the results)")
    q.set_defaults(func=run_report_cmd)


def run_sweep_cmd(args) -> int:
    from pathlib import Path

    from . import Sweep, run_sweep
    from .runner import read_results

    sweep = Sweep.from_toml(args.spec)
    ids = {t["trial_id"] for t in sweep.trials()}
    n = len(ids)
    done = 0 if args.fresh or not Path(args.out).exists() else len(ids & {r["trial_id"] for r in read_results(args.out)})
    print(f"{n} trials -> {args.out} (executor {args.executor})"
          + (f"; {done} already there, {n - done} to run" if done else ""), flush=True)
    t0 = time.perf_counter()
    try:
        rows = run_sweep(sweep, args.out, executor_spec=args.executor, workers=args.workers,
                         progress=False if args.no_progress else None, resume=not args.fresh)
    except KeyboardInterrupt:
        from ..cli import interruption_handled

        interruption_handled()
        print(f"\ninterrupted: {len(read_results(args.out))} finished trials are in {args.out}; "
              "run the same command again to resume")
        return 130
    mine = [r for r in rows if r["trial_id"] in ids]
    ok = f"; {sum(r['success'] for r in mine)} succeeded" if mine and "success" in mine[0] else ""
    print(f"{len(mine)}/{n} trials in {args.out}{ok}; {time.perf_counter() - t0:.1f} s")
    return 0


def run_report_cmd(args) -> int:
    from .report import write_report

    md, png = write_report(args.results, args.out_dir)
    print(f"wrote {md} and {png}")
    return 0
