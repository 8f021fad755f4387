"""The proximity model against an independent brute force (trimesh's triangle routine)."""

import numpy as np
import pytest
import trimesh

from touchloc import geometry
from touchloc.errors import ValidationError
from touchloc.models import Contacts, MeshObject, ProximityModel, SumModel


def random_poses(rng, n, half=0.05):
    v = np.concatenate([rng.uniform(-half, half, (n, 3)), rng.normal(size=(n, 3))], axis=1)
    return geometry.vector_to_pose(v)


def independent_costs(obj, poses, contacts, sigma_pos, sigma_nor):
    """d_M^2 by definition: minimum over every face of the joint cost (eq. 42.4-42.5)."""
    tri = obj.triangles
    nrm = obj.face_normals
    F = len(tri)
    out = np.empty((len(poses), len(contacts)))
    for i, T in enumerate(poses):
        inv = geometry.invert_poses(T)
        P = contacts.points @ inv[:3, :3].T + inv[:3, 3]
        q = np.repeat(P, F, axis=0)
        c = trimesh.triangles.closest_point(np.tile(tri, (len(P), 1, 1)), q)
        d2 = np.sum((c - q) ** 2, axis=1).reshape(len(P), F) / sigma_pos**2
        if contacts.has_normals and sigma_nor is not None:
            N = contacts.normals @ inv[:3, :3].T
            d2 = d2 + np.sum((N[:, None, :] - nrm[None]) ** 2, axis=2) / sigma_nor**2
        out[i] = d2.min(axis=1)
    return out


def noisy_contacts(obj, rng, k, pose, pos_noise=0.002, nor_noise=0.2):
    p, n, _ = obj.sample_surface(k, rng=rng)
    p = p + rng.normal(scale=pos_noise, size=p.shape)
    n = n + rng.normal(scale=nor_noise, size=n.shape)
    return Contacts(p, n).transform(pose)


@pytest.mark.parametrize("name", ["mug", "milk", "lemon"])
def test_exact_equals_independent_brute_force(objects, rng, name):
    obj = objects[name]
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 8, true)
    poses = np.concatenate([true[None], random_poses(rng, 5, half=0.03)])
    model = ProximityModel(obj, 0.003, 0.3, method="exact")
    got = model.contact_costs(poses, contacts)
    ref = independent_costs(obj, poses, contacts, 0.003, 0.3)
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-9)
    ll = model.log_likelihood(poses, contacts)
    assert np.allclose(ll, -0.5 * ref.sum(axis=1), rtol=1e-9)


def test_position_only_when_normals_absent_or_ignored(objects, rng):
    obj = objects["mug"]
    contacts = noisy_contacts(obj, rng, 6, np.eye(4))
    poses = random_poses(rng, 4, half=0.01)
    ref = independent_costs(obj, poses, contacts.without_normals(), 0.002, None)
    m_joint = ProximityModel(obj, 0.002, 0.1, method="exact")
    m_pos = ProximityModel(obj, 0.002, None, method="exact")
    assert np.allclose(m_joint.contact_costs(poses, contacts.without_normals()), ref, rtol=1e-9)
    assert np.allclose(m_pos.contact_costs(poses, contacts), ref, rtol=1e-9)
    # the normal term only adds cost
    assert np.all(m_joint.contact_costs(poses, contacts) >= ref - 1e-12)


def test_joint_minimum_differs_from_normal_at_closest_point(objects, rng):
    """A contact whose normal disagrees with the nearest face must be explained by a
    face further away when that is cheaper: the joint minimum, not the closest face."""
    obj = objects["cereal"]  # a box: faces meet at right angles
    model = ProximityModel(obj, 0.003, 0.3, method="exact")
    hi = obj.bounds[1]
    # just outside the +x face near the +z edge, but measuring the +z normal
    p = np.array([[hi[0] + 0.001, 0.0, hi[2] - 0.004]])
    n = np.array([[0.0, 0.0, 1.0]])
    joint = model.query_costs(p, n)
    _, nc, d = obj.closest_points(p)
    closest_face_cost = d**2 / 0.003**2 + np.sum((n - nc) ** 2) / 0.3**2
    assert joint[0] < closest_face_cost[0] - 1.0


def test_invariant_to_a_common_rigid_motion(objects, rng):
    obj = objects["lemon"]
    contacts = noisy_contacts(obj, rng, 10, np.eye(4))
    poses = random_poses(rng, 20, half=0.01)
    model = ProximityModel(obj, 0.002, 0.2, method="exact")
    base = model.log_likelihood(poses, contacts)
    G = random_poses(rng, 1, half=0.5)[0]
    moved = model.log_likelihood(G[None] @ poses, contacts.transform(G))
    assert np.allclose(moved, base, rtol=1e-9, atol=1e-9)


def test_true_pose_scores_best(objects, rng):
    obj = objects["can"]
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 20, true, pos_noise=0.001, nor_noise=0.05)
    poses = np.concatenate([true[None], random_poses(rng, 200)])
    ll = ProximityModel(obj, 0.002, 0.1).log_likelihood(poses, contacts)
    assert np.argmax(ll) == 0


def test_temperature_divides_the_log_likelihood(objects, rng):
    obj = objects["mug"]
    contacts = noisy_contacts(obj, rng, 5, np.eye(4))
    poses = random_poses(rng, 7, half=0.02)
    model = ProximityModel(obj, 0.002, 0.2)
    l1 = model.log_likelihood(poses, contacts)
    assert np.allclose(model.log_likelihood(poses, contacts, temperature=4.0), l1 / 4.0)
    for bad in (0, -1, np.nan, np.inf, "hot"):
        with pytest.raises(ValidationError, match="temperature"):
            model.log_likelihood(poses, contacts, temperature=bad)


@pytest.mark.parametrize("name", ["mug", "lemon", "milk"])
def test_fast_is_an_upper_bound_with_small_error_near_the_surface(objects, name):
    rng = np.random.default_rng(7)
    obj = objects[name]
    model = ProximityModel(obj, 0.003, 0.3)
    p, n, _ = obj.sample_surface(4000, rng=rng)
    P = p + rng.normal(scale=0.003, size=p.shape)
    N = n + rng.normal(scale=0.3, size=n.shape)
    N /= np.linalg.norm(N, axis=1)[:, None]
    exact = model.query_costs(P, N, method="exact")
    fast = model.query_costs(P, N, method="fast")
    err = fast - exact
    assert np.all(err >= -1e-9)  # a minimum over fewer faces is never lower
    # documented budget (docs/benchmarks.md): p95 error well below 0.5 on costs of ~2
    assert np.percentile(err, 50) < 0.01
    assert np.percentile(err, 95) < 0.5


def test_fast_position_only_is_exact_and_far_points_fall_back(objects, rng):
    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, None)
    P = obj.bounds[0] - 0.1 + rng.random((3000, 3)) * (obj.extents + 0.2)  # half lie off-grid
    assert np.allclose(model.query_costs(P, method="fast"), model.query_costs(P, method="exact"), rtol=1e-9)
    far = np.array([[5.0, 5.0, 5.0]])  # beyond the grid's coarsest level: the exact tree
    nn = np.array([[0.0, 0.0, 1.0]])
    m2 = ProximityModel(obj, 0.002, 0.2)
    assert np.allclose(m2.query_costs(far, nn, method="fast"), m2.query_costs(far, nn, method="exact"))


def test_fast_grid_levels_are_nested_and_list_far_contacts_with_small_relative_error(objects):
    from touchloc.models.proximity import COARSE_LEVELS

    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, 0.1)
    grid = model._grid(model._weight(True))
    assert len(grid.h) == 1 + len(COARSE_LEVELS)
    hi = grid.lo + grid.shape * grid.h[:, None]
    for a in range(len(grid.h) - 1):  # each level's box inside the next, with larger cells
        assert np.all(grid.lo[a + 1] <= grid.lo[a]) and np.all(hi[a + 1] >= hi[a])
        assert grid.h[a + 1] > grid.h[a]
    # contacts of a wrong pose: 1-3 extents from the mesh, any normal
    rng = np.random.default_rng(3)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    P = obj.bounds.mean(axis=0) + d * obj.extents.max() * rng.uniform(1.0, 3.0, (3000, 1))
    N = rng.normal(size=(3000, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    in_coarse = ~np.all((P >= grid.lo[0]) & (P < hi[0]), axis=1) & np.all((P >= grid.lo[-1]) & (P < hi[-1]), axis=1)
    assert in_coarse.mean() > 0.9  # these are served by the coarse levels, not the tree
    exact = model.query_costs(P, N, method="exact")
    fast = model.query_costs(P, N, method="fast")
    rel = (fast - exact) / exact
    assert np.all(rel >= -1e-9)
    assert np.percentile(rel, 99) < 0.01 and rel.max() < 0.5


def test_every_cell_lists_the_exact_winners_at_its_centre(objects):
    """A cell of the joint grid lists, for each sampled normal (and for the closest face in
    position), a face whose cost at the cell's centre is the exact minimum over all faces:
    the build gathers the faces within reach of the closest one once per centre and must
    lose no winner."""
    from touchloc.models import _kernels as K

    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, 0.1)
    w = model._weight(True)
    tree, grid = obj.bvh(w), model._grid(w)
    dirs = np.vstack([K.fibonacci_sphere(model.grid_normals), np.zeros((1, 3))])
    rng = np.random.default_rng(11)
    for lvl in range(len(grid.h)):
        shape = tuple(grid.shape[lvl])
        for c in rng.choice(int(np.prod(shape)), 60, replace=False):
            centre = grid.lo[lvl] + (np.array(np.unravel_index(c, shape)) + 0.5) * grid.h[lvl]
            P = np.repeat(centre[None], len(dirs), axis=0)
            _, best = K.query_bruteforce(tree.tri, tree.nrm, P, dirs, w)
            cell = grid.base[lvl] + c
            ids = grid.ids[grid.offsets[cell]:grid.offsets[cell + 1]]
            _, listed = K.query_bruteforce(tree.tri[ids], tree.nrm[ids], P, dirs, w)
            assert np.allclose(listed, best, rtol=1e-12, atol=0.0), (lvl, c)


def test_centres_with_too_many_faces_within_reach_search_the_tree_and_list_the_same_winners(monkeypatch):
    """A dense mesh's centre gathers more faces than the build keeps: it searches the tree
    per normal instead, and its list holds the exact winners all the same."""
    from touchloc.models import _kernels as K

    obj = MeshObject(trimesh.creation.icosphere(subdivisions=2, radius=0.04), name="ball")
    w = 0.002 ** 2 / 0.1 ** 2
    tree = obj.bvh(w)
    lo, hi = obj.bounds
    levels = [(lo - 0.01, hi + 0.01, 0.012)]
    grids = {}
    for most in (K.GATHER_MOST, 8):
        monkeypatch.setattr(K, "GATHER_MOST", most)
        grids[most] = K.build_candidate_grid(tree, levels, w, 16)
    dirs = np.vstack([K.fibonacci_sphere(16), np.zeros((1, 3))])
    shape = tuple(grids[8].shape[0])
    for c in range(int(np.prod(shape))):
        centre = grids[8].lo[0] + (np.array(np.unravel_index(c, shape)) + 0.5) * grids[8].h[0]
        P = np.repeat(centre[None], len(dirs), axis=0)
        _, best = K.query_bruteforce(tree.tri, tree.nrm, P, dirs, w)
        for grid in grids.values():
            ids = grid.ids[grid.offsets[c]:grid.offsets[c + 1]]
            _, listed = K.query_bruteforce(tree.tri[ids], tree.nrm[ids], P, dirs, w)
            assert np.allclose(listed, best, rtol=1e-12, atol=0.0), c


def test_near_samples_are_the_exact_winners_below_their_bound(objects, rng):
    """The near lists' samples: per point and direction, the exact winner where its cost
    is below the bound, else no face and the bound (points on, near and far from the
    surface; directions along and against its normals)."""
    from touchloc.models import _kernels as K

    obj = objects["lemon"]
    w, bound = 0.002 ** 2 / 0.1 ** 2, 50 * 0.002 ** 2
    tree = obj.bvh(w)
    p, n, _ = obj.sample_surface(40, rng=rng)
    pts = np.concatenate([p + n * rng.normal(scale=0.004, size=(40, 1)), p + n * 0.05])
    dirs, _ = K.cube_bin_directions()
    dirs = np.ascontiguousarray(dirs[::7])
    cost = np.empty((len(pts), len(dirs)))
    face = np.empty((len(pts), len(dirs)), np.int64)
    K._near_samples(tree.tri, tree.nrm, tree.plo, tree.phi, tree.nlo, tree.nhi, tree.left, tree.right, tree.start,
                    tree.count, pts, dirs, w, bound, cost, face)
    P = np.repeat(pts, len(dirs), axis=0)
    N = np.tile(dirs, (len(pts), 1))
    _, best = K.query_bruteforce(tree.tri, tree.nrm, P, N, w)
    best = best.reshape(cost.shape)
    below = best < bound
    assert 0.05 < below.mean() < 0.5  # both cases are exercised
    assert np.allclose(cost[below], best[below], rtol=1e-12, atol=0.0)
    assert np.all(face[below] >= 0)
    assert np.all(cost[~below] == bound) and np.all(face[~below] == -1)
    f, q, m = face[below], P[below.ravel()], N[below.ravel()]  # the face returned has that cost
    closest = trimesh.triangles.closest_point(tree.tri[f], q)
    mine = np.sum((closest - q) ** 2, axis=1) + w * np.sum((m - tree.nrm[f]) ** 2, axis=1)
    assert np.allclose(mine, best[below], rtol=1e-9, atol=1e-15)


def test_grid_scratch_rows_hold_the_longest_list_for_every_thread(objects):
    """A query keeps its cell list's bounds in a scratch row that the compiled kernels do
    not bounds-check: the row must hold the longest list, joint and position-only, and
    there must be one per numba thread."""
    import numba

    model = ProximityModel(objects["mug"], 0.002, 0.1)
    for w in (model._weight(True), model._weight(False)):
        grid = model._grid(w)
        assert grid.longest == int(np.diff(grid.offsets).max()) > 0
        assert grid.scratch().shape == (numba.config.NUMBA_NUM_THREADS, grid.longest)


def test_cube_bins_cover_every_direction_and_hold_their_own_samples(rng):
    """Every unit vector falls in one of the 384 bins (the axes and the cube's corners
    included), the zero vector in none, and each bin's sample directions (its centre and
    corners) lie in it or on its border."""
    from touchloc.models import _kernels as K

    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    special = np.vstack([np.eye(3), -np.eye(3), np.array([[1, 1, 1], [-1, 1, -1], [1, -1e-300, 0]]) / np.sqrt(3)])
    for v in np.vstack([d, special]):
        side, b = K._cube_bin(*v)
        assert 0 <= side < 6 and 0 <= b < 64
        # the side is the axis of the largest component, with its sign
        a = int(np.argmax(np.abs(v)))
        assert side // 2 == a or abs(abs(v[side // 2]) - abs(v[a])) < 1e-12
    assert K._cube_bin(0.0, 0.0, 0.0) == (-1, 0)
    dirs, corners = K.cube_bin_directions()
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    for b in range(6 * 64):
        side, bit = K._cube_bin(*dirs[b])
        assert side * 64 + bit == b  # a bin's centre is in the bin
        # its corners are the centre's nearest grid points: within a bin's diagonal
        assert np.all(np.degrees(np.arccos(np.clip(dirs[corners[b]] @ dirs[b], -1, 1))) < 12.0)


def test_popcount_counts_the_set_bits(rng):
    from touchloc.models import _kernels as K

    for x in list(rng.integers(0, 2**63, 200, dtype=np.uint64)) + [0, 1, 2**64 - 1, 2**63]:
        x = np.uint64(x)
        assert K._popcount(x) == bin(int(x)).count("1")


def test_plane_and_edge_bound_is_below_the_cost_and_exact_over_the_triangle(objects, rng):
    """The near lists' bound never exceeds a face's joint cost, and equals it where it says
    so (the point's projection lies in the triangle)."""
    from touchloc.models import _kernels as K

    tree = objects["mug"].bvh(0.01)
    planes = K.face_planes(tree.tri, tree.nrm)
    F = len(tree.tri)
    exact_seen = 0
    for _ in range(4000):
        f = int(rng.integers(F))
        c = tree.tri[f].mean(axis=0)
        p = c + rng.normal(scale=0.004, size=3)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        lb, exact = K._face_lb_edges(planes, f, *p, *n, 0.01)
        cost = K._face_cost(tree.tri, tree.nrm, f, *p, *n, 0.01)[0]
        assert lb <= cost * (1 + 1e-9) + 1e-15
        if exact:
            exact_seen += 1
            assert lb == pytest.approx(cost, rel=1e-9, abs=1e-15)
    assert 200 < exact_seen < 3800  # both kinds of point were met


def test_near_lists_are_indexed_consistently_and_answer_close_queries_as_the_exact_method(objects):
    """The normal-keyed lists: one entry per set bit, in order; on queries like those of a
    pose near the truth (another draw than the build's own check) they answer nearly all,
    never below the exact cost and within 0.1 d_M^2 of it on at least 98 % of them."""
    from touchloc.models import _kernels as K

    for name in ("mug", "milk", "lemon", "cereal"):
        obj = objects[name]
        model = ProximityModel(obj, 0.002, np.deg2rad(5))
        w = model._weight(True)
        grid = model._grid(w)
        table = grid.near_cells
        assert table.shape == (int(np.prod(grid.shape[0])), 8) and (table[:, 7] == 0).all()
        bits = np.array([[K._popcount(x) for x in r[:6]] for r in table]).sum(axis=1)
        assert bits.sum() == len(grid.near_entries) > 0
        # each cell's first entry follows the entries of the cells before it
        assert np.array_equal(table[bits > 0, 6].astype(np.int64), np.cumsum(bits)[bits > 0] - bits[bits > 0])
        off, ids = K.unpack_near_lists(grid.near_entries, grid.near_ids, len(grid.tri))
        assert np.all(np.diff(off) > 0) and 0 <= ids.min() and ids.max() < len(grid.tri)
        # the lists passed their own check
        answered, near_off, _, general_off, kept, fast_off = grid.near_check
        assert kept == 1 and answered > 0.95 and near_off <= max(K.NEAR_CHECK_SHARE, general_off)
        assert fast_off <= K.FAST_CHECK_SHARE and grid.fast_ok

        P, N = K.near_check_queries(obj.bvh(w), w, model.sigma_pos**2, n=6000, seed=7)
        found, near = K.near_list_costs(grid, P, N)
        exact = model.query_costs(P, N, method="exact")
        assert found.mean() > 0.95
        err = near[found] / model.sigma_pos**2 - exact[found]
        assert err.min() > -1e-9
        assert np.mean(err > 0.1) < 0.02, name
        # and the fast method gives these answers
        fast = model.query_costs(P, N, method="fast")
        assert np.allclose(fast[found], near[found] / model.sigma_pos**2, rtol=1e-12, atol=0)


def test_auto_leaves_a_fast_grid_that_fails_its_check_for_the_exact_method(objects):
    """At 3 cm of position noise the mug's fast grid answers 7 % of the queries near the
    truth more than 1 d_M^2 above the exact cost (by up to about 14): its check says so,
    and ``auto`` then scores exactly, in the model and in Scaling Series alike. At 2 mm the
    grid passes and ``auto`` uses it."""
    from touchloc.belief import PoseRegion, ScalingSeries
    from touchloc.models import _kernels as K

    obj = objects["mug"]
    coarse = ProximityModel(obj, 0.03, np.deg2rad(5))
    w = coarse._weight(True)
    grid = coarse._grid(w)
    assert not grid.fast_ok and grid.near_check[5] > 0.05
    P, N = K.near_check_queries(obj.bvh(w), w, coarse.sigma_pos**2, n=4000, seed=5)
    exact = coarse.query_costs(P, N, method="exact")
    fast = coarse.query_costs(P, N, method="fast")
    assert np.mean(fast - exact > 1.0) > 0.03          # the grid itself is still off ...
    assert np.array_equal(coarse.query_costs(P, N), exact)   # ... and auto does not use it
    region = PoseRegion.box((0, 0, 0), 0.05, "full")
    poses = region.sample(200, rng=1)
    contacts = Contacts(P[:20], N[:20])
    assert np.array_equal(coarse.contact_costs(poses, contacts), coarse.contact_costs(poses, contacts, method="exact"))
    assert ScalingSeries(coarse)._method(coarse, contacts) == "exact"

    fine = ProximityModel(obj, 0.002, np.deg2rad(5))
    assert fine._grid(fine._weight(True)).fast_ok
    assert ScalingSeries(fine)._method(fine, contacts) == "fast"


def test_near_lists_reach_every_pair_that_costs_less_than_their_threshold(objects):
    """Queries of poses around a posterior's support (1 cm / 0.5 rad off) that cost less
    than NEAR_COST find a list, on the small lemon, whose cells are 1.9 mm, as on the
    larger mug (three cells of the lemon reached 5.6 mm of the 10 mm such a pair can lie
    from the surface: 73 % of them found one)."""
    from touchloc.belief import PoseRegion
    from touchloc.models import _kernels as K
    from touchloc.models import contacts_in_object_frame

    rng = np.random.default_rng(11)
    for name in ("lemon", "mug"):
        obj = objects[name]
        model = ProximityModel(obj, 0.002, np.deg2rad(5))
        grid = model._grid(model._weight(True))
        region = PoseRegion.box((0, 0, 0), 0.1, "full").with_rho(obj.radius)
        true = region.sample(1, rng=rng)[0]
        p, n, _ = obj.sample_surface(30, rng=rng)
        X = region.perturb(np.repeat(true[None], 400, axis=0), 0.01, rng=rng, ball=False)
        P, N = contacts_in_object_frame(X, Contacts(p, n).transform(true))
        P, N = P.reshape(-1, 3), N.reshape(-1, 3)
        exact = model.query_costs(P, N, method="exact")
        found, _ = K.near_list_costs(grid, P, N)
        low = exact < K.NEAR_COST
        assert low.sum() > 1000 and (~low).sum() > 1000, name
        assert found[low].mean() > 0.999, name


def test_coplanar_groups_gather_the_faces_of_each_plane():
    """A box has six planes of two triangles each; a sphere's faces are each alone in their
    plane; two boxes side by side share the planes of their common sides."""
    from touchloc.models import _kernels as K

    def sizes(tri, nrm):
        group = K.coplanar_groups(np.asarray(tri, dtype=float), np.asarray(nrm, dtype=float))
        assert group.shape == (len(tri),) and group.dtype == np.int64
        shared = group[group >= 0]
        # ids run from 0 without gaps, and every id names at least two faces
        assert not len(shared) or (np.unique(shared) == np.arange(shared.max() + 1)).all()
        n = np.bincount(shared) if len(shared) else np.zeros(0, np.int64)
        assert np.all(n >= 2)
        return group, sorted(n.tolist())

    box = trimesh.creation.box((0.1, 0.03, 0.15))
    group, n = sizes(box.triangles, box.face_normals)
    assert n == [2] * 6 and np.all(group >= 0)
    # each group's faces do share a plane: one normal and one offset
    for g in range(6):
        f = np.flatnonzero(group == g)
        assert np.allclose(box.face_normals[f], box.face_normals[f[0]])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    group, n = sizes(ball.triangles, ball.face_normals)
    assert n == [] and np.all(group == -1)
    two = trimesh.util.concatenate([trimesh.creation.box((0.1, 0.1, 0.1)),
                                    trimesh.creation.box((0.1, 0.1, 0.1)).apply_translation((0.2, 0, 0))])
    # the tops, bottoms, fronts and backs of both boxes pair up: four planes of four
    # triangles; the ends facing +-x are four planes of two
    assert sizes(two.triangles, two.face_normals)[1] == [2] * 4 + [4] * 4
    # faces without a unit normal (degenerate) share no plane, even with each other
    nrm = np.asarray(two.face_normals, dtype=float).copy()
    nrm[:3] = 0.0
    group, _ = sizes(two.triangles, nrm)
    assert np.all(group[:3] == -1)


def test_near_lists_hold_every_triangle_of_a_flat_side_that_crosses_their_cell(objects):
    """A flat side split into long triangles is won by whichever holds the query's
    projection; a sliver crossing a cell between its corners wins no sample there. With the
    coplanar faces listed, the cereal box's lists (its sides are split so) answer queries
    near the surface at the exact cost but for one in a thousand or fewer (off by more than
    0.1 d_M^2), where the corners' winners alone were off on 1.3 % and failed their check."""
    from touchloc.models import _kernels as K

    obj = objects["cereal"]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    w = model._weight(True)
    grid = model._grid(w)
    assert grid.near_check[4] == 1 and grid.near_check[1] == 0.0
    P, N = K.near_check_queries(obj.bvh(w), w, model.sigma_pos**2, n=6000, seed=11)
    found, near = K.near_list_costs(grid, P, N)
    exact = model.query_costs(P, N, method="exact")
    assert found.mean() > 0.99
    err = near[found] / model.sigma_pos**2 - exact[found]
    assert err.min() > -1e-9 and np.mean(err > 0.1) <= 0.001 and np.percentile(err, 99.5) < 1e-9
    # the lists stay short: a face and its few coplanar neighbours
    off, _ = K.unpack_near_lists(grid.near_entries, grid.near_ids, len(grid.tri))
    assert np.mean(np.diff(off)) < 3.0


@pytest.mark.parametrize("n_faces", [3, 254, 255, 528, 1023, 65534, 65535, 3_000_000])
def test_packed_near_lists_give_back_every_list(n_faces):
    """Each near list packs into one uint64 entry, or, when longer than the entry holds,
    apart: unpacking gives back every list, face for face, at every id width (8 bits for
    the smallest meshes up to 22 for millions of faces), with lists at the longest that
    fit and one face longer."""
    from touchloc.models import _kernels as K

    rng = np.random.default_rng(n_faces)
    slots = 64 // K.near_width(n_faces)
    assert K.near_width(n_faces) == max(8, int(np.ceil(np.log2(n_faces + 2))))
    lengths = np.r_[rng.integers(1, 3 * slots, size=300), slots, slots + 1, 1]
    off = np.r_[0, np.cumsum(lengths)]
    ids = rng.integers(0, n_faces, size=off[-1])
    ids[:2] = n_faces - 1  # the largest id sits beside the two codes
    entries, over = K.pack_near_lists(off, ids, n_faces)
    assert entries.dtype == np.uint64 and len(entries) == len(lengths)
    assert len(over) == int(np.sum(lengths[lengths > slots] + 1))
    back_off, back_ids = K.unpack_near_lists(entries, over, n_faces)
    assert np.array_equal(back_off, off) and np.array_equal(back_ids, ids)
    assert np.array_equal(K.near_list_kinds(entries, n_faces), np.where(lengths > slots, K.NEAR_LONG, 0))

    # plane lists (one face) and coplanar lists (2 to slots - 1 faces) carry their kind
    kind = np.zeros(len(lengths), np.int64)
    kind[lengths == 1] = K.NEAR_PLANE
    if slots >= 3:
        kind[(lengths >= 2) & (lengths <= slots - 1)] = K.NEAR_COPLANAR
    entries, over = K.pack_near_lists(off, ids, n_faces, kind=kind)
    back_off, back_ids = K.unpack_near_lists(entries, over, n_faces)
    assert np.array_equal(back_off, off) and np.array_equal(back_ids, ids)
    assert np.array_equal(K.near_list_kinds(entries, n_faces), np.where(lengths > slots, K.NEAR_LONG, kind))
    # a long list whose index in ``over`` ends in the code's bits is still long
    b = K.near_width(n_faces)
    code = (1 << b) - 2
    assert K.near_list_kinds(np.array([code | (code << b)], np.uint64), n_faces)[0] == K.NEAR_LONG
    with pytest.raises(ValueError):
        K.pack_near_lists(off, ids, n_faces, kind=np.where(lengths == 2, K.NEAR_PLANE, 0))


def test_lists_in_one_plane_answer_as_the_lists_they_stand_for(objects):
    """A near list whose faces lie in one plane answers from the face that holds the
    query's projection (a coplanar list), or, where its whole cell projects into one face,
    from that face's plane alone (a plane list). Queries anywhere in such lists' cells, with
    their bins' normals, get the answers of the same lists packed as plain ones, bit for
    bit, never below the exact cost; a plane list's answer is its face's plane cost."""
    import dataclasses

    from touchloc.models import _kernels as K

    rng = np.random.default_rng(3)
    dirs, _ = K.cube_bin_directions()
    for name in ("cereal", "bread", "mug"):
        obj = objects[name]
        model = ProximityModel(obj, 0.002, np.deg2rad(5))
        w = model._weight(True)
        grid = model._grid(w)
        n = len(grid.tri)
        kinds = K.near_list_kinds(grid.near_entries, n)
        # each entry's cell and bin: entries follow the cells' set bits in order
        words = grid.near_cells[:, :6, None] >> np.arange(64, dtype=np.uint64)
        cell_of, bin_of = np.nonzero(((words & np.uint64(1)) != 0).reshape(len(grid.near_cells), 384))
        assert len(cell_of) == len(kinds)
        entries, over = K.pack_near_lists(*K.unpack_near_lists(grid.near_entries, grid.near_ids, n), n)
        plain = dataclasses.replace(grid, near_entries=entries, near_ids=over)
        for kind in (K.NEAR_PLANE, K.NEAR_COPLANAR):
            assert (kinds == kind).mean() > 0.005, (name, kind)
            e = rng.choice(np.flatnonzero(kinds == kind), 4000)
            ijk = np.stack(np.unravel_index(cell_of[e], tuple(grid.shape[0])), axis=1)
            P = grid.lo[0] + (ijk + rng.random((len(e), 3))) * grid.h[0]
            N = dirs[bin_of[e]] / np.linalg.norm(dirs[bin_of[e]], axis=1, keepdims=True)
            found, cost = K.near_list_costs(grid, P, N)
            found_plain, cost_plain = K.near_list_costs(plain, P, N)
            assert found.all() and found_plain.all()
            assert np.array_equal(cost, cost_plain), name
            exact = model.query_costs(P, N, method="exact")
            assert np.min(cost / model.sigma_pos**2 - exact) > -1e-9
            if kind == K.NEAR_PLANE:
                f = K.unpack_near_lists(grid.near_entries[e], grid.near_ids, n)[1]
                pl = grid.planes[f]
                d = np.einsum("ij,ij->i", P, pl[:, :3]) - pl[:, 3]
                assert np.allclose(cost, d * d + w * np.sum((N - pl[:, :3]) ** 2, axis=1), rtol=1e-12, atol=0)


def test_the_default_finest_cell_is_no_finer_than_the_noise(objects):
    """The fast grid's default finest cell: a 24th of the largest extent, but at least 1.5
    sigma_pos and at most an 8th of the extent; a given cell is kept as given."""
    from touchloc.models.proximity import GRID_CELL_SIGMAS

    lemon, mug = objects["lemon"], objects["mug"]
    ext = float(lemon.extents.max())
    assert ext / 24 < GRID_CELL_SIGMAS * 0.002 < ext / 8
    assert ProximityModel(lemon, 0.002, 0.1).grid_cell == pytest.approx(GRID_CELL_SIGMAS * 0.002)
    assert ProximityModel(lemon, 0.0005, 0.1).grid_cell == pytest.approx(ext / 24)
    assert ProximityModel(lemon, 0.05, 0.1).grid_cell == pytest.approx(ext / 8)
    assert ProximityModel(mug, 0.002, 0.1).grid_cell == pytest.approx(float(mug.extents.max()) / 24)
    assert ProximityModel(lemon, 0.002, 0.1, grid_cell=0.001).grid_cell == 0.001


def test_near_lists_are_dropped_where_their_check_finds_them_off(objects, rng):
    """A mesh whose faces are small against the cells (a finely tessellated torus) fails the
    lists' check (their answers are off more often than the general lists'): it keeps none,
    and the fast method answers from the cells' general lists and their walk, within 0.1
    d_M^2 of the exact cost on 99.5 % of such queries."""
    from touchloc.models import MeshObject
    from touchloc.models import _kernels as K

    # 20,000 faces (halves of 1.6-3.5 mm by 3.8 mm quads): off on 12 % of the check's queries, far from the
    # 1 % threshold (100 x 50 sections are off on 1.03 % since the lists hold coplanar faces)
    obj = MeshObject(trimesh.creation.torus(0.08, 0.03, major_sections=200, minor_sections=50), name="torus")
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    w = model._weight(True)
    grid = model._grid(w)
    answered, near_off, _, general_off, kept, fast_off = grid.near_check
    assert kept == 0 and near_off > max(K.NEAR_CHECK_SHARE, general_off)
    # the fast method answers from the general lists, and those pass the check
    assert fast_off <= general_off and grid.fast_ok
    assert len(grid.near_cells) == 0 and len(grid.near_entries) == 0 and len(grid.near_ids) == 0
    P, N = K.near_check_queries(obj.bvh(w), w, model.sigma_pos**2, n=4000, seed=7)
    found, _ = K.near_list_costs(grid, P, N)
    assert not found.any()
    err = model.query_costs(P, N, method="fast") - model.query_costs(P, N, method="exact")
    assert err.min() > -1e-9 and np.mean(err > 0.1) < 0.005


def test_near_lists_are_not_built_where_faces_crowd_a_samples_reach():
    """Faces small against a sample's reach (a 5120-face sphere at 5 mm of noise: hundreds
    within it) would make a long build of lists that fail their check: none is built."""
    from touchloc.models import MeshObject
    from touchloc.models import _kernels as K

    obj = MeshObject(trimesh.creation.icosphere(subdivisions=4, radius=0.05), name="sphere")
    # 1 cm cells (the default would be 4 mm): a reach of three cells crowds it the more, and
    # the general lists build in a tenth of the time
    model = ProximityModel(obj, 0.005, 0.1, grid_cell=0.01)
    w = model._weight(True)
    grid = model._grid(w)
    # no lists, so nothing of theirs is checked; the general lists still are
    assert len(grid.near_cells) == 0 and (grid.near_check[[0, 1, 2, 4]] == 0).all()
    assert grid.near_check[5] <= grid.near_check[3] and grid.fast_ok
    lo, hi = obj.bounds
    shape = np.ceil((hi - lo + 2 * model.grid_margin) / model.grid_cell).astype(np.int64)
    assert K.build_near_lists(obj.bvh(w), lo - model.grid_margin, model.grid_cell, shape, w, 0.005**2) is None


def test_auto_uses_the_grid_from_its_pair_threshold_and_not_below(objects, rng):
    from touchloc.models.proximity import AUTO_FAST_PAIRS

    obj = objects["milk"]
    model = ProximityModel(obj, 0.002, 0.1, grid_cell=0.0123)  # a grid no other test builds
    contacts = noisy_contacts(obj, rng, 10, np.eye(4))

    def grids():
        return [k for k in obj._cache if isinstance(k, tuple) and k[0] == "grid" and k[2] == 0.0123]

    model.contact_costs(random_poses(rng, AUTO_FAST_PAIRS // 10 - 1), contacts)
    assert grids() == []
    model.contact_costs(random_poses(rng, AUTO_FAST_PAIRS // 10), contacts)
    assert len(grids()) == 1


@pytest.mark.parametrize("method", ["exact", "fast"])
def test_pose_batch_pass_matches_the_per_query_path_and_respects_budgets(objects, rng, method):
    """The compiled poses x contacts pass gives the costs of moving the contacts into each
    frame and querying them one by one; with a budget, a pose is either complete (the same
    costs) or stopped with a partial sum between its budget and its full sum."""
    from touchloc.models.proximity import _to_object_frame

    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 7, true, nor_noise=0.05)
    poses = np.concatenate([true[None], random_poses(rng, 3000, half=0.03)])
    P, N = _to_object_frame(poses, contacts)
    ref = model.query_costs(P.reshape(-1, 3), N.reshape(-1, 3), method=method).reshape(len(poses), -1)
    got, done = model._budget_costs(poses, contacts, method)
    assert done.all()
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(model.contact_costs(poses, contacts, method=method), ref, rtol=1e-9, atol=1e-9)
    full = ref.sum(axis=1)
    budget = np.quantile(full, 0.3) * rng.uniform(0.5, 1.5, len(poses))
    part, done = model._budget_costs(poses, contacts, method, budget=budget)
    assert 0 < done.sum() < len(poses)
    assert np.all(done == (full < budget))
    np.testing.assert_allclose(part[done], ref[done], rtol=1e-9, atol=1e-9)
    s = part[~done].sum(axis=1)
    assert np.all(s >= budget[~done] * (1 - 1e-12))
    assert np.all(s <= full[~done] * (1 + 1e-12))


@pytest.mark.parametrize("method", ["exact", "fast"])
def test_outlier_distance_caps_each_contact_and_keeps_the_budget_semantics(objects, rng, method):
    """With ``outlier_distance`` every pair costs min(d_M^2, distance^2), in the per-query
    path and in the compiled pass; budgets still stop a pose only once its (capped) sum
    reaches them."""
    from touchloc.models.proximity import _to_object_frame

    obj = objects["mug"]
    plain = ProximityModel(obj, 0.002, np.deg2rad(5))
    capped = ProximityModel(obj, 0.002, np.deg2rad(5), outlier_distance=4.0)
    assert capped.cost_cap == 16.0 and plain.cost_cap == np.inf and "outlier_distance=4.0" in repr(capped)
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 7, true, nor_noise=0.05)
    from touchloc.models import GaussianDynamics

    near = GaussianDynamics(0.004, 0.1).sample(np.repeat(true[None], 1500, axis=0), rng=rng)
    poses = np.concatenate([true[None], near, random_poses(rng, 500, half=0.03)])
    ref = np.minimum(plain.contact_costs(poses, contacts, method=method), 16.0)
    assert 0.2 < np.mean(ref == 16.0) < 0.95  # the cap binds on some pairs, not on all
    P, N = _to_object_frame(poses, contacts)
    per_query = capped.query_costs(P.reshape(-1, 3), N.reshape(-1, 3), method=method).reshape(len(poses), -1)
    np.testing.assert_allclose(per_query, ref, rtol=1e-9, atol=1e-9)
    got, done = capped._budget_costs(poses, contacts, method)
    assert done.all()
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
    full = ref.sum(axis=1)
    budget = np.quantile(full, 0.3) * rng.uniform(0.5, 1.5, len(poses))
    part, done = capped._budget_costs(poses, contacts, method, budget=budget)
    assert np.all(done == (full < budget))
    np.testing.assert_allclose(part[done], ref[done], rtol=1e-9, atol=1e-9)
    s = part[~done].sum(axis=1)
    assert np.all(s >= budget[~done] * (1 - 1e-12)) and np.all(s <= full[~done] * (1 + 1e-12))
    # the log-likelihood is bounded below by K caps
    assert np.all(capped.log_likelihood(poses, contacts) >= -0.5 * 16.0 * len(contacts) - 1e-9)


def test_outlier_distance_must_be_a_positive_finite_number(objects):
    for bad in (0.0, -1.0, np.inf, np.nan, "7", True):
        with pytest.raises(ValidationError, match="outlier_distance"):
            ProximityModel(objects["mug"], 0.002, 0.1, outlier_distance=bad)


def test_bad_arguments_are_rejected(objects):
    obj = objects["mug"]
    with pytest.raises(ValidationError, match="sigma_pos"):
        ProximityModel(obj, 0.0)
    with pytest.raises(ValidationError, match="sigma_nor"):
        ProximityModel(obj, 0.002, -1.0)
    with pytest.raises(ValidationError, match="method"):
        ProximityModel(obj, 0.002, method="magic")
    with pytest.raises(ValidationError, match="MeshObject"):
        ProximityModel("mug.obj", 0.002)
    model = ProximityModel(obj, 0.002, 0.1)
    c = Contacts(np.zeros((2, 3)))
    with pytest.raises(ValidationError, match=r"\(N, 4, 4\)"):
        model.log_likelihood(np.eye(3), c)
    with pytest.raises(ValidationError, match="finite"):
        model.log_likelihood(np.full((4, 4), np.nan), c)
    with pytest.raises(ValidationError, match="empty"):
        model.log_likelihood(np.eye(4), Contacts(np.zeros((0, 3))))
    with pytest.raises(ValidationError, match="Contacts"):
        model.log_likelihood(np.eye(4), np.zeros((2, 3)))


def test_models_add(objects, rng):
    obj = objects["mug"]
    contacts = noisy_contacts(obj, rng, 4, np.eye(4))
    poses = random_poses(rng, 5, half=0.01)
    a = ProximityModel(obj, 0.002, 0.2)
    b = ProximityModel(obj, 0.004, None)
    s = a + b
    assert isinstance(s, SumModel) and len((s + a).models) == 3
    assert np.allclose(s.log_likelihood(poses, contacts),
                       a.log_likelihood(poses, contacts) + b.log_likelihood(poses, contacts))


def test_face_lower_bound_never_exceeds_the_face_cost(objects):
    """The bound that lets a search skip a face's closest-point routine (plane distance
    plus normal term) is below the face's joint cost for any point, normal and face."""
    from touchloc.models import _kernels as K

    obj = objects["mug"]
    tree = obj.bvh(0.0)
    rng = np.random.default_rng(11)
    w = 0.002 ** 2 / 0.1 ** 2
    P = obj.bounds[0] - 0.05 + rng.random((3000, 3)) * (obj.extents + 0.1)
    N = rng.normal(size=(3000, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    F = rng.integers(0, len(tree.tri), 3000)
    gap = []
    for p, n, f in zip(P, N, F):
        lb = K._face_lb(tree.tri, tree.nrm, f, *p, *n, w)
        cost = K._face_cost(tree.tri, tree.nrm, f, *p, *n, w)[0]
        gap.append(cost - lb)
    gap = np.array(gap)
    assert gap.min() >= -1e-12
    assert np.mean(gap > 1e-9) > 0.5  # a bound, not the cost itself: most points project off the face


def test_thread_choice_runs_the_faster_version_and_explores_the_other():
    from touchloc.models._kernels import _ThreadChoice

    ch = _ThreadChoice(512, 4096, explore=4)
    assert ch.pick(100) == 0 and ch.pick(5000) == 1       # outside the middle: fixed
    assert ch.pick(1000) == 0                             # nothing measured yet: one thread first
    ch.record(0, 1000, 1.0)                               # a first call is not counted (compiling)
    assert ch.rate == [None, None]
    ch.record(0, 1000, 1e-3)
    assert ch.pick(1000) == 1                             # the parallel version not measured yet
    ch.record(1, 1000, 1.0)
    ch.record(1, 1000, 5e-4)
    ch.record(0, 2000, 5e-3)                              # one thread: 1 then 2.5 us per pair
    assert ch.rate[0] == pytest.approx(0.8 * 1e-6 + 0.2 * 2.5e-6) and ch.rate[1] == pytest.approx(5e-7)
    picks = [ch.pick(1000) for _ in range(8)]
    assert picks.count(1) == 6 and picks.count(0) == 2   # the faster, and every 4th call the other
    ch.record(0, 100, 1.0)                                # sizes outside the middle teach nothing
    assert ch.rate[0] == pytest.approx(1.3e-6)


def test_pose_costs_are_the_same_on_one_thread_and_in_parallel(objects, rng):
    """The choice of kernel version changes the time only: every row is computed alike."""
    from touchloc.models import _kernels as K

    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 10, true, nor_noise=0.05)
    poses = np.concatenate([true[None], random_poses(rng, 150, half=0.03)])
    budget = np.full(len(poses), 0.5 * np.median(model._budget_costs(poses, contacts, "exact")[0].sum(axis=1)))
    saved = K.POSE_COSTS_THREADS
    out = {}
    try:
        for which, (low, high) in {"one": (10**9, 10**9), "parallel": (0, 0)}.items():
            K.POSE_COSTS_THREADS = K._ThreadChoice(low, high)
            for method in ("exact", "fast"):
                out[which, method] = model._budget_costs(poses, contacts, method, budget=budget)
    finally:
        K.POSE_COSTS_THREADS = saved
    for method in ("exact", "fast"):
        (a, da), (b, db) = out["one", method], out["parallel", method]
        assert np.array_equal(a, b) and np.array_equal(da, db) and 0 < da.sum() < len(poses)


@pytest.mark.parametrize("name", ["mug", "lemon", "bread"])
@pytest.mark.parametrize("normals", [True, False])
def test_the_bound_table_never_exceeds_the_exact_cost(objects, rng, name, normals):
    """Lower bounds of d_M^2 near the surface, in the table's margin and beyond it, with
    and without an outlier cap; and they are informative away from the surface."""
    obj = objects[name]
    ext = float(obj.extents.max())
    for cap in (None, 3.0):
        model = ProximityModel(obj, 0.002, np.deg2rad(5) if normals else None, outlier_distance=cap)
        true = random_poses(rng, 1)[0]
        contacts = noisy_contacts(obj, rng, 12, true, pos_noise=0.004, nor_noise=0.3)
        if not normals:
            contacts = Contacts(contacts.points)
        poses = np.concatenate([random_poses(rng, 150, half=0.01) @ true,      # near the surface
                                random_poses(rng, 150, half=0.5 * ext) @ true,  # in the margin
                                random_poses(rng, 50, half=3.0 * ext) @ true])   # beyond the table
        exact = model._budget_costs(poses, contacts, "exact")[0]
        lower = model._lower_costs(poses, contacts)
        assert lower.shape == exact.shape and np.all(lower >= 0)
        assert np.all(lower <= exact)
        far = exact > 0.5 * min(100.0, model.cost_cap)
        assert far.sum() > 100 and np.median(lower[far] / exact[far]) > 0.2  # a bound that prunes


@pytest.mark.parametrize("name", ["mug", "lemon"])
def test_a_bound_is_the_cost_dilated_by_at_most_twice_the_slack(objects, rng, name):
    """On the table's grid, sqrt(bound) >= sqrt(cost) - 2 slack (the cost of the nearest
    surface point within 2 slack in the joint metric), and the slack is tight: some
    queries come within a fifth of it."""
    from touchloc.models._bounds import BINS, _bin_of, bin_reach, cube_map_dirs

    obj = objects[name]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 12, true, pos_noise=0.004, nor_noise=0.3)
    v = np.concatenate([rng.uniform(-0.03, 0.03, (300, 3)), rng.normal(scale=0.3, size=(300, 3))], axis=1)
    poses = geometry.vector_to_pose(v) @ true
    s2 = model.sigma_pos**2
    exact = model._budget_costs(poses, contacts, "exact")[0] * s2  # m^2
    lower = model._lower_costs(poses, contacts) * s2
    bound = model._bound(model._weight(True))
    slack = model._bound_slack(contacts)
    assert slack == bound.slack > 0.5 * np.sqrt(3.0) * bound.h
    # the object-frame contacts on the table's grid (beyond it the bound is the box's distance)
    local = np.einsum("nji,nkj->nki", poses[:, :3, :3], contacts.points[None] - poses[:, None, :3, 3])
    on = np.all((local >= bound.lo) & (local < bound.lo + bound.shape * bound.h), axis=2)
    on &= exact < model.cost_cap * s2  # uncapped
    assert on.sum() > 1000
    assert np.all(np.sqrt(lower[on]) >= np.sqrt(exact[on]) - 2.0 * slack - 1e-12)
    assert np.any(np.sqrt(exact[on]) - np.sqrt(lower[on]) > 0.2 * slack)
    # the bins' reach: no direction is farther from its bin's centre (sampled)
    n = rng.normal(size=(20000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = cube_map_dirs(BINS)
    own = np.array([_bin_of(x, y, z, BINS) for x, y, z in n])
    reach = np.linalg.norm(n - d[own], axis=1)
    assert reach.max() <= bin_reach(BINS) < 1.03 * reach.max()


def test_costs_stopped_by_their_bounds_still_reach_the_budget(objects, rng):
    """With lower bounds, a pose stops as soon as its costs so far plus its remaining
    bounds reach the budget: its row then sums to at least the budget and no entry exceeds
    its cost; every completed row is the plain evaluation's."""
    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 10, true, nor_noise=0.05)
    poses = np.concatenate([true[None], random_poses(rng, 400, half=0.03) @ true])
    lower = model._lower_costs(poses, contacts)
    for method in ("exact", "fast"):
        full = model._budget_costs(poses, contacts, method)[0]
        budget = np.full(len(poses), np.quantile(full.sum(axis=1), 0.3) * (1 + 1e-7))  # equal to no row sum
        plain, plain_done = model._budget_costs(poses, contacts, method, budget=budget)
        got, done = model._budget_costs(poses, contacts, method, budget=budget, lower=lower)
        assert np.array_equal(done, full.sum(axis=1) < budget)  # the same poses complete
        assert np.array_equal(done, plain_done)
        assert np.array_equal(got[done], full[done])
        assert np.all(got[~done].sum(axis=1) >= budget[~done] * (1 - 1e-12))
        assert np.all(got <= full * (1 + 1e-12))
        # the bounds stop some poses without a single search, and the rest earlier
        assert np.any(np.all(got[~done] == lower[~done], axis=1))
        assert np.count_nonzero(got[~done] != lower[~done]) < np.count_nonzero(plain[~done])


@pytest.mark.parametrize("n_poses", [400, 20])   # the parallel kernel and the one-thread one
def test_bound_lookups_stop_once_their_sum_reaches_the_limit(objects, rng, n_poses):
    """Taken in a given order, a pose's lookups stop once their sum reaches the limit: a
    row that stays below it is the full row bit for bit; a stopped row sums to at least
    the limit and holds each pair's bound or 0 (not looked up)."""
    obj = objects["mug"]
    model = ProximityModel(obj, 0.002, np.deg2rad(5))
    true = random_poses(rng, 1)[0]
    contacts = noisy_contacts(obj, rng, 12, true, nor_noise=0.05)
    poses = random_poses(rng, n_poses, half=0.05) @ true
    full = model._lower_costs(poses, contacts)
    limit = float(np.quantile(full.sum(axis=1), 0.4)) * (1 + 1e-9)
    order = rng.permutation(len(contacts))
    got = model._lower_costs(poses, contacts, limit=limit, order=order)
    below = full.sum(axis=1) < limit
    assert 0 < below.sum() < n_poses
    np.testing.assert_array_equal(got[below], full[below])
    assert np.all(got[~below].sum(axis=1) >= limit * (1 - 1e-12))
    assert np.all((got == full) | (got == 0.0))
    # the pairs looked up are those whose predecessors in the order sum to less than the limit
    ordered = full[:, order]
    before = np.concatenate([np.zeros((len(poses), 1)), np.cumsum(ordered, axis=1)[:, :-1]], axis=1)
    np.testing.assert_array_equal(got[:, order], np.where(before < limit, ordered, 0.0))
    assert np.count_nonzero(got[~below]) < np.count_nonzero(full[~below])
    np.testing.assert_array_equal(model._lower_costs(poses, contacts, limit=np.inf, order=order), full)


def test_kernels_compile_one_signature_whatever_the_inputs_flags_and_layout(objects, rng):
    # numba types an array by its layout and its read-only flag: a frozen Contacts, a
    # Fortran-ordered or strided batch or a read-only one must not compile a kernel a second
    # time (minutes for the likelihood kernels), and must give the same answers
    from touchloc.models import IntegratedProximityModel, _bounds, _kernels, integrated

    obj = objects["milk"]
    poses = random_poses(rng, 600, half=0.01)
    c = noisy_contacts(obj, rng, 8, np.eye(4))
    assert not c.points.flags.writeable
    frozen = poses.copy()
    frozen.flags.writeable = False
    fortran = np.asfortranarray(poses)
    P_strided = np.repeat(c.points, 2, axis=0)[::2]
    N_frozen = c.normals.copy()
    N_frozen.flags.writeable = False
    joint, pos = ProximityModel(obj, 0.002, 0.2), ProximityModel(obj, 0.002, None)
    for model in (joint, pos):
        for method in ("exact", "fast"):
            ref = model.contact_costs(poses, Contacts(c.points.copy(), c.normals.copy()), method=method)
            for P, rows in ((frozen, ref), (fortran, ref), (poses[::2], ref[::2]), (poses[:7], ref[:7])):
                np.testing.assert_array_equal(model.contact_costs(P, c, method=method), rows)
            q = model.query_costs(P_strided, N_frozen, method=method)
            np.testing.assert_array_equal(q, model.query_costs(P_strided.copy(), c.normals.copy(), method=method))
        model._lower_costs(frozen, c)
    IntegratedProximityModel(obj, 0.002, 0.2, spacing=0.01).query_log_density(P_strided, N_frozen)
    many = {}
    for mod in (_kernels, _bounds, integrated):
        for name in dir(mod):
            f = getattr(mod, name)
            if hasattr(f, "signatures") and len(f.signatures) > 1:
                many[f"{mod.__name__}.{name}"] = [str(s) for s in f.signatures]
    assert not many, many
