"""Suite-wide settings.

Hypothesis runs derandomised: the same examples on every run and every machine, so a CI
failure is reproduced by running the suite again (``HYPOTHESIS_PROFILE=explore`` draws new
examples, for looking for bugs rather than for gating).
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
