"""PX4 facts as the mock vehicle says them on MAVLink: the mode flags of its heartbeat,
parameter values on the wire, its capabilities and version.

PX4 packs its flight mode into ``HEARTBEAT.custom_mode`` as
``(main_mode << 16) | (sub_mode << 24)`` (``px4_custom_mode.h``); the same
pair arrives in ``MAV_CMD_DO_SET_MODE`` as param2 (main) and param3 (sub), with
``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` in param1.  The modes and the parameter table
themselves are the simulation's (:mod:`mavlink.mock.sim.px4`).  Integer
parameters travel with PX4's byte-wise encoding (the int32 bits reinterpreted
as the float field).
"""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.sim.px4 import ParamType, Px4Mode


def base_mode_flags(mode: Px4Mode) -> int:
    """``MAV_MODE_FLAG_*`` bits PX4 reports with ``mode`` (without the armed bit)."""
    flags = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    main = mode.value[0]
    if main in (4, 6):
        flags |= (
            mavlink2.MAV_MODE_FLAG_AUTO_ENABLED
            | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        )
    elif main == 3:
        flags |= (
            mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        )
    else:
        flags |= (
            mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        )
    return flags


def encode_param_value(value: float, ptype: ParamType) -> float:
    """The float that carries ``value`` in PARAM_VALUE/PARAM_SET (PX4 byte-wise encoding)."""
    if ptype is ParamType.INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def decode_param_value(wire: float, ptype: ParamType) -> float:
    """Inverse of :func:`encode_param_value`."""
    if ptype is ParamType.INT32:
        return float(struct.unpack("<i", struct.pack("<f", wire))[0])
    return float(wire)


#: AUTOPILOT_VERSION.capabilities of the mock (what PX4 v1.17 reports, minus FTP).
CAPABILITIES: int = (
    mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)

#: PX4 v1.17.0 release as AUTOPILOT_VERSION.flight_sw_version (major, minor, patch, type 0xFF).
FLIGHT_SW_VERSION: int = (1 << 24) | (17 << 16) | (0 << 8) | 0xFF
