"""Shared pytest configuration.

Hypothesis runs a bounded number of examples with no per-example deadline (2 shared CPU cores make
timings noisy); set HYPOTHESIS_PROFILE=thorough for a longer local search.
"""

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "default", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile(
    "thorough", max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))
