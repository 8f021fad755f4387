"""``touchloc map``: map a hidden simulated object from touch alone, then show and save the map."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import ValidationError


def register(sub):
    p = sub.add_parser("map", help="map a hidden simulated object from touch alone (plot, HTML view, mesh file)")
    from ..cli import add_mesh_argument

    add_mesh_argument(p, default="can", help_extra="; the hidden object (default: can)")
    p.add_argument("--touches", type=int, default=50, help="number of guarded touches (default 50)")
    p.add_argument("--planner", default="uncertainty", choices=["uncertainty", "random", "lattice"])
    p.add_argument("--method", default="gpis", choices=["gpis", "occupancy"])
    p.add_argument("--noise-pos", type=float, default=1.0, help="contact position noise (mm, default 1)")
    p.add_argument("--noise-nor", type=float, default=5.0, help="contact normal noise (deg, default 5)")
    p.add_argument("--margin", type=float, default=20.0,
                   help="the map's box is the object's box grown by this (mm, default 20)")
    p.add_argument("--moving", default="none", choices=["none", "push", "inhand"],
                   help="the object moves while touched: 'push' (2 mm / 2 deg per action, on a table) or "
                        "'inhand' (15 deg turns about z with 5 %% odometry bias); mapped by tactile SLAM")
    p.add_argument("--odometry-scale", default=None, metavar="SCALE|learn",
                   help="with --moving inhand: the scale on the hand's reported turns. A number is a calibration "
                        "held fixed (the right one for the simulated bias is 0.952), with the turn of an object "
                        "that only a small feature shows estimated apart; 'learn' (the default) learns it online "
                        "from 1 (see docs/slam.md, 'What a known scale is worth')")
    p.add_argument("--calibrate-on", default=None, metavar="MESH",
                   help="with --moving inhand: first turn MESH (a box, whose touches show every turn; e.g. milk) "
                        "in the same simulated hand for as many touches with the scale learned, read the "
                        "odometry's scale off its trajectory (TactileSLAM.calibrate_odometry) and hold it while "
                        "mapping --mesh: for a mug, more reliable than learning the scale on it (docs/slam.md, "
                        "'Calibrating on a box, in practice')")
    p.add_argument("--odometry-noise", type=float, default=1.5, metavar="DEG",
                   help="with --moving inhand: the standard deviation of each reported turn's error once scaled "
                        "(deg, default 1.5); an in-hand run ends by printing the value its own turns imply")
    p.add_argument("--fingers", type=int, default=1, help="fingers closing at once per action (default 1)")
    p.add_argument("--thin", type=float, default=0.0, metavar="K",
                   help="leave out of the GPIS the contacts it already predicts (deviation below K times the "
                        "position noise): cheaper long sessions; default 0, every contact (ShapeMap's thin)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", default=None, help="write a PNG of the map beside the true object")
    p.add_argument("--html", default=None, help="write a rotating 3-D HTML view of the map")
    p.add_argument("--save", default=None, help="write the map's mesh (any format trimesh writes: .obj, .ply, .stl)")
    p.add_argument("--save-map", default=None, help="write the map itself (.npz, reloadable with ShapeMap.load)")
    p.set_defaults(func=run)


def _slam(bounds, args, **motion):
    """The command's TactileSLAM over ``bounds``, at the contacts' noise given on the command line."""
    import numpy as np

    from .slam import TactileSLAM

    return TactileSLAM(bounds, sigma_pos=max(args.noise_pos * 1e-3, 1e-4),
                       sigma_nor=max(np.deg2rad(args.noise_nor), 1e-3), rng=args.seed, thin=args.thin, **motion)


def _calibrate(box, world, args, motion, pad):
    """The odometry's calibration read off ``box`` turned in ``world`` for ``args.touches``
    actions with the scale learned (``TactileSLAM.calibrate_odometry``); printed."""
    import contextlib
    import io

    from .explore import explore

    lo, hi = box.bounds
    slam = _slam((lo - pad, hi + pad), args, learn_odometry_scale=True, **motion)
    print(f"calibrating the hand's odometry on {box.name}: {args.touches} turns with the scale learned ...", flush=True)
    with contextlib.redirect_stderr(io.StringIO()):
        explore(world, (lo - pad - 0.03, hi + pad + 0.03), args.touches, planner=args.planner, rng=args.seed,
                slam=slam, fingers=args.fingers)
    try:
        cal = slam.calibrate_odometry()
    except ValidationError as exc:
        raise ValidationError(f"--calibrate-on {args.calibrate_on}: {exc}") from None
    print(f"  the trajectory implies a scale of {cal.scale:.3f} +- {cal.scale_sd:.3f} ({cal.updates} turns; right for "
          f"the simulated hand: {1 / 1.05:.3f}); held while mapping")
    return cal


def run(args) -> int:
    import numpy as np
    from scipy.spatial.transform import Rotation

    from ..models import MeshObject
    from ..planners import SimulatedWorld
    from .._validate import as_float
    from .explore import explore
    from .shape_map import _THIN_MAX
    from .metrics import chamfer_distance, fscore

    from ..cli import load_mesh

    obj = load_mesh(args.mesh, args.scale)
    rng = np.random.default_rng(args.seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()
    T[:3, 3] = rng.uniform(-0.02, 0.02, 3)
    truth = MeshObject(obj.mesh.copy().apply_transform(T), name=f"{obj.name} (true)", check_units=False)
    lo, hi = truth.bounds
    pad = args.margin * 1e-3
    bounds = (lo - pad, hi + pad)
    noise = dict(noise_pos=args.noise_pos * 1e-3, noise_nor=np.deg2rad(args.noise_nor))
    slam = None
    if args.odometry_scale is not None and args.moving != "inhand":
        raise ValidationError("--odometry-scale needs --moving inhand (only in-hand turns come with an odometry)")
    if args.calibrate_on is not None and args.moving != "inhand":
        raise ValidationError("--calibrate-on needs --moving inhand (only in-hand turns come with an odometry)")
    if args.calibrate_on is not None and args.odometry_scale is not None:
        raise ValidationError("give --calibrate-on or --odometry-scale, not both: each sets the scale to hold")
    if not (np.isfinite(args.odometry_noise) and 0.0 < args.odometry_noise <= 90.0):
        raise ValidationError(f"--odometry-noise must be in (0, 90] deg, got {args.odometry_noise!r}")
    # checked before the run starts, as ShapeMap would check it after the header
    as_float(args.thin, "--thin", low=0.0, high=_THIN_MAX)
    if args.moving == "none":
        world = SimulatedWorld(obj, T, rng=args.seed + 1, **noise)
    else:
        from .world import MovingWorld

        if args.moving == "push":
            world = MovingWorld(obj, T, push=(0.002, np.deg2rad(2.0)), planar=True, rng=args.seed + 1, **noise)
            motion = dict(planar=True)
        else:
            def hand(o, pose, seed):
                """The simulated hand turning ``o``: 15 deg an action, reported 5 % too large."""
                return MovingWorld(o, pose, push=(0.0005, np.deg2rad(0.5)), inhand=True, step=np.deg2rad(15.0),
                                   bias=0.05, rng=seed, **noise)

            world = hand(obj, T, args.seed + 1)
            motion = dict(motion=(0.0005, np.deg2rad(0.5)), odometry_noise=(0.0005, np.deg2rad(args.odometry_noise)))
            if args.calibrate_on is not None:
                box = load_mesh(args.calibrate_on, args.scale)
                cal = _calibrate(box, hand(box, np.eye(4), args.seed + 2), args, motion, pad)
                motion.update(learn_odometry_scale=True, odometry_scale=cal.scale, odometry_scale_sd=0.0)
            elif args.odometry_scale in (None, "learn"):
                # the simulated hand reports its turns 5 % too large: learn the scale unless given
                motion.update(learn_odometry_scale=True)
            elif args.odometry_scale is not None:
                try:
                    scale = float(args.odometry_scale)
                except ValueError:
                    raise ValidationError(f"--odometry-scale must be a number or 'learn', got {args.odometry_scale!r}") \
                        from None
                motion.update(learn_odometry_scale=True, odometry_scale=scale, odometry_scale_sd=0.0)
        # the object frame is the world frame at the start: the truth to compare with is the start
        slam = _slam(bounds, args, **motion)
        bounds = (bounds[0] - 0.03, bounds[1] + 0.03)
    print(f"{obj}\nhidden in the box {np.round(bounds[0] * 1e3, 1).tolist()} .. {np.round(bounds[1] * 1e3, 1).tolist()} mm; "
          f"{args.touches} touches, planner {args.planner}, map {args.method}")
    checkpoints = sorted({k for k in (5, 10, 20, 30, 50, 75, 100, 150, 200, 300) if k < args.touches} | {args.touches})
    history = []

    def report(run_, step):
        if step["touch"] in checkpoints:
            try:
                m = run_.map.to_mesh()
                c, f = chamfer_distance(m, truth, n=4000), fscore(m, truth, 0.005, n=4000)
            except Exception as exc:  # noqa: BLE001 - a map without surface yet
                print(f"  touch {step['touch']:>4}: {step['contacts']:>4} contacts; no mesh yet ({exc})")
                return
            history.append((step["touch"], c, f))
            print(f"  touch {step['touch']:>4}: {step['contacts']:>4} contacts; Chamfer {c * 1e3:6.2f} mm, "
                  f"F-score@5mm {f:.3f}; update {step['update_time'] * 1e3:.0f} ms", flush=True)

    t0 = time.perf_counter()
    kw = {} if slam is not None else dict(method=args.method, sigma_pos=max(args.noise_pos * 1e-3, 1e-4),
                                           sigma_nor=max(np.deg2rad(args.noise_nor), 1e-3), thin=args.thin)
    res = explore(world, bounds, args.touches, planner=args.planner, rng=args.seed, callback=report, slam=slam,
                  fingers=args.fingers, **kw)
    dt = time.perf_counter() - t0
    stats = ""
    if history:
        stats = f"final Chamfer {history[-1][1] * 1e3:.2f} mm, F-score@5mm {history[-1][2]:.3f}"
    print(f"\n{res.touches} touches, {res.map.n_contacts} contacts in {dt:.1f} s; {stats}")
    if slam is not None and len(slam.trajectory) > 1:
        # SLAM poses map the map's frame (the world at the start) to the world: the mesh's
        # own frame is at X @ T for the hidden start pose T
        from ..belief import symmetric_pose_error

        est = [X @ T for X in slam.trajectory[1:]]
        sym = obj.symmetries()
        err = np.array([symmetric_pose_error(obj, a, b, symmetry=sym) for a, b in zip(est, world.trajectory[1:])])
        tra, rot = 1e3 * err[:, 0], np.degrees(err[:, 1])
        line = (f"pose error over the run (modulo the object's symmetry): rotation median {np.median(rot):.1f} deg "
                f"(last action {rot[-1]:.1f}), translation median {np.median(tra):.1f} mm")
        if args.moving == "inhand" and len(rot) >= 24:
            line += "; rotation per turn of 24 actions (median) " + " / ".join(
                f"{np.median(rot[i:i + 24]):.1f}" for i in range(0, len(rot) - 23, 24)) + " deg"
        print(line)
    cal = None
    if args.moving == "inhand":
        # what this run's trajectory implies of the odometry: on an object whose touches show
        # the turn (a box) it is the calibration to hold for one that rarely does (a mug)
        try:
            cal = slam.calibrate_odometry()
        except ValidationError as exc:   # too short a run, or turns the touches did not show
            print(f"no odometry calibration from this run: {str(exc).split(': ', 1)[-1]}")
    if args.moving == "inhand" and slam.odometry_scale_sd > 0.0:
        print(f"the odometry's scale learned on this run: {slam.odometry_scale:.3f} (right for the simulated hand: "
              f"{1 / 1.05:.3f})" + ("; it never left its prior: too few touches showed the turn, and "
                                     "--calibrate-on milk reads the scale off a box first"
                                     if abs(slam.odometry_scale - 1.0) < 1e-3 else ""))
    if cal is not None:
        print(f"the estimated turns imply an odometry scale of {cal.scale:.3f} +- {cal.scale_sd:.3f} and a turn "
              f"noise of {np.degrees(cal.turn_noise):.2f} deg; to hold them on another object: "
              f"--odometry-scale {cal.scale:.3f} --odometry-noise {np.degrees(cal.turn_noise):.2f}")
    title = f"{obj.name}: {args.method} map, {args.planner} touches" + (f"; {stats}" if stats else "")
    if args.plot:
        from .viz import plot_map

        print(f"wrote {plot_map(args.plot, res, truth, title=title, history=history or None)}")
    if args.plot and slam is not None:
        from .viz import plot_trajectory

        tp = Path(args.plot)
        tpath = tp.with_name(tp.stem + "_trajectory" + tp.suffix)
        print(f"wrote {plot_trajectory(tpath, est, world.trajectory[1:], obj=obj, title=title)}")
    if args.html:
        from .viz import write_map_html

        print(f"wrote {write_map_html(args.html, res, truth, title=title, stats=stats)}")
    if args.save:
        mesh = res.map.to_mesh()
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        mesh.mesh.export(args.save)
        print(f"wrote {args.save} ({len(mesh.mesh.faces)} faces, world frame, metres)")
    if args.save_map:
        print(f"wrote {res.map.save(args.save_map)}")
    return 0
