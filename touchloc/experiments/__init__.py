"""Experiments at scale: sweeps of localisation trials on any Executor (Dask too).

A :class:`Sweep` is a grid (meshes x estimators x contact counts x noise x seeds: passive
localisation, active localisation by planned touches, or identification of the touched
mesh); a :class:`DNFSweep` is a grid of orientation-tracking trials on rotating n-gons;
:func:`run_trial` runs one trial as a pure function of its parameters;
:func:`run_sweep` runs the missing trials of a sweep through an executor (serial, a
process pool, a Dask ``LocalCluster`` or an existing Dask scheduler) and streams one row
per trial to a CSV file, so an interrupted sweep resumes where it stopped;
:func:`write_report` draws a results file and writes its table (:func:`markdown_table` and
:func:`plot_results` for localisation rows, :func:`dnf_markdown_table` and
:func:`plot_dnf_results` for orientation-tracking rows).
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "runner": ("COLUMNS", "SerialExecutor", "executor", "read_results", "run_sweep", "summarize", "write_parquet"),
    "sweep": ("DNF_ESTIMATORS", "ESTIMATORS", "LOOP_OPTIONS", "MODES", "PLANNERS", "DNFSweep", "Sweep",
        "bundled_sweeps", "trial_id"),
    "trial": ("DNF_COLUMNS", "RESULT_COLUMNS", "TIME_COLUMNS", "cache_info", "clear_cache", "run_trial"),
    "report": ("write_report", "markdown_table", "plot_results", "dnf_markdown_table", "plot_dnf_results"),
}

__all__ = ["Sweep", "DNFSweep", "run_trial", "run_sweep", "executor", "SerialExecutor", "read_results", "write_parquet",
           "summarize", "trial_id", "bundled_sweeps", "cache_info", "write_report", "markdown_table",
           "plot_results", "dnf_markdown_table", "plot_dnf_results",
           "clear_cache", "COLUMNS", "RESULT_COLUMNS", "TIME_COLUMNS", "ESTIMATORS", "PLANNERS", "MODES",
           "LOOP_OPTIONS", "DNF_COLUMNS", "DNF_ESTIMATORS"]

__getattr__, __dir__ = attach(__name__, _NAMES)
