import warnings

import numpy as np
import pytest
import trimesh

from touchloc.data import MESHES, load_object, mesh_path
from touchloc.errors import MeshError
from touchloc.models import MeshObject, MeshRepairWarning, MeshUnitsWarning


def test_texture_seams_are_merged_so_closed_objects_are_watertight():
    for name in ["bread", "can", "cereal", "lemon", "milk"]:
        raw = trimesh.load(mesh_path(name), force="mesh", process=False)
        assert not raw.is_watertight  # the file as stored is split at its seams
        with pytest.warns(MeshRepairWarning, match="merged"):
            obj = load_object(name)
        assert obj.is_watertight, name


def test_open_mug_warns_but_loads():
    with pytest.warns(MeshRepairWarning, match="open"):
        obj = load_object("mug")
    assert not obj.is_watertight and obj.n_faces == 864


def test_zero_area_faces_are_ignored_and_milk_stays_closed(objects):
    milk = objects["milk"]
    assert any("zero-area" in r for r in milk.repairs)
    assert milk.n_faces == len(milk.mesh.faces) - 7
    assert np.all(np.isfinite(milk.face_normals))
    assert np.allclose(np.linalg.norm(milk.face_normals, axis=1), 1.0)
    assert milk.is_watertight


def test_bunny_is_not_in_metres():
    with pytest.warns(MeshUnitsWarning, match="metres"):
        MeshObject.from_file(mesh_path("bunny"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshUnitsWarning)
        warnings.simplefilter("ignore", MeshRepairWarning)
        obj = MeshObject.from_file(mesh_path("bunny"), scale=MESHES["bunny"])
    assert 0.1 < obj.extents.max() < 0.25


def test_unusable_meshes_are_rejected(tmp_path):
    with pytest.raises(MeshError, match="empty"):
        MeshObject(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)))
    with pytest.raises(MeshError, match="non-finite"):
        MeshObject(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]], process=False))
    with pytest.raises(MeshError, match="degenerate"):
        MeshObject(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False))
    with pytest.raises(MeshError, match="not found"):
        MeshObject.from_file(tmp_path / "nope.obj")
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(MeshError):
        MeshObject.from_file(bad)


def test_closest_points_match_brute_force_over_all_faces(objects, rng):
    obj = objects["mug"]
    P = obj.bounds[0] - 0.02 + rng.random((120, 3)) * (obj.extents + 0.04)
    cp, nrm, d = obj.closest_points(P)
    tri = obj.triangles
    F = len(tri)
    q = np.repeat(P, F, axis=0)
    c = trimesh.triangles.closest_point(np.tile(tri, (len(P), 1, 1)), q)
    bd = np.linalg.norm(c - q, axis=1).reshape(len(P), F)
    assert np.allclose(d, bd.min(axis=1), rtol=1e-9, atol=1e-12)
    assert np.allclose(np.linalg.norm(cp - P, axis=1), d)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    # trimesh's own query is never closer than ours (it is approximate on some queries)
    _, td, _ = trimesh.proximity.closest_point(obj.mesh, P)
    assert np.all(d <= td + 1e-12)


def test_ray_cast_hits_a_box_exactly_and_misses_return_inf():
    obj = MeshObject(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), name="box")
    O = np.array([[0.3, 0.0, 0.0], [0.3, 0.02, -0.01], [0.3, 0.3, 0.0]])
    D = np.array([[-1.0, 0, 0], [-2.0, 0, 0], [-1.0, 0, 0]])
    dist, pts, nrm = obj.ray_cast(O, D)
    assert np.allclose(dist[:2], 0.25, atol=1e-6)
    assert np.allclose(pts[1], [0.05, 0.02, -0.01], atol=1e-6)
    assert np.allclose(nrm[:2], [1, 0, 0])
    assert np.isinf(dist[2]) and np.all(np.isnan(pts[2]))


def test_contains_and_signed_distance_on_a_sphere():
    obj = MeshObject(trimesh.creation.icosphere(subdivisions=4, radius=0.05), name="ball")
    P = np.array([[0, 0, 0], [0.03, 0, 0], [0.07, 0, 0], [0, 0.1, 0]])
    assert obj.contains(P).tolist() == [True, True, False, False]
    sd = obj.signed_distance(P)
    assert np.allclose(sd, [-0.05, -0.02, 0.02, 0.05], atol=5e-4)


def test_sample_surface_is_on_the_surface_and_seeded(objects):
    obj = objects["lemon"]
    p1, n1, f1 = obj.sample_surface(500, rng=3)
    p2, _, _ = obj.sample_surface(500, rng=3)
    assert np.array_equal(p1, p2)
    _, _, d = obj.closest_points(p1)
    assert d.max() < 1e-9
    assert np.allclose(n1, obj.face_normals[f1])
    # area-uniform: the share of samples on each half of the lemon tracks its area share
    area = obj.mesh.area_faces[obj.valid_faces]
    upper = obj.triangles.mean(axis=1)[:, 2] > 0
    share = area[upper].sum() / area.sum()
    assert abs(np.mean(upper[f1]) - share) < 0.07
