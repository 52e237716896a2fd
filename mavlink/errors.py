"""Errors of the ground-station link (the tree is in :mod:`mavlink`'s docstring).

Every error names the vehicle and the connection URL it concerns when there
is one, so a message such as ``vehicle d2 (udpin://0.0.0.0:14541): no
heartbeat within 5.0 s`` is enough to find the cable, port or process at
fault.
"""

from __future__ import annotations

from enum import Enum


class LinkError(Exception):
    """A link to a vehicle failed, or a vehicle refused what was asked.

    Attributes:
        vehicle: the vehicle's name (``"d1"``) or ``None`` if no single
            vehicle is concerned.
        url: the connection URL of that vehicle, or ``None``.
        detail: the message without the vehicle/URL prefix.
    """

    def __init__(self, detail: str, *, vehicle: str | None = None, url: str | None = None) -> None:
        self.detail = detail
        self.vehicle = vehicle
        self.url = url
        super().__init__(self._text())

    def _text(self) -> str:
        if self.vehicle is None and self.url is None:
            return self.detail
        if self.url is None:
            return f"vehicle {self.vehicle}: {self.detail}"
        if self.vehicle is None:
            return f"{self.url}: {self.detail}"
        return f"vehicle {self.vehicle} ({self.url}): {self.detail}"


class UrlError(LinkError, ValueError):
    """A connection URL that cannot be used (scheme, host, port, device, baud)."""


class ConnectTimeoutError(LinkError):
    """A vehicle did not appear (no heartbeat from its system id) in time."""


class DuplicateSystemError(LinkError):
    """More than one vehicle answers as a fleet vehicle's system id (names the addresses)."""


class LinkLostError(LinkError):
    """A vehicle that was connected stopped sending heartbeats."""


class CommandError(LinkError):
    """A command was refused by the vehicle or got no answer.

    Attributes:
        result: the name of the MAVSDK/MAVLink result (``"COMMAND_DENIED"``).
    """

    def __init__(
        self, detail: str, *, result: str, vehicle: str | None = None, url: str | None = None
    ) -> None:
        self.result = result
        super().__init__(detail, vehicle=vehicle, url=url)


class PreflightError(LinkError):
    """A vehicle is not in a state to start the plan (position, altitude, mode)."""


class MissingHeadingError(LinkError):
    """A vehicle's heading was asked of a flown track that has none (a spec with ``face``
    judged on position-only telemetry)."""


class StreamError(LinkError):
    """The offboard setpoint stream could not be sent as scheduled."""


class MissionResult(Enum):
    """Why a mission operation failed (a MAVSDK ``MissionRawResult`` or a local check)."""

    MISMATCH = "mismatch"  # the vehicle's copy differs from what was uploaded
    TOO_MANY_ITEMS = "too_many_items"
    INVALID_ITEM = "invalid_item"  # cannot be encoded (e.g. outside int32 lat/lon)
    TRANSFER_FAILED = "transfer_failed"  # MAVSDK reported an error, see ``detail``
    NOT_REACHED = "not_reached"  # mission did not finish in time


class MissionError(LinkError):
    """A mission, geofence or rally transfer or check failed.

    Attributes:
        result: a :class:`MissionResult`.
        origin: the operation that failed (``"upload_mission"``,
            ``"download_geofence"``, ``"verify_mission"`` ...).
        mavsdk_result: the MAVSDK result name when MAVSDK reported the
            failure (``"TIMEOUT"``), else ``None``.
    """

    def __init__(
        self,
        result: MissionResult,
        origin: str,
        detail: str = "",
        *,
        mavsdk_result: str | None = None,
        vehicle: str | None = None,
        url: str | None = None,
    ) -> None:
        self.result = result
        self.origin = origin
        self.mavsdk_result = mavsdk_result
        text = f"{origin}: {result.value}"
        if mavsdk_result is not None:
            text += f" ({mavsdk_result})"
        if detail:
            text += f": {detail}"
        super().__init__(text, vehicle=vehicle, url=url)


class TransferGaveUpError(MissionError):
    """A retried transfer (:func:`mavlink.mission.upload_with_retries`) ran out of its time
    budget without a read-back equal to the plan.

    ``origin`` is the whole operation (``"upload_mission"``); ``result`` and
    ``mavsdk_result`` are those of the last cause. The vehicle holds whatever its last
    read-back showed (``held``), never a part of the plan reported as the plan.

    Attributes:
        attempts: uploads tried.
        elapsed_s: time spent, seconds.
        last: the last cause (a :class:`MissionError`).
        held: items of the vehicle's plan at its last completed read-back, which differed
            from the plan (``None``: no read-back completed, unknown).
    """

    def __init__(
        self,
        origin: str,
        last: MissionError,
        *,
        attempts: int,
        elapsed_s: float,
        budget_s: float,
        held: int | None,
        mission_type: str,
    ) -> None:
        self.last = last
        self.attempts = attempts
        self.elapsed_s = elapsed_s
        self.held = held
        holds = (
            f"the vehicle's {mission_type} plan is unknown (no read-back completed)"
            if held is None
            else f"the vehicle holds another {mission_type} plan ({held} items)"
        )
        super().__init__(
            last.result,
            origin,
            f"gave up after {attempts} attempt(s) in {elapsed_s:.1f} s (budget {budget_s:g} s); "
            f"last cause: {last.detail}; {holds}",
            mavsdk_result=last.mavsdk_result,
            vehicle=last.vehicle,
            url=last.url,
        )
