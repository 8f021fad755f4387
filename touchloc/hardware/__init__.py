"""The real hand: SDH-2 and DSACON32m drivers, kinematics, tactile contacts, guarded touches.

Drivers take an already-open transport (a pyserial port from ``serial.serial_for_url`` or
a python-can bus); see docs/hardware.md for real port names and the emulators.
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "dsacon": ("ControllerInfo", "DSACON32m", "DSAFirmwareError", "MatrixInfo", "PacketParser", "SensitivityInfo",
        "SensorInfo", "TactileFrame", "crc16", "decode_frame", "decode_rle", "encode_packet", "encode_rle"),
    "executor": ("GuardedTouchExecutor", "HandWorld", "TouchAborted", "TouchPlan"),
    "kinematics": ("DEFAULT_PADS", "FINGER_AXES", "PadLayout", "SDH2Kinematics"),
    "sdh2": ("SDH2", "AxisState", "GripPreset", "Identification", "SDHFirmwareError"),
    "session": ("SessionLog", "SessionRecord", "TornRecordWarning", "check_session", "read_session",
        "repair_session", "replay", "session_contacts"),
    "tactile": ("Blob", "blobs_to_contacts", "find_blobs", "frame_to_contacts"),
    "dnf_features": ("blob_normals", "blob_widths", "frame_normal_angles", "rotation_plane_angles"),
}

__all__ = [
    # drivers
    "SDH2", "SDHFirmwareError", "AxisState", "GripPreset", "Identification",
    "DSACON32m", "DSAFirmwareError", "TactileFrame", "ControllerInfo", "SensorInfo", "MatrixInfo",
    "SensitivityInfo", "PacketParser", "crc16", "encode_packet", "decode_frame", "decode_rle", "encode_rle",
    # geometry and contacts
    "SDH2Kinematics", "PadLayout", "DEFAULT_PADS", "FINGER_AXES",
    "Blob", "find_blobs", "frame_to_contacts", "blobs_to_contacts",
    # tactile frames to the DNF tracker's input
    "blob_normals", "blob_widths", "frame_normal_angles", "rotation_plane_angles",
    # touches and their log
    "GuardedTouchExecutor", "TouchPlan", "TouchAborted", "HandWorld",
    "SessionLog", "SessionRecord", "read_session", "session_contacts", "replay",
    "check_session", "repair_session", "TornRecordWarning",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
