"""Kinematics, tactile blobs -> contacts, the guarded-touch executor and the session log."""

import json
import math
import warnings

import numpy as np
import pytest
import trimesh

from touchloc.errors import HardwareTimeout, ValidationError
from touchloc.hardware import (GuardedTouchExecutor, PadLayout, SDH2Kinematics, SDHFirmwareError, SessionLog,
                               find_blobs, frame_to_contacts, read_session, replay, session_contacts)
from touchloc.hardware.emulator import EmulatedRig, SimWorld
from touchloc.models import Contacts, MeshObject
from touchloc.planners import GuardedTouch, TouchResult

KIN = SDH2Kinematics()


# -- kinematics (facts: sdh2_kinematics.md) ------------------------------------------------------
def test_fingertip_matches_closed_form():
    rng = np.random.default_rng(0)
    bases = {0: (33.0, 19.053), 1: (0.0, -38.105), 2: (-33.0, 19.053)}
    fac = {0: (-1, -1), 1: (1, 1), 2: (1, -1)}
    axes = {0: (0, 1, 2), 1: (None, 3, 4), 2: (0, 5, 6)}
    for _ in range(20):
        a = np.radians(rng.uniform([0, -90, -90, -90, -90, -90, -90], [90] + [90] * 6))
        tips = KIN.fingertips(a)
        for f in range(3):
            a0 = 0.0 if axes[f][0] is None else a[axes[f][0]]
            a1, a2 = a[axes[f][1]], a[axes[f][2]]
            L = 86.5 * math.sin(a1) + 68.5 * math.sin(a1 + a2)
            want = np.array([fac[f][0] * L * math.sin(a0) + bases[f][0],
                             fac[f][1] * L * math.cos(a0) + bases[f][1],
                             86.5 * math.cos(a1) + 68.5 * math.cos(a1 + a2) + 17.0]) * 1e-3
            np.testing.assert_allclose(tips[f], want, atol=1e-12)


def test_closing_directions():
    np.testing.assert_allclose(KIN.closing_direction(0, 0.0), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(KIN.closing_direction(2, 0.0), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(KIN.closing_direction(1, 1.0), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(KIN.closing_direction(0, math.pi / 2), [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(KIN.closing_direction(2, math.pi / 2), [1, 0, 0], atol=1e-12)


def test_planar_ik_round_trip_and_pad_normal():
    for f, a0 in ((0, 0.7), (1, 0.0), (2, 1.2)):
        for r, z in ((0.0, 0.11), (0.03, 0.1), (-0.02, 0.09)):
            q = KIN.planar_ik(f, r, z)
            assert q is not None
            a = np.zeros(7)
            ax = ((0, 1, 2), (None, 3, 4), (0, 5, 6))[f]
            if ax[0] is not None:
                a[0] = a0
            a[ax[1]], a[ax[2]] = q
            np.testing.assert_allclose(KIN.probe_point(a, f), KIN.plane_to_hand(f, a0, r, z), atol=1e-9)
            th = q[0] + q[1]
            c = KIN.closing_direction(f, a0)
            np.testing.assert_allclose(KIN.pad_normal(a, 2 * f + 1), math.cos(th) * c - math.sin(th) * np.array([0, 0, 1]),
                                       atol=1e-12)
    assert KIN.planar_ik(0, 0.3, 0.3) is None  # out of reach


def test_pad_layout_parameters_and_matrix_info():
    class Info:
        cells_x, cells_y, texel_width, texel_height = 4, 10, 5.0, 4.0
    k = KIN.with_matrix_info([Info()] * 6)
    assert k.pads[3].cells_x == 4 and k.pads[3].texel_width == pytest.approx(0.005)
    assert k.texel_points(np.zeros(7), 3).shape == (10, 4, 3)
    flipped = PadLayout(6, 13, row0_at_tip=True)
    assert flipped.local_coordinates(0, 0)[0] > PadLayout(6, 13).local_coordinates(0, 0)[0]
    with pytest.raises(ValidationError):
        PadLayout(0, 3)


# -- blobs -> contacts (seed 000, II-C) ----------------------------------------------------------
def _empty():
    return [np.zeros((p.cells_y, p.cells_x), dtype=np.uint16) for p in KIN.pads]


def test_blob_centroid_covariance_and_contact():
    mats = _empty()
    mats[1][4:7, 2:5] = [[100, 200, 100], [200, 800, 200], [100, 200, 100]]
    angles = np.radians([30, 10, 20, 0, 0, 0, 0])
    blobs = find_blobs(mats, angles, KIN, threshold=50)
    assert len(blobs) == 1
    b = blobs[0]
    np.testing.assert_allclose(b.centroid, [3.0, 5.0])
    w = np.array([[100, 200, 100], [200, 800, 200], [100, 200, 100]], float)
    var = (w.sum(0) * np.array([1, 0, 1])).sum() / w.sum()
    np.testing.assert_allclose(b.covariance, [[var, 0], [0, var]], atol=1e-12)
    assert b.pressure == 2000 and b.peak == 800 and b.n_texels == 9
    assert b.eigen_ratio == pytest.approx(1.0)
    np.testing.assert_allclose(b.point, KIN.pad_point(angles, 1, 3.0, 5.0), atol=1e-12)
    np.testing.assert_allclose(b.normal, -KIN.pad_normal(angles, 1), atol=1e-12)


def test_two_blobs_threshold_and_hand_pose():
    mats = _empty()
    mats[0][1, 1] = 500
    mats[0][10:12, 4] = 300   # elongated along y
    mats[5][0, 0] = 40        # below threshold
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.1, 0.2, 0.3]
    c_hand = frame_to_contacts(mats, np.zeros(7), KIN, threshold=100)
    c_world = frame_to_contacts(mats, np.zeros(7), KIN, threshold=100, hand_pose=T)
    assert len(c_hand) == 2
    assert c_world == c_hand.transform(T)
    blobs = find_blobs(mats, np.zeros(7), KIN, threshold=100)
    elongated = [b for b in blobs if b.n_texels == 2][0]
    assert elongated.eigen_ratio == pytest.approx(0.0) and abs(elongated.angle) == pytest.approx(math.pi / 2)
    assert len(find_blobs(mats, np.zeros(7), KIN, threshold=100, min_texels=2)) == 1
    with pytest.raises(ValidationError):
        find_blobs(mats[:5], np.zeros(7), KIN)


# -- the executor against the emulated hand and world -----------------------------------------------
def _box():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.creation.box(extents=(0.06, 0.05, 0.15)), name="box")


HAND_POSE = np.diag([1.0, -1.0, -1.0, 1.0])
HAND_POSE[2, 3] = 0.18
TRUE = np.eye(4)
TRUE[:3, 3] = [0.004, -0.003, 0.0]


def _rig(transport, tmp_path):
    world = SimWorld(_box(), TRUE, HAND_POSE)
    r = EmulatedRig(world, hand_transport=transport, tactile_transport="pty", time_scale=8.0).start()
    hand = r.open_hand(timeout=1.0)
    tactile = r.open_tactile(timeout=1.0)
    return r, GuardedTouchExecutor(hand, tactile, hand_pose=HAND_POSE, log=tmp_path / "session.jsonl")


@pytest.fixture(params=["can", "tcp"])
def rig(request, tmp_path):
    r, ex = _rig(request.param, tmp_path)
    yield r, ex
    r.close()


@pytest.fixture
def can_rig(tmp_path):
    r, ex = _rig("can", tmp_path)
    yield r, ex
    r.close()


def _surface_distance(points):
    obj = _box()
    Po = (points - TRUE[:3, 3]) @ TRUE[:3, :3]
    return obj.closest_points(Po)[2]


def test_touches_find_the_box_and_are_logged(rig, tmp_path):
    r, ex = rig
    t1 = ex.finger_touch(0, math.pi / 2, (-0.03, 0.112), (0.04, 0.112), name="f0")
    t2 = ex.finger_touch(1, 0.0, (-0.03, 0.112), (0.04, 0.112), name="thumb")
    res = [ex.execute(t1), ex.execute(t2)]
    for x in res:
        assert x.hit and 0 < x.travel < x.touch.max_travel
        assert np.all(_surface_distance(x.contact.points) < 0.0025)
    # finger 0 at a0 = 90 deg approaches the +x face: the contact normal points to +x
    assert res[0].contact.normals[0, 0] > 0.8
    recs = read_session(tmp_path / "session.jsonl")
    assert [rec.finger for rec in recs] == [0, 1]
    assert recs[0].result.contact == res[0].contact and recs[1].result.touch == t2
    assert len(session_contacts(tmp_path / "session.jsonl")) == len(res[0].contact) + len(res[1].contact)
    got = replay(tmp_path / "session.jsonl", lambda c: len(c))
    assert got == len(res[0].contact) + len(res[1].contact)


def test_free_touch_sweeps_free_space(rig):
    r, ex = rig
    t = ex.finger_touch(1, 0.0, (-0.045, 0.09), (-0.02, 0.09), name="outside")
    x = ex.execute(t)
    assert not x.hit and x.travel == pytest.approx(t.max_travel)


def test_unreachable_touch_sends_nothing(rig):
    r, ex = rig
    n = len(r.hand_emulator.received)
    with pytest.raises(ValidationError, match="cannot be made"):
        ex.execute(GuardedTouch((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.05))
    assert len(r.hand_emulator.received) == n


def _stop_seen(emu, n, wait=2.0):
    import time
    end = time.monotonic() + wait
    while time.monotonic() < end:
        if "stop" in emu.received[n:]:
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("fault", ["tactile-silence", "tactile-crc", "hand-error", "hand-disconnect"])
def test_faults_during_a_touch_stop_the_hand(rig, fault):
    r, ex = rig
    t = ex.finger_touch(2, math.pi / 2, (-0.03, 0.112), (0.04, 0.112))
    n = len(r.hand_emulator.received)
    if fault == "tactile-silence":
        r.tactile_emulator.faults.add("silence", on=0x03, skip=2)
        expected = HardwareTimeout
    elif fault == "tactile-crc":
        r.tactile_emulator.faults.add("crc", on=0x03, skip=2)
        from touchloc.errors import ChecksumError as expected
    elif fault == "hand-error":
        r.hand_emulator.faults.add("error", on="m", code=28, skip=3)
        expected = SDHFirmwareError
    else:
        r.hand_emulator.faults.add("disconnect", on="state", skip=3)
        from touchloc.errors import HardwareError as expected
    with pytest.raises(expected):
        ex.execute(t)
    if not (fault == "hand-disconnect" and r.hand_transport != "can"):
        assert _stop_seen(r.hand_emulator, n)
    assert ex.stops_sent >= 1


# -- the session log on its own -------------------------------------------------------------------
def test_session_log_survives_a_truncated_last_line(tmp_path):
    p = tmp_path / "s.jsonl"
    t = GuardedTouch((0, 0, 0.1), (0, 0, -1), 0.05, name="down")
    with SessionLog(p) as log:
        log.append(TouchResult(t, 0.02, Contacts([[0, 0, 0.08]], [[0, 0, 1]])), finger=1, angles=np.zeros(7))
        log.append(TouchResult(t, 0.05, None))
    with open(p, "a") as fh:
        fh.write('{"format": "touchloc-session/1", "touch": {"orig')   # a crash mid-write
    with pytest.warns(UserWarning, match="truncated"):
        recs = read_session(p)
    assert len(recs) == 2 and recs[0].result.hit and not recs[1].result.hit
    np.testing.assert_allclose(recs[0].result.contact.points, [[0, 0, 0.08]])
    # appending after the crash keeps the earlier records readable line by line
    assert json.loads(p.read_text().splitlines()[0])["finger"] == 1


def test_replay_into_a_filter(tmp_path):
    p = tmp_path / "s.jsonl"
    t = GuardedTouch((0, 0, 0.1), (0, 0, -1), 0.05)
    with SessionLog(p) as log:
        for z in (0.08, 0.07):
            log.append(TouchResult(t, 0.1 - z, Contacts([[0, 0, z]], [[0, 0, 1]])))

    class Filter:
        belief = None

        def __init__(self):
            self.seen = []

        def update(self, contacts):
            self.seen.append(float(contacts.points[0, 2]))
            self.belief = len(self.seen)

    f = Filter()
    assert replay(p, f) == 2 and f.seen == [0.08, 0.07]
    with pytest.raises(ValidationError):
        read_session(tmp_path / "missing.jsonl")


def test_flange_frame_straight_finger_length():
    # straight fingers: 246 mm from the mounting flange to the tips (sdh2_kinematics.md)
    T = SDH2Kinematics.flange_from_hand()
    tips = KIN.fingertips(np.zeros(7)) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(tips[:, 2], 0.246, atol=1e-9)
    # Rz(-90 deg): the hand's +x becomes the flange's -y
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)


def test_hand_touch_through_the_planners_world_interface(can_rig):
    from touchloc.hardware import HandWorld
    from touchloc.planners import HandTouch

    r, ex = can_rig
    action = HandTouch((ex.finger_touch(0, math.pi / 2, (-0.03, 0.112), (0.04, 0.112)),
                        ex.finger_touch(2, math.pi / 2, (-0.03, 0.112), (0.04, 0.112))))
    results = HandWorld(ex).execute(action)
    assert len(results) == 2 and all(x.hit for x in results)
    # fingers 0 and 2 at a0 = 90 deg touch opposite faces (+x and -x)
    assert results[0].contact.normals[0, 0] > 0.8 and results[1].contact.normals[0, 0] < -0.8


def test_velocity_mode_touch(tmp_path):
    world = SimWorld(_box(), TRUE, HAND_POSE)
    with EmulatedRig(world, hand_transport="can", tactile_transport="tcp", time_scale=2.0) as r:
        ex = GuardedTouchExecutor(r.open_hand(), r.open_tactile(), hand_pose=HAND_POSE, mode="velocity",
                                  probe_speed=0.03)
        x = ex.execute(ex.finger_touch(0, math.pi / 2, (-0.03, 0.112), (0.04, 0.112)))
        assert x.hit and np.all(_surface_distance(x.contact.points) < 0.003)
        assert x.contact.normals[0, 0] > 0.8
        got = r.hand_emulator.received
        assert "con=1" in got and any(c.startswith("tvav=") for c in got)
        assert got[got.index("con=1"):].count("con=0") == 1   # back to position control
        assert r.sim.controller == 0 and np.all(r.sim.state != 2)
        # a miss in velocity mode sweeps the whole line
        y = ex.execute(ex.finger_touch(1, 0.0, (-0.045, 0.09), (-0.02, 0.09)))
        assert not y.hit and y.travel == pytest.approx(0.025)


def test_thumb_touch_keeps_the_base_axis(can_rig):
    r, ex = can_rig
    before = float(r.sim.angles[0])
    ex.execute(ex.finger_touch(1, 0.0, (-0.03, 0.112), (0.04, 0.112)))
    # every target the hand was sent kept axis 0 (fingers 0 and 2) where it was
    sent = [c for c in r.hand_emulator.received if c.startswith("p=")]
    assert sent and all(float(c[2:].split(",")[0]) == pytest.approx(before, abs=1e-3) for c in sent)


def test_log_keeps_finished_touches_when_a_later_one_fails(can_rig, tmp_path):
    r, ex = can_rig
    ex.execute(ex.finger_touch(0, math.pi / 2, (-0.03, 0.112), (0.04, 0.112)))
    r.tactile_emulator.faults.add("silence")
    with pytest.raises(HardwareTimeout):
        ex.execute(ex.finger_touch(2, math.pi / 2, (-0.03, 0.112), (0.04, 0.112)))
    recs = read_session(tmp_path / "session.jsonl")   # read while the log is still open
    assert len(recs) == 1 and recs[0].result.hit and recs[0].finger == 0


def test_touch_pool_holds_only_touches_the_hand_can_make(can_rig):
    r, ex = can_rig
    pool = ex.touch_pool(20, rng=0)
    assert len(pool) == 20 and all(isinstance(t, GuardedTouch) for t in pool)
    for t in pool:
        ex.plan(t)                         # raises if no finger can make it
    fingers = {t.name.split()[1] for t in pool}
    assert fingers == {"0", "1", "2"}
    assert [t.name for t in ex.touch_pool(5, rng=3)] == [t.name for t in ex.touch_pool(5, rng=3)]
    for bad in (dict(n=0), dict(n=10**9), dict(heights=(0.2, 0.1)), dict(reach="x"), dict(heights=(np.nan, 0.1))):
        with pytest.raises(ValidationError):
            ex.touch_pool(**{"n": 3, **bad})
    world = SimWorld(_box(), TRUE, HAND_POSE)
    with pytest.raises(ValidationError):
        world.move_object(np.full((4, 4), np.nan))
    T = TRUE.copy()
    T[0, 3] += 0.01
    world.move_object(T)
    assert np.array_equal(world.object_pose, T)
