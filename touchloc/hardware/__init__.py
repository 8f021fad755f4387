"""The real hand: SDH-2 and DSACON32m drivers, kinematics, tactile contacts, guarded touches.

Drivers take an already-open transport (a pyserial port from ``serial.serial_for_url`` or
a python-can bus); see docs/hardware.md for real port names and the emulators.
"""

from .dsacon import (DSACON32m, DSAFirmwareError, MatrixInfo, PacketParser, TactileFrame, crc16,
                     decode_frame, decode_rle, encode_packet, encode_rle)
from .kinematics import DEFAULT_PADS, FINGER_AXES, PadLayout, SDH2Kinematics
from .sdh2 import SDH2, AxisState, GripPreset, SDHFirmwareError

__all__ = ["DSACON32m", "DSAFirmwareError", "MatrixInfo", "PacketParser", "TactileFrame", "crc16",
           "decode_frame", "decode_rle", "encode_packet", "encode_rle", "SDH2", "SDHFirmwareError", "AxisState", "GripPreset", "SDH2Kinematics", "PadLayout",
           "DEFAULT_PADS", "FINGER_AXES"]
