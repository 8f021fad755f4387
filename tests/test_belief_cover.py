"""The even density cover of Scaling Series: fast ball counts against a KD-tree, and the
cover's distribution against the reference implementation."""

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from touchloc import TouchlocError
from touchloc.belief import PoseRegion, ScalingSeries
from touchloc.belief import _cover
from touchloc.belief._cover import accept_draws, ball_counts
from touchloc.belief.scaling_series import _Draws
from touchloc.data import load_object
from touchloc.models import ProximityModel


@pytest.fixture(scope="module")
def mug():
    return load_object("mug")


def _cluster(region, n, spread, rng):
    """n poses scattered around one pose (a late-scale set of centres)."""
    ref = region.sample(1, rng=rng)
    return region.perturb(np.repeat(ref, n, axis=0), spread, rng=rng, ball=False)


def _touched(mug, k, seed):
    """A 400 mm cube with full rotations, and k contacts (2 mm noise) on the mug at a pose
    drawn in it."""
    from touchloc.models import Contacts

    rng = np.random.default_rng(seed)
    region = PoseRegion.box((0, 0, 0), 0.2, "full")
    true = region.with_rho(mug.radius).sample(1, rng=rng)[0]
    p, n, _ = mug.sample_surface(k, rng=rng)
    return region, Contacts(p + rng.normal(scale=0.002, size=p.shape), n).transform(true)


def _kdtree_counts(region, centres, draws, r):
    tree = cKDTree(region.embed(centres))
    c = tree.query_ball_point(region.embed(draws), r * 1.0000001, return_length=True)
    f = region.embed_flipped(draws)
    if f is not None:
        c = c + tree.query_ball_point(f, r * 1.0000001, return_length=True)
    return c


@pytest.mark.parametrize("rotation", ["full", "yaw"])
@pytest.mark.parametrize("r_over_spread", [0.3, 1.0, 8.0])
@pytest.mark.parametrize("lists", [True, False])
def test_ball_counts_equal_a_kdtree_query_per_draw(rotation, r_over_spread, lists, monkeypatch):
    if not lists:  # forbid the neighbour lists: the fall-back paths must agree too
        monkeypatch.setattr(_cover, "MAX_PAIRS_PER_CANDIDATE", -1e9)
    rng = np.random.default_rng(3)
    region = PoseRegion.box((0, 0, 0), 0.2, rotation, rho=0.05)
    spread = 0.02
    centres = _cluster(region, 600, spread, rng)
    if rotation == "full":  # put some centres near 180 deg turns, where the quaternion sign flips
        centres[:50, :3, :3] = centres[:50, :3, :3] @ np.diag([1.0, -1.0, -1.0])
    r = r_over_spread * spread
    pick = rng.integers(0, len(centres), 5000)
    d = _Draws(region, centres, pick, r, rng)
    got = ball_counts(d.centres_emb, d.emb, pick, r, flip_dims=4 if rotation == "full" else 0)
    want = _kdtree_counts(region, centres, d.poses(np.arange(len(pick))), r)
    assert np.all(got >= 1)
    np.testing.assert_array_equal(got, want)


def test_draws_match_the_region_perturbation_and_embedding():
    rng = np.random.default_rng(0)
    region = PoseRegion.box((0.1, 0, 0), (0.1, 0.05, 0.0), "full", rho=0.07)
    centres = region.sample(50, rng=rng)
    pick = rng.integers(0, 50, 20000)
    r = 0.03
    d = _Draws(region, centres, pick, r, np.random.default_rng(5))
    P = d.poses(np.arange(len(pick)))
    np.testing.assert_allclose(d.emb, region.embed(P), atol=1e-12)
    np.testing.assert_allclose(d.centres_emb, region.embed(centres), atol=1e-12)
    np.testing.assert_array_equal(d.inside, region.contains(P))
    # the same random stream through PoseRegion.perturb gives the same poses
    ref = region.perturb(centres[pick], r, rng=np.random.default_rng(5), ball=True)
    np.testing.assert_allclose(P, ref, atol=1e-12)
    # and the metric offsets from the parents fill the ball of radius r uniformly
    dist = np.array([np.linalg.norm(region.to_local(P[i:i + 1], centres[pick[i]])) for i in range(0, 20000, 20)])
    assert dist.max() <= r * (1 + 1e-9)
    # uniform in a 5-D ball: P(dist <= r/2) = 2^-5
    assert abs(np.mean(dist <= r / 2) - 2.0**-5) < 0.02


@pytest.mark.parametrize("cap", [8, 2])
def test_capped_acceptance_keeps_one_over_count(monkeypatch, cap):
    # heavily overlapping balls (radius larger than the cloud): every draw is in dozens
    # of balls; with the neighbour lists forbidden the capped staged acceptance is used
    # (cap 8: a capped recount at 128, then full counts; cap 2: recounts at 32 and 512)
    monkeypatch.setattr(_cover, "MAX_PAIRS_PER_CANDIDATE", -1e9)
    used = []
    monkeypatch.setattr(_cover, "_capped", lambda *a: used.append(1) or _cover._count_capped_serial(*a))
    rng = np.random.default_rng(1)
    region = PoseRegion.box((0, 0, 0), 0.2, "full", rho=0.05)
    centres = _cluster(region, 300, 0.01, rng)
    r = 0.05
    pick = rng.integers(0, 300, 4000)
    d = _Draws(region, centres, pick, r, rng)
    counts = ball_counts(d.centres_emb, d.emb, pick, r, flip_dims=4)
    assert np.median(counts) > 16  # saturates the cap
    trials = 40
    kept = np.zeros(len(pick))
    for s in range(trials):
        kept += accept_draws(d.centres_emb, d.emb, pick, r, np.random.default_rng(100 + s), flip_dims=4, cap=cap)
    assert len(used) >= 2 * trials  # the capped scan ran, and recounted
    # expected number kept: sum 1/count; binomial spread over trials * draws
    expect = trials * np.sum(1.0 / counts)
    assert abs(kept.sum() - expect) < 4 * np.sqrt(expect)
    # and by count: draws in few balls are kept more often than draws in many
    lo, hi = counts <= np.percentile(counts, 25), counts >= np.percentile(counts, 75)
    assert kept[lo].mean() / trials == pytest.approx(np.mean(1.0 / counts[lo]), rel=0.15)
    assert kept[hi].mean() / trials == pytest.approx(np.mean(1.0 / counts[hi]), rel=0.15)


def test_acceptance_without_neighbour_lists_keeps_one_over_count(monkeypatch):
    # sparse balls but lists forbidden: counts come from a KD-tree query per draw
    monkeypatch.setattr(_cover, "MAX_PAIRS_PER_CANDIDATE", -1e9)
    rng = np.random.default_rng(6)
    region = PoseRegion.box((0, 0, 0), 0.2, "full", rho=0.05)
    centres = _cluster(region, 300, 0.02, rng)
    pick = rng.integers(0, 300, 3000)
    d = _Draws(region, centres, pick, 0.01, rng)
    counts = ball_counts(d.centres_emb, d.emb, pick, 0.01, flip_dims=4)
    kept = sum(accept_draws(d.centres_emb, d.emb, pick, 0.01, np.random.default_rng(s), flip_dims=4)
               for s in range(20))
    expect = 20 * np.sum(1.0 / counts)
    assert abs(kept.sum() - expect) < 4 * np.sqrt(expect)


def test_mask_excludes_draws():
    rng = np.random.default_rng(2)
    region = PoseRegion.box((0, 0, 0), 0.2, "yaw", rho=0.05)
    centres = _cluster(region, 100, 0.01, rng)
    pick = rng.integers(0, 100, 1000)
    d = _Draws(region, centres, pick, 0.005, rng)
    mask = np.arange(1000) % 2 == 0
    keep = accept_draws(d.centres_emb, d.emb, pick, 0.005, rng, mask=mask)
    assert not keep[~mask].any() and keep[mask].any()


def test_cover_matches_the_reference_cover(mug):
    """Same centres, many seeds: the fast cover and the reference draw the same number of
    particles and estimate the same union volume, and their particles fill the same set."""
    region = PoseRegion.box((0, 0, 0), 0.2, "full").with_rho(mug.radius)
    rng = np.random.default_rng(4)
    centres = _cluster(region, 400, 0.01, rng)
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    ss_new, ss_ref = ScalingSeries(model, rng=0), ScalingSeries(model, rng=0)
    vol_new, vol_ref, n_new, n_ref = [], [], [], []
    for s in range(6):
        ss_new.rng, ss_ref.rng = np.random.default_rng(s), np.random.default_rng(1000 + s)
        X, v = ss_new._even_density_cover(region, centres, 0.01, 0.0089)
        Y, w = ss_ref._even_density_cover_reference(region, centres, 0.01, 0.0089)
        vol_new.append(v), vol_ref.append(w), n_new.append(len(X)), n_ref.append(len(Y))
    assert np.mean(vol_new) == pytest.approx(np.mean(vol_ref), rel=0.05)
    assert np.mean(n_new) == pytest.approx(np.mean(n_ref), rel=0.05)
    # every new particle lies in the union of the centres' balls
    tree = cKDTree(np.vstack([region.embed(centres), region.embed_flipped(centres)]))
    d, _ = tree.query(region.embed(X))
    assert d.max() <= 0.01 * (1 + 1e-6)
    # evenness: the nearest-centre distance distribution is the same for both covers
    dy, _ = tree.query(region.embed(Y))
    assert np.median(d) == pytest.approx(np.median(dy), rel=0.05)


@pytest.mark.parametrize("cap", [1500, 600])
def test_a_capped_cover_draws_in_batches_and_still_matches_the_reference(mug, monkeypatch, cap):
    """Where the particle cap binds, the cover draws only about what fills it (batches of
    whole rounds over the centres), and its particles and volume are still those of the
    reference cover, which draws everything and thins."""
    from touchloc.belief import scaling_series as ss_mod

    drawn = []

    class Counted(ss_mod._Draws):
        def __init__(self, region, centers, pick, *a, **kw):
            drawn.append(np.bincount(pick, minlength=len(centers)))
            super().__init__(region, centers, pick, *a, **kw)

    monkeypatch.setattr(ss_mod, "_Draws", Counted)
    region = PoseRegion.box((0, 0, 0), 0.2, "full").with_rho(mug.radius)
    centres = _cluster(region, 400, 0.01, np.random.default_rng(4))
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    # 400 centres x 13 draws: in rounds over the centres under a cap of 1500 (5200 <= 4 x 1500),
    # at random under 600; about 2800 would be kept, so both caps bind
    ss_new, ss_ref = ScalingSeries(model, rng=0, max_particles=cap), ScalingSeries(model, rng=0, max_particles=cap)
    tree = cKDTree(np.vstack([region.embed(centres), region.embed_flipped(centres)]))
    vol_new, vol_ref, d_new, d_ref, n_drawn = [], [], [], [], []
    for s in range(6):
        ss_new.rng, ss_ref.rng = np.random.default_rng(s), np.random.default_rng(1000 + s)
        ss_new._even_density_cover(region, centres, 0.01, 0.0089)  # sets the acceptance rate
        drawn.clear()
        X, v = ss_new._even_density_cover(region, centres, 0.01, 0.0089)
        Y, w = ss_ref._even_density_cover_reference(region, centres, 0.01, 0.0089)
        assert len(X) == len(Y) == cap
        per_centre = np.sum(drawn, axis=0)
        if cap == 1500:  # whole rounds: every centre its share
            assert np.all(per_centre == per_centre[0])
        n_drawn.append(per_centre.sum())
        vol_new.append(v), vol_ref.append(w)
        d_new.append(tree.query(region.embed(X))[0]), d_ref.append(tree.query(region.embed(Y))[0])
    full = min(len(centres) * int(np.ceil(6 * (0.01 / 0.0089) ** 6)), 4 * cap)
    assert max(n_drawn) < 0.7 * full
    assert np.mean(vol_new) == pytest.approx(np.mean(vol_ref), rel=0.05)
    assert np.concatenate(d_new).max() <= 0.01 * (1 + 1e-6)
    assert np.median(np.concatenate(d_new)) == pytest.approx(np.median(np.concatenate(d_ref)), rel=0.05)


@pytest.mark.parametrize("k", [6, 30])
def test_annealed_likelihood_prunes_exactly_like_a_full_evaluation(mug, k):
    """Scaling Series stops evaluating particles that the prune step drops anyway: the
    survivors and their weights are those of a complete evaluation."""
    rng = np.random.default_rng(k)
    region = PoseRegion.box((0, 0, 0), 0.2, "full").with_rho(mug.radius)
    true = region.sample(1, rng=rng)[0]
    p, n, _ = mug.sample_surface(k, rng=rng)
    from touchloc.models import Contacts

    contacts = Contacts(p + rng.normal(scale=0.002, size=p.shape), n).transform(true)
    X = region.perturb(np.repeat(true[None], 5000, axis=0), 0.02, rng=rng, ball=False)
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    ss = ScalingSeries(model, rng=0)
    slack = model._bound_slack(contacts)
    # with the table's bounds (a scale between one and two slacks wide) and without them
    # (narrower than the slack)
    for tau, delta in itertools.product((1.0, 30.0, 1000.0), (1.5 * slack, 0.5 * slack)):
        full = model.log_likelihood(X, contacts, temperature=tau)
        part = ss._annealed_loglik(X, contacts, tau, delta=delta)
        assert np.all(part >= full - 1e-9)  # a partial cost never exceeds the full one
        kept_full = ss._prune(X, full)
        kept_part = ss._prune(X, part)
        np.testing.assert_array_equal(kept_part, kept_full)
        keep = full >= full.max() + np.log(ss.prune_ratio)
        np.testing.assert_allclose(part[keep], full[keep], rtol=1e-12, atol=1e-9)
        if tau == 1.0:
            assert np.sum(part > full + 1e-6) > 0  # some particles were left unfinished


def test_wide_scales_are_scored_on_the_bound_table(mug):
    """At an intermediate scale at least ``bound_scales`` slacks wide a particle's annealed
    log-likelihood is its table bounds' (never below the exact value); at a narrower one,
    at the last scale or with ``bound_scales=None`` it is the exact evaluation's."""
    rng = np.random.default_rng(3)
    region = PoseRegion.box((0, 0, 0), 0.2, "full").with_rho(mug.radius)
    true = region.sample(1, rng=rng)[0]
    p, n, _ = mug.sample_surface(20, rng=rng)
    from touchloc.models import Contacts

    contacts = Contacts(p + rng.normal(scale=0.002, size=p.shape), n).transform(true)
    X = region.perturb(np.repeat(true[None], 2000, axis=0), 0.05, rng=rng, ball=False)
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    slack = model._bound_slack(contacts)
    tau = 200.0
    table = -0.5 * model._lower_costs(X, contacts).sum(axis=1) / tau
    full = model.log_likelihood(X, contacts, temperature=tau)
    on, off = ScalingSeries(model, rng=0), ScalingSeries(model, rng=0, bound_scales=None)
    assert on.bound_scales == 2.0
    got = on._annealed_loglik(X, contacts, tau, delta=2.0 * slack)
    # the prune keeps the same particles with the same values; the others stopped their
    # lookups once sure to be dropped: still below the threshold, above their full table value
    keep = table >= table.max() + np.log(on.prune_ratio)
    assert 0 < keep.sum() < len(X) // 2
    np.testing.assert_array_equal(got[keep], table[keep])
    assert np.all(got[~keep] < got.max() + np.log(on.prune_ratio)) and np.all(got >= table)
    assert np.any(got[~keep] > table[~keep] + 1.0)   # some lookups were skipped
    np.testing.assert_array_equal(on._prune(X, got), on._prune(X, table))
    np.testing.assert_array_equal(on._annealed_loglik(X[:40], contacts, tau, delta=2.0 * slack), table[:40])
    assert np.all(table >= full - 1e-9) and np.any(table > full + 1.0)
    for ss, delta, prune in ((on, 1.9 * slack, False), (on, 1.9 * slack, True), (off, 10 * slack, True),
                             (on, 10 * slack, False)):
        got = ss._annealed_loglik(X, contacts, tau, prune=prune, delta=delta)
        keep = full >= full.max() + np.log(ss.prune_ratio)
        np.testing.assert_allclose(got[keep], full[keep], rtol=1e-12, atol=1e-9)
    with pytest.raises(TouchlocError):
        ScalingSeries(model, bound_scales=-1.0)
    with pytest.raises(TouchlocError):
        ScalingSeries(model, bound_scales=float("nan"))


def test_the_table_scales_take_bound_steps_of_alg1_at_a_time(mug):
    """With ``bound_steps=k`` the scales at least ``bound_scales`` slacks wide are every
    k-th of Alg. 1's (a delta-ball's volume shrinks 2^k-fold between them); the narrower
    scales, and every scale without the table, are Alg. 1's own."""
    region, contacts = _touched(mug, 10, 8)
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    wide = 2.0 * model._bound_slack(contacts)

    def deltas(**kw):
        ss = ScalingSeries(model, rng=0, progress=False, final_moves=0, **kw)
        return np.array([st.delta for st in ss.iterate(contacts, region)])

    alg1 = deltas(bound_steps=1)
    assert np.allclose(np.diff(np.log(alg1[:-1])), -np.log(2) / 6)   # Alg. 1: 2^(-1/6) per scale
    for k in (2, 3):
        got = deltas(bound_steps=k)
        inner = alg1[:-1]
        expect = np.concatenate([inner[inner >= wide][::k], inner[inner < wide], alg1[-1:]])
        np.testing.assert_array_equal(got, expect)
        assert len(got) < len(alg1)
    np.testing.assert_array_equal(deltas(bound_steps=2, bound_scales=None), deltas(bound_steps=1, bound_scales=None))
    for bad in (0, -1, 2.5, float("nan"), "two", 17):
        with pytest.raises(TouchlocError):
            ScalingSeries(model, bound_steps=bad)


def test_compiled_box_and_parent_tests_match_numpy_bit_for_bit(rng):
    from touchloc.belief._cover import _beyond, in_box

    for d in (3, 4, 6, 7):
        E = rng.normal(size=(40, d))
        parent = rng.integers(0, 40, 20000)
        X = E[parent] + 0.3 * rng.normal(size=(20000, d))
        for r in (0.2, 0.5, 0.9):
            assert np.array_equal(_beyond(X, E, parent, r * r), np.sum((X - E[parent]) ** 2, axis=1) > r * r)
    t = rng.uniform(-1, 1, size=(20000, 3))
    t[:5] = [[0.5, 0, 0], [0.5 + 1e-9, 0, 0], [0.5 + 2e-9, 0, 0], [np.nan, 0, 0], [0, -0.7, 0.3]]
    c, h = np.array([0.0, 0.0, 0.0]), np.array([0.5, 0.7, 0.3])
    got = in_box(t, c, h)
    assert np.array_equal(got, np.all(np.abs(t - c) <= h + 1e-9, axis=1))
    assert got[0] and got[1] and not got[2] and not got[3] and got[4]


def test_compiled_quaternion_poses_are_scipys_bit_for_bit(rng):
    from scipy.spatial.transform import Rotation

    from touchloc.belief._cover import quat_poses

    q = rng.normal(size=(200_000, 4))
    q[:100_000] /= np.linalg.norm(q[:100_000], axis=1, keepdims=True)  # unit, as the draws make them
    q[100_000:100_010] *= 1e-3                                        # and far from unit
    t = rng.normal(size=(len(q), 3))
    idx = rng.permutation(len(q))[:150_000]
    got = quat_poses(q, idx, t)
    assert got.shape == (150_000, 4, 4)
    assert np.array_equal(got[:, :3, :3], Rotation.from_quat(q[idx]).as_matrix())
    assert np.array_equal(got[:, :3, 3], t[idx])
    assert np.array_equal(got[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (len(idx), 1)))


def test_compiled_matrix_quaternions_are_scipys_bit_for_bit(rng):
    from scipy.spatial.transform import Rotation

    from touchloc.belief._cover import matrix_quats

    R = Rotation.random(200_000, rng).as_matrix()
    axes = rng.normal(size=(2000, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R[:1000] = Rotation.from_rotvec(axes[:1000] * 1e-7).as_matrix()       # near the identity
    R[1000:2000] = Rotation.from_rotvec(axes[1000:] * np.pi).as_matrix()  # half turns
    R[2000] = np.eye(3)
    got = matrix_quats(R)
    assert np.array_equal(got, Rotation.from_matrix(R, assume_valid=True).as_quat())
    assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-15)


def test_the_draws_are_the_same_on_one_thread_and_on_many(rng):
    n, free = 6000, np.arange(3, dtype=np.int64)
    g, u = rng.normal(size=(n, 6)), rng.random(n)
    qc = rng.normal(size=(50, 4))
    qc /= np.linalg.norm(qc, axis=1, keepdims=True)
    tc, pick = rng.normal(size=(50, 3)), rng.integers(0, 50, n)
    outs = []
    for kernel in (_cover._draw_full_parallel, _cover._draw_full_serial):
        t, q, emb = np.empty((n, 3)), np.empty((n, 4)), np.empty((n, 7))
        kernel(g, u, qc, tc, pick, free, 0.05, 0.1, t, q, emb)
        outs.append((t, q, emb))
    for a, b in zip(*outs):
        assert np.array_equal(a, b)
    t, q, emb = outs[0]
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0) and np.all(q[:, 3] >= 0)
    assert np.array_equal(emb[:, 3:], 0.2 * q)


def _metric_distances(region, centres, X):
    """(len(X), len(centres)) distances in the metric the cover's balls are drawn in
    (:meth:`PoseRegion.perturb`): translation and rho times the rotation angle between."""
    from scipy.spatial.transform import Rotation

    free = region.free_translation
    dt = X[:, None, :3, 3][..., free] - centres[None, :, :3, 3][..., free]
    d2 = np.sum(dt**2, axis=-1)
    if region.rotation == "full":
        rel = np.einsum("nji,mjk->nmik", centres[:, :3, :3], X[:, :3, :3])  # R_c^T R_x
        ang = Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude().reshape(len(X), len(centres))
        d2 = d2 + (region.rho * ang) ** 2
    elif region.rotation == "yaw":
        dy = region.yaw_of(X)[:, None] - region.yaw_of(centres)[None, :]
        if region.periodic_yaw:
            dy = (dy + np.pi) % (2 * np.pi) - np.pi
        d2 = d2 + (region.rho * dy) ** 2
    return np.sqrt(d2)


@pytest.mark.parametrize("rotation, yaw_range, wide", [("full", None, 0.7), ("yaw", (-np.pi, np.pi), 0.5),
                                                       ("yaw", (0.0, 2.0), 0.5), ("fixed", None, 0.5)])
def test_covered_cells_lie_inside_the_balls(rotation, yaw_range, wide):
    """Every pose of a cell the grid calls covered is within r of a centre (the metric the
    balls are drawn in), whether or not the cell holds a centre itself."""
    from touchloc.belief.scaling_series import _CellCover

    rng = np.random.default_rng(5)
    kw = {} if yaw_range is None else {"yaw_range": yaw_range}
    rot = np.eye(3) if rotation == "fixed" else rotation
    region = PoseRegion.box((0.01, 0.0, -0.02), (0.2, 0.15, 0.1), rot, rho=0.05, **kw)
    X = region.sample(3000, rng=rng)
    centres = X[X[:, 0, 3] < -0.05][:200]   # a third of the region holds the centres
    r = wide * region.radius()
    cells = _CellCover(region, centres, r)
    assert 0.0 < cells.fraction < 1.0
    occupied = np.unique(cells.cells(centres))
    assert np.any(~np.isin(np.flatnonzero(cells.covered), occupied))   # reach, not occupancy alone
    Q = region.sample(3000, rng=rng)
    q = cells.cells(Q)
    inside = cells.covered[q]
    assert inside.sum() > 300
    d = _metric_distances(region, centres, Q[inside]).min(axis=1)
    assert d.max() <= r * (1 + 1e-9)


@pytest.mark.parametrize("rotation, wide", [("full", 0.9), ("yaw", 0.8)])
def test_the_region_cover_matches_the_reference_where_the_balls_hold_most_of_the_region(mug, rotation, wide):
    """Where a union of wide balls holds most of the region, the cover draws the region and
    keeps what lies in the union: where the particles lie, and (yaw) the union's volume,
    are those of the reference's rejection sampler (draws from the balls, kept with
    probability 1 / count), and it keeps the floor where the sampler kept a handful.

    With full rotations the balls are wider than pi rho: a draw's rotation vector wraps
    around, and the reference's counts (in the quaternion embedding, where a centre and
    its flipped copy may both hold a draw) no longer undo its draw density, so it thins
    the union's far side. There the particles are compared with uniform draws of the
    region kept by a brute-force test of the same union. A yaw range (0, 2 rad) has no
    wrap: there the reference is the comparison."""
    from touchloc.belief.scaling_series import _CellCover

    kw = {"yaw_range": (0.0, 2.0), "rho": mug.radius} if rotation == "yaw" else {"rho": mug.radius}
    region = PoseRegion.box((0, 0, 0), 0.2, rotation, **kw)
    rng = np.random.default_rng(6)
    X = region.sample(4000, rng=rng)
    centres = X[X[:, 0, 3] < -0.1][:300]   # the union reaches past x = 0, not to x = 0.2
    r = wide * region.radius()
    d = r * 2 ** (-1 / region.dim)
    cells = _CellCover(region, centres, r)
    assert 0.5 <= cells.fraction < 1.0   # the region cover is used, and asks the tree
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    ss_new = ScalingSeries(model, rng=0)
    ss_ref = ScalingSeries(model, rng=0, max_draws=10**6)   # every draw of the reference, uncapped
    vol_new, vol_ref, x_new, x_ref = [], [], [], []
    tree = cKDTree(region.embed(centres))
    for s in range(30):
        ss_new.rng, ss_ref.rng = np.random.default_rng(s), np.random.default_rng(1000 + s)
        P, v = ss_new._even_density_cover(region, centres, r, d)
        Q, w = ss_ref._even_density_cover_reference(region, centres, r, d)
        assert len(P) >= ss_new.min_particles
        dist = tree.query(region.embed(P))[0]
        if rotation == "full":
            dist = np.minimum(dist, tree.query(region.embed_flipped(P))[0])
        assert dist.max() <= r * (1 + 1e-6)
        vol_new.append(v), vol_ref.append(w), x_new.append(P[:, 0, 3]), x_ref.append(Q[:, 0, 3])
    if rotation == "yaw":
        assert np.mean(vol_new) == pytest.approx(np.mean(vol_ref), rel=0.05)
    x_new, x_ref = np.concatenate(x_new), np.concatenate(x_ref)
    assert len(x_ref) < 0.5 * len(x_new)     # the reference kept a few per cover
    if rotation == "full":
        Y = region.sample(20000, rng=np.random.default_rng(99))
        C = region.embed(centres)
        d2 = np.minimum(
            *[np.sum(E**2, 1)[:, None] + np.sum(C**2, 1)[None, :] - 2.0 * E @ C.T
              for E in (region.embed(Y), region.embed_flipped(Y))]).min(axis=1)
        x_ref = Y[d2 <= r * r, 0, 3]
    # the share of the union's far side in x as in the comparison
    far_new, far_ref = np.mean(x_new > 0.05), np.mean(x_ref > 0.05)
    se = np.sqrt(far_ref * (1 - far_ref) / len(x_ref) + far_new * (1 - far_new) / len(x_new))
    assert 0.05 < far_ref < 0.95 and abs(far_new - far_ref) < 4 * se


def test_the_first_cover_after_the_uniform_start_keeps_the_floor(mug):
    """The first scale's balls hold the region: its cover is a uniform draw of the region
    with at least ``min_particles`` particles (the rejection sampler had kept 3-5)."""
    region, contacts = _touched(mug, 10, 7)
    model = ProximityModel(mug, 0.002, np.deg2rad(5))
    for s in range(3):
        steps = ScalingSeries(model, rng=s, progress=False).iterate(contacts, region)
        next(steps)
        first = next(steps)
        assert first.n_particles >= 50
