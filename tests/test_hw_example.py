"""End to end: the example localises a hidden mesh with touches on the emulated hand over virtual CAN."""


def test_example_recovers_the_hidden_pose(tmp_path, capsys, example):
    mod = example("hardware_localize")
    code = mod.main(["--seed", "1", "--time-scale", "8", "--log", str(tmp_path / "session.jsonl")])
    out = capsys.readouterr().out
    assert "error:" in out, out
    assert code == 0, out   # within 5 mm and 10 deg of the hidden pose
    assert (tmp_path / "session.jsonl").read_text().count("\n") == 13
