"""The on-disk caches: per-mesh structures (touchloc._cache) and numba's kernel cache."""

import dataclasses
import json
import os
import re
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

from touchloc import _cache
from touchloc.data import load_object, mesh_path
from touchloc.models import MeshObject, ProximityModel
from touchloc.models import _kernels as K

# a coarse grid: builds in a fraction of a second, same code path as the default
CELL = 0.012


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A fresh cache directory; every structure is written, however fast its build."""
    d = tmp_path / "cache"
    monkeypatch.setenv("TOUCHLOC_CACHE_DIR", str(d))
    monkeypatch.setattr(_cache, "MIN_SAVE_SECONDS", 0.0)
    _cache.stats.clear()
    return d


def _mug(scale=1.0):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the mug is open: warned about and tested elsewhere
        return MeshObject.from_file(mesh_path("mug"), scale=scale, name="mug")


def _quiet(f, *a):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a)


def _grid(obj, cell=CELL, sigma_nor=0.3):
    model = ProximityModel(obj, 0.003, sigma_nor, grid_cell=cell)
    return model, model._grid(model._weight(True))


def _files(d):
    return sorted(p.relative_to(d) for p in d.rglob("*.npz"))


def _same(a, b):
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y), f.name
        else:
            assert x == y and type(x) is type(y), f.name


def test_round_trip_gives_identical_grid_and_costs(cache, rng):
    model1, g1 = _grid(_mug())
    assert _cache.stats["miss"] >= 1 and _cache.stats["write"] >= 1 and _cache.stats["hit"] == 0
    files = _files(cache)
    assert any(str(f).startswith("candidate_grid/") for f in files)

    model2, g2 = _grid(_mug())  # a new object: nothing cached in memory
    assert _cache.stats["hit"] >= 1
    assert _files(cache) == files
    _same(g1, g2)
    P = rng.normal(scale=0.05, size=(500, 3))
    N = rng.normal(size=(500, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    np.testing.assert_array_equal(model1.query_costs(P, N, method="fast"), model2.query_costs(P, N, method="fast"))


def test_bvh_round_trip(cache):
    t1 = _mug().bvh(0.01)
    t2 = _mug().bvh(0.01)
    assert _cache.stats["hit"] == 1
    _same(t1, t2)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "other key"])
def test_damaged_file_is_rebuilt_with_a_warning(cache, damage):
    _, g1 = _grid(_mug())
    (path,) = [cache / f for f in _files(cache) if str(f).startswith("candidate_grid/")]
    data = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not a cache file" * 10)
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    else:  # a valid file whose stored key is not the one its name promises
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["meta_key"] = np.asarray("0" * 64)
        with open(path, "wb") as f:
            np.savez(f, **arrays)
    with pytest.warns(_cache.CacheWarning, match="rebuilding"):
        _, g2 = _grid(_mug())
    assert _cache.stats["corrupt"] == 1
    _same(g1, g2)
    # the rebuilt structure replaced the damaged file: the next process reads it cleanly
    with warnings.catch_warnings():
        warnings.simplefilter("error", _cache.CacheWarning)
        _, g3 = _grid(_mug())
    assert _cache.stats["hit"] >= 1
    _same(g1, g3)


def test_key_changes_with_mesh_and_parameters(cache):
    mug = _mug()
    base = dict(w=0.01, cell=CELL)
    k = _cache.structure_key("candidate_grid", mug, base, (K,))
    assert k == _cache.structure_key("candidate_grid", _mug(), dict(base), (K,))  # same content, new object
    others = [
        _cache.structure_key("candidate_grid", _mug(scale=0.5), base, (K,)),  # scaled mesh
        _cache.structure_key("candidate_grid", _quiet(load_object, "can"), base, (K,)),  # another mesh
        _cache.structure_key("candidate_grid", mug, dict(base, cell=CELL * 1.0000001), (K,)),
        _cache.structure_key("candidate_grid", mug, dict(base, w=0.0), (K,)),
        _cache.structure_key("bvh", mug, base, (K,)),  # another kind
        _cache.structure_key("candidate_grid", mug, base, ()),  # other builder code
    ]
    assert len({k, *others}) == len(others) + 1
    # and on disk: other parameters write another file, the same ones do not
    _grid(mug)
    n = len(_files(cache))
    _grid(_mug())
    assert len(_files(cache)) == n
    _grid(_mug(), cell=CELL * 1.25)
    _grid(_mug(), sigma_nor=0.2)
    assert len([f for f in _files(cache) if str(f).startswith("candidate_grid/")]) == 3


def test_key_changes_when_format_version_changes(cache, monkeypatch):
    mug = _mug()
    k = _cache.structure_key("bvh", mug, {"w": 1.0})
    monkeypatch.setattr(_cache, "FORMAT_VERSION", _cache.FORMAT_VERSION + 1)
    assert _cache.structure_key("bvh", mug, {"w": 1.0}) != k


@pytest.mark.parametrize("value", ["off", "OFF", "0", "none"])
def test_off_disables_the_cache(tmp_path, monkeypatch, value):
    monkeypatch.setenv("TOUCHLOC_CACHE_DIR", value)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setattr(_cache, "MIN_SAVE_SECONDS", 0.0)
    _cache.stats.clear()
    assert _cache.cache_dir() is None
    _grid(_mug())
    _grid(_mug())
    assert _cache.stats["hit"] == 0 and _cache.stats["write"] == 0 and _cache.stats["miss"] >= 2
    assert list(tmp_path.rglob("*.npz")) == []
    assert _cache.info()["dir"] is None and _cache.clear() == 0


def test_default_directory_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.delenv("TOUCHLOC_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _cache.cache_dir() == tmp_path / "xdg" / "touchloc"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _cache.cache_dir() == tmp_path / "home" / ".cache" / "touchloc"


def test_unwritable_directory_warns_and_still_computes(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    monkeypatch.setenv("TOUCHLOC_CACHE_DIR", str(blocker / "cache"))  # below a file: never writable
    monkeypatch.setattr(_cache, "MIN_SAVE_SECONDS", 0.0)
    _cache.stats.clear()
    with pytest.warns(_cache.CacheWarning, match="could not write"):
        _, g = _grid(_mug())
    assert g.offsets[-1] == len(g.ids) > 0
    assert _cache.stats["write_error"] >= 1 and _cache.stats["write"] == 0


def test_info_and_clear(cache):
    _grid(_mug())
    inf = _cache.info()
    assert inf["dir"] == cache and inf["kinds"]["candidate_grid"][0] == 1
    assert inf["kinds"]["candidate_grid"][1] > 0
    n = len(_files(cache))
    assert _cache.clear() == n
    assert _files(cache) == []


# -- across processes ---------------------------------------------------------------------

_CHILD = textwrap.dedent("""
    import json, sys, warnings
    warnings.simplefilter("ignore")
    from touchloc import _cache
    _cache.MIN_SAVE_SECONDS = 0.0
    from touchloc.data import load_object
    from touchloc.models import ProximityModel
    import numpy as np
    model = ProximityModel(load_object("mug"), 0.003, 0.3, grid_cell=%r)
    c = model.query_costs(np.zeros((3, 3)), np.eye(3), method="fast")
    print(json.dumps({"stats": dict(_cache.stats), "events": [e[:2] for e in _cache.events],
                      "costs": c.tolist()}))
""" % CELL)


def _child(env):
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_second_process_loads_from_the_cache(tmp_path):
    env = dict(os.environ, TOUCHLOC_CACHE_DIR=str(tmp_path / "c"))
    first = _child(env)
    second = _child(env)
    assert ["candidate_grid", "built"] in first["events"] and first["stats"].get("hit", 0) == 0
    assert ["candidate_grid", "loaded"] in second["events"] and second["stats"].get("miss", 0) == 0
    assert first["costs"] == second["costs"]


def test_concurrent_processes_share_the_cache_safely(tmp_path):
    env = dict(os.environ, TOUCHLOC_CACHE_DIR=str(tmp_path / "c"))
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(3)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1] for o in outs]
    costs = {json.dumps(json.loads(o[0].strip().splitlines()[-1])["costs"]) for o in outs}
    assert len(costs) == 1
    assert list((tmp_path / "c").rglob("*.tmp")) == []  # no temporary file left behind
    after = _child(env)
    assert after["stats"].get("corrupt", 0) == 0 and after["stats"]["hit"] >= 1


def test_kernel_cache_falls_back_when_nothing_is_writable(tmp_path):
    """A read-only install with a read-only home: kernels go to touchloc's cache directory,
    or (when that is unwritable too) are compiled per process; importing never fails."""
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    src = tmp_path / "pkg" / "mod.py"
    src.parent.mkdir()
    src.write_text("")
    (src.parent / "__pycache__").write_text("a file where numba wants a directory")
    code = textwrap.dedent(f"""
        import numba, json
        from touchloc._cache import numba_cache_enabled
        ok = numba_cache_enabled({str(src)!r})
        print(json.dumps([ok, numba.config.CACHE_DIR]))
    """)
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "TOUCHLOC_CACHE_DIR")}
    env = dict(base, XDG_CACHE_HOME=str(blocker / "xdg"), HOME=str(blocker / "home"),
               TOUCHLOC_CACHE_DIR=str(tmp_path / "tl"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == [True, str(tmp_path / "tl" / "numba")]
    env["TOUCHLOC_CACHE_DIR"] = str(blocker / "tl")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)[0] is False
    # an explicit but unwritable NUMBA_CACHE_DIR: no disk cache, and the kernels still import
    env = dict(base, NUMBA_CACHE_DIR=str(blocker / "nb"))
    code2 = ("import touchloc.models._kernels as K, touchloc.belief._cover as C; "
             "print(K._NB['cache'], C._NB['cache'])")
    out = subprocess.run([sys.executable, "-c", code2], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False False"


# -- the command line ---------------------------------------------------------------------

def _touchloc(args, env):
    out = subprocess.run([sys.executable, "-c", "import sys; from touchloc.cli import main; sys.exit(main())", *args],
                         env=env, capture_output=True, text=True, timeout=900)
    return out.returncode, out.stdout, out.stderr


def test_cli_reports_set_up_apart_and_reuses_the_grid(tmp_path):
    obj = _mug()
    rng = np.random.default_rng(3)
    p, n, _ = obj.sample_surface(8, rng=rng)
    csv = tmp_path / "c.csv"
    np.savetxt(csv, np.hstack([p + [0.01, 0.0, 0.0], n]), delimiter=",", header="x,y,z,nx,ny,nz", comments="")
    env = dict(os.environ, TOUCHLOC_CACHE_DIR=str(tmp_path / "c"))
    args = ["localize", "--mesh", "mug", "--contacts", str(csv), "--rotation", "yaw", "--half-extent", "0.05"]
    rc1, out1, err1 = _touchloc(args, env)
    rc2, out2, err2 = _touchloc(args, env)
    assert rc1 == 0 and rc2 == 0, err1 + err2
    assert re.search(r"set-up: [\d.]+ s: kernels .*candidate grid [\d.]+ s \(built and cached\)", out1), out1
    assert re.search(r"candidate grid [\d.]+ s \(loaded from the cache\)", out2), out2
    assert re.search(r"time: [\d.]+ s localisation \(set-up [\d.]+ s more\)", out2)
    # the same answer either way
    pose = lambda out: out.split("MAP pose T_world_object:")[1].split("quat_xyzw")[0]  # noqa: E731
    assert pose(out1) == pose(out2)

    rc, out, _ = _touchloc(["cache", "info"], env)
    assert rc == 0 and str(tmp_path / "c") in out and "candidate_grid: 1 file" in out
    rc, out, _ = _touchloc(["cache", "clear"], env)
    assert rc == 0 and re.search(r"removed [1-9]\d* cached structure", out)
    assert list((tmp_path / "c").rglob("*.npz")) == []
    rc, out, _ = _touchloc(["cache"], dict(os.environ, TOUCHLOC_CACHE_DIR="off"))
    assert rc == 0 and "off" in out


def test_warmup_command_builds_a_mesh_into_the_cache(tmp_path):
    env = dict(os.environ, TOUCHLOC_CACHE_DIR=str(tmp_path / "c"))
    rc, out, err = _touchloc(["warmup", "--mesh", "milk"], env)
    assert rc == 0, err
    assert out.startswith("kernels: ") and "milk: set-up:" in out
    assert any(p.parent.name == "candidate_grid" for p in (tmp_path / "c").rglob("*.npz"))


def test_the_parallel_warmup_parts_cover_every_kernel_of_warm_kernels():
    """`touchloc warmup` compiles two parts in two processes: together they must give every
    kernel (and signature) that warm_kernels(full=True) loads, or the first command after
    an install would still compile. Run in a fresh process, parts in-process (the kernels
    load from numba's cache), then warm_kernels must add no signature."""
    code = textwrap.dedent("""
        import numba, warnings
        warnings.simplefilter("ignore")
        from touchloc import _warmup as W
        from touchloc.models import _kernels as K, _bounds as B
        from touchloc.belief import _cover as C
        from touchloc.models import integrated as I
        from touchloc.mapping import gpis as G
        from touchloc.dnf import _kernels as D

        def signatures():
            return {(m.__name__, n): set(d.signatures) for m in (K, B, C, I, G, D) for n, d in vars(m).items()
                    if isinstance(d, numba.core.registry.CPUDispatcher)}

        assert W.PARTS == ("serial", "parallel")
        for part in W.PARTS:
            W._warm_part(part, True)
        before = signatures()
        W.warm_kernels(full=True)
        after = signatures()
        new = {k: sorted(map(str, after[k] - before[k])) for k in after if after[k] - before[k]}
        assert not new, new
        assert sum(bool(v) for v in after.values()) >= 10
        assert W.compile_in_processes(jobs=1) == 0  # one job: nothing to do in other processes
        print("ok")
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr[-2000:]


def _njit_in_module(modname):
    import numba

    ns = {"__name__": modname}
    exec("def f(x):\n    return x + 1\n", ns)
    return numba.njit(cache=False)(ns["f"])


def test_compile_notice_is_printed_once_for_touchloc_kernels_only():
    import io

    from touchloc._warmup import NOTICE, CompileNotice

    buf = io.StringIO()
    with CompileNotice(file=buf) as cn:
        _njit_in_module("someone_else")(1)
        assert buf.getvalue() == "" and cn.count == 0
        f = _njit_in_module("touchloc._notice_test")
        f(1)
        f(1.5)  # a second signature compiles again, but says nothing more
    assert buf.getvalue() == NOTICE + "\n"
    assert cn.count == 2 and cn.seconds > 0
    buf2 = io.StringIO()
    with CompileNotice(file=buf2) as cn2:
        f(2)  # already compiled: no event
    assert buf2.getvalue() == "" and cn2.count == 0


def test_warm_kernels_leaves_nothing_for_a_localisation_to_load_or_compile():
    """After warm_kernels(), a Scaling Series localisation (large enough for the parallel
    kernels and both cover counts) adds no signature to any kernel of the proximity
    model or of the cover."""
    import numba

    from touchloc._warmup import warm_kernels
    from touchloc.belief import PoseRegion, ScalingSeries
    from touchloc.belief import _cover as C
    from touchloc.models import Contacts

    def signatures():
        return {(m.__name__, n): set(d.signatures) for m in (K, C) for n, d in vars(m).items()
                if isinstance(d, numba.core.registry.CPUDispatcher)}

    warm_kernels()
    before = signatures()
    obj = _mug()
    pts, nrm, _ = obj.sample_surface(10, rng=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ScalingSeries(ProximityModel(obj, 0.002, 0.1, grid_cell=CELL), rng=0).localize(
            Contacts(pts, nrm), PoseRegion.box((0, 0, 0), 0.05, "full"))
    after = signatures()
    new = {k: after[k] - before[k] for k in after if after[k] - before[k]}
    assert not new, new
    used = {n for (m, n), s in after.items() if s}
    assert {"_count_in_lists", "_count_in_lists_serial", "_csr", "_bvh_query", "_grid_query"} <= used
