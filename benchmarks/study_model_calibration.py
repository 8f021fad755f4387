"""Calibration with the sensor's own density: proximity against integrated proximity model.

The calibration benchmark draws each contact as the simulated sensor makes it (a surface
point uniform by area, plus Gaussian noise on the point and the normal), so the exact
likelihood of a contact is the integrated proximity model, and a posterior computed
with it is calibrated by construction. The proximity model keeps only the best surface
point. This study runs the calibration benchmark's trials (planar region, truth drawn
from the uniform prior, ``bench_calibration.trial``) with each estimator twice, once per
model, and reports how often the truth lies in the 50 / 90 / 95 % highest-density
regions (``touchloc.belief.hpd_level``, modulo the mesh's symmetries).

    cd benchmarks
    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 8 --offset 100
    # held-out sensor statistics: 1 mm / 0.05, and 3 mm / 0.15
    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 4 --offset 200 \
        --sigma 0.001 0.05 --contacts 10 30

Diagnostics of where a shortfall comes from (docs/localization.md, "Beliefs you can check:
calibration"):

* ``--twin`` runs each estimator a second time on the same contacts with another seed and
  ranks three of the twin's particles in the first run's belief, as the truth is ranked. A
  sampler whose runs draw from one distribution puts a twin's particle in its level-a
  region a of the time, whatever that distribution;
* ``--ranks`` reads the truth's level off the likelihood instead of ``hpd_level``'s
  neighbour density: the share of the sample more likely than the truth (the exact
  highest-density level of a sample from a uniform prior);
* ``--grid`` reads it off the exact posterior on a grid (0.5 mm over +-10 mm around the
  truth's position, every degree of yaw; planar trials), with no sampler at all;
* ``--no-normals`` drops the contacts' normals (both models then score positions only);
* ``--model-sigma-nor`` gives the models another normal noise than the sensor's;
* ``ellipsoid-S`` among ``--meshes``: a sheared ellipsoid (45 x 30 x 25 mm, an icosphere
  of S subdivisions: 320 faces at 2, 20,480 at 5), smooth where S is large.

    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 8 --offset 50 \
        --models proximity --estimators smc --twin --ranks --grid
    OMP_NUM_THREADS=1 ../.venv/bin/python study_model_calibration.py --trials 30 --offset 50 \
        --models proximity --estimators smc --ranks --contacts 10 30 --meshes ellipsoid-2 ellipsoid-5

Seed offsets: the calibration benchmark's tables use offsets 50-57 and the estimators'
settings were chosen on 0-49; the integrated model's quadrature was checked on offsets
0-11 (SMC only). Report other offsets.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

ESTIMATORS = ("SMCFilter", "Scaling Series")
MODELS = ("proximity", "integrated")
_cache: dict = {}


def _ellipsoid(subdivisions: int):
    """A sheared ellipsoid, 45 x 30 x 25 mm before the shear (x += 0.25 y, y += 0.15 z), so
    that no turn about the vertical maps it onto itself."""
    import trimesh

    from touchloc.models import MeshObject

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    m.apply_scale([0.045, 0.03, 0.025])
    shear = np.eye(4)
    shear[0, 1], shear[1, 2] = 0.25, 0.15
    m.apply_transform(shear)
    return MeshObject(m, name=f"ellipsoid-{subdivisions}")


def _mesh_index(mesh):
    """The mesh's place in the seed formula (bench_calibration's order; ellipsoids after)."""
    import bench_calibration as B

    names = B.MESHES + B.HELD_OUT_MESHES
    return names.index(mesh) if mesh in names else 10 + int(mesh.split("-")[1])


def _models(mesh, sigma_pos, sigma_nor):
    from bench_calibration import quiet_load
    from touchloc.models import IntegratedProximityModel, ProximityModel

    key = (mesh, sigma_pos, sigma_nor)
    if key not in _cache:
        obj = _ellipsoid(int(mesh.split("-")[1])) if mesh.startswith("ellipsoid-") else quiet_load(mesh)
        obj.symmetries()
        _cache[key] = (obj, ProximityModel(obj, sigma_pos, sigma_nor),
                       IntegratedProximityModel(obj, sigma_pos, sigma_nor))
    return _cache[key]


def _one(job):
    mesh, k, t, offset, sigma_pos, sigma_nor, estimators, smc_kw, models, extras, model_nor = job
    warnings.simplefilter("ignore")
    import bench_calibration as B
    from touchloc.belief import ScalingSeries, SMCFilter, hpd_level
    from touchloc.models import Contacts

    B.SIGMA_POS, B.SIGMA_NOR = sigma_pos, sigma_nor   # the generator's noise
    normals = "no-normals" not in extras
    obj, prox, integ = _models(mesh, sigma_pos, (model_nor or sigma_nor) if normals else None)
    region = B.planar_region(obj)
    seed = 10_000 * k + 100 * _mesh_index(mesh) + offset + t
    true, c = B.trial(obj, region, k, seed)
    if not normals:
        c = Contacts(c.points)
    out = []
    for est in estimators:
        for name, model in (("proximity", prox), ("integrated", integ)):
            if name not in models:
                continue
            def run(s):
                if est.startswith("SMC"):
                    return SMCFilter(model, rng=s, **smc_kw).localize(c, region)
                # the search on the proximity model; the posterior stage on the model named
                return ScalingSeries(prox, posterior_model=model, rng=s).localize(c, region)

            t0 = time.process_time()
            b = run(seed)
            dt = time.process_time() - t0
            row = dict(estimator=est, model=name, mesh=mesh, k=k, t=t,
                       level=float(hpd_level(b, true, obj, rng=seed)), cpu=dt)
            if "twin" in extras:
                other = run(seed + 7777)
                pick = np.random.default_rng(seed).choice(len(other), 3, replace=False)
                row["twin"] = [float(hpd_level(b, other.poses[i], obj, rng=seed + int(i))) for i in pick]
            if "ranks" in extras:
                row["rank"] = float(np.mean(model.log_likelihood(b.poses, c) > model.log_likelihood(true[None], c)[0]))
            if "grid" in extras:
                row["grid"], row["grid_edge"] = _grid_level(model, c, true)
            out.append(row)
    return out


def _grid_level(model, contacts, true, half=0.010, step=0.0005):
    """The truth's level under the exact posterior (uniform prior) on a grid around it:
    positions within ``half`` of the truth's at ``step``, every degree of yaw. Returns the
    posterior mass more likely than the truth and the mass within 1 mm of the grid's edge
    (which should be near 0, or the grid is too small)."""
    from scipy.spatial.transform import Rotation

    xs = np.arange(-half, half + step / 2, step)
    X, Y = (v.ravel() for v in np.meshgrid(xs, xs))
    turns = Rotation.from_euler("z", np.radians(np.arange(0.0, 360.0, 1.0))[:, None]).as_matrix()
    L = []
    for R in turns:
        P = np.repeat(true[None], X.size, axis=0)
        P[:, :3, :3] = R @ true[:3, :3]
        P[:, 0, 3] += X
        P[:, 1, 3] += Y
        L.append(model.log_likelihood(P, contacts))
    L = np.concatenate(L)
    w = np.exp(L - L.max())
    w /= w.sum()
    edge = np.tile((np.abs(X) > half - 0.001) | (np.abs(Y) > half - 0.001), len(turns))
    return float(w[L > model.log_likelihood(true[None], contacts)[0]].sum()), float(w[edge].sum())


def _init(ss_ess=None):
    os.environ["NUMBA_NUM_THREADS"] = "1"
    if ss_ess is not None:
        # Scaling Series' posterior stage tempers through smc.temper, which it looks up
        # when the stage runs: give every call this worker makes the study's ess_fraction
        import functools

        import touchloc.belief.smc as smc

        smc.temper = functools.partial(smc.temper, ess_fraction=ss_ess)


def _table(rows, levels=(0.5, 0.9, 0.95)):
    from _common import table

    meshes = list(dict.fromkeys(r["mesh"] for r in rows))
    extra = [(key, head) for key, head in (("twin", "a twin run's particle"), ("rank", "likelihood rank"),
                                           ("grid", "grid posterior"))
             if all(key in r for r in rows)]
    ks = sorted({r["k"] for r in rows})
    out = []
    ests = [e for e in ESTIMATORS if any(r["estimator"] == e for r in rows)]
    models = [m for m in MODELS if any(r["model"] == m for r in rows)]
    for est in ests:
        for name in models:
            sel = [r for r in rows if r["estimator"] == est and r["model"] == name]
            for k in ks + ["all"]:
                rr = [r for r in sel if k == "all" or r["k"] == k]
                q = np.array([r["level"] for r in rr])
                cells = []
                for key, _ in extra:
                    qx = np.array([x for r in rr for x in np.atleast_1d(r[key])])
                    cells += [f"{100 * np.mean(qx < a):.0f} %" for a in levels]
                out.append((est, name, k, len(q), *(f"{100 * np.mean(q < a):.0f} %" for a in levels), *cells,
                            f"{np.median([r['cpu'] for r in rr]):.2f}"))
    per_mesh = []
    for est in ests:
        for name in models:
            row = [est, name]
            for m in meshes:
                q = np.array([r["level"] for r in rows if r["estimator"] == est and r["model"] == name
                              and r["mesh"] == m])
                row.append(f"{100 * np.mean(q < 0.9):.0f} %")
            per_mesh.append(row)
    extra_head = [h for _, head in extra for h in (f"{head}: in 50 %", "in 90 %", "in 95 %")]
    edge = [r["grid_edge"] for r in rows if "grid_edge" in r]
    note = f"\n\nThe grid posterior's mass within 1 mm of its edge: at most {max(edge):.3f}." if edge else ""
    return (table(["estimator", "likelihood", "contacts", "trials", "truth in 50 % region", "in 90 %", "in 95 %",
                   *extra_head, "median CPU s"], out) + note
            + "\n\nTruth in the 90 % region, per mesh (all contact counts):\n\n"
            + table(["estimator", "likelihood"] + meshes, per_mesh))


def main(argv=None) -> int:
    import bench_calibration as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=B.MESHES + B.HELD_OUT_MESHES)
    ap.add_argument("--contacts", nargs="+", type=int, default=list(B.CONTACTS))
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--offset", type=int, default=100)
    ap.add_argument("--sigma", nargs=2, type=float, default=[B.SIGMA_POS, B.SIGMA_NOR],
                    metavar=("POS", "NOR"), help="the sensor's noise, which both models are given")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--estimators", nargs="+", choices=["smc", "ss"], default=["smc", "ss"])
    ap.add_argument("--particles", type=int, default=2000, help="SMCFilter's particles")
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--ess", type=float, default=None,
                    help="SMCFilter's ess_fraction: the share of the effective sample size kept per tempering step")
    ap.add_argument("--jumps", type=float, default=None,
                    help="SMCFilter's accepted moves per particle and tempering step (default: its own)")
    ap.add_argument("--ss-ess", type=float, default=None,
                    help="the ess_fraction of Scaling Series' posterior stage (default: temper's, 0.5); "
                         "use with --estimators ss")
    ap.add_argument("--twin", action="store_true",
                    help="also rank three particles of a second run (another seed) in each belief")
    ap.add_argument("--ranks", action="store_true",
                    help="also the truth's level as the share of the sample more likely than it")
    ap.add_argument("--grid", action="store_true",
                    help="also the truth's level under the exact posterior on a grid (slow: seconds a trial)")
    ap.add_argument("--no-normals", action="store_true", help="score the contacts' positions only")
    ap.add_argument("--model-sigma-nor", type=float, default=None,
                    help="the models' sigma_nor, where it differs from the sensor's (--sigma)")
    ap.add_argument("--jsonl", help="also write every trial here")
    a = ap.parse_args(argv)
    bad = [m for m in a.meshes if m not in B.MESHES + B.HELD_OUT_MESHES + [f"ellipsoid-{s}" for s in range(1, 7)]]
    if bad:
        ap.error(f"meshes must be among {B.MESHES + B.HELD_OUT_MESHES} or ellipsoid-1 ... ellipsoid-6, got {bad}")
    extras = {name for name, on in (("twin", a.twin), ("ranks", a.ranks), ("grid", a.grid),
                                    ("no-normals", a.no_normals)) if on}
    ests = [e for e in ESTIMATORS if ("smc" if e.startswith("SMC") else "ss") in a.estimators]
    smc_kw = {"n_particles": a.particles}
    if a.jumps is not None:
        smc_kw["jumps"] = a.jumps
    if a.ess is not None:
        smc_kw["ess_fraction"] = a.ess
    jobs = [(m, k, t, a.offset, a.sigma[0], a.sigma[1], ests, smc_kw, a.models, extras, a.model_sigma_nor)
            for t in range(a.trials)
            for k in a.contacts for m in a.meshes]
    rows = []
    w0 = time.time()
    sink = open(a.jsonl, "w") if a.jsonl else None
    if a.ss_ess is not None and "smc" in a.estimators:
        ap.error("--ss-ess changes every tempering in the workers, the SMC filter's too: use --estimators ss")
    with ProcessPoolExecutor(a.workers, initializer=_init, initargs=(a.ss_ess,)) as ex:
        for i, res in enumerate(ex.map(_one, jobs), 1):
            rows.extend(res)
            if sink:
                for r in res:
                    sink.write(json.dumps(r) + "\n")
                sink.flush()
            print(f"\r{i}/{len(jobs)} trials", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    load = os.getloadavg()[0]
    stage = f"Scaling Series' posterior stage ess_fraction {a.ss_ess}; " if a.ss_ess is not None else ""
    print(f"{len(jobs)} trials in {time.time() - w0:.0f} s wall; sensor {a.sigma[0] * 1e3:g} mm / {a.sigma[1]:g}; "
          f"seed offsets {a.offset}-{a.offset + a.trials - 1}; SMCFilter settings {smc_kw}; {stage}"
          f"diagnostics {sorted(extras) or 'none'}; models' sigma_nor {a.model_sigma_nor or a.sigma[1]:g}; "
          f"load average {load:.1f}\n")
    print(_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
