"""The in-hand mug with its odometry learned online, known, or calibrated on a box.

    python benchmarks/study_inhand_scale.py [--seeds 15-34] [--mesh mug] [--settings 0,1,2,3,4]
        [--calibrate-on milk] [--turns 4]
        [--before | --without-feature-fit | --without-feature-turn | --without-seeking]
        [--turn-search-anywhere]

The SLAM benchmark's in-hand world (15 deg turns about z, an odometry 5 % too large, 96
three-finger actions, 1 mm / 5 deg contacts), run five ways on each seed:

0. the scale learned from 1 (``learn_odometry_scale=True``, the default prior of 5 %);
1. a calibration 1 % off the right value held (``odometry_scale=0.962``,
   ``odometry_scale_sd=0``);
2. the right value, 1 / 1.05, held;
3. the scale calibrated on a run of the milk carton (``--calibrate-on``) in the same world
   and seed (scale learned, as by default; ``TactileSLAM.calibrate_odometry``), then held;
4. the same with the calibration's turn noise held as well (``odometry_noise``); the other
   rows assume the benchmark's 1.5 deg per action.

Reports the growth of the orientation error from the first turn to the fourth (the
median error within each turn of 24 actions; the benchmark's measure), how many runs stay
within 5 and 10 degrees, the error in the fourth turn, how many runs stay within 10 degrees
in every turn, and F@5mm of the final map. ``--turns 8`` runs eight turns (192 actions)
instead of four: the growth is then from the first turn to the last, and the error is the
last turn's; whether an error that grew stops growing is what tells bounded from drifting.
A second table gives the error per turn of the online estimate (each action's pose as its
own update left it, before later touches revised it) beside the smoothed trajectory's.
``--without-feature-fit`` runs it without the scale fitted to where the handle's touches
agree (``TactileSLAM._FEATURE_SCALE`` off);
``--without-feature-turn`` without the turn from the handle's angle
(``TactileSLAM._FEATURE_TURN`` off, the estimator before it); ``--without-seeking``
without the explorer's value of meeting the handle where that filter expects it
(``TactileSLAM._FEATURE_SEEK`` off); ``--turn-search-anywhere`` with the turn search moving
the turn on any contact before that filter's first sighting, those well inside the body's
radius too (``TactileSLAM._TURN_INSIDE`` off);
``--before`` also without the corrections counted from the step whose surface they were
measured against, the scale's robust posterior and the re-anchoring (``_TURN_REF`` and
``_SCALE_MIXTURE`` off), in the same processes. Two worker processes; about fifteen
minutes for the five settings and twenty seeds on two cores. Prints Markdown tables; nothing
is written to docs/ (docs/benchmarks.md, "In-hand mug", and docs/slam.md, "What a known scale
is worth", quote it).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: the odometry's turn noise the estimator assumes unless calibrated (the SLAM benchmark's)
TURN_NOISE = float(np.deg2rad(1.5))

#: (label, scale, its prior sd, odometry turn noise in rad). A scale given as a mesh's name is
#: calibrated on that mesh's run of the same world and seed, then held; so is a turn noise
#: given as "calibrated"
SETTINGS = (("learned from 1 (`odometry_scale_sd=0.05`, the default)", 1.0, 0.05, TURN_NOISE),
            ("held at 0.962, 1 % off the right value", 0.962, 0.0, TURN_NOISE),
            ("held at 0.952, the right value", 1 / 1.05, 0.0, TURN_NOISE),
            ("scale calibrated on the milk carton's run of the same seed, then held", "milk", 0.0, TURN_NOISE),
            ("scale and turn noise calibrated on the milk carton's run of the same seed, then held", "milk", 0.0,
             "calibrated"))


def inhand_run(mesh, seed, scale, sd, turn_noise=TURN_NOISE, before=False, fit=True, record=None, feature_turn=True,
               seek=True, turns=4, inside=True):
    """One in-hand run of the benchmark's world: (object, world, slam, run, orientation
    error per action in degrees, median error per turn of 24 actions).

    ``record``, a list: each update appends a dict of its world contact points (``P``,
    (k, 3)), the odometry's turn about z (``turn``, rad), the true pose and the pose the
    estimator ends the update at (``truth``, ``est``)."""
    import contextlib
    import io
    import warnings

    warnings.simplefilter("ignore")
    sys.path.insert(0, str(HERE))
    from _common import quiet_load
    from scipy.spatial.transform import Rotation

    from touchloc.mapping import MovingWorld, TactileSLAM, explore

    obj = quiet_load(mesh)
    lo, hi = obj.bounds
    noise = (0.001, np.deg2rad(5.0))
    world = MovingWorld(obj, rng=seed, noise_pos=noise[0], noise_nor=noise[1], push=(0.0005, np.deg2rad(0.5)),
                        inhand=True, step=np.deg2rad(15.0), bias=0.05)
    if before:
        TactileSLAM._TURN_REF = TactileSLAM._SCALE_MIXTURE = False
    if before or not fit:
        TactileSLAM._FEATURE_SCALE = False
    if before or not feature_turn:
        TactileSLAM._FEATURE_TURN = False
    if not seek:
        TactileSLAM._FEATURE_SEEK = False
    if not inside:
        TactileSLAM._TURN_INSIDE = 0.0
    slam = TactileSLAM((lo - 0.03, hi + 0.03), rng=seed, sigma_pos=noise[0], sigma_nor=noise[1],
                       motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, turn_noise),
                       learn_odometry_scale=True, odometry_scale=scale, odometry_scale_sd=sd)
    if record is not None:
        update = slam.update

        def recorded(results, odometry=None):
            out = update(results, odometry=odometry)
            pts = [r.contact.points for r in results if r.hit]
            turn = 0.0 if odometry is None else float(Rotation.from_matrix(np.asarray(odometry)[:3, :3]).as_rotvec()[2])
            record.append(dict(P=np.vstack(pts) if pts else np.zeros((0, 3)), turn=turn,
                               truth=world.trajectory[-1].copy(), est=slam.pose.copy()))
            return out

        slam.update = recorded
    with contextlib.redirect_stderr(io.StringIO()):
        run = explore(world, (lo - 0.06, hi + 0.06), 24 * turns, slam=slam, fingers=3, rng=seed)
    ang = np.array([float(np.degrees(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).magnitude()))
                    for a, b in zip(slam.trajectory[1:], world.trajectory[1:])])
    per_turn = [float(np.median(ang[i * 24:(i + 1) * 24])) for i in range(turns)]
    return obj, world, slam, run, ang, per_turn


def _run(args) -> tuple:
    """(growth of the turn's error from the first turn to the last, deg; F@5mm; the
    scale held or started from; the turn noise assumed, rad; the median error per turn, deg;
    the same of the online estimate, each action's pose as its update left it)."""
    from scipy.spatial.transform import Rotation

    from touchloc.mapping import fscore

    mesh, seed, scale, sd, noise, before, fit, feature_turn, seek, n_turns, inside = args
    if isinstance(scale, str):
        # calibration: the same world on another mesh, with the scale learned as by default
        cal = inhand_run(scale, seed, 1.0, 0.05, before=before, fit=fit,
                         feature_turn=feature_turn, seek=seek, turns=n_turns,
                         inside=inside)[2].calibrate_odometry()
        scale = cal.scale
        if noise == "calibrated":
            noise = cal.turn_noise
    rec = []
    obj, _, _, run, _, turns = inhand_run(mesh, seed, scale, sd, noise, before, fit, feature_turn=feature_turn,
                                          seek=seek, turns=n_turns, record=rec, inside=inside)
    online = np.degrees([Rotation.from_matrix(r["est"][:3, :3] @ r["truth"][:3, :3].T).magnitude() for r in rec])
    return (turns[-1] - turns[0], float(fscore(run.map.to_mesh(), obj, 0.005, n=4000)), float(scale), float(noise),
            turns, [float(np.median(online[i * 24:(i + 1) * 24])) for i in range(n_turns)])


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b) + 1)) if b else [int(s) for s in text.split(",")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="15-34", help="a range a-b or a comma list (default 15-34)")
    ap.add_argument("--mesh", default="mug")
    ap.add_argument("--calibrate-on", default="milk", help="the mesh of the calibration runs (default milk)")
    ap.add_argument("--settings", default="0,1,2,3,4", help="which rows to run, a comma list of 0-4 (default all)")
    ap.add_argument("--turns", type=int, default=4, help="turns of 24 actions per run (default 4, the benchmark's)")
    ap.add_argument("--before", action="store_true",
                    help="the in-hand estimator before the feature fit, the anchored corrections and the scale's "
                         "robust posterior")
    ap.add_argument("--without-feature-fit", action="store_true",
                    help="the in-hand estimator without the scale fitted to where the handle's touches agree")
    ap.add_argument("--without-feature-turn", action="store_true",
                    help="the in-hand estimator without the turn from the feature's angle (_feature_turn)")
    ap.add_argument("--without-seeking", action="store_true",
                    help="the explorer without the value of meeting the feature where the filter expects it")
    ap.add_argument("--turn-search-anywhere", action="store_true",
                    help="the turn search moving the turn on any contact before the feature's first sighting")
    args = ap.parse_args(argv)
    if args.turns < 1:
        ap.error("--turns must be at least 1")
    seeds = _seeds(args.seeds)
    settings = [SETTINGS[int(i)] for i in args.settings.split(",")]
    if args.calibrate_on != "milk":
        settings = [(label.replace("the milk carton", f"the {args.calibrate_on}"), args.calibrate_on, sd, noise)
                    if isinstance(scale, str) else (label, scale, sd, noise) for label, scale, sd, noise in settings]
    rows, online = [], []
    with ProcessPoolExecutor(2) as ex:
        for label, scale, sd, noise in settings:
            res = list(ex.map(_run, [(args.mesh, s, scale, sd, noise, args.before, not args.without_feature_fit,
                                      not args.without_feature_turn, not args.without_seeking, args.turns,
                                      not args.turn_search_anywhere)
                                     for s in seeds]))
            g = np.array([r[0] for r in res])
            f = np.array([r[1] for r in res])
            t = np.array([r[4] for r in res])
            rows.append(f"| {label} | {np.median(g):+.1f} | {np.sum(np.abs(g) <= 5)} / {np.sum(np.abs(g) <= 10)} "
                        f"of {len(g)} | {np.percentile(g, 75):+.1f} / {g.max():+.1f} | "
                        f"{np.median(t[:, -1]):.1f} | "
                        f"{np.sum(t.max(axis=1) <= 10)} of {len(g)} | "
                        f"{np.median(f):.2f} ({f.min():.2f}-{f.max():.2f}) |")
            print(f"{label}: growth per seed {' / '.join(f'{v:+.1f}' for v in g)}", file=sys.stderr, flush=True)
            on = np.array([r[5] for r in res])
            online.append(f"| {label} | " + " / ".join(f"{v:.1f}" for v in np.median(t, axis=0)) + " | "
                          + " / ".join(f"{v:.1f}" for v in np.median(on, axis=0)) + " | "
                          + " / ".join(f"{v:.1f}" for v in np.percentile(on, 90, axis=0)) + " |")
            if args.turns != 4:
                for s, row in zip(seeds, t):
                    print(f"{label}: seed {s}, error per turn {' / '.join(f'{v:.1f}' for v in row)}", file=sys.stderr,
                          flush=True)
            if isinstance(scale, str):
                c = np.array([r[2] for r in res])
                t = np.degrees([r[3] for r in res])
                print(f"{label}: calibrated scales {np.median(c):.4f} ({c.min():.4f}-{c.max():.4f}), "
                      f"per seed {' / '.join(f'{v:.4f}' for v in c)}; turn noise (deg) {np.median(t):.2f} "
                      f"({t.min():.2f}-{t.max():.2f})", file=sys.stderr, flush=True)
    which = (" (the estimator before)" if args.before else
             " (without the feature fit)" if args.without_feature_fit else
             " (without the turn from the feature's angle)" if args.without_feature_turn else
             " (without seeking the feature)" if args.without_seeking else
             " (the turn search on any contact before the feature is seen)" if args.turn_search_anywhere else "")
    print(f"{args.mesh}, seeds {args.seeds}, {args.turns} turns{which}\n")
    print(f"| scale | median growth, turn 1 -> {args.turns} (deg) | runs within 5 / 10 deg | "
          f"75th percentile / worst (deg) | error in turn {args.turns}, median (deg) | "
          "runs within 10 deg in every turn | F@5mm, median (range) |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    # the trajectory above is the smoothed one, each pose revised by what later touches showed;
    # a controller holding the object has only the pose each update ends at
    print("\nThe orientation error per turn (deg), the trajectory as the run ended (smoothed) against each "
          "action's pose as its own update left it (online)\n")
    print("| scale | smoothed, median | online, median | online, 90th percentile |")
    print("|---|---|---|---|")
    print("\n".join(online))
    return 0


if __name__ == "__main__":
    sys.exit(main())
