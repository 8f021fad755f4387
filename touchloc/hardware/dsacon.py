"""Driver of the DSACON32m tactile controller of the SDH-2: packets, CRC16, frames, RLE.

Packet layout, command ids, payload layouts, error codes and the CRC rule are the
controller's published protocol as summarised in SCHUNK SDHLibrary-C++ 0.0.2.10 (dsa.cpp, crc.cpp) and the ROS driver schunk_sdh:

* packet ``AA AA AA | id u8 | len u16 | payload | CRC16 u16`` (little-endian; the CRC is
  present only when len > 0 and covers id, length and payload);
* CRC16: the MSB-first table of polynomial 0x1021, updated LSB-first
  (``crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]``), initial 0xFFFF, no final XOR;
* frames: timestamp u32 (ms), flags u8 (bit 0 = RLE), then texels; an RLE unit is a u16
  whose low 12 bits are the value and high 4 bits the repeat count (1..15).

Texel pitch and matrix sizes are read from the controller (query 0x0B); nothing here
assumes them.
"""

from __future__ import annotations

import collections
import functools
import math
import struct
import time
from dataclasses import dataclass

import numpy as np

from ..errors import (ChecksumError, FirmwareError, HardwareError, HardwareTimeout, ProtocolError, TouchlocError,
                      ValidationError)
from .._validate import as_bool, as_bytes, as_count, as_float_array, as_probability, as_sequence, as_timeout
from ._transport import Link, as_link

__all__ = [
    "DSACON32m", "DSAFirmwareError", "TactileFrame", "ControllerInfo", "SensorInfo", "MatrixInfo",
    "SensitivityInfo", "PacketParser", "crc16", "encode_packet", "decode_rle", "encode_rle",
    "decode_frame", "DSA_ERROR_NAMES", "POWERUP_ESC",
]

#: error codes (u16) of the controller, by value (dsacon32m.md, "Error codes")
DSA_ERROR_NAMES = (
    "SUCCESS", "NOT_AVAILABLE", "NO_SENSOR", "NOT_INITIALIZED", "ALREADY_RUNNING",
    "FEATURE_NOT_SUPPORTED", "INCONSISTENT_DATA", "TIMEOUT", "READ_ERROR", "WRITE_ERROR",
    "INSUFFICIENT_RESOURCES", "CHECKSUM_ERROR", "CMD_NOT_ENOUGH_PARAMS", "CMD_UNKNOWN",
    "CMD_FORMAT_ERROR", "ACCESS_DENIED", "ALREADY_OPEN", "CMD_FAILED", "CMD_ABORTED",
    "INVALID_HANDLE", "DEVICE_NOT_FOUND", "DEVICE_NOT_OPENED", "IO_ERROR", "INVALID_PARAMETER",
    "INDEX_OUT_OF_BOUNDS", "CMD_PENDING", "OVERRUN", "RANGE_ERROR",
)

PREAMBLE = b"\xaa\xaa\xaa"
#: what the controller sends about 7 s after power-up, three times: ESC "[5n"
POWERUP_ESC = b"\x1b[5n"

CMD_FRAME = 0x00
CMD_CONTROLLER = 0x01
CMD_SENSOR = 0x02
CMD_ACQUISITION = 0x03
CMD_MATRIX = 0x0B
CMD_SET_SENSITIVITY = 0x0F
CMD_GET_SENSITIVITY = 0x12
CMD_SET_THRESHOLD = 0x13
CMD_GET_THRESHOLD = 0x14

ACQ_START = 0x80
ACQ_SINGLE = 0x40
ACQ_RLE = 0x01


def _make_table() -> tuple:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_table()


def crc16(data, crc: int = 0xFFFF) -> int:
    """CRC16 of the DSACON32m (and of the SDH-2 binary mode) over ``data``.

    >>> hex(crc16(b"123456789"))
    '0x6eb4'
    """
    data = as_bytes(data, "data")
    crc = as_count(crc, "crc", min=0, max=0xFFFF)
    t = _CRC_TABLE
    for b in data:
        crc = (crc >> 8) ^ t[(crc ^ b) & 0xFF]
    return crc


def encode_packet(cmd: int, payload: bytes = b"") -> bytes:
    """One packet: preamble, id, length, payload and (when the payload is not empty) the CRC."""
    cmd = as_count(cmd, "packet id", min=0, max=0xFF)
    payload = as_bytes(payload, "payload")
    if len(payload) > 0xFFFF:
        raise ValidationError(f"payload must be at most 65535 bytes, got {len(payload)}")
    head = struct.pack("<BH", cmd, len(payload))
    if not payload:
        return PREAMBLE + head
    return PREAMBLE + head + payload + struct.pack("<H", crc16(head + payload))


class PacketParser:
    """Incremental packet reader: hunts for the preamble, checks lengths and CRCs.

    Parameters
    ----------
    max_payload : int
        Longest payload accepted (bytes); a longer length field is taken for garbage and
        the hunt continues one byte further.

    Attributes
    ----------
    skipped : int
        Bytes dropped while hunting for a preamble (garbage, power-up ESC sequences).
    """

    def __init__(self, max_payload: int = 16384):
        self.max_payload = as_count(max_payload, "max_payload", max=0xFFFF, why="the length field's range")
        self.buf = bytearray()
        self.skipped = 0

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self.buf += as_bytes(data, "data")

    def reset(self) -> None:
        self.buf.clear()

    def next(self):
        """The next complete packet as ``(id, payload bytes)``, or None when more bytes are needed.

        Raises
        ------
        ChecksumError
            A complete packet whose CRC does not match; it is dropped (the hunt resumes
            after its preamble), so the next call continues with the following bytes.
        """
        buf = self.buf
        while True:
            i = buf.find(PREAMBLE)
            if i < 0:
                keep = 2 if buf.endswith(b"\xaa\xaa") else (1 if buf.endswith(b"\xaa") else 0)
                self.skipped += len(buf) - keep
                del buf[:len(buf) - keep]
                return None
            if i:
                self.skipped += i
                del buf[:i]
            if len(buf) < 6:
                return None
            if buf[3] == 0xAA:  # a longer run of 0xAA: the preamble starts later
                self.skipped += 1
                del buf[:1]
                continue
            cmd = buf[3]
            n = buf[4] | (buf[5] << 8)
            if n > self.max_payload:
                self.skipped += 1
                del buf[:1]
                continue
            total = 6 + n + (2 if n else 0)
            if len(buf) < total:
                return None
            payload = bytes(buf[6:6 + n])
            if n:
                got = buf[6 + n] | (buf[7 + n] << 8)
                want = crc16(memoryview(buf)[3:6 + n])
                if got != want:
                    self.skipped += 3
                    del buf[:3]
                    raise ChecksumError(f"DSACON32m packet 0x{cmd:02x} ({n} bytes): CRC 0x{got:04x}, "
                                        f"expected 0x{want:04x}; dropped")
            del buf[:total]
            return cmd, payload


def decode_rle(data, n: int) -> np.ndarray:
    """Decode RLE texel data into ``n`` uint16 values (12-bit).

    Each little-endian u16 unit is ``count << 12 | value`` with count 1..15.

    Raises :class:`ProtocolError` on an odd byte count, a zero count or a total other
    than ``n``.
    """
    data = as_bytes(data, "data")
    n = as_count(n, "n", min=0, max=10**7, why="texels of a frame")
    if len(data) % 2:
        raise ProtocolError(f"RLE data must be whole u16 units, got {len(data)} bytes")
    u = np.frombuffer(data, dtype="<u2")
    counts = (u >> 12).astype(np.int64)
    if counts.size and counts.min() == 0:
        raise ProtocolError(f"RLE unit {int(np.argmin(counts))} has a repeat count of 0 (expected 1..15)")
    total = int(counts.sum())
    if total != n:
        raise ProtocolError(f"RLE data decodes to {total} texels, expected {n}")
    return np.repeat((u & 0x0FFF).astype(np.uint16), counts)


def encode_rle(values) -> bytes:
    """Encode 12-bit texel values as RLE units (runs of up to 15)."""
    f = as_float_array(values, "values", expected="12-bit texel values").reshape(-1)
    if f.size and (f.min() < 0 or f.max() > 0x0FFF or np.any(f != np.floor(f))):
        raise ValidationError("texel values must be integers in 0..4095 for RLE")
    v = f.astype(np.int64)
    if v.size == 0:
        return b""
    change = np.flatnonzero(np.diff(v)) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [v.size]]))
    vals = v[starts]
    reps = (lengths + 14) // 15
    run_vals = np.repeat(vals, reps)
    counts = np.full(run_vals.size, 15, dtype=np.int64)
    last = np.cumsum(reps) - 1
    counts[last] = lengths - 15 * (reps - 1)
    return ((counts << 12) | run_vals).astype("<u2").tobytes()


@dataclass(frozen=True)
class TactileFrame:
    """One tactile frame.

    Attributes
    ----------
    timestamp : int
        Controller time (ms).
    flags : int
        Frame flags (bit 0: the frame was RLE-coded on the wire).
    texels : (N,) uint16
        All texels, matrix by matrix, each row-major.
    matrices : tuple of (cells_y, cells_x) uint16
        Views of ``texels`` per matrix (index = 2 * finger + part).
    """

    timestamp: int
    flags: int
    texels: np.ndarray
    matrices: tuple

    @property
    def rle(self) -> bool:
        return bool(self.flags & 1)

    def max(self) -> int:
        return int(self.texels.max()) if self.texels.size else 0


def decode_frame(payload: bytes, shapes) -> TactileFrame:
    """Decode a frame packet's payload for matrices of the given (cells_y, cells_x) shapes."""
    payload = as_bytes(payload, "payload")
    shapes = _check_shapes(shapes)
    if len(payload) < 5:
        raise ProtocolError(f"frame payload must hold at least 5 bytes (timestamp, flags), got {len(payload)}")
    ts, flags = struct.unpack_from("<IB", payload)
    data = payload[5:]
    n = int(sum(a * b for a, b in shapes))
    if flags & 1:
        tex = decode_rle(data, n)
    else:
        if len(data) != 2 * n:
            raise ProtocolError(f"raw frame must hold {2 * n} texel bytes ({n} texels), got {len(data)}")
        tex = np.frombuffer(data, dtype="<u2").astype(np.uint16)
    tex.flags.writeable = False
    mats, i = [], 0
    for cy, cx in shapes:
        mats.append(tex[i:i + cy * cx].reshape(cy, cx))
        i += cy * cx
    return TactileFrame(int(ts), int(flags), tex, tuple(mats))


def _check_shapes(shapes) -> list:
    """Matrix shapes as a list of (cells_y, cells_x) positive ints."""
    out = []
    for i, s in enumerate(as_sequence(shapes, "shapes", min_len=1, max_len=64,
                                      expected="a list of (cells_y, cells_x) pairs")):
        pair = as_sequence(s, f"shapes[{i}]", min_len=2, max_len=2, expected="a (cells_y, cells_x) pair")
        out.append(tuple(as_count(v, f"shapes[{i}]", max=256, why="texels of one pad") for v in pair))
    return out


@dataclass(frozen=True)
class ControllerInfo:
    error: int
    serial: int
    hw_version: int
    sw_version: int
    status: int
    features: int
    senscon_type: int
    active_interface: int
    can_baudrate: int
    can_id: int


@dataclass(frozen=True)
class SensorInfo:
    error: int
    nb_matrices: int
    generated_by: int
    hw_revision: int
    serial: int
    features: int


@dataclass(frozen=True)
class MatrixInfo:
    """Geometry of one matrix as reported by the controller (texel sizes in mm)."""

    error: int
    texel_width: float
    texel_height: float
    cells_x: int
    cells_y: int
    uid: bytes
    hw_revision: int
    center: tuple
    theta: tuple
    fullscale: float
    features: int


@dataclass(frozen=True)
class SensitivityInfo:
    adjustable: bool
    current: float
    factory: float


_FMT_CONTROLLER = "<HIBHBBBBIB"   # 18 bytes (can_id truncated to one byte on the wire)
_FMT_SENSOR = "<HHHBIB"           # 12 bytes
_FMT_MATRIX = "<HffHH6s2sB3f3ffB"  # 52 bytes
_FMT_SENS_INFO = "<HBff"          # 11 bytes


class DSAFirmwareError(FirmwareError):
    """The DSACON32m answered with a non-zero error code; ``code`` and ``name`` say which."""


def _check_error(cmd: int, payload: bytes) -> None:
    if len(payload) < 2:
        raise ProtocolError(f"DSACON32m reply 0x{cmd:02x}: expected an error code (2 bytes), got {len(payload)}")
    code = payload[0] | (payload[1] << 8)
    if code:
        name = DSA_ERROR_NAMES[code] if code < len(DSA_ERROR_NAMES) else f"UNKNOWN_CODE_{code}"
        raise DSAFirmwareError(code, name, f"DSACON32m command 0x{cmd:02x} failed: error {code} ({name})")


def _unpack(fmt: str, cmd: int, payload: bytes):
    _check_error(cmd, payload)
    size = struct.calcsize(fmt)
    if len(payload) != size:
        raise ProtocolError(f"DSACON32m reply 0x{cmd:02x}: expected {size} bytes, got {len(payload)}")
    return struct.unpack(fmt, payload)


def _typed(method):
    """Let only library errors leave a DSACON32m call; a raw one becomes ProtocolError."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except TouchlocError:
            raise
        except Exception as exc:
            raise ProtocolError(f"DSACON32m {method.__name__}: unusable reply "
                                f"({type(exc).__name__}: {exc})") from exc

    return wrapper


class DSACON32m:
    """The DSACON32m tactile controller over an injected transport.

    Parameters
    ----------
    port : serial port or Link
        ``serial.serial_for_url("/dev/ttyUSB1", baudrate=115200)`` (its own serial line),
        or ``"socket://192.168.1.42:13000"`` on hands with Ethernet.
    timeout : float
        Seconds to wait for a reply (default 1.0).
    connect : bool
        Run the opening sequence now: stop acquisition (3 tries, ``open_timeout`` each),
        drop pending input, read controller, sensor and matrix info.
    open_timeout : float
        Timeout of each try of the first command (default 3 s: the controller accepts
        commands only about 8 s after power-up and sends ESC "[5n" before that).
    retries : int
        Tries of the first command (default 3).
    max_skip : int
        Garbage bytes tolerated while waiting for one reply before a ProtocolError.
    max_packets : int
        Unexpected packets (e.g. pushed frames) skipped while waiting for one reply.
    """

    def __init__(self, port, *, timeout: float = 1.0, connect: bool = True, open_timeout: float = 3.0,
                 retries: int = 3, max_skip: int = 65536, max_packets: int = 1000,
                 max_payload: int = 16384):
        timeout = as_timeout(timeout)
        if timeout <= 0:
            raise ValidationError(f"timeout must be a positive number of seconds, got {timeout!r}")
        open_timeout = as_timeout(open_timeout, "open_timeout")
        connect = as_bool(connect, "connect")
        retries = as_count(retries, "retries", max=100)
        max_skip = as_count(max_skip, "max_skip", min=0)
        max_packets = as_count(max_packets, "max_packets", min=0)
        max_payload = as_count(max_payload, "max_payload", max=65535, why="the packet length field is 16 bits")
        self.link: Link = as_link(port)
        self.timeout = float(timeout)
        self.open_timeout = float(open_timeout)
        self.retries = int(retries)
        self.max_skip = int(max_skip)
        self.max_packets = int(max_packets)
        self.parser = PacketParser(max_payload)
        self._frames = collections.deque(maxlen=8)
        self.streaming = False
        self.rle = True
        self.controller = None
        self.sensor = None
        self.matrix_infos: list = []
        self.crc_errors = 0
        if connect:
            self.connect()

    # -- packet exchange ----------------------------------------------------------------
    def _send(self, cmd: int, payload: bytes = b"") -> None:
        self.link.write(encode_packet(cmd, payload))

    def _wait(self, want: int, timeout: float | None = None) -> bytes:
        """Read packets until one with id ``want``; frames met on the way are kept."""
        timeout = self.timeout if timeout is None else as_timeout(timeout)
        deadline = time.monotonic() + timeout
        skipped0 = self.parser.skipped
        others = 0
        while True:
            pkt = self.parser.next()  # may raise ChecksumError (parser already resynced)
            if pkt is not None:
                cmd, payload = pkt
                if cmd == want:
                    return payload
                if cmd == CMD_FRAME:
                    self._frames.append(payload)
                others += 1
                if others > self.max_packets:
                    raise ProtocolError(f"DSACON32m: {others} packets without the reply 0x{want:02x}")
                continue
            if self.parser.skipped - skipped0 > self.max_skip:
                raise ProtocolError(f"DSACON32m: {self.parser.skipped - skipped0} bytes without a packet "
                                    f"(waiting for 0x{want:02x})")
            left = deadline - time.monotonic()
            if left <= 0:
                raise HardwareTimeout(f"DSACON32m did not answer 0x{want:02x} within {timeout:g} s")
            self.parser.feed(self.link.read_some(min(left, 0.1)))

    def _request(self, cmd: int, payload: bytes = b"", timeout: float | None = None) -> bytes:
        self._send(cmd, payload)
        try:
            return self._wait(cmd, timeout)
        except ChecksumError:
            self.crc_errors += 1
            raise

    # -- opening ------------------------------------------------------------------------
    @_typed
    def connect(self) -> None:
        """Stop acquisition (with retries), flush, read controller, sensor and matrix info."""
        last = None
        for _ in range(self.retries):
            try:
                self.configure_acquisition(start=False, framerate=0, rle=True, timeout=self.open_timeout)
                break
            except (HardwareTimeout, ProtocolError) as exc:  # includes ChecksumError
                last = exc
                self.link.discard_input(quiet=0.02, limit=0.5)
                self.parser.reset()
        else:
            raise last
        self.link.discard_input(quiet=0.02, limit=0.5)
        self.parser.reset()
        self._frames.clear()
        self.controller = self.controller_info()
        self.sensor = self.sensor_info()
        self.matrix_infos = [self.matrix_info(m) for m in range(self.sensor.nb_matrices)]

    # -- queries ------------------------------------------------------------------------
    @_typed
    def controller_info(self) -> ControllerInfo:
        """Query 0x01: serial number, versions, interface, CAN settings."""
        return ControllerInfo(*_unpack(_FMT_CONTROLLER, CMD_CONTROLLER, self._request(CMD_CONTROLLER)))

    @_typed
    def sensor_info(self) -> SensorInfo:
        """Query 0x02: number of matrices and the sensor's serial number."""
        return SensorInfo(*_unpack(_FMT_SENSOR, CMD_SENSOR, self._request(CMD_SENSOR)))

    def _matrix(self, m) -> int:
        m = as_count(m, "matrix", min=0, max=255)
        if self.matrix_infos and m >= len(self.matrix_infos):
            raise ValidationError(f"matrix must be 0..{len(self.matrix_infos) - 1}, got {m}")
        return int(m)

    @_typed
    def matrix_info(self, m: int) -> MatrixInfo:
        """Query 0x0B: texel sizes (mm), cells, position and full scale of matrix ``m``."""
        m = self._matrix(m)
        v = _unpack(_FMT_MATRIX, CMD_MATRIX, self._request(CMD_MATRIX, bytes([m])))
        return MatrixInfo(v[0], v[1], v[2], v[3], v[4], v[5], v[7], tuple(v[8:11]), tuple(v[11:14]), v[14], v[15])

    @property
    def shapes(self) -> list:
        """(cells_y, cells_x) of every matrix, from the matrix info."""
        return [(i.cells_y, i.cells_x) for i in self.matrix_infos]

    # -- acquisition -----------------------------------------------------------------------
    @_typed
    def configure_acquisition(self, *, start: bool, framerate: int = 0, rle: bool = True,
                              timeout: float | None = None) -> None:
        """Command 0x03: start (``framerate`` > 0: streaming; 0: one frame) or stop acquisition."""
        framerate = as_count(framerate, "framerate (frames/s)", min=0, max=0xFFFF)
        flags = (ACQ_START if start else 0) | (ACQ_RLE if rle else 0)
        _check_error(CMD_ACQUISITION, self._request(CMD_ACQUISITION, struct.pack("<BH", flags, int(framerate)), timeout))
        self.rle = bool(rle)

    def _next_frame(self, timeout: float | None) -> TactileFrame:
        if not self._frames:
            try:
                self._frames.append(self._wait(CMD_FRAME, timeout))
            except ChecksumError:
                self.crc_errors += 1
                raise
        return decode_frame(self._frames.popleft(), self.shapes)

    @_typed
    def read_frame(self, *, timeout: float | None = None) -> TactileFrame:
        """One tactile frame: the next streamed frame, or a single frame on request."""
        if not self.matrix_infos:
            raise HardwareError("DSACON32m: no matrix info yet; call connect() first")
        if self.streaming:
            return self._next_frame(timeout)
        self._frames.clear()
        self.configure_acquisition(start=True, framerate=0, rle=self.rle, timeout=timeout)
        return self._next_frame(timeout)

    @_typed
    def start_streaming(self, framerate: int = 30, *, rle: bool = True) -> None:
        """Ask the controller to push frames at ``framerate`` frames/s."""
        framerate = as_count(framerate, "streaming framerate (frames/s)", min=1, max=0xFFFF)
        self._frames.clear()
        self.configure_acquisition(start=True, framerate=framerate, rle=rle)
        self.streaming = True

    @_typed
    def stop_streaming(self) -> None:
        """Stop pushed frames (frames still in flight are skipped)."""
        self.streaming = False
        self.configure_acquisition(start=False, framerate=0, rle=self.rle)
        self._frames.clear()

    def frames(self, n: int | None = None, *, skip_bad: bool = False):
        """Iterate over streamed frames (``n`` of them, or forever).

        With ``skip_bad``, frames with a CRC error are counted in ``crc_errors`` and
        skipped instead of raising.
        """
        if not self.streaming:
            raise HardwareError("DSACON32m: call start_streaming() before frames()")
        k = 0
        while n is None or k < n:
            try:
                yield self._next_frame(None)
            except ChecksumError:
                if not skip_bad:
                    raise
                continue
            k += 1

    # -- sensitivity and threshold ------------------------------------------------------------
    @_typed
    def sensitivity(self, m: int) -> SensitivityInfo:
        """Query 0x12: whether matrix ``m``'s sensitivity is adjustable, current and factory values."""
        m = self._matrix(m)
        v = _unpack(_FMT_SENS_INFO, CMD_GET_SENSITIVITY, self._request(CMD_GET_SENSITIVITY, bytes([m])))
        return SensitivityInfo(bool(v[1] & 0x02), float(v[2]), float(v[3]))

    @_typed
    def set_sensitivity(self, m: int, value: float, *, persistent: bool = False, all_matrices: bool = False,
                        reset: bool = False) -> None:
        """Command 0x0F: set the sensitivity (0..1) of matrix ``m`` (or all, or reset to factory)."""
        m = self._matrix(m)
        value = as_probability(value, "sensitivity")
        flags = (0x80 if persistent else 0) | (0x02 if all_matrices else 0) | (0x01 if reset else 0)
        payload = struct.pack("<BBf", flags, m, float(value))
        if persistent:  # no reply when stored persistently
            self._send(CMD_SET_SENSITIVITY, payload)
            return
        _check_error(CMD_SET_SENSITIVITY, self._request(CMD_SET_SENSITIVITY, payload))

    @_typed
    def threshold(self, m: int) -> int:
        """Query 0x14: the threshold of matrix ``m`` (texel units)."""
        m = self._matrix(m)
        return int(_unpack("<HH", CMD_GET_THRESHOLD, self._request(CMD_GET_THRESHOLD, bytes([m])))[1])

    @_typed
    def set_threshold(self, m: int, value: int, *, persistent: bool = False, all_matrices: bool = False) -> None:
        """Command 0x13: set the threshold (0..4095) of matrix ``m``."""
        m = self._matrix(m)
        value = as_count(value, "threshold", min=0, max=4095)
        flags = (0x80 if persistent else 0) | (0x02 if all_matrices else 0)
        payload = struct.pack("<BBH", flags, m, int(value))
        if persistent:
            self._send(CMD_SET_THRESHOLD, payload)
            return
        _check_error(CMD_SET_THRESHOLD, self._request(CMD_SET_THRESHOLD, payload))

    def close(self) -> None:
        self.link.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
