"""DNF orientation tracker (seed 000): time per step and side-count accuracy of every estimator.

Speed: one tracker step (360 sites, all 1-D fields, the 360 x 360 comparison field and its
diagonal read-out), timed sample by sample on a simulated 6-gon data set; the comparison
field's lateral interaction is also timed with the exact FFT convolution, the baseline
measured in the same run. Accuracy: every estimator on the simulated data sets of seed
000's experiment (5 per object), plus a second set of seeds that was not used to choose
the tracker's parameters.
"""

from __future__ import annotations

import os
import time

import numpy as np

TITLE = "DNF orientation tracker (seed 000)"


def _step_times(make, ds, repeats):
    out = []
    samples = list(ds.samples())
    for _ in range(repeats):
        est = make()
        for a, odo in samples:
            t0 = time.perf_counter()
            est.step(a, odo)
            out.append(time.perf_counter() - t0)
    return np.array(out)


def _timing(quick: bool) -> str:
    from touchloc.dnf import HistogramEstimator, OrientationTracker, generate_rotation_dataset
    from touchloc.dnf.particle import ParticleOrientationEstimator

    ds = generate_rotation_dataset(6, revolutions=2 if quick else 4, rng=123)
    repeats = 1 if quick else 3
    rows = []
    makers = [
        ("DNF tracker, full (2-D comparison field: active-block lateral)", lambda: OrientationTracker()),
        ("DNF tracker, full, 2-D lateral by exact FFT (baseline)",
         lambda: _fft_tracker(OrientationTracker())),
        ("DNF tracker without correction (no 2-D field)", lambda: OrientationTracker(correct=False)),
        ("histogram", lambda: HistogramEstimator()),
        ("particle filter, 400 particles x 120 bins", lambda: ParticleOrientationEstimator(400, rng=0)),
    ]
    times = {}
    for name, make in makers:
        t = _step_times(make, ds, repeats)
        times[name] = t
    base = np.median(times[makers[1][0]])
    lines = [f"Per step, over {len(ds)} samples x {repeats} run(s) of a simulated 6-gon data set "
             "(360 sites; `tracker.step(normal_angles, odometry)` including input validation):", "",
             "| estimator | median | 95th percentile | mean | speed-up vs FFT baseline |", "|---|---|---|---|---|"]
    for name, t in times.items():
        lines.append(f"| {name} | {np.median(t) * 1e3:.3f} ms | {np.percentile(t, 95) * 1e3:.3f} ms | "
                     f"{t.mean() * 1e3:.3f} ms | {base / np.median(t):.2f}x |")
    full = times[makers[0][0]]
    verdict = "meets" if np.median(full) <= 1e-3 else "misses"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += ["", f"The full tracker step {verdict} the 1 ms target: median {np.median(full) * 1e3:.3f} ms, "
              f"{np.mean(full <= 1e-3):.0%} of steps within 1 ms. The machine was shared (load average "
              f"{load:.1f} on {os.cpu_count()} cores at the end of the timing), which inflates the tail and "
              "the mean; the median is the figure to compare."]
    return "\n".join(lines)


def _fft_tracker(tr):
    tr.comparison.method = "fft"
    return tr


def _accuracy(quick: bool, seed: int) -> str:
    from touchloc.dnf import standard_datasets
    from touchloc.dnf.compare import compare, default_estimators, summary_table

    n = 2 if quick else 5
    sets = standard_datasets(n_per_object=n, seed=seed)
    t0 = time.perf_counter()
    res = compare(sets, default_estimators(rng=0), progress_bar=False)
    dt = time.perf_counter() - t0
    return (f"{n} simulated data sets per object (`standard_datasets(seed={seed})`, about 4 turns and "
            f"410 samples each; {dt:.0f} s for all runs). \"Right count\" is the fraction of second-half "
            "samples whose count equals the number of sides (seed 000, Fig. 7); the orientation error is "
            "wrapped to the object's symmetry (2 pi / n), so for the round object it is the odometry's "
            "unobservable drift.\n\n" + summary_table(res))


def run(quick: bool = False) -> str:
    parts = ["### Time per step", "", _timing(quick), "",
             "### Side count, every estimator (seed 000, section V)", "", _accuracy(quick, 0)]
    if not quick:
        parts += ["", "#### Held-out seeds", "",
                  "The same on data sets the parameters were not tuned on:", "", _accuracy(quick, 1)]
    return "\n".join(parts)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
