"""Suite-wide settings.

Hypothesis runs derandomised: the same examples on every run and every machine, so a CI
failure is reproduced by running the suite again (``HYPOTHESIS_PROFILE=explore`` draws new
examples, for looking for bugs rather than for gating).

Flights against the mock run on its simulated time, four times faster than real time
(``STL_GCS_SIM_SPEED``, :mod:`gcs.flight.dryrun`; set it to 1 to fly the suite in real
time): the ground station waits on the simulation's clock, so a busy machine slows the
flight down instead of making it late. Tests of the link's own real-time behaviour (faults,
retries, MAVSDK's timeouts) start their mock at speed 1 themselves.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

os.environ.setdefault("STL_GCS_SIM_SPEED", "4")
