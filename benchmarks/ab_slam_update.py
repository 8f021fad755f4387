"""This checkout's TactileSLAM update time against another commit's, run by run.

    python benchmarks/ab_slam_update.py REV [--rounds N] [--quick]

The run of "Update time as the map grows" (``bench_slam.py``: one pushed run of the milk
carton, three fingers, 200 actions, CPU time of each ``TactileSLAM.update`` in a child
process with single-threaded BLAS), for this checkout and for ``git archive REV``, in
alternating order for ``--rounds`` rounds so that both see the same load on a shared
machine. Where the two versions take the same touches (a change that keeps the results),
the updates are paired and the ratio is the median over updates of REV / this checkout;
otherwise only the medians per bin are comparable. The updates that ran a smoothing
round (the tail of the distribution) are also paired apart; so is the explorer's planning
before each update (wall clock). Prints Markdown tables; nothing is written to docs/.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import table  # noqa: E402
from bench_slam import _timing_child  # noqa: E402

BINS = ((0, 100), (100, 200), (200, 400), (400, 600))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", help="the commit to compare with")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="100 actions instead of 200")
    a = ap.parse_args(argv)
    cur, base = [], []
    for r in range(a.rounds):
        order = ((cur, None), (base, a.rev)) if r % 2 == 0 else ((base, a.rev), (cur, None))
        for out, rev in order:
            got = _timing_child(a.quick, rev)
            if got is None:
                print(f"no commit {a.rev!r} in this repository", file=sys.stderr)
                return 2
            out.append(got[3])   # three fingers: (contacts after each update, CPU s, smoother runs, smoothed, plan s)
    same = all(np.array_equal(c[0], b[0]) for c in cur for b in base)
    rows = []
    for lo, hi in BINS:
        meds_c, meds_b, ratios, p95_c, p95_b = [], [], [], [], []
        for c, b in zip(cur, base):
            cc, tc = np.array(c[0]), np.array(c[1])
            bc, tb = np.array(b[0]), np.array(b[1])
            sc, sb = (cc > lo) & (cc <= hi), (bc > lo) & (bc <= hi)
            if not (np.any(sc) and np.any(sb)):
                continue
            meds_c.append(np.median(tc[sc]) * 1e3)
            meds_b.append(np.median(tb[sb]) * 1e3)
            p95_c.append(np.percentile(tc[sc], 95) * 1e3)
            p95_b.append(np.percentile(tb[sb], 95) * 1e3)
            if same:
                ratios.append(np.median(tb[sb] / tc[sc]))
        if meds_c:
            rows.append([f"{lo + 1}-{hi}", " / ".join(f"{m:.0f}" for m in meds_b),
                         " / ".join(f"{m:.0f}" for m in meds_c),
                         " / ".join(f"{m:.0f}" for m in p95_b), " / ".join(f"{m:.0f}" for m in p95_c),
                         " / ".join(f"{x:.2f}x" for x in ratios) if same else "(other touches)"])
    # the updates that ran a smoothing round (the same schedule in both versions): the tail
    if same:
        for lo, hi in ((0, 200), (200, 600)):
            meds_c, meds_b, ratios = [], [], []
            for c, b in zip(cur, base):
                cc, tc, sm = np.array(c[0]), np.array(c[1]), np.array(c[3], bool)
                tb = np.array(b[1])
                sel = sm & (cc > lo) & (cc <= hi)
                if np.any(sel):
                    meds_c.append(np.median(tc[sel]) * 1e3)
                    meds_b.append(np.median(tb[sel]) * 1e3)
                    ratios.append(np.median(tb[sel] / tc[sel]))
            if meds_c:
                rows.append([f"smoothing updates, {lo + 1}-{hi} ({int(np.sum(sel))})",
                             " / ".join(f"{m:.0f}" for m in meds_b), " / ".join(f"{m:.0f}" for m in meds_c),
                             "", "", " / ".join(f"{x:.2f}x" for x in ratios)])
    print(f"Three-finger pushed milk carton, {a.rounds} rounds, load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores at the end; the two versions took {'the same' if same else 'other'} touches.\n")
    print(table(["contacts in the map", f"{a.rev} median (ms), per round", "this checkout median (ms), per round",
                 f"{a.rev} p95 (ms)", "this checkout p95 (ms)", "paired ratio per round"], rows))
    if all(len(r) > 4 for r in cur + base):
        print("\nThe explorer's planning before each update (wall clock, the same runs):\n")
        print(table(["contacts in the map", f"{a.rev} median (ms), per round", "this checkout median (ms), per round",
                     "paired ratio per round"], _plan_rows(cur, base, same)))
    return 0


def _plan_rows(cur, base, same):
    """Rows of the planning table: per bin of the map's contacts, medians per round and,
    where the versions took the same touches, the median paired ratio."""
    rows = []
    for lo, hi in BINS:
        meds_c, meds_b, ratios = [], [], []
        for c, b in zip(cur, base):
            cc, pc, bc, pb = np.array(c[0]), np.array(c[4]), np.array(b[0]), np.array(b[4])
            sc, sb = (cc > lo) & (cc <= hi), (bc > lo) & (bc <= hi)
            if np.any(sc) and np.any(sb):
                meds_c.append(np.median(pc[sc]) * 1e3)
                meds_b.append(np.median(pb[sb]) * 1e3)
                if same:
                    ratios.append(np.median(pb[sb] / pc[sc]))
        if meds_c:
            rows.append([f"{lo + 1}-{hi}", " / ".join(f"{m:.0f}" for m in meds_b),
                         " / ".join(f"{m:.0f}" for m in meds_c),
                         " / ".join(f"{x:.2f}x" for x in ratios) if same else "(other touches)"])
    return rows


if __name__ == "__main__":
    sys.exit(main())
