"""The seed 002 scan simulator: contact only where the pad meets the mesh, phases, output."""

import warnings

import numpy as np
import pytest
import trimesh

from touchloc.errors import ValidationError
from touchloc.models import MeshObject
from touchloc.recognition import PadConfig, TactileScanner, simulate_dataset

# noise-free, no elastic spread: a texel reads > 0 exactly where it is indented
CLEAN = PadConfig(noise=0.0, floor=0.5, spread=0.0, gain_jitter=0.0)


@pytest.fixture(scope="module")
def box():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.box(extents=(0.06, 0.05, 0.04)), name="box")


@pytest.fixture(scope="module")
def sphere():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.icosphere(subdivisions=3, radius=0.03), name="sphere")


def _texel_points(scan, cfg):
    """World positions (n_motion, n*n, 3) of the texel centres on the sensing face."""
    R, c = scan.pad_poses[:, :3, :3], scan.pad_poses[:, :3, 3]
    return c[:, None, :] + np.einsum("kij,tj->kti", R[:, :, :2], cfg.texel_uv)


def test_contact_only_where_the_pad_meets_the_mesh(box, sphere):
    scanner = TactileScanner(CLEAN)
    for obj in (box, sphere):
        scan = scanner.scan(obj, rng=3)
        k = len(scan.pad_poses)
        loaded = scan.frames[:k].reshape(k, -1) > 0
        assert np.array_equal(loaded, scan.depth.reshape(k, -1) > 0)
        # texel centres in the object frame, and their signed distance to the mesh
        P = _texel_points(scan, CLEAN).reshape(-1, 3)
        T = scan.object_pose
        sd = obj.signed_distance((P - T[:3, 3]) @ T[:3, :3]).reshape(k, -1)
        # a loaded texel has mesh within its area (half-diagonal 4.3 mm) and indentation depth
        reach = CLEAN.pitch / np.sqrt(2) + CLEAN.layer_thickness
        assert np.all(sd[loaded] < reach)
        # texels clearly away from the mesh read nothing
        assert not np.any(loaded[sd > reach])
        # every texel whose centre is pressed into the mesh reads pressure
        inside = sd < -1e-5
        assert inside.sum() > 20 and loaded[inside].all()
        # the pad keeps contact through the motion, and is blank after it
        assert loaded.any(axis=1).mean() > 0.8
        assert not np.any(scan.frames[k:])


def test_approach_footprint_of_a_box_top(box):
    scanner = TactileScanner(CLEAN)
    scan = scanner.scan(box, rng=0)
    app = np.flatnonzero(scan.phase == 0)
    assert 1 <= len(app) <= 12
    n_loaded = (scan.frames[app[-1]] > 0).sum()
    # the 60 x 50 mm top covers 10 x 8.3 texels; allow one texel row/column either way
    assert 9 * 7 <= n_loaded <= 12 * 10
    # horizontal during the approach, then tilted to the right (+x) and rolled around
    assert np.allclose(scan.pad_poses[app, 2, 2], 1.0)
    tilt = np.flatnonzero(scan.phase == 1)
    assert scan.pad_poses[tilt[-1], 0, 2] > 0.5  # pad normal leans towards +x
    roll = np.flatnonzero(scan.phase == 2)
    nz = scan.pad_poses[roll, :3, 2]
    az = np.unwrap(np.arctan2(nz[:, 1], nz[:, 0]))
    assert az[-1] - az[0] > np.pi  # the tilt direction turns round the object


def test_output_shape_range_and_determinism(sphere):
    scanner = TactileScanner()
    a = scanner.scan(sphere, rng=7).frames
    b = scanner.scan(sphere, rng=7).frames
    c = scanner.scan(sphere, rng=8).frames
    assert a.shape == (160, 16, 16) and a.dtype == np.uint16
    assert a.max() <= 4095 and a.max() >= PadConfig().contact_threshold
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_scans_differ_by_small_object_motions(box):
    scanner = TactileScanner()
    poses = [scanner.random_object_pose(box, rng=i) for i in range(50)]
    shifts = np.array([p[:2, 3] for p in poses])  # box centred at the origin in its frame
    yaws = np.array([np.arctan2(p[1, 0], p[0, 0]) for p in poses])
    assert 0.002 < shifts.std() < 0.008
    assert np.deg2rad(2) < yaws.std() < np.deg2rad(10)
    # resting on the table
    for p in poses:
        z = (box.mesh.vertices @ p[:3, :3].T + p[:3, 3])[:, 2]
        assert abs(z.min()) < 1e-12


def test_simulate_dataset_labels(box, sphere):
    cfg = PadConfig(n_frames=40)
    X, y = simulate_dataset({"box": box, "sphere": sphere}, 2, scanner=TactileScanner(cfg), rng=0)
    assert X.shape == (4, 40, 16, 16)
    assert y.tolist() == ["box", "box", "sphere", "sphere"]


def test_bad_configuration_is_rejected():
    with pytest.raises(ValidationError, match="pitch"):
        PadConfig(pitch=0.0)
    with pytest.raises(ValidationError, match="contact_threshold"):
        PadConfig(contact_threshold=5000)
    with pytest.raises(ValidationError, match="n_frames"):
        PadConfig(n_frames=0)
    with pytest.raises(ValidationError, match="PadConfig"):
        TactileScanner(config={"pitch": 0.006})
    with pytest.raises(ValidationError, match="objects"):
        simulate_dataset({}, 2)


def test_open_real_mesh_mug_shows_its_rim_first():
    """The bundled mug (two parts, open handle): first contact is the rim, a ring."""
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mug = load_object("mug")
    scan = TactileScanner(PadConfig(n_frames=30, noise=0.0, gain_jitter=0.0)).scan(mug, rng=0)
    assert np.all(np.diff(scan.phase) >= 0)  # approach, tilt, roll-around in order
    app = np.flatnonzero(scan.phase == 0)
    F = scan.frames[app[-1]] > 0
    assert F.sum() >= 20
    # the opening of the cup: blank texels with loaded texels on both sides in their row
    # and in their column (a flat top would leave none)
    left = np.maximum.accumulate(F, axis=1)
    right = np.maximum.accumulate(F[:, ::-1], axis=1)[:, ::-1]
    up = np.maximum.accumulate(F, axis=0)
    down = np.maximum.accumulate(F[::-1], axis=0)[::-1]
    enclosed = ~F & left & right & up & down
    assert enclosed.sum() >= 16
