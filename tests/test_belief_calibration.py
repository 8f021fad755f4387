"""Calibration: highest-density levels, the Scaling Series posterior stage, SMC tempering."""

import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from touchloc.belief import (ParticleBelief, PoseRegion, ScalingSeries, SMCFilter, belief_coverage, hpd_level,
                             pairwise_symmetric_distance, symmetric_pose_error)
from touchloc.belief.smc import temper
from touchloc.errors import ValidationError
from touchloc.geometry import make_poses
from touchloc.models import Contacts, MeasurementModel, ProximityModel


@pytest.fixture(scope="module")
def box():
    from touchloc.models import MeshObject

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.box((0.06, 0.04, 0.03)), name="box")


def _at(x, y=None):
    x = np.atleast_1d(np.asarray(x, dtype=float))
    y = np.zeros_like(x) if y is None else np.asarray(y, dtype=float)
    return make_poses(np.repeat(np.eye(3)[None], len(x), 0), np.c_[x, y, 0 * x])


def _xy_region(box):
    return PoseRegion.box((0, 0, 0), (0.04, 0.04, 0), rotation=np.eye(3)).with_rho(box.radius)


def test_pairwise_distance_matches_symmetric_pose_error(box):
    P = _xy_region(box).sample(6, rng=0)
    P[:, :3, :3] = Rotation.random(6, random_state=1).as_matrix()
    D = pairwise_symmetric_distance(box, P, rho=0.05)
    dt, dr = symmetric_pose_error(box, P, P[2])
    assert np.allclose(D[:, 2], np.hypot(dt, 0.05 * dr))
    assert np.allclose(D, D.T) and np.allclose(np.diag(D), 0)
    # a half-turn of the box about its long axis is the same box: distance zero
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec([np.pi, 0, 0]).as_matrix()
    assert pairwise_symmetric_distance(box, np.stack([P[0], P[0] @ g]), rho=0.05)[0, 1] < 1e-9


def test_hpd_level_is_uniform_for_a_correct_belief_and_not_for_a_narrow_one(box):
    """Truth and belief from the same distribution: the level is uniform, so the level-a
    region holds the truth in a of the trials. 300 trials: binomial s.e. 1.7 points at 90 %;
    the tolerance is 4 s.e."""
    reg = _xy_region(box)
    rng = np.random.default_rng(0)
    right, narrow = [], []
    for t in range(300):
        truth = _at(*rng.normal(0, 0.002, 2))[0]
        sample = _at(rng.normal(0, 0.002, 300), rng.normal(0, 0.002, 300))
        right.append(hpd_level(ParticleBelief(sample, region=reg), truth, box, n=100, rng=t))
        tight = _at(sample[:, 0, 3] / 3, sample[:, 1, 3] / 3)
        narrow.append(hpd_level(ParticleBelief(tight, region=reg), truth, box, n=100, rng=t))
    right, narrow = np.array(right), np.array(narrow)
    for a in (0.5, 0.9, 0.95):
        assert abs(np.mean(right < a) - a) < 4 * np.sqrt(a * (1 - a) / 300)
    # a belief three times too narrow holds the truth in its 90 % region far less often
    assert np.mean(narrow < 0.9) < 0.5


def test_hpd_level_weighted_beliefs_and_validation(box):
    reg = _xy_region(box)
    # weighted belief: all the weight on a particle 20 mm away, none near the truth
    P = _at([0.02, 0.0])
    b = ParticleBelief(P, np.log([1.0, 1e-12]), region=reg, resolution=0.001)
    assert hpd_level(b, _at(0.0)[0], box, n=50, rng=0) == 1.0
    assert belief_coverage(b, _at(0.02)[0], box, method="hpd", n=50, rng=0)[0.95]
    with pytest.raises(ValidationError):
        hpd_level(b, _at(0.0)[0], box, n=10, k=10)
    with pytest.raises(ValidationError):
        belief_coverage(b, _at(0.0)[0], box, method="nope")


def _face_contacts(box, k, x_true, seed):
    """k contacts on the box's +x face (normal +x), 2 mm noise along x only."""
    rng = np.random.default_rng(seed)
    p = np.c_[np.full(k, 0.03 + x_true + rng.normal(0, 0.002, k)), rng.uniform(-0.018, 0.018, k),
              rng.uniform(-0.013, 0.013, k)]
    return Contacts(p, np.tile([1.0, 0, 0], (k, 1)))


def test_scaling_series_output_is_the_posterior_not_a_cover(box):
    """Contacts on one face fix x only: the posterior in x is Gaussian with sd
    sigma / sqrt(k) around the mean offset; the old weighted cover (final_moves=0) is
    far from that when the posterior is narrower than delta*."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(box.radius)
    model = ProximityModel(box, 0.002, 0.1)
    k = 30
    c = _face_contacts(box, k, 0.0, 0)
    mean = float(np.mean(c.points[:, 0]) - 0.03)
    sd = 0.002 / np.sqrt(k)
    b = ScalingSeries(model, rng=0).localize(c, reg)
    x = b.poses[:, 0, 3]
    assert len(b) == 500 and np.ptp(b.log_weights) == 0
    assert abs(np.mean(x) - mean) < 0.3 * sd
    assert 0.75 * sd < np.std(x) < 1.25 * sd   # 500 correlated draws: a few % noise, 25 % tolerance
    assert abs(b.map_pose()[0, 3] - mean) < sd
    cover = ScalingSeries(model, final_moves=0, rng=0).localize(c, reg)
    assert np.ptp(cover.log_weights) > 0 and "cover" not in cover.info
    assert b.info["cover"].resolution == cover.resolution


def test_temper_reaches_the_target_posterior():
    """Uniform prior on [-10, 10] mm in x, Gaussian likelihood N(3 mm, 0.5 mm): the tempered
    sample's mean and sd match, and the ESS schedule needed several stages."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(0.05)
    P = reg.sample(2000, rng=0)

    def new(Q):
        return -0.5 * ((Q[:, 0, 3] - 0.003) / 0.0005) ** 2
    out, l_old, l_new, stages, acc = temper(P, np.zeros(2000), np.zeros(2000), new(P), None, new, reg, moves=3,
                                            max_stages=20, rng=0)
    x = out[:, 0, 3]
    assert stages >= 2 and 0.05 < np.mean(acc) < 0.95
    assert abs(np.mean(x) - 0.003) < 0.0001
    assert 0.00042 < np.std(x) < 0.00058
    assert np.allclose(l_new, new(out))


def test_temper_with_an_early_stopping_likelihood_makes_the_same_moves():
    """``new_above`` (the value where it exceeds the move's threshold, -inf where it does
    not) gives the tempering of ``new`` exactly, and is asked only about proposals."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(0.05)
    P = reg.sample(1000, rng=3)

    def new(Q):
        return -0.5 * ((Q[:, 0, 3] - 0.003) / 0.0005) ** 2

    asked, below = [], []

    def new_above(Q, t):
        v = new(Q)
        asked.append(len(Q))
        below.append(np.mean(v <= t))
        return np.where(v > t, v, -np.inf)

    a = temper(P, np.zeros(1000), np.zeros(1000), new(P), None, new, reg, moves=3, max_stages=20, rng=5)
    b = temper(P, np.zeros(1000), np.zeros(1000), new(P), None, new, reg, moves=3, max_stages=20, rng=5,
               new_above=new_above)
    for x, y in zip(a[:3], b[:3]):
        np.testing.assert_array_equal(x, y)
    assert a[3] == b[3] and a[4] == b[4]
    assert asked and 0.1 < np.mean(below) < 0.95  # most proposals are rejected, and are told so early


def test_smc_filter_still_sequential(box):
    """Two updates of 15 contacts reach the same posterior as one update of 30."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(box.radius)
    model = ProximityModel(box, 0.002, 0.1)
    c = _face_contacts(box, 30, 0.0, 1)
    f = SMCFilter(model, 1000, rng=0)
    f.initialize(reg)
    f.update(c[:15])
    b = f.update(c[15:])
    mean = float(np.mean(c.points[:, 0]) - 0.03)
    sd = 0.002 / np.sqrt(30)
    x = b.poses[:, 0, 3]
    assert abs(np.mean(x) - mean) < 0.3 * sd and 0.75 * sd < np.std(x) < 1.25 * sd


def test_temper_runs_to_power_one_and_estimates_the_evidence():
    """Uniform prior on [-10, 10] mm, likelihood exp(-x^2 / (2 s^2)) with s = 20 um (a
    posterior 500 times narrower than the prior, about ten ESS-halving steps): tempering
    reaches power 1 before its cap, and the evidence E_prior[L] = sqrt(2 pi) s / 20 mm is
    estimated within 0.25 in log (its spread over seeds is about 0.08 with 2000 particles)."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(0.05)
    P = reg.sample(2000, rng=0)
    s = 2e-5

    def new(Q):
        return -0.5 * (Q[:, 0, 3] / s) ** 2
    info = {}
    out, _, l_new, stages, acc = temper(P, np.zeros(2000), np.zeros(2000), new(P), None, new, reg, info=info,
                                        rng=0)
    assert 4 <= stages < 60
    x = out[:, 0, 3]
    assert 0.8 * s < np.std(x) < 1.2 * s and abs(np.mean(x)) < 0.2 * s
    assert info["log_evidence"] == pytest.approx(np.log(np.sqrt(2 * np.pi) * s / 0.02), abs=0.25)
    # the walk's size followed the posterior down: the late moves were not all rejected
    assert np.mean(acc[-3:]) > 0.1


def test_temper_keeps_two_separated_modes_in_proportion():
    """Two narrow Gaussian modes 12 mm apart, the right one holding 3/4 of the mass: the
    sample keeps both, in that proportion (2000 particles: s.e. 1 point, tolerance 6)."""
    reg = PoseRegion.box((0, 0, 0), (0.01, 0, 0), rotation=np.eye(3)).with_rho(0.05)
    P = reg.sample(2000, rng=2)
    s = 2e-4

    def new(Q):
        x = Q[:, 0, 3]
        return np.logaddexp(np.log(0.25) - 0.5 * ((x + 0.006) / s) ** 2, np.log(0.75) - 0.5 * ((x - 0.006) / s) ** 2)
    out, *_ = temper(P, np.zeros(2000), np.zeros(2000), new(P), None, new, reg, rng=2)
    x = out[:, 0, 3]
    right = np.mean(x > 0)
    assert 0.69 < right < 0.81
    assert np.all(np.abs(np.abs(x) - 0.006) < 6 * s)


class _TwoWells(MeasurementModel):
    """A likelihood in x alone with two narrow wells 12 mm apart (s = 0.2 mm) holding 1 %
    and 99 % of the mass, and a valley between them that no Metropolis walk crosses."""

    def __init__(self, obj):
        self.obj = obj

    def log_likelihood(self, poses, contacts=None, temperature=1.0):
        x = np.asarray(poses)[:, 0, 3]
        s = 2e-4
        return np.logaddexp(np.log(0.01) - 0.5 * ((x + 0.006) / s) ** 2,
                            np.log(0.99) - 0.5 * ((x - 0.006) / s) ** 2) / temperature


def test_second_opinion_recovers_a_lost_mode(box):
    """A filter whose particles only ever saw the small well (its prior sample lies in
    [-8, -4] mm) is confident and wrong. An independent run from the uniform prior over
    [-12, 12] mm finds both wells; its evidence is about 17 times larger (log 2.8), so the
    pool holds the large well in about 93 % of its particles. A filter that was right
    stays right."""
    reg = PoseRegion.box((0, 0, 0), (0.012, 0, 0), rotation=np.eye(3)).with_rho(box.radius)
    model = _TwoWells(box)
    c = Contacts([[0.0, 0.0, 0.0]])
    lost = SMCFilter(model, 1000, rng=0)
    lost.initialize(reg, poses=_at(np.random.default_rng(0).uniform(-0.008, -0.004, 1000)))
    lost.update(c)
    assert np.all(lost.belief.poses[:, 0, 3] < 0)                 # confident and wrong
    ratio = lost.second_opinion(rng=1)
    assert ratio == pytest.approx(np.log((1 / 0.024) / (0.01 / 0.004)), abs=0.3)
    x = lost.belief.poses[:, 0, 3]
    assert 0.85 < np.mean(np.abs(x - 0.006) < 0.001) < 0.98
    assert lost.belief.info["map_pose"][0, 3] == pytest.approx(0.006, abs=0.0005)
    right = SMCFilter(model, 1000, rng=4)
    right.initialize(reg)
    right.update(c)
    assert abs(right.second_opinion(rng=5)) < 0.3
    assert np.mean(np.abs(right.belief.poses[:, 0, 3] - 0.006) < 0.001) > 0.95


def test_gentle_tempering_keeps_a_narrow_heavy_mode_in_proportion_over_x_y_and_yaw():
    # a mode with 70 % of the mass (0.5 mm, 1 deg) against one four times wider, on the
    # planar region: with the default steps (half the effective sample size kept) runs of
    # 2000 particles gave it 52 +- 29 % and lost it once in 12; keeping 95 % per step gives
    # 66 +- 10 %. 12 runs: the mean within 0.1 of 0.7 and a spread below 0.15 (the default
    # steps fail both).
    region = PoseRegion.planar((0.0, 0.0), 0.05, z=0.0).with_rho(0.04)

    def ll(P):
        x, y = P[:, 0, 3], P[:, 1, 3]
        w = np.arctan2(P[:, 1, 0], P[:, 0, 0])

        def mode(mx, mw, s, sw):
            dw = np.angle(np.exp(1j * (w - mw)))
            return -0.5 * (((x - mx) / s) ** 2 + (y / s) ** 2 + (dw / sw) ** 2) - 2 * np.log(s) - np.log(sw)
        return np.logaddexp(np.log(0.7) + mode(-0.01, 0.0, 0.0005, np.radians(1.0)),
                            np.log(0.3) + mode(0.01, 2.0, 0.002, np.radians(4.0)))

    weights = []
    for seed in range(12):
        P0 = region.sample(2000, rng=seed)
        P, *_ = temper(P0, np.full(2000, -np.log(2000)), np.zeros(2000), ll(P0), None, ll, region,
                       ess_fraction=0.95, rng=seed)
        weights.append(np.mean(P[:, 0, 3] < 0))
    assert abs(np.mean(weights) - 0.7) < 0.1 and np.std(weights) < 0.15, weights
