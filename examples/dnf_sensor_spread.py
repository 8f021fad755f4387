"""The DNF tracker on a noisy sensor: what its spread normalisation estimates and changes.

A simulated n-gon turns between two fingers for four turns (seed 000's experiment). Each
finger gives two blob normals per sample from its curved pad, with ``--noise`` degrees of
angular noise on top of the pad's 1 mm centroid error, and one sample in ten has no
contact. The tracker runs twice on each data set: with its spread normalisation (the
default: it estimates how far one contact's normals scatter on the sides it remembers,
raises its input gain and lowers its correction gain when that is more than its
parameters were set for) and without it (``noise_ref=0``). The script prints, per data
set, the spread the tracker estimated against the generator's true one and the fraction
of the second half in which each counted the right number of sides, and with ``--plot``
saves both memories over time (docs/dnf.md, "The input stage: any spread of the normals").

Run::

    python examples/dnf_sensor_spread.py                       # 8-gon, 6 deg, 3 data sets
    python examples/dnf_sensor_spread.py --sides 6 --noise 3 --plot memories.png
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from touchloc.dnf import OrientationTracker, generate_rotation_dataset, run_estimator

#: the generator's blob-centroid error on the curved pad: 1 mm on a 2 cm radius (rad)
PAD_SPREAD = 0.001 / 0.02


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sides", type=int, default=8, help="sides of the n-gon (0: round)")
    ap.add_argument("--noise", type=float, default=6.0, help="angular noise of each normal, deg")
    ap.add_argument("--datasets", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plot", metavar="PNG", help="save the memories of the first data set")
    a = ap.parse_args(argv)
    true_spread = np.degrees(np.hypot(np.radians(a.noise), PAD_SPREAD))
    print(f"{a.sides}-gon, 2 pad normals per finger, {a.noise:g} deg of noise "
          f"({true_spread:.1f} deg with the pad's centroid error), 10 % empty samples")
    right = {"on": [], "off": []}
    for i in range(a.datasets):
        ds = generate_rotation_dataset(a.sides, rng=np.random.default_rng([a.seed, i]), normals_per_contact=2,
                                       noise=np.radians(a.noise), drop=0.1, normal_source="pad")
        trackers = {"on": OrientationTracker(), "off": OrientationTracker(noise_ref=0.0)}
        runs = {k: run_estimator(k, lambda t=t: t, ds, record=a.plot is not None and i == 0)
                for k, t in trackers.items()}
        for k, r in runs.items():
            right[k].append(r.accuracy)
        print(f"  data set {i}: estimated spread {np.degrees(trackers['on'].noise):.1f} deg; right side count "
              f"in {100 * runs['on'].accuracy:.0f} % of the second half with the normalisation, "
              f"{100 * runs['off'].accuracy:.0f} % without")
        if a.plot and i == 0:
            from touchloc.dnf.compare import plot_memories

            plot_memories({"spread normalisation (default)": runs["on"].memories,
                           "without (noise_ref=0)": runs["off"].memories}, a.plot,
                          title=f"{a.sides}-gon, {a.noise:g} deg of noise: memory over the samples")
            print(f"  memories saved to {a.plot}")
    print(f"mean right count: {np.mean(right['on']):.2f} with, {np.mean(right['off']):.2f} without")
    return 0


if __name__ == "__main__":
    sys.exit(main())
