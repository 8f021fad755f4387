"""The DNF spread example runs end to end: the estimated spread is near the generator's and
the normalisation counts the sides more often than the tracker without it."""

import importlib.util
import re
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "dnf_sensor_spread.py"


@pytest.mark.skipif(not EXAMPLE.exists(), reason="examples/ not present")
def test_example_estimates_the_spread_and_counts_better_with_it(capsys, tmp_path):
    spec = importlib.util.spec_from_file_location("dnf_sensor_spread", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    png = tmp_path / "memories.png"
    assert mod.main(["--datasets", "2", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    truth = float(re.search(r"\(([0-9.]+) deg with the pad's centroid error\)", out).group(1))
    spreads = [float(s) for s in re.findall(r"estimated spread ([0-9.]+) deg", out)]
    assert len(spreads) == 2 and all(abs(s - truth) < 0.25 * truth for s in spreads), out
    on, off = map(float, re.search(r"mean right count: ([0-9.]+) with, ([0-9.]+) without", out).groups())
    assert on > off, out
    assert png.stat().st_size > 10_000
