"""End to end: the example localises a hidden mesh with touches on the emulated hand over virtual CAN."""

import importlib.util
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "hardware_localize.py"


@pytest.mark.skipif(not EXAMPLE.exists(), reason="examples/ not present")
def test_example_recovers_the_hidden_pose(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("hardware_localize", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    code = mod.main(["--seed", "1", "--time-scale", "8", "--log", str(tmp_path / "session.jsonl")])
    out = capsys.readouterr().out
    assert "error:" in out, out
    assert code == 0, out   # within 5 mm and 10 deg of the hidden pose
    assert (tmp_path / "session.jsonl").read_text().count("\n") == 13
