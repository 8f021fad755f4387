"""The integrated proximity model: a quadrature of the surface integral, checked against
closed forms and a brute-force Monte Carlo sum."""

import numpy as np
import pytest
import trimesh
from scipy.special import logsumexp

from touchloc import geometry
from touchloc.errors import ValidationError
from touchloc.models import Contacts, IntegratedProximityModel, MeshObject, ProximityModel

SIGMA, SIGMA_N = 0.002, 0.1


@pytest.fixture(scope="module")
def ball():
    return MeshObject(trimesh.creation.icosphere(subdivisions=4, radius=0.03), name="ball")


@pytest.fixture(scope="module")
def slab():
    return MeshObject(trimesh.creation.box(extents=(0.2, 0.2, 0.05)), name="slab")


def _noisy(obj, k, seed):
    rng = np.random.default_rng(seed)
    p, n, _ = obj.sample_surface(k, rng=rng)
    p = p + rng.normal(scale=SIGMA, size=p.shape)
    n = n + rng.normal(scale=SIGMA_N, size=n.shape)
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


def _flat(obj):
    """log density of a contact on a flat face, per unit exp(-d_M^2 / 2)."""
    area = obj.mesh.area
    return -np.log(area) - 0.5 * np.log(2 * np.pi * SIGMA**2) - np.log(2 * np.pi * SIGMA_N**2)


def test_on_a_face_interior_it_is_the_proximity_model_with_its_normaliser(slab):
    # the top face, far from its edges: the surface integral over a plane is the 1-D
    # Gaussian across it, which is what the proximity cost keeps
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.05, 0.05, 200), rng.uniform(-0.05, 0.05, 200),
                         0.025 + rng.normal(scale=SIGMA, size=200)])
    n = np.array([0.0, 0.0, 1.0]) + rng.normal(scale=SIGMA_N, size=(200, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    m = IntegratedProximityModel(slab, SIGMA, SIGMA_N)
    prox = ProximityModel(slab, SIGMA, SIGMA_N)
    expect = _flat(slab) - 0.5 * prox.query_costs(p, n)
    d = np.abs(m.query_log_density(p, n) - expect)
    # the midpoint rule is exact to 1e-3 on a plane; a contact 3 sigma off the face loses
    # the terms beyond the 4 sigma cut-off, exp(-7 / 2) = 3 % of its patch
    assert np.median(d) < 2e-3 and np.max(d) < 0.035


def test_on_a_sphere_the_normals_narrow_the_patch_that_explains_a_contact(ball):
    # a contact on the surface with the surface's own normal: surface points at angle t
    # away cost (R t / sigma)^2 + (t / sigma_n)^2, so the patch's Gaussian area shrinks by
    # 1 + sigma^2 / (R sigma_n)^2 against a flat face (0.37 nats here); the proximity
    # model, which keeps the best point only, cannot see this
    R = 0.03
    p, _, _ = ball.sample_surface(300, rng=np.random.default_rng(1))
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    m = IntegratedProximityModel(ball, SIGMA, SIGMA_N)
    expect = -np.log(4 * np.pi * R**2) - 0.5 * np.log(2 * np.pi * SIGMA**2) - np.log(2 * np.pi * SIGMA_N**2) \
        - np.log(1 + SIGMA**2 / (R * SIGMA_N) ** 2)
    got = m.query_log_density(u * R, u)
    # the icosphere's facets (1.2 mm edges) stand for the sphere: within 0.03 nats
    assert abs(np.median(got - expect)) < 0.03
    assert np.ptp(got) < 0.05


def test_the_quadrature_agrees_with_a_brute_force_monte_carlo_sum(ball):
    p, n = _noisy(ball, 120, 2)
    S, Sn, _ = ball.sample_surface(400_000, rng=np.random.default_rng(3))
    const = -1.5 * np.log(2 * np.pi * SIGMA**2) - np.log(2 * np.pi * SIGMA_N**2)
    ref = np.array([logsumexp(-0.5 * (np.sum((S - p[i]) ** 2, 1) / SIGMA**2 + (2 - 2 * Sn @ n[i]) / SIGMA_N**2))
                    for i in range(len(p))]) - np.log(len(S)) + const
    got = IntegratedProximityModel(ball, SIGMA, SIGMA_N).query_log_density(p, n)
    d = got - ref
    # within 3 sigma of the surface the quadrature is used; the reference's own Monte Carlo
    # error is about 0.03 nats (some 300 points per patch)
    near = np.abs(np.linalg.norm(p, axis=1) - 0.03) < 3 * SIGMA
    assert near.sum() >= 110
    assert abs(np.median(d[near])) < 0.02 and np.max(np.abs(d[near])) < 0.12
    # beyond, the tangent-plane approximation ignores the curvature: within a nat here
    assert np.max(np.abs(d)) < 1.0


def test_far_contacts_get_the_tangent_plane_approximation_and_stay_finite(slab):
    m = IntegratedProximityModel(slab, SIGMA, SIGMA_N)
    prox = ProximityModel(slab, SIGMA, SIGMA_N)
    p = np.array([[0.0, 0.0, 0.025 + 0.02], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0]])  # above, far off, inside
    n = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    got = m.query_log_density(p, n)
    assert np.all(np.isfinite(got))
    assert np.allclose(got, _flat(slab) - 0.5 * prox.query_costs(p, n))
    # and the switch at 3 sigma is nearly continuous: just inside against just outside
    z = 0.025 + np.array([2.99, 3.01]) * SIGMA
    q = np.column_stack([np.zeros(2), np.zeros(2), z])
    a, b = m.query_log_density(q, np.tile([0.0, 0.0, 1.0], (2, 1)))
    assert abs((a - b) - 0.5 * (3.01**2 - 2.99**2)) < 0.05


def test_the_likelihood_sums_contacts_and_prefers_the_truth(ball, slab):
    p, n = _noisy(slab, 20, 4)
    T = geometry.vector_to_pose([[0.01, -0.02, 0.03, 0.1, 0.2, 0.3]])[0]
    c = Contacts(p, n).transform(T)
    m = IntegratedProximityModel(slab, SIGMA, SIGMA_N)
    off = T.copy()
    off[:3, 3] += 0.004
    ll = m.log_likelihood(np.stack([T, off]), c)
    P = (p - 0) @ np.eye(3)
    assert np.isclose(ll[0], m.query_log_density(P, n).sum(), atol=1e-6)
    assert ll[0] > ll[1] + 5
    # temperature divides, and chunking does not change the answer
    assert np.allclose(m.log_likelihood(np.stack([T, off]), c, temperature=2.0), ll / 2)
    assert np.allclose(m.log_likelihood(np.stack([T, off]), c, chunk=1), ll)


def test_bad_settings_are_refused(slab):
    with pytest.raises(ValidationError, match="not both"):
        IntegratedProximityModel(slab, SIGMA, SIGMA_N, spacing=0.002, n_samples=100)
    with pytest.raises(ValidationError, match="spacing"):
        IntegratedProximityModel(slab, SIGMA, SIGMA_N, spacing=1e-6)
    with pytest.raises(ValidationError):
        IntegratedProximityModel(slab, SIGMA, SIGMA_N, spacing=float("nan"))
    with pytest.raises(ValidationError, match="surface_prior"):
        IntegratedProximityModel(slab, SIGMA, SIGMA_N, surface_prior=lambda p, n: -np.ones(len(p)))


def test_the_log_density_is_continuous_from_the_surface_outwards(ball):
    # along a ray out of the sphere (the sum, the blend and the approximation in turn),
    # with the surface's normal and with one 40 deg off (which the normals nearby fit
    # badly): no jumps, only the Gaussian's slope of at most 6 sigma x 0.01 sigma per step
    m = IntegratedProximityModel(ball, SIGMA, SIGMA_N)
    u = np.array([0.36, 0.48, 0.8])
    r = 0.03 + SIGMA * np.arange(0.0, 6.0, 0.01)
    off = np.array([np.cos(0.7) * u[0] - np.sin(0.7) * u[1], np.sin(0.7) * u[0] + np.cos(0.7) * u[1], u[2]])
    for n in (u, off):
        ll = m.query_log_density(r[:, None] * u, np.tile(n, (len(r), 1)))
        assert np.all(np.isfinite(ll))
        assert np.max(np.abs(np.diff(ll))) < 0.065


def test_object_frame_queries_refuse_bad_arrays_with_a_clear_error(slab):
    m = IntegratedProximityModel(slab, SIGMA, SIGMA_N)
    prox = ProximityModel(slab, SIGMA, SIGMA_N)
    good = np.array([[0.0, 0.0, 0.026]])
    for f in (m.query_log_density, prox.query_costs):
        for pts, nrm, what in (([[np.nan, 0.0, 0.0]], [[0.0, 0.0, 1.0]], "finite"), ("abc", None, "array"),
                               ([[0.0, 0.0]], None, r"\(M, 3\)"), (good, [[0.0, 0.0, 0.0]], "non-zero"),
                               (good, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], "one row per point")):
            with pytest.raises(ValidationError, match=what):
                f(pts, nrm)
        # normals are made unit length; nothing is returned for no queries
        assert np.allclose(f(good, [[0.0, 0.0, 3.0]]), f(good, [[0.0, 0.0, 1.0]]))
        assert f(np.zeros((0, 3))).shape == (0,)
    # a point absurdly far away has zero density, not NaN
    assert m.query_log_density([[1e300, 0.0, 0.0]], [[1.0, 0.0, 0.0]])[0] == -np.inf
