"""The DNF spread example runs end to end: the estimated spread is near the generator's and
the normalisation counts the sides more often than the tracker without it."""

import re


def test_example_estimates_the_spread_and_counts_better_with_it(capsys, tmp_path, example):
    mod = example("dnf_sensor_spread")
    png = tmp_path / "memories.png"
    assert mod.main(["--datasets", "2", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    truth = float(re.search(r"\(([0-9.]+) deg with the pad's centroid error\)", out).group(1))
    spreads = [float(s) for s in re.findall(r"estimated spread ([0-9.]+) deg", out)]
    assert len(spreads) == 2 and all(abs(s - truth) < 0.25 * truth for s in spreads), out
    on, off = map(float, re.search(r"mean right count: ([0-9.]+) with, ([0-9.]+) without", out).groups())
    assert on > off, out
    assert png.stat().st_size > 10_000
