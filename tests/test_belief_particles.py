import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touchloc import geometry
from touchloc.belief import ParticleBelief, PoseRegion, systematic_resample
from touchloc.errors import BeliefDegenerateError, ValidationError


def gaussian_cloud(n, sd_t, sd_r, rng):
    v = np.concatenate([rng.normal(scale=sd_t, size=(n, 3)), rng.normal(scale=sd_r, size=(n, 3))], axis=1)
    return geometry.vector_to_pose(v)


def test_weights_are_normalised_in_log_space():
    P = np.repeat(np.eye(4)[None], 3, axis=0)
    b = ParticleBelief(P, [1000.0, 1000.0 + np.log(2), -np.inf])
    assert np.allclose(b.weights, [1 / 3, 2 / 3, 0.0])
    assert b.ess() == pytest.approx(1 / (1 / 9 + 4 / 9))
    assert np.array_equal(b.map_pose(), P[1])


def test_all_underflowed_or_nan_weights_raise():
    P = np.repeat(np.eye(4)[None], 2, axis=0)
    with pytest.raises(BeliefDegenerateError, match="zero weight"):
        ParticleBelief(P, [-np.inf, -np.inf])
    with pytest.raises(BeliefDegenerateError, match="NaN"):
        ParticleBelief(P, [0.0, np.nan])
    with pytest.raises(ValidationError, match=r"\(2,\)"):
        ParticleBelief(P, [0.0])


def test_mean_pose_averages_rotations_properly():
    R = Rotation.from_rotvec([[0, 0, 0.3], [0, 0, -0.3], [0, 0, 3.0], [0, 0, -3.0]]).as_matrix()
    P = geometry.make_poses(R, np.zeros((4, 3)))
    b = ParticleBelief(P[:2])
    assert np.allclose(b.mean_pose(), np.eye(4), atol=1e-12)
    # near +-pi the naive mean of rotation vectors would be the identity; the proper mean is yaw = pi
    m = ParticleBelief(P[2:]).mean_pose()
    assert abs(abs(np.arctan2(m[1, 0], m[0, 0])) - np.pi) < 1e-9


def test_covariance_and_gaussian_entropy_match_a_known_gaussian(rng):
    rho = 0.05
    P = gaussian_cloud(40000, 0.002, 0.04, rng)
    b = ParticleBelief(P, rho=rho)
    C = b.covariance()
    assert np.allclose(np.diag(C)[:3], 0.002**2, rtol=0.05)
    assert np.allclose(np.diag(C)[3:], (rho * 0.04) ** 2, rtol=0.05)
    sd = b.std()
    assert np.allclose(sd["rotation"], 0.04, rtol=0.05)
    expect = 0.5 * (6 * np.log(2 * np.pi * np.e) + 6 * np.log(0.002) + 6 * np.log(rho * 0.04))
    assert b.entropy() == pytest.approx(expect, abs=0.05)
    # comparable across particle counts
    small = ParticleBelief(P[:1000], rho=rho)
    assert small.entropy() == pytest.approx(expect, abs=0.3)
    assert small.entropy("kde") == pytest.approx(expect, abs=1.0)


def test_kde_entropy_sees_two_modes_and_gaussian_does_not_shrink_them(rng):
    rho = 0.05
    a = gaussian_cloud(1000, 0.001, 0.01, rng)
    b = gaussian_cloud(1000, 0.001, 0.01, rng)
    b[:, 0, 3] += 0.05
    one = ParticleBelief(a, rho=rho, resolution=0.002)
    two = ParticleBelief(np.concatenate([a, b]), rho=rho, resolution=0.002)
    # two separated equal modes: exactly log 2 more entropy than one
    assert two.entropy("kde") - one.entropy("kde") == pytest.approx(np.log(2), abs=0.1)
    assert two.entropy("gaussian") > one.entropy("gaussian") + 1.0  # an upper bound, loose here


def test_systematic_resampling_is_proportional():
    w = np.array([0.5, 0.25, 0.125, 0.125])
    idx = systematic_resample(w, 800, np.random.default_rng(0))
    counts = np.bincount(idx, minlength=4)
    assert np.all(np.abs(counts - 800 * w) <= 1)


def test_resample_and_reweight(rng):
    P = gaussian_cloud(100, 0.01, 0.1, rng)
    b = ParticleBelief(P, rho=0.05)
    r = b.reweighted(np.where(np.arange(100) < 10, 0.0, -np.inf)).resample(rng=1)
    assert len(r) == 100 and np.allclose(r.weights, 0.01)
    assert all(any(np.array_equal(p, q) for q in P[:10]) for p in r.poses)
    with pytest.raises(ValidationError, match="resampler"):
        b.resample(method="nope")


def test_credible_region_membership(rng):
    P = gaussian_cloud(2000, 0.002, 0.02, rng)
    b = ParticleBelief(P, rho=0.05, resolution=0.001)
    assert len(b.credible_set(0.9)) == 1800
    far = np.eye(4)
    far[0, 3] = 0.05
    assert b.in_credible_region(np.stack([np.eye(4), far])).tolist() == [True, False]


def test_region_sampling_membership_and_local_coordinates(rng):
    r = PoseRegion.box((0.1, 0, 0), (0.05, 0.02, 0.0), "yaw", yaw_range=(0, np.pi / 2), rho=0.05)
    assert r.dim == 3
    X = r.sample(500, rng=rng)
    assert r.contains(X).all()
    y = r.yaw_of(X)
    assert y.min() >= 0 and y.max() <= np.pi / 2
    v = r.to_local(X[:20], X[0])
    assert np.allclose(r.from_local(v, X[0]), X[:20], atol=1e-12)
    moved = X.copy()
    moved[:, 2, 3] = 0.01
    assert not r.contains(moved).any()
    full = PoseRegion.box((0, 0, 0), 0.1, "full", rho=0.05)
    Z = full.perturb(np.repeat(np.eye(4)[None], 2000, axis=0), 0.01, rng=rng)
    d = geometry.pose_distance(Z, np.eye(4), radius=0.05)
    assert d.max() <= 0.01 + 1e-9 and d.mean() > 0.007  # uniform in a 6-ball: mean radius 6/7


def test_region_rejects_bad_arguments():
    with pytest.raises(ValidationError, match="rotation"):
        PoseRegion.box(rotation="sideways")
    with pytest.raises(ValidationError, match="half_extent"):
        PoseRegion.box(half_extent=-1)
    with pytest.raises(ValidationError, match="rotation matrix"):
        PoseRegion.box(rotation=np.diag([1.0, 1.0, -1.0]))


def test_tempering_ess_equals_the_log_space_formula():
    """smc._ess (plain numpy, for the bisection on the tempering power) against
    exp(-logsumexp(2 lw)) of normalised log-weights, with -inf weights and a huge offset."""
    from scipy.special import logsumexp

    from touchloc.belief.smc import _ess

    rng = np.random.default_rng(4)
    for lw in (rng.normal(0, 3, 500), rng.normal(0, 30, 500) + 1e4, np.r_[rng.normal(0, 1, 50), [-np.inf] * 5]):
        n = lw - logsumexp(lw)
        assert _ess(lw) == pytest.approx(float(np.exp(-logsumexp(2 * n))), rel=1e-10)
    assert _ess(np.full(10, -np.inf)) == 0.0
    assert _ess(np.zeros(7)) == pytest.approx(7.0)


def test_tempering_logsumexp_is_scipys_bit_for_bit():
    """smc._logsumexp repeats scipy's arithmetic: ties at the maximum, -inf entries, every
    entry -inf, and offsets from 1e-3 to 1e3."""
    from scipy.special import logsumexp

    from touchloc.belief.smc import _logsumexp

    rng = np.random.default_rng(9)
    for i in range(3000):
        a = rng.normal(scale=10 ** rng.uniform(-3, 3), size=int(rng.integers(1, 400)))
        if i % 3 == 0:
            a[rng.random(len(a)) < 0.3] = -np.inf
        if i % 5 == 0:
            a[rng.integers(len(a), size=3)] = a.max()
        if i % 7 == 0:
            a = np.round(a)
        assert _logsumexp(a) == float(logsumexp(a))
    assert _logsumexp(np.full(4, -np.inf)) == -np.inf


def test_tangent_checks_a_given_reference_and_trusts_its_own_poses(rng):
    region = PoseRegion.box((0, 0, 0), 0.1, "full", rho=0.05)
    b = ParticleBelief(region.sample(50, rng=rng), region=region)
    v = b.tangent()
    np.testing.assert_allclose(v, region.to_local(b.poses, b.mean_pose()))
    np.testing.assert_allclose(b.tangent(b.poses[0]), region.to_local(b.poses, b.poses[0]))
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValidationError, match="ref"):
        b.tangent(mirror)


def test_trusted_belief_normalises_and_checks_its_weights():
    P = np.repeat(np.eye(4)[None], 3, axis=0)
    b = ParticleBelief._trusted(P, np.array([0.0, 1.0, 2.0]))
    assert np.exp(b.log_weights).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(b.log_weights, ParticleBelief(P, [0.0, 1.0, 2.0]).log_weights)
    with pytest.raises(BeliefDegenerateError):
        ParticleBelief._trusted(P, np.array([0.0, np.nan, 1.0]))


def test_checked_rotations_match_scipys_checked_conversion(rng):
    # matrices made from quaternions, and products of them, as an estimator's particles are
    R = Rotation.from_quat(rng.normal(size=(500, 4))).as_matrix()
    R2 = Rotation.from_rotvec(0.01 * rng.normal(size=(500, 3))).as_matrix() @ R
    for M in (R, R2, R2 @ np.swapaxes(R, 1, 2)):
        assert np.array_equal(geometry.checked_rotations(M).as_quat(), Rotation.from_matrix(M).as_quat())
    # within the 1e-6 that pose validation accepts, the two differ by about that much
    bent = R + 1e-7 * rng.normal(size=R.shape)
    angle = (geometry.checked_rotations(bent).inv() * Rotation.from_matrix(bent)).magnitude()
    assert 0 < angle.max() < 1e-6
