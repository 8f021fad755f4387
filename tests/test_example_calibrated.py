"""The calibrated-belief example runs end to end and both beliefs find the mug."""

import re


def test_example_localises_with_both_likelihoods(capsys, example):
    mod = example("calibrated_belief")
    assert mod.main(["--contacts", "8", "--particles", "600", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"^\s+(proximity|integrated) .*actual ADD-S ([0-9.]+) mm; the hidden pose lies at the "
                      r"(\d+) % level", out, flags=re.M)
    assert [r[0] for r in rows] == ["proximity", "integrated"], out
    for _, adds, level in rows:
        assert float(adds) < 5.0 and 0 <= int(level) <= 100
