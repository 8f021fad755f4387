"""``touchloc compare-dnf`` and ``touchloc dnf-figure``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ValidationError


def register(sub) -> None:
    p = sub.add_parser("compare-dnf", help="DNF tracker vs histogram, uncorrected memory and particle filter",
                       description="Run the shape estimators of the DNF paper (\"Using Haptics to Extract Object Shape from "
                                   "Rotational Manipulations\": accumulated histogram, memory trace "
                                   "without correction, full DNF model) and a Rao-Blackwellised particle filter "
                                   "on the same rotation data sets; print the side counts and orientation errors "
                                   "and save the plots.")
    p.add_argument("--objects", nargs="+", default=["6-gon", "8-gon", "round"],
                   help="simulated objects (4-gon, 5-gon, 6-gon, 8-gon, round)")
    p.add_argument("--datasets", type=int, default=5, help="simulated data sets per object (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated data sets")
    p.add_argument("--recording", nargs="+", metavar="FILE",
                   help="use recorded data sets (.csv or .npz, see docs/dnf.md) instead of simulated ones")
    p.add_argument("--source", choices=["simulated", "emulator"], default="simulated",
                   help="where the normals come from: the rotation generator (default) or the emulated hand's "
                        "DSACON32m frames (blobs -> curved-pad normals; slower, a few seconds per data set)")
    p.add_argument("--turns", type=float, default=4.0, help="turns per emulated data set (default 4)")
    p.add_argument("--min-width", type=float, default=8.0, metavar="MM",
                   help="emulator: keep blobs at least this wide across the finger, mm (flat sides; "
                        "corners touch along one texel column); 0 keeps every blob (default 8)")
    p.add_argument("--mapped", action="store_true",
                   help="add the third family: the n-gon mapped in 3-D by tactile SLAM (seconds per data set; "
                        "simulated data only)")
    p.add_argument("--particles", type=int, default=400, help="particles of the particle filter")
    p.add_argument("--normals", type=int, metavar="K",
                   help="simulate K blob normals per finger and sample from the curved pad (1..40), as a real "
                        "hand gives them, instead of the dense default")
    p.add_argument("--noise", type=float, default=None, metavar="DEG", help="angular noise of each normal, deg")
    p.add_argument("--drop", type=float, default=0.0, help="fraction of samples without contact (default 0)")
    p.add_argument("--out", default="dnf_compare", help="directory for the PNG plots (default dnf_compare)")
    p.add_argument("--no-plots", action="store_true", help="print the tables only")
    p.set_defaults(func=run_compare)

    f = sub.add_parser("dnf-figure", help="Fig. 5 of the DNF paper: histogram, uncorrected and corrected memory over time",
                       description="Plot the accumulated histogram, the uncorrected memory trace and the corrected "
                                   "memory trace of one data set over time, as in Fig. 5 of \"Using Haptics to Extract Object "
                                   "Shape from Rotational Manipulations\".")
    f.add_argument("--object", default="6-gon", help="simulated object (4-gon, 5-gon, 6-gon, 8-gon, round)")
    f.add_argument("--dataset", type=int, default=5, help="which simulated data set, 1-based (default 5)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--recording", metavar="FILE", help="a recorded data set instead (.csv or .npz)")
    f.add_argument("--out", default="dnf_fig5.png", help="output PNG (default dnf_fig5.png)")
    f.set_defaults(func=run_figure)


def _load(args):
    from .data import load_recording

    if args.recording:
        files = args.recording if isinstance(args.recording, list) else [args.recording]
        sets = {}
        for fn in files:
            ds = load_recording(fn)
            key = f"{ds.n_surfaces}-gon" if ds.n_surfaces else ("round" if ds.n_surfaces == 0 else Path(fn).stem)
            sets.setdefault(key, []).append(ds)
        return sets
    return None


def run_compare(args) -> int:
    from .compare import (compare, default_estimators, plot_orientation_error, plot_second_half,
                          plot_step_time, plot_surface_counts, summary_table)
    from .data import standard_datasets

    knobs = {}
    if args.normals is not None:
        knobs.update(normals_per_contact=args.normals, normal_source="pad")
    if args.noise is not None:
        knobs["noise"] = float(np.radians(args.noise))
    if args.drop:
        knobs["drop"] = args.drop
    sets = _load(args)
    if sets is None and args.source == "emulator":
        from ..experiments.ngon import emulated_rotation
        from .data import OBJECTS

        bad = [o for o in args.objects if o not in OBJECTS]
        if bad:
            raise ValidationError(f"unknown objects {bad}, expected some of {list(OBJECTS)}")
        width = args.min_width * 1e-3 if args.min_width != 0 else None
        sets = {o: [emulated_rotation(OBJECTS[o], turns=args.turns, rng=np.random.default_rng([args.seed, i]),
                                       min_width=width, name=f"{o} #{i + 1}")
                    for i in range(args.datasets)] for o in args.objects}
    if sets is None:
        sets = standard_datasets(args.objects, args.datasets, seed=args.seed, **knobs)
    n = sum(len(v) for v in sets.values())
    print(f"{n} data sets: " + ", ".join(f"{k} x {len(v)}" for k, v in sets.items()))
    if args.mapped:
        from ..experiments.ngon import estimators_with_map

        estimators = estimators_with_map(particles=args.particles, rng=args.seed)
    else:
        estimators = default_estimators(particles=args.particles, rng=args.seed)
    results = compare(sets, estimators)
    print()
    print(summary_table(results))
    if not args.no_plots:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        plot_surface_counts(results, out / "dnf_surfaces.png")
        plot_second_half(results, out / "dnf_second_half.png")
        plot_step_time(results, out / "dnf_step_time.png")
        if any(r.error is not None for by in results.values() for runs in by.values() for r in runs):
            plot_orientation_error(results, out / "dnf_orientation_error.png")
        print(f"\nplots in {out}/: dnf_surfaces.png (the DNF paper's Fig. 6), dnf_second_half.png (Fig. 7), "
              "dnf_orientation_error.png, dnf_step_time.png")
    return 0


def run_figure(args) -> int:
    from .compare import default_estimators, plot_memories, run_estimator
    from ..errors import ValidationError
    from .data import OBJECTS, generate_rotation_dataset, load_recording

    if args.recording:
        ds = load_recording(args.recording)
    else:
        if args.object not in OBJECTS:
            raise ValidationError(f"unknown object {args.object!r}, expected one of {list(OBJECTS)}")
        if args.dataset < 1:
            raise ValidationError(f"--dataset is 1-based, got {args.dataset}")
        names = list(OBJECTS)
        ds = generate_rotation_dataset(OBJECTS[args.object], name=f"{args.object} #{args.dataset}",
                                       rng=np.random.default_rng([args.seed, names.index(args.object),
                                                                  args.dataset - 1]))
    est = default_estimators(rng=args.seed)
    mems, lines = {}, []
    for name, title in (("histogram", "Histogram (each sample normalised)"),
                        ("memory, uncorrected", "Uncorrected memory trace"),
                        ("DNF, corrected", "Corrected memory trace")):
        run = run_estimator(name, est[name], ds, record=True)
        mems[title] = run.memories
        lines.append(f"{name}: {run.counts[-1]} sides at the end, right in {run.accuracy:.0%} of the 2nd half"
                     if run.n_true is not None else f"{name}: {run.counts[-1]} sides at the end")
    plot_memories(mems, args.out, title=f"{ds.name}: memory over orientation and time")
    print("\n".join(lines))
    print(f"wrote {args.out}")
    return 0
