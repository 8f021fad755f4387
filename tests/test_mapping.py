"""Shape maps from touch: GPIS and occupancy maps, superquadrics, exploration, metrics."""

import re
import warnings

import numpy as np
import pytest
import trimesh

from touchloc.errors import MappingError, TouchlocError, ValidationError
from touchloc.mapping import (ShapeMap, box_pool, chamfer_distance, explore, fit_superquadric, fscore,
                              lattice_pool)
from touchloc.models import Contacts, MeshObject
from touchloc.planners import GuardedTouch, SimulatedWorld, TouchResult


def _quiet(mesh, name="m"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(mesh, name=name, check_units=False)


@pytest.fixture(scope="module")
def sphere():
    return _quiet(trimesh.creation.icosphere(4, radius=0.03), "sphere")


def _bounds(obj, pad=0.02):
    lo, hi = obj.bounds
    return lo - pad, hi + pad


def _touches(obj, n, rng, noise=(0.0005, 0.03)):
    world = SimulatedWorld(obj, np.eye(4), noise_pos=noise[0], noise_nor=noise[1], rng=rng)
    res = []
    for t in lattice_pool(_bounds(obj), n):
        res += world.execute(t)
    return res


def test_incremental_update_equals_refit(sphere):
    res = _touches(sphere, 24, 0)
    inc = ShapeMap(_bounds(sphere), free_space=False)
    for k in range(0, 24, 8):
        inc.update(res[k:k + 8])
    batch = ShapeMap(_bounds(sphere), free_space=False).update(res)
    Q = np.random.default_rng(1).uniform(-0.04, 0.04, (300, 3))
    m1, s1 = inc.mean_std(Q)
    L_inc, d_inc, lam = inc._gp.L.copy(), inc._gp._dKi.copy(), inc._gp.scale
    inc.refit()
    assert np.allclose(inc._gp.L, L_inc, atol=1e-10)
    # diag(K^-1), kept incrementally for the calibration, matches the refactorised one
    assert np.allclose(inc._gp._dKi, d_inc, rtol=1e-8) and np.isclose(inc._gp.scale, lam, rtol=1e-8)
    m2, s2 = batch.mean_std(Q)
    # same observations, in another order of blocks: the same posterior
    assert np.allclose(m1, m2, atol=1e-9) and np.allclose(s1, s2, atol=1e-9)


def test_deferred_columns_and_inverse_match_a_refactorisation():
    """V = L^-1 K(X, Q) and diag(K^-1) are extended only when read; whatever the order of
    additions, reads, newly tracked points and a relocation, they equal a refactorisation."""
    from touchloc.mapping.gpis import GPIS

    rng = np.random.default_rng(3)
    prior = lambda P: (np.linalg.norm(P, axis=1) - 0.03, P / np.linalg.norm(P, axis=1)[:, None])  # noqa: E731

    def rows(k):
        P = rng.normal(size=(k, 3))
        P *= 0.03 / np.linalg.norm(P, axis=1)[:, None]
        X = np.concatenate([P, np.repeat(P, 3, 0)])
        kind = np.concatenate([np.full(k, -1), np.tile(np.arange(3), k)])
        y = np.concatenate([np.zeros(k), (P / 0.03).ravel()])
        return X, kind, y, np.full(4 * k, 1e-6)

    gp = GPIS(0.02, 0.01, prior)
    gp.add(*rows(5))
    gp.track(rng.uniform(-0.05, 0.05, (40, 3)))
    gp.add(*rows(4))
    gp.add(*rows(3))                      # two additions pending for V and L^-1
    mean_pending = gp.tracked_mean()      # brings V up to date, not L^-1
    assert gp._nv == gp.n and gp._nl < gp.n
    assert np.allclose(mean_pending, gp.mean(gp.Q), atol=1e-12)
    gp.add(*rows(6))
    gp.track(rng.uniform(-0.05, 0.05, (30, 3)))   # new columns over every row
    gp.untrack(np.arange(70) % 3 != 0)
    gp.add(*rows(2))
    L, dKi, V, sd = gp.L.copy(), gp._dKi.copy(), gp._V.copy(), gp.tracked_std()
    mu = gp.tracked_mean()
    assert np.allclose(mu, gp.mean(gp.Q), atol=1e-12)
    ref = GPIS(0.02, 0.01, prior)
    ref.add(gp.X, gp.kind, gp.y, gp.noise)
    ref.track(gp.Q)
    assert np.allclose(L, ref.L, atol=1e-10) and np.allclose(dKi, ref._dKi, rtol=1e-8)
    assert np.allclose(V, ref._V, atol=1e-10) and np.allclose(sd, ref.tracked_std(), rtol=1e-8)
    # a relocation of the last rows, with additions pending before it
    gp.add(*rows(3))
    n = gp.n
    X = gp.X.copy()
    X[n - 20:] += 0.001
    gp.relocate(X, gp.y, gp.Q, start=n - 20)
    assert gp._nv == gp._nl == gp.n == n
    ref = GPIS(0.02, 0.01, prior)
    ref.add(gp.X, gp.kind, gp.y, gp.noise)
    ref.track(gp.Q)
    assert np.allclose(gp._dKi, ref._dKi, rtol=1e-8) and np.allclose(gp._V, ref._V, atol=1e-10)
    # a relocation that re-adds more rows than the triangular products' threshold
    from touchloc.mapping.gpis import _TRMM_ROWS

    gp.add(*rows(40))
    X = gp.X.copy()
    start = gp.n - (_TRMM_ROWS + 40)
    X[start:] -= 0.0005
    gp.relocate(X, gp.y, gp.Q, start=start)
    ref = GPIS(0.02, 0.01, prior)
    ref.add(gp.X, gp.kind, gp.y, gp.noise)
    ref.track(gp.Q)
    assert np.allclose(gp.L, ref.L, atol=1e-10) and np.allclose(gp._dKi, ref._dKi, rtol=1e-8)
    assert np.allclose(gp._V, ref._V, atol=1e-10)


@pytest.mark.parametrize("k", [5, 127, 128, 300])
def test_triangular_products_equal_the_general_ones_and_leave_their_inputs(k):
    from touchloc.mapping.gpis import _lower_times, _times_lower

    rng = np.random.default_rng(k)
    big = rng.normal(size=(k + 7, 260))
    B = big[3:3 + k, 5:205]                      # a view, not contiguous
    A = np.tril(rng.normal(size=(200, 200)))
    Ak = np.tril(rng.normal(size=(k, k)))
    Ck = rng.normal(size=(k, 200))
    before = big.copy()
    assert np.allclose(_times_lower(B, A), B @ A, rtol=1e-12, atol=1e-12)
    assert np.allclose(_lower_times(Ak, B), Ak @ B, rtol=1e-12, atol=1e-12)
    assert np.allclose(_times_lower(np.ascontiguousarray(B), A), B @ A, rtol=1e-12, atol=1e-12)
    assert np.array_equal(big, before)
    C0 = Ck.copy()                               # a contiguous input is not overwritten either
    _lower_times(Ak, Ck)
    assert np.array_equal(Ck, C0)


def _batches_and_map(obj, free_space=True, k=4):
    res = _touches(obj, 3 * k, 0)
    batches = [res[i:i + 3] for i in range(0, 3 * k, 3)]
    m = ShapeMap(_bounds(obj, 0.03), free_space=free_space)
    for b in batches:
        m.update(b)
    return batches, m


def _move(yaw, t):
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
    T[:3, 3] = t
    return T


def test_relocating_the_last_touches_equals_a_map_built_where_they_now_are(sphere):
    from touchloc.mapping import transform_results

    T = _move(0.05, (0.003, -0.002, 0.001))
    batches, m = _batches_and_map(sphere, free_space=False)
    m.relocate([None, None, None, T])
    fresh = ShapeMap(_bounds(sphere, 0.03), free_space=False)
    for b in batches[:3] + [transform_results(batches[3], T)]:
        fresh.update(b)
    q = sphere.sample_surface(300, rng=1)[0]
    assert np.allclose(m.signed_distance(q), fresh.signed_distance(q), atol=1e-10)
    assert np.allclose(m.surface_std(q), fresh.surface_std(q), atol=1e-10)
    assert np.allclose(m.contacts.points, fresh.contacts.points)
    # the stored touches moved too (applied when read; two moves compose)
    pts = lambda mm: np.concatenate([r.contact.points for r in mm.results if r.contact is not None])  # noqa: E731
    assert np.allclose(pts(m), pts(fresh))
    U = _move(-0.02, (0.0, 0.001, 0.0))
    m.relocate([None, U, None, U])
    fresh2 = ShapeMap(_bounds(sphere, 0.03), free_space=False)
    for b in [batches[0], transform_results(batches[1], U), batches[2], transform_results(batches[3], U @ T)]:
        fresh2.update(b)
    assert np.allclose(pts(m), pts(fresh2)) and np.allclose(m.signed_distance(q), fresh2.signed_distance(q), atol=1e-10)


def test_relocation_keeps_the_factors_of_a_refit_and_moves_free_space_with_its_touches(sphere):
    batches, m = _batches_and_map(sphere)
    n_rows = m._gp.n
    m.relocate([None, _move(-0.04, (0.0, 0.002, 0.0)), None, _move(0.03, (-0.001, 0.0, 0.002))])
    gp = m._gp
    L, dKi, V = gp.L.copy(), gp._dKi.copy(), gp._V.copy()
    gp.refactor()
    assert gp.n == n_rows
    assert np.allclose(L, gp.L, atol=1e-10) and np.allclose(dKi, gp._dKi, rtol=1e-8)
    assert np.allclose(V, gp._V, atol=1e-10)
    # moving every touch by one rigid motion moves the whole map with it
    batches, m = _batches_and_map(sphere)
    q = sphere.sample_surface(200, rng=2)[0]
    before = m.signed_distance(q)
    T = _move(0.1, (0.004, 0.0, -0.003))
    m.relocate([T] * 4)
    assert np.allclose(m.signed_distance(q @ T[:3, :3].T + T[:3, 3]), before, atol=1e-9)
    # moves below the tolerance are ignored
    before = m.signed_distance(q)
    m.relocate([_move(1e-7, (1e-7, 0, 0))] * 4, tol=1e-5)
    assert np.array_equal(m.signed_distance(q), before)


def test_mean_and_gradient_in_one_pass_match_the_mean_and_its_differences(sphere):
    _, m = _batches_and_map(sphere)
    gp = m._gp
    lo, hi = _bounds(sphere, 0.03)
    Q = lo + np.random.default_rng(3).random((400, 3)) * (hi - lo)
    mu, g = gp.mean_grad(Q)
    h = 1e-6
    fd = np.stack([(gp.mean(Q + h * e) - gp.mean(Q - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    assert np.allclose(mu, gp.mean(Q), atol=1e-12)
    assert np.allclose(g, fd, atol=1e-6)
    # near the touched surface the gradient is about the outward unit normal
    p, n, _ = sphere.sample_surface(50, rng=4)
    assert np.median(np.einsum("ij,ij->i", gp.mean_grad(p)[1], n)) > 0.8


def test_relocate_rejects_bad_input(sphere):
    _, m = _batches_and_map(sphere, k=2)
    with pytest.raises(ValidationError):
        m.relocate([np.eye(4)])                      # one per update
    with pytest.raises(ValidationError, match=r"transforms\[1\].*reflection"):
        m.relocate([None, np.diag([1.0, 1.0, -1.0, 1.0])])   # a reflection, named by its update
    with pytest.raises(ValidationError, match=r"transforms\[1\]"):
        m.relocate([np.eye(4), np.eye(3)])
    with pytest.raises(ValidationError, match=r"transforms\[0\]"):
        m.relocate([[[1, 2], [3]], None])                      # ragged
    with pytest.raises(ValidationError):
        m.relocate([np.eye(4), np.full((4, 4), np.nan)])
    with pytest.raises(ValidationError):
        m.relocate("nope")
    with pytest.raises(ValidationError):
        m.relocate([None, None], tol=-1.0)


def test_tracked_free_space_mean_matches_the_direct_mean(sphere):
    # the free-space pool's mean is kept by extending L^-1 K(X, Q) block by block
    res = _touches(sphere, 30, 2)
    smap = ShapeMap(_bounds(sphere))
    for k in range(0, 30, 5):
        smap.update(res[k:k + 5])
    gp = smap._gp
    assert len(gp.Q) == len(smap._free) > 20
    assert np.allclose(gp.tracked_mean(), gp.mean(smap._free), atol=1e-9)
    gp.refactor()
    assert np.allclose(gp.tracked_mean(), gp.mean(smap._free), atol=1e-9)


def _pool_run(monkeypatch, sleep, mesh, moves=False):
    """A map of 40 touches of ``mesh`` in batches of 4 (and, with ``moves``, a relocation of
    every other batch half-way), with the pool's far points set aside or not."""
    monkeypatch.setattr(ShapeMap, "_SLEEP", sleep)
    res = _touches(mesh, 40, 3)
    smap = ShapeMap(_bounds(mesh))
    for k in range(0, 40, 4):
        smap.update(res[k:k + 4])
        if moves and k == 20:
            from scipy.spatial.transform import Rotation

            T = np.eye(4)
            T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.02]).as_matrix()
            T[:3, 3] = [0.002, -0.001, 0.0]
            smap.relocate([T if b % 2 else None for b in range(len(smap.batches))])
    return smap


@pytest.mark.parametrize("moves", [False, True])
def test_far_pool_points_set_aside_change_no_bound(monkeypatch, objects, moves):
    # a swept point becomes a bound only where the mean is below c + sd, and sd <= s: points
    # whose mean clears c by 1.5 s cannot become bounds, so setting them aside must leave the
    # same rows (the same bounds at the same places, in the same order) and the same map
    mug = objects["mug"]
    ref = _pool_run(monkeypatch, None, mug, moves)
    got = _pool_run(monkeypatch, (1.5, 2.5), mug, moves)
    n_asleep = len(got._asleep[0])
    assert n_asleep > len(got._free)                       # most of the pool was set aside
    assert len(ref._free) == len(got._free) + n_asleep     # and none was lost
    assert got._gp.n == ref._gp.n and np.array_equal(got._gp.kind, ref._gp.kind)
    assert np.allclose(got._gp.X, ref._gp.X, atol=1e-12)
    q = mug.sample_surface(500, rng=4)[0]
    assert np.allclose(got.signed_distance(q), ref.signed_distance(q), atol=1e-9)
    # the set-aside points moved with their batches (the tracked ones are checked by the GP)
    pool = {tuple(np.round(x, 12)) for x in np.concatenate([got._free, got._asleep[0]])}
    assert pool == {tuple(np.round(x, 12)) for x in ref._free}


def test_tracked_free_space_std_matches_the_direct_std(sphere):
    res = _touches(sphere, 20, 5)
    smap = ShapeMap(_bounds(sphere)).update(res)
    gp = smap._gp
    for calibrated in (True, False):
        assert np.allclose(gp.tracked_std(calibrated=calibrated),
                           gp.mean_std(smap._free, calibrated=calibrated)[1], atol=1e-12)


@pytest.mark.parametrize("mu", [-4.0, -1.0, 0.0, 0.7, 2.5])
def test_free_space_bound_site_matches_the_truncated_gaussian(mu):
    # cavity N(mu, sd^2) times the site must have the moments of the cavity cut to f >= c
    from scipy.stats import truncnorm

    from touchloc.mapping.gpis import bound_site

    sd, c = 0.8, 0.3
    val, var = bound_site(np.array([mu]), np.array([sd]), c)
    post_var = 1.0 / (1.0 / sd**2 + 1.0 / var[0])
    post_mean = post_var * (mu / sd**2 + val[0] / var[0])
    t = truncnorm((c - mu) / sd, np.inf, loc=mu, scale=sd)
    assert np.isclose(post_mean, t.mean(), rtol=1e-6, atol=1e-9)
    assert np.isclose(post_var, t.var(), rtol=1e-5)
    # a bound the belief breaks gives a sharp site near c; one it keeps gives a weak site
    if mu < c - 2 * sd:
        assert abs(val[0] - c) < 0.5 * sd and var[0] < 0.1 * sd**2
    if mu > c + 2 * sd:
        assert var[0] > 10 * sd**2


def test_each_contact_is_predicted_before_it_is_added():
    # the prequential record: every contact after the first touch, scored against the map
    # of the touches before it, whether the touches arrive one by one or in one batch
    box = _quiet(trimesh.creation.box((0.12, 0.06, 0.03)), "box")
    res = _touches(box, 12, 6)
    one_by_one, z2 = ShapeMap(_bounds(box), free_space=False), []
    for r in res:
        if one_by_one._gp.n and r.contact is not None:
            mu, sd = one_by_one._gp.mean_std(r.contact.points, calibrated=False)
            z2 += list(mu**2 / (sd**2 + one_by_one.sigma_pos**2))
        one_by_one.update([r])
    batch = ShapeMap(_bounds(box), free_space=False).update(res)
    for m in (one_by_one, batch):
        total, count = m._gp._preq
        assert count == len(z2) == sum(r.contact is not None for r in res[1:])
        assert np.isclose(total, np.sum(z2), rtol=1e-6)
        assert m._gp.scale >= np.mean(z2) - 1e-9


def test_prequential_scale_widens_the_band_between_sparse_touches():
    # 15 touches on a box: the fit at the contacts (leave-one-out) looks fine, but the map
    # is wrong between them; the one-step-ahead errors see it
    box = _quiet(trimesh.creation.box((0.12, 0.06, 0.03)), "box")
    smap = ShapeMap(_bounds(box)).update(_touches(box, 15, 3))
    gp = smap._gp
    a = gp.alpha[gp.scored]
    loo = max(1.0, float(np.mean(a * a / gp._dKi[gp.scored])))
    assert gp.scale > 2 * loo
    truth, _, _ = box.sample_surface(3000, rng=4)
    mu, sd = smap.mean_std(truth)
    _, raw = gp.mean_std(truth, calibrated=False)
    held = np.mean(np.abs(mu) <= 2 * sd)
    held_loo = np.mean(np.abs(mu) <= 2 * np.sqrt(np.minimum(loo * raw**2, gp.s2)))
    assert held > held_loo + 0.1


def test_leave_one_out_scale_calibrates_the_band_on_sharp_edges():
    # a box: the smooth kernel cannot follow its edges, so the sensor-noise band is too narrow
    box = _quiet(trimesh.creation.box((0.12, 0.06, 0.03)), "box")
    smap = ShapeMap(_bounds(box)).update(_touches(box, 40, 3))
    truth, _, _ = box.sample_surface(3000, rng=4)
    mu, sd = smap.mean_std(truth)
    lam = smap._gp.scale
    assert lam > 1.3
    held = np.mean(np.abs(mu) <= 2 * sd)
    raw = np.mean(np.abs(mu) <= 2 * sd / np.sqrt(lam))
    assert held >= 0.8 and held > raw + 0.05
    # the scale widens the band only: the mean (and so the mesh) is unchanged
    assert np.allclose(smap.signed_distance(truth), mu, atol=1e-9)


def test_gpis_recovers_a_sphere_and_its_uncertainty_shrinks(sphere):
    res = _touches(sphere, 40, 2)
    smap = ShapeMap(_bounds(sphere))
    far = np.array([[0.0, 0.0, 0.049]])
    before = smap.surface_std(far)[0]
    smap.update(res)
    pts, _, _ = sphere.sample_surface(400, rng=3)
    mu, sd = smap.mean_std(pts)
    assert np.median(np.abs(mu)) < 0.001          # the true surface is the zero level set
    assert np.median(sd) < 0.5 * before            # and is known better than before any touch
    mesh = smap.to_mesh()
    assert chamfer_distance(mesh, sphere, n=3000) < 0.0015
    assert fscore(mesh, sphere, 0.005, n=3000) > 0.95


def test_free_space_pushes_the_gpis_surface_out_of_swept_space(sphere):
    # one contact on top; a miss sweeps right beside the sphere where the prior puts matter
    hit = _touches(sphere, 1, 0)
    lo, hi = _bounds(sphere)
    miss = TouchResult(GuardedTouch((0.036, -0.06, 0.0), (0, 1, 0), 0.12), 0.12, None)
    with_free = ShapeMap((lo, hi), prior=lambda X: (np.linalg.norm(X, axis=1) - 0.045, X / np.linalg.norm(X, axis=1)[:, None]))
    without = ShapeMap((lo, hi), free_space=False,
                       prior=lambda X: (np.linalg.norm(X, axis=1) - 0.045, X / np.linalg.norm(X, axis=1)[:, None]))
    with_free.update(hit + [miss])
    without.update(hit + [miss])
    swept = np.array([[0.036, y, 0.0] for y in np.linspace(-0.02, 0.02, 9)])
    assert np.all(without.signed_distance(swept) < 0)     # the prior alone says "inside"
    assert np.all(with_free.signed_distance(swept) > -0.0005)  # the sweep says otherwise


class _PositionsOnly:
    """A world whose contacts carry no normals."""

    def __init__(self, world):
        self.world = world

    def execute(self, action):
        return [TouchResult(r.touch, r.travel, None if r.contact is None else Contacts(r.contact.points, None))
                for r in self.world.execute(action)]


@pytest.mark.parametrize("seed", [1, 2])
def test_without_normals_free_space_keeps_the_explorer_from_repeating_misses(seed):
    # a flat box touched by a sensor that reports positions only: without free space a miss
    # teaches the map nothing, so the explorer aims again where the map wrongly puts surface
    box = _quiet(trimesh.creation.box((0.10, 0.07, 0.02)), "box")
    hits = {}
    for free in (True, False):
        world = _PositionsOnly(SimulatedWorld(box, np.eye(4), noise_pos=0.001, noise_nor=0.087, rng=seed))
        run = explore(world, _bounds(box), 40, rng=seed, free_space=free)
        assert run.map.contacts.normals is None
        hits[free] = sum(r.hit for r in run.results)
    assert hits[True] >= 0.85 * 40
    assert hits[True] > hits[False]


def test_occupancy_free_space_lowers_and_contacts_raise(sphere):
    lo, hi = _bounds(sphere)
    smap = ShapeMap((lo, hi), method="occupancy", resolution=32)
    p0 = smap._grid.probability(np.zeros((1, 3)))[0]
    miss = TouchResult(GuardedTouch((-0.06, 0.04, 0.0), (1, 0, 0), 0.12), 0.12, None)
    hit = _touches(sphere, 1, 0)
    smap.update([miss] + hit)
    swept = np.array([[x, 0.04, 0.0] for x in np.linspace(-0.04, 0.04, 5)])
    assert np.all(smap._grid.probability(swept) < p0)
    c = hit[0].contact
    behind = c.points - 0.5 * smap._grid.voxel * c.normals
    assert smap._grid.probability(behind)[0] > p0
    assert np.all(smap.surface_std(swept) < 0.5)


def test_occupancy_map_is_a_conservative_carved_hull():
    """Unknown space stays possibly occupied: the map never carves into the object, and
    every sweep removes volume."""
    box = _quiet(trimesh.creation.box((0.06, 0.04, 0.05)), "box")
    world = SimulatedWorld(box, np.eye(4), noise_pos=0.0005, noise_nor=0.03, rng=4)
    smap = ShapeMap(_bounds(box), method="occupancy", resolution=48)
    occupied = [np.mean(smap._grid.logodds > 0)]
    for k in range(3):
        res = [r for t in box_pool(_bounds(box), 100, rng=k, probe_radius=0.004) for r in world.execute(t)]
        smap.update(res)
        occupied.append(np.mean(smap._grid.logodds > 0))
    assert occupied[0] == 1.0 and all(b < a for a, b in zip(occupied, occupied[1:]))
    pts, nrm, _ = box.sample_surface(2000, rng=0)
    inner = pts - 1.5 * smap._grid.voxel * nrm
    assert np.mean(smap._grid.probability(inner) > 0.5) > 0.97
    hull = smap.to_mesh()
    assert hull.mesh.volume > box.mesh.volume


@pytest.mark.parametrize("scale,eps", [((0.03, 0.02, 0.05), (0.2, 0.2)), ((0.025, 0.025, 0.04), (0.2, 1.0)),
                                       ((0.04, 0.03, 0.02), (1.0, 1.0))])
def test_superquadric_recovers_known_parameters(scale, eps):
    from scipy.spatial.transform import Rotation

    from touchloc.mapping.superquadric import Superquadric, inside_outside

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.2, -0.3, 0.5]).as_matrix()
    T[:3, 3] = (0.01, 0.02, -0.01)
    truth = Superquadric(T, np.array(scale), np.array(eps), np.zeros((11, 11)), 0.0)
    P = truth.sample_surface(900)
    X = (P - T[:3, 3]) @ T[:3, :3]
    _, g = inside_outside(X, truth.scale, truth.eps)
    N = g @ T[:3, :3].T
    N /= np.linalg.norm(N, axis=1)[:, None]
    rng = np.random.default_rng(0)
    keep = rng.choice(len(P), 150, replace=False)
    fit = fit_superquadric(Contacts(P[keep] + rng.normal(scale=3e-4, size=(150, 3)), N[keep]), sigma_pos=3e-4)
    # the extents are defined up to a permutation of the axes: compare sorted
    assert np.allclose(np.sort(fit.scale), np.sort(scale), atol=0.002)
    assert fit.rms < 0.001
    assert np.all(fit.std["scale"] < 0.002) and np.all(np.isfinite(fit.std["eps"]))
    # the fitted surface lies on the true one
    Q = fit.sample_surface(400)
    assert np.median(np.abs(truth.radial_distance(Q))) < 0.001


def test_chamfer_and_fscore_metrics(sphere):
    assert chamfer_distance(sphere, sphere, n=2000) < 1e-9
    bigger = _quiet(trimesh.creation.icosphere(4, radius=0.032))
    assert chamfer_distance(bigger, sphere, n=4000) == pytest.approx(0.002, abs=2e-4)
    assert fscore(bigger, sphere, 0.001, n=2000) < 0.05 and fscore(bigger, sphere, 0.003, n=2000) > 0.99


def test_explore_with_every_planner(sphere):
    world = SimulatedWorld(sphere, np.eye(4), noise_pos=0.001, noise_nor=0.087, rng=0)
    for planner in ("random", "lattice", "uncertainty"):
        run = explore(world, _bounds(sphere), 12, planner=planner, rng=1)
        assert run.touches == 12 and len(run.results) == 12
        assert run.map.n_contacts == sum(r.hit for r in run.results)
    # the uncertainty planner aims at the object: more of its touches hit than random ones do
    hits = {p: sum(r.hit for r in explore(world, _bounds(sphere, 0.05), 20, planner=p, rng=2).results)
            for p in ("random", "uncertainty")}
    assert hits["uncertainty"] > hits["random"]


def test_explore_refuses_keywords_it_would_drop_or_pass_on_blindly(sphere):
    """An unknown keyword is a ValidationError naming explore and ShapeMap's keywords, not
    ShapeMap's TypeError; a ShapeMap keyword beside a given map, which would be ignored, is
    refused too. A known one reaches the map."""
    world = SimulatedWorld(sphere, np.eye(4), noise_pos=0.001, noise_nor=0.087, rng=0)
    with pytest.raises(ValidationError, match="unknown keyword arguments \\['progres'\\].*resolution"):
        explore(world, _bounds(sphere), 2, progres=False, rng=0)
    given = ShapeMap(_bounds(sphere))
    with pytest.raises(ValidationError, match="map was given"):
        explore(world, _bounds(sphere), 2, smap=given, resolution=32, rng=0)
    run = explore(world, _bounds(sphere), 2, resolution=32, rng=0)
    assert run.map.resolution == 32 and run.touches == 2


def test_pools_are_well_formed():
    lo, hi = np.zeros(3), np.ones(3) * 0.1
    pool = box_pool((lo, hi), 50, rng=0)
    assert len(pool) == 50 and all(np.linalg.norm(t.origin - 0.05) > 0.08 for t in pool)
    lat = lattice_pool((lo, hi), 64)
    d = np.array([t.direction for t in lat[:8]])
    assert np.abs(d.mean(axis=0)).max() < 0.5      # an early prefix already surrounds the box


def test_save_load_round_trip(tmp_path, sphere):
    smap = ShapeMap(_bounds(sphere)).update(_touches(sphere, 15, 5))
    path = smap.save(tmp_path / "m.npz")
    back = ShapeMap.load(path)
    Q = np.random.default_rng(0).uniform(-0.04, 0.04, (100, 3))
    assert np.allclose(back.signed_distance(Q), smap.signed_distance(Q), atol=1e-12)
    mesh = smap.to_mesh()
    mesh.mesh.export(tmp_path / "m.ply")
    again = MeshObject.from_file(tmp_path / "m.ply", check_units=False)
    assert chamfer_distance(again, mesh, n=2000) < 1e-6


def _on_sphere(points, r=0.03, off=0.0):
    """Touches that meet the sphere's surface (or ``off`` beyond it) at the given directions."""
    out = []
    for d in np.asarray(points, float):
        d = d / np.linalg.norm(d)
        p = (r + off) * d
        out.append(TouchResult(GuardedTouch(p + 0.03 * d, -d, 0.06), 0.03, Contacts([p], [d])))
    return out


def test_thin_leaves_out_the_contacts_the_map_predicts_and_keeps_the_rest(sphere):
    dirs = np.random.default_rng(0).normal(size=(150, 3))
    again = dirs[:2]                                        # where the surface is mapped already
    fat = ShapeMap(_bounds(sphere), sigma_pos=0.001, sigma_nor=0.05, free_space=False)
    thin = ShapeMap(_bounds(sphere), sigma_pos=0.001, sigma_nor=0.05, free_space=False, thin=0.5)
    for m in (fat, thin):
        m.update(_on_sphere(dirs))
    assert thin.thinned > 0 and thin._gp.n < fat._gp.n       # a dense lattice repeats itself
    rows, left = thin._gp.n, thin.thinned
    thin.update(_on_sphere(again))                          # predicted: left out, but recorded
    assert thin._gp.n == rows and thin.thinned == left + 2
    assert thin.n_contacts == fat.n_contacts + 2 and len(thin.results) == len(fat.results) + 2
    thin.update(_on_sphere(again[:1], off=0.006))           # 6 mm off the mapped surface: added
    assert thin._gp.n == rows + 4 and thin.thinned == left + 2
    turned = _on_sphere(again[1:])                          # on the surface, the normal 30 deg off
    n = turned[0].contact.normals[0]
    turned[0] = TouchResult(turned[0].touch, 0.03,
                            Contacts(turned[0].contact.points, [(n + 0.58 * np.cross(n, [0, 0, 1.0]))]))
    thin.update(turned)
    assert thin._gp.n == rows + 8


def test_thin_costs_little_accuracy_on_noisy_touches():
    # a box, which the sphere prior does not explain: 200 touches with 1 mm / 0.05 noise
    box = _quiet(trimesh.creation.box((0.06, 0.05, 0.04)), "box")
    res = _touches(box, 200, 3, noise=(0.001, 0.05))
    maps = [ShapeMap(_bounds(box), sigma_pos=0.001, sigma_nor=0.05, thin=t) for t in (0.0, 0.5)]
    for m in maps:
        for k in range(0, len(res), 10):
            m.update(res[k:k + 10])
    fat, thin = maps
    assert thin.thinned >= 20 and thin._gp.n <= fat._gp.n - 4 * 20
    tp, _, _ = box.sample_surface(2000, rng=7)
    err = [float(np.mean(np.abs(m.signed_distance(tp)))) for m in maps]
    # measured 0.49 and 0.52 mm (39 of 200 left out): within 15 %
    assert err[0] < 0.0007 and err[1] < 1.15 * err[0]


def test_thin_is_kept_by_save_and_checked(tmp_path, sphere):
    m = ShapeMap(_bounds(sphere), free_space=False, thin=0.5).update(_on_sphere(np.eye(3)))
    assert ShapeMap.load(m.save(tmp_path / "t.npz")).thin == 0.5
    for bad in (-0.1, np.nan, np.inf, "a", None):
        with pytest.raises(ValidationError, match="thin"):
            ShapeMap(_bounds(sphere), thin=bad)


def test_map_then_localise_against_the_mapped_mesh():
    from touchloc.belief import PoseRegion, ScalingSeries, add_s
    from touchloc.data import load_object
    from touchloc.models import ProximityModel

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        obj = load_object("cereal")
    world = SimulatedWorld(obj, np.eye(4), noise_pos=0.001, noise_nor=0.087, rng=0)
    run = explore(world, _bounds(obj), 60, planner="uncertainty", rng=0)
    mapped = run.map.to_mesh()
    # the object moved: 10 new contacts at a new pose, localised against the mapped mesh
    region = PoseRegion.box((0, 0, 0), 0.02, rotation="yaw").with_rho(obj.radius)
    fails = 0
    for seed in range(3):
        true = region.sample(1, rng=10 + seed)[0]
        pts, nrm, _ = obj.sample_surface(10, rng=seed)
        rng = np.random.default_rng(seed)
        c = Contacts(pts + rng.normal(scale=0.001, size=pts.shape), nrm + rng.normal(scale=0.05, size=nrm.shape))
        model = ProximityModel(mapped, 0.002, 0.15)
        b = ScalingSeries(model, rng=seed, progress=False).localize(c.transform(true), region)
        fails += add_s(obj, b.map_pose(), true) >= 0.005
    assert fails == 0


@pytest.mark.parametrize("bounds", [((0, 0, 0), (0, 1, 1)), ((0, 0, np.nan), (1, 1, 1)), "box", ((0, 0), (1, 1)),
                                    ((1, 1, 1), (0, 0, 0)), ((0, 0, 0), (100, 100, 100))])
def test_bad_bounds_are_rejected(bounds):
    with pytest.raises(ValidationError):
        ShapeMap(bounds)


def test_bad_input_gets_clear_errors(sphere):
    lo, hi = _bounds(sphere)
    smap = ShapeMap((lo, hi))
    with pytest.raises(MappingError, match="no contacts"):
        smap.to_mesh()
    outside = TouchResult(GuardedTouch((0.5, 0, 0), (1, 0, 0), 0.1), 0.01, Contacts([[0.51, 0, 0]], [[1, 0, 0]]))
    with pytest.raises(ValidationError, match="outside the map's bounds"):
        smap.update([outside])
    assert smap.n_contacts == 0 and len(smap.results) == 0     # nothing half-applied
    with pytest.raises(ValidationError):
        smap.update(["not a result"])
    with pytest.raises(ValidationError):
        Contacts([[0, 0, 0]], [[0, 0, 0]])                     # zero normals never reach a map
    for kw in ({"method": "voxels"}, {"sigma_pos": -1.0}, {"sigma_pos": float("nan")}, {"lengthscale": 0.0},
               {"resolution": 3}, {"prior": "cube"}):
        with pytest.raises(ValidationError):
            ShapeMap((lo, hi), **kw)
    with pytest.raises(ValidationError):
        explore(object(), (lo, hi), 5)
    with pytest.raises(ValidationError):
        explore(SimulatedWorld(sphere, np.eye(4)), (lo, hi), 10**9)
    with pytest.raises(ValidationError):
        fit_superquadric(Contacts(np.zeros((3, 3))))
    with pytest.raises(ValidationError):
        ShapeMap.load(lo)


def test_empty_level_set_is_an_error():
    lo, hi = np.full(3, -0.01), np.full(3, 0.01)
    smap = ShapeMap((lo, hi), method="occupancy", resolution=8)
    c = Contacts([[0.0, 0.0, 0.0]], [[1.0, 0, 0]])
    smap.update([TouchResult(GuardedTouch((0.05, 0, 0), (-1, 0, 0), 0.1), 0.05, c)])
    # sweep every cell of the box several times: nothing can be left occupied
    ys = np.linspace(-0.0095, 0.0095, 16)
    misses = [TouchResult(GuardedTouch((-0.05, y, z), (1, 0, 0), 0.1), 0.1, None) for y in ys for z in ys]
    for _ in range(4):
        smap.update(misses)
    with pytest.raises(MappingError, match="empty level set"):
        smap.to_mesh()
    assert isinstance(MappingError("x"), TouchlocError)


def test_map_command_writes_plot_html_mesh_and_map(tmp_path, capsys):
    from touchloc.cli import main

    files = {k: tmp_path / f"m.{k}" for k in ("png", "html", "obj", "npz")}
    rc = main(["map", "--mesh", "lemon", "--touches", "10", "--plot", str(files["png"]), "--html",
               str(files["html"]), "--save", str(files["obj"]), "--save-map", str(files["npz"])])
    assert rc == 0
    assert all(f.stat().st_size > 1000 for f in files.values())
    out = capsys.readouterr().out
    assert "Chamfer" in out and "F-score" in out
    back = ShapeMap.load(files["npz"])
    assert len(back.results) == 10
    assert MeshObject.from_file(files["obj"], check_units=False).n_faces > 100


def test_map_command_with_a_moving_object(tmp_path, capsys):
    from touchloc.cli import main

    png = tmp_path / "s.png"
    assert main(["map", "--mesh", "lemon", "--touches", "6", "--moving", "push", "--fingers", "3",
                 "--thin", "0.3", "--plot", str(png)]) == 0
    assert png.exists() and (tmp_path / "s_trajectory.png").exists()
    assert main(["map", "--mesh", "lemon", "--touches", "6", "--thin", "-1"]) != 0
    assert "--thin must be" in capsys.readouterr().err


def test_map_command_in_hand_takes_a_calibrated_or_learned_odometry_scale(capsys):
    from touchloc.cli import main

    for scale in ("0.952", "learn", None):
        assert main(["map", "--mesh", "milk", "--touches", "4", "--moving", "inhand", "--fingers", "3"]
                    + ([] if scale is None else ["--odometry-scale", scale])) == 0
        out = capsys.readouterr().out
        # learned unless given (the simulated hand's odometry is biased), and reported
        assert ("scale learned on this run" in out) == (scale != "0.952")
        # and it reports the scale the run's own trajectory implies, ready to be held
        line = [ln for ln in out.splitlines() if "imply an odometry scale" in ln]
        assert len(line) == 1
        implied = line[0].rsplit("--odometry-scale ", 1)[1].split(" --odometry-noise ")
        assert 0.8 <= float(implied[0]) <= 1.25 and 0.0 <= float(implied[1]) < 90.0
    for argv, why in ((["--moving", "inhand", "--odometry-scale", "fast"], "a number or 'learn'"),
                      (["--moving", "inhand", "--odometry-scale", "2"], "odometry_scale must be <="),
                      (["--moving", "push", "--odometry-scale", "0.95"], "needs --moving inhand"),
                      (["--moving", "inhand", "--odometry-noise", "nan"], "--odometry-noise must be"),
                      (["--moving", "inhand", "--odometry-noise", "0"], "--odometry-noise must be")):
        assert main(["map", "--mesh", "milk", "--touches", "2", *argv]) == 1
        assert why in capsys.readouterr().err


def test_map_command_calibrates_the_odometry_on_a_box_and_holds_it(capsys):
    """--calibrate-on turns a box first, reads the scale off its trajectory and holds it on
    the mesh mapped; every moving run reports its pose error against the truth."""
    from touchloc.cli import main

    assert main(["map", "--mesh", "mug", "--touches", "24", "--moving", "inhand", "--fingers", "3",
                 "--calibrate-on", "milk"]) == 0
    out = capsys.readouterr().out
    got = re.search(r"implies a scale of ([0-9.]+) \+- ([0-9.]+) \((\d+) turns", out)
    assert got, out
    scale, sd, turns = float(got.group(1)), float(got.group(2)), int(got.group(3))
    # the simulated hand reports 5 % too much: within three of the calibration's own sd
    assert turns == 24 and 0.0 < sd < 0.05 and abs(scale - 1 / 1.05) <= 3 * sd
    # held, not learned again on the mug
    assert "scale learned on this run" not in out
    err = re.search(r"rotation median ([0-9.]+) deg .*rotation per turn of 24 actions \(median\) ([0-9.]+) deg", out)
    assert err, out
    # one turn at a scale within a few per cent of the right one: a few degrees of drift
    assert float(err.group(2)) < 15.0
    for argv, why in ((["--moving", "push", "--calibrate-on", "milk"], "needs --moving inhand"),
                      (["--moving", "inhand", "--calibrate-on", "milk", "--odometry-scale", "0.95"], "not both"),
                      (["--moving", "inhand", "--calibrate-on", "no-such-mesh.obj"], "no-such-mesh"),
                      (["--moving", "inhand", "--calibrate-on", "milk", "--touches", "1"], "at least three")):
        assert main(["map", "--mesh", "mug", "--touches", "2", *argv]) == 1
        assert why in capsys.readouterr().err


def test_explore_picks_from_a_given_candidate_pool(sphere):
    world = SimulatedWorld(sphere, np.eye(4), rng=0)
    seen = []

    def pool(rng):
        touches = box_pool(_bounds(sphere), 8, rng=rng)
        seen.append({id(t) for t in touches})
        return touches

    for planner in ("uncertainty", "random"):
        seen.clear()
        run = explore(world, _bounds(sphere), 4, planner=planner, candidates=pool, rng=0)
        assert len(seen) == 4
        assert all(id(r.touch) in s for r, s in zip(run.results, seen))
    with pytest.raises(ValidationError):
        explore(world, _bounds(sphere), 2, candidates=lambda rng: ["not a touch"], rng=0)
    with pytest.raises(ValidationError):
        explore(world, _bounds(sphere), 2, candidates=lambda rng: [], rng=0)
    with pytest.raises(ValidationError):
        explore(world, _bounds(sphere), 2, planner="lattice", candidates=pool, rng=0)
    with pytest.raises(ValidationError):
        explore(world, _bounds(sphere), 2, candidates="pool", rng=0)
    with pytest.raises(ValidationError):
        explore(world, _bounds(sphere), 2, candidates=5, rng=0)
    # a fixed list is the pool at every step
    fixed = box_pool(_bounds(sphere), 6, rng=1)
    run = explore(world, _bounds(sphere), 3, candidates=fixed, rng=0)
    assert all(any(r.touch is t for t in fixed) for r in run.results)


def test_gpis_factor_in_two_parts_and_lazily_dropped_pool_points_agree_with_a_refit():
    """Rows added one block at a time (past the merge of the factor's parts), pool points
    tracked and dropped in between (dropped columns left in place until compaction), then
    a relocation of the later rows: the factor, diag(K^-1) and the tracked means and
    deviations must equal a refactorisation and direct predictions."""
    from touchloc.mapping.gpis import GPIS

    rng = np.random.default_rng(4)

    def prior(X):
        r = np.linalg.norm(X, axis=1) + 1e-12
        return r - 0.04, X / r[:, None]

    gp = GPIS(0.02, 0.01, prior)
    gp.track(rng.uniform(-0.06, 0.06, (300, 3)))
    for i in range(60):
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        p = 0.045 * v
        gp.add(np.repeat(p[None], 4, 0), np.array([-1, 0, 1, 2]), np.concatenate([[0.0], v]),
               np.array([1e-6, 3e-3, 3e-3, 3e-3]))
        if i % 5 == 0:
            gp.untrack(rng.random(len(gp.Q)) > 0.2)
            gp.track(rng.uniform(-0.06, 0.06, (20, 3)))
    assert len(gp._L0) > 0 and gp.n > len(gp._L0)           # both parts in use
    assert len(gp._Qp) > len(gp.Q)                          # dropped columns still held

    def check():
        mu, sd = gp.mean_std(gp.Q)
        assert np.allclose(gp.tracked_mean(), mu, atol=1e-10)
        assert np.allclose(gp.tracked_std(), sd, atol=1e-10)
        # the planner's single-precision solve, through both parts of the factor (off by
        # about 1e-7 m here, at a signal deviation of 1 cm)
        mu32, sd32 = gp.mean_std(gp.Q, dtype=np.float32)
        assert np.abs(mu32 - mu).max() < 1e-6 and np.abs(sd32 - sd).max() < 1e-6
        assert np.abs(mu32 - mu).max() > 0.0 or np.abs(sd32 - sd).max() > 0.0   # (another precision ran)
        L, dKi = gp.L.copy(), gp._dKi.copy()
        ref = GPIS(gp.l, np.sqrt(gp.s2), prior)
        ref.add(gp.X, gp.kind, gp.y, gp.noise)
        ref.refactor()
        assert np.allclose(L, ref.L, atol=1e-10) and np.allclose(dKi, ref._dKi, rtol=1e-8)

    check()
    X = gp.X.copy()
    X[120:] += 0.002                                        # move the later rows
    gp.relocate(X, gp.y, gp.Q, start=120)
    assert len(gp._Qp) == len(gp.Q)                         # compacted
    check()


def test_gpis_cholesky_reads_the_lower_triangle_and_jitters_only_when_it_must():
    """The factor comes from LAPACK on the matrix's transpose: it must equal numpy's
    factor of the symmetric matrix (reading the lower triangle alone, as numpy does), be
    lower triangular and C-ordered; a singular kernel matrix (a point observed twice)
    gets a small jitter, and an indefinite one a clear error."""
    from touchloc.mapping.gpis import GPIS, _chol

    rng = np.random.default_rng(5)
    B = rng.normal(size=(60, 60))
    A = B @ B.T + 60 * np.eye(60)
    L = _chol(A)
    assert L.flags["C_CONTIGUOUS"] and np.array_equal(L, np.tril(L))
    assert np.allclose(L, np.linalg.cholesky(A), rtol=0, atol=1e-12)
    garbage = np.tril(A) + np.triu(rng.normal(size=(60, 60)), 1)   # the upper triangle is not read
    assert np.array_equal(_chol(garbage), L)
    assert np.allclose(_chol(np.asfortranarray(A)), L, rtol=0, atol=1e-12)
    gp = GPIS(0.02, 0.01, lambda X: (np.zeros(len(X)), np.zeros((len(X), 3))))
    X = np.array([[0.01, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.02, 0.0]])
    K = gp.kernel(X, np.full(3, -1), X, np.full(3, -1))    # rank 2: the first point twice
    Lk = _chol(K)
    jitter = np.diag(Lk @ Lk.T - K)
    assert np.all(jitter > 0) and np.max(jitter) < 1e-6 * np.mean(np.diag(K))
    with pytest.raises(TouchlocError, match="not positive definite"):
        _chol(-np.eye(3))
    assert _chol(np.zeros((0, 0))).shape == (0, 0)


def test_gpis_kernel_blocks_are_the_derivatives_of_the_value_kernel_and_ignore_row_order():
    """The compiled kernel against finite differences of its own value block (the gradient
    blocks are derivatives of k(x, y) in x and y), and against itself with rows and columns
    shuffled: shuffling breaks the runs of equal points whose exponential it reuses."""
    from touchloc.mapping.gpis import GPIS

    gp = GPIS(0.02, 0.01, lambda X: (np.zeros(len(X)), np.zeros((len(X), 3))))
    rng = np.random.default_rng(7)
    P, Q = rng.normal(scale=0.02, size=(5, 3)), rng.normal(scale=0.02, size=(4, 3))
    kinds = np.array([-1, 0, 1, 2])
    X1, k1 = np.repeat(P, 4, axis=0), np.tile(kinds, 5)       # contacts: a value row and 3 gradient rows each
    X2, k2 = np.vstack([np.repeat(Q, 4, axis=0), Q]), np.concatenate([np.tile(kinds, 4), np.full(4, -1)])
    K = gp.kernel(X1, k1, X2, k2)

    def value(x, y):
        return gp.kernel(x[None], np.array([-1]), y[None], np.array([-1]))[0, 0]

    h = 1e-7
    E = np.eye(3) * h
    for i in range(len(X1)):
        for j in range(len(X2)):
            x, y, a, b = X1[i], X2[j], k1[i], k2[j]
            if a < 0 and b < 0:
                ref = value(x, y)
            elif a < 0:
                ref = (value(x, y + E[b]) - value(x, y - E[b])) / (2 * h)
            elif b < 0:
                ref = (value(x + E[a], y) - value(x - E[a], y)) / (2 * h)
            else:
                ref = (value(x + E[a], y + E[b]) - value(x + E[a], y - E[b]) - value(x - E[a], y + E[b])
                       + value(x - E[a], y - E[b])) / (4 * h * h)
            assert abs(K[i, j] - ref) <= 1e-5 * np.max(np.abs(K)), (i, j, a, b, K[i, j], ref)
    r, c = rng.permutation(len(X1)), rng.permutation(len(X2))
    assert np.allclose(gp.kernel(X1[r], k1[r], X2[c], k2[c]), K[np.ix_(r, c)], rtol=1e-12, atol=0)
    # symmetric where it must be: K(X, X) of values and gradients
    S = gp.kernel(X1, k1, X1, k1)
    assert np.allclose(S, S.T, rtol=1e-12, atol=1e-30)
