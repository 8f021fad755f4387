"""``touchloc localize`` and ``touchloc identify``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from .._warmup import prepare_models
from ..cli import add_mesh_argument, diagnose, heartbeat, load_mesh, split_mesh_spec

ESTIMATORS = ("ss", "pf", "hf", "apf", "mpf", "ss+mcmc")

#: mean squared Mahalanobis distance per contact at the MAP pose above which the command
#: warns of low evidence (9: contacts 3 sigma off on average; above 36 the belief is degenerate)
LOW_EVIDENCE_COST = 9.0


def _region(args):
    from .region import PoseRegion

    c = [float(v) for v in args.center]
    if args.rotation == "planar":
        return PoseRegion.planar((c[0], c[1]), args.half_extent, z=c[2] if len(c) > 2 else 0.0)
    return PoseRegion.box(c, args.half_extent, args.rotation)


def register(sub):
    p = sub.add_parser("localize", help="localise a mesh from a CSV of contacts",
                       description="Localise a known mesh from measured contacts (CSV: x,y,z[,nx,ny,nz] "
                                   "in metres, world frame) and print the MAP pose, its spread and the time.")
    add_mesh_argument(p, required=True)
    p.add_argument("--contacts", help="CSV of contacts: x,y,z[,nx,ny,nz] in metres, world frame; a header "
                                      "line names the columns in any order; separators , ; tab or spaces")
    p.add_argument("--method", choices=ESTIMATORS, default="ss",
                   help="ss: Scaling Series (default), pf: importance sampling, hf: histogram (<= 3 DOF), "
                        "apf: annealed PF, mpf: manifold PF, ss+mcmc: Scaling Series refined by MCMC")
    p.add_argument("--center", nargs="+", default=[0.0, 0.0, 0.0], help="region centre x y [z] (m)")
    p.add_argument("--half-extent", type=float, default=0.2, help="region half side (m), default 0.2")
    p.add_argument("--rotation", choices=("full", "yaw", "planar"), default="full")
    p.add_argument("--sigma-pos", type=float, default=0.002, help="position noise (m)")
    p.add_argument("--sigma-nor", type=float, default=0.1, help="normal noise; <= 0 ignores normals")
    p.add_argument("--outlier-distance", type=float, default=None, metavar="SIGMAS",
                   help="cap each contact's cost at this many sigmas (stray contacts, or a mesh mapped by "
                        "touch: 7); default: no cap")
    p.add_argument("--particles", type=int, default=20000, help="particles for pf/apf/mpf")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", help="write a figure of mesh, contacts and particles (PNG)")
    p.add_argument("--save", help="write the belief (poses, log-weights, region, model parameters, MAP pose, "
                                  "contacts) to an .npz file; read it with touchloc.belief.load_belief")
    p.add_argument("--load", help="skip localisation: read a belief written by --save and report (and plot) it")
    p.add_argument("--json", action="store_true",
                   help="print the result as JSON: the MAP pose as a 4x4 matrix, quat_xyzw and translation (m)")
    p.set_defaults(func=run_localize)

    q = sub.add_parser("identify", help="which of several meshes explains the contacts?",
                       description="Posterior probability of each candidate mesh given contacts "
                                   "(recognition by localisation, uniform pose prior over the region).")
    q.add_argument("--meshes", nargs="+", required=True,
                   help="mesh files or bundled names; PATH:SCALE gives one mesh its own scale (e.g. duck.obj:0.001)")
    q.add_argument("--scale", default=None, help="factor to metres for every mesh without its own :SCALE "
                                                 "(e.g. 0.001 for files in millimetres)")
    q.add_argument("--contacts", required=True)
    q.add_argument("--center", nargs="+", default=[0.0, 0.0, 0.0])
    q.add_argument("--half-extent", type=float, default=0.2)
    q.add_argument("--rotation", choices=("full", "yaw", "planar"), default="full")
    q.add_argument("--sigma-pos", type=float, default=0.002)
    q.add_argument("--sigma-nor", type=float, default=0.1)
    q.add_argument("--outlier-distance", type=float, default=None, metavar="SIGMAS",
                   help="cap each contact's cost at this many sigmas; default: no cap")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--json", action="store_true", help="print the posterior as JSON")
    q.set_defaults(func=run_identify)


def _model(obj, args):
    from ..models import ProximityModel

    return ProximityModel(obj, args.sigma_pos, args.sigma_nor if args.sigma_nor > 0 else None,
                          outlier_distance=args.outlier_distance)


def run_localize(args) -> int:
    from ..errors import ValidationError
    from ..models import Contacts
    from . import (MCMC, AnnealedParticleFilter, HistogramFilter, ManifoldParticleFilter, ParticleFilter,
                   ScalingSeries, load_belief, pose_to_dict, save_belief)

    obj = load_mesh(args.mesh, args.scale)
    out = sys.stderr if args.json else sys.stdout
    dt = None
    if args.load:
        belief, contacts = load_belief(args.load)
        if args.contacts:
            contacts = Contacts.from_csv(args.contacts)
        if contacts is None:
            raise ValidationError(f"{args.load} holds no contacts: give --contacts")
        region = belief.region if belief.region is not None else _region(args)
        print(f"{obj}\nloaded {args.load}: {len(belief)} particles, {len(contacts)} contacts", file=out)
    else:
        if not args.contacts:
            raise ValidationError("give --contacts CSV (or --load a saved belief)")
        contacts = Contacts.from_csv(args.contacts)
        region = _region(args)
        model = _model(obj, args)
        est = {
            "ss": lambda: ScalingSeries(model, rng=args.seed),
            "ss+mcmc": lambda: ScalingSeries(model, rng=args.seed),
            "pf": lambda: ParticleFilter(model, n_particles=args.particles, rng=args.seed),
            "hf": lambda: HistogramFilter(model),
            "apf": lambda: AnnealedParticleFilter(model, args.particles, rng=args.seed),
            "mpf": lambda: ManifoldParticleFilter(model, args.particles, rng=args.seed),
        }[args.method]()
        print(f"{obj}\n{len(contacts)} contacts, {region}, method {args.method}", file=out, flush=True)
        setup = prepare_models()  # kernels now; per-mesh structures when first used, timed apart
        t0 = time.perf_counter()
        if args.method == "ss":
            belief = est.localize(contacts, region)  # Scaling Series reports its own progress
        else:
            with heartbeat(f"localize ({args.method})"):
                belief = est.localize(contacts, region)
                if args.method == "ss+mcmc":
                    belief = MCMC(model, rng=args.seed).refine(contacts, belief)
        dt = time.perf_counter() - t0 - setup.collect()
        print(setup.line(), file=out, flush=True)
    T = belief.map_pose()
    if args.json:
        doc = {"map_pose": pose_to_dict(T), "degenerate": belief.degenerate, "particles": len(belief),
               "ess": float(belief.ess()), "mesh": obj.name, "contacts": len(contacts)}
        if dt is not None:
            doc["time_s"] = dt
            doc["setup_s"] = setup.seconds
        print(json.dumps(doc, indent=2))
    else:
        np.set_printoptions(precision=5, suppress=True)
        q = pose_to_dict(T)
        print("MAP pose T_world_object:")
        print(T)
        print(f"quat_xyzw = {np.round(q['quat_xyzw'], 6).tolist()}, translation = "
              f"{np.round(q['translation'], 6).tolist()} m")
        print(belief.summary())
        if dt is not None:
            print(f"time: {dt:.2f} s localisation (set-up {setup.seconds:.2f} s more)")
    cost = belief.info.get("mean_cost_at_map")
    if belief.degenerate:
        print("touchloc localize: the result is degenerate (no pose in the region explains the contacts):",
              file=sys.stderr)
    elif cost is not None and cost > LOW_EVIDENCE_COST:
        print("touchloc localize: low evidence: the best pose explains the contacts poorly; treat it with care:",
              file=sys.stderr)
    if belief.degenerate or (cost is not None and cost > LOW_EVIDENCE_COST):
        for line in diagnose(obj, contacts, region, belief, sigma_pos=args.sigma_pos):
            print(f"  - {line}", file=sys.stderr)
    if args.save and not args.load:
        path = save_belief(args.save, belief, contacts=contacts, model=model,
                           extra={"method": args.method, "mesh_spec": args.mesh, "scale": args.scale})
        print(f"wrote {path}", file=out)
    if args.plot:
        plot_belief(obj, belief, contacts, args.plot)
        print(f"wrote {args.plot}", file=out)
    return 1 if belief.degenerate else 0


def _candidates(specs, scale):
    """Load candidate meshes under unique names (parent/stem when stems collide)."""
    from ..errors import ValidationError

    parsed = [split_mesh_spec(s) for s in specs]
    paths = [Path(p) for p, _ in parsed]
    names = [p.stem if p.suffix else str(p) for p in paths]
    for depth in range(1, 8):
        dup = {n for n in names if names.count(n) > 1}
        if not dup:
            break
        names = [("/".join(p.with_suffix("").parts[-depth - 1:]) if n in dup else n) for n, p in zip(names, paths)]
    if len(set(names)) != len(names):
        raise ValidationError(f"--meshes lists the same mesh twice: {specs}")
    return {n: load_mesh(p, s if s is not None else scale, name=n) for n, (p, s) in zip(names, parsed)}


def run_identify(args) -> int:
    from ..errors import BeliefDegenerateError
    from ..models import Contacts
    from . import identify

    objs = _candidates(args.meshes, args.scale)
    contacts = Contacts.from_csv(args.contacts)
    region = _region(args)
    models = {n: _model(o, args) for n, o in objs.items()}
    setup = prepare_models()
    t0 = time.perf_counter()
    try:
        post = identify(models, contacts, region, rng=args.seed)
    except BeliefDegenerateError as exc:
        if args.json:
            print(json.dumps({"identity": None, "reason": str(exc)}))
        else:
            print("none")
        print(f"touchloc identify: {exc}", file=sys.stderr)
        first = next(iter(objs.values()))
        for line in diagnose(first, contacts, region, sigma_pos=args.sigma_pos):
            print(f"  - {line}", file=sys.stderr)
        return 1
    dt = time.perf_counter() - t0 - setup.collect()
    print(setup.line(), file=sys.stderr, flush=True)  # stdout holds the answer only
    ranked = sorted(post.items(), key=lambda kv: -kv[1])
    if args.json:
        print(json.dumps({"identity": ranked[0][0], "posterior": dict(ranked),
                          "time_s": dt, "setup_s": setup.seconds}, indent=2))
    else:
        width = max(16, max(len(n) for n in post))
        for name, p in ranked:
            print(f"{name:>{width}s}  {p:.4f}")
        print(f"time: {dt:.1f} s identification (set-up {setup.seconds:.1f} s more)")
    return 0


def plot_belief(obj, belief, contacts, path, *, max_particles: int = 300):
    """Figure: the mesh at the MAP pose, the contacts with normals, the heaviest particles.

    Left: 3-D view in millimetres (mesh translucent, contacts red with their normals,
    the object origins of the heaviest particles in blue, darker for more weight).
    Right: the Scaling Series schedule, or the cumulative weight of the particles by rank.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from ..geometry import transform_points

    T = belief.map_pose()
    V = transform_points(T, obj.mesh.vertices) * 1e3
    fig = plt.figure(figsize=(12, 5.2))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.computed_zorder = False  # draw in call order: mesh, contacts, particles, MAP on top
    ax.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=obj.mesh.faces, color="0.75", alpha=0.18, linewidth=0)
    P = contacts.points * 1e3
    ax.scatter(P[:, 0], P[:, 1], P[:, 2], color="crimson", s=14, depthshade=False, label="contacts")
    if contacts.has_normals:
        L = 0.1 * float(np.ptp(V, axis=0).max())
        N = contacts.normals
        ax.quiver(P[:, 0], P[:, 1], P[:, 2], N[:, 0], N[:, 1], N[:, 2], length=L, color="crimson", lw=0.8)
    order = np.argsort(-belief.log_weights)[:max_particles]
    C = belief.poses[order, :3, 3] * 1e3
    w = belief.weights[order]
    alpha = 0.25 + 0.75 * w / max(float(w.max()), 1e-300)
    colors = np.zeros((len(order), 4))
    colors[:] = matplotlib.colors.to_rgba("navy")
    colors[:, 3] = alpha
    ax.scatter(C[:, 0], C[:, 1], C[:, 2], c=colors, s=18, marker="o", depthshade=False,
               label=f"object origin of the {len(order)} heaviest particles")
    ax.scatter(*T[:3, 3] * 1e3, color="orange", edgecolor="k", s=160, marker="*", depthshade=False, label="MAP origin")
    ax.set_xlabel("x (mm)", labelpad=8), ax.set_ylabel("y (mm)", labelpad=8), ax.set_zlabel("z (mm)", labelpad=8)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax.set_title(f"{obj.name} at the MAP pose" + (" (DEGENERATE)" if belief.degenerate else ""))
    ax.legend(loc="upper left", fontsize=8)
    allp = np.vstack([V, P, C])
    lo, hi = allp.min(0), allp.max(0)
    mid, r = (lo + hi) / 2, (hi - lo).max() * 0.55
    ax.set_xlim(mid[0] - r, mid[0] + r), ax.set_ylim(mid[1] - r, mid[1] + r), ax.set_zlim(mid[2] - r, mid[2] + r)
    ax2 = fig.add_subplot(1, 2, 2)
    steps = belief.info.get("scales")
    if steps:
        d = [s[0] * 1e3 for s in steps]
        n = [s[2] for s in steps]
        ax2.loglog(d, n, "o-", ms=3)
        ax2.invert_xaxis()
        ax2.set_xlabel("delta (mm, log scale; coarse to fine)")
        ax2.set_ylabel("particles per scale")
        ax2.set_title("Scaling Series")
    else:
        cw = np.cumsum(np.sort(belief.weights)[::-1])
        rank = np.arange(1, len(cw) + 1)
        ax2.semilogx(rank, cw)
        for level in (0.5, 0.9):
            k = int(np.searchsorted(cw, level)) + 1
            ax2.axhline(level, color="0.7", lw=0.8, ls="--")
            ax2.annotate(f"{level:.0%} of the weight in {k} particles", (k, level), xytext=(6, -14),
                         textcoords="offset points", fontsize=8)
        ax2.set_ylim(0, 1.02)
        ax2.set_xlabel("particles, heaviest first (log scale)")
        ax2.set_ylabel("cumulative weight")
        ax2.set_title(f"weights of {len(cw)} particles (ESS {belief.ess():.0f})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
