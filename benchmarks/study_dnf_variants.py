"""Structural variants of the DNF tracker at its mapping bottleneck, and why sides go missing.

Each variant changes what the tracker computes, not only a parameter, and runs on the
development seeds ``[11, cell, object, set]`` of all 13 cells of the robustness sweep and
all five objects (as ``study_dnf_search.py``'s stage 2; the defaults there on data sets
0-7: 10 cells, mean 0.969, 8-gon 0.907 before the ninth round, 11, 0.978, 0.934 after
it, 11, 0.982, 0.935 after the tenth, 11, 0.988, 0.951 after the eleventh, 12, 0.992,
0.972 after the twelfth, 12, 0.993, 0.976 after the thirteenth, 12, 0.995, 0.983 since
the seventeenth):

* ``defaults`` (the shipped tracker: since the ninth round with its detection evidence,
  since the tenth with the mute; the figures of the earlier rounds in docs/dnf_rounds.md are
  those of the tracker without them, ``set:detection_gain=0,detection_mute_high=0``, and
  the ninth round's those without the mute, ``set:detection_mute_high=0``; the
  ``evidence-*``, ``write-*`` and ``detect-*`` variants turn both off themselves (and the
  split decay, and set ``rate_prior=1``), while the others now run on top of them. They do
  not repeat their rounds' figures exactly: ``evidence-gwh-150-3-0.4`` scored 8 cells, mean
  0.982, 8-gon 0.948 in the seventh round and scores 9, 0.974, 0.934 on the same data sets
  since the eleventh round's commit; every
  round before the eleventh ran without the split decay, ``set:split_decay=0``, and
  every round before the twelfth with ``detection_gain=3``, and every round before the
  thirteenth with ``rate_prior=1``, and every round before the seventeenth with the
  detection evidence's window at 150 samples, ``evwin-150``, and every round before the
  nineteenth with the evidence from the 150th sample with contact and no early raise,
  ``evstart-150``, and every round before the twentieth with the pre-shape's threshold
  absolute only, ``set:detection_relative=0``; the ``evstart``, ``evearly``, ``evramp``,
  ``evwin``, ``evhand`` and ``evsoft`` variants set it so themselves, as they were screened;
  and every round before the twenty-first with a memory decay that did not slow with the
  sides remembered, ``set:memory_decay_sides=0``; the variants that replace the memory
  trace's step (``memcomp``, ``consol``, ``memblur``, ``evhold``, ``gated-decay``,
  ``write``, ``decayn``) set it so themselves);
* ``decayn-K``: the memory decays at min(1, K / n) of its rate, n the sides it holds
  (recounted every 10th update): the screening form of ``memory_decay_sides`` (docs/dnf_rounds.md,
  "Twenty-first round"; ``decayn-6`` is the defaults since);
* ``decaynmed-K-M``: as ``decayn-K``, n the median of the last M counts, so that a stray
  side slows the decay only once it has lasted (docs/dnf_rounds.md, "Twenty-second round": not
  kept);
* ``spread-tuning``: where the estimated spread ``s`` exceeds ``noise_ref``, the filter
  bank's tuning widens to ``sqrt(w^2 + s^2 - noise_ref^2)`` instead of the input gain
  rising (``spread-tuning+gain``: both). Either restores the expected bump's height; the
  wider tuning also smooths a sample's few scattered normals into one bump
  (``spread-tuning/VARIANT``: on top of another variant);
* ``spreadall-Q[-tune][/VARIANT]``: the spread normalisation fed by every contact's spread
  from the first sample (not only those on remembered sides), read at the window's
  quantile Q; ``-tune``: the tuning widens as in ``spread-tuning`` instead of the gain
  rising (docs/dnf_rounds.md, "Eighth round");
* ``strokewin-T``: the evidence window (``input_window`` = T samples) restarted at every
  regrasp (a sample whose odometry did not move), so that one stroke's codes are averaged;
* ``correxp-E``: the spread normalisation lowers the correction gain by
  ``(noise_ref / s)^E`` instead of its square (E = 2 is the defaults);
* ``set:NAME=VALUE[,NAME=VALUE]``: the tracker with those parameters (numbers), for
  probes of one parameter at a time;
* ``gated-decay-W-M``: the memory decays only where this sample's normals land (a von
  Mises bump of width W deg, capped at 1), at M times the default rate: forgetting on
  evidence against a side, not on time, so that a side the surface field misses on a
  visit is not lost between its writes;
* ``map-tau-T``: the map field's time constant T samples (default 5), so that a stroke's
  few detections write sooner;
* ``memcomp-R-LO-HI[-f|-w]``: a remembered side weaker than the strongest one LO-HI deg
  away decays at R a sample more (its sites within LO deg of its top compare that top);
  ``-f``: only where the map field is silent (the shipped ``split_decay``, since the
  eleventh round; these variants replace it); ``-w``: instead every
  site not written with a remembered side (above 0.4) LO-HI deg away, both halves of a
  split alike (docs/dnf_rounds.md, "Eleventh round");
* ``evidence-[MODE-]T-K-TH``: a leaky histogram of the sample codes in the object frame
  (time constant T samples, samples with contact only) and its contrast (the histogram
  over its mean, less its blur by 15 deg); K times the contrast's excess over TH
  pre-shapes the map field, so that a side seen in many short visits is written on the
  next one. MODE: none (everywhere), ``gated`` (withheld where the hand field is active,
  as the match drive is), ``gw`` (and near a remembered side), ``gwh`` (``gw``, less the
  contrast of the same histogram in the hand's frame at the same place: a contact that
  holds still against the hand is not a side), ``gws`` (``gw``, only where the object
  frame's contrast exceeds the hand frame's), ``gwhr`` (``gwh``, and the histogram moved
  with the read-out's share of each step's correction, in whole sites);
* ``detect-T-K-TH[-h][-g]``: as ``evidence-gw-T-K-TH``, but the histogram holds the surface
  field's detections (its output in the object frame), which a corner's broad spread of
  normals seldom makes; ``-h``: less the same histogram in the hand's frame; ``-g``: not
  withheld near remembered sides (gated by the hand field only); ``-r``: none at all while
  the detections' hand-frame histogram is the more concentrated (its fullest tenth of
  sites holding more of its mass than the object frame's does, by a ratio below 0.45 -
  0.7), as a round object's is, and ramped in over the first T samples with contact;
* ``evmatch-K-TH``: K times the detection histogram's contrast in excess of TH (the
  shipped histogram, object frame) is added to the match field's input from the tenth
  sample with contact on, so that the read-out can pair detections with sides seen often
  before any is remembered (docs/dnf_rounds.md, "Thirteenth round");
* ``edgedrop-K``: a contact whose normals spread more than K times the estimated noise
  (as an edge's do under the curved pad) is left out of its sample (docs/dnf_rounds.md,
  "Thirteenth round");
* ``evhold-K``: the memory decays less where the detection evidence supports a side, by
  1 - min(K x the contrast's excess, 1) (the excess that pre-shapes the map field), so
  that a side not landed on flat for a turn is held (docs/dnf_rounds.md, "Fourteenth round");
* ``slope-L``: the rate is the slope of the total correction against the odometry, with
  an intercept, over the read-outs so far (each weighing as the odometry turned since the
  one before), pulled to ``rate_prior_mean`` with weight L rad^3: a frame offset left by
  the first turn's drift no longer biases the rate (docs/dnf_rounds.md, "Fourteenth round");
* ``trend-Q-L``: the rate from a local linear trend, c = b + r D, by a Kalman filter whose
  offset b walks by Q deg^2 per rad of odometry (slips and the first turn's frame offset)
  and whose rate does not (prior as ``slope-L``; Q = 0 is ``slope-L``) (docs/dnf_rounds.md,
  "Fifteenth round");
* ``trendg-Q-L``: ``trend-Q-L`` whose offset moves only at a regrasp (a sample whose
  odometry did not move since the one before), by Q deg^2 each (docs/dnf_rounds.md, "Sixteenth
  round");
* ``offset-T-L``: ``slope-L`` over the first T turns, then the frame offset b it found is
  kept and the rate is the shipped mean rate of c - b (docs/dnf_rounds.md, "Fifteenth round");
* ``evstart-N``: the detection evidence (pre-shape and mute) starts after N samples with
  contact, without the early gate's raise (docs/dnf_rounds.md, "Fourteenth round", when the start
  was the window's length: those figures are ``evwin-150-N``'s now; ``evstart-150`` is the
  tracker of the seventeenth and eighteenth rounds);
* ``evearly-N-R[-S]``: the evidence starts after N samples with contact, and its gate's
  ratios are raised by R there, the raise falling linearly to 0 at S samples (default
  150); ``evearly-60-0.3`` is the defaults since the nineteenth round (docs/dnf_rounds.md,
  "Nineteenth round");
* ``evwin-W[-N][+NAME=VALUE[,NAME=VALUE]]``: the detection histograms' window W samples
  with contact, the evidence starting after N (default 150) without the early gate's
  raise, with other tracker parameters as given; ``evwin-150`` is the tracker before the
  seventeenth round and ``evwin-300`` the one before the nineteenth (docs/dnf_rounds.md,
  "Seventeenth round");
* ``evhand-X``: the hand frame's detection contrast subtracted from the object frame's at
  X times its weight, on the tracker of the eighteenth round (``evhand-1`` is
  ``evstart-150``; ``evhand-0``: not at all, the
  concentration ratio's gate and the mute alone keeping a round object out)
  (docs/dnf_rounds.md, "Nineteenth round");
* ``evsoft-M``: on the same tracker, the detection histograms fed the surface field's
  output as if its threshold were M lower, ``sigmoid(beta (u + M))``, so that a side whose scattered
  normals bring the field near threshold on a visit adds evidence without a peak
  (docs/dnf_rounds.md, "Nineteenth round");
* ``consol-W0``: a site's memory decays at 1 / (1 + W / W0) of the rate, W the map field's
  output summed there over the run: sides written often last longer between their writes
  (docs/dnf_rounds.md, "Fourteenth round");
* ``memblur-S``: the memory trace is written from the map field's output blurred by S deg,
  so that a side's peak is wider and survives the count's 3 deg smoothing at a lower
  height (docs/dnf_rounds.md, "Fourteenth round");
* ``write-K-W-TH``: ``evidence-gwh-150-K-TH``, and the memory trace's input is the larger
  of the map field's output and W times the contrast's excess over TH (where the hand
  field is quiet): the evidence writes the memory directly (``peakwrite-K-W-TH``: only a
  3 deg bump at each of the excess's local maxima; ``peakwriter-K-W-TH``: the same on
  ``gwhr``).

``--ideal CELL OBJECT`` asks whether the data hold the sides at all: at the true rotation,
the local maxima of a 5 deg density of the object-frame normals (above 0.4 of its peak) of
the whole run, its second half and its last 150 samples.

``--per-set CELL OBJECT`` lists the variants' right counts data set by data set, for one
cell and object (the seventeenth round's table).

``--why CELL OBJECT`` runs the defaults (or the variants given) with the true rotation as odometry (the tracking
taken out, as ``study_dnf_probes.py``'s probe) and splits the wrong second-half samples
into a side missing, a side split in two, a stray peak, or a mix; for one data set
(``--set``) it lists each side's visits (samples with a normal within 8 deg of it) and
the memory's strength there every 20 samples. The figures are in docs/dnf_rounds.md ("Sixth
round" and "Seventh round").

    cd benchmarks
    ../.venv/bin/python study_dnf_variants.py defaults spread-tuning gated-decay-10-3 map-tau-4 --sets 0-7
    ../.venv/bin/python study_dnf_variants.py --why noise=6 8-gon --set 7
    ../.venv/bin/python study_dnf_variants.py defaults set:tuning_width=0.14 --why noise=6 8-gon --sets 8-15
    ../.venv/bin/python study_dnf_variants.py defaults evidence-gwh-150-3-0.4 --sets 8-15
    ../.venv/bin/python study_dnf_variants.py --peaks noise=6 8-gon 6-gon round --sets 0-3
    ../.venv/bin/python study_dnf_variants.py defaults evwin-150 --per-set noise=6 8-gon --sets 0-15
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


def _line_fit(sums, w, D, c, L, m0):
    """Add the read-out (odometry turned D, total correction c) with weight w to ``sums`` (w,
    wD, wc, wD^2, wDc; updated in place) and return the weighted line c = b + r D through
    them all, its slope pulled to m0 with weight L: (r, b)."""
    sums += w * np.array([1.0, D, c, D * D, D * c])
    sw, sD, sc, sDD, sDc = sums
    r = (sDc - sD * sc / sw + L * m0) / (sDD - sD * sD / sw + L)
    return r, (sc - r * sD) / sw


def factory(variant: str):
    """A zero-argument callable that makes the variant's tracker."""
    from touchloc.dnf import OrientationTracker, TrackerParams
    from touchloc.dnf.tracker import population_code

    if variant == "defaults":
        return OrientationTracker
    if variant.startswith("spread-tuning"):
        keep_gain = variant.split("/")[0].endswith("+gain")
        # spread-tuning/VARIANT: the same on top of another variant (an evidence-* one)
        Base = _inner_tracker(variant, "spread-tuning/VARIANT")

        class SpreadTuning(Base):
            def _observe_spread(self, sp, mu):
                self.params = self._base
                super()._observe_spread(sp, mu)
                s, ref = self._noise, self._base.noise_ref
                if s > ref:
                    if not keep_gain:
                        self._gain_scale = 1.0
                    self.params = _widened(self._base, s)

        return _keeping_params(SpreadTuning)
    if variant.startswith("strokewin-"):
        # strokewin-T: the evidence window (input_window = T samples) restarts at every
        # regrasp (a sample whose odometry did not move since the one before), so that a
        # stroke's codes are averaged and the previous stroke's are not carried over
        T = float(variant.split("-", 1)[1])

        class StrokeWin(OrientationTracker):
            def __init__(self):
                super().__init__(input_window=T)

            def _step(self, a):
                if self._last_odo is not None and self.odometry == self._last_odo:
                    self._evidence[:] = 0.0
                    self._weight = 0.0
                super()._step(a)

        return StrokeWin
    if variant.startswith("correxp-"):
        # correxp-E: the spread normalisation lowers the correction gain by (noise_ref / s)^E
        # instead of the inverse-variance weight's square (E = 2, the defaults)
        E = float(variant.split("-", 1)[1])

        class CorrExp(OrientationTracker):
            def _observe_spread(self, sp, mu):
                super()._observe_spread(sp, mu)
                if self._noise > self.params.noise_ref:
                    self._correction_scale = min(1.0, (self.params.noise_ref / self._noise) ** E)

        return CorrExp
    if variant.startswith("spreadall-"):
        # spreadall-Q[-tune]: the spread normalisation fed by every contact from the first
        # sample (not only those on remembered sides), read at the window's quantile Q;
        # with -tune, the filter bank's tuning widens instead of the gain rising
        from collections import deque

        parts = variant.split("/")[0].split("-")[1:]
        q, tune = float(parts[0]), "tune" in parts
        Base = _inner_tracker(variant, "spreadall-Q/VARIANT")

        class SpreadAll(Base):
            def _observe_spread(self, sp, mu):
                p = self._base
                if not hasattr(self, "_every"):
                    self._every = deque(maxlen=int(round(p.noise_window)))
                self._every.extend(sp)
                n = len(self._every)
                if n == 0 or n < p.noise_min:
                    return
                s = max(float(np.sort(self._every)[min(n - 1, int(q * n))]), 1e-3 * p.noise_ref)
                w, ref = p.tuning_width, p.noise_ref
                self._noise = s
                self._correction_scale = min(1.0, (ref / s) ** 2)
                if tune:
                    self._gain_scale = 1.0
                    self.params = p if s <= ref else _widened(p, s)
                else:
                    self._gain_scale = max(1.0, float(np.sqrt((w * w + s * s) / (w * w + ref * ref))))

        return _keeping_params(SpreadAll)
    if variant.startswith("memcomp-"):
        # memcomp-R-LO-HI: a remembered side (its sites within LO deg of its top) weaker
        # than the strongest one remembered LO-HI deg away decays at R a sample more (a
        # split or a stray beside a side)
        # (``-w``: instead every site not written this sample with a remembered side, above
        # the read-out's 0.4, LO-HI deg away: both halves of a split fade unless refreshed)
        rate, lo, hi = (float(x) for x in variant.split("-")[1:4])
        both = variant.endswith("-w")
        unwritten = variant.endswith("-f")   # -f: the weaker side only while not written
        from scipy.ndimage import maximum_filter1d

        class MemComp(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                # the screening form of the shipped split decay: in its place
                self.params = dataclasses.replace(self.params, split_decay=0.0)
                n = self.n_sites
                a, b = int(round(lo * n / 360)), int(round(hi * n / 360))
                size = b - a + 1
                trace, trace_step = self.trace, self.trace.step

                def step(f):
                    P = trace_step(f)
                    m = maximum_filter1d(P, size, mode="wrap", origin=-(size // 2))   # max over [i, i+size)
                    near = np.maximum(np.roll(m, -a), np.roll(m, b))   # over [i+a, i+b] and [i-b, i-a]
                    if both:
                        P -= rate * P * (1.0 - f) * (near > 0.4)
                        return P
                    local = maximum_filter1d(P, 2 * a - 1, mode="wrap")         # the bump's own top
                    P -= rate * P * (near > local) * ((1.0 - f) if unwritten else 1.0)
                    return P
                trace.step = step
        return MemComp
    if variant.startswith("evstart-"):
        # evstart-N: the detection evidence (pre-shape and mute) starts after N samples with
        # contact (the histograms' window is unchanged; the fourteenth round's figures are
        # evwin-150-N's, from when the start was the window's length)
        start = float(variant.split("-")[1])
        return lambda: OrientationTracker(detection_start=start, detection_early_raise=0.0, detection_relative=0.0)
    if variant.startswith("evearly-"):
        # evearly-N-R[-S]: the detection evidence starts after N samples with contact, its
        # gate (detection_hold_low/high) raised by R at the start, the raise falling
        # linearly to 0 at S samples (default 150): an early ratio, from few detections, must
        # be the clearer (the shipped defaults since the nineteenth round: evearly-60-0.3)
        parts = variant.split("-")[1:]
        start, R = float(parts[0]), float(parts[1])
        settle = float(parts[2]) if len(parts) > 2 else 150.0
        return lambda: OrientationTracker(detection_start=start, detection_early_raise=R, detection_settle=settle,
                                          detection_relative=0.0)
    if variant.startswith("evramp-"):
        # evramp-N-R-G-T: evearly-N-R whose pre-shape's gain rises linearly from G times its
        # value at the start to its value at 150 samples, and whose contrast threshold is
        # raised by T at the start, the raise falling linearly to 0 at 150 samples: an early
        # histogram holds few detections, so a corner's few look like a side
        start, R, G, T = (float(x) for x in variant.split("-")[1:5])

        class EvRamp(OrientationTracker):
            def __init__(self):
                super().__init__(detection_start=start, detection_early_raise=R, detection_relative=0.0)
                self._base = self.params

            def _detection_evidence(self, f_s, f_hand, shift):
                b = self._base
                n = self._detection_samples + 1
                f = min(max((b.detection_settle - n) / max(b.detection_settle - start, 1.0), 0.0), 1.0)
                self.params = dataclasses.replace(b, detection_gain=b.detection_gain * (1.0 - f * (1.0 - G)),
                                                  detection_threshold=b.detection_threshold + T * f)
                try:
                    return super()._detection_evidence(f_s, f_hand, shift)
                finally:
                    self.params = b
        return EvRamp
    if variant.startswith("evhand-"):
        # evhand-X: the hand frame's detection contrast is subtracted from the object
        # frame's at X times its weight (1: the defaults; 0: not at all, the concentration
        # ratio's gate and mute alone keeping a round object out)
        X = float(variant.split("-")[1])
        from touchloc.dnf.tracker import _concentration, _roll

        class EvHand(OrientationTracker):
            # on the tracker it was screened on (the evidence from the 150th sample, no early
            # raise): its gate below is the plain one
            def __init__(self):
                super().__init__(detection_start=150.0, detection_early_raise=0.0, detection_relative=0.0)

            def _detection_evidence(self, f_s, f_hand, shift):
                p = self.params
                pre, mute = super()._detection_evidence(f_s, f_hand, shift)
                if pre is None:
                    return pre, mute
                ratio = (_concentration(self._detections_total)
                         / max(_concentration(self._detections_hand_total), 1e-300))
                scale = (ratio - p.detection_hold_low) / (p.detection_hold_high - p.detection_hold_low)
                obj, hand = self._contrast(np.stack((self._detections, self._detections_hand)))
                d = obj - X * np.maximum(_roll(hand, -shift), 0.0)
                return (p.detection_gain * min(scale, 1.0)) * np.clip(d - p.detection_threshold, 0.0, None), mute
        return EvHand
    if variant.startswith("evsoft-"):
        # evsoft-M: the detection histograms hold the surface field's output as if its
        # threshold were M lower (sigmoid(beta (u + M))): a side whose scattered normals
        # bring the field near threshold on a visit, without a peak, still adds evidence
        M = float(variant.split("-")[1])
        from touchloc.dnf.fields import sigmoid
        from touchloc.dnf.tracker import _roll

        class EvSoft(OrientationTracker):
            def __init__(self):   # the tracker it was screened on, as evhand-X
                super().__init__(detection_start=150.0, detection_early_raise=0.0, detection_relative=0.0)

            def _detection_evidence(self, f_s, f_hand, shift):
                soft = sigmoid(self.surface.u + M, self.params.surface.beta)
                return super()._detection_evidence(soft, _roll(soft, shift), shift)
        return EvSoft
    if variant.startswith("evwin-"):
        # evwin-W[-N]: the detection histograms' window W samples with contact, the
        # evidence starting after N (default 150, the start of the seventeenth and
        # eighteenth rounds) without the early gate's raise, so that a side landed on flat
        # once a turn keeps its evidence
        # (+NAME=VALUE[,NAME=VALUE]: other tracker parameters as well)
        head, _, extra = variant.partition("+")
        try:
            kw = {k: float(v) for k, v in (item.split("=") for item in extra.split(",") if item)}
            parts = head.split("-")[1:]
            window = float(parts[0])
            start = float(parts[1]) if len(parts) > 1 else 150.0
            kw = {"detection_early_raise": 0.0, "detection_relative": 0.0, **kw}
            OrientationTracker(detection_window=window, detection_start=start, **kw)
        except Exception as e:
            raise SystemExit(f"evwin-W[-N][+NAME=VALUE[,NAME=VALUE]], got {variant!r}: {e}") from None

        class EvWin(OrientationTracker):
            def __init__(self):
                super().__init__(detection_window=window, detection_start=start, **kw)
        return EvWin
    if variant.startswith("consol-"):
        # consol-W0: a site's memory decays at 1 / (1 + W / W0) of the rate, W the map
        # field's output summed there over the run (samples written): sides written often
        # are kept longer between their writes
        W0 = float(variant.split("-")[1])

        class Consol(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                self._W = np.zeros(self.n_sites)
                trace, W = self.trace, self._W

                def step(f):
                    np.add(W, f, out=W)
                    return type(trace).step(trace, f, decay_scale=1.0 / (1.0 + W / W0))
                trace.step = step
        return Consol
    if variant.startswith(("decayn-", "decaynmed-")):
        # decayn-K: the memory decays at min(1, K / n) of its rate, n the sides it holds
        # (count_surfaces of the trace, every 10th sample): a side of an n-gon is visited
        # about every n-th stroke, so the time it must be held grows with n.
        # decaynmed-K-M: n the median of the last M counts, so that a stray side counts
        # only once it has lasted M / 2 counts (decayn-K is decaynmed-K-1)
        parts = variant.split("-")[1:]
        K, M = float(parts[0]), int(parts[1]) if variant.startswith("decaynmed-") else 1
        from touchloc.dnf import count_surfaces

        class DecayN(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                trace, state = self.trace, {"t": 0, "scale": 1.0, "seen": []}

                def step(f):
                    if state["t"] % 10 == 0:
                        state["seen"] = (state["seen"] + [count_surfaces(trace.P)])[-M:]
                        state["scale"] = min(1.0, K / max(float(np.median(state["seen"])), 1.0))
                    state["t"] += 1
                    return type(trace).step(trace, f, decay_scale=state["scale"])
                trace.step = step
        return DecayN
    if variant.startswith("slope-"):
        # slope-L: the rate is the slope of the total correction against the odometry, with
        # an intercept, over the read-outs so far, each weighing as the odometry turned since
        # the one before; the prior pulls the slope to rate_prior_mean with weight L (rad^3)
        L = float(variant.split("-")[1])

        class Slope(OrientationTracker):
            def __init__(self):
                super().__init__()
                self._sums = np.zeros(5)   # sum w, w D, w c, w D^2, w D c
                self._last_D = 0.0

            def _step(self, a):
                super()._step(a)
                if self.last_error != 0.0 and self._first_odo is not None:
                    D, c = self.odometry - self._first_odo, self.correction
                    w = max(abs(D - self._last_D), 1e-3)
                    self._last_D = D
                    r, _ = _line_fit(self._sums, w, D, c, L, self.params.rate_prior_mean)
                    self._rate = min(max(r, -0.5), 0.5)
        return Slope
    if variant.startswith(("trend-", "trendg-")):
        # trend-Q-L: the rate from a local linear trend of the total correction against the
        # odometry, c = b + r D, by a Kalman filter: the offset b walks (variance Q deg^2 per
        # rad of odometry turned: slips, and the first turn's frame offset, move it) and the
        # rate r does not; r's prior is rate_prior_mean with the weight L of slope-L (Q = 0 is
        # slope-L; a read-out weighs as the odometry turned since the one before).
        # trendg-Q-L: the offset moves only at a regrasp (a sample whose odometry did not
        # move since the one before: the hand let go and took hold again), by Q deg^2 each;
        # between regrasps all drift goes into the rate
        Q, L = (float(x) for x in variant.split("-")[1:3])
        at_regrasp = variant.startswith("trendg-")
        s2 = np.radians(3.0) ** 2 * 0.5   # a read-out 0.5 rad after the last: 3 deg

        class Trend(OrientationTracker):
            def __init__(self):
                super().__init__()
                self._x = np.array([0.0, self.params.rate_prior_mean])
                self._P = np.diag([np.radians(90.0) ** 2, s2 / L])
                self._last_D = 0.0
                self._regrasps = 0

            def _step(self, a):
                prev = self._last_odo
                super()._step(a)
                self._regrasps += prev is not None and self.odometry == prev
                if self.last_error != 0.0 and self._first_odo is not None:
                    D, c = self.odometry - self._first_odo, self.correction
                    dD = abs(D - self._last_D)
                    self._last_D = D
                    P = self._P
                    P[0, 0] += np.radians(1.0) ** 2 * Q * (self._regrasps if at_regrasp else dD)
                    self._regrasps = 0
                    H = np.array([1.0, D])
                    S = H @ P @ H + s2 / max(dD, 1e-3)
                    K = P @ H / S
                    self._x = self._x + K * (c - H @ self._x)
                    self._P = P - np.outer(K, H @ P)
                    self._rate = min(max(float(self._x[1]), -0.5), 0.5)
        return Trend
    if variant.startswith("offset-"):
        # offset-T-L: the first T turns of odometry fit the correction as c = b + r D (the
        # slope-L fit, b the frame offset that the first turn's drift leaves in the map);
        # then b is kept and the rate is the shipped mean rate of c - b, whose slips weigh
        # as they do in the mean (s / D), not as a line's leverage makes them
        T, L = (float(x) for x in variant.split("-")[1:3])

        class Offset(OrientationTracker):
            def __init__(self):
                super().__init__()
                self._sums = np.zeros(5)
                self._last_D = 0.0
                self._b = None

            def _step(self, a):
                super()._step(a)
                if self.last_error != 0.0 and self._first_odo is not None:
                    p = self.params
                    D, c = self.odometry - self._first_odo, self.correction
                    m0 = p.rate_prior_mean
                    if self._b is None:
                        w = max(abs(D - self._last_D), 1e-3)
                        self._last_D = D
                        r, b = _line_fit(self._sums, w, D, c, L, m0)
                        self._rate = min(max(r, -0.5), 0.5)
                        if D >= T * 2 * np.pi:
                            self._b = b
                    else:
                        self._rate = min(max(((c - self._b) * D + m0 * p.rate_prior ** 2)
                                             / (D * D + p.rate_prior ** 2), -0.5), 0.5)
        return Offset
    if variant.startswith("memblur-"):
        # memblur-S: the memory trace is written from the map field's output blurred by a
        # Gaussian of S deg (unit peak kept where the output is a plateau wider than it)
        S = float(variant.split("-")[1])
        from touchloc.dnf.fields import circular_convolve, periodic_distance

        class MemBlur(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                g = np.exp(-0.5 * (periodic_distance(self.n_sites) / np.radians(S)) ** 2)
                k = np.fft.rfft(g / g.sum())
                trace_step = self.trace.step
                n = self.n_sites
                self.trace.step = lambda f: trace_step(np.clip(circular_convolve(f, k, n), 0.0, 1.0))
        return MemBlur
    if variant.startswith("evhold-"):
        # evhold-K: the memory decays less where the detection evidence supports a side: by
        # 1 - min(K x the contrast's excess, 1), the excess that pre-shapes the map field
        K = float(variant.split("-")[1])

        class EvHold(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                self._hold = np.zeros(self.n_sites)
                trace, hold = self.trace, self._hold

                trace.step = lambda f: type(trace).step(trace, f, decay_scale=1.0 - hold)

            def _detection_evidence(self, f_s, f_hand, shift):
                pre, mute = super()._detection_evidence(f_s, f_hand, shift)
                if pre is None:
                    self._hold[:] = 0.0
                else:
                    np.minimum(pre * (K / self.params.detection_gain), 1.0, out=self._hold)
                return pre, mute
        return EvHold
    if variant.startswith("gated-decay-"):
        width, mult = (float(x) for x in variant.split("-")[2:4])

        class GatedDecay(OrientationTracker):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                self._gate = np.zeros(self.n_sites)
                trace, gate = self.trace, self._gate

                trace.step = lambda f: type(trace).step(trace, f, decay_scale=mult * gate)

            def _step(self, a):
                if a.size:
                    code = population_code(a - self.orientation, self.n_sites, np.radians(width), 1.0)
                    np.minimum(code, 1.0, out=self._gate)
                super()._step(a)
        return GatedDecay
    if variant.startswith(("write-", "peakwrite-", "peakwriter-")):
        # write-K-W-TH: the gwh evidence (T 150, pre-shape K) also writes the memory
        # directly: the trace's input is max(map output, W x the contrast's excess over TH),
        # where the hand field is not active
        K, W, TH = (float(x) for x in variant.split("-")[1:])
        peaks_only = variant.startswith("peakwrite")
        base = _evidence("gwhr" if variant.startswith("peakwriter-") else "gwh", 150.0, K, TH)
        from touchloc.dnf.fields import circular_convolve, periodic_distance

        class Write(base):
            def __init__(self):
                super().__init__()
                # screened on a trace whose decay did not slow with its sides, and it
                # replaces the trace's step
                self.params = dataclasses.replace(self.params, memory_decay_sides=0.0)
                trace_step = self.trace.step
                self.trace.step = lambda f: trace_step(np.maximum(f, self._written()))
                n = self.n_sites
                g = np.exp(-0.5 * (periodic_distance(n) / np.radians(3.0)) ** 2)
                self._bump = np.fft.rfft(g / g.max())

            def _written(self):
                e = np.clip(W * np.clip(self._d - TH, 0.0, None) * self._hand_gate(), 0.0, 1.0)
                if not peaks_only:
                    return e
                # a 3 deg bump at each local maximum, as high as the excess there
                top = (e > 0) & (e > np.roll(e, 1)) & (e >= np.roll(e, -1))
                return np.clip(circular_convolve(np.where(top, e, 0.0), self._bump, self.n_sites), 0.0, 1.0)
        return Write
    if variant.startswith("detect-"):
        # detect-T-K-TH[-h][-g]: as evidence-gw, but the histogram holds the surface field's
        # detections (its output), not the sample codes; -h: less the same in the hand
        # frame; -g: gated by the hand field only, not withheld near remembered sides
        parts = variant.split("-")[1:]
        T, K, TH = (float(x) for x in parts[:3])
        return _detections(T, K, TH, hand="h" in parts[3:], near_sides="g" not in parts[3:],
                           held="r" in parts[3:])
    if variant.startswith("evidence-"):
        # evidence-[MODE-]T-K-TH: see the module's docstring
        parts = variant.split("-")[1:]
        mode = parts.pop(0) if parts[0] in ("gated", "gw", "gwh", "gws", "gwhr") else "plain"
        T, K, TH = (float(x) for x in parts)
        return _evidence(mode, T, K, TH)
    if variant.startswith("set:"):
        # set:NAME=VALUE[,NAME=VALUE]: the tracker with those parameters (numbers)
        try:
            kw = {k: float(v) for k, v in (item.split("=") for item in variant[4:].split(","))}
            OrientationTracker(**kw)
        except Exception as e:
            raise SystemExit(f"set:NAME=VALUE[,NAME=VALUE] with tracker parameters, got {variant!r}: {e}") from None
        return lambda: OrientationTracker(**kw)
    if variant.startswith("map-tau-"):
        tau = float(variant.split("-")[2])
        default = TrackerParams().map
        return lambda: OrientationTracker(map=dataclasses.replace(default, tau=tau))
    if variant.startswith("evmatch-"):
        # the detection histogram's contrast also pre-shapes the match field, so that the
        # read-out pairs detections with sides seen often before any is remembered
        k, th = (float(x) for x in variant.split("-")[1:3])

        class EvMatch(OrientationTracker):
            def __init__(self):
                super().__init__()
                step = self.match.step

                def match_step(u, **kw):
                    if self._detection_samples >= 10:
                        u = u + k * np.clip(self._contrast(self._detections) - th, 0.0, None)
                    return step(u, **kw)

                self.match.step = match_step

        return EvMatch
    if variant.startswith("edgedrop-"):
        # a contact whose normals spread more than K times the estimated noise (an edge
        # under a curved pad) is left out of the sample
        kk = float(variant.split("-")[1])
        from touchloc.dnf.tracker import _contacts

        class EdgeDrop(OrientationTracker):
            def _step(self, a):
                if a.size >= 2:
                    s_ = np.sort(np.mod(a, 2 * np.pi))
                    sp, mu, _ = _contacts(a, self.params.contact_gap)
                    lim = kk * max(self._noise, self.params.noise_ref)
                    for v, m in zip(sp, mu):
                        if v > lim:
                            d = np.abs((s_ - m + np.pi) % (2 * np.pi) - np.pi)
                            s_ = s_[d > 2.5 * v]
                    a = s_
                super()._step(a)

        return EdgeDrop
    raise SystemExit(f"unknown variant {variant!r}")


def _widened(p, s: float):
    """Tracker parameters ``p`` with the filter bank's tuning widened for a spread ``s``
    above ``noise_ref``: ``sqrt(w^2 + s^2 - noise_ref^2)``."""
    w, ref = p.tuning_width, p.noise_ref
    return dataclasses.replace(p, tuning_width=float(np.sqrt(w * w + s * s - ref * ref)))


def _keeping_params(cls):
    """A maker of ``cls`` trackers that keep their own parameters as ``_base`` (the
    variants that re-tune ``params`` as they go)."""
    def make():
        t = cls()
        t._base = t.params
        return t
    return make


def _inner_tracker(variant: str, form: str):
    """The tracker class a ``NAME/VARIANT`` variant builds on (the plain tracker without
    ``/VARIANT``)."""
    from touchloc.dnf import OrientationTracker

    inner = variant.split("/", 1)[1] if "/" in variant else None
    Base = OrientationTracker if inner is None else factory(inner)
    if not isinstance(Base, type):
        raise SystemExit(f"{form} needs a variant that is a tracker class "
                         f"(evidence-*, write-*, gated-decay-*), got {inner!r}")
    return Base


def _detections(T: float, K: float, TH: float, hand: bool, near_sides: bool = True, held: bool = False):
    """The tracker with a leaky histogram of its surface field's detections pre-shaping
    its map field (``detect-*``), gated as ``evidence-gw`` (``near_sides`` False: as
    ``evidence-gated``)."""
    from touchloc.dnf.fields import TWO_PI
    from touchloc.dnf.tracker import _concentration

    base = _evidence("gw" if near_sides else "gated", T, 0.0, TH)

    class Detections(base):
        def __init__(self):
            super().__init__()
            self._det = np.zeros(self.n_sites)
            self._det_hand = np.zeros(self.n_sites)
            step = self.surface.step

            def surface_step(stim, **kw):
                f = step(stim, **kw)
                n = self.n_sites
                self._det += (f - self._det) / T
                d = self._contrast(self._det)
                shift = int(round(self.orientation * n / TWO_PI)) % n
                self._det_hand += (np.roll(f, shift) - self._det_hand) / T
                if hand:
                    d = d - np.maximum(np.roll(self._contrast(self._det_hand), -shift), 0.0)
                self._d = d
                self._pre = K * np.clip(d - TH, 0.0, None)
                if held:
                    # an object whose detections hold still against the hand (a round one)
                    # gets no pre-shape: its hand-frame histogram is the more concentrated;
                    # and none before the histograms hold T samples' worth
                    self._seen = getattr(self, "_seen", 0) + 1
                    r = _concentration(self._det) / max(_concentration(self._det_hand), 1e-300)
                    self._pre *= float(np.clip((r - 0.45) / 0.25, 0.0, 1.0)) * min(1.0, self._seen / T)
                return f
            self.surface.step = surface_step
    return Detections


def _evidence(mode: str, T: float, K: float, TH: float, blur: float = 15.0):
    """The tracker with evidence histograms pre-shaping its map field (``evidence-*``)."""
    from touchloc.dnf import OrientationTracker
    from touchloc.dnf.fields import TWO_PI, circular_convolve, periodic_distance, sigmoid
    from touchloc.dnf.tracker import population_code

    realign = mode.endswith("r")
    mode = mode[:-1] if realign else mode
    gated = mode != "plain"
    withheld = mode in ("gw", "gwh", "gws")

    class Evidence(OrientationTracker):
        def __init__(self):
            super().__init__()
            # on the tracker as the seventh to ninth rounds screened it: without the detection
            # evidence and the mute it has shipped since (``detect-*`` is its screening form),
            # and with the rate prior of its time
            self.params = dataclasses.replace(self.params, detection_gain=0.0, detection_mute_high=0.0,
                                              split_decay=0.0, rate_prior=1.0)
            n = self.n_sites
            g = np.exp(-0.5 * (periodic_distance(n) / np.radians(blur)) ** 2)
            self._blur = np.fft.rfft(g / g.sum())    # a mean: the contrast's background
            self._near = np.fft.rfft(g / g.max())    # a reach: near a remembered side
            self._hist = np.zeros(n)                 # object frame
            self._hist_hand = np.zeros(n)            # hand (world) frame
            self._pre = np.zeros(n)
            self._d = np.zeros(n)                    # the contrast the pre-shape is made of
            self._shift = 0.0
            step = self.map.step
            self.map.step = lambda drive, **kw: step(drive + self._pre * self._gate(), **kw)

        def _contrast(self, h):
            c = h / max(float(h.mean()), 1e-300)
            return c - circular_convolve(c, self._blur, self.n_sites)

        def _hand_gate(self):
            """0 where the hand field is active (blurred, as the match drive's gate), else 1."""
            p, n = self.params, self.n_sites
            shift = int(round(self.orientation * n / TWO_PI)) % n
            g_h = np.roll(sigmoid(self.hand.u + p.hand_gate_margin, p.hand.beta), -shift)
            return 1.0 - np.clip(circular_convolve(g_h, self._match_blur_fft, n), 0.0, 1.0)

        def _gate(self):
            """Where the pre-shape may drive the map field: not where the hand field is
            active, and with ``gw*`` not near a remembered side."""
            if not gated:
                return 1.0
            gate = self._hand_gate()
            if withheld:
                gate = gate * (1.0 - np.clip(circular_convolve(self.trace.P, self._near, self.n_sites), 0.0, 1.0))
            return gate

        def _step(self, a):
            if a.size:
                n, w = self.n_sites, self.params.tuning_width
                # the orientation the filter bank is about to use for this sample
                o = self.odometry + self.correction
                if self._last_odo is not None:
                    o += self._rate * (self.odometry - self._last_odo)
                self._hist += (population_code(a - o, n, w, 1.0, normalize=True) - self._hist) / T
                d = self._contrast(self._hist)
                if mode in ("gwh", "gws"):
                    self._hist_hand += (population_code(a, n, w, 1.0, normalize=True) - self._hist_hand) / T
                    shift = int(round(o * n / TWO_PI)) % n
                    dw = np.roll(self._contrast(self._hist_hand), -shift)
                    if mode == "gwh":   # less the hand frame's contrast there
                        d = d - np.maximum(dw, 0.0)
                    else:               # only where the object frame's is the sharper
                        d = np.where(d > dw, d, -np.inf)
                self._d = d
                self._pre = K * np.clip(d - TH, 0.0, None)
            before, rate, last = self.correction, self._rate, self._last_odo
            super()._step(a)
            if realign and last is not None:
                # the read-out's share of this step's correction re-registers the histogram:
                # earlier samples were placed with an estimate that was off by as much
                self._shift += (self.correction - before - rate * (self.odometry - last)) * self.n_sites / TWO_PI
                k = int(np.trunc(self._shift))
                if k:
                    self._hist = np.roll(self._hist, -k)
                    self._shift -= k
    return Evidence


def right_counts(make, ds) -> float:
    from touchloc.dnf.compare import run_estimator

    counts = run_estimator("dnf", make, ds).counts
    return float(np.mean(counts[len(counts) // 2:] == ds.n_surfaces))


def _one(job):
    import warnings

    warnings.simplefilter("ignore")
    variant, ci, obj, s = job
    return right_counts(factory(variant), dev_dataset(ci, obj, s))


def why(cell: str, obj: str, sets, one_set: int, variant: str = "defaults") -> None:
    """The wrong second-half samples of a variant (the defaults unless given) with the
    true rotation as odometry."""
    from touchloc.dnf import RotationDataset, surface_peaks

    make = factory(variant)

    n = dict(zip(OBJECTS, (4, 5, 6, 8, 0)))[obj]
    site = np.radians(np.arange(360))
    total = dict.fromkeys(("right", "missing", "split", "stray", "mixed"), 0)
    for s in sets:
        ds = dev_dataset(CELLS[cell][0], obj, s)
        ds = RotationDataset(ds.time, ds.true_orientation, ds.normal_angles, ds.sample_index,
                             true_orientation=ds.true_orientation, n_surfaces=ds.n_surfaces, name=ds.name)
        tracker = make()
        tracker.params = dataclasses.replace(tracker.params, rate_prior_mean=0.0)
        tracker.reset()
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
    print(f"{variant}: {cell}, {obj}, true rotation as odometry, data sets {sets[0]}-{sets[-1]}: "
          + ", ".join(f"{k} {100 * v / n_all:.0f} %" for k, v in total.items()))


def peaks(cell: str, objects, sets, T: float = 150.0, level: float = 0.3) -> None:
    """How many sides the evidence histogram holds: the defaults run (``evidence-T-0-0``
    adds nothing to their drive) with the object-frame histogram of the sample codes at
    their orientation, and beside it the same histogram at the true rotation; every 10
    samples of the second half, the count of each contrast's local maxima above ``level``."""
    from touchloc.dnf.tracker import population_code

    make = _evidence("plain", T, 0.0, 0.0)

    def count(tr, h):
        c = tr._contrast(h)
        return int(np.sum((c > level) & (c > np.roll(c, 1)) & (c >= np.roll(c, -1))))

    for obj in objects:
        for s in sets:
            ds = dev_dataset(CELLS[cell][0], obj, s)
            tr = make()
            h_true = np.zeros(tr.n_sites)
            est, true = [], []
            for k, ((a, odo), rot) in enumerate(zip(ds.samples(), ds.true_orientation)):
                a = np.asarray(a)
                if a.size:
                    code = population_code(a - rot, tr.n_sites, tr.params.tuning_width, 1.0, normalize=True)
                    h_true += (code - h_true) / T
                tr.step(a, odo)
                if k + 1 > len(ds.odometry) // 2 and (k + 1) % 10 == 0:
                    est.append(count(tr, tr._hist))
                    true.append(count(tr, h_true))
            hist = lambda x: ", ".join(f"{v}: {c}" for v, c in enumerate(np.bincount(x)) if c)  # noqa: E731
            print(f"{cell}, {obj}, data set {s}: peaks (count: read-outs) at the estimate {hist(est)}; "
                  f"at the true rotation {hist(true)}")


def ideal(cell: str, obj: str, sets, width: float = 5.0, level: float = 0.4) -> None:
    """Whether the data hold the sides: at the true rotation, a kernel density (``width``
    deg) of the object-frame normals of the whole run, of its second half and of its last
    150 samples, and the count of its local maxima above ``level`` times its peak."""
    site = np.arange(360.0)
    for s in sets:
        ds = dev_dataset(CELLS[cell][0], obj, s)
        T = len(ds.true_orientation)
        seen = [(np.degrees(np.asarray(a) - rot) % 360, k)
                for k, ((a, _), rot) in enumerate(zip(ds.samples(), ds.true_orientation)) if len(a)]
        out = []
        for label, lo in (("whole run", 0), ("second half", T // 2), ("last 150 samples", T - 150)):
            x = np.concatenate([v for v, k in seen if k >= lo])
            d = (site[:, None] - x[None, :] + 180.0) % 360.0 - 180.0
            kde = np.exp(-0.5 * (d / width) ** 2).sum(axis=1)
            top = (kde > np.roll(kde, 1)) & (kde >= np.roll(kde, -1)) & (kde > level * kde.max())
            out.append(f"{label} {int(top.sum())}")
        print(f"{cell}, {obj}, data set {s}, true rotation, maxima of a {width:g} deg density: " + ", ".join(out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["defaults"])
    ap.add_argument("--sets", default="0-7")
    ap.add_argument("--why", nargs=2, metavar=("CELL", "OBJECT"))
    ap.add_argument("--peaks", nargs="+", metavar="CELL_THEN_OBJECTS",
                    help="the evidence histogram's side counts: a cell, then objects")
    ap.add_argument("--set", type=int, default=-1, help="with --why: the data set whose sides to list")
    ap.add_argument("--ideal", nargs=2, metavar=("CELL", "OBJECT"),
                    help="the maxima of a density of all the normals at the true rotation")
    ap.add_argument("--per-set", nargs=2, metavar=("CELL", "OBJECT"),
                    help="each variant's right count on every data set of one cell and object")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    a = ap.parse_args(argv)
    sets = _sets(a.sets)
    if a.peaks:
        peaks(a.peaks[0], a.peaks[1:] or OBJECTS, sets)
        return 0
    if a.ideal:
        ideal(a.ideal[0], a.ideal[1], sets)
        return 0
    if a.why:
        for variant in a.variants:
            why(a.why[0], a.why[1], sets, a.set, variant)
        return 0
    names = {i: name for name, (i, _) in CELLS.items()}
    if a.per_set:
        cell, obj = a.per_set
        for variant in a.variants:
            factory(variant)
        jobs = [(v, CELLS[cell][0], obj, s) for v in a.variants for s in sets]
        with ProcessPoolExecutor(a.workers) as ex:
            right = iter(ex.map(_one, jobs))
            for variant in a.variants:
                r = [next(right) for _ in sets]
                print(f"{variant:>32}: mean {100 * np.mean(r):.1f} % | " + " ".join(f"{100 * x:.0f}" for x in r))
        return 0
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
