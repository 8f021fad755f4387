"""Driver of the SCHUNK SDH-2 three-finger hand: the ASCII command protocol.

Protocol facts (commands, replies, units, error codes, limits) are those listed in
``docs/hardware.md`` and taken from the hand's published host library (see
SCHUNK SDHLibrary-C++ 0.0.2.10 and the ROS driver schunk_sdh). The library speaks radians; the wire speaks degrees.

Every fault seen while talking to the hand (timeout, malformed reply, firmware error,
disconnect) makes the driver send ``stop`` (best effort, without waiting for the answer)
before the typed error is raised, so that a failed exchange never leaves a finger moving.
"""

from __future__ import annotations

import enum
import functools
import math
import re
import time
from dataclasses import dataclass

import numpy as np

from ..errors import (FirmwareError, HardwareError, HardwareTimeout,
                      JointLimitError, ProtocolError, ValidationError)
from .._validate import as_bool, as_timeout
from ._transport import CANLink, Link, as_link

__all__ = ["SDH2", "SDHFirmwareError", "AxisState", "SDH_ERROR_NAMES", "GripPreset",
           "DEFAULT_ANGLE_LIMITS_DEG", "parse_reply", "parse_values", "LineReader"]

#: firmware error names by code E<n> (sdh2.md, "Codes")
SDH_ERROR_NAMES = (
    "SUCCESS", "NOT_AVAILABLE", "NOT_INITIALIZED", "ALREADY_RUNNING", "FEATURE_NOT_SUPPORTED",
    "INCONSISTENT_DATA", "TIMEOUT", "READ_ERROR", "WRITE_ERROR", "INSUFFICIENT_RESOURCES",
    "CHECKSUM_ERROR", "NOT_ENOUGH_PARAMS", "NO_PARAMS_EXPECTED", "CMD_UNKNOWN",
    "CMD_FORMAT_ERROR", "ACCESS_DENIED", "ALREADY_OPEN", "CMD_FAILED", "CMD_ABORTED",
    "INVALID_HANDLE", "DEVICE_NOT_FOUND", "DEVICE_NOT_OPENED", "IO_ERROR", "INVALID_PARAMETER",
    "RANGE_ERROR", "NO_DATAPIPE", "INDEX_OUT_OF_BOUNDS", "HOMING_ERROR", "AXIS_DISABLED",
    "OVER_TEMPERATURE", "MAX_COMMANDS_EXCEEDED", "INVALID_PASSWORD", "MAX_COMMANDLINE_EXCEEDED",
    "CRC_ERROR", "NO_COMMAND", "INTERNAL", "UNKNOWN_ERROR",
)

N_AXES = 7
#: joint limits in degrees (sdh2.md, "Axes, fingers, limits"); replaced by p_min / p_max
#: read from the firmware on connect
DEFAULT_ANGLE_LIMITS_DEG = (np.array([0.0, -90, -90, -90, -90, -90, -90]),
                            np.array([90.0, 90, 90, 90, 90, 90, 90]))
#: default velocity (deg/s) and acceleration (deg/s^2) limits (sdh2.md)
DEFAULT_VLIM_DEG = np.array([80.0, 100, 100, 100, 100, 100, 100])
DEFAULT_ALIM_DEG = np.array([5000.0, 400, 1500, 400, 1500, 400, 1500])

_LINE_MAX = 4096  # bytes: a reply line longer than this is a protocol error

#: physical ranges of reply values (wire units); a reply outside is a ProtocolError.
#: Joints turn less than a full turn, speeds stay well below 1000 deg/s, and no move or
#: grip of the hand lasts ten minutes, so a value beyond these bounds is a corrupted reply.
REPLY_RANGES = {
    "angle": (-360.0, 360.0),          # deg
    "velocity": (-1000.0, 1000.0),     # deg/s
    "acceleration": (0.0, 100_000.0),  # deg/s^2
    "duration": (0.0, 600.0),          # s
    "temperature": (-60.0, 200.0),     # deg C
}
_KIND = {"p": "angle", "pos": "angle", "tpap": "angle", "p_min": "angle", "p_max": "angle",
         "v": "velocity", "vel": "velocity", "rvel": "velocity", "tvav": "velocity", "vlim": "velocity",
         "a": "acceleration", "alim": "acceleration", "temp": "temperature"}
MAX_AXES = 64  # an identification reply announcing more axes than this is corrupt


def _in_range(v: np.ndarray, kind: str, what: str) -> np.ndarray:
    lo, hi = REPLY_RANGES[kind]
    bad = (v < lo) | (v > hi)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ProtocolError(f"SDH-2 {what}: value {v[i]!r} outside the physical {kind} range [{lo:g}, {hi:g}]")
    return v


def _duration(values, what: str) -> float:
    if len(values) < 1:
        raise ProtocolError(f"SDH-2 {what}: expected a duration in seconds, got no value")
    try:
        d = float(values[0])
    except ValueError:
        raise ProtocolError(f"SDH-2 {what}: expected a duration in seconds, got {values[:3]}") from None
    if not math.isfinite(d):
        raise ProtocolError(f"SDH-2 {what}: non-finite duration {values[0]!r}")
    return float(_in_range(np.array([d]), "duration", what)[0])


def _guarded(method):
    """Make every failure of a driver call end in a typed error, with ``stop`` sent.

    Validation errors (raised before anything is sent) pass unchanged. Any other
    exception -- a library error or a raw one from a corrupted reply -- makes sure a
    ``stop`` went out during the call (when the link is alive) and leaves as a
    :class:`~touchloc.errors.TouchlocError`; raw exceptions become :class:`ProtocolError`.
    """

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        if self._depth:
            return method(self, *args, **kwargs)
        self._depth += 1
        stops0 = self.stops_sent
        try:
            return method(self, *args, **kwargs)
        except (ValidationError, JointLimitError):
            raise
        except HardwareError:
            if self.stops_sent == stops0:
                self._fault(None)
            raise
        except Exception as exc:  # a raw error from a corrupted reply: never let it escape
            if self.stops_sent == stops0:
                self._fault(None)
            raise ProtocolError(f"SDH-2 {method.__name__}: unusable reply ({type(exc).__name__}: {exc})") from exc
        finally:
            self._depth -= 1

    return wrapper


class SDHFirmwareError(FirmwareError):
    """The SDH-2 firmware answered ``E<n>``; ``code`` and ``name`` say which error."""


class AxisState(enum.IntEnum):
    """Per-axis state codes reported by ``state`` (sdh2.md, "Codes")."""

    IDLE = 0
    POSITIONING = 1
    SPEED_MODE = 2
    NOT_INITIALIZED = 3
    CW_BLOCKED = 4
    CCW_BLOCKED = 5
    DISABLED = 6
    LIMITS_REACHED = 7


class GripPreset(enum.IntEnum):
    """Preset grasps of ``selgrip`` (sdh2.md)."""

    CENTRICAL = 0
    PARALLEL = 1
    CYLINDRICAL = 2
    SPHERICAL = 3


_REPLY_RE = re.compile(r"^([A-Z_]+)(\([0-9]+\))?(?:=(.*))?$", re.ASCII | re.DOTALL)
_ERROR_RE = re.compile(r"^E([0-9]{1,6})$", re.ASCII)


def parse_reply(line: str):
    """Split one reply line into ``(name, index, values)``.

    ``"P=1.0,2.0"`` -> ``("P", None, ["1.0", "2.0"])``; ``"P(3)=12.5"`` ->
    ``("P", 3, ["12.5"])``; ``"STOP"`` -> ``("STOP", None, [])``. Raises
    :class:`SDHFirmwareError` for ``E<n>`` and :class:`ProtocolError` for anything else
    that is not a reply.
    """
    em = _ERROR_RE.match(line)
    if em is not None:
        code = int(em.group(1))
        name = SDH_ERROR_NAMES[code] if code < len(SDH_ERROR_NAMES) else f"UNKNOWN_CODE_{code}"
        raise SDHFirmwareError(code, name, f"SDH-2 firmware error E{code} ({name})")
    m = _REPLY_RE.match(line)
    if m is None:
        raise ProtocolError(f"SDH-2 reply {line[:80]!r} is not NAME[=values] or E<n>")
    name, idx, vals = m.group(1), m.group(2), m.group(3)
    index = int(idx[1:-1]) if idx else None
    values = [] if vals is None or vals == "" else [v.strip() for v in vals.split(",")]
    return name, index, values


def _floats(values, n, what):
    if len(values) != n:
        raise ProtocolError(f"SDH-2 {what}: expected {n} values, got {len(values)}: {values[:10]}")
    try:
        out = np.array([float(v) for v in values], dtype=np.float64)
    except ValueError:
        raise ProtocolError(f"SDH-2 {what}: values must be numbers, got {values[:10]}") from None
    if not np.all(np.isfinite(out)):
        raise ProtocolError(f"SDH-2 {what}: non-finite values {values[:10]}")
    return out


class LineReader:
    """Splits the hand's reply bytes into text lines (CR/LF stripped).

    Raises :class:`ProtocolError` for a line that is not ASCII or longer than
    ``max_line`` bytes (the buffer is dropped, so reading can go on afterwards).
    """

    def __init__(self, max_line: int = _LINE_MAX):
        self.max_line = int(max_line)
        self._buf = bytearray()

    def feed(self, data: bytes) -> None:
        self._buf += data

    def clear(self) -> None:
        self._buf.clear()

    def pending(self) -> bytes:
        return bytes(self._buf)

    def next_line(self):
        """The next complete line, or None when no line end has arrived yet."""
        i = self._buf.find(b"\n")
        if i < 0:
            if len(self._buf) > self.max_line:
                n = len(self._buf)
                self._buf.clear()
                raise ProtocolError(f"SDH-2 reply line longer than {self.max_line} bytes ({n}) without a line end")
            return None
        raw = bytes(self._buf[:i])
        del self._buf[:i + 1]
        try:
            return raw.decode("ascii").strip("\r\n\x00 ")
        except UnicodeDecodeError:
            raise ProtocolError(f"SDH-2 reply is not ASCII: {raw[:40]!r}") from None


def parse_values(values, n: int, what: str = "reply") -> np.ndarray:
    """``n`` finite floats from reply values (ProtocolError otherwise)."""
    return _floats(values, n, what)


@dataclass(frozen=True)
class Identification:
    """What the hand says about itself (``ver``, ``ver_date``, ``id``, ``sn``, ``soc``...)."""

    firmware: str
    firmware_date: str
    hand_id: str
    serial_number: str
    soc: str
    soc_date: str
    num_axes: int


class SDH2:
    """The SDH-2 hand over an injected transport.

    Parameters
    ----------
    port : serial port, python-can bus or Link
        An open transport. For RS232: ``serial.serial_for_url("/dev/ttyUSB0",
        baudrate=115200)``; for a hand with Ethernet: ``serial.serial_for_url(
        "socket://192.168.1.42:23")``. For CAN use :meth:`over_can`.
    timeout : float
        Seconds to wait for each reply line (default 1.0).
    connect : bool
        Run the opening handshake now (``" \\r\\n"``, drain, ``ver``) and read the joint
        limits from the firmware (default True).
    stop_on_fault : bool
        Send ``stop`` before raising on any fault (default True).

    Notes
    -----
    Angles are radians, velocities rad/s and accelerations rad/s^2 in every method;
    the driver converts to and from the degrees of the wire.
    """

    N_AXES = N_AXES

    def __init__(self, port, *, timeout: float = 1.0, connect: bool = True, stop_on_fault: bool = True):
        timeout = as_timeout(timeout, "timeout")
        if timeout <= 0:
            raise ValidationError(f"timeout must be a positive number of seconds, got {timeout!r}")
        connect = as_bool(connect, "connect")
        stop_on_fault = as_bool(stop_on_fault, "stop_on_fault")
        self._depth = 0
        self.stops_sent = 0
        self.link: Link = as_link(port)
        self.timeout = float(timeout)
        self.stop_on_fault = bool(stop_on_fault)
        self._lines = LineReader()
        lo, hi = DEFAULT_ANGLE_LIMITS_DEG
        self._lo = np.radians(lo)
        self._hi = np.radians(hi)
        self.velocity_limits = np.radians(DEFAULT_VLIM_DEG)
        self.acceleration_limits = np.radians(DEFAULT_ALIM_DEG)
        self.stops_sent = 0
        self._version = None
        if connect:
            self.connect()

    @classmethod
    def over_can(cls, bus, *, tx_id: int = 42, rx_id: int = 43, **kwargs) -> "SDH2":
        """The hand on a python-can bus: requests on ``tx_id`` (42), answers on ``rx_id`` (43).

        Parameters
        ----------
        bus : can.BusABC
            E.g. ``can.Bus(interface="socketcan", channel="can0", bitrate=1_000_000)``,
            ``interface="pcan", channel="PCAN_USBBUS1"``, ``interface="ixxat", channel=0``
            or, in tests, ``interface="virtual"``.
        """
        return cls(CANLink(bus, tx_id=tx_id, rx_id=rx_id), **kwargs)

    # -- low level -------------------------------------------------------------------
    @_guarded
    def connect(self) -> str:
        """Opening handshake: end any half-sent command, drain input, ask ``ver``.

        Also reads the joint, velocity and acceleration limits. Returns the firmware
        version string.
        """
        self._write(b" \r\n")
        self.link.discard_input(quiet=0.05, limit=0.5)
        self._lines.clear()
        self._version = self.firmware_version()
        self._lo = np.radians(self._get_values("p_min", N_AXES))
        self._hi = np.radians(self._get_values("p_max", N_AXES))
        if np.any(self._lo > self._hi):
            raise self._fault(ProtocolError(f"SDH-2 limits: p_min {np.degrees(self._lo)} above p_max {np.degrees(self._hi)}"))
        self.velocity_limits = np.radians(self._get_values("vlim", N_AXES))
        self.acceleration_limits = np.radians(self._get_values("alim", N_AXES))
        return self._version

    def _write(self, data: bytes) -> None:
        self.link.write(data)

    def _readline(self, deadline: float) -> str:
        while True:
            line = self._lines.next_line()
            if line is not None:
                return line
            left = deadline - time.monotonic()
            if left <= 0:
                partial = self._lines.pending()
                raise HardwareTimeout(f"SDH-2 did not answer within {self.timeout:g} s"
                                      + (f" (partial reply {partial[:40]!r})" if partial else ""))
            self._lines.feed(self.link.read_some(min(left, 0.1)))

    def _fault(self, exc: HardwareError | None) -> HardwareError | None:
        """Send ``stop`` (best effort, when the link is alive) and return ``exc`` for raising."""
        if self.stop_on_fault:
            try:
                self._write(b"stop\r\n")
                self.stops_sent += 1
            except Exception:  # a dead link: nothing can be sent
                pass
        return exc

    @_guarded
    def command(self, cmd: str, *, timeout: float | None = None):
        """Send one ASCII command and return its reply as ``(name, index, values)``.

        Debug lines (``@...``) and empty lines are skipped; a reply naming another
        command (a late answer to an earlier request) is skipped too.

        Raises
        ------
        SDHFirmwareError
            The hand answered ``E<n>``.
        HardwareTimeout
            No reply within ``timeout`` (default: the driver's).
        ProtocolError
            A reply that is not ``NAME[=values]``.
        DeviceDisconnected
            The transport closed.
        """
        if not isinstance(cmd, str) or not cmd or not cmd.isascii() or "\n" in cmd or "\r" in cmd:
            raise ValidationError(f"command must be a non-empty single-line string, got {cmd!r}")
        m = re.match(r"^([a-z_]+)(\(\d+\))?", cmd)
        if m is None:
            raise ValidationError(f"command must start with a lower-case name like 'p' or 'p(3)', got {cmd!r}")
        want = m.group(1).upper()
        deadline = time.monotonic() + (self.timeout if timeout is None else as_timeout(timeout))
        try:
            self._write(cmd.encode("ascii") + b"\r\n")
            while True:
                line = self._readline(deadline)
                if not line or line.startswith("@"):
                    continue
                name, index, values = parse_reply(line)
                if name == want:
                    return name, index, values
        except HardwareError as exc:
            self._fault(exc)
            raise
        except Exception as exc:  # a raw error (transport, decoding): stop, then a typed error
            self._fault(None)
            raise ProtocolError(f"SDH-2 {cmd[:20]!r}: {type(exc).__name__}: {exc}") from exc

    def _get_values(self, cmd: str, n: int) -> np.ndarray:
        _, _, values = self.command(cmd)
        try:
            v = _floats(values, n, cmd)
            return _in_range(v, _KIND[cmd], cmd) if cmd in _KIND else v
        except ProtocolError as exc:
            raise self._fault(exc) from None

    def _get_text(self, cmd: str) -> str:
        _, _, values = self.command(cmd)
        return ",".join(values)

    def _check_vector(self, values, name: str, *, unit: str) -> np.ndarray:
        try:
            a = np.asarray(values, dtype=np.float64).reshape(-1) if np.ndim(values) else None
        except (TypeError, ValueError, OverflowError):
            a = None
        if a is None or a.shape != (N_AXES,) or not np.all(np.isfinite(a)):
            raise ValidationError(f"{name} must be {N_AXES} finite values in {unit}, got {values!r}")
        return a

    @staticmethod
    def _fmt(deg: np.ndarray) -> str:
        return ",".join(f"{v:.3f}" for v in deg)

    # -- identification ---------------------------------------------------------------
    @_guarded
    def firmware_version(self) -> str:
        """Firmware release, e.g. ``"0.0.2.15"``."""
        return self._get_text("ver")

    @_guarded
    def identification(self) -> Identification:
        """Firmware, dates, hand id, serial number, SoC and number of axes."""
        n = self._get_text("numaxis")
        try:
            f = float(n)
        except ValueError:
            f = float("nan")
        if not (math.isfinite(f) and f == int(f) and 1 <= f <= MAX_AXES):
            raise self._fault(ProtocolError(f"SDH-2 numaxis: expected an integer 1..{MAX_AXES}, got {n!r}"))
        num = int(f)
        return Identification(self._get_text("ver"), self._get_text("ver_date"), self._get_text("id"),
                              self._get_text("sn"), self._get_text("soc"), self._get_text("soc_date"), num)

    # -- angles, velocities, accelerations ---------------------------------------------
    @property
    def angle_limits(self):
        """(lower (7,), upper (7,)) joint limits in radians (read from the hand on connect)."""
        return self._lo.copy(), self._hi.copy()

    def check_angles(self, angles) -> np.ndarray:
        """Validate 7 target angles (rad) against the joint limits; returns them as floats.

        Raises :class:`JointLimitError` (nothing is sent) when any is outside.
        """
        a = self._check_vector(angles, "angles", unit="radians")
        tol = 1e-9
        bad = np.flatnonzero((a < self._lo - tol) | (a > self._hi + tol))
        if bad.size:
            i = int(bad[0])
            raise JointLimitError(
                f"target of axis {i} is {math.degrees(a[i]):.3f} deg, outside its limits "
                f"[{math.degrees(self._lo[i]):.1f}, {math.degrees(self._hi[i]):.1f}] deg; nothing was sent")
        return a

    @_guarded
    def target_angles(self) -> np.ndarray:
        """(7,) float: the current target angles (rad)."""
        return np.radians(self._get_values("p", N_AXES))

    @_guarded
    def set_target_angles(self, angles) -> np.ndarray:
        """Set all 7 target angles (rad) without moving; returns the targets the hand echoed."""
        a = self.check_angles(angles)
        _, _, values = self.command("p=" + self._fmt(np.degrees(a)))
        return np.radians(self._parse(values, "p"))

    def _parse(self, values, what):
        try:
            v = _floats(values, N_AXES, what)
            return _in_range(v, _KIND[what], what) if what in _KIND else v
        except ProtocolError as exc:
            raise self._fault(exc) from None

    @_guarded
    def actual_angles(self) -> np.ndarray:
        """(7,) float: measured joint angles (rad)."""
        return np.radians(self._get_values("pos", N_AXES))

    @_guarded
    def set_target_get_actual(self, angles) -> np.ndarray:
        """``tpap``: set the target angles (rad) and read the actual angles (rad) at once."""
        a = self.check_angles(angles)
        _, _, values = self.command("tpap=" + self._fmt(np.degrees(a)))
        return np.radians(self._parse(values, "tpap"))

    @_guarded
    def target_velocities(self) -> np.ndarray:
        """(7,) float: target velocities (rad/s)."""
        return np.radians(self._get_values("v", N_AXES))

    @_guarded
    def set_target_velocities(self, velocities) -> np.ndarray:
        """Set the target velocities (rad/s, each within ``velocity_limits``)."""
        v = self._check_vector(velocities, "velocities", unit="rad/s")
        if np.any(np.abs(v) > self.velocity_limits + 1e-9):
            i = int(np.flatnonzero(np.abs(v) > self.velocity_limits + 1e-9)[0])
            raise JointLimitError(f"velocity of axis {i} is {math.degrees(v[i]):.2f} deg/s, above its limit "
                                  f"{math.degrees(self.velocity_limits[i]):.1f} deg/s; nothing was sent")
        _, _, values = self.command("v=" + self._fmt(np.degrees(v)))
        return np.radians(self._parse(values, "v"))

    @_guarded
    def set_velocities_get_actual(self, velocities) -> np.ndarray:
        """``tvav``: set target velocities (rad/s) and read the actual ones (rad/s)."""
        v = self._check_vector(velocities, "velocities", unit="rad/s")
        if np.any(np.abs(v) > self.velocity_limits + 1e-9):
            raise JointLimitError(f"velocities {np.degrees(v).round(2).tolist()} deg/s exceed the limits "
                                  f"{np.degrees(self.velocity_limits).round(1).tolist()} deg/s; nothing was sent")
        _, _, values = self.command("tvav=" + self._fmt(np.degrees(v)))
        return np.radians(self._parse(values, "tvav"))

    @_guarded
    def actual_velocities(self) -> np.ndarray:
        """(7,) float: measured velocities (rad/s)."""
        return np.radians(self._get_values("vel", N_AXES))

    @_guarded
    def reference_velocities(self) -> np.ndarray:
        """(7,) float: reference velocities of the controller (rad/s)."""
        return np.radians(self._get_values("rvel", N_AXES))

    @_guarded
    def accelerations(self) -> np.ndarray:
        """(7,) float: target accelerations (rad/s^2)."""
        return np.radians(self._get_values("a", N_AXES))

    @_guarded
    def set_accelerations(self, accelerations) -> np.ndarray:
        """Set the target accelerations (rad/s^2, each within ``acceleration_limits``)."""
        a = self._check_vector(accelerations, "accelerations", unit="rad/s^2")
        if np.any(a < 0) or np.any(a > self.acceleration_limits + 1e-9):
            raise JointLimitError(f"accelerations {np.degrees(a).round(1).tolist()} deg/s^2 must lie in "
                                  f"[0, {np.degrees(self.acceleration_limits).round(1).tolist()}]; nothing was sent")
        _, _, values = self.command("a=" + self._fmt(np.degrees(a)))
        return np.radians(self._parse(values, "a"))

    # -- motion -----------------------------------------------------------------------
    @_guarded
    def move(self, angles=None, *, wait: bool = False, timeout: float | None = None) -> float:
        """Start a synchronised move to the targets (optionally set first); returns its duration (s).

        Parameters
        ----------
        angles : (7,) float, optional
            New target angles (rad), checked against the limits before anything is sent.
        wait : bool
            Poll ``state`` until no axis is positioning any more.
        timeout : float, optional
            When waiting: give up (stop, raise :class:`HardwareTimeout`) after this many
            seconds (default: twice the expected duration plus the reply timeout).
        """
        if timeout is not None:
            timeout = as_timeout(timeout)
        if angles is not None:
            self.set_target_angles(angles)
        _, _, values = self.command("m")
        if len(values) != 1:
            raise self._fault(ProtocolError(f"SDH-2 m: expected one duration in seconds, got {values}"))
        try:
            duration = _duration(values, "m")
        except ProtocolError as exc:
            raise self._fault(exc) from None
        if wait:
            self.wait_until_idle(timeout if timeout is not None else 2 * duration + self.timeout)
        return duration

    @_guarded
    def wait_until_idle(self, timeout: float, poll: float = 0.005) -> np.ndarray:
        """Poll ``state`` until no axis is positioning; returns the final states.

        Raises :class:`HardwareTimeout` (after sending ``stop``) when still moving after
        ``timeout`` seconds.
        """
        timeout = as_timeout(timeout)
        poll = as_timeout(poll, "poll")
        end = time.monotonic() + timeout
        while True:
            st = self.state()
            if not np.any(st == AxisState.POSITIONING):
                return st
            if time.monotonic() > end:
                raise self._fault(HardwareTimeout(f"SDH-2 axes still positioning after {timeout:.2f} s: states {st.tolist()}"))
            time.sleep(poll)

    @_guarded
    def stop(self) -> None:
        """Stop the current ``m`` move (grip moves are not stopped by the firmware)."""
        self.command("stop")

    @_guarded
    def state(self) -> np.ndarray:
        """(7,) int: per-axis :class:`AxisState` codes."""
        v = self._get_values("state", N_AXES)
        if np.any(v != np.round(v)) or np.any((v < 0) | (v > 7)):
            raise self._fault(ProtocolError(f"SDH-2 state: expected integers 0..7, got {v.tolist()}"))
        return v.astype(np.int64)

    @_guarded
    def expected_duration(self) -> float:
        """Predicted duration (s) of a move to the current targets (``get_duration``)."""
        _, _, values = self.command("get_duration")
        try:
            return _duration(values, "get_duration")
        except ProtocolError as exc:
            raise self._fault(exc) from None

    @_guarded
    def power(self, on=None) -> np.ndarray:
        """Read (``on=None``) or set the axis power: a bool for all axes or 7 bools."""
        if on is None:
            return self._get_values("power", N_AXES).astype(bool)
        flags = np.asarray(on, dtype=object)
        if flags.shape not in ((), (N_AXES,)) or not all(isinstance(f, (bool, np.bool_, int, np.integer))
                                                         and f in (0, 1) for f in flags.reshape(-1)):
            raise ValidationError(f"power must be a bool or {N_AXES} bools, got {on!r}")
        flags = np.broadcast_to(flags.astype(bool), (N_AXES,))
        _, _, values = self.command("power=" + ",".join("1" if f else "0" for f in flags))
        return self._parse(values, "power").astype(bool)

    @_guarded
    def grip(self, preset, close: float, velocity: float = 40.0, *, wait: bool = False) -> float:
        """Run a preset grasp: ``selgrip``, then ``vp=0`` and ``grip=close,velocity``.

        Parameters
        ----------
        preset : GripPreset or int
            0 centrical, 1 parallel, 2 cylindrical, 3 spherical.
        close : float
            Closing ratio in [0, 1].
        velocity : float
            Grip velocity in (0, 100] (the firmware's own unit).

        Returns the expected duration (s).
        """
        from .._validate import as_count, as_float, as_probability

        try:
            p = GripPreset(as_count(preset, "preset", min=0, max=3))
        except ValidationError:
            raise ValidationError("preset must be 0..3 (centrical, parallel, cylindrical, spherical), "
                                  f"got {type(preset).__name__} {preset!r}"[:200]) from None
        wait = as_bool(wait, "wait")
        close = as_probability(close, "close")
        velocity = as_float(velocity, "velocity", low=0.0, low_open=True, high=100.0)
        self.command(f"selgrip={int(p)}")
        self.command("vp=0")
        _, _, values = self.command(f"grip={float(close):.3f},{float(velocity):.3f}")
        try:
            duration = _duration(values, "grip")
        except ProtocolError as exc:
            raise self._fault(exc) from None
        if wait:
            time.sleep(max(0.0, duration))
        return duration

    @_guarded
    def temperatures(self) -> dict:
        """Temperatures (deg C): ``{"axes": (7,), "fpga": float, "pcb": float}``."""
        t = self._get_values("temp", 9)
        return {"axes": t[:7], "fpga": float(t[7]), "pcb": float(t[8])}

    @_guarded
    def controller(self, mode: int | None = None) -> int:
        """Read or set the controller type (0 pose, 1 velocity, 2 velocity + acceleration)."""
        if mode is None:
            return self._controller_mode(self._get_values("con", 1))
        if isinstance(mode, bool) or mode not in (0, 1, 2):
            raise ValidationError(f"controller mode must be 0 (pose), 1 (velocity) or 2, got {mode!r}")
        return self._controller_mode(self._parse_n(self.command(f"con={int(mode)}")[2], 1, "con"))

    def _parse_n(self, values, n, what):
        try:
            return _floats(values, n, what)
        except ProtocolError as exc:
            raise self._fault(exc) from None

    def _controller_mode(self, v) -> int:
        if v[0] not in (0.0, 1.0, 2.0):
            raise self._fault(ProtocolError(f"SDH-2 con: expected a controller mode 0, 1 or 2, got {v[0]!r}"))
        return int(v[0])

    def close(self) -> None:
        """Close the transport (the port is the caller's, but closing it here is allowed)."""
        self.link.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
