import numpy as np
import pytest
import trimesh

from touchloc import geometry
from touchloc.errors import ValidationError
from touchloc.models import Contacts, FreeSpaceModel, GaussianDynamics, IntegratedProximityModel, MeshObject
from touchloc.planners import GuardedTouch, TouchResult


def test_dynamics_samples_have_the_stated_spread():
    dyn = GaussianDynamics(0.002, 0.05)
    T0 = geometry.vector_to_pose([[0.1, 0.2, 0.3, 0.5, 0.0, 0.0]])[0]
    X = dyn.sample(np.repeat(T0[None], 20000, axis=0), rng=1)
    dt = X[:, :3, 3] - T0[:3, 3]
    assert np.allclose(dt.std(axis=0), 0.002, rtol=0.03)
    w = geometry.matrix_to_rotvec(X[:, :3, :3] @ T0[:3, :3].T)
    assert np.allclose(w.std(axis=0), 0.05, rtol=0.03)
    assert np.allclose(np.linalg.det(X[:, :3, :3]), 1.0)


def test_planar_dynamics_stay_on_the_table():
    dyn = GaussianDynamics(0.01, 0.1, planar=True)
    X = dyn.sample(np.repeat(np.eye(4)[None], 500, axis=0), rng=2)
    assert np.allclose(X[:, 2, 3], 0.0) and np.allclose(X[:, 2, 2], 1.0)


def test_transition_density_is_the_gaussian_and_integrates_to_one():
    dyn = GaussianDynamics(0.01, 0.1)
    prev = np.eye(4)[None]
    nxt = geometry.vector_to_pose([[0.01, 0.0, 0.0, 0.0, 0.0, 0.0]])
    lt = dyn.log_transition(nxt, prev)
    expect = -0.5 - 3 * np.log(0.01) - 1.5 * np.log(2 * np.pi) - 3 * np.log(0.1) - 1.5 * np.log(2 * np.pi)
    assert lt.shape == (1, 1) and np.isclose(lt[0, 0], expect)
    # planar: integrate numerically over x, y, yaw
    pdyn = GaussianDynamics(0.01, 0.1, planar=True)
    g = np.linspace(-0.05, 0.05, 41)
    a = np.linspace(-0.5, 0.5, 41)
    X, Y, A = np.meshgrid(g, g, a, indexing="ij")
    v = np.zeros((X.size, 6))
    v[:, 0], v[:, 1], v[:, 5] = X.ravel(), Y.ravel(), A.ravel()
    dens = np.exp(pdyn.log_transition(geometry.vector_to_pose(v), prev))[:, 0]
    integral = dens.sum() * (g[1] - g[0]) ** 2 * (a[1] - a[0])
    assert abs(integral - 1.0) < 0.01


def test_dynamics_rejects_negative_sigma():
    with pytest.raises(ValidationError):
        GaussianDynamics(-1.0, 0.1)


@pytest.fixture(scope="module")
def box():
    return MeshObject(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), name="box")


def test_free_space_rules_out_poses_that_intersect_the_sweep(box):
    # a probe swept along x at y = 0.2 without touching anything
    fs = FreeSpaceModel(box, [[-0.3, 0.2, 0.0]], [[0.3, 0.2, 0.0]], radius=0.005, sigma=0.002)
    poses = geometry.vector_to_pose([[0, 0, 0, 0, 0, 0], [0, 0.2, 0, 0, 0, 0], [0, 0.15, 0, 0, 0, 0],
                                     [0, 0.1, 0, 0, 0, 0]])
    c = fs.clearance(poses)[:, 0]
    assert np.allclose(c[[0, 2, 3]], [0.145, -0.005, 0.045], atol=1e-9)
    assert c[1] < -0.05  # the sweep passes through the centre of the box
    ll = fs.log_likelihood(poses)
    assert ll[0] == pytest.approx(0.0, abs=1e-9) and ll[3] == pytest.approx(0.0, abs=1e-6)
    assert ll[1] == pytest.approx(np.log(fs.eps), abs=1e-6)
    assert ll[2] < np.log(0.1)


def test_free_space_from_touch_results(box):
    miss = TouchResult(GuardedTouch((0.0, 0.3, 0.0), (0, -1, 0), max_travel=0.1), travel=0.1)
    fs = FreeSpaceModel.from_results(box, [miss])
    assert np.allclose(fs.ends[0], [0.0, 0.2, 0.0])
    ll = fs.log_likelihood(geometry.vector_to_pose([[0, 0, 0, 0, 0, 0], [0, 0.16, 0, 0, 0, 0]]))
    assert ll[0] > -1e-6 and ll[1] < -5


def test_integrated_model_prefers_the_true_pose_and_is_normalised(box):
    rng = np.random.default_rng(3)
    p, n, _ = box.sample_surface(10, rng=rng)
    contacts = Contacts(p, n)
    model = IntegratedProximityModel(box, 0.003, 0.2, n_samples=3000, rng=0)
    poses = geometry.vector_to_pose([[0, 0, 0, 0, 0, 0], [0.004, 0.004, 0.004, 0, 0, 0], [0, 0, 0, 0, 0.1, 0.2]])
    ll = model.log_likelihood(poses, contacts)
    assert ll[0] > ll[1] and ll[0] > ll[2]
    # position-only density of one contact integrates to ~1 over space
    g = np.linspace(-0.07, 0.07, 57)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    m = IntegratedProximityModel(box, 0.004, None, n_samples=3000, rng=0)
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    # the density of one contact at the identity pose, for all points in one call (the same
    # numbers as one log_likelihood call per point)
    logd = m.query_log_density(pts[::7])
    assert np.allclose(logd[:50], [m.log_likelihood(np.eye(4), Contacts(q[None]))[0] for q in pts[::7][:50]])
    dens = np.exp(logd)
    integral = dens.mean() * (0.14 + (g[1] - g[0])) ** 3
    assert abs(integral - 1.0) < 0.1
