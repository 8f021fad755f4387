"""Byte-stream links over the injected transports: a pyserial port or a python-can bus.

The drivers never open ports themselves (DESIGN.md convention 10): the caller passes an
already-open pyserial object (``serial.serial_for_url("/dev/ttyUSB0")``,
``"socket://host:port"``, ``"loop://"``, a pty path) or a python-can ``Bus``. This module
wraps either in a :class:`Link` with one small interface: ``write(bytes)``,
``read_some(timeout) -> bytes`` (b"" on timeout) and ``discard_input()``.

CAN framing of the SDH-2 (docs: SCHUNK SDHLibrary-C++ 0.0.2.10 and the ROS driver schunk_sdh, "CAN framing"): the ASCII
byte stream is cut into data frames of at most 8 bytes on the request id (42), answers are
the concatenated payloads of the frames on the answer id (43); extended, remote and error
frames are ignored.
"""

from __future__ import annotations

import time

from ..errors import DeviceDisconnected, HardwareError, ValidationError

__all__ = ["Link", "SerialLink", "CANLink", "as_link"]

#: poll interval of a serial port read (s): a port's own timeout is lowered to this so
#: that no read can block longer than the caller's deadline
SERIAL_POLL = 0.02


class Link:
    """A bidirectional byte stream (base class)."""

    def write(self, data: bytes) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def read_some(self, timeout: float) -> bytes:  # pragma: no cover - interface
        raise NotImplementedError

    def discard_input(self, quiet: float = 0.02, limit: float = 0.5) -> int:
        """Read and drop bytes until the line has been quiet for ``quiet`` seconds.

        Returns the number of bytes dropped. Never runs longer than ``limit`` seconds.
        """
        n = 0
        end = time.monotonic() + limit
        while time.monotonic() < end:
            b = self.read_some(quiet)
            if not b:
                break
            n += len(b)
        return n

    def close(self) -> None:
        """Close the underlying transport (the caller may also close it directly)."""


class SerialLink(Link):
    """A :class:`Link` over a pyserial-like object (``read``, ``write``, ``in_waiting``).

    Parameters
    ----------
    port : serial.Serial or compatible
        An open port, e.g. from ``serial.serial_for_url(url, baudrate=115200)``. Its read
        timeout is set to a short poll interval (a port with ``timeout=None`` would block
        forever); the link's own deadlines decide when a read gives up.
    """

    def __init__(self, port):
        for attr in ("read", "write"):
            if not hasattr(port, attr):
                raise ValidationError(
                    f"port must be an open pyserial port (serial.serial_for_url(...)), got {type(port).__name__}"
                )
        self.port = port
        try:
            if getattr(port, "timeout", None) is None or port.timeout > SERIAL_POLL:
                port.timeout = SERIAL_POLL
        except Exception as exc:  # a port that cannot be configured
            raise DeviceDisconnected(f"cannot configure port {port!r}: {exc}") from exc

    def write(self, data: bytes) -> None:
        try:
            self.port.write(bytes(data))
            flush = getattr(self.port, "flush", None)
            if flush is not None:
                flush()
        except Exception as exc:
            raise DeviceDisconnected(f"write to {getattr(self.port, 'port', self.port)!r} failed: {exc}") from exc

    def read_some(self, timeout: float) -> bytes:
        end = time.monotonic() + _finite_wait(timeout)
        try:
            while True:
                n = getattr(self.port, "in_waiting", 0) or 0
                if n:
                    return bytes(self.port.read(n))
                b = self.port.read(1)
                if b:
                    n = getattr(self.port, "in_waiting", 0) or 0
                    return bytes(b) + (bytes(self.port.read(n)) if n else b"")
                if time.monotonic() >= end:
                    return b""
        except Exception as exc:
            if isinstance(exc, HardwareError):
                raise
            raise DeviceDisconnected(f"read from {getattr(self.port, 'port', self.port)!r} failed: {exc}") from exc

    def close(self) -> None:
        try:
            self.port.close()
        except Exception:
            pass


class CANLink(Link):
    """A :class:`Link` over a python-can bus: 8-byte chunks out, reassembled bytes in.

    Parameters
    ----------
    bus : can.BusABC
        An open bus, e.g. ``can.Bus(interface="socketcan", channel="can0", bitrate=1_000_000)``.
    tx_id : int
        Identifier of the frames sent to the device (SDH-2: 42, i.e. 0x2A).
    rx_id : int
        Identifier of the device's answers (SDH-2: 43, i.e. 0x2B).
    """

    def __init__(self, bus, *, tx_id: int = 42, rx_id: int = 43):
        if not hasattr(bus, "send") or not hasattr(bus, "recv"):
            raise ValidationError(f"bus must be an open python-can Bus, got {type(bus).__name__}")
        for name, v in (("tx_id", tx_id), ("rx_id", rx_id)):
            if int(v) != v or not 0 <= v < 0x800:
                raise ValidationError(f"{name} must be an 11-bit CAN identifier 0..2047, got {v}")
        self.bus = bus
        self.tx_id = int(tx_id)
        self.rx_id = int(rx_id)

    def write(self, data: bytes) -> None:
        import can

        data = bytes(data)
        try:
            for i in range(0, len(data), 8):
                self.bus.send(can.Message(arbitration_id=self.tx_id, data=data[i:i + 8],
                                          is_extended_id=False), timeout=1.0)
        except Exception as exc:  # CanError, or a bus shut down under us
            raise DeviceDisconnected(f"CAN send on id {self.tx_id} failed: {type(exc).__name__}: {exc}") from exc

    def read_some(self, timeout: float) -> bytes:
        import can

        end = time.monotonic() + _finite_wait(timeout)
        try:
            while True:
                left = end - time.monotonic()
                msg = self.bus.recv(timeout=max(0.0, left))
                if msg is None:
                    return b""
                if (msg.arbitration_id == self.rx_id and not msg.is_extended_id
                        and not msg.is_remote_frame and not msg.is_error_frame):
                    if msg.dlc:
                        return bytes(msg.data[:msg.dlc])
                if time.monotonic() >= end:
                    return b""
        except Exception as exc:  # CanError, or a bus shut down under us
            if isinstance(exc, HardwareError):
                raise
            raise DeviceDisconnected(f"CAN receive failed: {type(exc).__name__}: {exc}") from exc

    def close(self) -> None:
        pass  # the bus belongs to the caller


def _finite_wait(timeout) -> float:
    """A read's wait in seconds: NaN or negative -> 0; +inf is refused (it would block forever)."""
    t = float(timeout)
    if t != t or t < 0:
        return 0.0
    if t == float("inf"):
        raise ValidationError("a read timeout must be finite, got inf")
    return t


def as_link(transport) -> Link:
    """Wrap a pyserial port or a python-can bus (or pass a :class:`Link` through)."""
    if isinstance(transport, Link):
        return transport
    try:
        import can

        if isinstance(transport, can.BusABC):
            return CANLink(transport)
    except ImportError:  # pragma: no cover
        pass
    return SerialLink(transport)
