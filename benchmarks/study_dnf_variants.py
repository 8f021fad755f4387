"""Structural variants of the DNF tracker at its mapping bottleneck, and why sides go missing.

Each variant changes what the tracker computes, not only a parameter, and runs on the
development seeds ``[11, cell, object, set]`` of all 13 cells of the robustness sweep and
all five objects (as ``study_dnf_search.py``'s stage 2; the defaults there on data sets
0-7: 10 cells, mean 0.969, 8-gon 0.907):

* ``defaults``;
* ``spread-tuning``: where the estimated spread ``s`` exceeds ``noise_ref``, the filter
  bank's tuning widens to ``sqrt(w^2 + s^2 - noise_ref^2)`` instead of the input gain
  rising (``spread-tuning+gain``: both). Either restores the expected bump's height; the
  wider tuning also smooths a sample's few scattered normals into one bump;
* ``gated-decay-W-M``: the memory decays only where this sample's normals land (a von
  Mises bump of width W deg, capped at 1), at M times the default rate: forgetting on
  evidence against a side, not on time, so that a side the surface field misses on a
  visit is not lost between its writes;
* ``map-tau-T``: the map field's time constant T samples (default 5), so that a stroke's
  few detections write sooner.

``--why CELL OBJECT`` runs the defaults with the true rotation as odometry (the tracking
taken out, as ``study_dnf_probes.py``'s probe) and splits the wrong second-half samples
into a side missing, a side split in two, a stray peak, or a mix; for one data set
(``--set``) it lists each side's visits (samples with a normal within 8 deg of it) and
the memory's strength there every 20 samples. The figures are in docs/dnf.md ("Sixth
round").

    cd benchmarks
    ../.venv/bin/python study_dnf_variants.py defaults spread-tuning gated-decay-10-3 map-tau-4 --sets 0-7
    ../.venv/bin/python study_dnf_variants.py --why noise=6 8-gon --set 7
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from study_dnf_probes import CELLS, _sets, dev_dataset  # noqa: E402
from study_dnf_search import OBJECTS, evaluate, summary  # noqa: E402


def factory(variant: str):
    """A zero-argument callable that makes the variant's tracker."""
    from touchloc.dnf import OrientationTracker, TrackerParams
    from touchloc.dnf.tracker import population_code

    if variant == "defaults":
        return OrientationTracker
    if variant.startswith("spread-tuning"):
        keep_gain = variant.endswith("+gain")

        class SpreadTuning(OrientationTracker):
            def _observe_spread(self, sp, mu):
                self.params = self._base
                super()._observe_spread(sp, mu)
                s, w, ref = self._noise, self._base.tuning_width, self._base.noise_ref
                if s > ref:
                    if not keep_gain:
                        self._gain_scale = 1.0
                    self.params = dataclasses.replace(self._base, tuning_width=float(np.sqrt(w * w + s * s - ref * ref)))

        def make():
            t = SpreadTuning()
            t._base = t.params
            return t
        return make
    if variant.startswith("gated-decay-"):
        width, mult = (float(x) for x in variant.split("-")[2:4])

        class GatedDecay(OrientationTracker):
            def __init__(self):
                super().__init__()
                self._gate = np.zeros(self.n_sites)
                trace, gate = self.trace, self._gate

                def step(f):
                    P = trace.P
                    P += (trace.dt / trace.tau) * (trace.build * (f - P) * f - mult * trace.decay * P * (1.0 - f) * gate)
                    return P
                trace.step = step

            def _step(self, a):
                if a.size:
                    code = population_code(a - self.orientation, self.n_sites, np.radians(width), 1.0)
                    np.minimum(code, 1.0, out=self._gate)
                super()._step(a)
        return GatedDecay
    if variant.startswith("evidence-"):
        # evidence-T-K-TH[-S]: a leaky histogram of the object-frame codes (time constant T
        # samples), its contrast against a blur of S deg (default 15), and K times its
        # excess over TH added to the map field's drive
        hand_h = variant.startswith("evidence-gwh-")
        withheld = hand_h or variant.startswith("evidence-gw-")
        gated = withheld or variant.startswith("evidence-gated-")
        parts = variant.split("-")[2 if gated else 1:]
        T, K, TH = (float(x) for x in parts[:3])
        S = float(parts[3]) if len(parts) > 3 else 15.0
        from touchloc.dnf.fields import circular_convolve

        class Evidence(OrientationTracker):
            def __init__(self):
                super().__init__()
                n = self.n_sites
                x = np.radians(np.arange(n))
                d = np.minimum(x, 2 * np.pi - x)
                g = np.exp(-0.5 * (d / np.radians(S)) ** 2)
                self._wide = np.fft.rfft(g / g.sum())
                self._near = np.fft.rfft(g / g.max())
                self._H = np.zeros(n)
                self._Hw = np.zeros(n)
                self._pre = np.zeros(n)
                step = self.map.step
                self.map.step = lambda drive: step(drive + self._pre * self._gate())

            def _gate(self):
                """1, or where the hand field is active (as the match drive's gate) less."""
                if not gated:
                    return 1.0
                from touchloc.dnf.tracker import TWO_PI, sigmoid

                p, n = self.params, self.n_sites
                shift = int(round(self.orientation * n / TWO_PI)) % n
                g_h = np.roll(sigmoid(self.hand.u + p.hand_gate_margin, p.hand.beta), -shift)
                gate = 1.0 - np.clip(circular_convolve(g_h, self._match_blur_fft, n), 0.0, 1.0)
                if withheld:
                    # only where no side is remembered nearby: the histogram adds sides, the
                    # match drive keeps the remembered ones at their place
                    gate = gate * (1.0 - np.clip(circular_convolve(self.trace.P, self._near, n), 0.0, 1.0))
                return gate

            def _step(self, a):
                if a.size:
                    o = self.odometry + self.correction
                    if self._last_odo is not None:
                        o += self._rate * (self.odometry - self._last_odo)
                    code = population_code(a - o, self.n_sites, self.params.tuning_width, 1.0, normalize=True)
                    self._H += (code - self._H) / T
                    C = self._H / max(self._H.mean(), 1e-12)
                    D = C - circular_convolve(C, self._wide, self.n_sites)
                    if hand_h:
                        # the same contrast in the hand's frame, moved into the object frame:
                        # a contact that holds still against the hand is not a side
                        self._Hw += (population_code(a, self.n_sites, self.params.tuning_width, 1.0,
                                                     normalize=True) - self._Hw) / T
                        Cw = self._Hw / max(self._Hw.mean(), 1e-12)
                        Dw = Cw - circular_convolve(Cw, self._wide, self.n_sites)
                        shift = int(round(o * self.n_sites / (2 * np.pi))) % self.n_sites
                        D = D - np.maximum(np.roll(Dw, -shift), 0.0)
                    self._pre = K * np.clip(D - TH, 0.0, None)
                super()._step(a)
        return Evidence
    if variant.startswith("map-tau-"):
        tau = float(variant.split("-")[2])
        default = TrackerParams().map
        return lambda: OrientationTracker(map=dataclasses.replace(default, tau=tau))
    raise SystemExit(f"unknown variant {variant!r}")


def right_counts(make, ds) -> float:
    from touchloc.dnf.compare import run_estimator

    counts = run_estimator("dnf", make, ds).counts
    return float(np.mean(counts[len(counts) // 2:] == ds.n_surfaces))


def _one(job):
    import warnings

    warnings.simplefilter("ignore")
    variant, ci, obj, s = job
    return right_counts(factory(variant), dev_dataset(ci, obj, s))


def why(cell: str, obj: str, sets, one_set: int) -> None:
    """The wrong second-half samples of the defaults with the true rotation as odometry."""
    from touchloc.dnf import OrientationTracker, RotationDataset, surface_peaks

    n = dict(zip(OBJECTS, (4, 5, 6, 8, 0)))[obj]
    site = np.radians(np.arange(360))
    total = dict.fromkeys(("right", "missing", "split", "stray", "mixed"), 0)
    for s in sets:
        ds = dev_dataset(CELLS[cell][0], obj, s)
        ds = RotationDataset(ds.time, ds.true_orientation, ds.normal_angles, ds.sample_index,
                             true_orientation=ds.true_orientation, n_surfaces=ds.n_surfaces, name=ds.name)
        tracker = OrientationTracker(rate_prior_mean=0.0)
        memory, seen = [], []
        for a, odo in ds.samples():
            tracker.step(a, odo)
            memory.append(tracker.trace.P.copy())
            seen.append(np.degrees(np.asarray(a) - odo) % 360)
        # the sides in the object frame: the phase of the final memory's n-fold harmonic
        phase = np.angle(np.sum(memory[-1] * np.exp(1j * n * site))) / n if n else 0.0
        sides = (phase + np.arange(n) * 2 * np.pi / max(n, 1)) % (2 * np.pi)
        for P in memory[len(memory) // 2:]:
            pk = surface_peaks(P)
            if n == 0:
                total["right" if pk.size == 0 else "stray"] += 1
                continue
            d = np.abs((pk[:, None] - sides[None, :] + np.pi) % (2 * np.pi) - np.pi)
            close = d.min(axis=1) < np.radians(12) if pk.size else np.zeros(0, bool)
            per = np.bincount(d.argmin(axis=1)[close], minlength=n) if pk.size else np.zeros(n, int)
            missing, split, stray = bool((per == 0).any()), bool((per > 1).any()), bool((~close).any())
            kind = ("right" if not (missing or split or stray) else
                    "mixed" if missing + split + stray > 1 else
                    "missing" if missing else "split" if split else "stray")
            total[kind] += 1
        if s == one_set and n:
            print(f"data set {s}: each side's visits and the memory there every 20 samples")
            for sd in np.degrees(sides):
                near = (np.arange(-12, 13) + int(round(sd))) % 360
                visits = sum(np.any(np.abs((x - sd + 180) % 360 - 180) < 8) for x in seen)
                strength = " ".join(f"{P[near].max():.2f}" for P in memory[::20])
                print(f"  side {sd:5.1f} deg: {visits:3d} visits; memory {strength}")
    n_all = sum(total.values())
    print(f"{cell}, {obj}, true rotation as odometry, data sets {sets[0]}-{sets[-1]}: "
          + ", ".join(f"{k} {100 * v / n_all:.0f} %" for k, v in total.items()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["defaults"])
    ap.add_argument("--sets", default="0-7")
    ap.add_argument("--why", nargs=2, metavar=("CELL", "OBJECT"))
    ap.add_argument("--set", type=int, default=-1, help="with --why: the data set whose sides to list")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    a = ap.parse_args(argv)
    sets = _sets(a.sets)
    if a.why:
        why(a.why[0], a.why[1], sets, a.set)
        return 0
    names = {i: name for name, (i, _) in CELLS.items()}
    with ProcessPoolExecutor(a.workers) as ex:
        for variant in a.variants:
            factory(variant)   # an unknown name fails here, not in a worker
            t0 = time.perf_counter()
            table = evaluate(ex, variant, OBJECTS, sets, one=_one)
            r = summary(table)
            print(f"{variant}: cells {r['cells']}, mean {r['mean']:.3f}, score {r['score']:.4f}, "
                  f"8-gon {r['8-gon']:.3f} ({time.perf_counter() - t0:.0f} s)")
            for ci in range(len(CELLS)):
                row = [table[f"{ci}|{o}"] for o in OBJECTS]
                if min(row) < 0.9:
                    print(f"  {names[ci]:>22}: " + " / ".join(f"{100 * x:.0f}" for x in row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
