"""The vehicle simulation behind the mock PX4 endpoint: no MAVLink in it.

What a PX4 quad-rotor does, apart from what it says on the link: the vectorised physics
and PX4's controller cascade (``physics``), what the vehicle believes (``estimator``), PX4's
navigation geometry (``navigation``: the auto modes' trajectory setpoint, corner speeds, the
geofence), wind
and disturbances drawn for a campaign (``disturbances``), PX4's modes and parameter table
(``px4``) and what the parameters make of the vehicle (``params``), the profiles
(``profiles``: ``px4``, ``ideal``), the camera's and gimbal's state (``payload_state``), the
radio link's loss and delay (``faults``), the simulated clock (``clock``), PX4 SITL's
figures the mock is calibrated to (``calibration``), the mock's configuration (``config``)
and errors (``errors``), and the batch simulator of ``gcs assess`` (``batch``: many runs of a
plan at once, without sockets).

The MAVLink endpoint (:mod:`mavlink.mock`) is built on it, and so are mission prediction
and ``gcs assess``; nothing here imports pymavlink, the endpoint or the ground station's
side of the link (import-linter's contracts in pyproject.toml check it).
"""
