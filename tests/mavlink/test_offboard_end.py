"""The end of an offboard flight: Hold is commanded while the setpoints still flow.

Stopping the setpoints first leaves the vehicle without any until the Hold command arrives;
on a lossy or busy link that outlasted PX4's COM_OF_LOSS_T in CI (a failsafe seen at the end of
a flight with 10 % uplink loss), and PX4's own offboard-loss action (COM_OBL_RC_ACT, possibly
Land or RTL) would then decide how the flight ends.
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from mavsdk.plugins.offboard import OffboardResult

from mavlink.errors import CommandError
from mavlink.offboard import end_action_of
from mavlink.offboard.setpoints import EndAction


class _Offboard:
    def __init__(self, log: list[str]) -> None:
        self.log = log

    def stop_async(self, callback: Any) -> None:
        self.log.append("setpoints stopped")
        callback(OffboardResult.SUCCESS, None)


class _Vehicle:
    name = "d1"
    url = "udpin://127.0.0.1:9"

    def __init__(self, hold_fails: bool = False) -> None:
        self.log: list[str] = []
        self.offboard = _Offboard(self.log)
        self.hold_fails = hold_fails

    async def hold(self) -> None:
        self.log.append("hold")
        if self.hold_fails:
            raise CommandError(
                "hold failed: TIMEOUT", result="TIMEOUT", vehicle=self.name, url=self.url
            )

    async def land(self) -> None:
        self.log.append("land")


@pytest.mark.parametrize(
    ("action", "expected"),
    [
        (EndAction.HOLD, ["hold", "setpoints stopped"]),
        (EndAction.LAND, ["hold", "setpoints stopped", "land"]),
    ],
)
def test_hold_is_commanded_before_the_setpoints_stop(
    action: EndAction, expected: list[str]
) -> None:
    v = _Vehicle()
    asyncio.run(end_action_of(v, action))  # type: ignore[arg-type]
    assert v.log == expected


def test_a_refused_hold_still_stops_the_setpoints_and_is_reported() -> None:
    v = _Vehicle(hold_fails=True)
    with pytest.raises(CommandError, match="hold failed"):
        asyncio.run(end_action_of(v, EndAction.LAND))  # type: ignore[arg-type]
    assert v.log == ["hold", "setpoints stopped"]  # no land on an unconfirmed end
