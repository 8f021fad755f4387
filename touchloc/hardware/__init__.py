"""The real hand: SDH-2 and DSACON32m drivers, kinematics, tactile contacts, guarded touches.

Drivers take an already-open transport (a pyserial port from ``serial.serial_for_url`` or
a python-can bus); see docs/hardware.md for real port names and the emulators.
"""

from .dsacon import (DSACON32m, DSAFirmwareError, MatrixInfo, PacketParser, TactileFrame, crc16,
                     decode_frame, decode_rle, encode_packet, encode_rle)
from .executor import GuardedTouchExecutor, TouchAborted, TouchPlan
from .kinematics import DEFAULT_PADS, FINGER_AXES, PadLayout, SDH2Kinematics
from .sdh2 import SDH2, AxisState, GripPreset, SDHFirmwareError
from .session import SessionLog, SessionRecord, read_session, replay, session_contacts
from .tactile import Blob, blobs_to_contacts, find_blobs, frame_to_contacts

__all__ = ["DSACON32m", "DSAFirmwareError", "MatrixInfo", "PacketParser", "TactileFrame", "crc16",
           "decode_frame", "decode_rle", "encode_packet", "encode_rle", "SDH2", "SDHFirmwareError", "AxisState", "GripPreset", "SDH2Kinematics", "PadLayout",
           "DEFAULT_PADS", "FINGER_AXES", "GuardedTouchExecutor", "TouchAborted", "TouchPlan",
           "SessionLog", "SessionRecord", "read_session", "replay", "session_contacts", "Blob",
           "blobs_to_contacts", "find_blobs", "frame_to_contacts"]
