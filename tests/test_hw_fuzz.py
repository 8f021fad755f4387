"""Fuzzing the byte parsers: >= 10,000 seeded inputs each; only the library's own errors may escape.

Inputs mix pure noise with mutations of valid traffic (bit flips, cuts, insertions,
duplications), so the parsers reach their deep states (complete packets with bad CRCs,
wrong lengths, RLE data that decodes to the wrong size, replies with bad numbers).
"""

import struct

import numpy as np
import pytest

from touchloc.errors import TouchlocError
from touchloc.hardware.dsacon import PacketParser, decode_frame, decode_rle, encode_packet, encode_rle
from touchloc.hardware.sdh2 import LineReader, parse_reply, parse_values

N_INPUTS = 10_000
SHAPES = [(14, 6), (13, 6)] * 3


def _mutate(rng, data: bytes) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 5))
        if op == 0 and b:  # flip bits
            i = int(rng.integers(0, len(b)))
            b[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1 and b:  # cut
            i = int(rng.integers(0, len(b)))
            del b[i:i + int(rng.integers(1, 8))]
        elif op == 2:  # insert noise
            i = int(rng.integers(0, len(b) + 1))
            b[i:i] = rng.bytes(int(rng.integers(1, 6)))
        elif op == 3 and b:  # duplicate a slice
            i = int(rng.integers(0, len(b)))
            b[i:i] = b[i:i + int(rng.integers(1, 12))]
        else:  # truncate
            b = b[: int(rng.integers(0, len(b) + 1))]
    return bytes(b)


def _valid_dsacon(rng) -> bytes:
    kind = int(rng.integers(0, 4))
    if kind == 0:
        tex = np.repeat(rng.integers(0, 4096, 40), rng.integers(1, 30, 40))[:sum(a * b for a, b in SHAPES)]
        tex = np.pad(tex, (0, sum(a * b for a, b in SHAPES) - tex.size))
        return encode_packet(0, struct.pack("<IB", int(rng.integers(0, 2**32)), 1) + encode_rle(tex))
    if kind == 1:
        return encode_packet(0x03, b"\x00\x00")
    if kind == 2:
        return encode_packet(0x14, struct.pack("<HH", 0, int(rng.integers(0, 4096))))
    return encode_packet(int(rng.integers(0, 256)), rng.bytes(int(rng.integers(0, 40))))


def test_fuzz_dsacon_packet_parser_and_frame_decoder():
    rng = np.random.default_rng(20240601)
    seen = {"packets": 0, "crc": 0, "frames": 0, "frame_errors": 0}
    parser = PacketParser(max_payload=4096)
    for i in range(N_INPUTS):
        if i % 3 == 0:
            data = rng.bytes(int(rng.integers(0, 64)))
            if rng.random() < 0.3:
                data = b"\xaa\xaa\xaa" + data
        else:
            data = _mutate(rng, b"".join(_valid_dsacon(rng) for _ in range(int(rng.integers(1, 3)))))
        if i % 50 == 0:
            parser = PacketParser(max_payload=4096)  # fresh state now and then, carried state otherwise
        parser.feed(data)
        for _ in range(len(data) + 2):  # each call consumes bytes or returns None: bounded
            try:
                pkt = parser.next()
            except TouchlocError:
                seen["crc"] += 1
                continue
            if pkt is None:
                break
            seen["packets"] += 1
            cmd, payload = pkt
            if cmd == 0:
                try:
                    f = decode_frame(payload, SHAPES)
                    assert len(f.matrices) == 6 and f.texels.size == sum(a * b for a, b in SHAPES)
                    seen["frames"] += 1
                except TouchlocError:
                    seen["frame_errors"] += 1
        assert len(parser.buf) <= 4096 + 8 + len(data) + 64
    # the fuzzing reached every outcome
    assert all(v > 0 for v in seen.values()), seen


def test_fuzz_rle_decoder():
    rng = np.random.default_rng(7)
    ok = bad = 0
    for _ in range(N_INPUTS):
        n = int(rng.integers(0, 60))
        if rng.random() < 0.5:
            data = _mutate(rng, encode_rle(np.repeat(rng.integers(0, 4096, 8), rng.integers(1, 20, 8))))
        else:
            data = rng.bytes(int(rng.integers(0, 40)))
        try:
            out = decode_rle(data, n)
            assert out.size == n and out.max(initial=0) <= 4095
            ok += 1
        except TouchlocError:
            bad += 1
    assert ok > 0 and bad > 0


_ALPHABET = np.frombuffer(b"PEOSTAVMG_=,.-+0123456789()@ \r\nxyz\x00\xff", dtype=np.uint8)
_VALID_REPLIES = [b"P=1.000,2.000,3.000,4.000,5.000,6.000,7.000\r\n", b"STATE=0,0,1,0,4,5,0\r\n", b"E13\r\n",
                  b"@debug line\r\n", b"M=0.750\r\n", b"P(3)=12.500\r\n", b"STOP\r\n", b"VER=0.0.2.15\r\n"]


def test_fuzz_sdh2_reply_reader_and_parser():
    rng = np.random.default_rng(99)
    reader = LineReader(max_line=256)
    seen = {"lines": 0, "replies": 0, "values": 0, "errors": 0}
    for i in range(N_INPUTS):
        r = rng.random()
        if r < 0.3:
            data = rng.bytes(int(rng.integers(0, 80)))
        elif r < 0.6:
            data = _ALPHABET[rng.integers(0, _ALPHABET.size, int(rng.integers(0, 80)))].tobytes()
        else:
            data = _mutate(rng, b"".join(_VALID_REPLIES[int(k)] for k in rng.integers(0, len(_VALID_REPLIES), 2)))
        reader.feed(data)
        for _ in range(len(data) + 2):
            try:
                line = reader.next_line()
            except TouchlocError:
                seen["errors"] += 1
                continue
            if line is None:
                break
            seen["lines"] += 1
            if not line or line.startswith("@"):
                continue
            try:
                name, index, values = parse_reply(line)
                seen["replies"] += 1
                if name in ("P", "STATE") and index is None:
                    v = parse_values(values, 7, name)
                    assert v.shape == (7,) and np.all(np.isfinite(v))
                    seen["values"] += 1
            except TouchlocError:
                seen["errors"] += 1
        assert len(reader.pending()) <= 256 + 80
    assert all(v > 0 for v in seen.values()), seen


@pytest.mark.parametrize("line", ["E", "E-1", "E²", "P(x)=1", "P=1,2,nan,4,5,6,7", "", "=", "P==", "E99999999"])
def test_odd_reply_lines_raise_library_errors(line):
    with pytest.raises(TouchlocError):
        name, index, values = parse_reply(line)
        parse_values(values, 7)


class _NoiseDevice:
    """Answers every request with seeded noise or a mutated valid reply (over a real socket)."""

    def __init__(self, seed, valid):
        from touchloc.hardware.emulator import FaultPlan

        self.rng = np.random.default_rng(seed)
        self.valid = valid
        self.faults = FaultPlan()

    def reset(self):
        pass

    def poll(self):
        return b""

    def feed(self, data):
        r = self.rng.random()
        if r < 0.4:
            return self.rng.bytes(int(self.rng.integers(0, 300)))
        if r < 0.75:
            return _mutate(self.rng, self.valid)
        return self.valid


def test_drivers_on_a_noisy_wire_end_in_library_errors():
    import serial

    from touchloc.hardware import SDH2, DSACON32m
    from touchloc.hardware.emulator import TCPServer

    outcomes = {"ok": 0, "error": 0}
    dsa_reply = encode_packet(0x14, struct.pack("<HH", 0, 5))
    with TCPServer(_NoiseDevice(1, dsa_reply)) as srv:
        port = serial.serial_for_url(srv.url, timeout=0.01)
        dev = DSACON32m(port, connect=False, timeout=0.15)
        dev.matrix_infos = []
        for _ in range(30):
            try:
                assert 0 <= dev.threshold(0) <= 0xFFFF
                outcomes["ok"] += 1
            except TouchlocError:
                outcomes["error"] += 1
        port.close()
    with TCPServer(_NoiseDevice(2, b"P=1,2,3,4,5,6,7\r\n")) as srv:
        port = serial.serial_for_url(srv.url, timeout=0.01)
        hand = SDH2(port, connect=False, timeout=0.15)
        for _ in range(30):
            try:
                assert hand.target_angles().shape == (7,)
                outcomes["ok"] += 1
            except TouchlocError:
                outcomes["error"] += 1
        port.close()
    assert outcomes["ok"] > 0 and outcomes["error"] > 0, outcomes


def test_sdh2_driver_over_20000_corrupted_replies_stops_and_raises_typed():
    """Every failed call over the real emulator's corrupted replies: library error + stop."""
    from touchloc.hardware.emulator._corrupt import fuzz_sdh2

    r = fuzz_sdh2(20_000, rate=0.5, seed=12)
    assert r["calls"] == 20_000
    assert r["raw"] == 0, r["raw_examples"]
    assert r["missing_stop"] == 0
    # the corruption reached every kind, and both outcomes occurred often
    assert all(v > 100 for v in r["corruptions"].values()), r["corruptions"]
    assert r["ok"] > 2000 and r["typed"] > 2000
    assert {"ProtocolError", "HardwareTimeout", "SDHFirmwareError"} <= set(r["errors"])


@pytest.mark.parametrize("reply, call", [
    (b"CON=nan\r\n", lambda h: h.controller()),
    (b"CON\r\n", lambda h: h.controller()),
    (b"CON=7\r\n", lambda h: h.controller()),
    (b"CON=x\r\n", lambda h: h.controller(1)),
    (b"NUMAXIS=inf\r\n", lambda h: h.identification()),
    (b"GRIP=1e9\r\n", lambda h: h.grip(0, 0.5, wait=True)),
    (b"GET_DURATION=nan\r\n", lambda h: h.expected_duration()),
    (b"M=-1\r\n", lambda h: h.move()),
    (b"POS=0,0,0,0,0,0,1e9\r\n", lambda h: h.actual_angles()),
    (b"VEL=0,0,0,0,0,0,-5e4\r\n", lambda h: h.actual_velocities()),
])
def test_reply_outside_physical_range_is_protocol_error_with_stop(reply, call):
    from touchloc.errors import ProtocolError
    from touchloc.hardware import SDH2
    from touchloc.hardware.emulator import SDH2Emulator
    from touchloc.hardware.emulator._corrupt import CorruptingLink

    class Fixed(SDH2Emulator):
        def feed(self, data):
            out = super().feed(data)
            name = reply.split(b"=")[0].strip(b"\r\n")
            return reply if out.upper().startswith(name) else out

    link = CorruptingLink(Fixed(), rate=0.0)
    hand = SDH2(link, timeout=1.0, connect=False)
    with pytest.raises(ProtocolError):
        call(hand)
    assert link.stops >= 1


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0, "1"])
def test_sdh2_timeouts_are_validated(bad):
    from touchloc.errors import ValidationError
    from touchloc.hardware import SDH2
    from touchloc.hardware.emulator import SDH2Emulator
    from touchloc.hardware.emulator._corrupt import CorruptingLink

    hand = SDH2(CorruptingLink(SDH2Emulator(), rate=0.0), timeout=1.0)
    with pytest.raises(ValidationError):
        hand.command("pos", timeout=bad)
    with pytest.raises(ValidationError):
        hand.wait_until_idle(bad)
    with pytest.raises(ValidationError):
        SDH2(CorruptingLink(SDH2Emulator(), rate=0.0), timeout=bad)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
def test_dsacon_wait_timeout_is_validated(bad):
    from touchloc.errors import ValidationError
    from touchloc.hardware import DSACON32m
    from touchloc.hardware.emulator import DSACON32mEmulator
    from touchloc.hardware.emulator._corrupt import CorruptingLink

    dev = DSACON32m(CorruptingLink(DSACON32mEmulator(), rate=0.0), timeout=1.0)
    with pytest.raises(ValidationError):
        dev.read_frame(timeout=bad)
    with pytest.raises(ValidationError):
        dev.threshold("0")
