"""Checks of the arguments every scenario run takes (duration, seed, threshold, delay).

The same rules for the open-loop and the closed-loop runs, so the command line refuses the
same values whatever the scenario.
"""

from __future__ import annotations

import math

from models.log import SETTLE_SECONDS
from scenarios.errors import RunInputError

__all__ = ["MAX_DURATION", "MAX_SEED", "check_delay", "check_duration", "check_seed",
           "check_threshold"]

MAX_DURATION = 3600.0  # [s] one simulated hour
MAX_SEED = 2**32 - 1  # NumPy's seed range for one integer


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_duration(duration, default: float) -> float:
    """The run's duration [s]: ``duration``, or ``default`` when None.

    Raises:
        RunInputError: Not a number in (`SETTLE_SECONDS`, `MAX_DURATION`] s: the metrics
            skip the first `SETTLE_SECONDS`, so a shorter run has nothing to score.
    """
    value = default if duration is None else duration
    if not _is_number(value) or not math.isfinite(value) \
            or not SETTLE_SECONDS < value <= MAX_DURATION:
        raise RunInputError(f"duration {value!r} s outside ({SETTLE_SECONDS:g}, "
                            f"{MAX_DURATION:g}] s (the first {SETTLE_SECONDS:g} s are the "
                            f"settling, not scored)")
    return float(value)


def check_seed(seed) -> int:
    """The terrain seed.

    Raises:
        RunInputError: Not an integer in [0, `MAX_SEED`].
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise RunInputError(f"seed {seed!r} outside [0, {MAX_SEED}] (an integer)")
    return int(seed)


def check_delay(delay_periods) -> int:
    """The measurement delay [control periods].

    Raises:
        RunInputError: Not an integer in [0, 100].
    """
    if isinstance(delay_periods, bool) or not isinstance(delay_periods, int) \
            or not 0 <= delay_periods <= 100:
        raise RunInputError(f"delay_periods {delay_periods!r} outside [0, 100] control "
                            f"periods (an integer)")
    return int(delay_periods)


def check_threshold(threshold_n, static_wheel_load_n: float) -> float:
    """The normal-force threshold [N].

    Raises:
        RunInputError: Not a number in [0, ``static_wheel_load_n``) N.
    """
    if not _is_number(threshold_n) or not math.isfinite(threshold_n) \
            or not 0.0 <= threshold_n < static_wheel_load_n:
        raise RunInputError(f"threshold {threshold_n!r} N outside [0, "
                            f"{static_wheel_load_n:.0f}) N (the static wheel load)")
    return float(threshold_n)
