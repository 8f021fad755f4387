"""Hostile arguments for the public methods of the exported classes.

test_fuzz_public.py calls every exported name; a user also calls the methods of what those
names return (``belief.credible_set(level)``, ``region.sample(n)``, ``smap.to_mesh(resolution)``).
Here every public method of every class exported by :data:`METHOD_MODULES` is called, one
parameter at a time, with each hostile value of the function suite, on an instance built from
ordinary values. Each call must end in a :class:`~touchloc.errors.TouchlocError` or a result
without NaN, within the time limit. Each method's ordinary call must succeed, so that each
hostile value meets a call that would otherwise have worked. A fresh instance serves every
call, so that a hostile value cannot be masked by an earlier call's side effects.

The SDH-2 and DSACON32m drivers are called on one emulated rig shared by the module
(the emulators speak the devices' bytes over loopback TCP), so a hostile call must also
leave the driver usable. Left out (:data:`DEVICES`, :data:`EXCLUDED`): what runs a whole
guarded touch per call, which test_hw_touch.py runs on the emulator.
"""

from __future__ import annotations

import enum
import inspect
import warnings

import numpy as np
import pytest

pytest.importorskip("hypothesis")

from test_fuzz_public import BAD, CHEAP, _call_kwargs, _hardware_args, _mapping_args, run_one, world  # noqa: E402

@pytest.fixture(autouse=True, scope="module")
def _in_a_scratch_directory(tmp_path_factory):
    """The suite writes files (a contacts CSV, a mesh, a map, sweeps) and hostile calls may
    write files named by their arguments: keep them out of the working tree."""
    import os

    import test_fuzz_public

    # the function suite's world writes files where it is first built: build our own here,
    # and leave none behind for the function suite, whose directory is another one
    old = os.getcwd()
    test_fuzz_public._WORLD = None
    os.chdir(tmp_path_factory.mktemp("fuzz-methods"))
    yield
    if _RIG:
        # the hand and tactile sensor are the rig's: a later set-up of this module in the same
        # process (a test runner that splits a file) starts a new rig, not the closed ports
        _RIG.pop("rig").close()
        _RIG.clear()
    test_fuzz_public._WORLD = None
    os.chdir(old)


METHOD_MODULES = ["touchloc.models", "touchloc.belief", "touchloc.mapping", "touchloc.planners", "touchloc.dnf",
                  "touchloc.recognition", "touchloc.experiments", "touchloc.hardware"]

#: hardware classes left out: a whole guarded touch per call (test_hw_touch runs it on the emulator)
DEVICES = {"hardware.HandWorld"}

#: classes that only define an interface (their methods raise NotImplementedError by design)
INTERFACES = {"models.MeasurementModel", "models.FreeSpaceBase", "planners.Utility"}

#: methods left out, with the reason
EXCLUDED = {
    f"planners.{cls}.{m}": "the planner's callback protocol for utilities: the planner calls it on its own "
                           "arrays in its inner loop; users implement it rather than call it"
    for cls in ("NegEntropy", "KLDivergence", "TaskSuccess") for m in ("prepare", "values", "subset")
} | {
    f"hardware.GuardedTouchExecutor.{m}": "a whole guarded touch per call: test_hw_touch runs it on the emulator"
    for m in ("execute", "execute_action")
} | {"hardware.SDH2.over_can": "a constructor that connects over a CAN bus: test_hw_sdh2 runs it on the virtual bus"}


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


def _plan(w):
    from touchloc.planners import OneStepPlanner

    return OneStepPlanner(w["model"], n_representatives=4, max_particles=50).plan(_belief(w), w["candidates"], rng=0)


def _task(w):
    from touchloc.planners import TaskSuccess

    return TaskSuccess((0.01, 0.01, 0.01, 0.1))


def _fitted(name):
    def build(w):
        import touchloc.recognition as rec

        return getattr(rec, name)().fit(w["X"], w["y"])
    return build


def _llm(w):
    from touchloc.recognition import LocalLinearMap

    return LocalLinearMap(3, epochs=3, rng=0).fit(w["P"], w["T"])


def _sweep_files(w):
    if "sweep_files" not in w:
        with open("fuzz-sweep.toml", "w") as fh:
            fh.write('meshes = ["can"]\ncontacts = [3]\nseeds = 1\n[[estimators]]\nname = "pf"\nn_particles = 50\n')
        with open("fuzz-dnf-sweep.toml", "w") as fh:
            fh.write('kind = "dnf"\nsides = [6]\nsets = 1\nrevolutions = 0.05\n')
        w["sweep_files"] = True
    return w


#: one emulated hand with tactile pads, served over loopback TCP, for the whole module
_RIG: dict = {}


def _device(kind):
    """The SDH-2 or DSACON32m driver of the module's emulated rig (the drivers and the
    emulators are shared by every call: a hostile call must leave them usable)."""
    def build(w):
        if not _RIG:
            from touchloc.hardware.emulator import EmulatedRig

            rig = _RIG["rig"] = EmulatedRig(hand_transport="tcp", tactile_transport="tcp", time_scale=50.0).start()
            _RIG["hand"] = rig.open_hand(timeout=0.5)
            _RIG["tactile"] = rig.open_tactile(timeout=0.5)
        return _RIG[kind]
    return build


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
    "planners.Plan": _plan,
    "planners.TaskSuccess": _task,
    "dnf.MemoryTrace": lambda w: __import__("touchloc.dnf").dnf.MemoryTrace(36),
    "dnf.RotationDataset": lambda w: CHEAP["dnf.compare"](w)["ds"],
    "recognition.SequenceClassifier": _fitted("SequenceClassifier"),
    "recognition.NearestNeighbourClassifier": _fitted("NearestNeighbourClassifier"),
    "recognition.LocalLinearMap": _llm,
    "hardware.SDH2": _device("hand"),
    "hardware.DSACON32m": _device("tactile"),
}

_EYE4 = np.eye(4)

#: ordinary values by name for the hardware methods: finger 0 at a 0.3 rad base angle, its
#: distal pad, a point of its plane in reach, and a touch along that plane; for the drivers,
#: a posture inside the limits, a harmless query, slow motions, and streaming left on
_HARDWARE = dict(finger=0, a0=0.3, matrix=1, x=1.0, y=2.0, r=0.08, z=0.1, start=(0.05, 0.12), end=(0.09, 0.12),
                 name="fuzz", angles=np.radians([60.0, -10, 10, -10, 10, -10, 10]), cmd="v", timeout=0.5, mode=0,
                 preset=1, close=0.5, velocity=20.0, accelerations=np.full(7, 0.5), velocities=np.full(7, 0.1),
                 poll=0.005, on=None, framerate=30, rle=True, n=1, skip_bad=False, m=1, value=0.5,
                 persistent=False, all_matrices=False, reset=False, wait=False)

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
    "planners.TaskSuccess.offsets": lambda w: dict(ref_poses=w["poses"], region=_region(w)),
    "planners.TaskSuccess.success": lambda w: dict(belief=_belief(w), grasp_pose=_EYE4),
    "planners.IdentityPlanner.plan": lambda w: dict(beliefs={"box": _belief(w)}, probabilities={"box": 1.0}),
    "dnf.OrientationTracker.run": lambda w: dict(dataset=CHEAP["dnf.compare"](w)["ds"]),
    "dnf.OrientationTracker.step": dict(normal_angles=[0.1, 0.2], odometry=0.01),
    "dnf.HistogramEstimator.step": dict(normal_angles=[0.1, 0.2], odometry=0.01),
    "dnf.ParticleOrientationEstimator.step": dict(normal_angles=[0.1, 0.2], odometry=0.01),
    "dnf.MemoryTrace.step": dict(f=np.zeros(36)),
    "dnf.RotationDataset.angles": dict(t=0),
    "recognition.TactileScanner.scan_many": dict(n_scans=1),
    "experiments.SerialExecutor.map": dict(fn=abs),
    "hardware.SDH2Kinematics.with_matrix_info": lambda w: dict(infos=[__import__("touchloc.hardware").hardware.MatrixInfo(
        error=0, texel_width=3.4, texel_height=3.4, cells_x=6, cells_y=13, uid=b"", hw_revision=0, center=(0, 0, 0),
        theta=(0, 0, 0), fullscale=4095.0, features=0)] * 6),
    "hardware.SDH2Kinematics.touch_plane": lambda w: dict(origin=w["kinematics"].plane_to_hand(0, 0.3, 0.05, 0.12),
                                                          direction=w["kinematics"].closing_direction(0, 0.3)),
    "hardware.GuardedTouchExecutor.plan": lambda w: dict(touch=w["executor"].touch_pool(1, rng=0)[0], finger=None),
    "hardware.PadLayout.local_coordinates": dict(x=1.0, y=2.0),
    "hardware.DSACON32m.set_threshold": dict(value=10),
    "hardware.DSACON32m.configure_acquisition": dict(start=True),
    "hardware.SDH2.grip": dict(velocity=100.0),       # wait=True (a valid value) then waits under a second
    "recognition.LocalLinearMap.fit": dict(T=np.random.default_rng(0).normal(size=(12, 2))),
    "experiments.Sweep.from_dict": dict(d={"meshes": ["can"], "contacts": [3], "seeds": 1}),
    "experiments.Sweep.from_toml": lambda w: dict(path=(_sweep_files(w), "fuzz-sweep.toml")[1]),
    "experiments.DNFSweep.from_dict": dict(d={"sides": [6], "sets": 1, "revolutions": 0.05}),
    "experiments.DNFSweep.from_toml": lambda w: dict(path=(_sweep_files(w), "fuzz-dnf-sweep.toml")[1]),
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
            if not inspect.isclass(cls) or issubclass(cls, (BaseException, enum.Enum)) or key in INTERFACES | DEVICES:
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
            if mname.startswith("_") or not callable(member) or inspect.isclass(member) \
                    or f"{key.split('[')[0]}.{mname}" in EXCLUDED:
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
    if name.startswith("hardware."):
        values = {**values, **_hardware_args(w), **_HARDWARE}
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
    assert {m.split(".")[0] for m in names} == {m.split(".")[-1] for m in METHOD_MODULES}
    assert len(METHODS) >= 130


def test_files_states_and_poses_users_meet(tmp_path):
    """What the suite found on ordinary calls, and a reflection posing as a pose."""
    from touchloc.errors import TouchlocError, ValidationError
    from touchloc.experiments import Sweep
    from touchloc.experiments.runner import SerialExecutor
    from touchloc.recognition import LocalLinearMap, TactileScanner
    from touchloc.recognition.classifier import NotFittedError

    binary = tmp_path / "sweep.toml"
    binary.write_bytes(b"meshes = [\x8e\xff]\n")
    with pytest.raises(ValidationError, match="UTF-8"):
        Sweep.from_toml(binary)
    with pytest.raises(NotFittedError, match="fit"):
        LocalLinearMap(3).predict(np.zeros((2, 3)))
    ex = SerialExecutor()
    assert list(ex.map(abs, [-1, 2])) == [1, 2]
    ex.shutdown()
    with pytest.raises(TouchlocError, match="shutdown") as err:
        ex.submit(abs, -1)
    assert isinstance(err.value, RuntimeError)       # what concurrent.futures callers expect
    flip = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValidationError, match="reflection"):
        TactileScanner().scan(world()["obj"], object_pose=flip, rng=0)


def test_writers_turn_an_unwritable_path_into_a_library_error(tmp_path):
    """A file in a directory that does not exist: a ValidationError naming the file, nothing raw."""
    from touchloc import dnf
    from touchloc.errors import ValidationError

    w = world()
    nowhere = tmp_path / "no-such-dir"
    writers = [(w["contacts"].to_csv, "contacts.csv"), (_shape_map("occupancy")(w).save, "map.npz"),
               (lambda p: dnf.save_recording(CHEAP["dnf.compare"](w)["ds"], p), "rec.npz"),
               (lambda p: dnf.save_recording(CHEAP["dnf.compare"](w)["ds"], p), "rec.csv")]
    for write, name in writers:
        with pytest.raises(ValidationError, match="cannot write"):
            write(nowhere / name)
        assert not nowhere.exists()
