"""This checkout's localisation time against another commit's, trial by trial.

    python benchmarks/ab_speed.py REV [--trials N] [--contacts 10,30] [--meshes mug,milk,...]
                                      [--identify N] [--options JSON]

The speed benchmark's trials (``bench_speed.py``: the README quick-start path, 2 mm / 5 deg
contacts, pose uniform in a 400 mm cube) on two worker processes, one importing touchloc
from this checkout and one from ``git archive REV``. The two answer each trial in turn, in
alternating order, so that both see the same load on a shared machine; the ratio reported
is the median over trials of the per-trial ratio (REV / this checkout). Prints a Markdown
table; nothing is written to docs/. ``--identify N`` adds N identifications among the six
bundled objects from 10 contacts (the speed benchmark's, true object in turn), alternating in
the same way. ``--options '{"final_moves": 0}'`` passes keyword arguments to this checkout's
``ScalingSeries`` only (REV's keeps its defaults), e.g. to compare like with like where REV
lacks a stage.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import baseline_tree, table  # noqa: E402
from bench_speed import BALL, ROOT, _Worker, _ball_mesh  # noqa: E402


def _tail(t) -> str:
    """The 95th percentile of times ``t`` over their median, for a table cell."""
    return f"{np.percentile(t, 95) / np.median(t):.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", help="the commit to compare with (e.g. HEAD for the working tree's changes)")
    ap.add_argument("--trials", type=int, default=6)
    ap.add_argument("--contacts", default="10,30")
    ap.add_argument("--meshes", default="mug,milk,can,cereal",
                    help=f"bundled meshes, or {BALL!r} for the speed benchmark's near-spherical one")
    ap.add_argument("--threads", type=int, default=0, help="numba threads per worker (0: numba's default)")
    ap.add_argument("--identify", type=int, default=0, help="identification trials to add (0: none)")
    ap.add_argument("--options", default="{}", help="JSON keyword arguments for this checkout's ScalingSeries only")
    a = ap.parse_args(argv)
    ks = [int(k) for k in a.contacts.split(",")]
    options = json.loads(a.options)
    if not isinstance(options, dict):
        ap.error("--options must be a JSON object")
    meshes = a.meshes.split(",")
    threads = a.threads or None
    rows = []
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmpd:
        base_path = baseline_tree(a.rev, Path(tmpd) / "base")
        if base_path is None:
            print(f"no commit {a.rev!r} in this repository", file=sys.stderr)
            return 2
        ball = _ball_mesh(Path(tmpd) / "ball.obj") if BALL in meshes else None
        cur, base = _Worker(ROOT, threads), _Worker(base_path, threads)
        try:
            for mesh in meshes:
                for k in ks:
                    tb, tc, ok_b, ok_c = [], [], [], []
                    for s in range(a.trials):
                        seed = 5000 + 100 * k + s
                        first, second = (cur, base) if s % 2 == 0 else (base, cur)
                        name = ball if mesh == BALL else mesh
                        r1 = first.ask(mesh=name, k=k, seed=seed, **({"options": options} if first is cur else {}))
                        r2 = second.ask(mesh=name, k=k, seed=seed, **({"options": options} if second is cur else {}))
                        rc, rb = (r1, r2) if first is cur else (r2, r1)
                        tc.append(rc["time"])
                        tb.append(rb["time"])
                        ok_c.append(rc["adds"] < 0.005)
                        ok_b.append(rb["adds"] < 0.005)
                    tb, tc = np.array(tb), np.array(tc)
                    rows.append([mesh, k, a.trials, f"{np.median(tb):.3f}", f"{np.median(tc):.3f}",
                                 _tail(tc),
                                 f"{np.median(tb / tc):.2f}x", f"{sum(ok_b)}/{a.trials}", f"{sum(ok_c)}/{a.trials}"])
                    print(" | ".join(str(x) for x in rows[-1]), file=sys.stderr, flush=True)
            if a.identify:
                six = ["bread", "can", "cereal", "lemon", "milk", "mug"]
                tb, tc, ok_b, ok_c = [], [], [], []
                for s in range(a.identify):
                    first, second = (cur, base) if s % 2 == 0 else (base, cur)
                    req = dict(kind="identify", meshes=six, truth=six[s % 6], k=10, seed=300 + s)
                    r1, r2 = first.ask(**req), second.ask(**req)
                    rc, rb = (r1, r2) if first is cur else (r2, r1)
                    tc.append(rc["time"])
                    tb.append(rb["time"])
                    ok_c.append(rc["correct"])
                    ok_b.append(rb["correct"])
                tb, tc = np.array(tb), np.array(tc)
                rows.append(["identify (six objects)", 10, a.identify, f"{np.median(tb):.3f}", f"{np.median(tc):.3f}",
                             _tail(tc), f"{np.median(tb / tc):.2f}x", f"{sum(ok_b)}/{a.identify} right",
                             f"{sum(ok_c)}/{a.identify} right"])
                print(" | ".join(str(x) for x in rows[-1]), file=sys.stderr, flush=True)
        finally:
            cur.close()
            base.close()
    load.append(os.getloadavg()[0])
    print(f"Load average (1 min) before / after: {load[0]:.1f} / {load[1]:.1f} on {os.cpu_count()} cores; "
          f"threads: {threads or 'numba default'}.\n")
    print(table(["mesh", "contacts", "trials", f"{a.rev} median s", "this checkout median s",
                 "this checkout p95 / median", "speed-up (median of per-trial ratios)", f"{a.rev} ADD-S < 5 mm", "this checkout ADD-S < 5 mm"],
                rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
