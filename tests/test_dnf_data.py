"""Rotation data sets: the simulated experiment of seed 000 (section IV) and the
CSV/NPZ recording format."""

import numpy as np
import pytest

from touchloc.dnf import (RotationDataset, generate_rotation_dataset, load_recording, save_recording,
                          standard_datasets)
from touchloc.errors import ValidationError

DEG = np.pi / 180


@pytest.fixture(scope="module")
def hexagon():
    return generate_rotation_dataset(6, rng=11)


def test_generated_experiment_matches_section_iv(hexagon):
    ds = hexagon
    turns = ds.true_orientation[-1] / (2 * np.pi)
    assert 4.0 <= turns < 4.2                                   # four times 360 degrees
    rate = 1 / np.diff(ds.time)
    assert rate.min() >= 2.0 - 1e-9 and rate.max() <= 3.0 + 1e-9  # 2-3 Hz
    # the odometry systematically under-estimates the rotation (4-8 %)
    ratio = ds.odometry[-1] / ds.true_orientation[-1]
    assert 0.9 < ratio < 0.97
    assert ds.n_surfaces == 6 and len(ds) == ds.true_orientation.size
    # contacts on sides are sharp: in the object frame (true orientation) most normals lie
    # within 6 deg of a side normal (multiples of 60 deg)
    obj = ds.normal_angles - ds.true_orientation[ds.sample_index]
    dist = np.abs((obj + np.pi / 6) % (np.pi / 3) - np.pi / 6)
    assert np.mean(dist < 6 * DEG) > 0.6
    # but edges add a broad spread
    assert np.mean(dist > 15 * DEG) > 0.05


def test_generator_is_reproducible_and_seeds_differ():
    a = generate_rotation_dataset(8, rng=5)
    b = generate_rotation_dataset(8, rng=5)
    c = generate_rotation_dataset(8, rng=6)
    np.testing.assert_array_equal(a.normal_angles, b.normal_angles)
    assert len(a) != len(c) or not np.array_equal(a.normal_angles, c.normal_angles)


@pytest.mark.parametrize("per_contact", [None, 2])
def test_without_edge_normals_only_the_edge_landings_go(per_contact):
    kw = dict(revolutions=2, normals_per_contact=per_contact, noise=3 * DEG, drop=0.1)
    if per_contact:
        kw["normal_source"] = "pad"
    full = generate_rotation_dataset(8, rng=4, **kw)
    sides = generate_rotation_dataset(8, rng=4, edge_normals=False, **kw)
    # the same experiment: samples, odometry and truth; the normals a subset
    assert len(full) == len(sides)
    np.testing.assert_array_equal(full.odometry, sides.odometry)
    np.testing.assert_array_equal(full.true_orientation, sides.true_orientation)
    assert 0 < sides.normal_angles.size < 0.9 * full.normal_angles.size
    assert np.isin(sides.normal_angles, full.normal_angles).all()

    def far_from_sides(ds):
        obj = ds.normal_angles - ds.true_orientation[ds.sample_index]
        return np.mean(np.abs((obj + np.pi / 8) % (np.pi / 4) - np.pi / 8) > 14 * DEG)
    # what goes is the broad spread of the edges (an 8-gon's reach 18 deg from the edge,
    # 4.5 deg from a side); 14 deg is more than 3 sd of a side's normals here
    assert far_from_sides(full) > 0.08
    assert far_from_sides(sides) < 0.01
    # a round object has no edges: nothing changes
    np.testing.assert_array_equal(generate_rotation_dataset(0, rng=4, edge_normals=False, **kw).normal_angles,
                                  generate_rotation_dataset(0, rng=4, **kw).normal_angles)
    with pytest.raises(ValidationError, match="edge_normals"):
        generate_rotation_dataset(8, edge_normals="no")


def test_round_object_normals_sweep_through_the_object_frame():
    ds = generate_rotation_dataset(0, rng=2)
    obj = (ds.normal_angles - ds.true_orientation[ds.sample_index]) % (2 * np.pi)
    hist = np.histogram(obj, bins=12, range=(0, 2 * np.pi))[0]
    assert hist.min() > 0.4 * hist.mean()                       # no preferred orientation


def test_standard_datasets_shape():
    sets = standard_datasets(["6-gon", "round"], 2, revolutions=0.5)
    assert list(sets) == ["6-gon", "round"] and all(len(v) == 2 for v in sets.values())
    assert sets["round"][0].n_surfaces == 0
    with pytest.raises(ValidationError, match="unknown object"):
        standard_datasets(["7-gon"])


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_recording_round_trip(tmp_path, suffix):
    ds = generate_rotation_dataset(6, revolutions=0.5, rng=3)
    path = save_recording(ds, tmp_path / f"rec{suffix}")
    back = load_recording(path)
    assert len(back) == len(ds) and back.n_surfaces == 6 and back.name == ds.name
    np.testing.assert_allclose(back.normal_angles, ds.normal_angles, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.odometry, ds.odometry, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.sample_index, ds.sample_index)
    np.testing.assert_allclose(back.true_orientation, ds.true_orientation)
    for (a1, o1), (a2, o2) in zip(back.samples(), ds.samples()):
        assert o1 == pytest.approx(o2) and a1.shape == a2.shape


def test_minimal_csv_without_ground_truth(tmp_path):
    p = tmp_path / "mine.csv"
    p.write_text("time,odometry,normal_angle\n0.0,0.0,0.1\n0.0,0.0,0.12\n0.4,0.05,0.2\n")
    ds = load_recording(p)
    assert len(ds) == 2 and ds.true_orientation is None and ds.n_surfaces is None
    np.testing.assert_allclose(ds.angles(0), [0.1, 0.12])


@pytest.mark.parametrize("text, match", [
    ("", "no samples"),
    ("time,odometry\n0,0\n", "lacks column 'normal_angle'"),
    ("time,odometry,normal_angle\n0,0,nan\n", "finite"),
    ("time,odometry,normal_angle\n0,0,0.1\n0,0.2,0.1\n", "share the odometry"),
    ("time,odometry,normal_angle\n0,0,abc\n", "must be a number"),
])
def test_loader_rejects_bad_csv(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(ValidationError, match=match):
        load_recording(p)


def test_loader_rejects_missing_file_and_bad_suffix(tmp_path):
    with pytest.raises(ValidationError, match="no recording"):
        load_recording(tmp_path / "nope.csv")
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(ValidationError, match=r"\.csv or \.npz"):
        load_recording(tmp_path / "x.txt")
    np.savez(tmp_path / "y.npz", time=np.zeros(1))
    with pytest.raises(ValidationError, match="lacks arrays"):
        load_recording(tmp_path / "y.npz")


def test_dataset_validation():
    # a sample without normals (no contact) is valid
    empty = RotationDataset([0, 1], [0, 0], [0.1], [0])
    assert empty.angles(1).size == 0 and [a.size for a, _ in empty.samples()] == [1, 0]
    with pytest.raises(ValidationError, match="odometry must have shape"):
        RotationDataset([0, 1], [0], [0.1, 0.2], [0, 1])
    with pytest.raises(ValidationError, match="n_sides"):
        generate_rotation_dataset(2)
