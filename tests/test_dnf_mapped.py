"""The third family of the DNF comparison: the rotating n-gon mapped in 3-D by tactile SLAM."""

import numpy as np
import pytest

from touchloc.dnf import count_surfaces, generate_rotation_dataset
from touchloc.dnf.compare import MAPPED, default_estimators, orientation_error, run_estimator
from touchloc.experiments.ngon import (MappedPrismEstimator, estimators_with_map, prism_mesh,
                                      section_normal_density)
from touchloc.errors import ValidationError


def _polygon_radius(n, n_rays=360, r=0.03):
    """Radius along evenly spaced rays of a regular n-gon with circumradius r (corners at 2 pi j / n)."""
    phi = np.arange(n_rays) * 2 * np.pi / n_rays
    half = np.pi / n
    rel = (phi % (2 * half)) - half            # angle from the nearest side's normal
    return r * np.cos(half) / np.cos(rel)


def test_section_density_is_flat_for_a_circle_and_peaks_at_each_side():
    circle = section_normal_density(np.full(180, 0.03))
    np.testing.assert_allclose(circle, 1.0, atol=0.15)     # 180 segments in 360 bins: a ripple
    assert count_surfaces(np.clip(circle / 4.0, 0, 1)) == 0
    for n in (4, 5, 6, 8):
        dens = section_normal_density(_polygon_radius(n))
        assert count_surfaces(np.clip(dens / 4.0, 0, 1)) == n
    assert section_normal_density(np.full(10, np.nan)).max() == 0.0


def _outline_radius(vertices, n_rays=180):
    """Radius along evenly spaced rays of a star-shaped polygon about the origin."""
    v = np.asarray(vertices)
    phi = np.arange(n_rays) * 2 * np.pi / n_rays
    u = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    r = np.full(n_rays, np.inf)
    for a, b in zip(v, np.roll(v, -1, axis=0)):
        e = b - a
        det = u[:, 1] * e[0] - u[:, 0] * e[1]          # ray s u meets a + t e
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (a[1] * e[0] - a[0] * e[1]) / det
            t = (u[:, 0] * a[1] - u[:, 1] * a[0]) / det
        hit = (s > 0) & (t >= 0) & (t <= 1)
        r[hit] = np.minimum(r[hit], s[hit])
    return r


def test_a_face_mapped_as_two_facets_counts_once():
    # a hexagon whose first face bulges into two facets 10 deg apart, as the map's Gaussian
    # process bends a 30 mm face: the count's own 3 deg smoothing reads a seventh side, the
    # estimator's smoothing (5 deg) one face; a plain hexagon and octagon keep their counts
    est = MappedPrismEstimator()
    ang = np.arange(6) * np.pi / 3
    corners = list(0.03 * np.stack([np.cos(ang), np.sin(ang)], axis=1))
    mid = 0.5 * (corners[0] + corners[1])
    half = 0.5 * np.linalg.norm(corners[1] - corners[0])
    bent = corners[:1] + [mid * (1 + half * np.tan(np.radians(5.0)) / np.linalg.norm(mid))] + corners[1:]

    def count(r, sigma):
        return count_surfaces(np.clip(section_normal_density(r, sigma=sigma) / est.flat_ratio, 0, 1))

    assert count(_outline_radius(bent), np.radians(3.0)) == 7
    assert count(_outline_radius(bent), est.smoothing) == 6
    assert count(_outline_radius(corners), est.smoothing) == 6
    assert count(_polygon_radius(8, n_rays=180), est.smoothing) == 8


def test_prism_mesh_has_n_side_normals():
    obj = prism_mesh(6, diameter=0.05, height=0.04)
    nz = obj.mesh.face_normals
    side = np.abs(nz[:, 2]) < 1e-6
    ang = np.unique(np.round(np.degrees(np.arctan2(nz[side, 1], nz[side, 0])) % 360, 3))
    assert ang.size == 6
    with pytest.raises(ValidationError):
        prism_mesh(2)
    with pytest.raises(ValidationError):
        prism_mesh(6, diameter=-1.0)


def test_mapped_prism_counts_sides_and_corrects_the_odometry():
    # eight data sets: with the count's own 3 deg smoothing a face mapped as two facets read
    # as a seventh side in 7-84 % of a set's second half on four of them (right 59 % pooled on
    # an AMD EPYC, and the share moved with the CPU that sums the likelihood); with the
    # estimator's 5 deg every set was right throughout on that machine
    halves = []
    for s in range(2, 10):
        ds = generate_rotation_dataset(6, revolutions=1.5, under_estimate=(0.08, 0.08), slip_std=0.0, rng=s)
        run = run_estimator(MAPPED, lambda: MappedPrismEstimator(every=3, rng=0), ds)
        halves.append(np.asarray(run.counts[len(run.counts) // 2:]))
        # the odometry under-estimates by 8 %: 43 deg after 1.5 turns, wrapped to the 60 deg
        # symmetry (17-23 deg here); the map's estimate is within 3-6 deg
        odo = np.abs(orientation_error(ds.odometry, ds.true_orientation, 6))[-20:]
        est = np.abs(run.error)[-20:]
        assert np.median(odo) > np.radians(12)
        assert np.median(est) < 0.5 * np.median(odo)
    assert min(np.mean(h == 6) for h in halves) >= 0.75
    assert np.mean(np.concatenate(halves) == 6) >= 0.95


def test_round_cylinder_maps_no_sides():
    ds = generate_rotation_dataset(0, revolutions=1.0, rng=5)
    run = run_estimator(MAPPED, lambda: MappedPrismEstimator(every=3, rng=0), ds)
    assert run.counts[-1] == 0


def test_mapped_family_joins_on_request_and_checks_its_input():
    assert MAPPED not in default_estimators()
    assert MAPPED in estimators_with_map(rng=0)
    est = MappedPrismEstimator()
    with pytest.raises(ValidationError, match="bind"):
        est.step([0.1], 0.0)
    ds = generate_rotation_dataset(4, revolutions=0.2, rng=1)
    ds.true_orientation = None
    with pytest.raises(ValidationError, match="true_orientation"):
        est.bind(ds)
    with pytest.raises(ValidationError):
        MappedPrismEstimator(every=0)
    with pytest.raises(ValidationError):
        MappedPrismEstimator(flat_ratio=1.0)
    for bad in (-0.01, np.pi, float("nan"), "5"):
        with pytest.raises(ValidationError, match="smoothing"):
            MappedPrismEstimator(smoothing=bad)
    with pytest.raises(ValidationError, match="fingers"):
        MappedPrismEstimator(fingers=np.zeros(100))
