"""``touchloc active``: the active-localisation loop on a mesh file or a bundled mesh, with options."""

from __future__ import annotations

import time
from pathlib import Path

PLANNERS = ("one-step", "two-step", "random", "kl")


def add_arguments(p, *, mesh="cereal", max_touches=20, particles=2000, confidence=None):
    from ..cli import add_mesh_argument

    add_mesh_argument(p, default=mesh, help_extra=f"; default {mesh}")
    p.add_argument("--setting", default="planar", choices=["planar", "6dof"],
                   help="planar: x, y, yaw in a 100 mm square; 6dof: 60 mm cube, any rotation")
    p.add_argument("--planner", default="one-step", choices=PLANNERS)
    p.add_argument("--beta", type=float, default=0.0, help="cost weight (nats per metre of travel)")
    p.add_argument("--candidates", type=int, default=100, help="candidate touches per step (world + relative)")
    p.add_argument("--hands", type=int, default=0, help="also offer this many three-finger hand closings")
    p.add_argument("--particles", type=int, default=particles)
    p.add_argument("--max-touches", type=int, default=max_touches)
    p.add_argument("--stop-error", type=float, default=5.0,
                   help="stop when the belief gives its estimate an error below this (mm; default 5) ...")
    p.add_argument("--stop-probability", type=float, default=0.95,
                   help="... with at least this probability (default 0.95)")
    p.add_argument("--stop-metric", default="add_s", choices=["add_s", "pose"],
                   help="error of that claim: ADD-S, or the pose metric modulo symmetry (sees a mug's handle)")
    p.add_argument("--no-verify-stop", dest="verify_stop", action="store_false",
                   help="stop on the claim without first checking it against a second, independent run")
    p.add_argument("--confidence", type=float, default=confidence,
                   help="the older rule instead: stop when the belief's expected ADD-S is below this (mm)"
                        + (f"; default {confidence}" if confidence is not None else ""))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out", help="directory for the plot and the HTML view ('' for none)")
    p.add_argument("--name", default="active", help="file stem of the outputs")


def register(sub):
    p = sub.add_parser("active", help="active touch localisation in simulation of a mesh file or bundled mesh (planner, loop, plots)")
    add_arguments(p)
    p.set_defaults(func=run)


def make_planner(name, model, beta=0.0):
    from . import OneStepPlanner, RandomPlanner, TwoStepPlanner

    if name == "one-step":
        return OneStepPlanner(model, beta=beta)
    if name == "kl":
        return OneStepPlanner(model, utility="kl", beta=beta)
    if name == "two-step":
        return TwoStepPlanner(model, beta=beta, branch=3)
    return RandomPlanner(model)


def run(args) -> int:
    import numpy as np

    from .loop import SimulatedWorld, active_localization
    from .scenarios import make_scenario
    from .viz import plot_run, write_html

    n_world = max(1, int(round(0.6 * args.candidates)))
    from ..cli import load_mesh

    obj = load_mesh(args.mesh, args.scale)
    sc = make_scenario(obj, args.setting, n_world=n_world, n_relative=args.candidates - n_world,
                       n_hands=args.hands, seed=args.seed)
    true = sc.hidden_pose(rng=args.seed)
    world = SimulatedWorld(sc.obj, true, rng=args.seed + 1)
    planner = make_planner(args.planner, sc.model, args.beta)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(true[:3, :3])
    rpy = np.degrees(q.as_euler("xyz"))
    print(f"{sc.obj}\nsetting: {args.setting}; hidden pose: t = {np.round(true[:3, 3] * 1e3, 1).tolist()} mm, "
          f"roll/pitch/yaw (xyz) = {np.round(rpy, 1).tolist()} deg, quat_xyzw = "
          f"{np.round(q.as_quat(), 4).tolist()}; planner: {planner.name}"
          f"{' (KL)' if args.planner == 'kl' else ''}; {args.particles} particles\n")
    header = [True]

    def show(step):
        from .loop import ActiveResult

        lines = ActiveResult([step], None, False).table().splitlines()
        if header[0]:
            print("\n".join(lines[:2]))
            header[0] = False
        print(lines[2], flush=True)

    from .._warmup import prepare_models

    setup = prepare_models()  # kernels now; per-mesh structures when first used, timed apart
    t0 = time.perf_counter()
    res = active_localization(world, sc.model, sc.region, planner, sc.candidates, n_particles=args.particles,
                              max_touches=args.max_touches, stop_error=args.stop_error * 1e-3,
                              stop_probability=args.stop_probability, stop_metric=args.stop_metric,
                              verify_stop=args.verify_stop, confidence=None if args.confidence is None else args.confidence * 1e-3, rng=args.seed,
                              callback=show)
    dt = time.perf_counter() - t0 - setup.collect()
    print(f"\n{'confident' if res.confident else 'not confident'} after {res.touches} touches "
          f"({sum(s.hits for s in res.steps)} contacts); final ADD-S {res.error * 1e3:.2f} mm; {dt:.1f} s")
    print(setup.line())
    if args.out:
        out = Path(args.out)
        title = f"{sc.obj.name}, {args.setting}, {planner.name}: {res.touches} touches, ADD-S {res.error * 1e3:.1f} mm"
        png = plot_run(out / f"{args.name}.png", res, sc.obj, title=title)
        html = write_html(out / f"{args.name}.html", res, sc.obj, title=title)
        print(f"wrote {png} and {html}")
    return 0
