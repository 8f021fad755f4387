"""Hostile arguments for the public methods of the core classes (models, belief, mapping).

test_fuzz_public.py calls every exported name; a user also calls the methods of what those
names return (``belief.credible_set(level)``, ``region.sample(n)``, ``smap.to_mesh(resolution)``).
Here every public method of every class exported by :data:`METHOD_MODULES` is called, one
parameter at a time, with each hostile value of the function suite, on an instance built from
ordinary values. Each call must end in a :class:`~touchloc.errors.TouchlocError` or a result
without NaN, within the time limit. Each method's ordinary call must succeed, so that each
hostile value meets a call that would otherwise have worked. A fresh instance serves every
call, so that a hostile value cannot be masked by an earlier call's side effects.
"""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

pytest.importorskip("hypothesis")

from test_fuzz_public import BAD, CHEAP, _call_kwargs, _mapping_args, run_one, world  # noqa: E402

METHOD_MODULES = ["touchloc.models", "touchloc.belief", "touchloc.mapping"]

#: classes that only define an interface (their methods raise NotImplementedError by design)
INTERFACES = {"models.MeasurementModel", "models.FreeSpaceBase"}


def _hits(w):
    """Guarded touches on the fuzz world's box from its six sides (three each), as results."""
    from touchloc.planners import GuardedTouch

    if "hits" not in w:
        res = []
        for d in np.array([[0, 0, -1], [0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float):
            for off in (-0.01, 0.0, 0.01):
                res += w["world"].execute(GuardedTouch(tuple(-0.045 * d + off * np.roll(d, 1)), tuple(d), 0.08))
        w["hits"] = res
    return w["hits"]


def _values(w):
    """The function suite's values by name, with the mapping ones and touch results that hit
    (not the mapping's ``method``: methods named ``method`` mean other things)."""
    mapping = {k: v for k, v in _mapping_args(w).items() if k != "method"}
    return {**w, **mapping, "results": _hits(w)}


def _region(w):
    return w["region"].with_rho(0.03)


def _planar(w):
    from touchloc.belief import PoseRegion

    return PoseRegion.planar((0.0, 0.0), 0.01, rho=0.03)


def _files(w):
    """A contacts CSV, a mesh file and a saved map, for the methods that read them."""
    if "files" not in w:
        w["contacts"].to_csv("fuzz-contacts.csv")
        w["mesh"].export("fuzz-box.stl")
        _shape_map("gpis")(w).save("fuzz-map.npz")
        w["files"] = True
    return w


def _shape_map(method):
    def build(w):
        from touchloc.mapping import ShapeMap

        smap = ShapeMap(_mapping_args(w)["bounds"], method=method, resolution=16)
        smap.update(_hits(w))
        return smap
    return build


def _slam(w):
    from touchloc.mapping import TactileSLAM

    slam = TactileSLAM(_mapping_args(w)["bounds"], n_particles=20)
    slam.update(_hits(w)[:6])
    return slam


def _initialized(name, region=_region, **kw):
    """An estimator with a belief over the region (ready for ``update``)."""
    def build(w):
        import touchloc.belief as tb

        est = getattr(tb, name)(w["model"], **kw)
        est.initialize(region(w))
        return est
    return build


def _belief(w):
    from touchloc.belief import ParticleBelief

    return ParticleBelief(w["poses"], region=_region(w), resolution=0.005)


def _superquadric(w):
    from touchloc.mapping import fit_superquadric

    return fit_superquadric(_mapping_args(w)["contacts"], n_starts=1)


def _symmetry(w):
    from touchloc.models import Symmetry

    return Symmetry(np.eye(3)[None], np.zeros(3), np.array([0.0, 0.0, 1.0]), continuous=True)


#: instances that the function suite's ordinary constructor call does not give (or gives
#: without the state a user's instance has): name -> builder of a fresh instance
INSTANCES = {
    "models.Symmetry": _symmetry,
    "belief.PoseRegion": _region,
    "belief.ParticleBelief": _belief,
    "belief.ScalingSeries": _initialized("ScalingSeries", n_initial=200, m_per_delta=2, max_particles=500,
                                         delta_final=0.004, progress=False),
    "belief.ParticleFilter": _initialized("ParticleFilter", n_particles=200),
    "belief.SMCFilter": _initialized("SMCFilter", n_particles=200),
    "belief.HistogramFilter": _initialized("HistogramFilter", region=_planar, resolution=0.004,
                                           angular_resolution=0.2),
    "mapping.ShapeMap[gpis]": _shape_map("gpis"),
    "mapping.ShapeMap[occupancy]": _shape_map("occupancy"),
    "mapping.TactileSLAM": _slam,
    "mapping.Superquadric": _superquadric,
}

_EYE4 = np.eye(4)

#: ordinary values for one method where the values by name do not fit it
ARGS = {
    "models.Contacts.concatenate": lambda w: dict(items=[w["contacts"], w["contacts"]]),
    "models.Contacts.from_csv": lambda w: dict(path=(_files(w), "fuzz-contacts.csv")[1]),
    "models.MeshObject.bvh": dict(normal_weight=0.0004),
    "models.MeshObject.from_file": lambda w: dict(path=(_files(w), "fuzz-box.stl")[1], scale=1.0, name="box"),
    "models.MeshObject.ray_cast": lambda w: dict(origins=w["starts"], directions=w["ends"] - w["starts"]),
    "models.GaussianDynamics.log_prior": lambda w: dict(prev_poses=w["poses"], prev_log_weights=np.zeros(8)),
    "models.GaussianDynamics.log_transition": lambda w: dict(next_poses=w["poses"], prev_poses=w["poses"]),
    "models.Symmetry.canonical": dict(quat_xyzw=[[0.0, 0.0, 0.0, 1.0]], t=[[0.0, 0.0, 0.0]]),
    "models.Symmetry.rotation_error": dict(R_est=np.eye(3), R_true=np.eye(3)),
    "belief.PoseRegion.from_local": dict(v=np.zeros((2, 4)), ref=_EYE4),
    "belief.PoseRegion.to_local": dict(ref=_EYE4),
    "belief.PoseRegion.perturb": dict(scale=0.01),
    "belief.PoseRegion.planar": dict(center=(0.0, 0.0)),
    "belief.PoseRegion.with_rho": dict(rho=0.03),
    "belief.ParticleBelief.reweighted": dict(log_likelihood=np.zeros(8)),
    "belief.HistogramFilter.initialize": lambda w: dict(region=_planar(w)),
    "belief.HistogramFilter.localize": lambda w: dict(region=_planar(w)),
    "belief.MCMC.refine": lambda w: dict(start=_belief(w), region=_region(w)),
    "mapping.ShapeMap[gpis].load": lambda w: dict(path=(_files(w), "fuzz-map.npz")[1]),
    "mapping.ShapeMap[occupancy].load": lambda w: dict(path=(_files(w), "fuzz-map.npz")[1]),
    "mapping.ShapeMap[gpis].relocate": dict(transforms=[_EYE4]),
    "mapping.ShapeMap[occupancy].relocate": dict(transforms=[_EYE4]),
}


#: methods whose NaN results are documented outputs, not leaks (with where the docs say so)
NAN_DOCUMENTED = {
    "models.MeshObject.ray_cast": "hit points and normals are NaN on a miss (its Returns section)",
}


def _instance_builders():
    import importlib

    out = {}
    for modname in METHOD_MODULES:
        mod = importlib.import_module(modname)
        short = modname.split(".")[-1]
        for name in mod.__all__:
            cls = getattr(mod, name)
            key = f"{short}.{name}"
            if not inspect.isclass(cls) or issubclass(cls, BaseException) or key in INTERFACES:
                continue
            variants = [k for k in INSTANCES if k == key or k.startswith(key + "[")]
            if variants:
                out.update({k: (cls, INSTANCES[k]) for k in variants})
                continue
            params = [p for p in inspect.signature(cls).parameters.values()
                      if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

            def build(w, cls=cls, params=params, extra=CHEAP.get(key)):
                return _call_kwargs(cls, params, None, None, extra)
            out[key] = (cls, build)
    return out


def _methods():
    out = []
    for key, (cls, build) in _instance_builders().items():
        for mname, member in inspect.getmembers(cls):
            if mname.startswith("_") or not callable(member) or inspect.isclass(member):
                continue
            try:
                sig = inspect.signature(member)
            except (TypeError, ValueError):
                continue
            params = [p for p in sig.parameters.values()
                      if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.name not in ("self", "cls")]
            if params:
                out.append((f"{key}.{mname}", build, mname, params))
    return out


METHODS = _methods()


def _call(entry, target, bad, time_limit_s=3.0):
    name, build, mname, params = entry
    w = world()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        obj = build(w)
    extra = ARGS.get(name)
    values = _values(w)
    if callable(extra):
        values = {**values, **extra(values)}
    elif extra:
        values = {**values, **extra}
    return run_one(getattr(obj, mname), params, target, bad, time_limit_s=time_limit_s,
                   extra=lambda _w: values)


@pytest.mark.parametrize("entry", [pytest.param(m, id=m[0]) for m in METHODS])
def test_method_ordinary_call_is_valid(entry):
    kind, detail = _call(entry, None, None, time_limit_s=30.0)
    assert kind == "ok", f"{entry[0]}: {kind} {detail}"


@pytest.mark.parametrize("entry", [pytest.param(m, id=m[0]) for m in METHODS])
def test_method_survives_every_hostile_value(entry):
    failures = []
    for p in entry[3]:
        for bad in sorted(BAD):
            kind, detail = _call(entry, p.name, BAD[bad])
            if kind == "nan" and entry[0] in NAN_DOCUMENTED:
                continue
            if kind in ("raw", "hang", "nan"):
                failures.append(f"{entry[0]}({p.name}={bad}): {kind} {detail}")
    assert not failures, "\n".join(failures[:20])


def test_method_suite_covers_the_core_classes():
    """Every exported class of the three subpackages is built, and its methods are reached."""
    names = {m[0].rsplit(".", 1)[0] for m in METHODS}
    for must in ("models.MeshObject", "models.Contacts", "models.ProximityModel", "models.Symmetry",
                 "belief.PoseRegion", "belief.ParticleBelief", "belief.ScalingSeries", "belief.SMCFilter",
                 "mapping.ShapeMap[gpis]", "mapping.ShapeMap[occupancy]", "mapping.TactileSLAM"):
        assert must in names, must
    assert len(METHODS) >= 60
