"""Run the shape estimators side by side on the same data sets, summarise and plot.

Reproduces seed 000's evaluation (section V): the number of detected sides over time
(Fig. 6), its mean and spread over the second half of each data set (Fig. 7) and the
three estimators' memories over time (Fig. 5), plus the orientation error over time and
the time per step. Three families are compared: the neural fields of seed 000 (with its
two baselines), a particle filter over the orientation, and the n-gon mapped in 3-D by
tactile SLAM (:mod:`touchloc.experiments.ngon`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._util import progress as show_progress
from .._util import progress_keyword
from .._validate import (as_bool, as_callable, as_count, as_float_array, as_instance, as_mapping, as_name,
                         as_sequence)
from ..errors import ValidationError
from .estimators import HistogramEstimator, count_surfaces
from .fields import Field2D
from .particle import ParticleOrientationEstimator
from .tracker import OrientationTracker

__all__ = ["EstimatorRun", "default_estimators", "run_estimator", "compare", "summary_table",
           "orientation_error", "plot_surface_counts", "plot_second_half", "plot_orientation_error",
           "plot_memories", "plot_step_time", "ESTIMATOR_COLORS", "MAPPED"]

TWO_PI = 2.0 * np.pi

#: colours of seed 000's Fig. 6 (blue, green, red) plus one for the particle filter
ESTIMATOR_COLORS = {"histogram": "tab:blue", "memory, uncorrected": "tab:green", "DNF, corrected": "tab:red",
                    "particle filter": "tab:purple", "3-D map (tactile SLAM)": "tab:brown"}

#: display name of the third family
MAPPED = "3-D map (tactile SLAM)"


def default_estimators(*, particles: int = 400, rng=None) -> dict:
    """Factories of the estimators, keyed by display name.

    ``rng`` seeds the particle filter (an int gives every run the same seed, so results
    are reproducible). The third family, the n-gon mapped in 3-D by tactile SLAM, joins
    through :func:`touchloc.experiments.ngon.estimators_with_map`.

    Returns
    -------
    dict
        ``{name: callable() -> estimator}``. Any estimator with ``step(normal_angles,
        odometry)``, ``orientation`` and ``memory`` (an activation over orientation for
        :func:`count_surfaces`) can join the comparison.
    """
    out = {
        "histogram": lambda: HistogramEstimator(360),
        "memory, uncorrected": lambda: OrientationTracker(correct=False),
        "DNF, corrected": lambda: OrientationTracker(),
        "particle filter": lambda: ParticleOrientationEstimator(particles, rng=rng),
    }
    return out


@dataclass
class EstimatorRun:
    """One estimator on one data set.

    Attributes
    ----------
    estimator, dataset : str
    n_true : int or None
        The object's number of sides.
    counts : (T,) int
        :func:`count_surfaces` of the estimator's memory after each sample.
    orientation : (T,) float
        Orientation estimate after each sample, rad.
    error : (T,) float or None
        :func:`orientation_error` (needs the data set's ground truth).
    seconds_per_step : float
        Mean wall time of one estimator step (counting excluded).
    memories : (T, n) float or None
        Memory after each sample, if recorded.
    """

    estimator: str
    dataset: str
    n_true: int | None
    counts: np.ndarray
    orientation: np.ndarray
    error: np.ndarray | None
    seconds_per_step: float
    memories: np.ndarray | None = field(default=None, repr=False)

    @property
    def second_half(self) -> np.ndarray:
        """Counts over the second half of the data set (seed 000, Fig. 7)."""
        return self.counts[len(self.counts) // 2:]

    @property
    def accuracy(self) -> float:
        """Fraction of second-half steps with the right number of sides (nan if unknown)."""
        if self.n_true is None:
            return float("nan")
        return float(np.mean(self.second_half == self.n_true))


def orientation_error(estimate, truth, n_sides) -> np.ndarray:
    """Orientation error, wrapped to the object's symmetry.

    An n-gon looks the same after a turn of ``2 pi / n``, so its orientation is only
    defined modulo that; the error is wrapped to ``[-pi / n, pi / n)`` (to ``[-pi, pi)``
    for a round object, whose orientation cannot be observed at all).

    Returns
    -------
    (T,) float, rad
    """
    n_sides = 0 if n_sides is None else as_count(n_sides, "n_sides", min=0, max=10_000)
    estimate = as_float_array(estimate, "estimate (rad)")
    truth = as_float_array(truth, "truth (rad)")
    try:
        np.broadcast_shapes(estimate.shape, truth.shape)
    except ValueError:
        raise ValidationError(f"estimate {estimate.shape} and truth {truth.shape} must have the same shape") from None
    period = TWO_PI / n_sides if n_sides else TWO_PI
    e = estimate - truth
    return (e + period / 2) % period - period / 2


def run_estimator(name: str, make, dataset, *, record: bool = False) -> EstimatorRun:
    """Run one estimator over a data set, counting sides after every sample.

    An estimator with a ``bind(dataset)`` method (the mapped prism, which simulates its
    touches on the data set's object) is bound to the data set first. The time per step
    leaves out compiling the tracker's kernel (once per install) or loading it (once per
    process): that is done before the first timed step.
    """
    from .data import RotationDataset

    name = as_name(name, "name", allow_none=False)
    make = as_callable(make, "make")
    dataset = as_instance(dataset, RotationDataset, "dataset")
    record = as_bool(record, "record")
    est = make()
    if hasattr(est, "bind"):
        est.bind(dataset)
    if isinstance(getattr(est, "comparison", None), Field2D):
        from ._kernels import load_kernels

        load_kernels()
    T = len(dataset)
    counts = np.empty(T, dtype=np.int64)
    orient = np.empty(T)
    mems = None
    spent = 0.0
    for t, (a, odo) in enumerate(dataset.samples()):
        t0 = time.perf_counter()
        est.step(a, odo)
        spent += time.perf_counter() - t0
        mem = est.memory
        counts[t] = count_surfaces(mem)
        orient[t] = est.orientation
        if record:
            if mems is None:
                mems = np.empty((T, mem.shape[0]))
            mems[t] = mem
    err = None
    if dataset.true_orientation is not None:
        err = orientation_error(orient, dataset.true_orientation, dataset.n_surfaces or 0)
    return EstimatorRun(name, dataset.name, dataset.n_surfaces, counts, orient, err, spent / T, mems)


def compare(datasets: dict, estimators: dict | None = None, *, record: bool = False, progress=None,
            progress_bar=None) -> dict:
    """Run every estimator on every data set.

    Parameters
    ----------
    datasets : dict
        ``{object name: [RotationDataset, ...]}`` (e.g. :func:`standard_datasets`).
    estimators : dict, optional
        ``{name: factory}``; default ``default_estimators(rng=0)``.
    record : bool
        Keep every memory over time (for :func:`plot_memories`).
    progress : bool, optional
        A bar over the runs (default: when stderr is a terminal; otherwise a line to stderr every few
        seconds). ``progress_bar=`` is its deprecated old name.

    Returns
    -------
    dict
        ``{object name: {estimator name: [EstimatorRun per data set]}}``
    """
    from .data import RotationDataset

    datasets = as_mapping(datasets, "datasets", expected="a dict {object name: [RotationDataset, ...]}")
    if not datasets:
        raise ValidationError("datasets is empty; expected {object name: [RotationDataset, ...]}")
    datasets = {k: as_sequence(v, f"datasets[{k!r}]", of=RotationDataset) for k, v in datasets.items()}
    if estimators is not None:
        estimators = as_mapping(estimators, "estimators", expected="a dict {name: factory}")
        for k, v in estimators.items():
            as_callable(v, f"estimators[{k!r}]")
    record = as_bool(record, "record")
    progress = progress_keyword(progress, progress_bar, "compare")
    estimators = estimators or default_estimators(rng=0)
    jobs = [(obj, name, make, ds) for obj, dss in datasets.items() for ds in dss for name, make in estimators.items()]
    out = {obj: {name: [] for name in estimators} for obj in datasets}
    for obj, name, make, ds in show_progress(jobs, desc="estimators x data sets", enabled=progress):
        out[obj][name].append(run_estimator(name, make, ds, record=record))
    return out


def summary_table(results: dict) -> str:
    """Markdown table: per object and estimator, the second-half surface counts and errors.

    The orientation error's RMS includes a constant offset (the frame in which a map was
    first built is arbitrary); its sd (circular, per data set, pooled) is the tracking
    jitter and drift around that offset.
    """
    results = as_mapping(results, "results", expected="a dict {object: {estimator: [EstimatorRun, ...]}} from compare()")
    for obj, by_est in results.items():
        by_est = as_mapping(by_est, f"results[{obj!r}]", expected="a dict {estimator: [EstimatorRun, ...]}")
        for name, runs in by_est.items():
            as_sequence(runs, f"results[{obj!r}][{name!r}]", of=EstimatorRun, min_len=1)
    lines = ["| object | estimator | right count, 2nd half | count, 2nd half (mean ± sd) | "
             "per data set | orientation error, 2nd half: RMS / sd | time per step |",
             "|---|---|---|---|---|---|---|"]
    for obj, by_est in results.items():
        for name, runs in by_est.items():
            halves = np.concatenate([r.second_half for r in runs])
            acc = [r.accuracy for r in runs]
            per = " ".join(f"{a:.0%}" if np.isfinite(a) else "-" for a in acc)
            errs = [r.error[len(r.error) // 2:] for r in runs if r.error is not None]
            if errs:
                rms = np.degrees(np.sqrt(np.mean(np.concatenate(errs) ** 2)))
                period = TWO_PI / runs[0].n_true if runs[0].n_true else TWO_PI
                sd = np.degrees(np.sqrt(np.mean([_circular_var(e, period) for e in errs])))
                err = f"{rms:.1f} / {sd:.1f} deg"
            else:
                err = "-"
            tps = np.mean([r.seconds_per_step for r in runs])
            n_true = runs[0].n_true
            right = f"{np.nanmean(acc):.0%}" if n_true is not None else "-"
            lines.append(f"| {obj} ({n_true if n_true is not None else '?'} sides) | {name} | {right} | "
                         f"{halves.mean():.2f} ± {halves.std():.2f} | {per} | {err} | {tps * 1e3:.3f} ms |")
    return "\n".join(lines)


def _circular_var(e, period) -> float:
    """Circular variance (rad^2) of angles ``e`` that are defined modulo ``period``."""
    z = np.abs(np.mean(np.exp(1j * TWO_PI / period * np.asarray(e))))
    return float(-2.0 * np.log(max(z, 1e-12))) * (period / TWO_PI) ** 2


# -- plots -------------------------------------------------------------------------------

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_surface_counts(results: dict, path) -> None:
    """Fig. 6 of seed 000: mean ± sd (over data sets) of the side count over the samples."""
    plt = _plt()
    objs = list(results)
    fig, axes = plt.subplots(1, len(objs), figsize=(5 * len(objs), 3.6), squeeze=False)
    for ax, obj in zip(axes[0], objs):
        for name, runs in results[obj].items():
            T = min(len(r.counts) for r in runs)
            c = np.stack([r.counts[:T] for r in runs]).astype(float)
            m, s = c.mean(0), c.std(0)
            x = np.arange(T)
            col = ESTIMATOR_COLORS.get(name)
            ax.plot(x, m, color=col, label=name, lw=1.2)
            ax.fill_between(x, m - s, m + s, color=col, alpha=0.15, lw=0)
        n_true = results[obj][next(iter(results[obj]))][0].n_true
        if n_true is not None:
            ax.axhline(n_true, color="k", ls=":", lw=1)
        ax.set_title(f"{obj}")
        ax.set_xlabel("sample (about 4 turns in total)")
        ax.set_ylabel("number of sides")
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.set_ylim(bottom=-0.5)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_second_half(results: dict, path) -> None:
    """Fig. 7 of seed 000: mean ± sd of the side count over each data set's second half."""
    plt = _plt()
    objs = list(results)
    fig, axes = plt.subplots(1, len(objs), figsize=(5 * len(objs), 3.4), squeeze=False)
    for ax, obj in zip(axes[0], objs):
        names = list(results[obj])
        n_ds = len(results[obj][names[0]])
        w = 0.8 / len(names)
        for k, name in enumerate(names):
            runs = results[obj][name]
            m = [r.second_half.mean() for r in runs]
            s = [r.second_half.std() for r in runs]
            ax.bar(np.arange(n_ds) + (k - (len(names) - 1) / 2) * w, m, w, yerr=s, capsize=2,
                   color=ESTIMATOR_COLORS.get(name), label=name)
        n_true = results[obj][names[0]][0].n_true
        if n_true is not None:
            ax.axhline(n_true, color="k", ls=":", lw=1)
        ax.set_xticks(np.arange(n_ds), [str(i + 1) for i in range(n_ds)])
        ax.set_xlabel("data set")
        ax.set_ylabel("number of sides, 2nd half")
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.set_title(obj)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_orientation_error(results: dict, path) -> None:
    """Orientation error (wrapped to the object's symmetry) over the samples, every run.

    The histogram and the uncorrected memory use the odometry as their estimate, so their
    curves coincide (the odometry's own error).
    """
    plt = _plt()
    objs = list(results)
    fig, axes = plt.subplots(1, len(objs), figsize=(max(5 * len(objs), 8), 3.8), squeeze=False)
    for ax, obj in zip(axes[0], objs):
        for name, runs in results[obj].items():
            for i, r in enumerate(runs):
                if r.error is None:
                    continue
                e = np.degrees(r.error)
                period = 360.0 / r.n_true if r.n_true else 360.0
                e[1:][np.abs(np.diff(e)) > period / 2] = np.nan      # break the line where it wraps
                # the histogram's curve is the uncorrected memory's: draw it wide and dashed beneath
                same = name == "histogram"
                ax.plot(e, color=ESTIMATOR_COLORS.get(name), lw=3.0 if same else 0.8, ls="--" if same else "-",
                        alpha=0.7, zorder=1 if same else 2,
                        label=(f"{name} (same as uncorrected)" if same else name) if i == 0 else None)
        ax.set_title(obj)
        ax.set_xlabel("sample")
        ax.set_ylabel("orientation error (deg)")
    fig.legend(*axes[0][0].get_legend_handles_labels(), fontsize=8, loc="lower center", ncol=4, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_step_time(results: dict, path) -> None:
    """Mean wall time per step of each estimator, per object (log scale)."""
    plt = _plt()
    objs = list(results)
    names = list(results[objs[0]])
    fig, ax = plt.subplots(figsize=(7, 3.4))
    w = 0.8 / len(names)
    for k, name in enumerate(names):
        t = [np.mean([r.seconds_per_step for r in results[o][name]]) * 1e3 for o in objs]
        ax.bar(np.arange(len(objs)) + (k - (len(names) - 1) / 2) * w, t, w, color=ESTIMATOR_COLORS.get(name),
               label=name)
    ax.set_xticks(np.arange(len(objs)), objs)
    ax.set_yscale("log")
    ax.set_ylabel("time per step (ms)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_memories(memories: dict, path, *, title: str = "") -> None:
    """Fig. 5 of seed 000: each estimator's memory over orientation (y) and samples (x).

    Parameters
    ----------
    memories : dict
        ``{panel title: (T, n) array}``, e.g. histogram, uncorrected and corrected memory.
    """
    plt = _plt()
    fig, axes = plt.subplots(len(memories), 1, figsize=(8, 2.3 * len(memories)), sharex=True, squeeze=False)
    for ax, (name, m) in zip(axes[:, 0], memories.items()):
        im = ax.imshow(np.asarray(m).T, aspect="auto", origin="lower", extent=(0, m.shape[0], 0, 360),
                       cmap="viridis", vmin=0, vmax=1, interpolation="nearest")
        ax.set_ylabel("orientation (deg)")
        ax.set_yticks([0, 90, 180, 270, 360])
        ax.set_title(name, fontsize=10)
        fig.colorbar(im, ax=ax, pad=0.01)
    axes[-1, 0].set_xlabel("sample")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
