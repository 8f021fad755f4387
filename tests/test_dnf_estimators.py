"""count_surfaces (seed 000's rule), the histogram baseline and the particle filter."""

import numpy as np
import pytest

from touchloc.dnf import HistogramEstimator, count_surfaces, generate_rotation_dataset, surface_peaks
from touchloc.dnf.compare import run_estimator
from touchloc.dnf.particle import ParticleOrientationEstimator
from touchloc.errors import ValidationError

DEG = np.pi / 180
X = np.arange(360) * DEG


def bumps(centers_deg, amp=0.7, width_deg=3.0):
    out = np.zeros(360)
    for c in centers_deg:
        d = (X - c * DEG + np.pi) % (2 * np.pi) - np.pi
        out += amp * np.exp(-0.5 * (d / (width_deg * DEG)) ** 2)
    return out


def test_count_surfaces_counts_peaks_above_threshold():
    assert count_surfaces(bumps(range(0, 360, 60))) == 6
    assert count_surfaces(bumps(range(0, 360, 45))) == 8
    assert count_surfaces(np.zeros(360)) == 0
    assert count_surfaces(bumps([100], amp=0.35)) == 0                 # below 0.4
    np.testing.assert_allclose(np.degrees(surface_peaks(bumps([30, 200]))), [30, 200])


def test_count_surfaces_periodic_and_smoothing():
    # a peak straddling 0 deg counts once, at 0
    a = bumps([0.0])
    assert count_surfaces(a) == 1 and surface_peaks(a)[0] == 0.0
    # noise ripples on a peak are smoothed away (seed 000: "remove local optima")
    noisy = bumps([90]) + 0.08 * np.cos(np.arange(360) * np.pi / 2)
    assert count_surfaces(noisy, sigma=0.0) > 1
    assert count_surfaces(noisy) == 1
    # other resolutions: sigma is in rad, not in sites
    assert count_surfaces(bumps(range(0, 360, 60))[::3]) == 6
    with pytest.raises(ValidationError, match="1-D array"):
        count_surfaces(np.zeros((3, 360)))
    with pytest.raises(ValidationError, match="finite"):
        count_surfaces(np.full(360, np.nan))


def test_histogram_estimator_accumulates_in_the_odometry_frame():
    h = HistogramEstimator(360)
    h.step([10 * DEG, 10.2 * DEG], 0.0)
    h.step([30.3 * DEG], 20 * DEG)                  # object frame: 10.3 deg
    assert h.counts[10] == 3 and h.counts.sum() == 3
    assert h.memory.max() == 1.0 and h.orientation == 20 * DEG
    with pytest.raises(ValidationError):
        h.step([np.inf], 0.0)


def test_particle_filter_is_reproducible_and_maps_sides_without_drift():
    # exact odometry: the particle filter must find the six sides
    ds = generate_rotation_dataset(6, revolutions=2, under_estimate=(0.0, 0.0), slip_std=0.0, rng=4)
    r1 = run_estimator("pf", lambda: ParticleOrientationEstimator(100, rng=1), ds)
    r2 = run_estimator("pf", lambda: ParticleOrientationEstimator(100, rng=1), ds)
    np.testing.assert_array_equal(r1.orientation, r2.orientation)
    assert r1.accuracy >= 0.9
    # the map has no absolute frame, so the offset may wander a little together with it
    # (measured 3.8 deg RMS here); a lost filter would be off by up to 30 deg
    assert np.degrees(np.sqrt(np.mean(r1.error ** 2))) < 6


def test_particle_filter_state_and_validation():
    pf = ParticleOrientationEstimator(50, 72, rng=0)
    pf.step([0.1, 0.11, 0.12], 0.0)
    assert pf.maps.shape == (50, 72) and pf.maps.sum() == pytest.approx(50 * 3)
    assert np.exp(pf.log_weights).sum() == pytest.approx(1.0)
    assert 1 <= pf.ess() <= 50
    with pytest.raises(ValidationError, match="n_particles"):
        ParticleOrientationEstimator(0)
    with pytest.raises(ValidationError, match="forget"):
        ParticleOrientationEstimator(forget=1.0)
    with pytest.raises(ValidationError, match="scale_range"):
        ParticleOrientationEstimator(scale_range=(0.2, 0.1))


def test_particle_filter_scale_error_moves_offsets_with_the_odometry():
    pf = ParticleOrientationEstimator(20, drift_std=1e-9, scale_range=(0.1, 0.1), rng=0)
    pf.step([0.1], 0.0)
    pf.step([0.1], 1.0)
    np.testing.assert_allclose(pf.offsets, 0.1, atol=1e-6)    # k * change of odometry
    # a sample without contact is valid: the offsets still follow the odometry
    pf.step([], 2.0)
    np.testing.assert_allclose(pf.offsets, 0.2, atol=1e-6)


def test_run_estimator_loads_the_trackers_kernel_before_its_first_timed_step():
    """The time per step must not hold the compiled comparison step's compile (seconds, once
    per install) or load: in a fresh process, the kernel already has its signature when the
    tracker's first step is called."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        from touchloc.dnf import OrientationTracker, generate_rotation_dataset
        from touchloc.dnf import _kernels
        from touchloc.dnf.compare import run_estimator

        seen = []
        step = OrientationTracker.step

        def first(self, a, odo):
            if not seen:
                seen.append(len(_kernels.ridge_step.signatures))
            return step(self, a, odo)

        OrientationTracker.step = first
        assert not _kernels.ridge_step.signatures
        run = run_estimator("dnf", OrientationTracker, generate_rotation_dataset(6, revolutions=0.3, rng=1))
        print(seen[0], len(run.counts))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    kernels, samples = map(int, r.stdout.split())
    assert kernels >= 1 and samples > 5
