"""An SDH-2 emulator that speaks the hand's ASCII protocol (bytes in, bytes out).

It answers the commands listed in SCHUNK SDHLibrary-C++ 0.0.2.10 and the ROS driver schunk_sdh in their documented reply
forms, in degrees, over any server of :mod:`touchloc.hardware.emulator.servers` (pty, TCP,
python-can). Faults can be injected to test the driver's error handling.
"""

from __future__ import annotations

import re
import threading

import numpy as np

from ._faults import FaultPlan
from ._sim import GRIP_PRESETS, SimHand

__all__ = ["SDH2Emulator"]

_CMD = re.compile(r"^([a-z_]+)(?:\((\d+)\))?(?:=(.*))?$")

_AXIS_VECTORS = {"p": "targets", "v": "velocities", "a": "accelerations"}
_READ_ONLY = {"pos": "angles", "vel": "actual_vel", "rvel": "actual_vel", "vlim": "vlim", "alim": "alim",
              "p_min": "p_min", "p_max": "p_max", "temp": "temps"}
_IDENT = {"ver": "0.0.2.15", "ver_date": "2014-07-01", "id": "42", "sn": "1234", "soc": "0.0.2.8",
          "soc_date": "2014-07-01", "numaxis": "7"}


def _fmt(values) -> str:
    return ",".join(f"{float(v):.3f}" for v in values)


class SDH2Emulator:
    """Byte-level SDH-2: feed it request bytes, get reply bytes.

    Parameters
    ----------
    hand : SimHand, optional
        The simulated joints (and world) it drives; a free-moving hand by default.
    debug_lines : bool
        Emit an ``@`` debug line before every ``m`` reply, as debug firmware does.

    Attributes
    ----------
    received : list of str
        Every command line received, in order (the wire as the hand saw it).
    faults : FaultPlan
        Queue faults with ``faults.add(kind, on=..., ...)``.
    """

    def __init__(self, hand: SimHand | None = None, *, debug_lines: bool = False):
        self.hand = hand or SimHand()
        self.debug_lines = bool(debug_lines)
        self.received: list = []
        self.faults = FaultPlan()
        self._buf = bytearray()
        self._lock = threading.Lock()

    def reset(self) -> None:
        """Forget half-received input (a new connection)."""
        self._buf.clear()

    def poll(self) -> bytes:
        return b""

    def feed(self, data: bytes) -> bytes:
        """Consume request bytes; return the reply bytes (possibly empty)."""
        out = bytearray()
        with self._lock:
            self._buf += data
            while True:
                i = self._buf.find(b"\n")
                if i < 0:
                    if len(self._buf) > 4096:
                        self._buf.clear()
                        out += b"E32\r\n"  # MAX_COMMANDLINE_EXCEEDED
                    break
                raw = bytes(self._buf[:i]).strip(b"\r ")
                del self._buf[:i + 1]
                if not raw:
                    continue
                line = raw.decode("ascii", "replace")
                self.received.append(line)
                out += self._with_faults(line)
        return bytes(out)

    def _with_faults(self, line: str) -> bytes:
        name = line.split("=")[0].split("(")[0]
        if self.faults.silent:
            return b""
        fault = self.faults.take(name)
        reply = self._handle(line)
        if fault is None:
            return reply
        kind = fault.kind
        if kind == "error":
            return f"E{fault.code}\r\n".encode()
        if kind == "drop":
            return b""
        if kind == "truncate":
            return reply[: max(1, len(reply) // 2)].rstrip(b"\r\n")
        if kind == "lose":
            i = len(reply) // 2
            return reply[:i] + reply[i + 3:]
        if kind == "garbage":
            return b"\x00#!garbage\xff\r\n" + reply
        if kind == "debug":
            return b"@debug: " + line.encode() + b"\r\n" + reply
        if kind == "silence":
            self.faults.silent = True
            return b""
        if kind == "disconnect":
            self.faults.disconnect = True
            return reply
        return reply

    def _handle(self, line: str) -> bytes:
        m = _CMD.match(line)
        if m is None:
            return b"E13\r\n"  # CMD_UNKNOWN
        cmd, idx, args = m.group(1), m.group(2), m.group(3)
        idx = None if idx is None else int(idx)
        if idx is not None and not 0 <= idx < 7:
            return b"E26\r\n"  # INDEX_OUT_OF_BOUNDS
        up = cmd.upper()
        h = self.hand
        try:
            vals = None if args is None else [float(x) for x in args.split(",")]
        except ValueError:
            return b"E14\r\n"  # CMD_FORMAT_ERROR
        if vals is not None and not all(np.isfinite(vals)):
            return b"E14\r\n"
        with h.lock:
            h.advance()
            if cmd in _AXIS_VECTORS or cmd in ("tpap", "tvav"):
                attr = {"tpap": "targets", "tvav": "velocities"}.get(cmd, _AXIS_VECTORS.get(cmd))
                cur = getattr(h, attr)
                if vals is not None:
                    if idx is None and len(vals) != 7:
                        return b"E11\r\n"  # NOT_ENOUGH_PARAMS
                    new = cur.copy()
                    if idx is None:
                        new[:] = vals
                    else:
                        new[idx] = vals[0]
                    if attr == "targets" and np.any((new < h.p_min - 1e-6) | (new > h.p_max + 1e-6)):
                        return b"E24\r\n"  # RANGE_ERROR
                    if attr == "velocities" and np.any(np.abs(new) > h.vlim + 1e-6):
                        return b"E24\r\n"
                    setattr(h, attr, new)
                    if cmd == "tvav" and h.controller in (1, 2):
                        h.start_velocity()
                if cmd == "tpap":
                    return f"TPAP={_fmt(h.angles)}\r\n".encode()
                if cmd == "tvav":
                    return f"TVAV={_fmt(h.actual_vel)}\r\n".encode()
                cur = getattr(h, attr)
                if idx is not None:
                    return f"{up}({idx})={float(cur[idx]):.3f}\r\n".encode()
                return f"{up}={_fmt(cur)}\r\n".encode()
            if cmd in _READ_ONLY:
                if vals is not None:
                    return b"E15\r\n"  # ACCESS_DENIED
                cur = getattr(h, _READ_ONLY[cmd])
                if idx is not None:
                    return f"{up}({idx})={float(cur[idx]):.3f}\r\n".encode()
                return f"{up}={_fmt(cur)}\r\n".encode()
            if cmd in _IDENT:
                return f"{up}={_IDENT[cmd]}\r\n".encode()
            if cmd == "m":
                d = h.start_move()
                pre = b"@move started\r\n" if self.debug_lines else b""
                return pre + f"M={d:.3f}\r\n".encode()
            if cmd == "stop":
                h.stop()
                return b"STOP\r\n"
            if cmd == "state":
                return ("STATE=" + ",".join(str(int(s)) for s in h.state) + "\r\n").encode()
            if cmd == "get_duration":
                return f"GET_DURATION={h.expected_duration():.3f}\r\n".encode()
            if cmd == "power":
                if vals is not None:
                    if len(vals) != 7:
                        return b"E11\r\n"
                    h.power = np.array(vals) != 0
                    h.state[~h.power] = 6
                    h.state[h.power & (h.state == 6)] = 0
                return ("POWER=" + ",".join("1" if p else "0" for p in h.power) + "\r\n").encode()
            if cmd in ("vp", "con"):
                attr = {"vp": "vp", "con": "controller"}[cmd]
                if vals is not None:
                    if len(vals) != 1 or vals[0] not in ((0, 1) if cmd == "vp" else (0, 1, 2)):
                        return b"E24\r\n"
                    setattr(h, attr, int(vals[0]))
                return f"{up}={getattr(h, attr)}\r\n".encode()
            if cmd == "selgrip":
                if vals is None or len(vals) != 1 or vals[0] not in GRIP_PRESETS:
                    return b"E24\r\n"
                h.grip_preset = int(vals[0])
                return f"SELGRIP={0.0:.3f},{h.grip_preset}\r\n".encode()
            if cmd == "grip":
                if vals is None or len(vals) != 2:
                    return b"E11\r\n"
                close, vel = vals
                if not (0 <= close <= 1 and 0 < vel <= 100):
                    return b"E24\r\n"
                d = h.grip(close, vel)
                return f"GRIP={d:.3f},{close:.3f},{vel:.3f}\r\n".encode()
        return b"E13\r\n"
