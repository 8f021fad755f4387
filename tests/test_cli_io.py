"""touchloc.belief.save_belief / load_belief / pose_to_dict."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touchloc.belief import ParticleBelief, PoseRegion, load_belief, pose_to_dict, save_belief
from touchloc.errors import ValidationError
from touchloc.models import Contacts, ProximityModel


@pytest.mark.parametrize("region", [
    PoseRegion.box((0.1, -0.2, 0.3), 0.05, "full", rho=0.04),
    PoseRegion.planar((0.0, 0.01), 0.02, z=0.05, yaw_range=(-1.0, 2.0)),
    PoseRegion.box((0, 0, 0), (0.01, 0.02, 0.0), Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()),
])
def test_save_load_round_trip(tmp_path, objects, rng, region):
    poses = region.sample(50, rng=rng)
    lw = rng.normal(size=50)
    b = ParticleBelief(poses, lw, region=region, resolution=0.003, degenerate=True)
    c = Contacts(rng.normal(size=(7, 3)), rng.normal(size=(7, 3)))
    model = ProximityModel(objects["can"], 0.002, 0.1)
    path = save_belief(tmp_path / "b", b, contacts=c, model=model, extra={"method": "ss"})
    assert path.suffix == ".npz" and path.exists()
    b2, c2 = load_belief(path)
    assert np.array_equal(b2.poses, b.poses) and np.allclose(b2.log_weights, b.log_weights)
    assert np.array_equal(b2.map_pose(), b.map_pose()) and np.array_equal(b2.info["map_pose"], b.map_pose())
    assert b2.degenerate and b2.resolution == 0.003
    assert b2.region.rotation == region.rotation and b2.region.dim == region.dim
    assert np.array_equal(b2.region.center, region.center) and b2.region.yaw_range == region.yaw_range
    assert b2.region.rho == region.rho
    if region.rotation == "fixed":
        assert np.array_equal(b2.region.fixed_rotation, region.fixed_rotation)
    assert np.array_equal(c2.points, c.points) and np.allclose(c2.normals, c.normals, atol=1e-15)
    assert b2.info["model"] == {"class": "ProximityModel", "sigma_pos": 0.002, "sigma_nor": 0.1,
                                "outlier_distance": None, "mesh": "can"}
    assert b2.info["method"] == "ss"
    # plain arrays only: numpy reads it without pickles
    with np.load(path, allow_pickle=False) as z:
        assert z["poses"].shape == (50, 4, 4) and json.loads(str(z["meta"]))["method"] == "ss"


def test_load_without_region_or_contacts(tmp_path):
    b = ParticleBelief(np.tile(np.eye(4), (3, 1, 1)))
    b2, c2 = load_belief(save_belief(tmp_path / "b.npz", b))
    assert c2 is None and b2.region is None and len(b2) == 3 and not b2.degenerate


def test_load_rejects_what_is_not_a_belief(tmp_path):
    with pytest.raises(ValidationError, match="no such belief file"):
        load_belief(tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    bad.write_text("hello")
    with pytest.raises(ValidationError, match="not a belief file"):
        load_belief(bad)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    with pytest.raises(ValidationError, match="no 'poses'"):
        load_belief(other)
    newer = tmp_path / "newer.npz"
    np.savez(newer, poses=np.eye(4)[None], log_weights=np.zeros(1), format_version=99)
    with pytest.raises(ValidationError, match="newer"):
        load_belief(newer)
    with pytest.raises(ValidationError):
        save_belief(tmp_path / "x.npz", "not a belief")


def test_pose_to_dict_quaternion_is_xyzw(rng):
    R = Rotation.random(random_state=3)
    T = np.eye(4)
    T[:3, :3] = R.as_matrix()
    T[:3, 3] = [0.1, 0.2, 0.3]
    d = pose_to_dict(T)
    assert np.allclose(np.abs(d["quat_xyzw"]), np.abs(R.as_quat()))
    assert np.allclose(Rotation.from_quat(d["quat_xyzw"]).as_matrix(), T[:3, :3])
    assert d["translation"] == [0.1, 0.2, 0.3] and np.array_equal(d["matrix"], T)
    json.dumps(d)
    with pytest.raises(ValidationError):
        pose_to_dict(np.eye(3))
