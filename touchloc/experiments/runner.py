"""Run a sweep on any ``concurrent.futures.Executor``, streaming rows to a CSV file."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import io
import os
import threading
from pathlib import Path

from .._validate import as_bool, as_count, as_path
from ..errors import ValidationError
from .sweep import Sweep
from .trial import RESULT_COLUMNS, run_trial

__all__ = ["SerialExecutor", "executor", "run_sweep", "read_results", "write_parquet", "summarize", "COLUMNS"]

#: column order of a results file
COLUMNS = ("trial_id", "mode", "mesh", "estimator", "planner", "options", "contacts", "noise", "seed",
           "region", "sigma_pos", "sigma_nor", "normal_noise", "success_threshold") + RESULT_COLUMNS
_INT = {"contacts", "seed", "touches"}
_BOOL = {"success", "degenerate", "cov50", "cov90", "cov95"}
_STR = {"trial_id", "mode", "mesh", "estimator", "planner", "options", "region"}


class SerialExecutor(cf.Executor):
    """Runs each task at submission, in the calling process (for debugging)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._shutdown = False

    def submit(self, fn, /, *args, **kwargs):
        if self._shutdown:
            raise RuntimeError("cannot submit after shutdown")
        f = cf.Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            if isinstance(exc, KeyboardInterrupt):
                raise
            f.set_exception(exc)
        return f

    def shutdown(self, wait=True, *, cancel_futures=False):
        self._shutdown = True


def _single_threaded(threads: int = 1) -> None:
    """Worker initialiser: compiled kernels use ``threads`` threads (one process per core)."""
    import numba

    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


@contextlib.contextmanager
def executor(spec: str = "processes", workers: int | None = None):
    """An Executor for ``spec``, shut down (cluster closed) on exit, even on error.

    Parameters
    ----------
    spec : str
        ``"serial"``; ``"processes"`` (a process pool, ``workers`` processes, default
        all cores); ``"dask"`` (a ``dask.distributed.LocalCluster`` of ``workers``
        single-threaded worker processes); ``"dask://HOST:PORT"`` or ``"tcp://HOST:PORT"``
        (an existing Dask scheduler).
    workers : int, optional

    Notes
    -----
    The compiled kernels are multi-threaded. Local pool and cluster workers run them on
    one thread each (one trial per core beats two threads per trial); workers of an
    existing scheduler keep their own settings (start them with NUMBA_NUM_THREADS=1).
    """
    if spec == "serial":
        ex = SerialExecutor()
        try:
            yield ex
        finally:
            ex.shutdown()
        return
    if spec == "processes":
        import multiprocessing as mp

        ex = cf.ProcessPoolExecutor(max_workers=workers or os.cpu_count(), mp_context=mp.get_context("spawn"),
                                    initializer=_single_threaded)
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
              parquet=True, executor_obj=None) -> list:
    """Run every trial of ``sweep`` not yet in ``out`` and append its row as it finishes.

    Parameters
    ----------
    sweep : Sweep or list of dict
        The sweep, or trial parameters from :meth:`Sweep.trials`.
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

    Returns
    -------
    list of dict
        Every row of ``out`` (old and new), sorted by trial_id.
    """
    if isinstance(sweep, Sweep):
        trials = sweep.trials()
    elif isinstance(sweep, (list, tuple)) and all(isinstance(t, dict) for t in sweep):
        trials = list(sweep)
    else:
        raise ValidationError(f"sweep must be a Sweep or a list of trial dicts, got {type(sweep).__name__}")
    out = as_path(out, "out", must_exist=False)
    if not isinstance(executor_spec, str):
        raise ValidationError(f"executor_spec must be a str (see executor()), got {type(executor_spec).__name__}")
    if workers is not None:
        workers = as_count(workers, "workers", max=4096)
    if progress is not None:
        progress = as_bool(progress, "progress")
    resume, parquet = as_bool(resume, "resume"), as_bool(parquet, "parquet")
    if executor_obj is not None and not callable(getattr(executor_obj, "submit", None)):
        raise ValidationError(f"executor_obj must be a concurrent.futures.Executor, got {type(executor_obj).__name__}")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not resume and out.exists():
        out.unlink()
    if out.exists():
        _truncate_partial_line(out)  # before reading: a cut-off row is not a finished trial
    done = _done_ids(out) if out.exists() else set()
    todo = [t for t in trials if t["trial_id"] not in done]
    new_file = not out.exists() or out.stat().st_size == 0
    with open(out, "a", newline="") as fh:
        w = csv.writer(fh)
        if new_file:
            w.writerow(COLUMNS)
            fh.flush()
        if todo:
            ctx = contextlib.nullcontext(executor_obj) if executor_obj is not None else executor(executor_spec, workers)
            with ctx as ex:
                _drain(ex, todo, w, fh, progress)
    rows = read_results(out)
    if parquet:
        write_parquet(rows, out.with_suffix(".parquet"))
    return rows


def _drain(ex, todo, writer, fh, progress):
    from .._util import progress as bar

    futures = [ex.submit(run_trial, t) for t in todo]
    try:
        for f in bar(cf.as_completed(futures), total=len(futures), desc="trials", enabled=progress):
            row = f.result()
            writer.writerow([_encode(row[c]) for c in COLUMNS])
            fh.flush()
    except BaseException:
        for f in futures:
            f.cancel()
        raise


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

