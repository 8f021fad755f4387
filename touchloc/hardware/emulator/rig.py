"""An emulated SDH-2 with DSACON32m pads, both served over real transports, in one object."""

from __future__ import annotations

import itertools
import os

import numpy as np

from ...errors import ValidationError
from ._sim import SimHand, SimWorld
from .dsacon import DSACON32mEmulator
from .sdh2 import SDH2Emulator
from .servers import CANServer, PtyServer, TCPServer

__all__ = ["EmulatedRig"]

_channels = itertools.count()

#: the open posture the emulated hand powers up in (deg): fingers bent outwards
REST_DEG = (90.0, -30.0, 30.0, -30.0, 30.0, -30.0, 30.0)


class EmulatedRig:
    """Hand and tactile emulators sharing one :class:`SimHand`, each behind a server.

    Parameters
    ----------
    world : SimWorld, optional
        What the fingers touch (None: free space).
    hand_transport : {"can", "tcp", "pty"}
        How the hand is served: python-can bus (requests on id 42, answers on 43), a
        loopback TCP port, or a pty pair.
    tactile_transport : {"tcp", "pty"}
        How the tactile controller is served (it has its own serial line on the real hand).
    can_interface, can_channel : str
        python-can interface and channel for ``hand_transport="can"`` (default: the
        in-process ``"virtual"`` bus on a fresh channel name).
    time_scale : float
        Emulated seconds per wall-clock second.
    initial_angles_deg : (7,) float, optional
        Power-up joint angles (default :data:`REST_DEG`).
    """

    def __init__(self, world: SimWorld | None = None, *, hand_transport: str = "can",
                 tactile_transport: str = "pty", can_interface: str = "virtual", can_channel: str | None = None,
                 time_scale: float = 1.0, initial_angles_deg=None, powerup_esc: bool = True):
        if hand_transport not in ("can", "tcp", "pty"):
            raise ValidationError(f"hand_transport must be 'can', 'tcp' or 'pty', got {hand_transport!r}")
        if tactile_transport not in ("tcp", "pty"):
            raise ValidationError(f"tactile_transport must be 'tcp' or 'pty', got {tactile_transport!r}")
        init = REST_DEG if initial_angles_deg is None else initial_angles_deg
        self.sim = SimHand(world, time_scale=time_scale, initial_angles_deg=np.asarray(init, dtype=float))
        self.hand_emulator = SDH2Emulator(self.sim)
        self.tactile_emulator = DSACON32mEmulator(self.sim, powerup_esc=powerup_esc)
        self.hand_transport = hand_transport
        self.can_interface = can_interface
        self.can_channel = can_channel or f"touchloc-sdh-{os.getpid()}-{next(_channels)}"
        if hand_transport == "can":
            self.hand_server = CANServer(self.hand_emulator, channel=self.can_channel, interface=can_interface)
        elif hand_transport == "tcp":
            self.hand_server = TCPServer(self.hand_emulator)
        else:
            self.hand_server = PtyServer(self.hand_emulator)
        self.tactile_server = (TCPServer if tactile_transport == "tcp" else PtyServer)(self.tactile_emulator)
        self._opened = []

    # -- addresses ----------------------------------------------------------------------
    @staticmethod
    def _address(server) -> str:
        return server.url if isinstance(server, TCPServer) else getattr(server, "path", "")

    @property
    def hand_address(self) -> str:
        """pyserial URL / pty path of the hand, or ``"<interface>:<channel>"`` on CAN."""
        if self.hand_transport == "can":
            return f"{self.can_interface}:{self.can_channel}"
        return self._address(self.hand_server)

    @property
    def tactile_address(self) -> str:
        """pyserial URL or pty path of the tactile controller."""
        return self._address(self.tactile_server)

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> "EmulatedRig":
        self.hand_server.start()
        self.tactile_server.start()
        return self

    def close(self) -> None:
        for obj in self._opened:
            try:
                obj.shutdown() if hasattr(obj, "shutdown") else obj.close()
            except Exception:
                pass
        self._opened.clear()
        self.hand_server.close()
        self.tactile_server.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    # -- clients --------------------------------------------------------------------------
    def open_hand(self, **kwargs):
        """An :class:`~touchloc.hardware.SDH2` connected to the emulated hand."""
        from ..sdh2 import SDH2

        if self.hand_transport == "can":
            import can

            bus = can.Bus(interface=self.can_interface, channel=self.can_channel)
            self._opened.append(bus)
            return SDH2.over_can(bus, **kwargs)
        import serial

        port = serial.serial_for_url(self.hand_address, baudrate=115200, timeout=0.02)
        self._opened.append(port)
        return SDH2(port, **kwargs)

    def open_tactile(self, **kwargs):
        """A :class:`~touchloc.hardware.DSACON32m` connected to the emulated controller."""
        import serial

        from ..dsacon import DSACON32m

        port = serial.serial_for_url(self.tactile_address, baudrate=115200, timeout=0.02)
        self._opened.append(port)
        kwargs.setdefault("open_timeout", 1.0)
        return DSACON32m(port, **kwargs)
