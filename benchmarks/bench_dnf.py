"""DNF orientation tracker (seed 000): time per step and side-count accuracy of every estimator.

Speed: one tracker step (360 sites, all 1-D fields, the 360 x 360 comparison field and its
diagonal read-out), timed sample by sample on a simulated 6-gon data set; the comparison
field's lateral interaction is also timed with the exact FFT convolution, the baseline
measured in the same run. Accuracy: every estimator on the simulated data sets of seed
000's experiment (5 per object), plus a second set of seeds that was not used to choose
the tracker's parameters. Robustness: a sweep over seed-faithful data (one to 40
normals per finger and sample, angular noise, dropped samples, odometry bias, regrasp slip;
4-, 5-, 6-, 8-gons and a round object), every cell with the same default parameters, on
the sweep's seeds and on held-out seeds. Third family: the rotating n-gon mapped in 3-D by
tactile SLAM, on a few of the same data sets. End to end: seed 000's stroke experiment
recorded from the emulated hand's DSACON32m bytes.
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
    from touchloc.dnf._kernels import load_kernels
    from touchloc.dnf.particle import ParticleOrientationEstimator

    load_kernels()   # compiled (or loaded from the cache) before anything is timed
    ds = generate_rotation_dataset(6, revolutions=2 if quick else 4, rng=123)
    repeats = 1 if quick else 5
    rows = []
    makers = [
        ("DNF tracker, full (2-D comparison field: active-block lateral)", lambda: OrientationTracker()),
        ("DNF tracker, full, 2-D lateral by exact FFT (baseline)",
         lambda: _fft_tracker(OrientationTracker())),
        ("DNF tracker without correction (no 2-D field)", lambda: OrientationTracker(correct=False)),
        ("DNF tracker, full, without the detection evidence (`detection_gain=0, detection_mute_high=0`)",
         lambda: OrientationTracker(detection_gain=0.0, detection_mute_high=0.0)),
        ("histogram", lambda: HistogramEstimator()),
        ("particle filter, 400 particles x 120 bins", lambda: ParticleOrientationEstimator(400, rng=0)),
    ]
    # interleaved: each round runs every estimator once, in an order that turns by one each
    # round, so that the ratios to the baseline see the same load on a shared machine
    times = {name: [] for name, _ in makers}
    for r in range(repeats):
        for name, make in makers[r % len(makers):] + makers[:r % len(makers)]:
            times[name].append(_step_times(make, ds, 1))
    times = {name: np.concatenate(t) for name, t in times.items()}
    base = np.median(times[makers[1][0]])
    lines = [f"Per step, over {len(ds)} samples x {repeats} run(s) of a simulated 6-gon data set "
             "(360 sites; `tracker.step(normal_angles, odometry)` including input validation); the runs "
             f"of the first {len(makers)} rows interleaved, one of each per round:", "",
             "| estimator | median | 95th percentile | mean | speed-up vs FFT baseline |", "|---|---|---|---|---|"]
    for name, t in times.items():
        lines.append(f"| {name} | {np.median(t) * 1e3:.3f} ms | {np.percentile(t, 95) * 1e3:.3f} ms | "
                     f"{t.mean() * 1e3:.3f} ms | {base / np.median(t):.2f}x |")
    # the full tracker on the sweep's base cell too (seed-faithful: 2 pad normals per finger)
    sf = generate_rotation_dataset(6, revolutions=2 if quick else 4, rng=123, **_cell_kwargs(_BASE))
    t = _step_times(makers[0][1], sf, repeats)
    name = "DNF tracker, full, on the sweep's base cell (2 pad normals per finger, 10 % empty samples)"
    times[name] = t
    lines.append(f"| {name} | {np.median(t) * 1e3:.3f} ms | {np.percentile(t, 95) * 1e3:.3f} ms | "
                 f"{t.mean() * 1e3:.3f} ms | {base / np.median(t):.2f}x |")
    full = np.concatenate([times[makers[0][0]], t])
    verdict = "meets" if np.median(full) <= 1e-3 else "misses"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += ["", f"The full tracker step {verdict} the 1 ms target: median {np.median(full) * 1e3:.3f} ms, "
              f"{np.mean(full <= 1e-3):.0%} of steps within 1 ms. The machine was shared (load average "
              f"{load:.1f} on {os.cpu_count()} cores at the end of the timing), which inflates the tail and "
              "the mean; the median is the figure to compare."]
    return "\n".join(lines + ["", _against_baseline(quick)])


#: the commit before the step's speed-up (batched FFTs, the compiled comparison step)
TIMING_BASELINE = "6b516ff"


def _against_baseline(quick: bool) -> str:
    """The full tracker's step against :data:`TIMING_BASELINE`'s in the same run
    (``ab_dnf_step.py``: two worker processes, alternating run by run)."""
    from _common import table
    from ab_dnf_step import paired

    rounds = 2 if quick else 4
    res = paired(TIMING_BASELINE, rounds=rounds, revolutions=2 if quick else 4)
    if res is None:
        return f"(No commit {TIMING_BASELINE} in this checkout: the step was not timed against it.)"
    rows = [[name, f"{np.median(t) * 1e3:.3f} ms", f"{np.median(b) * 1e3:.3f} ms", f"{np.median(b) / np.median(t):.2f}x",
             "yes" if same else "no"] for name, (t, b, same) in res.items()]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"Against the commit before the step's speed-up ({TIMING_BASELINE}), measured in the same run: the "
            f"full tracker of each tree in its own worker process (single-threaded BLAS), {rounds} runs of each "
            "data set, alternating tree by tree (`python benchmarks/ab_dnf_step.py REV` prints the same table; "
            f"load average {load:.1f} at the end). \"Same\" compares the final orientation (within 1e-6 rad).\n\n"
            + table(["data set", "median, this tree", f"median, {TIMING_BASELINE}", "speed-up", "same"], rows))


def _fft_tracker(tr):
    tr.comparison.method = "fft"
    return tr


def _accuracy(quick: bool, seed: int) -> str:
    from touchloc.dnf import standard_datasets
    from touchloc.dnf.compare import compare, default_estimators, summary_table

    n = 2 if quick else 5
    sets = standard_datasets(n_per_object=n, seed=seed)
    t0 = time.perf_counter()
    res = compare(sets, default_estimators(rng=0), progress=False)
    dt = time.perf_counter() - t0
    return (f"{n} simulated data sets per object (`standard_datasets(seed={seed})`, about 4 turns and "
            f"410 samples each; {dt:.0f} s for all runs). \"Right count\" is the fraction of second-half "
            "samples whose count equals the number of sides (seed 000, Fig. 7); the orientation error is "
            "wrapped to the object's symmetry (2 pi / n), so for the round object it is the odometry's "
            "unobservable drift.\n\n" + summary_table(res))


#: the sweep's base cell: 2 blob normals per finger from the curved pad, 3 deg noise, 10 % of
#: the samples without contact, 4-8 % odometry under-estimate, 1.5 deg slip per regrasp
_BASE = dict(normals_per_contact=2, noise=3.0, drop=0.1, bias=None, slip=1.5)
_AXES = [("normals per finger", "normals_per_contact", [1, 2, 4, 12, 40]),
         ("noise (deg)", "noise", [1.0, 3.0, 6.0]),
         ("dropped samples", "drop", [0.0, 0.1, 0.2]),
         ("odometry bias", "bias", [0.0, None, 0.1]),
         ("slip per regrasp (deg)", "slip", [0.0, 1.5, 3.0])]
_SWEEP_OBJECTS = [("4-gon", 4), ("5-gon", 5), ("6-gon", 6), ("8-gon", 8), ("round", 0)]
#: the estimators of the sweep (touchloc.dnf.compare.default_estimators, made with rng=0)
DNF_NAMES = ("histogram", "memory, uncorrected", "DNF, corrected", "particle filter")
DNF, PARTICLE = DNF_NAMES[2], DNF_NAMES[3]


def _cell_kwargs(cell):
    bias = cell["bias"]
    return dict(normals_per_contact=cell["normals_per_contact"], noise=np.radians(cell["noise"]),
                drop=cell["drop"], normal_source="pad", slip_std=np.radians(cell["slip"]),
                under_estimate=(0.04, 0.08) if bias is None else (bias, bias))


#: data sets per object and cell in the sweep (seeds [2, ...]) and in its held-out run (seeds
#: [3, ...]): in the cells that fail, one data set's right count can be anywhere from 0 to
#: 100 %, so a cell's figure needs several
SWEEP_SETS, HELD_OUT_SETS = 6, 4


def sweep_cells() -> list[dict]:
    """The sweep's cells in its order (the base cell once): one knob moved at a time."""
    cells, seen = [], set()
    for _, key, values in _AXES:
        for v in values:
            c = dict(_BASE, **{key: v})
            k = tuple(sorted(c.items(), key=lambda kv: kv[0]))
            if k not in seen:
                seen.add(k)
                cells.append(c)
    return cells


def _sweep_cell(cell):
    """A cell as :class:`touchloc.experiments.DNFSweep` takes it."""
    return dict(normals_per_contact=cell["normals_per_contact"], noise_deg=cell["noise"], drop=cell["drop"],
                bias=(0.04, 0.08) if cell["bias"] is None else cell["bias"], slip_deg=cell["slip"])


def _cell_label(cell):
    b = "4-8 %" if cell["bias"] is None else f"{cell['bias']:.0%}"
    return (f"{cell['normals_per_contact']} / {cell['noise']:g} / {cell['drop']:.0%} / {b} / "
            f"{cell['slip']:g}")


def _sweep(quick: bool, seed: int = 2, n_sets: int | None = None, label: str = "") -> str:
    from _common import run_trials
    from touchloc.experiments import DNFSweep

    cells = sweep_cells()
    n_sets = n_sets or (1 if quick else SWEEP_SETS)
    revolutions = 3.0 if quick else 4.0
    # one trial per (cell, object, data set, estimator), all on the process pool
    sweep = DNFSweep(sides=[n for _, n in _SWEEP_OBJECTS], estimators=list(DNF_NAMES), sets=n_sets, seed=seed,
                     revolutions=revolutions, normal_source="pad",
                     cells=[_sweep_cell(c) for c in cells])
    t0 = time.perf_counter()
    results, how = run_trials(f"dnf-sweep-{seed}", sweep.trials(), quick)
    names = list(DNF_NAMES)
    rows = []
    worst = {}
    pf_vs_dnf = []
    worst_obj, base_acc = {}, []
    spread = {}
    for ci, cell in enumerate(cells):
        acc = {name: {} for name in names}
        for r in sorted((r for r in results if r["cell"] == ci), key=lambda r: (r["object"], r["set"])):
            acc[r["estimator"]].setdefault(_SWEEP_OBJECTS[r["object"]][0], []).append(r["accuracy"])
        dnf = {o: float(np.mean(v)) for o, v in acc[DNF].items()}
        spread[_cell_label(cell)] = {o: (min(v), max(v)) for o, v in acc[DNF].items()}
        means = {name: float(np.mean([np.mean(v) for v in acc[name].values()])) for name in names}
        pf8 = float(np.mean(acc[PARTICLE]["8-gon"]))
        pf_vs_dnf.append(dnf["8-gon"] - pf8)
        worst[_cell_label(cell)] = min(dnf.values())
        worst_obj[_cell_label(cell)] = min(dnf, key=dnf.get)
        base_acc.append((means["histogram"], means["memory, uncorrected"]))
        rows.append(f"| {_cell_label(cell)} | " + " | ".join(f"{dnf[o]:.0%}" for o, _ in _SWEEP_OBJECTS)
                    + f" | **{means[DNF]:.0%}** | {means['memory, uncorrected']:.0%} | "
                    f"{means['histogram']:.0%} | {means['particle filter']:.0%} | {pf8:.0%} |")
    dt = time.perf_counter() - t0
    n_ok = sum(w >= 0.9 for w in worst.values())
    failing = [(lab, w) for lab, w in worst.items() if w < 0.9]
    head = [f"{label}{n_sets} data set(s) per object and cell (seeds `[{seed}, cell, object, i]`), "
            f"{revolutions:g} turns each, generated with "
            "`generate_rotation_dataset(..., normal_source=\"pad\")` (blob-centroid normals of the curved "
            "finger pad, 1 mm centroid error on a 2 cm pad radius on top of the angular noise). One "
            "parameter at a time is varied around the base cell (2 normals per finger and sample, 3 deg "
            "noise, 10 % dropped samples, 4-8 % odometry under-estimate, 1.5 deg slip per regrasp); every "
            "estimator keeps its default parameters in every cell. Cells are \"normals per finger / noise "
            "(deg) / dropped / odometry bias / slip (deg)\". Entries are the fraction of second-half "
            f"samples with the right side count (round: 0). {dt:.0f} s for the sweep. {how}", "",
            "| cell | DNF 4-gon | DNF 5-gon | DNF 6-gon | DNF 8-gon | DNF round | DNF mean | memory, "
            "uncorrected | histogram | particle filter | PF 8-gon |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    tail = ["", f"The full DNF reaches >= 90 % on every object in {n_ok} of {len(cells)} cells. On the 8-gon "
            f"it is ahead of the particle filter by {np.mean(pf_vs_dnf) * 100:+.0f} points on average over "
            f"the cells (min {min(pf_vs_dnf) * 100:+.0f}, max {max(pf_vs_dnf) * 100:+.0f})."]
    if failing:
        tail.append("Cells below 90 % (cell: worst object, its right count" +
                    (", and its lowest and highest over the data sets" if n_sets > 1 else "") + "): " + "; ".join(
            f"{lab}: {worst_obj[lab]} {w:.0%}" + (" ({:.0%}-{:.0%})".format(*spread[lab][worst_obj[lab]])
                                                  if n_sets > 1 else "") for lab, w in failing) + ".")
    h, m = np.array(base_acc).T
    tail.append(f"The baselines still fail as seed 000 reports: the histogram gets {h.mean():.0%} right on average "
                f"over the cells (best cell {h.max():.0%}), the uncorrected memory {m.mean():.0%} "
                f"(best cell {m.max():.0%}).")
    return "\n".join(head + rows + tail)


#: data sets per object and cell of the large held-out run of the DNF alone (seeds [31, ...])
LARGE_SETS = 32


def _large(quick: bool, seed: int = 31) -> str:
    """The full DNF alone on many more held-out data sets per cell, with intervals.

    The sweep's cells hold 6 (and the held-out run's 4) data sets per object, and in the cells
    near 90 % a single data set that collapses moves the figure by 10-25 points. Here each
    cell and object gets :data:`LARGE_SETS` fresh data sets, and the figure a 95 % interval
    (bootstrap over the data sets), so that a cell's standing against 90 % can be read.
    """
    from _common import run_trials
    from touchloc.experiments import DNFSweep

    cells = sweep_cells()
    n_sets = 2 if quick else LARGE_SETS
    sweep = DNFSweep(sides=[n for _, n in _SWEEP_OBJECTS], estimators=[DNF], sets=n_sets, seed=seed,
                     revolutions=4.0, normal_source="pad",
                     cells=[_sweep_cell(c) for c in cells])
    t0 = time.perf_counter()
    results, how = run_trials(f"dnf-large-{seed}", sweep.trials(), quick)
    dt = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    rows, below, short = [], [], []
    for ci, cell in enumerate(cells):
        acc = {}
        for r in sorted((r for r in results if r["cell"] == ci), key=lambda r: (r["object"], r["set"])):
            acc.setdefault(_SWEEP_OBJECTS[r["object"]][0], []).append(r["accuracy"])
        entries = []
        for o, _ in _SWEEP_OBJECTS:
            v = np.array(acc[o])
            boot = rng.choice(v, size=(2000, v.size)).mean(axis=1)
            lo, hi = np.percentile(boot, [2.5, 97.5])
            entries.append(f"{v.mean():.1%} ({lo:.1%}-{hi:.1%})")
            if v.mean() < 0.9:
                below.append(f"{_cell_label(cell)}: {o} {v.mean():.1%} ({lo:.1%}-{hi:.1%})")
            if hi < 0.9:
                short.append(f"{_cell_label(cell)}: {o}")
        rows.append(f"| {_cell_label(cell)} | " + " | ".join(entries) + " |")
    head = [f"{n_sets} data sets per object and cell (seeds `[{seed}, cell, object, i]`, neither the development "
            f"seeds nor the sweep's), 4 turns each, the full DNF alone with its defaults. Entries are the right "
            "count over the second halves, with a 95 % interval (bootstrap over the data sets: 2,000 resamples). "
            f"{dt:.0f} s. {how}", "",
            "| cell | 4-gon | 5-gon | 6-gon | 8-gon | round |", "|---|---|---|---|---|---|"]
    tail = ["", ("Below 90 %: " + "; ".join(below) + "." if below else
                 "Every cell and object is at 90 % or more.")
            + (" Of these, the interval lies wholly below 90 % for: " + "; ".join(short) + "." if short else
               " No interval lies wholly below 90 %.")]
    return "\n".join(head + rows + tail)


def _families(quick: bool) -> str:
    """All three families (neural fields, particle filter, 3-D map) on the same data sets."""
    from touchloc.dnf import SEED_FAITHFUL, generate_rotation_dataset
    from touchloc.dnf.compare import MAPPED, compare, summary_table
    from touchloc.experiments.ngon import estimators_with_map

    objects = [("6-gon", 6), ("8-gon", 8), ("round", 0)] if quick else \
        [("4-gon", 4), ("5-gon", 5), ("6-gon", 6), ("8-gon", 8), ("round", 0)]
    out = []
    n_sets = 1 if quick else 4
    for title, kw in (("dense data (the first generator's default)", {}),
                      ("seed-faithful data (`SEED_FAITHFUL`: 1-2 pad normals per finger, 3 deg, 10 % dropped)",
                       SEED_FAITHFUL)):
        sets = {o: [generate_rotation_dataset(n, rng=np.random.default_rng([5, n, i]), name=f"{o} #{i + 1}", **kw)
                    for i in range(n_sets)] for o, n in objects}
        t0 = time.perf_counter()
        res = compare(sets, estimators_with_map(rng=0), progress=False)
        dt = time.perf_counter() - t0
        mapped_s = np.mean([r.seconds_per_step * len(r.counts) for o in res for r in res[o][MAPPED]])
        sets_text = "one data set" if n_sets == 1 else f"{n_sets} data sets"
        seeds_text = "`[5, n, 0]`" if n_sets == 1 else f"`[5, n, i]`, i = 0-{n_sets - 1}"
        out += [f"On {title}; {sets_text} per object, 4 turns (seeds {seeds_text}); {dt:.0f} s for all "
                f"runs, {mapped_s:.0f} s per data set for the 3-D map (it touches on every 4th sample, two "
                "fingers, 100 pose particles):", "", summary_table(res), ""]
    return "\n".join(out)



#: held-out settings of the emulated hand: seeds and geometry not looked at while the width
#: filter (8 mm) was chosen on seeds 0-1 at the defaults
EMULATED_HELD_OUT = (
    ("seed 7", {}),
    ("press 0.5 mm", {"depth": 0.0005}),
    ("press 1.2 mm", {"depth": 0.0012}),
    ("sides 15 mm from the axis", {"inradius": 0.015}),
    ("sides 24 mm from the axis", {"inradius": 0.024}),
    ("pad radius 15 mm", {"pad_radius": 0.015}),
    ("pad radius 15 mm, filter 7 mm", {"pad_radius": 0.015, "min_width": 0.007}),
    ("slip 1.5 deg, odometry 10 % short", {"slip_std": float(np.radians(1.5)), "under_estimate": 0.10}),
)


def _emulated(quick: bool) -> str:
    """The tracker and its rivals on normals recorded from the emulated hand's bytes."""
    from touchloc.dnf.compare import compare, default_estimators, summary_table
    from touchloc.experiments.ngon import emulated_rotation

    objects = [("6-gon", 6), ("8-gon", 8)] if quick else [("4-gon", 4), ("5-gon", 5), ("6-gon", 6), ("8-gon", 8)]
    n_sets = 1 if quick else 2
    t0 = time.perf_counter()
    runs = {}
    for label, width in (("default", 0.008), ("every blob", None)):
        sets = {o: [emulated_rotation(n, turns=4.0, rng=i, min_width=width, name=f"{o} #{i + 1}")
                    for i in range(n_sets)] for o, n in objects}
        runs[label] = compare(sets, default_estimators(rng=0), progress=False)
    rec = time.perf_counter() - t0
    out = ["`touchloc.experiments.ngon.emulated_rotation(n, turns=4, rng=i)`: an n-gon prism "
           "(sides 18 mm from its axis) between the three distal pads of the emulated SDH-2, turned in "
           "strokes of 25-40 deg with the fingers, regrasped, odometry 6 % short. Every sample is a "
           "DSACON32m frame rendered by the emulator (pads curved across the finger, 20 mm radius, each "
           "pressed 0.8 mm into the object), read by the driver over a loopback TCP socket and cut into "
           "blobs; blobs at least 8 mm wide across the finger (flat sides; a corner touches the pad along "
           "one texel column) become one normal each (`frame_normal_angles(..., min_width=0.008)`). "
           f"{rec:.0f} s to record and run both tables, the estimators' defaults unchanged.", "",
           summary_table(runs["default"]), "",
           "The same recordings with every blob kept (`min_width=None`), corners included:", "",
           summary_table(runs["every blob"]), ""]
    if quick:
        return "\n".join(out)
    # held out: other seeds, presses, sizes and pads; one data set per object
    head = "| setting | " + " | ".join(f"DNF {o}" for o, _ in objects) + " | " + \
        " | ".join(f"PF {o}" for o, _ in objects) + " | DNF, every blob (mean) |"
    rows = [head, "|" + "---|" * (2 * len(objects) + 2)]
    t0 = time.perf_counter()
    for label, kw in EMULATED_HELD_OUT:
        kw = dict(kw)
        width = kw.pop("min_width", 0.008)
        cells = {}
        for w in (width, None):
            sets = {o: [emulated_rotation(n, turns=4.0, rng=np.random.default_rng([7, n]), min_width=w, **kw)]
                    for o, n in objects}
            cells[w] = compare(sets, {k: v for k, v in default_estimators(rng=0).items() if k in (DNF, PARTICLE)},
                               progress=False)
        acc = lambda res, o, est: float(np.nanmean([r.accuracy for r in res[o][est]]))  # noqa: E731
        dnf = [acc(cells[width], o, DNF) for o, _ in objects]
        pf = [acc(cells[width], o, PARTICLE) for o, _ in objects]
        raw = np.mean([acc(cells[None], o, DNF) for o, _ in objects])
        rows.append(f"| {label} | " + " | ".join(f"{a:.0%}" for a in dnf) + " | " +
                    " | ".join(f"{a:.0%}" for a in pf) + f" | {raw:.0%} |")
    out += [f"Held out (seeds `[7, n]`, one data set per object; settings not looked at while choosing the 8 mm "
            f"width on seeds 0-1; {time.perf_counter() - t0:.0f} s). Right count in the second half, width "
            "filter on unless the setting says otherwise:", ""] + rows
    return "\n".join(out)


def run(quick: bool = False) -> str:
    parts = ["### Time per step", "", _timing(quick), "",
             "### Side count, every estimator (seed 000, section V)", "", _accuracy(quick, 0)]
    parts += ["", "### Robustness sweep on seed-faithful data", "", _sweep(quick)]
    parts += ["", "#### Held-out seeds", "",
              "The parameters were chosen on development seeds `[11, cell, object, i]`, neither the "
              "sweep's nor these:", "",
              _sweep(quick, seed=3, n_sets=1 if quick else HELD_OUT_SETS, label="Held-out sweep: ")]
    parts += ["", "#### Many held-out data sets, the DNF alone", "", _large(quick)]
    if not quick:
        # a second family of as many fresh data sets: one family's intervals, read against 90 %,
        # were what a parameter change was judged on, so its verdict is checked on another
        parts += ["", "A second family of held-out data sets, as many, on other seeds:", "", _large(quick, seed=41)]
        parts += ["", _accuracy(quick, 1)]
    parts += ["", "### Three families: neural fields, particle filter, 3-D map (tactile SLAM)", "", _families(quick)]
    parts += ["### End to end on the emulated hand's tactile bytes", "", _emulated(quick)]
    return "\n".join(parts)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
