"""The orientation tracker of seed 000 (Fig. 2): mapping and tracking with neural fields.

Per sample, the contact-normal angles are moved into the object frame with the current
orientation estimate and encoded by a filter bank (population code). The input stage makes
the tracker's input independent of how many normals a sample holds (1 to 40, or none):

count normalisation (the default)
    the sample's code is the *mean* of the normals' tuning curves, not their sum. Its
    expected value is the tuning curve smoothed by the distribution of the normals, which
    does not depend on their number; a flat side gives a sharp, high bump, an edge (a
    spread of normals) a broad, low one. The surface field's own time constant (2
    samples) already integrates a few samples, which is what one or two normals per
    sample need.
evidence window (optional, ``input_window > 0``)
    as in seed 000 (section II: "the normals of a short time window are the input"), the
    codes can be averaged over the last samples with a leaky accumulator in the object
    frame. It is off by default: measured on the seed-faithful generator it carried the
    previous stroke's contacts across each regrasp, widened the memory's peaks and split
    them (0-68 % right counts on the 8-gon with windows of 4-8 samples, against 88-100 %
    without, with 1-40 normals per finger and 1-6 degrees of noise).

spread normalisation (on by default, ``noise_ref``)
    the mean code's bump is lower the more a contact's normals spread, so the tracker
    estimates that spread on the sides it remembers (:func:`contact_spreads`) and, where it
    exceeds the spread the defaults were set at, raises the input gain to restore the
    bump's expected height and lowers the correction gain (an inverse-variance weight);
    a sample with fewer normals per contact than two (``normals_ref``) is corrected by
    less, for the same reason.

A sample without contact (``K = 0``) is valid. By default (``hold_empty``) it changes no
field: the orientation follows the odometry and everything else waits for the next
contact. No contact is no evidence, and since the fields live in the object frame, the
sides they hold have not moved. (Letting the fields relax instead cut a stroke's evidence
in two at every dropped sample: with 20 % of the samples empty, the 8-gon's memory never
completed on the development seeds.)

Mapping needs a side to hold still in the object frame for several samples, and the
normal of a round object does not: it points at the finger, so it holds still against
the *hand* while the object turns. The hand field, the map field's twin over the world
frame, is fed by the same detected sides moved into that frame; where it forms a peak (a
contact that stays put against the hand), it inhibits the map field (``hand_to_map``).
This lets the map field be fast enough to write a side within one stroke (time constant 5
samples) without mapping a round object's sliding normal.

Two pathways follow (seed 000, III-B):

mapping (slow)
    surface detection field -> map field -> memory trace (eq. 2): the object's shape,
    a trace over object-frame orientation with one peak per flat side;
tracking (fast)
    surface detection -> match field, pre-shaped by the memory so that a detected side's
    peak forms at the nearest remembered side -> 2-D comparison field (detected side
    along the first dimension, matched side along the second) -> read out along the
    diagonal into the error field, whose peak position (relative to its centre) is the
    orientation error. The estimate is corrected by a fraction of it every sample, and the
    corrected estimate transforms the next sample's normals into the object frame. The
    estimate also follows the odometry's increments at a learnt rate - a correction per
    radian of odometry - so that a hand that systematically under-estimates the rotation
    (seed 000, II-B) is corrected between read-outs too, instead of only after its error
    has built up. By default (``rate_mode="mean"``, an addition to seed 000) the rate is
    the correction accumulated so far per radian of odometry turned, a least-squares fit
    ``correction = rate * D`` over the odometry ``D`` turned since the first sample with a
    prior of ``rate_prior`` radians at rate ``rate_prior_mean`` (0.05: seed 000, II-B,
    reports a systematic under-estimate, so the prior expects one rather than none);
    ``rate_mode="integral"`` changes it by ``-rate_gain * error`` per read-out instead (it
    learnt the rate about half as fast).

The two pathways meet once more (an addition to seed 000): the match field also drives the
map field (``match_to_map``), so a detected side that matches a remembered one refreshes
the memory at the remembered place rather than beside it. A side written once is kept up
by later landings, and a tracking error of a few degrees no longer writes a second peak
next to the first. The drive needs a detection nearby (the loop memory -> match -> map ->
memory must not run without contact) and is withheld where the hand field is active or
close to threshold (a round object's sliding normal must not keep a stray peak alive).

Sides seen in many short visits (an addition to seed 000): with one or two noisy normals
a finger, a side is detected in bursts of a sample or two, and the map field (time constant
5 samples) seldom fires on one visit. So the tracker keeps a leaky histogram of the
surface field's detections in the object frame (``detection_window`` samples, about three
turns, so that a side landed on flat only once a turn keeps its evidence) and its twin
in the hand's frame. A place whose detections stand out in the object frame and not in the
hand's frame pre-shapes the map field (``detection_gain`` times the contrast's excess over
``detection_threshold``, or over ``detection_relative`` times the median of the contrast's
peaks where that is higher), so that the next visit writes it. The contrast is the
histogram over its mean, less its blur by ``detection_blur``. Detections, unlike raw codes,
seldom come from a corner's broad spread of normals; the relative threshold keeps out the
few that do, a stroke over a corner that stands out of an early histogram. The pre-shape
is withheld where the hand field is active, as the match drive is. It is off altogether
while the run's hand-frame detections are the more concentrated, as a round object's are,
since its normal points at the finger. It also waits for the first ``detection_start``
samples with contact, and until ``detection_settle`` asks the ratio to be the clearer
(``detection_early_raise``). Where that concentration ratio is lower still, as only a round
object's is, the map field's whole drive is muted (``detection_mute_low`` to
``detection_mute_high``): a round object's scattered normals then write no stray side, and
the ones written before fade.

All fields are periodic over ``[0, 2 pi)`` with ``n_sites`` sites and are integrated with
explicit Euler steps of ``dt = 1`` sample (about 0.4 s at the 2-3 Hz of seed 000, IV-A);
time constants are in samples.
"""

from __future__ import annotations

from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.ndimage import maximum_filter1d
from scipy.special import gammaincinv

from .._validate import as_bool, as_count, as_float, as_instance
from ..errors import ValidationError
from .fields import (TWO_PI, Field1D, Field2D, FieldParams, MemoryTrace, _convolve, lateral_inputs, sigmoid,
                     periodic_distance, site_angles)

__all__ = ["TrackerParams", "OrientationTracker", "population_code", "as_angles", "as_odometry"]


def _concentration(h: np.ndarray, share: float = 0.1) -> float:
    """The share of a non-negative histogram's mass in its fullest ``share`` of sites."""
    k = max(1, int(round(share * h.size)))
    return float(np.sum(np.partition(h, h.size - k)[-k:]) / max(float(h.sum()), 1e-300))


def as_odometry(odometry) -> float:
    """Validate the hand's rotation estimate: a finite float (rad)."""
    try:
        odo = float(odometry)
    except (TypeError, ValueError):
        raise ValidationError(f"odometry must be a finite float (rad), got {odometry!r}") from None
    if not np.isfinite(odo):
        raise ValidationError(f"odometry must be a finite float (rad), got {odo}")
    return odo


def as_angles(normal_angles, name: str = "normal_angles", *, allow_empty: bool = False) -> np.ndarray:
    """Validate contact-normal angles: a finite 1-D array (rad); returns (K,) float.

    An empty array (a sample without contact) is accepted only with ``allow_empty``.
    """
    try:
        a = np.asarray(normal_angles, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be a 1-D array of angles in rad: {exc}") from None
    if a.ndim == 0:
        a = a[None]
    if a.ndim != 1:
        raise ValidationError(f"{name} must be a 1-D array (K,) of angles in rad, got shape {a.shape}")
    if a.size == 0 and not allow_empty:
        raise ValidationError(f"{name} must hold at least one angle, got an empty array")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.isfinite(a))[0])
        raise ValidationError(f"{name} must be finite angles in rad, entry {bad} is {a[bad]}")
    return a


def population_code(angles, n_sites: int, width: float, gain: float, *, normalize: bool = False) -> np.ndarray:
    """Filter-bank encoding of normal angles (seed 000, III-B).

    Neuron ``i`` prefers the direction ``phi_i = 2 pi i / n``; its response to a normal is
    a sharpened scalar product of its weight vector and the normal,
    ``exp((cos(phi_i - a) - 1) / width^2)`` (a von Mises tuning curve, about a Gaussian
    of standard deviation ``width``), summed over the normals and scaled by ``gain``.
    Many normals with one orientation (a flat side) give a strong, sharp input; a broad
    spread (an edge) gives a weak one.

    Parameters
    ----------
    angles : (K,) float
        Normal angles, rad.
    n_sites : int
    width : float
        Tuning width, rad.
    gain : float
        Input per normal at the preferred direction.
    normalize : bool
        Average over the normals instead of summing (the tracker's input stage): the
        result no longer grows with the number of normals. No normals give zeros.

    Returns
    -------
    (n_sites,) float
    """
    a = as_angles(angles, "angles", allow_empty=True)
    n_sites = as_count(n_sites, "n_sites", min=3, max=1_000_000, why="one response per site")
    width = as_float(width, "width (rad)", low=1e-6, high=1e3)  # width^2 must neither under- nor overflow
    gain = as_float(gain, "gain")
    normalize = as_bool(normalize, "normalize")
    phi = site_angles(n_sites)
    if a.size == 0:
        return np.zeros(n_sites)
    if normalize:
        gain = gain / a.size
    return _code(a, np.cos(phi), np.sin(phi), width, gain)


def _code(a: np.ndarray, cos_phi: np.ndarray, sin_phi: np.ndarray, width: float, gain: float) -> np.ndarray:
    """:func:`population_code` of at least one angle, without its checks, given the cosines
    and sines of the sites' preferred directions."""
    # cos(phi - a) = cos(phi) cos(a) + sin(phi) sin(a)
    cosd = np.cos(a)[:, None] * cos_phi[None, :] + np.sin(a)[:, None] * sin_phi[None, :]
    return gain * np.exp((cosd - 1.0) / width**2).sum(axis=0)


def _roll(x: np.ndarray, shift: int) -> np.ndarray:
    """``np.roll(x, shift)`` of a 1-D array, for a few microseconds less."""
    n = x.shape[0]
    s = shift % n
    return np.concatenate((x[n - s:], x[:n - s])) if s else x.copy()


#: memory height at which a side counts as remembered (seed 000's read-out threshold)
REMEMBERED = 0.4


@lru_cache(maxsize=256)
def _sd_median(n: int) -> float:
    """Median of the sample standard deviation of ``n`` unit Gaussian values:
    ``sqrt(median(chi2(n - 1)) / (n - 1))``."""
    k = n - 1
    return float(np.sqrt(2.0 * gammaincinv(0.5 * k, 0.5) / k))


def contact_spreads(angles, gap: float = np.radians(20.0)) -> np.ndarray:
    """Angular spread of each contact's normals within one sample.

    The normals, sorted by angle, are split into contacts wherever two neighbours are more
    than ``gap`` apart. For each contact with two normals or more, the sample standard
    deviation of its angles divided by that statistic's median for Gaussian normals of
    unit spread: an estimate of the normals' standard deviation whose median does not
    depend on how many normals the contact gave. The tracker's spread normalisation
    (``TrackerParams.noise_ref``) takes the median of these over the contacts that landed
    on remembered sides.

    Parameters
    ----------
    angles : (K,) float
        Normal angles of one sample, rad; any number, including none.
    gap : float
        Largest angle between neighbouring normals of one contact, rad (in ``(0, pi)``).

    Returns
    -------
    (C,) float
        One spread per contact with two normals or more, rad (empty if none).
    """
    a = as_angles(angles, "angles", allow_empty=True)
    gap = as_float(gap, "gap (rad)", low=1e-9, high=np.pi)
    return np.array(_contacts(a, gap)[0], dtype=float)


def _contacts(a: np.ndarray, gap: float) -> tuple[list, list, int]:
    """One sample's contacts: ``contact_spreads`` and those contacts' mean angles, as lists,
    and how many contacts the normals make in all (single normals included)."""
    # plain Python over the sorted angles: a sample holds a few to a hundred normals, where
    # numpy's per-call overhead would dominate
    s = np.sort(np.mod(a, TWO_PI)).tolist()
    n = len(s)
    spreads, means, count = [], [], min(n, 1)
    if n >= 2:
        # start after the widest gap, so that no contact is cut at 0 rad
        gaps = [s[i + 1] - s[i] for i in range(n - 1)] + [s[0] + TWO_PI - s[-1]]
        if max(gaps) > gap:
            start = (max(range(n), key=gaps.__getitem__) + 1) % n
            s = s[start:] + [v + TWO_PI for v in s[:start]]
        group = [s[0]]
        for v in s[1:] + [None]:
            if v is not None and v - group[-1] <= gap:
                group.append(v)
                continue
            m = len(group)
            count += v is not None
            if m >= 2:
                mu = sum(group) / m
                var = sum((g - mu) ** 2 for g in group) / (m - 1)
                spreads.append(var ** 0.5 / _sd_median(m))
                means.append(mu)
            if v is not None:
                group = [v]
    return spreads, means, count


#: memory updates between two counts of the sides the memory holds (``memory_decay_sides``)
_RECOUNT_EVERY = 10


@dataclass(frozen=True)
class TrackerParams:
    """Parameters of :class:`OrientationTracker`; the defaults reproduce seed 000's behaviour.

    One addition to seed 000's architecture is on by default: the hand field
    (``hand_to_map``), which keeps contacts that hold still against the hand out of the
    map; ``hand_to_map=0`` removes it.

    Time constants are in samples (Euler step ``dt = 1``); kernel strengths are per active
    site; widths in rad.
    """

    n_sites: int = 360
    #: filter bank tuning width; input at a side seen steadily (the code is a mean over
    #: the normals, so it does not grow with their number). 5 deg: wide enough that 1-2
    #: blob normals with 3-6 deg of scatter still reach threshold
    tuning_width: float = np.radians(5.0)
    input_gain: float = 16.0
    #: spread normalisation of the input (an addition to seed 000): the tracker estimates
    #: the angular spread of one contact's normals within a sample (:func:`contact_spreads`;
    #: the median over the last ``noise_window`` contacts with two normals or more that
    #: landed on a remembered side) and, where it exceeds ``noise_ref``, raises
    #: ``input_gain`` by ``sqrt(w^2 + s^2) / sqrt(w^2 + noise_ref^2)`` (w: ``tuning_width``;
    #: the inverse of the expected peak of the mean code of normals spread by ``s``) and
    #: lowers ``correction_gain`` by ``(noise_ref / s)^2`` (an inverse-variance weight of
    #: the read-out). ``noise_ref`` stands for the spread the other parameters were set at
    #: (the robustness sweep's base cell: 3 deg of noise on the curved pad, where the
    #: estimate reads 3.8-5.2 deg). Spreads at or below it leave the defaults, and so do one normal per contact
    #: and the first ``noise_min`` contacts. Only remembered sides count, since an edge's
    #: or a round object's normals spread for reasons other than the sensor's noise.
    #: ``noise_ref = 0`` turns it off
    noise_ref: float = np.radians(4.8)
    noise_window: float = 600.0
    noise_min: float = 10.0
    #: the read-out's weight by the normals per contact (an addition to seed 000): a side
    #: detected from fewer normals a contact than this (the sweep's base cell has two) is
    #: located less precisely, and a sample's correction is scaled by its mean count of
    #: normals per contact over ``normals_ref`` (capped at 1; the variance of a mean falls
    #: with the count). 0 turns it off
    normals_ref: float = 2.0
    #: normals of one sample closer than this (sorted by angle) belong to one contact
    contact_gap: float = np.radians(20.0)
    #: time constant of the optional evidence window, samples (leaky average of the codes;
    #: 0: the current sample only)
    input_window: float = 0.0
    #: surface detection: fast, input driven (no peak without input)
    surface: FieldParams = FieldParams(tau=2.0, h=-5.0, beta=4.0, c_exc=0.5, sigma_exc=np.radians(3.0),
                                       c_inh=0.15, sigma_inh=np.radians(12.0))
    #: map field (5 samples: most of a stroke) and its memory trace (eq. 2). A side holds
    #: still in the object frame through a stroke and drives it up; the normal of a round
    #: object, which points at the finger, slides through the object frame (and is held
    #: back by the hand field below)
    map: FieldParams = FieldParams(tau=5.0, h=-5.0, beta=4.0, c_exc=0.6, sigma_exc=np.radians(3.0),
                                   c_inh=0.2, sigma_inh=np.radians(12.0))
    surface_to_map: float = 10.0
    #: hand field: the map field's twin over the hand's (world) frame, fed by the detected
    #: sides moved into that frame. A contact that holds still against the hand while the
    #: object turns (a round object's normal points at the finger) builds a peak here, and
    #: that peak inhibits the map field at the same place (0: no hand field)
    hand: FieldParams = FieldParams(tau=5.0, h=-5.0, beta=4.0, c_exc=0.6, sigma_exc=np.radians(3.0),
                                    c_inh=0.2, sigma_inh=np.radians(12.0))
    hand_to_map: float = 10.0
    #: detection evidence (an addition to seed 000; see the module): leaky histograms of
    #: the surface field's detections over ``detection_window`` samples with contact, in
    #: the object and the hand frame; ``detection_gain`` times the object frame's contrast
    #: (over its mean, less its blur by ``detection_blur``), less the hand frame's, in
    #: excess of ``detection_threshold`` pre-shapes the map field, from the
    #: ``detection_start``-th sample with contact on (60, about two thirds of a turn; 150
    #: until the nineteenth round, docs/dnf_rounds.md). It is scaled by the ratio of the
    #: concentrations of the run's summed detections (the mass in their fullest tenth of
    #: sites, object frame over hand frame), from 0 at ``detection_hold_low`` to 1 at
    #: ``detection_hold_high``: a round object's detections hold still against the hand
    #: (ratios 0.16-0.52 on dense and seed-faithful development data after 150 samples,
    #: polygons 0.52-2.45; docs/dnf_rounds.md, "Ninth round"; before that, see
    #: ``detection_early_raise``). ``detection_gain = 0`` turns it off.
    #: The window was 150 samples until the seventeenth round (docs/dnf_rounds.md): 300 holds a side
    #: between flat landings a turn or more apart, at 6 deg of noise
    detection_window: float = 300.0
    detection_start: float = 60.0
    #: an early ratio, from few detections, must be the clearer: from ``detection_start``
    #: the gate's two ratios are raised by ``detection_early_raise``, the raise falling
    #: linearly to 0 at ``detection_settle`` samples with contact. A round object's ratio
    #: starts high and falls as its detections spread over the object frame: on dense
    #: development data it reached 0.76 at 60 samples, 0.64 at 100 and 0.53 at 150, while
    #: the 6 deg 8-gons' lowest were 0.67-0.70 and the 4- to 6-gons' higher (docs/dnf_rounds.md,
    #: "Nineteenth round"). ``detection_early_raise = 0`` gives the plain gate from the start
    detection_early_raise: float = 0.3
    detection_settle: float = 150.0
    detection_gain: float = 8.0
    detection_threshold: float = 0.4
    detection_blur: float = np.radians(15.0)
    detection_hold_low: float = 0.55
    detection_hold_high: float = 0.65
    #: the same ratio mutes the map field: its drive is scaled from 0 at
    #: ``detection_mute_low`` to 1 at ``detection_mute_high`` (from the
    #: ``detection_start``-th sample with contact on), so that a run whose detections hold
    #: still against the hand writes no side, and sides written before fade at the
    #: memory's decay rate. Only a round object's ratios fall this low: in the second half
    #: of seed-faithful development data round objects stay within 0.15-0.33 (0.24 or less
    #: in nine runs of ten), polygons within 0.33-2.4 (one run below 0.46); docs/dnf_rounds.md,
    #: "Tenth round". ``detection_mute_high = 0`` turns it off
    detection_mute_low: float = 0.25
    detection_mute_high: float = 0.35
    #: a place's contrast must also exceed ``detection_relative`` times the median of the
    #: contrast's peaks (its local maxima above ``detection_threshold``): one stroke over a
    #: corner, whose normals may hold still for a few samples, stands out of an early
    #: histogram as much as a side does, and a pre-shape there would hold the stray side it
    #: writes for as long as the window remembers the stroke; beside the sides of the same
    #: polygon its contrast is a fraction of theirs (docs/dnf_rounds.md, "Twentieth round").
    #: 0 turns it off
    detection_relative: float = 0.15
    #: the match field's output into the map field (an addition to seed 000): a detected
    #: side that matches a remembered one also drives the map field at the *remembered*
    #: place, so the memory is refreshed where it already holds the side instead of
    #: beside it (a doubled peak) and a side written once is kept up by later landings.
    #: Where the hand field is active (blurred by ``match_width``) this drive is
    #: withheld, so that a round object's sliding normal cannot keep a stray peak alive
    match_to_map: float = 4.0
    #: the match drive is withheld where the hand field's activation is within this margin
    #: of its threshold (or above), blurred by ``match_width``: more cautious than the hand
    #: field's own inhibition, since the match drive feeds the memory back into itself
    hand_gate_margin: float = 1.0
    memory_to_map: float = 2.0
    memory_tau: float = 1.0
    memory_build: float = 0.2
    #: decay where the map field is silent: a peak written while the estimate was still
    #: off fades within about 250 samples unless the side is touched there again
    memory_decay: float = 0.004
    #: the decay slows with the number of sides remembered (an addition to seed 000): it is
    #: ``memory_decay * min(1, memory_decay_sides / n)``, ``n`` the sides the memory holds
    #: (:func:`count_surfaces`, recounted on every 10th update). The hand turns the object
    #: by about the same angle a stroke whatever its shape, so each side of an n-gon is
    #: touched about every n-th stroke and must be held n times as long; up to
    #: ``memory_decay_sides`` sides the decay is as before (docs/dnf_rounds.md, "Twenty-first
    #: round"). Only with ``correct``, as the split decay; 0 turns it off
    memory_decay_sides: float = 6.0
    #: a split fades (an addition to seed 000): a remembered side weaker than another one
    #: remembered ``split_near`` to ``split_far`` away (a side written twice while the
    #: estimate drifted, or a stray beside a side) decays at ``split_decay`` a sample more
    #: where the map field is silent. Sides of a polygon with up to 360 / 18 = 20 sides
    #: lie farther apart (docs/dnf_rounds.md, "Eleventh round"). Only with ``correct``: without a
    #: correction the estimate drifts on, and fading the older copies would let the map
    #: slide with the drift (a window of the last turn) instead of failing as seed 000's
    #: uncorrected memory does. ``split_decay = 0`` turns it off
    split_decay: float = 0.04
    split_near: float = np.radians(8.0)
    split_far: float = np.radians(18.0)
    #: match field: broad copy of the detected sides plus the memory as pre-shape
    match: FieldParams = FieldParams(tau=1.0, h=-5.0, beta=4.0, c_exc=0.5, sigma_exc=np.radians(3.0),
                                     c_inh=0.2, sigma_inh=np.radians(15.0))
    match_width: float = np.radians(8.0)
    surface_to_match: float = 3.5
    memory_to_match: float = 4.0
    #: 2-D comparison field: active only where a detected and a matched side coincide
    comparison: FieldParams = FieldParams(tau=1.0, h=-8.0, beta=4.0, c_exc=0.3, sigma_exc=np.radians(2.0),
                                          c_glob=0.0005)
    to_comparison: float = 4.5
    #: error field over the deviation (centre = no error), fed by the diagonal read-out
    error: FieldParams = FieldParams(tau=1.0, h=-3.0, beta=4.0, c_exc=0.3, sigma_exc=np.radians(3.0),
                                     c_glob=0.02)
    comparison_to_error: float = 0.5
    error_window: float = np.radians(15.0)
    #: fraction of the read-out error corrected per sample (small: with one or two normals
    #: per finger a single read-out can pair a side with the wrong remembered one)
    correction_gain: float = 0.15
    #: how the odometry's scale error is learnt: the correction follows the odometry's
    #: increments at a rate (correction per radian of odometry). ``"mean"``: the rate is
    #: the total correction per radian of odometry turned since the first sample,
    #: ``(c D + rate_prior_mean rate_prior^2) / (D^2 + rate_prior^2)`` (least squares with a
    #: prior of ``rate_prior`` rad at rate ``rate_prior_mean``); ``"integral"``: every
    #: read-out error changes it by ``-rate_gain * error``; ``"off"``: no rate. The prior
    #: weighs as half a radian of odometry (it was 1 rad until the thirteenth round,
    #: docs/dnf_rounds.md): with a 10 % under-estimate the first turn, before any side is
    #: remembered, drifts less, and fewer sides are written twice
    rate_mode: str = "mean"
    rate_prior: float = 0.5
    #: the rate the prior of ``rate_mode="mean"`` pulls towards (and the rate before any
    #: read-out): seed 000 (II-B) reports that the hand systematically *under*-estimates
    #: the rotation, so the prior expects a 5 % under-estimate rather than none; the data
    #: move it within about one radian of odometry
    rate_prior_mean: float = 0.05
    rate_gain: float = 0.01
    #: whether the estimate is corrected (False: the "memory trace without correction")
    correct: bool = True
    #: a sample without contact leaves every field as it is (True) instead of letting
    #: them relax towards rest (False): no contact is no evidence, and the fields live in
    #: the object frame, where the sides have not moved
    hold_empty: bool = True

    def with_(self, **changes) -> "TrackerParams":
        """A copy with some parameters changed."""
        return replace(self, **changes)


class OrientationTracker:
    """Track a rotating object's orientation and map its sides (seed 000, Fig. 2).

    Parameters
    ----------
    params : TrackerParams, optional
        Model parameters (defaults reproduce seed 000).
    correct : bool, optional
        Override ``params.correct``; ``False`` gives the uncorrected memory-trace baseline
        of seed 000, section V.
    **changes
        Further overrides of :class:`TrackerParams` fields.

    Attributes
    ----------
    orientation : float
        Corrected estimate of the object's accumulated rotation, rad
        (``odometry + correction``).
    correction : float
        Accumulated correction, rad.
    memory : (n_sites,) float
        Memory trace over object-frame orientation, in [0, 1] (the object's shape).
    n_steps : int

    Examples
    --------
    >>> tracker = OrientationTracker()
    >>> for angles, odo in dataset.samples():        # doctest: +SKIP
    ...     tracker.step(angles, odo)
    >>> count_surfaces(tracker.memory)               # doctest: +SKIP
    6
    """

    def __init__(self, params: TrackerParams | None = None, *, correct: bool | None = None, **changes):
        p = TrackerParams() if params is None else as_instance(params, TrackerParams, "params")
        if correct is not None:
            changes["correct"] = as_bool(correct, "correct")
        if changes:
            unknown = set(changes) - set(TrackerParams.__dataclass_fields__)
            if unknown:
                raise ValidationError(f"unknown tracker parameters {sorted(unknown)}")
            p = p.with_(**changes)
        if not isinstance(p.n_sites, (int, np.integer)) or p.n_sites < 16:
            raise ValidationError(f"n_sites must be an int >= 16, got {p.n_sites!r}")
        as_count(p.n_sites, "n_sites", min=16, max=3000, why="the comparison field holds n_sites^2 sites")
        for f in TrackerParams.__dataclass_fields__:
            v = getattr(p, f)
            if f in ("correct", "hold_empty"):
                as_bool(v, f)
            elif f == "rate_mode":
                if not isinstance(v, str) or v not in ("mean", "integral", "off"):
                    raise ValidationError(f"rate_mode must be 'mean', 'integral' or 'off', got {v!r}")
            elif isinstance(getattr(TrackerParams, f, None), FieldParams):
                as_instance(v, FieldParams, f)
            elif f != "n_sites":
                as_float(v, f)
        if p.rate_mode == "mean" and not p.rate_prior > 0:
            raise ValidationError(f"rate_prior must be > 0 rad with rate_mode='mean', got {p.rate_prior!r}")
        if not (np.isfinite(p.input_window) and p.input_window >= 0):
            raise ValidationError(f"input_window must be >= 0 samples (0: no window), got {p.input_window!r}")
        if not (0.0 <= p.noise_ref <= np.pi):
            raise ValidationError(f"noise_ref must be in [0, pi] rad (0: no spread normalisation), got {p.noise_ref!r}")
        if not (1.0 <= p.noise_window <= 1e6):
            raise ValidationError(f"noise_window must be 1 to 1e6 contacts, got {p.noise_window!r}")
        if not (0.0 <= p.noise_min <= p.noise_window):
            raise ValidationError(f"noise_min must be 0 to noise_window contacts, got {p.noise_min!r}")
        if not (0.0 <= p.normals_ref <= 1e6):
            raise ValidationError(f"normals_ref must be 0 to 1e6 normals per contact (0: off), got {p.normals_ref!r}")
        if not (0.0 < p.contact_gap < np.pi):
            raise ValidationError(f"contact_gap must be in (0, pi) rad, got {p.contact_gap!r}")
        if not (1.0 <= p.detection_window <= 1e6):
            raise ValidationError(f"detection_window must be 1 to 1e6 samples, got {p.detection_window!r}")
        if not (1.0 <= p.detection_start <= 1e6):
            raise ValidationError(f"detection_start must be 1 to 1e6 samples, got {p.detection_start!r}")
        if not (0.0 <= p.detection_early_raise <= 1e3):
            raise ValidationError(f"detection_early_raise must be 0 to 1e3, got {p.detection_early_raise!r}")
        if not (1.0 <= p.detection_settle <= 1e6):
            raise ValidationError(f"detection_settle must be 1 to 1e6 samples, got {p.detection_settle!r}")
        if not (0.0 <= p.detection_gain <= 1e3):
            raise ValidationError(f"detection_gain must be 0 to 1e3 (0: off), got {p.detection_gain!r}")
        if not (0.0 <= p.memory_decay_sides <= 1e3):
            raise ValidationError(f"memory_decay_sides must be 0 to 1e3 sides (0: off), got {p.memory_decay_sides!r}")
        if not (0.0 <= p.detection_relative <= 1e3):
            raise ValidationError(f"detection_relative must be 0 to 1e3 (0: off), got {p.detection_relative!r}")
        if not (0.0 <= p.detection_threshold <= 1e3):
            raise ValidationError(f"detection_threshold must be 0 to 1e3, got {p.detection_threshold!r}")
        if not (0.0 < p.detection_blur < np.pi):
            raise ValidationError(f"detection_blur must be in (0, pi) rad, got {p.detection_blur!r}")
        if not (0.0 <= p.detection_hold_low < p.detection_hold_high <= 1e3):
            raise ValidationError(f"need 0 <= detection_hold_low < detection_hold_high <= 1e3, got "
                                  f"{p.detection_hold_low!r} and {p.detection_hold_high!r}")
        if not (0.0 <= p.detection_mute_low <= 1e3 and 0.0 <= p.detection_mute_high <= 1e3
                and (p.detection_mute_high == 0.0 or p.detection_mute_low <= p.detection_mute_high)):
            raise ValidationError(f"need 0 <= detection_mute_low <= detection_mute_high <= 1e3 (or "
                                  f"detection_mute_high = 0: off), got {p.detection_mute_low!r} and "
                                  f"{p.detection_mute_high!r}")
        if not (0.0 <= p.split_decay <= 1.0):
            raise ValidationError(f"split_decay must be 0 to 1 per sample (0: off), got {p.split_decay!r}")
        if not (0.0 < p.split_near < p.split_far < np.pi):
            raise ValidationError(f"need 0 < split_near < split_far < pi rad, got {p.split_near!r} and "
                                  f"{p.split_far!r}")
        self.params = p
        n = self.n_sites = int(p.n_sites)
        self.angles = site_angles(n)
        self._cos_phi, self._sin_phi = np.cos(self.angles), np.sin(self.angles)
        self.surface = Field1D(n, p.surface)
        self.map = Field1D(n, p.map)
        self.hand = Field1D(n, p.hand)
        self.trace = MemoryTrace(n, tau=p.memory_tau, build=p.memory_build, decay=p.memory_decay)
        self.match = Field1D(n, p.match)
        self.comparison = Field2D((n, n), p.comparison)
        self.error = Field1D(n, p.error)
        d = periodic_distance(n)
        g = np.exp(-0.5 * (d / p.match_width) ** 2)
        self._match_blur_fft = np.fft.rfft(g / g.max())
        g = np.exp(-0.5 * (d / p.detection_blur) ** 2)
        self._detection_blur_fft = np.fft.rfft(g / g.sum())   # a mean: the contrast's background
        # signed deviation of each error-field site from the centre (site 0), rad
        self._dev = (self.angles + np.pi) % TWO_PI - np.pi
        self._window = np.exp(-0.5 * (self._dev / p.error_window) ** 2)
        # a split's reach in whole sites: [near, far] on either side (near >= 1)
        self._split_near = max(1, int(round(p.split_near * n / TWO_PI)))
        self._split_far = max(self._split_near, int(round(p.split_far * n / TWO_PI)))
        self._f32 = np.float32
        self._leak = float(np.exp(-1.0 / p.input_window)) if p.input_window > 0 else 0.0
        self.correction = 0.0
        self.odometry = 0.0
        self.n_steps = 0
        self.last_error = 0.0
        self._evidence = np.zeros(n)
        self._weight = 0.0
        self._rate = self._rate0()
        self._last_odo = None
        self._first_odo = None
        # the window of spreads, in arrival order and sorted (for the median)
        self._spread_fifo = deque(maxlen=int(round(p.noise_window)))
        self._spread_ranked = []
        self._gain_scale = 1.0
        self._correction_scale = 1.0
        self._noise = float(p.noise_ref)
        self._detections = np.zeros(n)        # object frame
        self._detections_hand = np.zeros(n)   # hand (world) frame
        self._detections_total = np.zeros(n)  # the same, summed over the run
        self._detections_hand_total = np.zeros(n)
        self._detection_samples = 0
        self._memory_updates = 0
        self._decay_scale = 1.0

    def _rate0(self) -> float:
        """The rate before any read-out: the prior's mean (``rate_mode="mean"`` with
        correction on), else 0 (the uncorrected memory follows the odometry alone)."""
        p = self.params
        return float(p.rate_prior_mean) if (p.rate_mode == "mean" and p.correct) else 0.0

    # -- state -------------------------------------------------------------------------
    @property
    def orientation(self) -> float:
        """Corrected estimate of the object's accumulated rotation, rad."""
        return self.odometry + self.correction

    @property
    def rate(self) -> float:
        """Learnt correction per radian of odometry (the odometry's relative error; 0 with
        ``rate_mode="off"``)."""
        return self._rate

    @property
    def noise(self) -> float:
        """Estimated spread of one contact's normals within a sample, rad (see
        ``TrackerParams.noise_ref``); ``noise_ref`` until enough contacts were seen."""
        return self._noise

    @property
    def memory(self) -> np.ndarray:
        """Memory trace over object-frame orientation, (n_sites,) in [0, 1]."""
        return self.trace.P

    def reset(self) -> None:
        """Forget everything: fields at rest, empty memory, no correction."""
        for f in (self.surface, self.map, self.hand, self.match, self.comparison, self.error):
            f.reset()
        self.trace.reset()
        self._evidence[:] = 0.0
        self._weight = 0.0
        self._rate = self._rate0()
        self._last_odo = None
        self._first_odo = None
        self._spread_fifo.clear()
        self._spread_ranked.clear()
        self._gain_scale = 1.0
        self._correction_scale = 1.0
        self._noise = float(self.params.noise_ref)
        self._detections[:] = 0.0
        self._detections_hand[:] = 0.0
        self._detections_total[:] = 0.0
        self._detections_hand_total[:] = 0.0
        self._detection_samples = 0
        self._memory_updates = 0
        self._decay_scale = 1.0
        self.correction = 0.0
        self.odometry = 0.0
        self.n_steps = 0
        self.last_error = 0.0

    # -- one sample --------------------------------------------------------------------
    def step(self, normal_angles, odometry: float) -> float:
        """Process one sample.

        Parameters
        ----------
        normal_angles : (K,) float
            Contact-normal angles of this sample, rad, world frame; any number, including
            none (K = 0: no contact in this sample).
        odometry : float
            The hand's estimate of the object's accumulated rotation, rad, such that
            ``world angle = object-frame angle + rotation``.

        Returns
        -------
        float
            The corrected orientation estimate after this sample, rad.
        """
        a = as_angles(normal_angles, allow_empty=True)
        self.odometry = as_odometry(odometry)
        self._step(a)
        return self.orientation

    def _step(self, a: np.ndarray) -> None:
        p = self.params
        if self._last_odo is not None:
            self.correction += self._rate * (self.odometry - self._last_odo)
        else:
            self._first_odo = self.odometry
        self._last_odo = self.odometry
        if p.hold_empty and a.size == 0:
            self.last_error = 0.0
            self.n_steps += 1
            return
        # input stage: mean code in the object frame (corrected estimate), averaged over
        # the evidence window; an empty sample (without hold_empty) only lets it leak
        self._evidence *= self._leak
        self._weight *= self._leak
        if a.size:
            # the mean code (population_code with normalize=True)
            self._evidence += _code(a - self.orientation, self._cos_phi, self._sin_phi, p.tuning_width, 1.0 / a.size)
            self._weight += 1.0
        # the sample's contacts: their spreads feed the spread normalisation, their number
        # the read-out's count weight
        sp, mu, n_contacts = _contacts(a, p.contact_gap) if a.size else ([], [], 0)
        if p.noise_ref > 0 and sp:
            self._observe_spread(sp, mu)
        stim = (p.input_gain * self._gain_scale / max(self._weight, 1.0)) * self._evidence
        # every field stepped below gets its lateral input from its activation before this
        # sample: one FFT for all of them
        stepped = ["surface", "map", "match"] + ["hand"] * bool(p.hand_to_map) + ["error"] * bool(p.correct)
        lateral = dict(zip(stepped, lateral_inputs([getattr(self, name) for name in stepped])))
        # mapping pathway
        f_s = self.surface.step(stim, lateral=lateral["surface"])
        P = self.trace.P
        drive = p.surface_to_map * f_s + p.memory_to_map * P
        # world angle = object-frame angle + orientation: a shift by whole sites
        shift = int(round(self.orientation * self.n_sites / TWO_PI)) % self.n_sites
        f_s_hand = _roll(f_s, shift)   # the detections in the hand's frame
        pre, mute = (self._detection_evidence(f_s, f_s_hand, shift)
                     if p.detection_gain > 0 or p.detection_mute_high > 0 else (None, 1.0))
        f_h = None
        hand_gate = None
        if p.hand_to_map:
            f_h = _roll(self.hand.step(p.surface_to_map * f_s_hand, lateral=lateral["hand"]), -shift)
            drive = drive - p.hand_to_map * f_h
            # 0 near a contact that holds (or nearly holds) still against the hand, else 1;
            # blurred together with the detections (the match field's input)
            g_h = _roll(sigmoid(self.hand.u + p.hand_gate_margin, p.hand.beta), -shift)
            broad, g_h = _convolve(np.stack((f_s, g_h)), self._match_blur_fft, self.n_sites)
            hand_gate = 1.0 - np.clip(g_h, 0.0, 1.0)
        else:
            broad = _convolve(f_s, self._match_blur_fft, self.n_sites)
        if pre is not None:
            drive = drive + (pre if hand_gate is None else pre * hand_gate)
        # tracking pathway: match field pulled towards remembered sides (the memory as it
        # was before this sample)
        f_match = self.match.step(p.surface_to_match * np.minimum(broad, 1.0) + p.memory_to_match * P,
                                  lateral=lateral["match"])
        if p.match_to_map:
            # only while a detected side is near: memory -> match -> map -> memory must not
            # sustain itself without contact
            m = p.match_to_map * f_match * np.minimum(broad, 1.0)
            if hand_gate is not None:
                m = m * hand_gate
            drive = drive + m
        f_m = self.map.step(drive if mute == 1.0 else mute * drive, lateral=lateral["map"])
        if p.memory_decay_sides > 0 and p.correct:
            if self._memory_updates % _RECOUNT_EVERY == 0:
                from .estimators import count_surfaces   # here: estimators imports this module
                self._decay_scale = min(1.0, p.memory_decay_sides / max(count_surfaces(self.trace.P), 1))
            self._memory_updates += 1
            self.trace.step(f_m, decay_scale=self._decay_scale)
        else:
            self.trace.step(f_m)
        if p.split_decay > 0 and p.correct:
            self._fade_splits(f_m)
        if p.correct:
            k = self._f32(p.to_comparison)
            self.comparison.step(((f_s * k).astype(np.float32)[:, None],
                                  (f_match * k).astype(np.float32)[None, :]))
            diag = self._diagonal()
            f_e = self.error.step(p.comparison_to_error * diag * self._window, lateral=lateral["error"])
            w = np.where(f_e > 0.5, f_e, 0.0)
            tot = w.sum()
            if tot > 0:
                z = np.sum(w * np.exp(1j * self._dev))
                err = float(np.angle(z))
                self.last_error = err
                self.correction -= p.correction_gain * self._correction_scale * self._count_weight(a.size, n_contacts) * err
                if p.rate_mode == "mean":
                    D = self.odometry - self._first_odo
                    self._rate = min(max((self.correction * D + p.rate_prior_mean * p.rate_prior ** 2)
                                         / (D * D + p.rate_prior ** 2), -0.5), 0.5)
                elif p.rate_mode == "integral":
                    self._rate -= p.rate_gain * err
            else:
                self.last_error = 0.0
        self.n_steps += 1

    def _detection_evidence(self, f_s: np.ndarray, f_hand: np.ndarray, shift: int) -> tuple:
        """Add this sample's detections (``f_s`` in the object frame, ``f_hand`` the same
        moved ``shift`` sites into the hand's frame) to the detection histograms. Returns
        the map field's pre-shape from them (see ``TrackerParams.detection_gain``; None
        while it is off) and the factor of the map field's drive (see
        ``TrackerParams.detection_mute_low``; 1 while it is off)."""
        p = self.params
        self._detection_samples += 1
        self._detections += (f_s - self._detections) / p.detection_window
        self._detections_hand += (f_hand - self._detections_hand) / p.detection_window
        self._detections_total += f_s
        self._detections_hand_total += f_hand
        if self._detection_samples < p.detection_start:
            return None, 1.0
        ratio = _concentration(self._detections_total) / max(_concentration(self._detections_hand_total), 1e-300)
        mute = 1.0
        if ratio < p.detection_mute_high:   # never with detection_mute_high = 0 (off): ratio >= 0
            low = p.detection_mute_low
            mute = 0.0 if ratio <= low else (ratio - low) / (p.detection_mute_high - low)
        n = self._detection_samples
        raise_ = 0.0
        if n < p.detection_settle and p.detection_early_raise > 0.0:
            span = max(p.detection_settle - p.detection_start, 1.0)
            raise_ = p.detection_early_raise * min((p.detection_settle - n) / span, 1.0)
        scale = (ratio - p.detection_hold_low - raise_) / (p.detection_hold_high - p.detection_hold_low)
        if not (p.detection_gain > 0.0 and scale > 0.0):
            return None, mute
        obj, hand = self._contrast(np.stack((self._detections, self._detections_hand)))
        d = obj - np.maximum(_roll(hand, -shift), 0.0)
        thr = p.detection_threshold
        if p.detection_relative > 0.0:
            peaks = d[(d >= _roll(d, 1)) & (d > _roll(d, -1)) & (d > thr)]
            if peaks.size:
                thr = max(thr, p.detection_relative * float(np.median(peaks)))
        return (p.detection_gain * min(scale, 1.0)) * np.clip(d - thr, 0.0, None), mute

    def _fade_splits(self, f_m: np.ndarray) -> None:
        """Let a remembered side weaker than one ``split_near`` to ``split_far`` away decay
        at ``split_decay`` where the map field (output ``f_m``) is silent. A side's sites
        within ``split_near`` of its top compare that top, so its own flanks do not fade."""
        P = self.trace.P
        a, b = self._split_near, self._split_far
        size = b - a + 1
        m = maximum_filter1d(P, size, mode="wrap", origin=-(size // 2))   # max over sites i .. i + size - 1
        near = np.maximum(_roll(m, -a), _roll(m, b))                       # over i + a .. i + b and i - b .. i - a
        top = maximum_filter1d(P, 2 * a - 1, mode="wrap")                  # over i - a + 1 .. i + a - 1
        P -= self.params.split_decay * P * (1.0 - f_m) * (near > top)

    def _contrast(self, h: np.ndarray) -> np.ndarray:
        """A histogram over its mean, less its blur by ``detection_blur``; several at once as
        the rows of a 2-D ``h``."""
        c = h / np.maximum(h.mean(axis=-1, keepdims=True), 1e-300)
        return c - _convolve(c, self._detection_blur_fft, self.n_sites)

    def _count_weight(self, n_normals: int, n_contacts: int) -> float:
        """The read-out's weight by a sample's normals per contact (``normals_ref``)."""
        ref = self.params.normals_ref
        if ref <= 0 or n_contacts == 0:
            return 1.0
        return min(1.0, n_normals / n_contacts / ref)

    def _observe_spread(self, sp: list, mu: list) -> None:
        """Add this sample's contact spreads (``sp``, at mean angles ``mu``) to the window
        and re-scale the gains."""
        p = self.params
        # only contacts on a remembered side: an edge's or a round object's normals spread
        # for reasons other than the sensor's noise
        P, n_sites, o = self.trace.P, self.n_sites, self.orientation
        fifo, ranked = self._spread_fifo, self._spread_ranked
        for v, m in zip(sp, mu):
            if P[int(round((m - o) * n_sites / TWO_PI)) % n_sites] < REMEMBERED:
                continue
            if len(fifo) == fifo.maxlen:
                del ranked[bisect_left(ranked, fifo[0])]
            fifo.append(v)
            insort(ranked, v)
        n = len(ranked)
        if n == 0 or n < p.noise_min:
            return
        s = max(0.5 * (ranked[(n - 1) // 2] + ranked[n // 2]), 1e-3 * p.noise_ref)
        w2 = p.tuning_width ** 2
        self._noise = s
        self._gain_scale = max(1.0, float(np.sqrt((w2 + s * s) / (w2 + p.noise_ref ** 2))))
        self._correction_scale = min(1.0, (p.noise_ref / s) ** 2)

    def _diagonal(self) -> np.ndarray:
        """Diagonal read-out of the comparison output: ``out[d] = sum_x F[x, x + d]``.

        Only the active block is summed (every other site's output is below the comparison
        field's ``eps``, so each entry errs by less than ``n_sites * eps``).
        """
        n = self.n_sites
        rows, cols, block = self.comparison.active_block()
        if rows.size == 0:
            return np.zeros(n)
        d = (cols[None, :] - rows[:, None]) % n
        return np.bincount(d.ravel(), weights=block.ravel().astype(np.float64), minlength=n)

    def run(self, dataset, *, record: bool = False):
        """Process every sample of a :class:`~touchloc.dnf.RotationDataset`.

        Returns
        -------
        orientation : (T,) float
            Corrected estimate after each sample.
        memory : (T, n_sites) float or None
            Memory trace after each sample if ``record``.
        """
        if not (callable(getattr(dataset, "samples", None)) and hasattr(dataset, "__len__")):
            raise ValidationError(f"dataset must be a RotationDataset (samples() and len()), got {type(dataset).__name__}")
        record = as_bool(record, "record")
        T = len(dataset)
        est = np.empty(T)
        mem = np.empty((T, self.n_sites)) if record else None
        for t, (a, odo) in enumerate(dataset.samples()):
            self.odometry = odo
            self._step(a)
            est[t] = self.orientation
            if record:
                mem[t] = self.trace.P
        return est, mem
