"""The tracker's input stage: independent of the number of normals per sample, samples
without contact are valid, and the seed-faithful generator's knobs do what they say."""

import numpy as np
import pytest

from touchloc.dnf import (SEED_FAITHFUL, HistogramEstimator, count_surfaces, OrientationTracker, ParticleOrientationEstimator,
                          generate_rotation_dataset, population_code, run_estimator, save_recording, load_recording)
from touchloc.errors import ValidationError

DEG = np.pi / 180


def test_normalised_code_does_not_grow_with_the_number_of_normals():
    one = population_code([0.3], 360, 4 * DEG, 1.0, normalize=True)
    many = population_code(np.full(40, 0.3), 360, 4 * DEG, 1.0, normalize=True)
    np.testing.assert_allclose(one, many, rtol=1e-12)
    summed = population_code(np.full(40, 0.3), 360, 4 * DEG, 1.0)
    assert summed.max() == pytest.approx(40 * one.max())
    assert not np.any(population_code([], 360, 4 * DEG, 1.0, normalize=True))


def test_expected_code_is_the_same_for_1_and_40_normals_per_sample():
    rng = np.random.default_rng(0)
    codes = {k: np.mean([population_code(rng.normal(1.0, 3 * DEG, k), 360, 4 * DEG, 1.0, normalize=True)
                         for _ in range(400)], axis=0) for k in (1, 40)}
    # same expected input (the tuning curve smoothed by the 3 deg noise: peak 4/5 = 0.8)
    assert codes[1].max() == pytest.approx(codes[40].max(), rel=0.05)
    assert codes[40].max() == pytest.approx(0.8, rel=0.05)
    sites = np.arange(360) * DEG
    assert all(abs(sites[np.argmax(c)] - 1.0) < 2 * DEG for c in codes.values())


def _windowed(k, rng):
    tr = OrientationTracker(correct=False, input_window=8.0)
    rng = np.random.default_rng(rng)
    for _ in range(60):
        tr.step(rng.normal(1.0, 3 * DEG, k), 0.0)
    return tr._evidence / max(tr._weight, 1.0)


def test_evidence_window_averages_to_the_same_input_for_1_and_40_normals():
    e1 = np.mean([_windowed(1, s) for s in range(6)], axis=0)
    e40 = _windowed(40, 0)
    assert e1.max() == pytest.approx(e40.max(), rel=0.15)


def _turning_sides(tr, n, deg_per_sample=4.0):
    """Two opposite sides (object frame 0.5 and 0.5 + pi) turned with exact odometry."""
    for t in range(n):
        theta = deg_per_sample * DEG * t
        tr.step(np.array([0.5, 0.5 + np.pi]) + theta, theta)
    return theta


def test_a_sample_without_contact_is_valid():
    tr = OrientationTracker()
    theta = _turning_sides(tr, 40)
    assert tr.memory.max() > 0.9 and count_surfaces(tr.memory) == 2
    u, mem, corr = tr.surface.u.copy(), tr.memory.copy(), tr.correction
    # follows the odometry (at the learnt rate)
    assert tr.step([], theta + 0.1) == pytest.approx(theta + 0.1 + corr + 0.1 * tr.rate, abs=1e-12)
    np.testing.assert_array_equal(tr.surface.u, u)                        # no evidence: nothing changes
    np.testing.assert_array_equal(tr.memory, mem)
    # the fields may relax instead (hold_empty=False); the memory keeps its shape
    tr = OrientationTracker(hold_empty=False)
    theta = _turning_sides(tr, 40)
    u = tr.surface.u.copy()
    tr.step(np.empty(0), theta)
    assert tr.surface.u.max() < u.max()
    mem = tr.memory.copy()
    tr.step(np.empty(0), theta)
    assert np.abs(tr.memory - mem).max() < 0.05
    # the baselines accept it too
    assert HistogramEstimator().step([], 0.3) == 0.3
    ParticleOrientationEstimator(20, rng=0).step([], 0.0)


def test_hand_field_keeps_a_round_objects_sliding_normal_out_of_the_memory():
    # a round object: the normals point at the two fingers (fixed in the world frame) while
    # the object turns 2.5 deg per sample, so they slide through the object frame
    def round_object(**kw):
        tr = OrientationTracker(**kw)
        rng = np.random.default_rng(0)
        for t in range(200):
            tr.step(np.repeat([0.0, np.pi], 2) + rng.normal(0.0, 3 * DEG, 4), 2.5 * DEG * t)
        return tr
    assert count_surfaces(round_object().memory) == 0
    assert round_object().memory.max() < 0.3
    assert count_surfaces(round_object(hand_to_map=0.0).memory) > 0     # without it, phantom sides
    # flat sides, which turn with the object, are mapped either way
    for kw in ({}, {"hand_to_map": 0.0}):
        tr = OrientationTracker(**kw)
        _turning_sides(tr, 40)
        assert count_surfaces(tr.memory) == 2


def test_with_a_window_an_empty_sample_does_not_dilute_the_evidence():
    tr = OrientationTracker(input_window=4.0, hold_empty=False)
    for _ in range(10):
        tr.step([0.5, 0.5 + np.pi], 0.0)
    before = tr._evidence / tr._weight
    tr.step([], 0.0)
    np.testing.assert_allclose(tr._evidence / max(tr._weight, 1.0), before, rtol=1e-9)
    for _ in range(40):                         # a long gap: the evidence fades
        tr.step(np.empty(0), 0.0)
    assert (tr._evidence / max(tr._weight, 1.0)).max() < 0.01 * before.max()
    with pytest.raises(ValidationError, match="input_window"):
        OrientationTracker(input_window=-1.0)


def test_generator_default_is_the_dense_setting_and_knobs_validate():
    ds = generate_rotation_dataset(6, revolutions=0.5, rng=3)
    counts = np.bincount(ds.sample_index, minlength=len(ds))
    assert set(np.unique(counts)) <= {12, 18, 24}             # 12 per side, 6 per edge, two fingers
    with pytest.raises(ValidationError, match="normals_per_contact"):
        generate_rotation_dataset(6, normals_per_contact=41)
    with pytest.raises(ValidationError, match="drop"):
        generate_rotation_dataset(6, drop=1.0)
    with pytest.raises(ValidationError, match="normal_source"):
        generate_rotation_dataset(6, normal_source="object")


def test_seed_faithful_generator_counts_drops_and_noise(tmp_path):
    ds = generate_rotation_dataset(8, rng=4, **dict(SEED_FAITHFUL, drop=0.2))
    counts = np.bincount(ds.sample_index, minlength=len(ds))
    assert set(np.unique(counts)) <= {0, 2, 3, 4}             # 1-2 blobs per finger, two fingers
    assert 0.12 < np.mean(counts == 0) < 0.28                 # about 20 % dropped
    # face normals: the pad adds centroid error / pad radius (1 mm / 2 cm = 2.9 deg) to the
    # 3 deg noise, so about 4.1 deg in all
    obj = ds.normal_angles - ds.true_orientation[ds.sample_index]
    dist = (obj + np.pi / 8) % (np.pi / 4) - np.pi / 8
    core = dist[np.abs(dist) < 10 * DEG]
    assert 3.0 * DEG < np.std(core) < 5.5 * DEG
    # a recording with empty samples survives a round trip
    back = load_recording(save_recording(ds, tmp_path / "r.npz"))
    np.testing.assert_array_equal(np.bincount(back.sample_index, minlength=len(back)), counts)


def test_odometry_bias_knob():
    ds = generate_rotation_dataset(6, rng=5, under_estimate=(0.1, 0.1), slip_std=0.0,
                                   normals_per_contact=1)
    ratio = (ds.odometry[-1] - ds.odometry[0]) / (ds.true_orientation[-1] - ds.true_orientation[0])
    assert ratio == pytest.approx(0.9, abs=0.01)


def test_csv_round_trip_keeps_samples_without_contact(tmp_path):
    ds = generate_rotation_dataset(5, revolutions=0.5, rng=6, normals_per_contact=1, drop=0.3)
    back = load_recording(save_recording(ds, tmp_path / "r.csv"))
    assert len(back) == len(ds)
    np.testing.assert_array_equal(back.sample_index, ds.sample_index)
    np.testing.assert_allclose(back.normal_angles, ds.normal_angles, atol=1e-12)


# -- spread normalisation ----------------------------------------------------------------
def test_contact_spreads_estimate_the_normals_spread_whatever_their_number():
    from touchloc.dnf import contact_spreads

    rng = np.random.default_rng(5)
    sigma = 4 * DEG
    for k in (2, 3, 10, 40):
        # three contacts a sample, one of them across 0 rad
        est = np.concatenate([contact_spreads(np.concatenate([rng.normal(c, sigma, k) for c in (0.0, 2.0, 4.0)]))
                              for _ in range(600)])
        assert est.size == 3 * 600           # one spread per contact, none split or merged
        assert np.median(est) == pytest.approx(sigma, rel=0.04)
    # the contact across 0 rad is one contact
    np.testing.assert_allclose(contact_spreads([-0.01, 0.01]), [0.02 / np.sqrt(2) / 0.6744897501960817], rtol=1e-9)
    # single normals and empty samples give no spread
    assert contact_spreads([0.1, 2.0, 4.0]).size == 0 and contact_spreads([]).size == 0
    with pytest.raises(ValidationError, match="gap"):
        contact_spreads([0.1, 0.2], gap=4.0)


def _six_degree_sets(n, count):
    return [generate_rotation_dataset(n, rng=np.random.default_rng([21, n, i]), normals_per_contact=2,
                                      noise=6 * DEG, drop=0.1, normal_source="pad") for i in range(count)]


def test_tracker_estimates_the_spread_on_remembered_sides_and_scales_its_gains():
    ds = _six_degree_sets(6, 1)[0]
    tr = OrientationTracker()
    tr.run(ds)
    # the generator's normals: 6 deg of noise on 1 mm / 2 cm of centroid error (2.9 deg)
    truth = np.hypot(6.0, np.degrees(0.001 / 0.02)) * DEG
    assert tr.noise == pytest.approx(truth, rel=0.15)
    w, ref = tr.params.tuning_width, tr.params.noise_ref
    assert tr._gain_scale == pytest.approx(np.sqrt((w**2 + tr.noise**2) / (w**2 + ref**2)))
    assert tr._correction_scale == pytest.approx((ref / tr.noise) ** 2) and tr._correction_scale < 1
    off = OrientationTracker(noise_ref=0.0)
    off.run(ds)
    assert off.noise == 0.0 and off._gain_scale == 1.0 and off._correction_scale == 1.0
    # below the reference spread the defaults stay
    quiet = OrientationTracker()
    quiet.run(generate_rotation_dataset(6, rng=1, normals_per_contact=2, noise=1 * DEG, normal_source="pad"))
    assert quiet.noise < ref and quiet._gain_scale == 1.0 and quiet._correction_scale == 1.0


def test_spread_normalisation_counts_the_sides_under_6_degrees_of_noise():
    """Four data sets each of the 6- and 8-gon with 6 deg of noise (seeds not used to set any
    parameter). Without the normalisation the memory misses sides; with it the right count
    rose by 0.29 on average over these sets (0.57 -> 0.85) when this test was written. The
    test asks for half of that. Both run without the detection evidence, which came later
    and by itself brings these sets to 0.93 with or without the normalisation."""
    on, off = [], []
    for n in (6, 8):
        for ds in _six_degree_sets(n, 4):
            on.append(run_estimator("on", lambda: OrientationTracker(detection_gain=0.0), ds).accuracy)
            off.append(run_estimator("off", lambda: OrientationTracker(noise_ref=0.0, detection_gain=0.0),
                                     ds).accuracy)
    assert np.mean(on) >= np.mean(off) + 0.15


@pytest.mark.parametrize("bad, match", [
    (dict(noise_ref=-0.1), "noise_ref"), (dict(noise_ref=np.nan), "noise_ref"),
    (dict(noise_window=0.5), "noise_window"), (dict(noise_min=1e7), "noise_min"),
    (dict(contact_gap=0.0), "contact_gap"), (dict(contact_gap=np.inf), "contact_gap"),
    (dict(normals_ref=-1.0), "normals_ref"), (dict(normals_ref=np.nan), "normals_ref"),
    (dict(detection_window=0.5), "detection_window"), (dict(detection_gain=-1.0), "detection_gain"),
    (dict(detection_start=0.0), "detection_start"), (dict(detection_start=np.nan), "detection_start"),
    (dict(detection_early_raise=-0.1), "detection_early_raise"),
    (dict(detection_early_raise=np.nan), "detection_early_raise"),
    (dict(detection_settle=0.5), "detection_settle"), (dict(detection_settle=np.inf), "detection_settle"),
    (dict(detection_gain=np.inf), "detection_gain"), (dict(detection_threshold=np.nan), "detection_threshold"),
    (dict(detection_blur=0.0), "detection_blur"), (dict(detection_blur=4.0), "detection_blur"),
    (dict(detection_hold_low=0.8), "detection_hold"), (dict(detection_hold_high=-1.0), "detection_hold"),
    (dict(detection_mute_low=0.5), "detection_mute"), (dict(detection_mute_high=-1.0), "detection_mute"),
    (dict(detection_mute_low=np.nan), "detection_mute"), (dict(detection_mute_high=np.inf), "detection_mute"),
    (dict(split_decay=-0.1), "split_decay"), (dict(split_decay=2.0), "split_decay"),
    (dict(split_near=0.0), "split_near"), (dict(split_near=0.4, split_far=0.3), "split_near"),
    (dict(split_far=4.0), "split_far"), (dict(split_far=np.nan), "split_far"),
])
def test_spread_normalisation_parameters_are_checked(bad, match):
    with pytest.raises(ValidationError, match=match):
        OrientationTracker(**bad)


def test_spread_normalisation_from_the_first_remembered_contact():
    # noise_min=0: the first contact on a remembered side already sets the gains; before
    # any, the defaults hold (and nothing fails on an empty window)
    tr = OrientationTracker(noise_min=0.0)
    tr.step([0.10, 0.16, 3.2, 3.3], 0.0)
    assert tr.noise == tr.params.noise_ref and tr._gain_scale == 1.0
    tr.trace.P[:] = 1.0                     # every side remembered
    tr.step([0.10, 0.40, 3.2, 3.5], 0.0)    # two contacts, each read as a spread of about 18 deg
    assert tr.noise > tr.params.noise_ref and tr._gain_scale > 1.0 and tr._correction_scale < 1.0


def test_the_correction_is_weighted_by_the_normals_per_contact():
    from touchloc.dnf.tracker import _contacts

    def n_contacts(a):
        return _contacts(np.array(a), 20 * DEG)[2]

    # contacts are split at gaps over contact_gap, also across 0 rad
    assert n_contacts([0.1, 0.12, 3.2, 3.25]) == 2 and n_contacts([-0.05, 0.05, 3.2]) == 2
    assert n_contacts([0.1, 1.0, 2.0, 3.0]) == 4 and n_contacts(np.linspace(0.0, 0.01, 40)) == 1
    assert n_contacts([1.0]) == 1 and n_contacts([]) == 0

    def weight(tr, a):
        return tr._count_weight(len(a), n_contacts(a))

    tr = OrientationTracker()
    one, two, forty = [0.1, 3.2], [0.1, 0.11, 3.2, 3.21], np.linspace(0.0, 0.01, 40)
    assert weight(tr, one) == 0.5 and weight(tr, two) == 1.0 and weight(tr, forty) == 1.0
    assert weight(OrientationTracker(normals_ref=0.0), one) == 1.0


def test_one_normal_per_finger_tracks_better_with_the_count_weight():
    """Four data sets of the 8-gon with one pad normal per finger (seeds not used to set any
    parameter): the weight halves each single-normal read-out's correction, so a landing
    on an edge, which one normal cannot tell from a side, pulls the estimate less. The
    right count was 0.71 without it and 0.98 with it when this test was written; the test
    asks for half of that gain. Both arms run without the split decay, which since lifts
    the arm without the weight to 0.92 (and the one with it to 0.95), and with the
    detection evidence's window of 150 samples (the seventeenth round's 300 gives 0.84
    without the weight and 0.96 with it)."""
    on, off = [], []
    for i in range(4):
        ds = generate_rotation_dataset(8, rng=np.random.default_rng([22, i]), normals_per_contact=1,
                                       noise=3 * DEG, drop=0.1, normal_source="pad")
        on.append(run_estimator("on", lambda: OrientationTracker(split_decay=0.0, detection_window=150.0),
                                ds).accuracy)
        off.append(run_estimator("off", lambda: OrientationTracker(normals_ref=0.0, split_decay=0.0,
                                                                   detection_window=150.0), ds).accuracy)
    assert np.mean(on) >= np.mean(off) + 0.13
