"""The ``touchloc`` command: warnings, interruption, mesh files, outputs."""

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from touchloc import cli
from touchloc.belief import PoseRegion, load_belief
from touchloc.models import Contacts


SCRIPT = Path(sys.executable).with_name("touchloc")
COMMAND = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "touchloc.cli"]


def touchloc(*argv, timeout=600):
    """Run the installed command in a new process, as a user would."""
    return subprocess.run([*COMMAND, *map(str, argv)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def mug_csv(tmp_path_factory, objects):
    """Contacts on the mug at a planar pose; in metres and in millimetres."""
    d = tmp_path_factory.mktemp("contacts")
    obj = objects["mug"]
    T = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [0.004, -0.003, -obj.bounds[0][2]]
    pts, nrm, _ = obj.sample_surface(20, rng=3)
    con = Contacts(pts, nrm).transform(T)
    con.to_csv(d / "m.csv")
    Contacts(con.points * 1000, con.normals).to_csv(d / "mm.csv")
    return d / "m.csv", d / "mm.csv", T


PLANAR = ["--rotation", "planar", "--half-extent", "0.01", "--center", "0", "0", "0.0"]


def test_verbosity_options_on_every_subcommand():
    parser = cli.build_parser()
    for name, sub in parser._subparsers._group_actions[0].choices.items():
        opts = {o for a in sub._actions for o in a.option_strings}
        assert {"-q", "--quiet", "-v", "--verbose"} <= opts, name
    a = parser.parse_args(["localize", "--mesh", "mug", "--contacts", "c.csv", "-v"])
    assert a.verbose == 1 and not a.quiet
    a = parser.parse_args(["-q", "localize", "--mesh", "mug", "--contacts", "c.csv"])
    assert a.quiet and a.verbose == 0
    with pytest.raises(SystemExit):
        parser.parse_args(["localize", "--mesh", "mug", "--contacts", "c.csv", "-q", "-v"])


def test_warnings_reach_the_terminal_unless_quiet(tmp_path, capsys):
    # the bundled mug is open: loading it warns; the CSV then fails with a one-line error
    bad = tmp_path / "c.csv"
    bad.write_text("x,y,z\n")
    for argv, shown in ((["localize"], True), (["-q", "localize"], False), (["localize", "-v"], True)):
        assert cli.main(argv + ["--mesh", "mug", "--contacts", str(bad)]) == 1
        err = capsys.readouterr().err
        assert ("not watertight" in err) == shown, argv
        assert "c.csv: empty" in err
        if "-v" in argv:
            assert "MeshRepairWarning" in err


def test_degenerate_result_says_why_and_suggests_millimetres(mug_csv):
    _, mm, _ = mug_csv
    r = touchloc("localize", "--mesh", "mug", "--contacts", mm, "--method", "hf", *PLANAR)
    assert r.returncode == 1
    assert "degenerate" in r.stderr
    assert "millimetres" in r.stderr and "--center" in r.stderr
    assert "touchloc: warning:" in r.stderr  # the estimator's own warning is shown, too


def test_bad_csv_is_one_line_error_not_a_traceback(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("x;y;z\n1;2\n")
    r = touchloc("localize", "--mesh", "mug", "--contacts", p)
    assert r.returncode == 1
    assert "line 2" in r.stderr and "Traceback" not in r.stderr


def _interrupt(argv, marker, delay):
    """Start the command, wait for ``marker`` on stdout, then ``delay`` s, then send one SIGINT."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([*COMMAND, *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=env)
    try:
        seen = []
        for line in p.stdout:
            seen.append(line)
            if marker in line:
                break
        time.sleep(delay)
        alive = p.poll() is None
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    return alive, p.returncode, "".join(seen) + out, err


# 0 s and 0.5 s after the estimator's first line land while the kernels load from numba's
# cache (numba and LLVM code, where the interruption must wait); 3 s lands in the estimator
@pytest.mark.parametrize("delay", [0.0, 0.5, 3.0])
def test_ctrl_c_ends_with_one_line_and_exit_130(mug_csv, delay):
    m, _, _ = mug_csv
    # the annealed particle filter works for a minute or more: the signal always lands in the work
    alive, rc, out, err = _interrupt(["localize", "--mesh", "mug", "--contacts", m, "--method", "apf"],
                                     "method apf", delay)
    assert alive, "finished before it could be interrupted"
    assert rc == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err
    assert err.strip().splitlines()[-1] == "touchloc localize: interrupted"
    assert "MAP pose" not in out


@pytest.mark.parametrize("delay", [0.0, 0.05, 0.2])
def test_ctrl_c_after_the_work_never_kills_the_process_by_the_signal(mug_csv, delay):
    # the signal lands while the command prints its result or while Python shuts down
    m, _, _ = mug_csv
    _, rc, out, err = _interrupt(["localize", "--mesh", "mug", "--contacts", m, "--method", "hf", *PLANAR],
                                 "time:", delay)
    assert rc in (0, 130), (rc, err)
    assert "Traceback" not in err and "Exception ignored" not in err
    if rc == 130:
        assert err.strip().splitlines()[-1] == "touchloc localize: interrupted"


def test_interrupt_inside_numba_is_held_until_numba_returns():
    import numba
    from numba.core import event

    seen = {}

    class Listener(event.Listener):
        def on_start(self, ev):
            signal.raise_signal(signal.SIGINT)  # Ctrl-C while numba compiles

        def on_end(self, ev):
            seen["held"] = intr.held

    @numba.njit(cache=False)
    def add_one(x):
        return x + 1

    intr = cli._Interrupts()
    assert intr.install()
    listener = Listener()
    event.register("numba:compile", listener)
    result = None
    try:
        with pytest.raises(KeyboardInterrupt):
            result = add_one(1)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # delivered here, once numba has returned
                time.sleep(0.01)
    finally:
        event.unregister("numba:compile", listener)
        intr.uninstall()
    assert seen["held"] is True
    assert result == 2  # the compilation finished and its result came back before the interruption
    assert signal.getsignal(signal.SIGINT) is not intr


def test_interrupt_inside_numpys_ctypes_check_is_not_lost():
    # numpy's C code calls npy_ctypes_check while it builds a dtype and clears whatever it
    # raises: a KeyboardInterrupt raised there would vanish and the command would go on
    def trace(frame, event, arg):
        if event == "call" and frame.f_code.co_name == "npy_ctypes_check":
            signal.raise_signal(signal.SIGINT)  # Ctrl-C while numpy is inside the check
        return None

    intr = cli._Interrupts()
    assert intr.install()
    try:
        with pytest.raises(KeyboardInterrupt):
            sys.settrace(trace)
            try:
                dtype = np.dtype((np.void, 8))
            finally:
                sys.settrace(None)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # delivered here, once numpy has returned
                time.sleep(0.01)
    finally:
        intr.uninstall()
    assert dtype.itemsize == 8


def _idle(seconds):
    """Run Python (where an interruption can land) for ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        time.sleep(0.01)


def test_an_interruption_cleared_by_the_code_it_landed_in_is_raised_again(monkeypatch):
    # C code that calls back into Python may clear an exception at places nobody listed (a
    # ctypes callback reports it as "ignored" and returns): a KeyboardInterrupt that the
    # command never caught is raised again after _REDELIVER_AFTER
    import ctypes

    monkeypatch.setattr(cli, "_REDELIVER_AFTER", 0.2)
    ignored = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: ignored.append(u.exc_type))
    callback = ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(signal.SIGINT))
    intr = cli._Interrupts()
    assert intr.install()
    again = 0
    try:
        callback()  # Ctrl-C inside the callback: ctypes swallows the KeyboardInterrupt
        assert ignored == [KeyboardInterrupt]
        try:
            _idle(30.0)
        except KeyboardInterrupt:
            again += 1
            intr.handled()
        _idle(1.0)  # once handled, nothing more arrives
    finally:
        intr.uninstall()
    assert again == 1
    assert intr.raised_at is None


def test_an_interruption_the_command_catches_on_purpose_is_not_raised_again(monkeypatch):
    # code that catches the KeyboardInterrupt and works on in its handler (a sweep recording
    # its running trials, a driver stopping the hand) must not get a second one
    monkeypatch.setattr(cli, "_REDELIVER_AFTER", 0.2)
    intr = cli._Interrupts()
    assert intr.install()
    worked = 0.0
    try:
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            t0 = time.monotonic()
            _idle(1.5)  # more than _REDELIVER_AFTER, inside the handler
            worked = time.monotonic() - t0
        cli.interruption_handled()
        _idle(1.0)
    finally:
        intr.uninstall()
    assert worked >= 1.5
    assert intr.raised_at is None
    assert cli._ACTIVE is None


def test_unsafe_code_is_recognised_on_the_stack():
    import threading

    from numba.core import event

    frames = {}

    class Listener(event.Listener):
        def on_start(self, ev):
            frames["numba"] = cli._in_unsafe_code(sys._getframe())

        def on_end(self, ev):
            pass

    import numba

    @numba.njit(cache=False)
    def twice(x):
        return 2 * x

    listener = Listener()
    event.register("numba:compile", listener)
    try:
        twice(1.5)
    finally:
        event.unregister("numba:compile", listener)
    assert frames["numba"] is True
    assert cli._in_unsafe_code(sys._getframe()) is False

    # a thread being joined (scipy's threaded KD-tree queries): the main thread waits in join
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, args=(30,))
    t.start()
    main = threading.main_thread().ident
    checker = threading.Thread(target=lambda: (time.sleep(0.2), frames.__setitem__(
        "join", cli._in_unsafe_code(sys._current_frames()[main])), stop.set()))
    checker.start()
    t.join()
    checker.join()
    assert frames["join"] is True


def test_progress_lines_on_a_non_tty_stderr(capsys):
    from touchloc._util import progress

    assert list(progress(range(5), desc="work", interval=0.0)) == list(range(5))
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("work: 0/5") and err[-1].startswith("work: 4/5") and len(err) == 5
    assert list(progress(range(5), desc="work")) == list(range(5))
    assert capsys.readouterr().err == ""  # at most a line per interval (5 s)
    assert list(progress(range(3), desc="w", enabled=False, interval=0.0)) == [0, 1, 2]
    assert capsys.readouterr().err == ""


def test_save_load_json_round_trip(mug_csv, tmp_path):
    m, _, T = mug_csv
    path = tmp_path / "b.npz"
    r = touchloc("localize", "--mesh", "mug", "--contacts", m, "--method", "hf", *PLANAR, "--save", path, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    M = np.array(doc["map_pose"]["matrix"])
    from scipy.spatial.transform import Rotation

    assert np.allclose(Rotation.from_quat(doc["map_pose"]["quat_xyzw"]).as_matrix(), M[:3, :3], atol=1e-9)
    assert np.allclose(doc["map_pose"]["translation"], M[:3, 3])
    assert np.linalg.norm(M[:2, 3] - T[:2, 3]) < 0.005
    belief, contacts = load_belief(path)
    assert np.allclose(belief.map_pose(), M) and np.allclose(belief.info["map_pose"], M)
    c0 = Contacts.from_csv(m)
    assert np.allclose(contacts.points, c0.points) and np.allclose(contacts.normals, c0.normals)
    assert isinstance(belief.region, PoseRegion) and belief.region.dim == 3
    assert belief.info["model"]["sigma_pos"] == 0.002 and belief.info["method"] == "hf"
    r2 = touchloc("localize", "--mesh", "mug", "--load", path, "--json", "--plot", tmp_path / "b.png")
    assert r2.returncode == 0, r2.stderr
    assert (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG"
    assert np.allclose(json.loads(r2.stdout)["map_pose"]["matrix"], M)


def test_outlier_distance_keeps_a_stray_contact_from_moving_the_pose(mug_csv, tmp_path):
    m, _, T = mug_csv
    c = Contacts.from_csv(m)
    stray = tmp_path / "stray.csv"
    far = c.points[:1] + np.array([[0.05, 0.0, 0.0]])      # 5 cm from the mug: no surface explains it
    Contacts(np.vstack([c.points, far]), np.vstack([c.normals, c.normals[:1]])).to_csv(stray)

    def error(*extra):
        r = touchloc("localize", "--mesh", "mug", "--contacts", stray, "--method", "hf", *PLANAR, "--json",
                     "--save", tmp_path / "b.npz", *extra)
        assert r.returncode == 0, r.stderr
        return np.linalg.norm(np.array(json.loads(r.stdout)["map_pose"]["matrix"])[:2, 3] - T[:2, 3])

    capped, plain = error("--outlier-distance", "5"), error()
    assert load_belief(tmp_path / "b.npz")[0].info["model"]["outlier_distance"] is None
    assert capped < 0.0015 < plain
    r = touchloc("localize", "--mesh", "mug", "--contacts", m, "--outlier-distance", "-1")
    assert r.returncode != 0 and "outlier_distance" in r.stderr and "Traceback" not in r.stderr


# -- meshes and identify -------------------------------------------------------------------
def test_load_mesh_scales_files_and_bundled_names(tmp_path, objects):
    from touchloc.data import mesh_path

    ref = objects["mug"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.allclose(cli.load_mesh("mug").extents, ref.extents)
        assert np.allclose(cli.load_mesh("mug", "2").extents, 2 * ref.extents)
        mm = tmp_path / "mug_mm.obj"
        cli.load_mesh("mug", 1000.0).mesh.export(mm)
        assert np.allclose(cli.load_mesh(str(mm), 0.001).extents, ref.extents, rtol=1e-6)
    assert cli.split_mesh_spec(f"{mm}:0.001") == (str(mm), 0.001)
    assert cli.split_mesh_spec(str(mesh_path("mug"))) == (str(mesh_path("mug")), None)
    for bad in ("0", "-1", "mm", "inf"):
        with pytest.raises(Exception, match="--scale"):
            cli.load_mesh("mug", bad)
    with pytest.raises(Exception, match="no such file"):
        cli.load_mesh(str(tmp_path / "none.obj"))


@pytest.fixture(scope="module")
def ycb_like(tmp_path_factory, objects):
    """Two candidates with the same file name in different folders, the second in millimetres."""
    d = tmp_path_factory.mktemp("ycb")
    (d / "mug").mkdir(), (d / "can").mkdir()
    objects["mug"].mesh.export(d / "mug" / "textured.obj")
    can = objects["can"].mesh.copy()
    can.apply_scale(1000.0)
    can.export(d / "can" / "textured.obj")
    return d / "mug" / "textured.obj", d / "can" / "textured.obj"


def test_identify_unique_names_and_per_mesh_scale(ycb_like, mug_csv):
    m, _, _ = mug_csv
    mug, can = ycb_like
    r = touchloc("identify", "--meshes", mug, f"{can}:0.001", "--contacts", m, *PLANAR, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert set(doc["posterior"]) == {"mug/textured", "can/textured"}
    assert doc["identity"] == "mug/textured" and doc["posterior"]["mug/textured"] > 0.9


def test_identify_prints_none_when_no_candidate_explains_the_contacts(mug_csv):
    _, mm, _ = mug_csv
    r = touchloc("identify", "--meshes", "mug", "can", "--contacts", mm, *PLANAR)
    assert r.returncode == 1
    assert r.stdout.strip().splitlines()[0] == "none"
    assert "millimetres" in r.stderr


def test_identify_api_refuses_when_every_candidate_is_degenerate(objects, mug_csv):
    from touchloc.belief import identify
    from touchloc.errors import BeliefDegenerateError
    from touchloc.models import ProximityModel

    m, _, _ = mug_csv
    far = Contacts.from_csv(m).transform(np.array([[1, 0, 0, 1.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    region = PoseRegion.planar((0, 0), 0.01, z=-objects["mug"].bounds[0][2])
    models = {n: ProximityModel(objects[n], 0.002, 0.1) for n in ("mug", "can")}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(BeliefDegenerateError, match="no candidate"):
            identify(models, far, region, rng=0)
        post = identify(models, Contacts.from_csv(m), region, rng=0)
    assert post["mug"] > 0.9


def test_active_takes_a_mesh_file_with_scale_and_prints_the_full_pose(ycb_like, tmp_path):
    _, can_mm = ycb_like
    r = touchloc("active", "--mesh", can_mm, "--scale", "0.001", "--setting", "6dof", "--max-touches", "1",
                 "--particles", "200", "--candidates", "8", "--out", "")
    assert r.returncode == 0, r.stderr
    assert "extents=[0.0" in r.stdout  # scaled to metres
    assert "roll/pitch/yaw" in r.stdout and "quat_xyzw" in r.stdout


def test_heartbeat_reports_long_silent_work(capsys):
    err = []
    with cli.heartbeat("work", interval=0.05):
        deadline = time.monotonic() + 30
        while not err and time.monotonic() < deadline:  # wait for the first line, however loaded the machine
            time.sleep(0.05)
            err += capsys.readouterr().err.splitlines()
    err += capsys.readouterr().err.splitlines()  # lines written before the exit
    assert err and all(line.startswith("work: still working (") for line in err)
    time.sleep(0.2)
    assert capsys.readouterr().err == ""  # stopped on exit


def test_diagnose_names_units_region_and_mesh(objects, mug_csv):
    from touchloc.belief import ParticleBelief

    m, mm, _ = mug_csv
    obj = objects["mug"]
    region = PoseRegion.planar((0, 0), 0.01)
    b = ParticleBelief(np.eye(4)[None], info={"mean_cost_at_map": 4e9})
    lines = cli.diagnose(obj, Contacts.from_csv(mm), region, b, sigma_pos=0.002)
    text = "\n".join(lines)
    assert "unit mismatch" in text and "contacts in millimetres" in text and "--center" in text
    b = ParticleBelief(np.eye(4)[None], info={"mean_cost_at_map": 16.0})
    text = "\n".join(cli.diagnose(obj, Contacts.from_csv(m), region, b, sigma_pos=0.002))
    assert "4 sigma" in text and "millimetres" not in text and "check: units" in text


def test_every_progress_keyword_is_called_progress(capsys):
    """Design convention 9: long work takes ``progress=``. The functions that called it
    ``progress_bar=`` take ``progress=`` now; the old name still works with a
    DeprecationWarning, and both at once is a ValidationError. ``progress=True`` shows a
    bar, ``progress=False`` and ``progress_bar=False`` nothing."""
    import inspect
    import warnings

    from touchloc import ValidationError
    from touchloc.dnf import compare, generate_rotation_dataset
    from touchloc.dnf.compare import default_estimators
    from touchloc.mapping import explore
    from touchloc.planners import active_localization
    from touchloc.recognition import TactileScanner, evaluate_protocol, simulate_dataset

    for fn in (explore, active_localization, evaluate_protocol, simulate_dataset, TactileScanner.scan_many,
               compare):
        params = inspect.signature(fn).parameters
        assert "progress" in params and params["progress"].default is None, fn.__name__

    # each of them reads the keyword through the same check: both names at once is refused
    # before any work starts
    from touchloc.belief import PoseRegion
    from touchloc.data import load_object
    from touchloc.models import ProximityModel
    from touchloc.planners import GuardedTouch, RandomPlanner, SimulatedWorld

    can = load_object("can")
    world = SimulatedWorld(can, np.eye(4), rng=0)
    touch = GuardedTouch(np.array([0.0, 0.0, 0.3]), np.array([0.0, 0.0, -1.0]), 0.4)
    scans = np.random.default_rng(0).uniform(0, 4095, (8, 4, 4, 4))
    both = dict(progress=False, progress_bar=False)
    calls = {
        "explore": lambda: explore(world, ((-0.1,) * 3, (0.1,) * 3), 1, **both),
        "active_localization": lambda: active_localization(
            world, ProximityModel(can, 0.002, 0.1), PoseRegion.box((0, 0, 0), 0.01, "yaw"), RandomPlanner(),
            [touch], **both),
        "evaluate_protocol": lambda: evaluate_protocol(scans, np.repeat(["a", "b"], 4), lambda s: None, **both),
        "simulate_dataset": lambda: simulate_dataset({"can": can}, 1, **both),
        "scan_many": lambda: TactileScanner().scan_many(can, 1, **both),
    }
    for name, call in calls.items():
        with pytest.raises(ValidationError, match=f"{name}: give progress= only"):
            call()

    sets = {"6-gon": [generate_rotation_dataset(6, revolutions=0.2, rng=0)]}
    est = {k: v for k, v in default_estimators(rng=0).items() if k == "histogram"}
    compare(sets, est, progress=False)
    assert capsys.readouterr().err == ""
    compare(sets, est, progress=True)
    assert "estimators x data sets" in capsys.readouterr().err
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compare(sets, est, progress_bar=False)
    assert capsys.readouterr().err == ""
    dep = [w for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(dep) == 1 and "use progress=" in str(dep[0].message)
    assert dep[0].filename == __file__    # points at the caller's line
    with pytest.raises(ValidationError, match="progress= only"):
        compare(sets, est, progress=False, progress_bar=False)
    with pytest.raises(ValidationError, match="progress"):
        compare(sets, est, progress="yes")
