"""Sweeps: the grid, pure trials, streamed and resumable results, serial vs processes vs Dask."""

import csv
import concurrent.futures as cf
import json

import numpy as np
import pytest

from touchloc.cli import main
from touchloc.errors import ValidationError
from touchloc.experiments import (COLUMNS, TIME_COLUMNS, SerialExecutor, Sweep, cache_info, executor, read_results,
                                  run_sweep, run_trial)

# tiny and fast: 30 contacts, small meshes, importance sampling with few particles
SMALL = dict(meshes=["cereal", "milk"], estimators=[{"name": "pf", "n_particles": 1500}], contacts=[30],
             seeds=[0, 1])


def _same(a, b):
    """Tables equal in every column but the wall times."""
    from touchloc.experiments.runner import same_tables

    assert [r["trial_id"] for r in a] == [r["trial_id"] for r in b]
    for ra, rb in zip(a, b):
        for c in COLUMNS:
            if c not in TIME_COLUMNS:
                assert ra[c] == rb[c], (c, ra[c], rb[c])
    assert same_tables(a, b)


def test_grid_from_toml_and_validation(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('meshes = ["can", "milk"]\ncontacts = [5, 10]\nseeds = 3\nmodes = ["passive", "active"]\n'
                 'planners = ["random"]\n[[estimators]]\nname = "ss"\n[[estimators]]\nname = "pf"\nn_particles = 100\n')
    s = Sweep.from_toml(f)
    t = s.trials()
    assert len(t) == 2 * 2 * 2 * 3 + 2 * 1 * 2 * 3
    assert len({p["trial_id"] for p in t}) == len(t)
    assert [p["trial_id"] for p in t] == [p["trial_id"] for p in Sweep.from_toml(f).trials()]
    assert {p["options"] for p in t if p["estimator"] == "pf"} == {'{"n_particles": 100}'}
    with pytest.raises(ValidationError, match="estimator name"):
        Sweep(estimators=["nope"])
    with pytest.raises(ValidationError, match="unknown sweep keys"):
        Sweep.from_dict({"mesh": ["can"]})
    f.write_text("meshes = [")
    with pytest.raises(ValidationError, match="TOML"):
        Sweep.from_toml(f)
    with pytest.raises(ValidationError, match="executor"):
        with executor("threads"):
            pass


def test_a_trial_is_a_pure_function_of_its_parameters():
    p = Sweep(**SMALL).trials()[0]
    a, b = run_trial(p), run_trial(dict(p))
    assert {k: v for k, v in a.items() if k not in TIME_COLUMNS} == {k: v for k, v in b.items() if k not in TIME_COLUMNS}
    assert a["plan_time"] == 0.0 and set(json.loads(a["metrics"])) == {"in90_pose"}
    assert 0 <= a["add_s"] < 0.2 and a["touches"] == 30
    assert a["cov50"] <= a["cov90"] <= a["cov95"]        # nested credible regions
    # another seed is another trial
    q = dict(p, seed=7)
    assert run_trial(q)["add_s"] != a["add_s"]
    assert cache_info()["mesh"] >= 1


class CountingExecutor(SerialExecutor):
    """Serial, and counts the trials it was given."""

    def __init__(self):
        super().__init__()
        self.ids = []

    def submit(self, fn, /, *args, **kwargs):
        self.ids.append(args[0]["trial_id"])
        return super().submit(fn, *args, **kwargs)


def test_results_stream_and_an_interrupted_sweep_resumes(tmp_path):
    sweep = Sweep(**SMALL)
    trials = sweep.trials()
    out = tmp_path / "r.csv"
    # an "interrupted" run: half the trials done, and a row cut off mid-write
    first = CountingExecutor()
    run_sweep(trials[:2], out, executor_obj=first, parquet=False)
    assert len(first.ids) == 2
    with open(out, "a") as fh:
        fh.write(trials[2]["trial_id"] + ",passive,cer")
    second = CountingExecutor()
    rows = run_sweep(sweep, out, executor_obj=second, parquet=False)
    assert sorted(second.ids) == sorted(t["trial_id"] for t in trials[2:])   # nothing twice, nothing lost
    assert len(rows) == len(trials) and len({r["trial_id"] for r in rows}) == len(trials)
    with open(out, newline="") as fh:
        lines = list(csv.reader(fh))
    assert lines[0] == list(COLUMNS) and len(lines) == 1 + len(trials)
    third = CountingExecutor()
    run_sweep(sweep, out, executor_obj=third, parquet=False)
    assert third.ids == []
    # a fresh run recomputes everything and gives the same table
    fresh = run_sweep(sweep, tmp_path / "f.csv", executor_spec="serial", parquet=False)
    _same(fresh, rows)


@pytest.fixture(scope="module")
def dask_cluster():
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        yield cluster


def test_dask_and_process_pool_tables_equal_the_serial_table(tmp_path, dask_cluster):
    from dask.distributed import Client

    sweep = Sweep(**SMALL)
    serial = run_sweep(sweep, tmp_path / "serial.csv", executor_spec="serial", parquet=False)
    with Client(dask_cluster) as client:
        dask_rows = run_sweep(sweep, tmp_path / "dask.csv", executor_obj=client.get_executor(pure=False),
                              parquet=False)
        # each worker holds the meshes it used, once, whatever the number of trials it ran
        info = client.run(cache_info)
        assert all(v.get("mesh", 0) <= len(SMALL["meshes"]) for v in info.values())
        assert sum(v.get("mesh", 0) for v in info.values()) >= 1
    _same(serial, dask_rows)
    # an existing scheduler, by address
    host_port = dask_cluster.scheduler_address.split("://", 1)[1]
    remote = run_sweep(sweep, tmp_path / "remote.csv", executor_spec=f"dask://{host_port}", parquet=False)
    _same(serial, remote)
    procs = run_sweep(sweep, tmp_path / "procs.csv", executor_spec="processes", workers=2, parquet=False)
    _same(serial, procs)


def test_cli_sweep_and_report(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text('meshes = ["cereal"]\ncontacts = [10, 30]\nseeds = [3]\n'
                    '[[estimators]]\nname = "pf"\nn_particles = 1000\n')
    out = tmp_path / "res.csv"
    assert main(["sweep", str(spec), "-o", str(out), "--executor", "serial", "--no-progress"]) == 0
    assert "2/2 trials" in capsys.readouterr().out
    rows = read_results(out)
    assert [r["contacts"] for r in sorted(rows, key=lambda r: r["contacts"])] == [10, 30]
    assert main(["report", str(out)]) == 0
    md = (tmp_path / "res.md").read_text()
    assert md.count("| passive | pf | cereal |") == 2
    png = (tmp_path / "res.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["report", str(tmp_path / "missing.csv")]) == 1
    assert main(["sweep", str(tmp_path / "none.toml"), "-o", str(out)]) == 1


def test_serial_executor_is_a_real_executor():
    with executor("serial") as ex:
        assert isinstance(ex, cf.Executor)
        assert list(ex.map(np.square, [1, 2])) == [1, 4]
        f = ex.submit(int, "x")
        assert isinstance(f.exception(), ValueError)


def test_an_active_trial_runs_the_planning_loop_and_repeats():
    p = Sweep(meshes=["cereal"], modes=["active"], planners=["random"], contacts=[2], seeds=[4],
              region="planar").trials()[0]
    a, b = run_trial(p), run_trial(p)
    assert a["mode"] == "active" and a["estimator"] == "smc" and a["planner"] == "random"
    assert 1 <= a["touches"] <= 2
    assert {k: v for k, v in a.items() if k not in TIME_COLUMNS} == {k: v for k, v in b.items() if k not in TIME_COLUMNS}


def test_the_smc_filter_runs_as_a_static_estimator_in_a_sweep():
    p = Sweep(meshes=["cereal"], estimators=[{"name": "smc", "n_particles": 400}], contacts=[10],
              seeds=[2]).trials()[0]
    a, b = run_trial(p), run_trial(p)
    assert a["estimator"] == "smc" and a["touches"] == 10 and np.isfinite(a["add_s"])
    assert {k: v for k, v in a.items() if k not in TIME_COLUMNS} == {k: v for k, v in b.items() if k not in TIME_COLUMNS}


def test_warm_builds_every_per_mesh_structure_a_timed_trial_would_need():
    """A worker's warm-up must leave nothing for its first timed trial to build: the
    exact tree, the fast grid and Scaling Series' bound table for the model's normal
    weight (the first 30-contact trial of each mesh used to time the grid's building)."""
    from touchloc.experiments.trial import _model, warm

    warm([("cereal", 0.002, 0.1)])
    model = _model({"mesh": "cereal", "sigma_pos": 0.002, "sigma_nor": 0.1})
    w = model._weight(True)
    assert {model._grid_key(w), ("cost_bound", w)} <= set(model.obj._cache)
