"""OrientationTracker (seed 000, Fig. 2): validation, correction sign, and the seed's result
on simulated data sets (one per object: full model right, baselines worse)."""

import numpy as np
import pytest

from touchloc.dnf import HistogramEstimator, OrientationTracker, count_surfaces, generate_rotation_dataset
from touchloc.dnf.compare import orientation_error, run_estimator
from touchloc.errors import ValidationError

DEG = np.pi / 180


@pytest.fixture(scope="module")
def datasets():
    return {n: generate_rotation_dataset(n, rng=np.random.default_rng([7, n])) for n in (6, 8, 0)}


@pytest.mark.parametrize("bad, match", [
    ([np.nan, 0.1], "entry 0 is nan"),
    (np.zeros((2, 3)), r"1-D array \(K,\)"),
    ("abc", "angles in rad"),
])
def test_step_rejects_bad_normal_angles(bad, match):
    with pytest.raises(ValidationError, match=match):
        OrientationTracker().step(bad, 0.0)


def test_step_rejects_bad_odometry_and_unknown_parameters():
    with pytest.raises(ValidationError, match="odometry"):
        OrientationTracker().step([0.1], float("inf"))
    with pytest.raises(ValidationError, match="odometry"):
        OrientationTracker().step([0.1], "x")
    with pytest.raises(ValidationError, match="unknown tracker parameters"):
        OrientationTracker(gain=3)


def _regular_samples(n_sides, n_samples, offset=0.0, rng=None):
    """A hexagon turned 4 deg per sample, both fingers on opposite sides, exact odometry
    (plus ``offset`` from sample ``n_samples // 2`` on)."""
    rng = np.random.default_rng(rng)
    out = []
    for t in range(n_samples):
        theta = 4 * DEG * t
        stroke_start = theta - (4 * DEG) * (t % 8)
        side = np.round(-stroke_start / (2 * np.pi / n_sides)) * 2 * np.pi / n_sides
        world = side + theta + np.array([0.0, np.pi])
        a = np.repeat(world, 12) + rng.normal(0, 2 * DEG, 24)
        out.append((a, theta + (offset if t >= n_samples // 2 else 0.0)))
    return out


def test_exact_odometry_builds_n_sides_and_needs_no_correction():
    # without the prior's expected under-estimate, exact odometry is left as it is
    tr = OrientationTracker(rate_prior_mean=0.0)
    for a, odo in _regular_samples(6, 300, rng=1):
        tr.step(a, odo)
    assert count_surfaces(tr.memory) == 6
    assert abs(tr.correction) < 2 * DEG
    assert 0.5 < tr.memory.max() <= 1.0


def test_the_rate_prior_gives_way_to_exact_odometry():
    # the default prior expects a 5 % under-estimate; with exact odometry the learnt rate
    # must return to about 0, leaving only the frame offset taken up meanwhile (5 % of
    # about the first radian: 3 deg)
    tr = OrientationTracker()
    assert tr.rate == pytest.approx(0.05)
    for a, odo in _regular_samples(6, 300, rng=1):
        tr.step(a, odo)
    assert count_surfaces(tr.memory) == 6
    assert abs(tr.rate) < 0.005
    assert abs(tr.correction) < 5 * DEG
    # the uncorrected memory has no rate at all: it follows the odometry
    assert OrientationTracker(correct=False).rate == 0.0


def test_correction_removes_an_odometry_jump():
    # after the memory is built, the odometry jumps by +10 deg: the tracker must correct it
    tr = OrientationTracker()
    samples = _regular_samples(6, 400, offset=10 * DEG, rng=2)
    for a, odo in samples[:200]:
        tr.step(a, odo)
    c0 = tr.correction
    for a, odo in samples[200:]:
        tr.step(a, odo)
    assert tr.correction - c0 == pytest.approx(-10 * DEG, abs=2 * DEG)
    assert count_surfaces(tr.memory) == 6
    # without correction the estimate keeps the jump
    un = OrientationTracker(correct=False)
    for a, odo in samples:
        un.step(a, odo)
    assert un.correction == 0.0 and un.orientation == samples[-1][1]


def test_reset_forgets_everything():
    tr = OrientationTracker()
    for a, odo in _regular_samples(6, 60, rng=3):
        tr.step(a, odo)
    assert tr.memory.max() > 0
    assert tr._detections.max() > 0
    tr.reset()
    assert tr.memory.max() == 0 and tr.correction == 0 and tr.n_steps == 0
    assert np.all(tr.surface.u == tr.params.surface.h)
    assert tr._detections.max() == 0 and tr._detections_hand.max() == 0 and tr._detection_samples == 0


def _two_bumps(tr, strong=1.0, weak=0.8, apart_deg=12.0):
    """The memory holding a side at 90 deg and a weaker copy ``apart_deg`` beside it."""
    x = np.degrees(tr.angles)
    P = tr.trace.P
    P[:] = strong * np.exp(-0.5 * ((x - 90.0) / 4.0) ** 2)
    P[:] = np.maximum(P, weak * np.exp(-0.5 * ((x - 90.0 - apart_deg) / 4.0) ** 2))


@pytest.mark.parametrize("split_decay, weak_kept", [(0.04, False), (0.0, True)])
def test_a_split_fades_and_a_side_does_not(split_decay, weak_kept):
    # a side remembered twice, 12 deg apart (the estimate moved between two writes), while
    # the fingers touch elsewhere: the weaker copy fades within 30 samples, the stronger
    # one only at the memory's own decay; with split_decay = 0 both stay sides
    tr = OrientationTracker(split_decay=split_decay)
    _two_bumps(tr)
    for _ in range(30):
        tr.step([np.radians(270.0)], 0.0)
    i_strong, i_weak = np.argmin(np.abs(np.degrees(tr.angles) - 90.0)), np.argmin(np.abs(np.degrees(tr.angles) - 102.0))
    assert tr.memory[i_strong] > 0.8
    assert (tr.memory[i_weak] > 0.6) == weak_kept
    near_pair = np.where(np.abs(np.degrees(tr.angles) - 96.0) < 30.0, tr.memory, 0.0)
    assert count_surfaces(near_pair) == (2 if weak_kept else 1)
    assert tr.correction == 0.0          # nothing to match: the estimate stayed put


def test_the_uncorrected_memory_keeps_its_splits():
    # seed 000's baseline: without a correction the split decay is off
    tr = OrientationTracker(correct=False)
    _two_bumps(tr)
    for _ in range(30):
        tr.step([np.radians(270.0)], 0.0)
    assert tr.memory[np.argmin(np.abs(np.degrees(tr.angles) - 102.0))] > 0.6


def test_sides_farther_apart_than_a_split_do_not_fade():
    # two sides 30 deg apart (a 12-gon's spacing) are both kept at the memory's own decay
    tr = OrientationTracker()
    _two_bumps(tr, apart_deg=30.0)
    for _ in range(30):
        tr.step([np.radians(270.0)], 0.0)
    i_weak = np.argmin(np.abs(np.degrees(tr.angles) - 120.0))
    assert tr.memory[i_weak] > 0.7


def test_seed_result_on_simulated_data(datasets):
    """Seed 000, Fig. 6/7: full model right on the n-gons and 0 on the round object; the
    histogram and the uncorrected memory clearly worse."""
    makers = {"hist": lambda: HistogramEstimator(), "uncorrected": lambda: OrientationTracker(correct=False),
              "full": lambda: OrientationTracker()}
    acc = {(n, k): run_estimator(k, m, ds).accuracy for n, ds in datasets.items() for k, m in makers.items()}
    for n in (6, 8):
        assert acc[n, "full"] >= 0.9
        assert acc[n, "hist"] <= 0.5 and acc[n, "uncorrected"] <= 0.5
    assert acc[0, "full"] == 1.0                    # 0 sides on the round object
    assert acc[0, "hist"] <= 0.5                    # the histogram finds false sides


def test_orientation_error_is_wrapped_to_the_symmetry():
    e = orientation_error([0.0, 61 * DEG, -31 * DEG], [0.0, 0.0, 0.0], 6)
    np.testing.assert_allclose(np.degrees(e), [0.0, 1.0, 29.0], atol=1e-9)
    e0 = orientation_error([3.5], [0.0], 0)
    assert e0[0] == pytest.approx(3.5 - 2 * np.pi)


def test_active_block_comparison_field_reproduces_exact_fft_field():
    ds = generate_rotation_dataset(8, revolutions=1.5, rng=5)
    fast, exact = OrientationTracker(), OrientationTracker()
    exact.comparison.method = "fft"
    for a, odo in ds.samples():
        fast.step(a, odo)
        exact.step(a, odo)
        assert abs(fast.correction - exact.correction) < 1e-3 * DEG
    assert abs(exact.correction) > 1 * DEG          # the comparison did correct something
    np.testing.assert_allclose(fast.comparison.u, exact.comparison.u, atol=1e-3)
    np.testing.assert_allclose(fast.memory, exact.memory, atol=1e-4)


def test_run_matches_step_by_step():
    ds = generate_rotation_dataset(6, revolutions=0.5, rng=9)
    a, b = OrientationTracker(), OrientationTracker()
    est, mem = a.run(ds, record=True)
    for t, (ang, odo) in enumerate(ds.samples()):
        assert b.step(ang, odo) == pytest.approx(est[t], abs=1e-12)
    np.testing.assert_allclose(mem[-1], b.memory)


def test_the_odometrys_under_estimate_is_learnt():
    from touchloc.dnf import generate_rotation_dataset

    # the odometry reports 92 % of each turn: the right rate is 0.08 / 0.92 = 0.087 per radian
    ds = generate_rotation_dataset(6, revolutions=3.0, under_estimate=(0.08, 0.08), slip_std=0.0, rng=0)
    samples = list(ds.samples())
    rates = {}
    for mode in ("mean", "integral"):
        tr = OrientationTracker(rate_mode=mode)
        for a, odo in samples[:100]:             # about one turn
            tr.step(a, odo)
        early = tr.rate
        for a, odo in samples[100:]:
            tr.step(a, odo)
        rates[mode] = (early, tr.rate)
    # both learn it; the mean correction per radian (the default) learns it faster
    assert 0.06 < rates["mean"][1] < 0.11
    assert 0.02 < rates["integral"][1] < 0.11
    assert rates["mean"][0] > 0.035 and rates["mean"][0] > 2 * rates["integral"][0]
    for off in (OrientationTracker(rate_mode="off"), OrientationTracker(rate_mode="integral", rate_gain=0.0)):
        off.run(ds)
        assert off.rate == 0.0
    tr.reset()
    assert tr.rate == 0.0


@pytest.mark.parametrize("bad, match", [
    (dict(rate_mode="fast"), "rate_mode must be"),
    (dict(rate_prior=0.0), "rate_prior must be > 0"),
])
def test_rate_learning_parameters_are_validated(bad, match):
    with pytest.raises(ValidationError, match=match):
        OrientationTracker(**bad)
