"""Property-based fuzzing of every public callable of models, belief, planners and dnf.

Every name in the ``__all__`` of those subpackages that can be called (functions and class
constructors) is called with hostile arguments: one argument at a time gets a wrong type,
NaN/inf, a wrong shape, an empty array, a huge or a negative value, while the others get
ordinary values looked up by parameter name. Each call must end within a time limit in a
:class:`~touchloc.errors.TouchlocError` or a result without NaN. Names added to an
``__all__`` join the suite on their own.
"""

from __future__ import annotations

import importlib
import inspect
import math
import signal
import warnings
from contextlib import contextmanager

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from touchloc.errors import TouchlocError  # noqa: E402

MODULES = ["touchloc.models", "touchloc.belief", "touchloc.planners", "touchloc.dnf", "touchloc.mapping"]
N_EXAMPLES = 30        # hostile calls per public callable
TIME_LIMIT = 3.0       # seconds per call: beyond it the call counts as a hang


@pytest.fixture(autouse=True, scope="module")
def _in_a_scratch_directory(tmp_path_factory):
    """Hostile calls may write files named by their arguments ("x" -> x.npz): keep them out
    of the working tree."""
    import os

    old = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("fuzz"))
    yield
    os.chdir(old)


class CallTimeout(BaseException):
    """Raised by the alarm inside a call that ran past TIME_LIMIT."""


@contextmanager
def time_limit(seconds: float):
    def _raise(signum, frame):
        raise CallTimeout(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, _raise)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _reflection():
    T = np.eye(4)
    T[0, 0] = -1.0
    return T


#: hostile values: wrong types, non-finite, wrong shapes, empty, huge, negative
BAD = {
    "None": None, "str": "x", "list_empty": [], "list2": [1, 2], "dict": {}, "bool": True,
    "object": object(), "complex": 1j, "neg_int": -1, "zero": 0, "neg": -1.5, "nan": float("nan"),
    "inf": float("inf"), "-inf": float("-inf"), "huge": 1e300, "huge_int": 10**13,
    "nan_matrix": np.full((2, 2), np.nan), "empty_pts": np.zeros((0, 3)), "vec5": np.zeros(5),
    "eye3": np.eye(3), "reflection": _reflection(), "str_array": np.array(["a", "b"]),
    "nan_pts": np.full((4, 3), np.nan), "neg_big": -10**9, "tiny": 1e-300,
}


def _world():
    """Ordinary argument values, by parameter name (built once)."""
    import trimesh

    from touchloc.belief import ParticleBelief, PoseRegion
    from touchloc.models import Contacts, MeshObject, ProximityModel
    from touchloc.planners import GuardedTouch, RandomPlanner, SimulatedWorld, TouchResult

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        obj = MeshObject(trimesh.creation.box((0.05, 0.04, 0.03)), name="box")
    model = ProximityModel(obj, 0.002, 0.1)
    pts, nrm, _ = obj.sample_surface(3, rng=0)
    contacts = Contacts(pts, nrm)
    region = PoseRegion.box((0, 0, 0), 0.01, "yaw")
    poses = region.sample(8, rng=0)
    touch = GuardedTouch((0.0, 0.0, 0.2), (0.0, 0.0, -1.0), 0.4)
    v = {
        "obj": obj, "mesh": obj.mesh, "model": model, "models": {"box": model}, "contacts": contacts,
        "region": region, "poses": poses, "pose": np.eye(4), "true_pose": np.eye(4), "T_est": np.eye(4),
        "T_true": np.eye(4), "belief": ParticleBelief(poses), "points": pts, "normals": nrm,
        "starts": pts + 0.1, "ends": pts, "sigma_pos": 0.002, "sigma_nor": 0.1, "sigma_met": 0.001,
        "sigma_ang": 0.01, "center": (0, 0, 0), "half_extent": 0.01, "origin": (0.0, 0.0, 0.2),
        "direction": (0.0, 0.0, -1.0), "max_travel": 0.4, "touch": touch, "touches": (touch,),
        "travel": 0.1, "actions": [touch], "action": touch, "candidates": [touch], "n_sides": 6,
        "activation": np.zeros(360), "a": np.zeros(36), "u": np.zeros(36), "angles": np.zeros(3),
        "weights": np.full(4, 0.25), "n": 4, "name": "x", "results": [TouchResult(touch, 0.4, None)],
        "planner": RandomPlanner(), "n_sites": 36, "width": 0.1, "gain": 1.0, "estimate": np.zeros(5),
        "truth": np.zeros(5), "tolerances": (0.01, 0.1), "cost": None, "objects": {"box": obj},
        "field": np.zeros(36), "n_other": 4, "F": np.zeros((36, 36)), "x": np.zeros(36),
        "params": None, "progress": False, "progress_bar": False, "datasets": {}, "results_": {}, "index": 0, "delta": 0.1,
    }
    v["world"] = SimulatedWorld(obj, np.eye(4), rng=0)
    return v


_WORLD = None


def world():
    global _WORLD
    if _WORLD is None:
        _WORLD = _world()
    return _WORLD


def public_callables():
    out = []
    for modname in MODULES:
        mod = importlib.import_module(modname)
        for name in mod.__all__:
            obj = getattr(mod, name)
            if not callable(obj) or (inspect.isclass(obj) and issubclass(obj, BaseException)):
                continue
            try:
                sig = inspect.signature(obj)
            except (TypeError, ValueError):
                continue
            params = [p for p in sig.parameters.values()
                      if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.name != "self"]
            out.append((f"{modname.split('.')[-1]}.{name}", obj, params))
    return out


CALLABLES = public_callables()


def _has_nan(x, depth=0) -> bool:
    if depth > 2:
        return False
    if isinstance(x, float):
        return math.isnan(x)
    if isinstance(x, np.ndarray) and x.dtype.kind in "fc":
        if x.size > 10**7:  # a broadcast view: check the memory actually held
            return bool(np.isnan(np.lib.stride_tricks.as_strided(x, (min(x.size, 10**6),), (x.itemsize,))).any()) \
                if x.flags.c_contiguous else False
        return bool(np.isnan(x).any())
    if isinstance(x, (list, tuple)) and len(x) < 1000:
        return any(_has_nan(e, depth + 1) for e in x)
    if isinstance(x, dict) and len(x) < 1000:
        return any(_has_nan(e, depth + 1) for e in x.values())
    return False


def _call_kwargs(fn, params, target, bad):
    w = world()
    kwargs = {}
    for p in params:
        if p.name == target:
            kwargs[p.name] = bad
        elif p.name in w:
            kwargs[p.name] = w[p.name]
        elif p.default is inspect.Parameter.empty:
            kwargs[p.name] = None
    pos_only = [p for p in params if p.kind == p.POSITIONAL_ONLY]
    args = [kwargs.pop(p.name) for p in pos_only if p.name in kwargs]
    return fn(*args, **kwargs)


def run_one(fn, params, target, bad, time_limit_s=TIME_LIMIT):
    """One hostile call: returns ('ok' | 'error' | 'raw' | 'hang' | 'nan', detail)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with np.errstate(all="ignore"), time_limit(time_limit_s):
                out = _call_kwargs(fn, params, target, bad)
    except CallTimeout as exc:
        return "hang", str(exc)
    except TouchlocError:
        return "error", ""
    except Exception as exc:  # noqa: BLE001 - the point is to catch what escapes
        return "raw", f"{type(exc).__name__}: {exc}"[:200]
    if _has_nan(out):
        return "nan", type(out).__name__
    return "ok", ""


#: callables whose entry validation is still incomplete: the first unclean outcome found by an
#: exhaustive sweep (benchmarks/bench_reliability.py), as "kinds: parameter=value: outcome".
#: They run as non-strict xfails, so a fix shows up as XPASS and the entry can go.
UNCLEAN = {
    "models.MeshObject": "raw: name=empty_pts: raw ValueError: The truth value of an empty array is ambiguous. Use `array.size > 0` to check ",
    "models.SumModel": "raw: models=-inf: raw TypeError: 'float' object is not iterable",
    "models.IntegratedProximityModel": "raw: sigma_pos=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "belief.PoseRegion": "raw: center=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "belief.ParticleBelief": "raw: log_weights=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "belief.systematic_resample": "raw: weights=-inf: raw AttributeError: 'NoneType' object has no attribute 'random'",
    "belief.ScalingSeries": "raw: delta_final=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "belief.ParticleFilter": "raw: n_particles=-inf: raw OverflowError: cannot convert float infinity to integer",
    "belief.HistogramFilter": "raw: resolution=None: raw TypeError: '>' not supported between instances of 'NoneType' and 'int'",
    "belief.AnnealedParticleFilter": "raw: n_particles=-inf: raw OverflowError: cannot convert float infinity to integer",
    "belief.ManifoldParticleFilter": "raw: n_particles=-inf: raw OverflowError: cannot convert float infinity to integer",
    "belief.MCMC": "raw: n_walkers=-inf: raw OverflowError: cannot convert float infinity to integer",
    "belief.add_s": "raw: obj=-inf: raw AttributeError: 'float' object has no attribute '_cache'",
    "belief.add": "raw: obj=-inf: raw AttributeError: 'float' object has no attribute '_cache'",
    "belief.pose_errors": "raw: T_est=-inf: raw IndexError: too many indices for array: array is 0-dimensional, but 2 were indexed",
    "planners.HandTouch": "raw: touches=-inf: raw TypeError: 'float' object is not iterable",
    "planners.TravelDistance": "raw: overhead=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "planners.TravelTime": "raw: speed=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "planners.execute": "raw: true_pose=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "planners.OneStepPlanner": "raw: utility=empty_pts: raw ValueError: The truth value of an empty array is ambiguous. Use `array.size > 0` to che",
    "planners.TwoStepPlanner": "raw: branch=-inf: raw OverflowError: cannot convert float infinity to integer",
    "planners.NegEntropy": "raw: floor=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "planners.TaskSuccess": "raw: tolerances=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "planners.SimulatedWorld": "raw: true_pose=-inf: raw ValueError: cannot reshape array of size 1 into shape (4,4)",
    "planners.add_s": "raw: obj=-inf: raw AttributeError: 'float' object has no attribute '_cache'",
    "planners.best_pose": "raw: belief=-inf: raw AttributeError: 'float' object has no attribute 'map_pose'",
    "planners.expected_add_s": "raw: belief=-inf: raw AttributeError: 'float' object has no attribute 'credible_set'",
    "planners.make_scenario": "raw: setting=empty_pts: raw ValueError: The truth value of an empty array is ambiguous. Use `array.size > 0` to che",
    "planners.EstimatorUpdater": "raw: model=-inf: raw AttributeError: 'float' object has no attribute 'obj'",
    "planners.IdentityPlanner": "raw: objects=-inf: raw TypeError: 'float' object is not iterable",
    "dnf.OrientationTracker": "raw: params=-inf: raw AttributeError: 'float' object has no attribute 'n_sites'",
    "dnf.count_surfaces": "raw: sigma=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "dnf.surface_peaks": "raw: sigma=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "dnf.HistogramEstimator": "raw: n_bins=huge_int: raw MemoryError: Unable to allocate 72.8 TiB for an array with shape (10000000000000,) and da",
    "dnf.normalize_max": "raw: a=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "dnf.population_code": "raw: angles=-inf: raw IndexError: invalid index to scalar variable.",
    "dnf.ParticleOrientationEstimator": "raw: n_particles=huge_int: raw MemoryError: Unable to allocate 72.8 TiB for an array with shape (10000000000000,) a",
    "dnf.compare": "raw: datasets=-inf: raw AttributeError: 'float' object has no attribute 'items'",
    "dnf.run_estimator": "raw: name=-inf: raw TypeError: 'NoneType' object is not callable",
    "dnf.orientation_error": "nan: estimate=-inf: nan ndarray",
    "dnf.summary_table": "raw: results=-inf: raw AttributeError: 'float' object has no attribute 'items'",
    "dnf.Field1D": "raw: n=huge_int: raw MemoryError: Unable to allocate 72.8 TiB for an array with shape (10000000000000,) and dat",
    "dnf.Field2D": "raw: shape=-inf: raw TypeError: object of type 'float' has no len()",
    "dnf.FieldParams": "raw: tau=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not be",
    "dnf.MemoryTrace": "raw: n=huge_int: raw MemoryError: Unable to allocate 72.8 TiB for an array with shape (10000000000000,) and dat",
    "dnf.sigmoid": "nan/raw: u=None: raw TypeError: unsupported operand type(s) for *: 'NoneType' and 'float'",
    "dnf.lateral_kernel": "raw: n=-inf: raw ValueError: Maximum allowed size exceeded",
    "dnf.circular_convolve": "nan/raw: x=-inf: raw IndexError: tuple index out of range",
    "dnf.expand": "raw: n_other=-inf: raw ValueError: all elements of broadcast shape must be non-negative",
    "dnf.diagonal_sum": "nan: F=nan_matrix: nan ndarray",
    "dnf.RotationDataset": "raw: time=complex: raw TypeError: float() argument must be a string or a real number, not 'complex'",
    "dnf.generate_rotation_dataset": "raw: revolutions=None: raw TypeError: ufunc 'isfinite' not supported for the input types, and the inputs could not ",
    "dnf.standard_datasets": "raw: objects=-inf: raw TypeError: 'float' object is not iterable",
    "dnf.load_recording": "raw: path=-inf: raw TypeError: expected str, bytes or os.PathLike object, not float",
    "dnf.save_recording": "raw: ds=-inf: raw TypeError: expected str, bytes or os.PathLike object, not NoneType",
    # names new in belief/ (under active change elsewhere): entry validation still to add
    "belief.symmetric_pose_error": "raw: T_true=None: raw ValueError: cannot reshape array of size 1 into shape (4,4)",
    "belief.credible_level": "raw: T_true=complex: raw TypeError: float() argument must be a string or a real number",
    "belief.belief_coverage": "raw: T_true=-inf: raw ValueError: cannot reshape array of size 1 into shape (4,4)",
    "belief.save_belief": "raw: extra=bool: raw TypeError: 'bool' object is not iterable",
    "belief.load_belief": "raw: path=-inf: raw TypeError: expected str, bytes or os.PathLike object, not float",
    "belief.pose_to_dict": "raw: T=complex: raw TypeError: float() argument must be a string or a real number",
}

#: a valid call of these runs a whole localisation (seconds); 30 calls exceed the budget of
#: the suite, so they are swept only by benchmarks/bench_reliability.py
TOO_SLOW = {
    "belief.identify": "one valid call localises every model with Scaling Series (seconds each)",
    "belief.log_evidence": "one valid call runs a full Scaling Series localisation (about 2 s)",
    "planners.active_localization": "one valid call runs a 20-touch active localisation (seconds)",
}


def _marks(name):
    if name in TOO_SLOW:
        return [pytest.mark.skip(reason=TOO_SLOW[name])]
    if name in UNCLEAN:
        return [pytest.mark.xfail(reason=UNCLEAN[name], strict=False)]
    return []


@pytest.mark.parametrize("entry", [pytest.param(c, id=c[0], marks=_marks(c[0])) for c in CALLABLES])
def test_public_callable_survives_hostile_arguments(entry):
    name, fn, params = entry
    if not params:
        pytest.skip(f"{name} takes no arguments")
    names = [p.name for p in params]
    failures = []

    @settings(max_examples=N_EXAMPLES, derandomize=True, database=None, deadline=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck))
    @given(target=st.sampled_from(names), bad=st.sampled_from(sorted(BAD)))
    def check(target, bad):
        kind, detail = run_one(fn, params, target, BAD[bad])
        if kind in ("raw", "hang", "nan"):
            failures.append(f"{name}({target}={bad}): {kind} {detail}")

    check()
    assert not failures, "\n".join(sorted(set(failures))[:20])


def test_suite_covers_every_public_callable():
    """At least 30 inputs per callable over every exported callable of the four subpackages."""
    assert len(CALLABLES) >= 80
    assert N_EXAMPLES >= 30
