"""Run a sweep on any ``concurrent.futures.Executor``, streaming rows to a CSV file."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import io
import math
import os
import threading
from pathlib import Path

from .._validate import as_bool, as_callable, as_count, as_nonnegative_float, as_path, as_timeout
from ..errors import TouchlocError, ValidationError
from .sweep import DNFSweep, Sweep
from .trial import DNF_COLUMNS, RESULT_COLUMNS, TIME_COLUMNS, run_dnf_trial, run_trial, warm

__all__ = ["SerialExecutor", "executor", "run_sweep", "read_results", "write_parquet", "summarize", "same_tables",
           "warm_keys", "COLUMNS"]

#: column order of a results file
COLUMNS = ("trial_id", "mode", "mesh", "estimator", "planner", "options", "contacts", "noise", "seed",
           "region", "half_extent", "sigma_pos", "sigma_nor", "normal_noise", "success_threshold") + RESULT_COLUMNS
_INT = {"contacts", "seed", "touches", "sides", "normals_per_contact", "cell", "object", "set", "samples"}
_BOOL = {"success", "degenerate", "cov50", "cov90", "cov95"}
_STR = {"trial_id", "mode", "mesh", "estimator", "planner", "options", "region", "metrics", "kind", "normal_source"}
#: per kind of trial: the function that runs one, and the columns of its results file
_KINDS = {"localization": (run_trial, COLUMNS), "dnf": (run_dnf_trial, DNF_COLUMNS)}


def _kind(trials) -> str:
    kinds = {str(t.get("kind", "localization")) for t in trials}
    if len(kinds) > 1 or not kinds <= set(_KINDS):
        raise ValidationError(f"a sweep's trials must be of one kind among {sorted(_KINDS)}, got {sorted(map(str, kinds))}")
    return kinds.pop() if kinds else "localization"


class SerialExecutor(cf.Executor):
    """Runs each task at submission, in the calling process (for debugging)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._shutdown = False

    def submit(self, fn, /, *args, **kwargs):
        if self._shutdown:
            raise ExecutorShutdown("cannot submit after shutdown")
        f = cf.Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            if isinstance(exc, KeyboardInterrupt):
                raise
            f.set_exception(exc)
        return f

    def map(self, fn, *iterables, timeout=None, chunksize=1):
        """:meth:`concurrent.futures.Executor.map`, with its arguments checked."""
        fn = as_callable(fn, "fn")
        timeout = as_timeout(timeout, "timeout", allow_none=True)
        as_count(chunksize, "chunksize")
        return super().map(fn, *iterables, timeout=timeout)

    def shutdown(self, wait=True, *, cancel_futures=False):
        self._shutdown = True


class ExecutorShutdown(TouchlocError, RuntimeError):
    """A task submitted to an executor that was shut down."""


def _single_threaded(threads: int = 1, keys=()) -> None:
    """Worker initialiser: compiled kernels use ``threads`` threads (one process per core).

    The worker ignores SIGINT: a Ctrl-C at the terminal reaches the whole process group,
    and the parent, not each worker, decides what happens (it lets the running trials
    finish and records them). ``keys`` are meshes to build now (see :func:`warm`).
    """
    import signal

    import numba

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    _dask_worker_setup(keys)


def _dask_worker_setup(keys=()) -> None:
    """Load the meshes ``keys`` name (see :func:`warm`); a mesh that fails to load is left
    to the trials that need it, which report the error."""
    for k in keys:
        try:
            warm([k])
        except Exception:  # noqa: BLE001 - the trial raises it again, with its parameters
            pass


def _check_preload(preload) -> list:
    if isinstance(preload, (str, bytes, dict)) or not hasattr(preload, "__iter__"):
        raise ValidationError(f"preload must be a list of (mesh, sigma_pos, sigma_nor), got {type(preload).__name__}")
    out = []
    for k in preload:
        ok = (isinstance(k, (tuple, list)) and len(k) == 3 and isinstance(k[0], str)
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in k[1:]))
        if not ok:
            raise ValidationError(f"preload entries must be (mesh name or path, sigma_pos > 0, sigma_nor > 0), "
                                  f"got {k!r}"[:160])
        out.append((k[0], float(k[1]), float(k[2])))
    return out


def warm_keys(trials) -> list:
    """The (mesh, sigma_pos, sigma_nor) every trial of ``trials`` needs, each once, in order."""
    import json

    out = []
    for t in trials:
        try:
            meshes = [t["mesh"]]
            if t.get("mode") == "identify":
                meshes += list(json.loads(t["options"]).get("candidates", []))
            sp, sn = float(t["sigma_pos"]), float(t["sigma_nor"])
        except (KeyError, TypeError, ValueError, AttributeError):
            continue  # not a valid trial: run_trial says what is wrong with it
        for m in meshes:
            k = (m, sp, sn)
            if isinstance(m, str) and sp > 0 and sn > 0 and k not in out:
                out.append(k)
    return out


@contextlib.contextmanager
def executor(spec: str = "processes", workers: int | None = None, *, preload=()):
    """An Executor for ``spec``, shut down (cluster closed) on exit, even on error.

    Parameters
    ----------
    spec : str
        ``"serial"``; ``"processes"`` (a process pool, ``workers`` processes, default
        all cores); ``"dask"`` (a ``dask.distributed.LocalCluster`` of ``workers``
        single-threaded worker processes); ``"dask://HOST:PORT"`` or ``"tcp://HOST:PORT"``
        (an existing Dask scheduler).
    workers : int, optional
    preload : list of (mesh, sigma_pos, sigma_nor)
        Meshes and models every worker builds when it starts (:func:`warm_keys` of the
        trials), so that no trial's time includes loading them; the serial executor
        builds them in this process.

    Notes
    -----
    The compiled kernels are multi-threaded. Local pool and cluster workers run them on
    one thread each (one trial per core beats two threads per trial); workers of an
    existing scheduler keep their own settings (start them with NUMBA_NUM_THREADS=1).
    """
    preload = _check_preload(preload)
    if not isinstance(spec, str):
        raise ValidationError(f"executor spec must be a str ('serial', 'processes', 'dask', 'dask://HOST:PORT'), "
                              f"got {type(spec).__name__}")
    if workers is not None:
        workers = as_count(workers, "workers", max=4096)
    if spec == "serial":
        warm(preload)
        ex = SerialExecutor()
        try:
            yield ex
        finally:
            ex.shutdown()
        return
    if spec == "processes":
        import multiprocessing as mp

        ex = cf.ProcessPoolExecutor(max_workers=workers or os.cpu_count(), mp_context=mp.get_context("spawn"),
                                    initializer=_single_threaded, initargs=(1, preload))
        try:
            yield ex
        finally:
            ex.shutdown(wait=True, cancel_futures=True)
        return
    if spec == "dask" or spec.startswith(("dask://", "tcp://")):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError as exc:
            raise ValidationError("the dask executor needs dask.distributed: pip install 'touchloc[dask]'") from exc
        with contextlib.ExitStack() as stack:
            if spec == "dask":
                cluster = stack.enter_context(LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1,
                                                           processes=True, host="127.0.0.1",
                                                           dashboard_address=None,
                                                           env={"NUMBA_NUM_THREADS": "1"}))
                client = stack.enter_context(Client(cluster))
            else:
                address = "tcp://" + spec.split("://", 1)[1]
                client = stack.enter_context(Client(address))
            if preload:
                client.run(_dask_worker_setup, preload)
            yield client.get_executor(pure=False)
        return
    raise ValidationError(f"executor must be 'serial', 'processes', 'dask' or 'dask://HOST:PORT', got {spec!r}")


def _encode(v):
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _decode(col, s):
    if col in _STR:
        return s
    if col in _INT:
        return int(s)
    if col in _BOOL:
        return s == "1"
    return float(s)


def read_results(path) -> list:
    """Rows of a results CSV as dicts with typed values, sorted by trial_id.

    A last line cut off by an interruption is ignored.
    """
    p = as_path(path, "results file", must_exist=False)
    if not p.exists():
        return []
    if not p.is_file():
        raise ValidationError(f"results file must be a file, got {p}")
    rows = []
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            text = fh.read()
    except UnicodeDecodeError as exc:
        raise ValidationError(f"{p}: not a results CSV (not UTF-8 text at byte {exc.start})") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        for r in reader:
            if None in r or any(v is None for v in r.values()):
                continue  # a partial line
            try:
                rows.append({c: _decode(c, r[c]) for c in reader.fieldnames})
            except (ValueError, KeyError):
                continue
    except csv.Error as exc:
        raise ValidationError(f"{p}: not a results CSV: {exc}") from None
    if rows and "trial_id" not in rows[0]:
        raise ValidationError(f"{p}: not a results CSV: no trial_id column (columns {list(rows[0])[:8]})")
    rows.sort(key=lambda r: r["trial_id"])
    return rows


def write_parquet(rows, path) -> bool:
    """Write rows to Parquet when pyarrow is installed; returns whether it did."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    pq.write_table(pa.Table.from_pylist(list(rows)), str(path))
    return True


def _done_ids(path: Path) -> set:
    return {r["trial_id"] for r in read_results(path)}


def run_sweep(sweep, out, *, executor_spec="processes", workers=None, progress=None, resume=True,
              parquet=True, executor_obj=None, preload=True) -> list:
    """Run every trial of ``sweep`` not yet in ``out`` and append its row as it finishes.

    Parameters
    ----------
    sweep : Sweep, DNFSweep or list of dict
        The sweep, or trial parameters from :meth:`Sweep.trials` (or all from
        :meth:`DNFSweep.trials`: a results file holds one kind of trial).
    out : str or Path
        Results CSV. Rows are appended and flushed one by one, so an interrupted run
        keeps every finished trial; rerunning skips them (``resume``).
    executor_spec : str
        See :func:`executor`. Ignored when ``executor_obj`` is given.
    workers : int, optional
    progress : bool, optional
        tqdm bar (default: when stderr is a TTY).
    resume : bool
        False: start the file afresh.
    parquet : bool
        Also write ``out`` with a ``.parquet`` suffix at the end, when pyarrow is there.
    executor_obj : concurrent.futures.Executor, optional
        Use this executor (left open) instead of making one.
    preload : bool
        Every worker of the executor made here builds the meshes and models of the
        sweep when it starts, so that trial times never include that set-up.

    Interruption: on Ctrl-C (KeyboardInterrupt) the trials not yet started are
    cancelled, the ones running are waited for and recorded (pool workers ignore SIGINT),
    then the interrupt propagates; a second Ctrl-C stops waiting.

    Returns
    -------
    list of dict
        Every row of ``out`` (old and new), sorted by trial_id.
    """
    if isinstance(sweep, (Sweep, DNFSweep)):
        trials = sweep.trials()
    elif isinstance(sweep, (list, tuple)) and all(isinstance(t, dict) for t in sweep):
        trials = list(sweep)
    else:
        raise ValidationError(f"sweep must be a Sweep, a DNFSweep or a list of trial dicts, got {type(sweep).__name__}")
    if not all("trial_id" in t for t in trials):
        raise ValidationError("every trial dict needs its trial_id (take them from Sweep.trials())")
    fn, columns = _KINDS[_kind(trials)]
    out = as_path(out, "out", must_exist=False)
    if out.exists() and not out.is_file():
        raise ValidationError(f"out must be a results file, got {out}" + (" (a directory)" if out.is_dir() else ""))
    if not isinstance(executor_spec, str):
        raise ValidationError(f"executor_spec must be a str (see executor()), got {type(executor_spec).__name__}")
    if workers is not None:
        workers = as_count(workers, "workers", max=4096)
    if progress is not None:
        progress = as_bool(progress, "progress")
    resume, parquet, preload = as_bool(resume, "resume"), as_bool(parquet, "parquet"), as_bool(preload, "preload")
    if executor_obj is not None and not callable(getattr(executor_obj, "submit", None)):
        raise ValidationError(f"executor_obj must be a concurrent.futures.Executor, got {type(executor_obj).__name__}")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValidationError(f"cannot make the folder of {out}: {exc}") from None
    if not resume and out.exists():
        out.unlink()
    if out.exists():
        _truncate_partial_line(out)  # before reading: a cut-off row is not a finished trial
        _check_header(out, columns)
    done = _done_ids(out) if out.exists() else set()
    todo = []
    for t in trials:  # each trial once, even when listed twice
        if t["trial_id"] not in done:
            done.add(t["trial_id"])
            todo.append(t)
    new_file = not out.exists() or out.stat().st_size == 0
    with open(out, "a", newline="") as fh:
        w = csv.writer(fh)
        if new_file:
            w.writerow(columns)
            fh.flush()
        if todo:
            keys = warm_keys(todo) if preload and fn is run_trial else ()
            ctx = (contextlib.nullcontext(executor_obj) if executor_obj is not None
                   else executor(executor_spec, workers, preload=keys))
            with ctx as ex:
                _drain(ex, fn, columns, todo, w, fh, progress)
    rows = read_results(out)
    if parquet:
        write_parquet(rows, out.with_suffix(".parquet"))
    return rows


def _drain(ex, fn, columns, todo, writer, fh, progress):
    from .._util import progress as bar

    futures, written = [], set()

    def write(f):
        row = f.result()
        writer.writerow([_encode(row[c]) for c in columns])
        fh.flush()
        written.add(f)

    try:
        for t in todo:
            futures.append(ex.submit(fn, t))
        for f in bar(cf.as_completed(futures), total=len(futures), desc="trials", enabled=progress):
            write(f)
    except KeyboardInterrupt:
        # keep what is already computed: cancel the trials not started, record the running ones
        for f in futures:
            f.cancel()
        running = [f for f in futures if f not in written and not f.cancelled()]
        for f in cf.as_completed(running):
            if not f.cancelled() and f.exception() is None:
                write(f)
        raise
    except BaseException:
        for f in futures:
            f.cancel()
        raise


def _check_header(path: Path, columns) -> None:
    with open(path, newline="", encoding="utf-8", errors="replace") as fh:
        first = fh.readline()
    if not first:
        return
    head = next(csv.reader([first]))
    if tuple(head) != tuple(columns):
        raise ValidationError(f"{path}: its columns are not this version's results columns (first: "
                              f"{head[:6]}...); write to another file, or start it anew (--fresh / resume=False)")


def same_tables(a, b, *, rtol: float = 0.0) -> bool:
    """Whether two lists of result rows are equal in every column but the wall times.

    ``rtol`` lets float columns differ by that much relative to their size (0: exactly
    equal). A BLAS product's summation order follows its thread count, so a trial run in
    a process with several threads and the same trial on a single-threaded pool worker can
    differ in the last digits of a float summary; counts and success flags must still match.
    """
    rtol = as_nonnegative_float(rtol, "rtol")

    def same(x, y) -> bool:
        if x == y:
            return True
        if rtol > 0 and isinstance(x, float) and isinstance(y, float):
            return math.isclose(x, y, rel_tol=rtol, abs_tol=0.0)
        return False

    a, b = sorted(a, key=lambda r: r["trial_id"]), sorted(b, key=lambda r: r["trial_id"])
    return len(a) == len(b) and all(ra.keys() == rb.keys() and all(same(ra[c], rb[c]) for c in ra if c not in TIME_COLUMNS)
                                    for ra, rb in zip(a, b))


def _truncate_partial_line(path: Path) -> None:
    """Drop a last line without its newline (a write cut off by an interruption)."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        path.write_bytes(data[: data.rfind(b"\n") + 1])


_SUMMARY_COLUMNS = ("success", "add_s", "time", "touches", "cov50", "cov90", "cov95")


def summarize(rows, by=("mode", "estimator", "planner", "mesh", "contacts")) -> list:
    """Per group: trials, success rate, median ADD-S, median time, median touches, coverage."""
    import numpy as np

    if isinstance(rows, (str, bytes, dict)) or not hasattr(rows, "__iter__"):
        raise ValidationError(f"rows must be a list of result dicts (read_results), got {type(rows).__name__}")
    if isinstance(by, str) or not hasattr(by, "__iter__") or not all(isinstance(k, str) for k in by):
        raise ValidationError(f"by must be a list of column names, got {by!r}"[:160])
    rows, by = list(rows), tuple(by)
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise ValidationError(f"rows[{i}] must be a result dict, got {type(r).__name__}")
        missing = [k for k in (*by, *_SUMMARY_COLUMNS) if k not in r]
        if missing:
            raise ValidationError(f"rows[{i}] lacks columns {missing}")
        for c in _SUMMARY_COLUMNS:
            if isinstance(r[c], (str, bytes)) or not isinstance(r[c], (int, float, np.number)):
                raise ValidationError(f"rows[{i}][{c!r}] must be a number, got {type(r[c]).__name__}")
    groups: dict = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in by), []).append(r)
    out = []
    for key in sorted(groups, key=lambda k: tuple(str(x) if not isinstance(x, (int, float)) else f"{x:012.4f}" for x in k)):
        g = groups[key]
        col = lambda c: np.array([r[c] for r in g], dtype=float)  # noqa: E731
        out.append(dict(zip(by, key), trials=len(g), success=col("success").mean(),
                        median_add_s=float(np.median(col("add_s"))), median_time=float(np.median(col("time"))),
                        median_touches=float(np.median(col("touches"))), cov50=col("cov50").mean(),
                        cov90=col("cov90").mean(), cov95=col("cov95").mean()))
    return out

