"""Experiments at scale: sweeps of localisation trials on any Executor (Dask too).

A :class:`Sweep` is a grid (meshes x estimators x contact counts x noise x seeds, passive
or active); :func:`run_trial` runs one trial as a pure function of its parameters;
:func:`run_sweep` runs the missing trials of a sweep through an executor (serial, a
process pool, a Dask ``LocalCluster`` or an existing Dask scheduler) and streams one row
per trial to a CSV file, so an interrupted sweep resumes where it stopped.
"""

from .runner import COLUMNS, SerialExecutor, executor, read_results, run_sweep, summarize, write_parquet
from .sweep import ESTIMATORS, PLANNERS, Sweep, trial_id
from .trial import RESULT_COLUMNS, cache_info, clear_cache, run_trial

__all__ = ["Sweep", "run_trial", "run_sweep", "executor", "SerialExecutor", "read_results", "write_parquet",
           "summarize", "trial_id", "cache_info", "clear_cache", "COLUMNS", "RESULT_COLUMNS", "ESTIMATORS",
           "PLANNERS"]
