"""``touchloc localize`` and ``touchloc identify``."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ESTIMATORS = ("ss", "pf", "hf", "apf", "mpf", "ss+mcmc")


def _load_mesh(spec: str, scale: float | None):
    from ..data import MESHES, load_object
    from ..models import MeshObject

    if spec in MESHES and not Path(spec).exists():
        return load_object(spec)
    return MeshObject.from_file(spec, scale=1.0 if scale is None else scale)


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
    p.add_argument("--mesh", required=True, help="mesh file (any format trimesh reads) or a bundled name")
    p.add_argument("--scale", type=float, default=None, help="factor to metres (e.g. 0.001 for mm files)")
    p.add_argument("--contacts", required=True, help="CSV file of contacts")
    p.add_argument("--method", choices=ESTIMATORS, default="ss",
                   help="ss: Scaling Series (default), pf: importance sampling, hf: histogram (<= 3 DOF), "
                        "apf: annealed PF, mpf: manifold PF, ss+mcmc: Scaling Series refined by MCMC")
    p.add_argument("--center", nargs="+", default=[0.0, 0.0, 0.0], help="region centre x y [z] (m)")
    p.add_argument("--half-extent", type=float, default=0.2, help="region half side (m), default 0.2")
    p.add_argument("--rotation", choices=("full", "yaw", "planar"), default="full")
    p.add_argument("--sigma-pos", type=float, default=0.002, help="position noise (m)")
    p.add_argument("--sigma-nor", type=float, default=0.1, help="normal noise; <= 0 ignores normals")
    p.add_argument("--particles", type=int, default=20000, help="particles for pf/apf/mpf")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", help="write a figure of mesh, contacts and particles (PNG)")
    p.add_argument("--save", help="write the belief (poses and log-weights) to an .npz file")
    p.set_defaults(func=run_localize)

    q = sub.add_parser("identify", help="which of several meshes explains the contacts?",
                       description="Posterior probability of each candidate mesh given contacts "
                                   "(recognition by localisation, uniform pose prior over the region).")
    q.add_argument("--meshes", nargs="+", required=True, help="mesh files or bundled names")
    q.add_argument("--contacts", required=True)
    q.add_argument("--center", nargs="+", default=[0.0, 0.0, 0.0])
    q.add_argument("--half-extent", type=float, default=0.2)
    q.add_argument("--rotation", choices=("full", "yaw", "planar"), default="full")
    q.add_argument("--sigma-pos", type=float, default=0.002)
    q.add_argument("--sigma-nor", type=float, default=0.1)
    q.add_argument("--seed", type=int, default=0)
    q.set_defaults(func=run_identify)


def _model(obj, args):
    from ..models import ProximityModel

    return ProximityModel(obj, args.sigma_pos, args.sigma_nor if args.sigma_nor > 0 else None)


def run_localize(args) -> int:
    from ..models import Contacts
    from . import (MCMC, AnnealedParticleFilter, HistogramFilter, ManifoldParticleFilter, ParticleFilter,
                   ScalingSeries)

    obj = _load_mesh(args.mesh, args.scale)
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
    print(f"{obj}\n{len(contacts)} contacts, {region}, method {args.method}")
    t0 = time.perf_counter()
    belief = est.localize(contacts, region)
    if args.method == "ss+mcmc":
        belief = MCMC(model, rng=args.seed).refine(contacts, belief)
    dt = time.perf_counter() - t0
    T = belief.map_pose()
    np.set_printoptions(precision=5, suppress=True)
    print("MAP pose T_world_object:")
    print(T)
    print(belief.summary())
    print(f"time: {dt:.2f} s")
    if args.save:
        np.savez(args.save, poses=belief.poses, log_weights=belief.log_weights)
        print(f"wrote {args.save}")
    if args.plot:
        plot_belief(obj, belief, contacts, args.plot)
        print(f"wrote {args.plot}")
    return 1 if belief.degenerate else 0


def run_identify(args) -> int:
    from ..models import Contacts
    from . import identify

    objs = [_load_mesh(m, None) for m in args.meshes]
    contacts = Contacts.from_csv(args.contacts)
    models = {o.name: _model(o, args) for o in objs}
    t0 = time.perf_counter()
    post = identify(models, contacts, _region(args), rng=args.seed)
    for name, p in sorted(post.items(), key=lambda kv: -kv[1]):
        print(f"{name:>16s}  {p:.4f}")
    print(f"time: {time.perf_counter() - t0:.1f} s")
    return 0


def plot_belief(obj, belief, contacts, path, *, max_particles: int = 300):
    """Figure: the mesh at the MAP pose, the contacts with normals, the heaviest particles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..geometry import transform_points

    T = belief.map_pose()
    V = transform_points(T, obj.mesh.vertices)
    fig = plt.figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=obj.mesh.faces, color="0.8", alpha=0.35, linewidth=0)
    P = contacts.points
    ax.scatter(P[:, 0], P[:, 1], P[:, 2], color="crimson", s=12, label="contacts")
    if contacts.has_normals:
        L = 0.1 * float(obj.extents.max())
        N = contacts.normals
        ax.quiver(P[:, 0], P[:, 1], P[:, 2], N[:, 0], N[:, 1], N[:, 2], length=L, color="crimson", lw=0.8)
    order = np.argsort(-belief.log_weights)[:max_particles]
    C = belief.poses[order, :3, 3]
    ax.scatter(C[:, 0], C[:, 1], C[:, 2], c=belief.weights[order], cmap="viridis", s=6, label="particles (origin)")
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.set_zlabel("z (m)")
    ax.set_title(f"{obj.name} at the MAP pose")
    ax.legend(loc="upper left", fontsize=8)
    lo, hi = V.min(0), V.max(0)
    mid, r = (lo + hi) / 2, (hi - lo).max() * 0.7
    ax.set_xlim(mid[0] - r, mid[0] + r), ax.set_ylim(mid[1] - r, mid[1] + r), ax.set_zlim(mid[2] - r, mid[2] + r)
    ax2 = fig.add_subplot(1, 2, 2)
    steps = belief.info.get("scales")
    if steps:
        d = [s[0] * 1e3 for s in steps]
        n = [s[2] for s in steps]
        ax2.semilogy(d, n, "o-", ms=3)
        ax2.invert_xaxis()
        ax2.set_xlabel("delta (mm)")
        ax2.set_ylabel("particles per scale")
        ax2.set_title("Scaling Series")
    else:
        w = np.sort(belief.weights)[::-1]
        ax2.semilogy(np.arange(1, len(w) + 1), w)
        ax2.set_xlabel("particle rank")
        ax2.set_ylabel("weight")
        ax2.set_title(f"weights (ESS {belief.ess():.0f})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
