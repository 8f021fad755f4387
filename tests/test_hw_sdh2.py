"""SDH-2 driver against the byte-level emulator over TCP, a pty pair and a virtual CAN bus."""

import itertools
import math
import time

import can
import numpy as np
import pytest
import serial

from touchloc.errors import (DeviceDisconnected, FirmwareError, HardwareError, HardwareTimeout,
                             JointLimitError, ProtocolError, ValidationError)
from touchloc.hardware import SDH2, AxisState, SDHFirmwareError
from touchloc.hardware.emulator import CANServer, PtyServer, SDH2Emulator, SimHand, TCPServer
from touchloc.hardware.sdh2 import parse_reply

_ids = itertools.count()


def _open(kind, emu):
    if kind == "tcp":
        srv = TCPServer(emu).start()
        return srv, serial.serial_for_url(srv.url, timeout=0.05)
    if kind == "pty":
        srv = PtyServer(emu).start()
        return srv, serial.serial_for_url(srv.path, baudrate=115200, timeout=0.05)
    ch = f"sdh-test-{next(_ids)}"
    srv = CANServer(emu, channel=ch).start()
    return srv, can.Bus(interface="virtual", channel=ch)


@pytest.fixture(params=["tcp", "pty", "can"])
def rig(request):
    emu = SDH2Emulator(SimHand(time_scale=20.0))
    srv, port = _open(request.param, emu)
    hand = SDH2.over_can(port, timeout=0.5) if request.param == "can" else SDH2(port, timeout=0.5)
    yield request.param, emu, hand
    try:
        port.shutdown() if request.param == "can" else port.close()
    finally:
        srv.close()


def _stop_after(emu, n_before, wait=2.0):
    """Whether the emulator received "stop" after line n_before (waits for in-flight bytes)."""
    end = time.monotonic() + wait
    while time.monotonic() < end:
        if "stop" in emu.received[n_before:]:
            return True
        time.sleep(0.01)
    return False


def test_connect_identify_and_limits(rig):
    kind, emu, hand = rig
    assert hand.firmware_version() == "0.0.2.15"
    ident = hand.identification()
    assert ident.num_axes == 7 and ident.serial_number == "1234"
    lo, hi = hand.angle_limits
    assert lo[0] == pytest.approx(0.0) and hi[0] == pytest.approx(math.pi / 2)
    assert lo[1] == pytest.approx(-math.pi / 2)
    # the handshake asked ver first
    assert emu.received[0] == "ver"


def test_move_in_radians_degrees_on_wire(rig):
    kind, emu, hand = rig
    target = np.radians([10, 20, 30, -10, 5, 0, -7.5])
    d = hand.move(target, wait=True, timeout=5.0)
    assert d == pytest.approx(30 / 40, abs=1e-3)  # slowest axis: 30 deg at 40 deg/s
    assert "p=10.000,20.000,30.000,-10.000,5.000,0.000,-7.500" in emu.received
    np.testing.assert_allclose(hand.actual_angles(), target, atol=1e-4)
    np.testing.assert_allclose(hand.target_angles(), target, atol=1e-4)
    assert np.all(hand.state() == AxisState.IDLE)


def test_velocities_accelerations_temperatures_power(rig):
    kind, emu, hand = rig
    v = np.radians([10, 20, 30, 40, 50, 60, 70])
    np.testing.assert_allclose(hand.set_target_velocities(v), v, atol=1e-4)
    np.testing.assert_allclose(hand.target_velocities(), v, atol=1e-4)
    a = np.radians([100, 100, 200, 300, 300, 300, 300])
    np.testing.assert_allclose(hand.set_accelerations(a), a, atol=1e-4)
    np.testing.assert_allclose(hand.accelerations(), a, atol=1e-4)
    t = hand.temperatures()
    assert t["axes"].shape == (7,) and t["fpga"] == 45.0
    assert hand.power().all()
    p = hand.power([True, False, True, True, True, True, True])
    assert not p[1] and hand.state()[1] == AxisState.DISABLED
    assert hand.expected_duration() == 0.0


def test_grip_preset(rig):
    kind, emu, hand = rig
    d = hand.grip(2, 0.5, 50.0)
    assert d > 0
    assert emu.received[-3:] == ["selgrip=2", "vp=0", "grip=0.500,50.000"]
    hand.wait_until_idle(5.0)
    assert np.degrees(hand.actual_angles())[2] == pytest.approx(45.0, abs=1e-3)


def test_joint_limit_refused_before_sending(rig):
    kind, emu, hand = rig
    n = len(emu.received)
    with pytest.raises(JointLimitError, match="axis 0"):
        hand.move(np.radians([-5, 0, 0, 0, 0, 0, 0]))
    with pytest.raises(JointLimitError, match="axis 3"):
        hand.set_target_angles(np.radians([0, 0, 0, 95, 0, 0, 0]))
    with pytest.raises(ValidationError):
        hand.set_target_angles([0, 0, 0])
    assert len(emu.received) == n


@pytest.mark.parametrize("kind_of_fault", ["error", "drop", "truncate", "lose", "silence", "garbage"])
def test_faults_raise_typed_and_send_stop(rig, kind_of_fault):
    kind, emu, hand = rig
    hand.move(np.radians([0, 10, 10, 10, 10, 10, 10]))
    n = len(emu.received)
    emu.faults.add(kind_of_fault, on="state", code=17)
    # "lose" drops 3 bytes of "STATE=1,1,1,1,1,1,1": a value and its comma vanish
    expected = {"error": SDHFirmwareError, "drop": HardwareTimeout, "truncate": HardwareTimeout,
                "lose": ProtocolError, "silence": HardwareTimeout, "garbage": ProtocolError}[kind_of_fault]
    with pytest.raises(expected) as info:
        hand.wait_until_idle(5.0)
    if kind_of_fault == "error":
        assert info.value.code == 17 and info.value.name == "CMD_FAILED"
        assert isinstance(info.value, FirmwareError)
    assert _stop_after(emu, n)
    assert hand.stops_sent >= 1


def test_error_on_move_names_code(rig):
    kind, emu, hand = rig
    emu.faults.add("error", on="m", code=29)
    with pytest.raises(SDHFirmwareError, match="OVER_TEMPERATURE"):
        hand.move()
    assert _stop_after(emu, len(emu.received) - 2)


def test_debug_lines_are_skipped(rig):
    kind, emu, hand = rig
    emu.debug_lines = True
    emu.faults.add("debug", on="pos", count=3)
    for _ in range(3):
        assert hand.actual_angles().shape == (7,)
    assert hand.move(np.radians([0, 5, 0, 0, 0, 0, 0])) > 0


def test_disconnect_mid_move(rig):
    kind, emu, hand = rig
    hand.move(np.radians([0, 60, 0, 0, 0, 0, 0]))
    emu.faults.add("disconnect", on="state")
    # CAN has no connection: the device falls silent, and the stop is still on the bus
    expected = HardwareTimeout if kind == "can" else DeviceDisconnected
    n = len(emu.received)
    with pytest.raises(expected):
        hand.wait_until_idle(5.0)
        hand.wait_until_idle(5.0)
    if kind == "can":
        assert _stop_after(emu, n)


def test_parse_reply_forms():
    assert parse_reply("P=1.0,2.5") == ("P", None, ["1.0", "2.5"])
    assert parse_reply("P(3)=12.500") == ("P", 3, ["12.500"])
    assert parse_reply("STOP") == ("STOP", None, [])
    with pytest.raises(SDHFirmwareError) as info:
        parse_reply("E13")
    assert info.value.name == "CMD_UNKNOWN"
    with pytest.raises(ProtocolError):
        parse_reply("p=1")
    with pytest.raises(SDHFirmwareError, match="UNKNOWN_CODE_99"):
        parse_reply("E99")


def test_loop_url_timeout_without_device():
    # loop:// echoes our own bytes: the echo is not a reply, so the handshake times out
    port = serial.serial_for_url("loop://", timeout=0.05)
    with pytest.raises(HardwareError):
        SDH2(port, timeout=0.3)


def test_can_frames_are_at_most_8_bytes_and_on_id_42():
    ch = f"sdh-sniff-{next(_ids)}"
    emu = SDH2Emulator(SimHand(time_scale=20.0))
    sniff = can.Bus(interface="virtual", channel=ch)
    bus = can.Bus(interface="virtual", channel=ch)
    with CANServer(emu, channel=ch):
        hand = SDH2.over_can(bus, timeout=0.5)
        hand.set_target_angles(np.radians([1, 2, 3, 4, 5, 6, 7]))
        frames = []
        while True:
            m = sniff.recv(timeout=0.2)
            if m is None:
                break
            frames.append(m)
    bus.shutdown()
    sniff.shutdown()
    assert frames and all(m.dlc <= 8 for m in frames)
    assert {m.arbitration_id for m in frames} == {42, 43}
    sent = b"".join(bytes(m.data) for m in frames if m.arbitration_id == 42)
    assert b"p=1.000,2.000,3.000,4.000,5.000,6.000,7.000\r\n" in sent


def test_can_reader_ignores_foreign_frames():
    ch = f"sdh-foreign-{next(_ids)}"
    emu = SDH2Emulator(SimHand(time_scale=20.0))
    bus = can.Bus(interface="virtual", channel=ch)
    other = can.Bus(interface="virtual", channel=ch)
    with CANServer(emu, channel=ch):
        hand = SDH2.over_can(bus, timeout=0.5)
        hand.move(np.radians([5, 0, 0, 0, 0, 0, 0]), wait=True)
        # frames the hand's reader must skip: extended id 43, remote frame, error frame, another id
        other.send(can.Message(arbitration_id=43, data=b"POS=9\r\n", is_extended_id=True))
        other.send(can.Message(arbitration_id=43, is_remote_frame=True, dlc=8, is_extended_id=False))
        other.send(can.Message(arbitration_id=43, is_error_frame=True, is_extended_id=False))
        other.send(can.Message(arbitration_id=44, data=b"POS=1\r\n", is_extended_id=False))
        np.testing.assert_allclose(np.degrees(hand.actual_angles()), [5, 0, 0, 0, 0, 0, 0], atol=1e-3)
    other.shutdown()
    bus.shutdown()
