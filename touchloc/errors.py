"""Exceptions raised by touchloc.

Every error the library raises on purpose derives from :class:`TouchlocError`, so callers
can catch the library's own failures in one place. Input-validation errors also derive
from :class:`ValueError` so that generic code keeps working.
"""

from __future__ import annotations

__all__ = [
    "TouchlocError",
    "ValidationError",
    "MeshError",
    "BeliefDegenerateError",
    "PlanningError",
    "HardwareError",
    "HardwareTimeout",
    "ProtocolError",
    "ChecksumError",
    "FirmwareError",
    "JointLimitError",
    "DeviceDisconnected",
    "MappingError",
]


class TouchlocError(Exception):
    """Base class of every error raised by touchloc."""


class ValidationError(TouchlocError, ValueError):
    """An argument at a public boundary had the wrong shape, type or value."""


class MeshError(TouchlocError, ValueError):
    """A mesh is unusable (empty, non-finite, or nothing left after repair)."""


class BeliefDegenerateError(TouchlocError, ArithmeticError):
    """A belief cannot be formed: every weight underflowed or is not finite."""


class PlanningError(TouchlocError):
    """A planner could not score or choose an action."""


class HardwareError(TouchlocError):
    """Base class of errors from the hand, the tactile controller or their transports."""


class HardwareTimeout(HardwareError, TimeoutError):
    """A device did not answer in time."""


class ProtocolError(HardwareError):
    """Bytes from a device did not follow its protocol."""


class ChecksumError(ProtocolError):
    """A packet's checksum (CRC) did not match its contents."""


class FirmwareError(HardwareError):
    """The device firmware reported an error code."""

    def __init__(self, code: int, name: str, message: str = ""):
        self.code = int(code)
        self.name = name
        super().__init__(message or f"firmware error E{code} ({name})")


class JointLimitError(HardwareError, ValueError):
    """A commanded target lies outside the joint limits; nothing was sent."""


class DeviceDisconnected(HardwareError, ConnectionError):
    """The transport to a device closed or vanished."""


class MappingError(TouchlocError):
    """A shape map cannot give what was asked (no contacts yet, an empty level set)."""
