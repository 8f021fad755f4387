"""Drive the SDH-2 driver over corrupted replies from the real emulator.

:class:`CorruptingLink` sits between :class:`~touchloc.hardware.SDH2` and an
:class:`SDH2Emulator`: every request goes to the emulator unchanged, and its reply is
corrupted with a given probability (numbers replaced by NaN, inf or absurd magnitudes,
values dropped, bytes lost, lines cut or dropped, firmware error codes). It records every
``stop`` the driver writes, so :func:`fuzz_sdh2` can check the driver's promise: every
failed call ends in a library error with ``stop`` sent, and no raw exception escapes.
"""

from __future__ import annotations

import re
import time

import numpy as np

from ...errors import JointLimitError, TouchlocError, ValidationError
from .._transport import Link
from .sdh2 import SDH2Emulator

__all__ = ["CorruptingLink", "fuzz_sdh2", "CORRUPTIONS"]

#: what the link does to a reply
CORRUPTIONS = ("nan", "inf", "huge", "negative", "bare", "fewer", "more", "word", "cut", "drop",
               "lose", "flip", "ecode", "noise")
_NUM = re.compile(rb"-?[0-9]+(?:\.[0-9]*)?(?:e[-+]?[0-9]+)?")


class CorruptingLink(Link):
    """An in-process link to an emulator whose replies are corrupted at ``rate``."""

    def __init__(self, device, *, rate: float = 0.5, rng=None):
        self.device = device
        self.rate = float(rate)
        self.rng = np.random.default_rng(rng)
        self._pending = bytearray()
        self.stops = 0
        self.writes = 0
        self.kinds = {k: 0 for k in CORRUPTIONS}

    def write(self, data: bytes) -> None:
        self.writes += 1
        if bytes(data) == b"stop\r\n":
            self.stops += 1
        reply = self.device.feed(bytes(data))
        if reply and self.rng.random() < self.rate:
            reply = self._corrupt(reply)
        self._pending += reply

    def _corrupt(self, reply: bytes) -> bytes:
        rng = self.rng
        kind = CORRUPTIONS[int(rng.integers(len(CORRUPTIONS)))]
        self.kinds[kind] += 1
        nums = list(_NUM.finditer(reply))
        if kind in ("nan", "inf", "huge", "negative", "word") and nums:
            m = nums[int(rng.integers(len(nums)))]
            new = {"nan": b"nan", "inf": b"inf", "huge": b"1e9", "negative": b"-1e6", "word": b"x"}[kind]
            if kind == "huge" and rng.random() < 0.5:
                new = b"1e300"
            return reply[:m.start()] + new + reply[m.end():]
        if kind == "bare" and b"=" in reply:
            return reply[:reply.index(b"=")] + b"\r\n"
        if kind == "fewer" and b"," in reply:
            return reply[:reply.rindex(b",")] + b"\r\n"
        if kind == "more" and reply.endswith(b"\r\n"):
            return reply[:-2] + b",1.0\r\n"
        if kind == "cut":
            return reply[: int(rng.integers(0, len(reply)))]
        if kind == "drop":
            return b""
        if kind == "lose" and len(reply) > 4:
            i = int(rng.integers(0, len(reply) - 3))
            return reply[:i] + reply[i + 3:]
        if kind == "flip":
            b = bytearray(reply)
            i = int(rng.integers(len(b)))
            b[i] ^= 1 << int(rng.integers(8))
            return bytes(b)
        if kind == "ecode":
            return f"E{int(rng.integers(0, 60))}\r\n".encode()
        return rng.bytes(int(rng.integers(1, 40))) + reply  # noise

    def read_some(self, timeout: float) -> bytes:
        if self._pending:
            out = bytes(self._pending)
            self._pending.clear()
            return out
        time.sleep(min(max(float(timeout), 0.0), 0.0005))
        return b""

    def discard_input(self, quiet: float = 0.02, limit: float = 0.5) -> int:
        n = len(self._pending)
        self._pending.clear()
        return n

    def close(self) -> None:
        pass


def _calls(hand, rng):
    lo, hi = hand.angle_limits
    a = lo + (hi - lo) * rng.random(7)
    v = 0.5 * hand.velocity_limits * rng.random(7)
    return [
        ("target_angles", lambda: hand.target_angles()),
        ("actual_angles", lambda: hand.actual_angles()),
        ("set_target_angles", lambda: hand.set_target_angles(a)),
        ("set_target_get_actual", lambda: hand.set_target_get_actual(a)),
        ("move", lambda: hand.move(a)),
        ("move_wait", lambda: hand.move(a, wait=True, timeout=0.02)),
        ("state", lambda: hand.state()),
        ("expected_duration", lambda: hand.expected_duration()),
        ("grip", lambda: hand.grip(int(rng.integers(4)), float(rng.random()), 40.0)),
        ("temperatures", lambda: hand.temperatures()),
        ("controller", lambda: hand.controller()),
        ("set_controller", lambda: hand.controller(int(rng.integers(3)))),
        ("identification", lambda: hand.identification()),
        ("power", lambda: hand.power()),
        ("set_velocities", lambda: hand.set_target_velocities(v)),
        ("velocities", lambda: hand.actual_velocities()),
        ("accelerations", lambda: hand.accelerations()),
        ("firmware_version", lambda: hand.firmware_version()),
        ("stop", lambda: hand.stop()),
        ("wait_until_idle", lambda: hand.wait_until_idle(0.01)),
    ]


def fuzz_sdh2(n_calls: int = 20_000, *, rate: float = 0.5, seed: int = 0, reply_timeout: float = 0.003) -> dict:
    """Run ``n_calls`` driver calls over corrupted replies; return what came back.

    Returns a dict: ``calls``, ``ok``, ``typed`` (library errors), ``raw`` (anything else
    that escaped: must be 0), ``missing_stop`` (failed calls without a ``stop`` sent: must be
    0), ``errors`` (count by exception type), ``raw_examples`` and ``corruptions`` (count by
    kind).
    """
    from ..sdh2 import SDH2

    rng = np.random.default_rng(seed)
    emu = SDH2Emulator()
    link = CorruptingLink(emu, rate=0.0, rng=seed)
    # A clean connect with a timeout a loaded machine cannot miss, then the short
    # timeout and the corruption: a stall of a few ms while connecting is not a finding.
    hand = SDH2(link, timeout=max(float(reply_timeout), 1.0))
    hand.timeout = float(reply_timeout)
    link.rate = float(rate)
    out = {"calls": 0, "ok": 0, "typed": 0, "raw": 0, "missing_stop": 0, "errors": {}, "raw_examples": []}
    calls = _calls(hand, rng)
    for i in range(int(n_calls)):
        if i % 200 == 0:
            calls = _calls(hand, rng)
        name, fn = calls[int(rng.integers(len(calls)))]
        stops0 = link.stops
        out["calls"] += 1
        try:
            fn()
            out["ok"] += 1
        except (ValidationError, JointLimitError) as exc:  # refused before sending: no stop needed
            out["typed"] += 1
            out["errors"][type(exc).__name__] = out["errors"].get(type(exc).__name__, 0) + 1
        except TouchlocError as exc:
            out["typed"] += 1
            out["errors"][type(exc).__name__] = out["errors"].get(type(exc).__name__, 0) + 1
            if link.stops == stops0:
                out["missing_stop"] += 1
        except Exception as exc:  # noqa: BLE001 - counting what escapes is the point
            out["raw"] += 1
            if link.stops == stops0:
                out["missing_stop"] += 1
            if len(out["raw_examples"]) < 5:
                out["raw_examples"].append(f"{name}: {type(exc).__name__}: {exc}")
        link.discard_input()
        hand._lines.clear()
    out["corruptions"] = dict(link.kinds)
    return out
