"""Emulators of the SDH-2 hand and the DSACON32m tactile controller.

They speak the devices' real bytes over a pty pair, a loopback TCP socket or a python-can
bus (:mod:`.servers`), optionally backed by a simulated world (a mesh at a hidden pose:
:class:`SimWorld`) in which the fingers stop on the mesh and the pads report pressure
where they press into it. Faults can be injected (:class:`FaultPlan`).
"""

from ._faults import FAULT_KINDS, Fault, FaultPlan
from ._sim import SimHand, SimWorld
from .dsacon import DEFAULT_SHAPES, DSACON32mEmulator
from .sdh2 import SDH2Emulator
from .rig import REST_DEG, EmulatedRig
from .servers import CANServer, PtyServer, TCPServer

__all__ = [
    "SDH2Emulator", "DSACON32mEmulator", "DEFAULT_SHAPES", "SimHand", "SimWorld", "EmulatedRig", "REST_DEG",
    "TCPServer", "PtyServer", "CANServer", "FaultPlan", "Fault", "FAULT_KINDS",
]
