"""The in-hand example: the odometry calibrated on a box, then held while a mug is mapped."""

import re


def test_example_calibrates_on_a_box_and_holds_it_on_the_mug(capsys, example, tmp_path):
    mod = example("inhand_calibrate")
    png = tmp_path / "inhand.png"
    assert mod.main(["--box-actions", "24", "--actions", "24", "--seed", "1", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    cal = re.search(r"implies a scale of ([0-9.]+) \+- ([0-9.]+) and a turn noise of ([0-9.]+) deg", out)
    assert cal, out
    scale, sd, noise = map(float, cal.groups())
    # the simulated hand reports 5 % too much: the right scale is 1 / 1.05, within the
    # calibration's own three standard deviations
    assert 0.0 < sd < 0.05 and abs(scale - 1 / 1.05) <= 3 * sd, out
    assert 0.0 < noise < 5.0
    held = re.search(r"scale held from the box: scale ([0-9.]+); orientation error per turn ([0-9.]+) deg; .*"
                     r"F-score@5mm ([0-9.]+)", out)
    assert held, out
    # the mug's run holds exactly the box's scale; one turn at a scale within a few per cent
    # of the right one drifts by a few degrees, and the map has the mug's shape
    assert float(held.group(1)) == scale
    assert float(held.group(2)) < 15.0 and float(held.group(3)) > 0.5
    assert png.exists() and png.stat().st_size > 10_000
