import numpy as np
import pytest

from touchloc import geometry
from touchloc.errors import TouchlocError, ValidationError
from touchloc.models import Contacts


def test_normals_are_normalised_and_arrays_read_only():
    c = Contacts([[0, 0, 0], [1, 2, 3]], [[0, 0, 2], [3, 0, 0]])
    assert np.allclose(np.linalg.norm(c.normals, axis=1), 1.0)
    assert np.allclose(c.normals[0], [0, 0, 1])
    with pytest.raises(ValueError):
        c.points[0, 0] = 5.0


def test_input_is_copied():
    p = np.zeros((2, 3))
    c = Contacts(p)
    p[0, 0] = 1.0
    assert c.points[0, 0] == 0.0


@pytest.mark.parametrize(
    "points, normals, match",
    [
        (np.zeros((5, 2)), None, r"\(5, 2\)"),
        ([[0, 0, np.nan]], None, "finite"),
        ([[0, 0, np.inf]], None, "finite"),
        (np.zeros((2, 3)), np.zeros((3, 3)), "must match"),
        (np.zeros((1, 3)), [[0, 0, 0]], "non-zero"),
        (np.zeros((1, 3)), [[0, np.nan, 1]], "finite"),
        ("abc", None, "finite floats"),
    ],
)
def test_bad_inputs_rejected_with_clear_errors(points, normals, match):
    with pytest.raises(ValidationError, match=match):
        Contacts(points, normals)


def test_errors_share_the_library_base_class():
    with pytest.raises(TouchlocError):
        Contacts(np.zeros((1, 2)))


def test_transform_moves_points_and_rotates_normals(rng):
    P = rng.normal(size=(6, 3))
    N = rng.normal(size=(6, 3))
    c = Contacts(P, N)
    T = geometry.vector_to_pose([[0.1, -0.2, 0.3, 0.4, -0.5, 0.6]])[0]
    ct = c.transform(T)
    assert np.allclose(ct.points, P @ T[:3, :3].T + T[:3, 3])
    assert np.allclose(ct.normals, c.normals @ T[:3, :3].T)
    back = ct.transform(geometry.invert_poses(T))
    assert np.allclose(back.points, P) and np.allclose(back.normals, c.normals)


def test_transform_rejects_non_rigid():
    with pytest.raises(ValidationError, match="orthonormal"):
        Contacts(np.zeros((1, 3))).transform(np.diag([2.0, 1, 1, 1]))


def test_concatenate_keeps_normals_only_when_all_have_them():
    a = Contacts(np.zeros((2, 3)), np.tile([0, 0, 1.0], (2, 1)))
    b = Contacts(np.ones((1, 3)), [[1.0, 0, 0]])
    ab = a + b
    assert len(ab) == 3 and ab.has_normals
    assert np.allclose(ab.points[2], 1.0)
    assert not Contacts.concatenate([a, Contacts(np.ones((1, 3)))]).has_normals
    assert len(Contacts.concatenate([])) == 0


def test_indexing_and_csv_round_trip(tmp_path, rng):
    c = Contacts(rng.normal(size=(4, 3)), rng.normal(size=(4, 3)))
    assert len(c[1:3]) == 2 and np.allclose(c[2].points, c.points[2:3])
    path = tmp_path / "c.csv"
    c.to_csv(path)
    d = Contacts.from_csv(path)
    assert np.allclose(d.points, c.points, atol=1e-8) and np.allclose(d.normals, c.normals, atol=1e-8)
    Contacts(c.points).to_csv(path)
    assert not Contacts.from_csv(path).has_normals
