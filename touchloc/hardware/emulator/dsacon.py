"""A DSACON32m emulator that speaks the controller's packet protocol (bytes in, bytes out).

Packets, payload layouts and the CRC follow SCHUNK SDHLibrary-C++ 0.0.2.10 (dsa.cpp, crc.cpp) and the ROS driver schunk_sdh. The pads'
texel values come from the shared :class:`SimHand` (pressure where the pads press into
the simulated mesh), from a user callable, or are zero.
"""

from __future__ import annotations

import struct
import threading
import time

import numpy as np

from ...errors import ChecksumError
from ..dsacon import (CMD_ACQUISITION, CMD_CONTROLLER, CMD_FRAME, CMD_GET_SENSITIVITY,
                      CMD_GET_THRESHOLD, CMD_MATRIX, CMD_SENSOR, CMD_SET_SENSITIVITY,
                      CMD_SET_THRESHOLD, POWERUP_ESC, PacketParser, encode_packet, encode_rle)
from ._faults import FaultPlan

__all__ = ["DSACON32mEmulator", "DEFAULT_SHAPES"]

#: (cells_y, cells_x) per matrix: 6 x 14 proximal, 6 x 13 distal (dsacon32m.md; the real
#: sizes are whatever the controller reports in 0x0B)
DEFAULT_SHAPES = ((14, 6), (13, 6), (14, 6), (13, 6), (14, 6), (13, 6))


class DSACON32mEmulator:
    """Byte-level DSACON32m.

    Parameters
    ----------
    hand : SimHand, optional
        Source of pad pressures (its world decides what the pads touch).
    frame_source : callable, optional
        ``frame_source() -> list of 6 (cells_y, cells_x) arrays``; overrides ``hand``.
    shapes : sequence of (cells_y, cells_x)
        Matrix sizes reported by query 0x0B.
    texel_size : float
        Texel pitch reported by 0x0B (mm); 3.4 by default (assumed, see dsacon32m.md).
    powerup_esc : bool
        Send ESC "[5n" three times before the first reply, as when the host starts talking
        while the controller is still booting.

    Attributes
    ----------
    received : list of (id, payload)
        Every request packet received.
    faults : FaultPlan
        Faults keyed by request packet id (``on=0x03``) or None for any.
    """

    def __init__(self, hand=None, *, frame_source=None, shapes=DEFAULT_SHAPES, texel_size: float = 3.4,
                 powerup_esc: bool = False, serial: int = 0x2A2A):
        self.hand = hand
        self.frame_source = frame_source
        self.shapes = tuple((int(a), int(b)) for a, b in shapes)
        self.texel_size = float(texel_size)
        self.serial = int(serial)
        self.parser = PacketParser()
        self.received: list = []
        self.faults = FaultPlan()
        self._esc_pending = bool(powerup_esc)
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.framerate = 0
        self.streaming = False
        self.rle = True
        self._next_push = 0.0
        self.sensitivity = [0.5] * len(self.shapes)
        self.factory_sensitivity = 0.5
        self.thresholds = [0] * len(self.shapes)
        self.frames_sent = 0

    def reset(self) -> None:
        self.parser.reset()

    # -- frames ---------------------------------------------------------------------------
    def texels(self) -> np.ndarray:
        if self.frame_source is not None:
            mats = self.frame_source()
        elif self.hand is not None:
            mats = self.hand.pressures()
        else:
            mats = None
        if mats is None:
            mats = [np.zeros(s, dtype=np.uint16) for s in self.shapes]
        out = []
        for m, (arr, shape) in enumerate(zip(mats, self.shapes)):
            a = np.asarray(arr, dtype=np.int64).reshape(shape)
            a = np.where(a < self.thresholds[m], 0, a)
            out.append(np.clip(a, 0, 4095).reshape(-1))
        return np.concatenate(out)

    def frame_packet(self) -> bytes:
        tex = self.texels()
        ts = int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF
        data = encode_rle(tex) if self.rle else tex.astype("<u2").tobytes()
        self.frames_sent += 1
        return encode_packet(CMD_FRAME, struct.pack("<IB", ts, 1 if self.rle else 0) + data)

    def poll(self) -> bytes:
        """Bytes pushed without a request: streamed frames."""
        out = b""
        if self.streaming and self.framerate > 0 and not self.faults.silent:
            now = time.monotonic()
            if now >= self._next_push:
                self._next_push = max(self._next_push + 1.0 / self.framerate, now - 0.5)
                out += self._faulted(CMD_FRAME, self.frame_packet())
        return out

    # -- requests -------------------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        out = bytearray()
        with self._lock:
            self.parser.feed(data)
            while True:
                try:
                    pkt = self.parser.next()
                except ChecksumError:
                    continue  # a corrupted request is dropped, as by the device
                if pkt is None:
                    break
                cmd, payload = pkt
                self.received.append((cmd, payload))
                if self._esc_pending:  # the host spoke while the controller was still booting
                    self._esc_pending = False
                    out += POWERUP_ESC * 3
                if self.faults.silent:
                    continue
                fault = self.faults.take(cmd)
                reply = self._handle(cmd, payload, fault)
                out += self._apply(fault, reply) if fault is not None else reply
        return bytes(out)

    def _faulted(self, cmd, reply: bytes) -> bytes:
        fault = self.faults.take(cmd)
        return reply if fault is None else self._apply(fault, reply)

    def _apply(self, fault, reply: bytes) -> bytes:
        k = fault.kind
        if k == "drop":
            return b""
        if k == "truncate":
            return reply[: max(1, len(reply) // 2)]
        if k == "lose":
            i = len(reply) // 2
            return reply[:i] + reply[i + 3:]
        if k == "crc" and len(reply) >= 8:
            return reply[:-2] + bytes([reply[-2] ^ 0xFF, reply[-1]])
        if k == "garbage":
            return b"\x00\xaa\x13garbage\xaa\xaa" + reply
        if k == "silence":
            self.faults.silent = True
            return b""
        if k == "disconnect":
            self.faults.disconnect = True
            return b""
        return reply

    @staticmethod
    def _err(cmd: int, code: int) -> bytes:
        return encode_packet(cmd, struct.pack("<H", code))

    def _handle(self, cmd: int, p: bytes, fault) -> bytes:
        if fault is not None and fault.kind == "error":
            return self._err(cmd, fault.code)
        n = len(self.shapes)
        if cmd == CMD_CONTROLLER:
            if p:
                return self._err(cmd, 14)
            return encode_packet(cmd, struct.pack("<HIBHBBBBIB", 0, self.serial, 1, 0x0302, 0, 0, 1, 0,
                                                  1_000_000, 0x42))
        if cmd == CMD_SENSOR:
            return encode_packet(cmd, struct.pack("<HHHBIB", 0, n, 0, 1, self.serial + 1, 0))
        if cmd == CMD_MATRIX:
            if len(p) != 1:
                return self._err(cmd, 12)
            m = p[0]
            if m >= n:
                return self._err(cmd, 24)
            cy, cx = self.shapes[m]
            return encode_packet(cmd, struct.pack("<HffHH6s2sB3f3ffB", 0, self.texel_size, self.texel_size,
                                                  cx, cy, bytes([m, 1, 2, 3, 4, 5]), b"\x00\x00", 1,
                                                  0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 250.0, 0))
        if cmd == CMD_ACQUISITION:
            if len(p) != 3:
                return self._err(cmd, 12)
            flags, rate = struct.unpack("<BH", p)
            self.rle = bool(flags & 0x01)
            ack = self._err(cmd, 0)
            if flags & 0x80 and rate == 0:
                self.streaming = False
                return ack + self._faulted(CMD_FRAME, self.frame_packet())
            if flags & 0x80:
                self.streaming, self.framerate = True, rate
                self._next_push = time.monotonic()
            else:
                self.streaming, self.framerate = False, 0
            return ack
        if cmd == CMD_SET_SENSITIVITY:
            if len(p) != 6:
                return self._err(cmd, 12)
            flags, m, value = struct.unpack("<BBf", p)
            if m >= n or not 0.0 <= value <= 1.0:
                return self._err(cmd, 23)
            targets = range(n) if flags & 0x02 else [m]
            for i in targets:
                self.sensitivity[i] = self.factory_sensitivity if flags & 0x01 else float(value)
            return b"" if flags & 0x80 else self._err(cmd, 0)
        if cmd == CMD_GET_SENSITIVITY:
            if len(p) != 1 or p[0] >= n:
                return self._err(cmd, 24)
            return encode_packet(cmd, struct.pack("<HBff", 0, 0x02, self.sensitivity[p[0]], self.factory_sensitivity))
        if cmd == CMD_SET_THRESHOLD:
            if len(p) != 4:
                return self._err(cmd, 12)
            flags, m, value = struct.unpack("<BBH", p)
            if m >= n or value > 4095:
                return self._err(cmd, 23)
            for i in (range(n) if flags & 0x02 else [m]):
                self.thresholds[i] = int(value)
            return b"" if flags & 0x80 else self._err(cmd, 0)
        if cmd == CMD_GET_THRESHOLD:
            if len(p) != 1 or p[0] >= n:
                return self._err(cmd, 24)
            return encode_packet(cmd, struct.pack("<HH", 0, self.thresholds[p[0]]))
        return self._err(cmd, 13)  # CMD_UNKNOWN
