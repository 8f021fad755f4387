"""Where the in-hand mug's turn error is made: before the handle is first touched, or after.

    python benchmarks/study_inhand_handle.py [--seeds 15-34] [--mesh mug]

The in-hand world of the SLAM benchmark and of ``study_inhand_scale.py`` (15 deg turns about
z, an odometry 5 % too large, 96 three-finger actions, 1 mm / 5 deg contacts), with the
odometry's scale learned (the shipped default) and with the right scale held. A contact is
on the handle when it lies more than 4 mm outside the body's radius (41 mm) from the mug's
axis, in the object's true frame. For each run: the first action that touched the handle,
the orientation error there, and the growth of the benchmark's measure (median error in
turn 4 minus that in turn 1) split into the part made before that action (the error at the
first handle touch minus turn 1's) and the part made after (turn 4's minus the error at the
first handle touch). Before the handle is touched, nothing the fingers feel shows the turn
(the body is a solid of revolution), so the first part is the odometry's own drift. Two
worker processes, about five minutes on two cores. Prints a Markdown table; nothing is
written to docs/ (docs/slam.md, "What a known scale is worth", quotes it).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BODY_RADIUS, HANDLE_MARGIN = 0.041, 0.004
SETTINGS = (("learned from 1 (the default)", 1.0, 0.05), ("held at the right value, 1 / 1.05", 1 / 1.05, 0.0))


def _run(args):
    sys.path.insert(0, str(HERE))
    from study_inhand_scale import inhand_run

    _, world, _, run, ang, turns = inhand_run(*args)
    per = len(run.results) // len(ang)
    first = None
    for i in range(len(ang)):
        T = np.linalg.inv(world.trajectory[i])
        for r in run.results[i * per:(i + 1) * per]:
            if r.contact is None:
                continue
            p = r.contact.points @ T[:3, :3].T + T[:3, 3]
            if np.any(np.hypot(p[:, 0], p[:, 1]) > BODY_RADIUS + HANDLE_MARGIN):
                first = i
                break
        if first is not None:
            break
    e_h = float(ang[first]) if first is not None else float("nan")
    return dict(seed=args[1], first=first, e_first=e_h, turn1=turns[0], turn4=turns[3], growth=turns[3] - turns[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="15-34", help="a range a-b or a comma list (default 15-34)")
    ap.add_argument("--mesh", default="mug")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    from study_inhand_scale import _seeds

    seeds = _seeds(args.seeds)
    rows = []
    with ProcessPoolExecutor(2) as ex:
        for label, scale, sd in SETTINGS:
            res = list(ex.map(_run, [(args.mesh, s, scale, sd) for s in seeds]))
            first = np.array([np.nan if r["first"] is None else r["first"] + 1 for r in res], dtype=float)
            g = np.array([r["growth"] for r in res])
            before = np.array([r["e_first"] - r["turn1"] for r in res])
            after = np.array([r["turn4"] - r["e_first"] for r in res])
            print(f"{label}: " + "; ".join(f"seed {r['seed']}: handle at action {r['first'] + 1 if r['first'] is not None else '-'}"
                                          f", error there {r['e_first']:.1f}, turns 1/4 {r['turn1']:.1f}/{r['turn4']:.1f}"
                                          for r in res), file=sys.stderr, flush=True)
            rows.append(f"| {label} | {np.nanmedian(first):.0f} ({np.nanmin(first):.0f}-{np.nanmax(first):.0f}) | "
                        f"{np.nanmedian([r['e_first'] for r in res]):.1f} | {np.median(g):+.1f} | "
                        f"{np.nanmedian(before):+.1f} | {np.nanmedian(after):+.1f} | "
                        f"{np.sum(np.abs(after) <= 5)} / {np.sum(np.abs(g) <= 5)} of {len(g)} |")
    print(f"{args.mesh}, seeds {args.seeds}\n")
    print("| scale | first action touching the handle, median (range) | error there, median (deg) | growth turn 1 -> 4, "
          "median (deg) | ... made before the first handle touch | ... made after it | runs within 5 deg after it "
          "/ over the whole run |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
