"""The ground station's link to its vehicles: one vehicle (:mod:`mavlink.link.vehicle`, what it
reported in :mod:`mavlink.link.vehicle_status`), a fleet on one MAVSDK (:mod:`mavlink.link.fleet`),
MAVSDK's glue, connection URLs, who answers on which port, message signing and the camera.
Import the modules directly."""
