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


# -- CSV reading -----------------------------------------------------------------------
ROWS6 = [[0.1, 0.2, 0.3, 0.0, 0.0, 1.0], [0.4, -0.5, 0.6, 1.0, 0.0, 0.0]]


@pytest.mark.parametrize("sep", [",", ";", "\t", " ", "   ", " , "])
def test_csv_separators_are_sniffed(tmp_path, sep):
    path = tmp_path / "c.csv"
    path.write_text("\n".join(sep.join(str(v) for v in r) for r in ROWS6) + "\n")
    c = Contacts.from_csv(path)
    assert np.allclose(c.points, np.array(ROWS6)[:, :3]) and np.allclose(c.normals, np.array(ROWS6)[:, 3:])


def test_csv_header_names_choose_columns_in_any_order(tmp_path):
    path = tmp_path / "c.csv"
    order = ["nz", "X", "ny", "z", "nx", "y"]
    idx = {n: i for i, n in enumerate(["x", "y", "z", "nx", "ny", "nz"])}
    lines = [";".join(order)] + [";".join(str(r[idx[n.lower()]]) for n in order) for r in ROWS6]
    path.write_text("\n".join(lines) + "\n")
    c = Contacts.from_csv(path)
    assert np.allclose(c.points, np.array(ROWS6)[:, :3]) and np.allclose(c.normals, np.array(ROWS6)[:, 3:])


def test_csv_positions_only_comments_and_bom(tmp_path):
    path = tmp_path / "c.csv"
    path.write_bytes("\ufeff# measured today\nz,y,x\n\n3,2,1\n6,5,4\n".encode("utf-8"))
    c = Contacts.from_csv(path)
    assert not c.has_normals and np.allclose(c.points, [[1, 2, 3], [4, 5, 6]])


MALFORMED = {
    "empty": (b"", r"empty"),
    "blank_lines": (b"\n\n  \n", r"empty"),
    "comments_only": (b"# nothing\n", r"empty"),
    "header_only": (b"x,y,z,nx,ny,nz\n", r"empty"),
    "header_only_xyz": (b"x;y;z\n", r"empty"),
    "ragged_short": (b"1,2,3\n4,5\n", r"line 2: 2 columns, expected 3"),
    "ragged_long": (b"1,2,3,0,0,1\n4,5,6,0,0,1,7\n", r"line 2: 7 columns"),
    "ragged_after_header": (b"x,y,z\n1,2,3\n\n4,5,6,7\n", r"line 4"),
    "text_cell": (b"1,2,3\n4,five,6\n", r"line 2, column 2: 'five' is not a number"),
    "empty_cell": (b"1,2,3\n4,,6\n", r"line 2, column 2"),
    "nan_cell": (b"1,2,3\n4,nan,6\n", r"line 2, column 2: 'nan' is not finite"),
    "inf_cell": (b"1,2,inf\n", r"line 1, column 3: 'inf' is not finite"),
    "one_column": (b"1\n2\n", r"line 1: expected 3 or 6 columns"),
    "two_columns": (b"1 2\n3 4\n", r"line 1: expected 3 or 6 columns .*got 2"),
    "four_columns": (b"1;2;3;4\n", r"line 1: expected 3 or 6 columns .*got 4"),
    "unknown_header": (b"x,y,w\n1,2,3\n", r"line 1: unknown column name"),
    "duplicate_header": (b"x,y,x\n1,2,3\n", r"twice"),
    "header_missing_z": (b"x,y,nx,ny,nz,nz2\n1,2,3,4,5,6\n", r"unknown column"),
    "header_incomplete_normals": (b"x,y,z,nx\n1,2,3,4\n", r"must name x,y,z"),
    "zero_normal": (b"1,2,3,0,0,1\n1,2,3,0,0,0\n", r"line 2: the normal is zero"),
    "latin1": ("x,y,z\n1,2,3\n# caf\u00e9\n".encode("latin-1"), r"not a UTF-8"),
    "binary": (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", r"not a UTF-8|NUL"),
    "nul_bytes": (b"1,2,3\x00\n", r"NUL"),
    "mixed_separators": (b"1,2,3\n4;5;6\n", r"line 2"),
    "header_wrong_count": (b"x,y,z\n1,2,3,0,0,1\n", r"line 2: 6 columns, expected 3"),
}


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_csv_malformed_files_raise_validation_errors_naming_the_problem(tmp_path, name):
    content, match = MALFORMED[name]
    path = tmp_path / f"{name}.csv"
    path.write_bytes(content)
    with pytest.raises(ValidationError, match=match) as info:
        Contacts.from_csv(path)
    assert str(path) in str(info.value)


def test_csv_missing_file_and_directory(tmp_path):
    with pytest.raises(ValidationError, match="no such contacts file"):
        Contacts.from_csv(tmp_path / "nope.csv")
    with pytest.raises(ValidationError, match="is a directory"):
        Contacts.from_csv(tmp_path)


@pytest.mark.parametrize("bad", [True, False, 0, 3, 1.5, None, b"c.csv", ["c.csv"]])
def test_csv_non_path_arguments_never_read_a_file_descriptor(bad):
    # open(0) would read stdin and open(3) some descriptor: a bool or int is not a path
    with pytest.raises(ValidationError, match="must be a path"):
        Contacts.from_csv(bad)


def test_csv_round_trip_keeps_order_after_header_reorder(tmp_path, rng):
    c = Contacts(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)))
    path = tmp_path / "c.csv"
    c.to_csv(path)
    assert Contacts.from_csv(str(path)) == Contacts.from_csv(path)
    d = Contacts.from_csv(path)
    assert np.allclose(d.points, c.points, atol=1e-8) and np.allclose(d.normals, c.normals, atol=1e-8)


@pytest.mark.parametrize("idx", [slice(0, 2), slice(2, None), [4, 0, 3], 1, np.array([True, False, True, True, False, False])])
def test_a_subset_equals_the_contacts_built_from_its_rows(idx, rng):
    c = Contacts(rng.normal(size=(6, 3)), rng.normal(size=(6, 3)) * 3.0)
    sub = c[idx]
    rows = np.atleast_1d(np.arange(6)[idx])
    assert sub == Contacts(c.points[rows], c.normals[rows])  # exact: the same arithmetic
    assert not sub.points.flags.writeable and not sub.normals.flags.writeable
    assert not np.shares_memory(sub.points, c.points)
    assert c[[1, 2]].normals is not None and Contacts(c.points)[[1, 2]].normals is None
    with pytest.raises(IndexError):
        c[[7]]
