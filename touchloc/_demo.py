"""``touchloc demo``: localise a bundled mesh from simulated contacts."""

from __future__ import annotations

import time

import numpy as np


def register(sub):
    p = sub.add_parser("demo", help="localise a bundled mesh from simulated touches")
    p.add_argument("--mesh", default="mug", help="bundled mesh name (default: mug)")
    p.add_argument("--contacts", type=int, default=10, help="number of simulated contacts")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--particles", type=int, default=200_000, help="importance samples")
    p.set_defaults(func=run)


def run(args) -> int:
    from . import geometry
    from .data import load_object
    from .models import Contacts, ProximityModel

    rng = np.random.default_rng(args.seed)
    obj = load_object(args.mesh)
    # a hidden pose: 5 cm square on a table, unknown yaw
    yaw = rng.uniform(-np.pi, np.pi)
    true = geometry.vector_to_pose([[*rng.uniform(-0.025, 0.025, 2), 0.0, 0.0, 0.0, yaw]])[0]
    pts, nrm, _ = obj.sample_surface(args.contacts, rng=rng)
    c_obj = Contacts(pts + rng.normal(scale=0.001, size=pts.shape), nrm)
    contacts = c_obj.transform(true)
    model = ProximityModel(obj, sigma_pos=0.002, sigma_nor=0.15)
    print(f"{obj}\nhidden pose: x={true[0,3]*1e3:.1f} mm y={true[1,3]*1e3:.1f} mm yaw={np.degrees(yaw):.1f} deg")
    t0 = time.perf_counter()
    v = np.zeros((args.particles, 6))
    v[:, :2] = rng.uniform(-0.025, 0.025, (args.particles, 2))
    v[:, 5] = rng.uniform(-np.pi, np.pi, args.particles)
    poses = geometry.vector_to_pose(v)
    ll = model.log_likelihood(poses, contacts)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    best = poses[np.argmax(ll)]
    dt = time.perf_counter() - t0
    err_t = np.linalg.norm(best[:3, 3] - true[:3, 3]) * 1e3
    err_r = np.degrees(geometry.rotation_angle(best[:3, :3], true[:3, :3]))
    print(f"importance sampling, {args.particles} poses x {args.contacts} contacts: {dt:.2f} s")
    print(f"MAP error: {err_t:.1f} mm, {err_r:.1f} deg; effective samples {1 / np.sum(w**2):.1f}")
    return 0
