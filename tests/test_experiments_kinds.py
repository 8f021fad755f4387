"""Sweeps beyond passive localisation: planned touches with options, identification, the
bundled 600-trial study, a real Ctrl-C of `touchloc sweep` and its resumption."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from touchloc.errors import ValidationError
from touchloc.experiments import COLUMNS, Sweep, bundled_sweeps, read_results, run_sweep, run_trial
from touchloc.experiments.runner import same_tables, warm_keys

SCRIPT = Path(sys.executable).with_name("touchloc")
COMMAND = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "touchloc.cli"]


def test_identification_and_planned_touches_serial_equals_processes(tmp_path):
    ident = Sweep(meshes=["cereal", "can"], modes=["identify"], contacts=[20], seeds=[0], half_extent=0.1)
    active = Sweep(meshes=["cereal"], modes=["active"], region="planar", contacts=[3], seeds=[1],
                   planners=["random", {"name": "two-step", "branch": 2}],
                   loop={"n_particles": 300, "confidence": 0.003}, sigma_nor=0.15, noise=[0.001],
                   normal_noise=0.05)
    trials = ident.trials() + active.trials()
    assert len(trials) == 4 and len({t["trial_id"] for t in trials}) == 4
    # the options name what the trial runs; each worker preloads every candidate mesh
    assert {json.loads(t["options"])["candidates"][1] for t in trials[:2]} == {"can"}
    assert json.loads(trials[3]["options"]) == {"loop": {"confidence": 0.003, "n_particles": 300},
                                                "planner": {"branch": 2}}
    assert json.loads(trials[2]["options"]) == {"loop": {"confidence": 0.003, "n_particles": 300}}
    assert [k[0] for k in warm_keys(trials)] == ["cereal", "can", "cereal"]

    serial = run_sweep(trials, tmp_path / "s.csv", executor_spec="serial", parquet=False)
    procs = run_sweep(trials, tmp_path / "p.csv", executor_spec="processes", workers=2, parquet=False)
    assert same_tables(serial, procs)
    for r in serial:
        m = json.loads(r["metrics"])
        if r["mode"] == "identify":
            assert r["estimator"] == "identify" and r["touches"] == 20 and r["half_extent"] == 0.1
            assert r["success"] == (m["best"] == r["mesh"]) == m["correct"]
            assert 0.0 <= m["p_true"] <= m["p_best"] <= 1.0
        else:
            assert set(m) == {"confident", "add"} and m["add"] >= 0.0
            assert 1 <= r["touches"] <= 3 and r["plan_time"] > 0.0
            assert r["half_extent"] == 0.05


def test_sweep_validation_of_the_new_fields():
    with pytest.raises(ValidationError, match="planner name"):
        Sweep(modes=["active"], planners=[{"name": "greedy"}])
    with pytest.raises(ValidationError, match="loop options"):
        Sweep(modes=["active"], loop={"max_touches": 3})
    with pytest.raises(ValidationError, match="identities"):
        Sweep(meshes=["can", "milk"], modes=["identify"], identities=["can"])
    with pytest.raises(ValidationError, match="modes"):
        Sweep(modes=["dream"])
    with pytest.raises(ValidationError, match="half_extent"):
        Sweep(half_extent=-1.0)
    p = Sweep(meshes=["can"], modes=["identify"], seeds=1).trials()[0]
    with pytest.raises(ValidationError, match="candidates"):
        run_trial(dict(p, options='{"candidates": ["milk"]}'))


def test_a_results_file_of_other_columns_is_not_resumed_into(tmp_path):
    out = tmp_path / "old.csv"
    out.write_text("trial_id,mode,mesh\nabc,passive,can\n")
    with pytest.raises(ValidationError, match="columns"):
        run_sweep(Sweep(seeds=1), out, executor_spec="serial", parquet=False)
    assert out.read_text() == "trial_id,mode,mesh\nabc,passive,can\n"   # left as it was


def test_the_bundled_600_trial_study_is_one_command_and_repeats(tmp_path):
    assert "study600" in bundled_sweeps()
    sweep = Sweep.from_toml("study600")
    t = sweep.trials()
    assert len(t) == 600 == 3 * 4 * 5 * 10 and len({p["trial_id"] for p in t}) == 600
    assert {p["estimator"] for p in t} == {"ss", "pf", "apf"} and len({p["mesh"] for p in t}) == 4
    assert sorted({p["contacts"] for p in t}) == [5, 10, 20, 30, 50] and len({p["seed"] for p in t}) == 10
    # a slice of it (every estimator, one mesh, the largest contact count, one seed) through
    # the serial executor, a process pool and a Dask LocalCluster: the same table
    part = [p for p in t if p["contacts"] == 50 and p["seed"] == 0 and p["mesh"] == "cereal"]
    assert len(part) == 3
    serial = run_sweep(part, tmp_path / "s.csv", executor_spec="serial", parquet=False)
    procs = run_sweep(part, tmp_path / "p.csv", executor_spec="processes", workers=2, parquet=False)
    assert same_tables(serial, procs)
    pytest.importorskip("dask.distributed")
    dask_rows = run_sweep(part, tmp_path / "d.csv", executor_spec="dask", workers=2, parquet=False)
    assert same_tables(serial, dask_rows)
    assert [r["success"] for r in serial if r["estimator"] == "ss"] == [True]


def _data_lines(path):
    with open(path, "rb") as fh:
        return fh.read().splitlines(keepends=True)[1:]


def test_ctrl_c_of_a_real_sweep_then_the_same_command_loses_nothing_and_repeats_nothing(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('meshes = ["cereal"]\ncontacts = [10]\nseeds = 14\n'
                    '[[estimators]]\nname = "pf"\nn_particles = 30000\n')
    out = tmp_path / "r.csv"
    cmd = [*COMMAND, "sweep", str(spec), "-o", str(out), "--executor", "processes", "--workers", "2",
           "--no-progress"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # its own process group: the signal reaches the command and its pool workers, as a
    # Ctrl-C at a terminal does
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         start_new_session=True)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 240 and p.poll() is None:
            if out.exists() and len(_data_lines(out)) >= 2:
                break
            time.sleep(0.05)
        assert p.poll() is None, "finished before it could be interrupted: " + p.stdout.read()
        os.killpg(p.pid, signal.SIGINT)
        stdout, stderr = p.communicate(timeout=240)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted:" in stdout
    first = _data_lines(out)
    n1 = len(first)
    assert 2 <= n1 < 14, "the interrupt should land mid-sweep"
    assert f"interrupted: {n1} finished trials" in stdout
    # the same command again: runs exactly the missing trials
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr
    assert f"{n1} already there, {14 - n1} to run" in r.stdout
    assert "14/14 trials" in r.stdout
    lines = _data_lines(out)
    assert lines[:n1] == first                       # the first run's rows kept as written
    rows = read_results(out)
    ids = [x["trial_id"] for x in rows]
    assert len(ids) == 14 and len(set(ids)) == 14    # nothing twice, nothing lost
    assert set(ids) == {t["trial_id"] for t in Sweep.from_toml(spec).trials()}
    assert list(rows[0]) == list(COLUMNS)


def test_dnf_trials_are_a_sweep_too_and_repeat_on_a_process_pool(tmp_path):
    from touchloc.experiments import DNF_COLUMNS, DNFSweep
    from touchloc.experiments.trial import run_dnf_trial

    sw = DNFSweep(sides=[4, 0], estimators=["histogram", "DNF, corrected"], sets=1, seed=7, revolutions=1.5,
                  cells=[{}, {"noise_deg": 6.0, "bias": 0.1}])
    trials = sw.trials()
    assert len(trials) == 2 * 2 * 2 and len({t["trial_id"] for t in trials}) == 8
    assert {(t["bias_lo"], t["bias_hi"]) for t in trials} == {(0.04, 0.08), (0.1, 0.1)}
    serial = run_sweep(sw, tmp_path / "s.csv", executor_spec="serial", parquet=False)
    procs = run_sweep(sw, tmp_path / "p.csv", executor_spec="processes", workers=2, parquet=False)
    # the pool's workers run single-threaded, this process may not: the tracker's BLAS
    # products then sum in another order, and a float summary moves in its 11th digit
    # (the 6 deg 4-gon's RMS error, 5.13625519017 against ...011, in one thread setting);
    # every count must still be the same
    assert same_tables(serial, procs, rtol=1e-9)
    assert not same_tables(serial, [dict(r, accuracy=r["accuracy"] + 1e-6) for r in procs], rtol=1e-9)
    with open(tmp_path / "s.csv") as fh:
        assert fh.readline().strip().split(",") == list(DNF_COLUMNS)
    for r in serial:
        assert 0.0 <= r["accuracy"] <= 1.0 and r["samples"] > 50 and r["time_per_step"] > 0
        assert isinstance(r["sides"], int) and r["kind"] == "dnf"
    # the estimators of one data set see the same data; the row repeats in this process
    a = run_dnf_trial(trials[0])
    b = next(r for r in serial if r["trial_id"] == trials[0]["trial_id"])
    assert {k: v for k, v in a.items() if "time" not in k} == {k: v for k, v in b.items() if "time" not in k}
    # one kind per results file
    with pytest.raises(ValidationError, match="one kind"):
        run_sweep(trials + Sweep(seeds=1).trials(), tmp_path / "mixed.csv", executor_spec="serial")
    with pytest.raises(ValidationError, match="columns"):
        run_sweep(Sweep(seeds=1), tmp_path / "s.csv", executor_spec="serial")
    with pytest.raises(ValidationError, match="DNF estimators"):
        DNFSweep(estimators=["kalman"])
    with pytest.raises(ValidationError, match="cells"):
        DNFSweep(cells=[{"noise": 3.0}])


def test_a_dnf_sweep_from_toml_runs_through_the_command(tmp_path, capsys):
    from touchloc.cli import main
    from touchloc.experiments import DNFSweep

    spec = tmp_path / "d.toml"
    spec.write_text('kind = "dnf"\nsides = [4]\nestimators = ["histogram"]\nrevolutions = 1.0\nseed = 5\n'
                    '[[cells]]\nnoise_deg = 2.0\n[[cells]]\nbias = [0.0, 0.02]\n')
    sw = Sweep.from_toml(spec)
    assert isinstance(sw, DNFSweep) and len(sw.trials()) == 2 and sw.cells[1]["bias"] == (0.0, 0.02)
    out = tmp_path / "d.csv"
    assert main(["sweep", str(spec), "-o", str(out), "--executor", "serial", "--no-progress"]) == 0
    assert "2/2 trials" in capsys.readouterr().out
    assert [r["cell"] for r in sorted(read_results(out), key=lambda r: r["cell"])] == [0, 1]
    spec.write_text('kind = "dnf"\nmeshes = ["can"]\n')
    with pytest.raises(ValidationError, match="unknown sweep keys"):
        Sweep.from_toml(spec)
    spec.write_text('kind = "maps"\n')
    with pytest.raises(ValidationError, match="kind"):
        Sweep.from_toml(spec)



def test_a_dnf_sweep_gets_its_own_report(tmp_path, capsys):
    # `touchloc report` on a DNF sweep's results: the right count per cell and object for
    # each estimator (the mean over the data sets), a heat map, and how many cells pass
    from touchloc.cli import main

    spec = tmp_path / "d.toml"
    spec.write_text('kind = "dnf"\nsides = [4, 0]\nsets = 2\nestimators = ["histogram", "DNF, corrected"]\n'
                    'revolutions = 1.0\nseed = 5\n[[cells]]\n[[cells]]\nnoise_deg = 6.0\nbias = 0.1\n')
    out = tmp_path / "d.csv"
    assert main(["sweep", str(spec), "-o", str(out), "--executor", "serial", "--no-progress"]) == 0
    rows = read_results(out)
    assert len(rows) == 16
    assert main(["report", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    md = (tmp_path / "d.md").read_text()
    assert (tmp_path / "d.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tables = {}
    for block in md.split("**")[1::2]:
        tables[block] = md.split(f"**{block}**")[1].split("**")[0]
    assert set(tables) == {"histogram", "DNF, corrected"}
    for est, table in tables.items():
        for label, cell in (("2 / 3 / 10% / 4-8 % / 1.5", 0), ("2 / 6 / 10% / 10 % / 1.5", 1)):
            want = [sum(r["accuracy"] for r in rows if r["estimator"] == est and r["cell"] == cell
                        and r["sides"] == n) / 2 for n in (4, 0)]
            line = next(x for x in table.splitlines() if x.startswith(f"| {label} |"))
            assert line == f"| {label} | {100 * want[0]:.0f} % | {100 * want[1]:.0f} % | 2 |"
        assert "| cell | 4-gon | round | data sets |" in table


def test_a_report_refuses_what_it_cannot_draw(tmp_path):
    from touchloc.experiments import write_report
    from touchloc.experiments.report import dnf_markdown_table

    with pytest.raises(ValidationError, match="does not exist"):
        write_report(tmp_path / "none.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("trial_id,x\na,1\n")
    with pytest.raises(ValidationError, match="not the results of a sweep"):
        write_report(bad)
    row = {"kind": "dnf", "estimator": "histogram", "sides": 4, "normals_per_contact": 2, "noise_deg": 3.0,
           "drop": 0.1, "bias_lo": 0.04, "bias_hi": 0.08, "slip_deg": 1.5, "cell": 0, "accuracy": 0.5}
    assert "| 2 / 3 / 10% / 4-8 % / 1.5 | 50 % | 1 |" in dnf_markdown_table([row])
    for rows, match in (([], "empty"), ("rows", "list"), ([dict(row, kind=None)], "kind 'dnf'"),
                        ([dict(row, accuracy=float("nan"))], "finite"), ([{"kind": "dnf"}], "lacks")):
        with pytest.raises(ValidationError, match=match):
            dnf_markdown_table(rows)
    # the localisation report's plots check their rows as its table does
    from touchloc.experiments.report import plot_results

    for rows, match in (([{"mode": "passive"}], "lacks columns"), ([], "empty"), ("rows", "list")):
        with pytest.raises(ValidationError, match=match):
            plot_results(rows, tmp_path / "p.png")
    assert not (tmp_path / "p.png").exists()

class _CountingThreads:
    """A thread pool that counts the trials it finished (whatever became of their rows).

    With ``interrupt_at=k``, the k-th trial submitted (from 0) raises KeyboardInterrupt
    instead of running: the sweep's loop then meets it in the main thread when it collects
    that trial, as it would meet a Ctrl-C while it waits, but at a known point rather than
    whenever a signal happens to be seen (which made an earlier form of this test flaky
    on a loaded machine)."""

    def __init__(self, n, interrupt_at=None):
        import concurrent.futures as cf
        import threading

        self.pool = cf.ThreadPoolExecutor(n)
        self.finished = []
        self.lock = threading.Lock()
        self.interrupt_at, self.submitted = interrupt_at, 0

    def submit(self, fn, params):
        interrupt = self.submitted == self.interrupt_at
        self.submitted += 1

        def run():
            if interrupt:
                raise KeyboardInterrupt
            row = fn(params)
            with self.lock:
                self.finished.append(row["trial_id"])
            return row

        return self.pool.submit(run)


def test_an_interrupt_records_the_trials_that_were_running(tmp_path):
    trials = Sweep(meshes=["cereal"], estimators=[{"name": "pf", "n_particles": 20000}], contacts=[10],
                   seeds=12).trials()
    out = tmp_path / "r.csv"
    # two trials run; the third, started when one of them ends, is the interrupt
    ex = _CountingThreads(2, interrupt_at=2)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(trials, out, executor_obj=ex, parquet=False)
    ex.pool.shutdown(wait=True)
    rows = read_results(out)
    # every trial that finished is in the file; the ones never started were cancelled
    assert sorted(r["trial_id"] for r in rows) == sorted(ex.finished)
    assert 1 <= len(rows) < len(trials)
    # and the same call again runs exactly the others
    again = _CountingThreads(2)
    rows = run_sweep(trials, out, executor_obj=again, parquet=False)
    again.pool.shutdown(wait=True)
    assert sorted(again.finished) == sorted(set(t["trial_id"] for t in trials) - set(ex.finished))
    assert len(rows) == len(trials)


def test_the_toml_examples_of_the_docs_are_valid_sweeps():
    import re

    tomllib = pytest.importorskip("tomllib")
    text = (Path(__file__).resolve().parent.parent / "docs" / "experiments.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert len(blocks) >= 3
    sizes = [len(Sweep.from_dict(tomllib.loads(b)).trials()) for b in blocks]
    assert sizes[0] == 600 and all(n > 0 for n in sizes)


def test_a_sweep_will_not_write_its_results_into_a_directory(tmp_path):
    # a folder where the results file should be (the fuzz suite met one) is a clear error,
    # not a raw IsADirectoryError, and the folder is left as it was
    from touchloc.experiments import DNFSweep

    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "keep.txt").write_text("x")
    sweep = DNFSweep(sides=[4], estimators=["histogram"], revolutions=0.5)
    with pytest.raises(ValidationError, match="a directory"):
        run_sweep(sweep, tmp_path / "res", executor_spec="serial", progress=False)
    assert (tmp_path / "res" / "keep.txt").read_text() == "x"
    with pytest.raises(ValidationError, match="cannot make the folder"):
        run_sweep(sweep, tmp_path / "res" / "keep.txt" / "out.csv", executor_spec="serial", progress=False)
