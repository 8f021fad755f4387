"""The in-hand turn from one feature's angle about the axis (mapping._feature_turn)."""

import numpy as np
import pytest

from touchloc.mapping._feature_turn import FeatureTurn, wrap


def _turned(rng, steps=96, bias=0.05, slip=np.deg2rad(0.5), every=6, phi=1.2, outliers=0):
    """A body of revolution (radius 40 mm, 100 mm tall) with a feature at angle ``phi``
    (radius 70 mm, within 8 deg of it), turned 15 deg a step about z with an odometry
    ``bias`` too large: the true turns, the reported ones and each step's world contacts."""
    truth, reported, contacts, t = [], [], [], 0.0
    for k in range(steps):
        t += np.deg2rad(15.0) + rng.normal(scale=slip)
        truth.append(t)
        reported.append(np.deg2rad(15.0) * (1.0 + bias))
        ang = rng.uniform(-np.pi, np.pi, 3)
        P = np.c_[0.04 * np.cos(ang), 0.04 * np.sin(ang), rng.uniform(0.0, 0.1, 3)]
        if k % every == every - 1:
            f = phi + t + rng.normal(scale=np.deg2rad(5.0))
            P = np.vstack([P, [0.07 * np.cos(f), 0.07 * np.sin(f), rng.uniform(0.03, 0.07)]])
        if outliers and k % every == 2:
            f = rng.uniform(-np.pi, np.pi)
            P = np.vstack([P, [0.07 * np.cos(f), 0.07 * np.sin(f), 0.05]])
        contacts.append(P)
    return np.array(truth), np.array(reported), contacts


def _run(ft, reported, contacts):
    out = []
    for R, P in zip(reported, contacts):
        ft.predict(R)
        ft.update(P, np.zeros(3), np.array([0.0, 0.0, 1.0]))
        out.append(ft.turn)
    return np.array(out)


def test_the_feature_filter_learns_the_scale_and_holds_the_turn():
    truth, reported, contacts = _turned(np.random.default_rng(0))
    ft = FeatureTurn()
    filtered = _run(ft, reported, contacts)
    # 16 sightings; the first comes before 20 contacts have set the body's radius
    assert ft.started and ft.used == 15
    assert ft.scale == pytest.approx(1 / 1.05, abs=0.005)
    # the odometry alone is 72 deg off after four turns; the filter holds the turn to the
    # sightings' noise (5 deg) and the slip between them
    err = np.degrees(np.abs(wrap(filtered - truth)))
    assert np.degrees(abs(np.sum(reported) - truth[-1])) > 60
    assert np.median(err[48:]) < 6.0 and np.max(err[48:]) < 15.0
    # the smoothed turns use the later sightings for the earlier steps too: the first turn's
    # drift, made before the scale was learned, is taken out
    smooth = np.degrees(np.abs(wrap(ft.smoothed() - truth)))
    assert len(smooth) == len(truth) and smooth[-1] == pytest.approx(err[-1])
    assert np.median(smooth[:24]) < 0.3 * np.median(err[:24])
    assert np.max(smooth) < 7.0


def test_the_feature_filter_ignores_the_body_and_gates_stray_contacts():
    truth, reported, contacts = _turned(np.random.default_rng(1), outliers=True)
    ft = FeatureTurn()
    _run(ft, reported, contacts)
    # 15 sightings taken and 16 strays at random angles beyond the body: most strays gated
    assert 15 <= ft.used <= 23
    assert ft.scale == pytest.approx(1 / 1.05, abs=0.015)
    # a body alone (no contact beyond the median radius by the margin) never starts it
    body = FeatureTurn()
    _run(body, reported, [P[:3] for P in contacts])
    assert not body.started and body.used == 0 and body.scale == 1.0
