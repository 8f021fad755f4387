"""The calibrated-belief example runs end to end and both beliefs find the mug."""

import importlib.util
import re
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "calibrated_belief.py"


@pytest.mark.skipif(not EXAMPLE.exists(), reason="examples/ not present")
def test_example_localises_with_both_likelihoods(capsys):
    spec = importlib.util.spec_from_file_location("calibrated_belief", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--contacts", "8", "--particles", "600", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"^\s+(proximity|integrated) .*actual ADD-S ([0-9.]+) mm; the hidden pose lies at the "
                      r"(\d+) % level", out, flags=re.M)
    assert [r[0] for r in rows] == ["proximity", "integrated"], out
    for _, adds, level in rows:
        assert float(adds) < 5.0 and 0 <= int(level) <= 100
