"""Everything that speaks MAVLink: the ground-station link and the mock vehicle.

GCS side (this package's modules; MAVSDK for connections, telemetry,
actions, missions and offboard, pymavlink for logs)::

    mavlink.link.urls        connection URLs and the PX4 SITL port convention
    mavlink.px4_modes   PX4 custom_mode encode/decode, DO_SET_MODE params
    mavlink.link.mavsdk_glue MAVSDK's callback API as awaitables, its log routed to logging
    mavlink.link.vehicle     Vehicle: one vehicle's link (telemetry, commands, status)
    mavlink.link.fleet       Fleet: N vehicles through one MAVSDK instance, live status
    mavlink.preflight   checks before a plan starts (distance to start, take-off height,
                        settled)
    mavlink.offboard.stream      deadline-scheduled setpoint streaming and its statistics
    mavlink.offboard.setpoints  a plan sampled into PX4 setpoints (OffboardConfig)
    mavlink.flight      the flight engine: the phases every flight has (checks, take-off,
                        arrival gate, one shared start, monitor, tracks), a driver per mode
    mavlink.offboard    fly_offboard: a plan flown in offboard mode, all in step
    mavlink.mission     package: items and their comparison, trajectory -> PX4 mission,
                        geofence items, transfer, whole-transfer retries within a time
                        budget, starting and following a mission, the mission driver
    mavlink.monitor     online safety monitor of the spec's always-clauses
    mavlink.link.scan        who answers on the udpin ports (duplicate system ids)
    mavlink.tlog        telemetry recording to .tlog, tracks rebuilt from it
    mavlink.tracks      FlownTrack (positions, heading) and its CSV
    mavlink.mock        the mock PX4 vehicle endpoint (vehicle side)

Error tree (``mavlink.errors``)::

    LinkError(Exception)              a link to a vehicle failed or a vehicle refused;
                                      carries .vehicle and .url, names them in the message
      UrlError(LinkError, ValueError)     malformed connection URL
      ConnectTimeoutError                 a vehicle did not appear in time
      DuplicateSystemError                two autopilots answer as one vehicle's system id
      LinkLostError                       a connected vehicle stopped sending heartbeats
      CommandError                        a command was refused / unanswered (.result)
      PreflightError                      a vehicle may not start the plan (too far from
                                          its start, cannot reach it, no offboard)
      StreamError                         setpoints that cannot be streamed (rate, shapes)
      MissingHeadingError                 a flown track without the heading a spec reads
      MissionError                        mission transfer or verification failed
                                          (.result: MissionResult, .origin: operation)
        TransferGaveUpError                   a retried transfer's time budget ran out
                                              (.attempts, .elapsed_s, .last cause, .held)
      UnknownModeError(LinkError, ValueError)  custom_mode that is no PX4 mode
                                               (defined in mavlink.px4_modes)

A safety stop by the monitor is not an error: it is reported as a
``mavlink.monitor.SafetyEvent`` in the flight result.
"""

from mavlink.errors import (
    CommandError,
    ConnectTimeoutError,
    DuplicateSystemError,
    LinkError,
    LinkLostError,
    MissingHeadingError,
    MissionError,
    MissionResult,
    PreflightError,
    StreamError,
    TransferGaveUpError,
    UrlError,
)

__all__ = [
    "CommandError",
    "ConnectTimeoutError",
    "DuplicateSystemError",
    "LinkError",
    "LinkLostError",
    "MissingHeadingError",
    "MissionError",
    "MissionResult",
    "PreflightError",
    "StreamError",
    "TransferGaveUpError",
    "UrlError",
]
