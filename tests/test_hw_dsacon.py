"""DSACON32m: CRC vectors, packets, RLE, and the driver against the emulator (TCP, pty and a
virtual CAN bus)."""

import itertools
import struct

import can

import numpy as np
import pytest
import serial

from touchloc.errors import (ChecksumError, DeviceDisconnected, FirmwareError, HardwareTimeout, ProtocolError,
                             ValidationError)
from touchloc.hardware import (DSACON32m, DSAFirmwareError, PacketParser, crc16, decode_frame, decode_rle,
                               encode_packet, encode_rle)
from touchloc.hardware._transport import CANLink
from touchloc.hardware.dsacon import POWERUP_ESC
from touchloc.hardware.emulator import CANServer, DSACON32mEmulator, PtyServer, TCPServer

SHAPES = [(14, 6), (13, 6)] * 3


# -- the test vectors of the protocol facts (dsacon32m.md, "CRC16") --------------------------
def test_crc_check_value():
    assert crc16(b"123456789") == 0x6EB4


@pytest.mark.parametrize("cmd,payload,wire", [
    (0x03, bytes([0x01, 0x00, 0x00]), "aa aa aa 03 03 00 01 00 00 2f 6a"),
    (0x03, bytes([0x81, 0x1E, 0x00]), "aa aa aa 03 03 00 81 1e 00 2c 76"),
    (0x0B, bytes([0x00]), "aa aa aa 0b 01 00 00 cb fb"),
    (0x03, bytes([0x00, 0x00]), "aa aa aa 03 02 00 00 00 4b b9"),
])
def test_packet_vectors(cmd, payload, wire):
    raw = bytes.fromhex(wire.replace(" ", ""))
    assert encode_packet(cmd, payload) == raw
    p = PacketParser()
    p.feed(raw)
    assert p.next() == (cmd, payload)
    assert p.next() is None


def test_empty_packet_has_no_crc():
    assert encode_packet(0x01) == bytes.fromhex("aaaaaa010000")


# -- RLE ------------------------------------------------------------------------------------
def test_rle_decodes_hand_made_frame_exactly():
    # units: 3 x 5, 1 x 4095, 15 x 0, 2 x 7   -> 21 texels
    units = [(3 << 12) | 5, (1 << 12) | 4095, (15 << 12) | 0, (2 << 12) | 7]
    data = struct.pack("<4H", *units)
    out = decode_rle(data, 21)
    assert out.dtype == np.uint16
    assert out.tolist() == [5] * 3 + [4095] + [0] * 15 + [7] * 2


def test_rle_frame_payload_and_matrix_order():
    values = np.arange(14 * 6 + 13 * 6, dtype=np.uint16) % 4096
    payload = struct.pack("<IB", 1234, 1) + encode_rle(values)
    f = decode_frame(payload, [(14, 6), (13, 6)])
    assert f.timestamp == 1234 and f.rle
    assert f.matrices[0][1, 0] == 6            # row-major: offset + y * cells_x + x
    assert f.matrices[1][0, 0] == 84 and f.matrices[1].shape == (13, 6)
    np.testing.assert_array_equal(f.texels, values)


@pytest.mark.parametrize("seed", range(5))
def test_rle_round_trip_random(seed):
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.integers(0, 4096, 60), rng.integers(1, 40, 60))
    np.testing.assert_array_equal(decode_rle(encode_rle(v), v.size), v)


def test_raw_frame():
    v = np.arange(10, dtype=np.uint16)
    f = decode_frame(struct.pack("<IB", 7, 0) + v.astype("<u2").tobytes(), [(2, 5)])
    assert not f.rle and f.matrices[0].tolist() == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]


@pytest.mark.parametrize("data,n,match", [
    (b"\x01", 1, "whole u16"),
    (struct.pack("<H", 5), 1, "count of 0"),
    (struct.pack("<H", (2 << 12) | 5), 3, "decodes to 2"),
])
def test_rle_errors(data, n, match):
    with pytest.raises(ProtocolError, match=match):
        decode_rle(data, n)


# -- the packet hunter ---------------------------------------------------------------------------
def test_parser_skips_garbage_esc_and_resyncs_after_crc_error():
    good = encode_packet(0x02, b"\x00\x00" + bytes(10))
    bad = bytearray(encode_packet(0x14, b"\x00\x00\x05\x00"))
    bad[-1] ^= 0x55
    p = PacketParser()
    p.feed(POWERUP_ESC * 3 + b"\xaa\x00junk\xaa\xaa" + bytes(bad) + b"\xaa" + good)
    with pytest.raises(ChecksumError):
        p.next()
    assert p.next() == (0x02, b"\x00\x00" + bytes(10))
    assert p.skipped >= 12


def test_parser_byte_by_byte():
    pkts = [encode_packet(i, bytes([i] * i)) for i in range(1, 6)]
    p = PacketParser()
    got = []
    for b in b"".join(pkts):
        p.feed(bytes([b]))
        r = p.next()
        if r:
            got.append(r)
    assert [g[0] for g in got] == [1, 2, 3, 4, 5]


# -- driver against the emulator -------------------------------------------------------------------
_channels = itertools.count()


@pytest.fixture(params=["tcp", "pty", "can"])
def tactile(request):
    rng = np.random.default_rng(3)
    mats = [rng.integers(0, 4096, s).astype(np.uint16) for s in SHAPES]
    for m in mats:
        m[2:5] = 0   # runs for RLE
    emu = DSACON32mEmulator(frame_source=lambda: mats, powerup_esc=True)
    if request.param == "tcp":
        srv = TCPServer(emu).start()
        port = serial.serial_for_url(srv.url, timeout=0.05)
    elif request.param == "pty":
        srv = PtyServer(emu).start()
        port = serial.serial_for_url(srv.path, baudrate=115200, timeout=0.05)
    else:  # the same packets cut into 8-byte frames on a python-can virtual bus
        ch = f"dsa-test-{next(_channels)}"
        srv = CANServer(emu, channel=ch).start()
        port = can.Bus(interface="virtual", channel=ch)
    dev = DSACON32m(port, timeout=0.5, open_timeout=0.5)
    yield emu, dev, mats
    port.shutdown() if request.param == "can" else port.close()
    srv.close()


def test_open_sequence_and_info(tactile):
    emu, dev, mats = tactile
    # configure acquisition (stopped, RLE) first, then controller, sensor, matrices
    ids = [c for c, _ in emu.received]
    assert ids[:3] == [0x03, 0x01, 0x02] and ids[3:9] == [0x0B] * 6
    assert emu.received[0][1] == bytes([0x01, 0x00, 0x00])
    assert dev.sensor.nb_matrices == 6
    assert dev.shapes == SHAPES
    assert dev.matrix_infos[0].texel_width == pytest.approx(3.4, abs=1e-6)
    assert dev.controller.serial == 0x2A2A


def test_single_frame_and_streaming(tactile):
    emu, dev, mats = tactile
    f = dev.read_frame()
    assert len(f.matrices) == 6 and all(m.dtype == np.uint16 for m in f.matrices)
    for a, b in zip(f.matrices, mats):
        np.testing.assert_array_equal(a, b)
    dev.start_streaming(200)
    frames = list(dev.frames(5))
    assert len(frames) == 5 and all(np.array_equal(fr.matrices[3], mats[3]) for fr in frames)
    assert frames[-1].timestamp >= frames[0].timestamp
    dev.stop_streaming()
    # a query after streaming still gets its own reply
    assert dev.threshold(0) == 0


def test_raw_frames(tactile):
    emu, dev, mats = tactile
    dev.configure_acquisition(start=False, rle=False)
    f = dev.read_frame()
    assert not f.rle
    np.testing.assert_array_equal(f.matrices[5], mats[5])


def test_sensitivity_threshold(tactile):
    emu, dev, mats = tactile
    dev.set_sensitivity(1, 0.25)
    s = dev.sensitivity(1)
    assert s.adjustable and s.current == pytest.approx(0.25) and s.factory == pytest.approx(0.5)
    dev.set_threshold(2, 2000)
    assert dev.threshold(2) == 2000
    f = dev.read_frame()
    assert f.matrices[2][(f.matrices[2] > 0)].min() >= 2000
    with pytest.raises(ValidationError):
        dev.set_sensitivity(1, 1.5)
    with pytest.raises(ValidationError):
        dev.threshold(6)


@pytest.mark.parametrize("fault,exc", [
    ("crc", ChecksumError), ("drop", HardwareTimeout), ("truncate", HardwareTimeout),
    ("lose", (ChecksumError, HardwareTimeout)),
    ("error", DSAFirmwareError), ("silence", HardwareTimeout),
])
def test_faults_are_typed_and_recoverable(tactile, fault, exc):
    emu, dev, mats = tactile
    emu.faults.add(fault, on=0x03, code=17)
    with pytest.raises(exc) as info:
        dev.read_frame()
    if fault == "error":
        assert isinstance(info.value, FirmwareError) and info.value.name == "CMD_FAILED"
    if fault == "silence":
        return
    # the stream resynchronises: the next frame is exact
    dev.link.discard_input()
    dev.parser.reset()
    np.testing.assert_array_equal(dev.read_frame().matrices[0], mats[0])


def test_disconnect_mid_stream_is_typed(tactile):
    emu, dev, mats = tactile
    dev.start_streaming(100)
    assert len(list(dev.frames(2))) == 2
    dev.stop_streaming()
    emu.faults.add("disconnect", on=0x03)
    # TCP and the pty close the line; CAN has no connection, so the device falls silent
    with pytest.raises((DeviceDisconnected, HardwareTimeout)) as info:
        dev.read_frame()
        dev.read_frame()
    if isinstance(dev.link, CANLink):
        assert isinstance(info.value, HardwareTimeout)


def test_garbage_before_reply_is_skipped(tactile):
    emu, dev, mats = tactile
    emu.faults.add("garbage", on=0x14, count=2)
    assert dev.threshold(0) == 0 and dev.threshold(1) == 0


def test_unknown_command_error_name(tactile):
    emu, dev, mats = tactile
    dev._send(0x42, b"\x00")
    with pytest.raises(DSAFirmwareError, match="CMD_UNKNOWN"):
        from touchloc.hardware.dsacon import _check_error
        _check_error(0x42, dev._wait(0x42))


def test_powerup_esc_sequence_is_skipped():
    emu = DSACON32mEmulator(powerup_esc=True)
    with TCPServer(emu) as srv:
        port = serial.serial_for_url(srv.url, timeout=0.05)
        dev = DSACON32m(port, timeout=0.5, open_timeout=0.5)
        # the three ESC "[5n" (12 bytes) arrived first and were hunted over
        assert dev.parser.skipped >= 12
        assert dev.sensor.nb_matrices == 6
        port.close()
