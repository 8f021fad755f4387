"""``touchloc recognize``: simulate the scans of "Dynamic Tactile Sensing for Object Identification" and
run that paper's protocol."""

from __future__ import annotations

import time

import numpy as np


def register(sub):
    p = sub.add_parser("recognize", help="identify objects from simulated tactile scans (\"Dynamic Tactile Sensing for Object Identification\")",
                       description="Simulate the scans of \"Dynamic Tactile Sensing for Object Identification\" (7 objects x 20 scans, 160 frames of a 16x16 pad), "
                                   "train the view-based classifier on 16 scans per object, test on 4, over "
                                   "random splits, and print accuracy beside a nearest-neighbour baseline.")
    p.add_argument("--objects", choices=["bundled", "procedural"], default="bundled",
                   help="bundled real meshes (default) or procedural primitive shapes")
    p.add_argument("--scans", type=int, default=20, help="scans per object (the paper: 20)")
    p.add_argument("--train", type=int, default=16, help="training scans per object (the paper: 16)")
    p.add_argument("--splits", type=int, default=10, help="random train/test splits (the paper: 10)")
    p.add_argument("--pca", choices=["svd", "sanger"], default="svd", help="local PCA method")
    p.add_argument("--n-vq", type=int, default=6)
    p.add_argument("--n-pc", type=int, default=8)
    p.add_argument("--n-llm", type=int, default=20)
    p.add_argument("--no-baseline", action="store_true", help="skip the nearest-neighbour baseline")
    p.add_argument("--reject", action="store_true",
                   help="also measure rejection of two held-back objects (ROC AUC of the novelty score)")
    p.add_argument("--plot", metavar="PNG", help="save the frames of one scan of the first object")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ValidationError
    from . import (NearestNeighbourClassifier, SequenceClassifier, bundled_objects, evaluate_protocol,
                   evaluate_rejection, procedural_objects, simulate_dataset)

    if args.scans <= args.train:
        raise ValidationError(f"--scans ({args.scans}) must exceed --train ({args.train})")
    rng = np.random.default_rng(args.seed)
    objects = bundled_objects() if args.objects == "bundled" else procedural_objects()
    t0 = time.perf_counter()
    X, y = simulate_dataset(objects, args.scans, rng=rng)
    print(f"simulated {len(objects)} objects x {args.scans} scans, {X.shape[1]} frames of "
          f"{X.shape[2]}x{X.shape[3]} in {time.perf_counter() - t0:.1f} s: {', '.join(objects)}")
    if args.plot:
        from .plot import plot_scan

        first = next(iter(objects))
        plot_scan(X[0], title=f"{first}, scan 0").savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")

    def seq(s):
        return SequenceClassifier(args.n_vq, args.n_pc, args.n_llm, pca=args.pca, rng=args.seed * 1000 + s)

    rows = [(f"SequenceClassifier ({args.n_vq}, {args.n_pc}, {args.n_llm}, {args.pca})",
             evaluate_protocol(X, y, seq, n_train=args.train, n_splits=args.splits, rng=rng))]
    if not args.no_baseline:
        rows.append(("nearest neighbour", evaluate_protocol(X, y, lambda s: NearestNeighbourClassifier(),
                                                            n_train=args.train, n_splits=args.splits, rng=rng)))
    print(f"\n{args.splits} splits, {args.train} train / {args.scans - args.train} test scans per object; "
          f"chance {100 * rows[0][1].chance:.0f} %")
    print(f"{'classifier':44s} {'accuracy':>9s} {'range':>13s} {'train s':>8s} {'predict s':>9s}")
    for name, r in rows:
        lo, hi = r.range
        print(f"{name:44s} {100 * r.mean:8.1f}% {100 * lo:5.1f}-{100 * hi:5.1f} % {r.train_times.mean():8.2f} "
              f"{r.predict_times.mean():9.3f}")
    if args.reject:
        rej = evaluate_rejection(X, y, lambda s: SequenceClassifier(args.n_vq, args.n_pc, args.n_llm, pca=args.pca,
                                                                    reject_quantile=0.95, rng=s),
                                 n_train=args.train, n_splits=args.splits, rng=rng)
        line = f"\nrejection of 2 held-back objects: ROC AUC {rej.aucs.mean():.3f} ({rej.aucs.min():.3f}-{rej.aucs.max():.3f})"
        if rej.false_reject is not None:
            line += (f"; at the 95 % threshold {100 * rej.true_reject.mean():.0f} % of unknown and "
                     f"{100 * rej.false_reject.mean():.0f} % of known scans rejected")
        print(line)
    return 0
