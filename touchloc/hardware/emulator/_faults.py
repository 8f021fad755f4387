"""Fault injection shared by the emulators."""

from __future__ import annotations

import threading
from dataclasses import dataclass

from ...errors import ValidationError

__all__ = ["Fault", "FaultPlan", "FAULT_KINDS"]

#: what an emulator can do wrong, on purpose:
#: error (answer a firmware error code), drop (swallow the reply), truncate (send half
#: of the reply), lose (drop 3 bytes from the middle of the reply, as a noisy UART),
#: garbage (noise before the reply), debug (an "@" line before the reply,
#: SDH-2 only), crc (a wrong CRC, DSACON32m only), silence (stop answering for good),
#: disconnect (close the connection after the reply)
FAULT_KINDS = ("error", "drop", "truncate", "lose", "garbage", "debug", "crc", "silence", "disconnect")


@dataclass
class Fault:
    kind: str
    on: object = None     # command name (SDH-2, e.g. "m") or packet id (DSACON32m); None: any
    code: int = 17        # error code for kind == "error" (17: CMD_FAILED on both devices)
    count: int = 1        # how many times it fires
    skip: int = 0         # matching requests to let through first


class FaultPlan:
    """A thread-safe queue of faults an emulator applies to matching requests."""

    def __init__(self):
        self._lock = threading.Lock()
        self._faults: list = []
        self.silent = False
        self.disconnect = False

    def add(self, kind: str, *, on=None, code: int = 17, count: int = 1, skip: int = 0) -> "FaultPlan":
        """Queue a fault (see :data:`FAULT_KINDS`) for requests matching ``on``."""
        if kind not in FAULT_KINDS:
            raise ValidationError(f"fault kind must be one of {FAULT_KINDS}, got {kind!r}")
        with self._lock:
            self._faults.append(Fault(kind, on, int(code), int(count), int(skip)))
        return self

    def clear(self) -> None:
        with self._lock:
            self._faults.clear()
            self.silent = False
            self.disconnect = False

    def take(self, on):
        """The fault to apply to a request named/numbered ``on``, or None."""
        with self._lock:
            for f in self._faults:
                if f.on is None or f.on == on:
                    if f.skip > 0:
                        f.skip -= 1
                        return None
                    f.count -= 1
                    if f.count <= 0:
                        self._faults.remove(f)
                    return f
        return None
