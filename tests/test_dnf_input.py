"""The tracker's input stage: independent of the number of normals per sample, samples
without contact are valid, and the seed-faithful generator's knobs do what they say."""

import numpy as np
import pytest

from touchloc.dnf import (SEED_FAITHFUL, HistogramEstimator, OrientationTracker, ParticleOrientationEstimator,
                          generate_rotation_dataset, population_code, save_recording, load_recording)
from touchloc.errors import ValidationError

DEG = np.pi / 180


def test_normalised_code_does_not_grow_with_the_number_of_normals():
    one = population_code([0.3], 360, 4 * DEG, 1.0, normalize=True)
    many = population_code(np.full(40, 0.3), 360, 4 * DEG, 1.0, normalize=True)
    np.testing.assert_allclose(one, many, rtol=1e-12)
    summed = population_code(np.full(40, 0.3), 360, 4 * DEG, 1.0)
    assert summed.max() == pytest.approx(40 * one.max())
    assert not np.any(population_code([], 360, 4 * DEG, 1.0, normalize=True))


def _mean_stimulus(k, rng):
    """Window-averaged input of a tracker fed k noisy normals per sample of one side."""
    tr = OrientationTracker(correct=False)
    rng = np.random.default_rng(rng)
    for _ in range(60):
        tr.step(rng.normal(1.0, 3 * DEG, k), 0.0)
    return tr._evidence / max(tr._weight, 1.0)


def test_evidence_is_the_same_for_1_and_40_normals_per_sample():
    e1 = np.mean([_mean_stimulus(1, s) for s in range(8)], axis=0)
    e40 = _mean_stimulus(40, 0)
    # same expected input: peak heights within 10 % and both at the side (1 rad)
    assert e1.max() == pytest.approx(e40.max(), rel=0.1)
    sites = np.arange(360) * DEG
    assert abs(sites[np.argmax(e1)] - 1.0) < 3 * DEG and abs(sites[np.argmax(e40)] - 1.0) < 3 * DEG


def test_a_sample_without_contact_is_valid_and_does_not_dilute_the_evidence():
    tr = OrientationTracker()
    for _ in range(10):
        tr.step([0.5, 0.5 + np.pi], 0.0)
    before = tr._evidence / tr._weight
    assert tr.step([], 0.0) == pytest.approx(tr.orientation)
    after = tr._evidence / max(tr._weight, 1.0)
    np.testing.assert_allclose(after, before, rtol=1e-9)
    for _ in range(40):                         # a long gap: the evidence fades
        tr.step(np.empty(0), 0.0)
    assert (tr._evidence / max(tr._weight, 1.0)).max() < 0.01 * before.max()
    # the baselines accept it too
    assert HistogramEstimator().step([], 0.3) == 0.3
    ParticleOrientationEstimator(20, rng=0).step([], 0.0)


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
