"""PX4 flight modes as carried in MAVLink (docs/architecture.md, "The MAVLink side").

PX4 puts its mode in ``HEARTBEAT.custom_mode`` as ``(main << 16) | (sub << 24)``;
the low 16 bits are zero. Main modes: MANUAL 1, ALTCTL 2, POSCTL 3, AUTO 4,
ACRO 5, OFFBOARD 6, STABILIZED 7. AUTO sub modes: READY 1, TAKEOFF 2,
LOITER 3 (shown as "Hold"), MISSION 4, RTL 5, LAND 6. A mode is commanded
with ``MAV_CMD_DO_SET_MODE`` (176): param1 the base mode with
``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` (1), param2 the main mode, param3 the
sub mode.
"""

from __future__ import annotations

from enum import Enum, IntEnum

from mavlink.errors import LinkError

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_CMD_DO_SET_MODE = 176


class MainMode(IntEnum):
    """PX4 main modes (``custom_mode`` bits 16..23)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(IntEnum):
    """PX4 AUTO sub modes (``custom_mode`` bits 24..31)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


class Px4Mode(Enum):
    """A complete PX4 mode; the value is ``(main, sub)``.

    The mock vehicle has its own (:class:`mavlink.mock.sim.px4.Px4Mode`) on purpose: the vehicle's
    side shares only the wire with the ground station it tests.
    """

    MANUAL = (MainMode.MANUAL, 0)
    ALTCTL = (MainMode.ALTCTL, 0)
    POSCTL = (MainMode.POSCTL, 0)
    AUTO_READY = (MainMode.AUTO, AutoSubMode.READY)
    AUTO_TAKEOFF = (MainMode.AUTO, AutoSubMode.TAKEOFF)
    AUTO_LOITER = (MainMode.AUTO, AutoSubMode.LOITER)
    AUTO_MISSION = (MainMode.AUTO, AutoSubMode.MISSION)
    AUTO_RTL = (MainMode.AUTO, AutoSubMode.RTL)
    AUTO_LAND = (MainMode.AUTO, AutoSubMode.LAND)
    ACRO = (MainMode.ACRO, 0)
    OFFBOARD = (MainMode.OFFBOARD, 0)
    STABILIZED = (MainMode.STABILIZED, 0)

    @property
    def main(self) -> MainMode:
        """The main mode."""
        return MainMode(self.value[0])

    @property
    def sub(self) -> int:
        """The sub mode (0 for main modes without one)."""
        return int(self.value[1])

    @property
    def label(self) -> str:
        """PX4's dotted name, e.g. ``"AUTO.MISSION"``."""
        return self.name.replace("_", ".", 1) if self.main is MainMode.AUTO else self.name


class UnknownModeError(LinkError, ValueError):
    """A ``custom_mode`` value that is not one of the PX4 modes above."""


_BY_PAIR = {(int(m.value[0]), int(m.value[1])): m for m in Px4Mode}


def encode_custom_mode(mode: Px4Mode) -> int:
    """``HEARTBEAT.custom_mode`` of a PX4 mode: ``(main << 16) | (sub << 24)``."""
    return (mode.main << 16) | (mode.sub << 24)


def decode_custom_mode(custom_mode: int) -> Px4Mode:
    """The PX4 mode in a ``HEARTBEAT.custom_mode`` value.

    Raises:
        UnknownModeError: the value is not a PX4 mode (naming it in hex and
            its main/sub fields).
    """
    value = int(custom_mode)
    if not 0 <= value <= 0xFFFFFFFF:
        raise UnknownModeError(f"custom_mode {value} is not a 32-bit unsigned value")
    main = (value >> 16) & 0xFF
    sub = (value >> 24) & 0xFF
    low = value & 0xFFFF
    mode = _BY_PAIR.get((main, sub))
    if mode is None or low:
        raise UnknownModeError(
            f"custom_mode 0x{value:08x} (main {main}, sub {sub}, low bits 0x{low:04x}) "
            "is not a PX4 mode"
        )
    return mode


def set_mode_params(mode: Px4Mode, *, armed: bool = False) -> tuple[float, float, float]:
    """``MAV_CMD_DO_SET_MODE`` params 1..3 for ``mode``.

    Args:
        mode: the PX4 mode to switch to.
        armed: set ``MAV_MODE_FLAG_SAFETY_ARMED`` (128) in the base mode, as
            QGroundControl does for an armed vehicle (PX4 ignores it).

    Returns:
        ``(base_mode, main_mode, sub_mode)`` as floats (COMMAND_LONG params).
    """
    base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (128 if armed else 0)
    return float(base), float(mode.main), float(mode.sub)


def parse_mode(text: str) -> Px4Mode:
    """A mode from its name, e.g. ``"offboard"``, ``"AUTO.LOITER"``, ``"hold"``.

    ``"hold"`` is PX4's user-facing name of AUTO.LOITER; ``"land"``,
    ``"rtl"``, ``"mission"``, ``"takeoff"`` are the AUTO sub modes.
    """
    key = text.strip().upper().replace(".", "_").replace("-", "_")
    aliases = {
        "HOLD": "AUTO_LOITER",
        "LOITER": "AUTO_LOITER",
        "LAND": "AUTO_LAND",
        "RTL": "AUTO_RTL",
        "MISSION": "AUTO_MISSION",
        "TAKEOFF": "AUTO_TAKEOFF",
        "READY": "AUTO_READY",
        "POSITION": "POSCTL",
        "ALTITUDE": "ALTCTL",
    }
    key = aliases.get(key, key)
    try:
        return Px4Mode[key]
    except KeyError:
        raise UnknownModeError(
            f"unknown PX4 mode {text!r}, expected one of " + ", ".join(m.label for m in Px4Mode)
        ) from None
