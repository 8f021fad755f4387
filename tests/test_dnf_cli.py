"""``touchloc compare-dnf`` and ``touchloc dnf-figure``."""

import argparse

import pytest

from touchloc.dnf import _cli, generate_rotation_dataset, save_recording


def run(argv):
    parser = argparse.ArgumentParser(prog="touchloc")
    _cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


def test_compare_dnf_prints_table_and_saves_plots(tmp_path, capsys):
    rc = run(["compare-dnf", "--objects", "6-gon", "--datasets", "1", "--particles", "50",
              "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "| 6-gon (6 sides) | DNF, corrected | 100% |" in out
    for name in ("histogram", "memory, uncorrected", "particle filter"):
        assert f"| {name} |" in out
    for png in ("dnf_surfaces.png", "dnf_second_half.png", "dnf_orientation_error.png", "dnf_step_time.png"):
        assert (tmp_path / png).read_bytes()[:4] == b"\x89PNG"


def test_compare_dnf_on_a_recording(tmp_path, capsys):
    rec = save_recording(generate_rotation_dataset(8, revolutions=1, rng=2), tmp_path / "rec.npz")
    rc = run(["compare-dnf", "--recording", str(rec), "--particles", "20", "--no-plots"])
    out = capsys.readouterr().out
    assert rc == 0 and "1 data sets: 8-gon x 1" in out and "| 8-gon (8 sides) | DNF, corrected |" in out


def test_dnf_figure_writes_png(tmp_path, capsys):
    path = tmp_path / "fig5.png"
    rc = run(["dnf-figure", "--object", "6-gon", "--dataset", "1", "--out", str(path)])
    out = capsys.readouterr().out
    assert rc == 0 and path.read_bytes()[:4] == b"\x89PNG"
    assert "DNF, corrected: 6 sides at the end" in out


def test_dnf_figure_rejects_unknown_object():
    from touchloc.errors import ValidationError

    with pytest.raises(ValidationError, match="unknown object"):
        run(["dnf-figure", "--object", "7-gon"])


def test_compare_dnf_on_sparse_pad_normals(capsys):
    rc = run(["compare-dnf", "--objects", "4-gon", "--datasets", "1", "--particles", "50", "--normals", "2",
              "--noise", "2", "--drop", "0.1", "--no-plots"])
    out = capsys.readouterr().out
    assert rc == 0 and "| 4-gon (4 sides) | DNF, corrected |" in out
    from touchloc.errors import ValidationError

    with pytest.raises(ValidationError, match="normals_per_contact"):
        run(["compare-dnf", "--objects", "4-gon", "--datasets", "1", "--normals", "41", "--no-plots"])


def test_compare_dnf_on_the_emulated_hand(capsys):
    rc = run(["compare-dnf", "--source", "emulator", "--objects", "6-gon", "--datasets", "1", "--turns", "0.5",
              "--particles", "20", "--no-plots"])
    out = capsys.readouterr().out
    assert rc == 0 and "1 data sets: 6-gon x 1" in out
    assert "| 6-gon (6 sides) | DNF, corrected |" in out and "| 6-gon (6 sides) | particle filter |" in out
    from touchloc.errors import ValidationError

    with pytest.raises(ValidationError, match="min_width"):
        run(["compare-dnf", "--source", "emulator", "--objects", "6-gon", "--datasets", "1", "--turns", "0.5",
             "--min-width", "-2", "--no-plots"])


def test_compare_dnf_adds_the_mapped_family(capsys):
    rc = run(["compare-dnf", "--objects", "4-gon", "--datasets", "1", "--particles", "20", "--no-plots", "--mapped",
              "--normals", "2"])
    out = capsys.readouterr().out
    assert rc == 0 and "| 4-gon (4 sides) | 3-D map (tactile SLAM) |" in out
