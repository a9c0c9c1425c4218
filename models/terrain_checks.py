"""Checks of the terrain constructors' parameters and query points (`models.terrain`).

The bounds keep every height, slope and normal finite, every grid in memory and every
smoothing short; a value outside them is a `TerrainError` that names the parameter.
"""

from __future__ import annotations

import math

import numpy as np

from models.errors import TerrainError

__all__ = ["MAX_ANGLE_DEG", "MAX_COORDINATE", "MAX_NODES", "MAX_SMOOTHING_WORK", "MIN_SPACING",
           "check_angle", "check_finite", "check_interval", "check_points", "check_positive",
           "check_scalars"]

MAX_ANGLE_DEG = 60.0  # steeper terrain is not drivable and only breeds bad placements
MAX_COORDINATE = 1e6  # [m] largest |x|, |y| of a grid corner and |height|
MIN_SPACING = 1e-3  # [m] smallest grid spacing (slopes up to 2e9 stay finite)
MAX_NODES = 4_000_000  # grid nodes (32 MB of heights)
MAX_SMOOTHING_WORK = 2e9  # operations of the Gaussian smoothing of `rough` (a few seconds)


def check_finite(name: str, value: float) -> float:
    """``value`` as a finite float; `TerrainError` naming ``name`` otherwise."""
    try:
        if isinstance(value, (str, bytes, bool, np.bool_)) or np.iscomplexobj(value):
            raise TypeError("not a number")
        value = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise TerrainError(f"{name} must be a real number, got {value!r}") from exc
    if not math.isfinite(value):
        raise TerrainError(f"{name} must be finite, got {value}")
    return value


def check_positive(name: str, value: float) -> float:
    """``value`` as a finite float > 0; `TerrainError` naming ``name`` otherwise."""
    value = check_finite(name, value)
    if value <= 0:
        raise TerrainError(f"{name} must be positive, got {value}")
    return value


def check_interval(name: str, value) -> tuple[float, float]:
    """``value`` as a finite ``(min, max)`` [m] with max > min, inside `MAX_COORDINATE`."""
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError("not numbers")
        value = tuple(value)
        if any(isinstance(v, (str, bytes, bool, np.bool_)) or np.iscomplexobj(v)
               for v in value):
            raise TypeError("not numbers")
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise TerrainError(f"{name} must be a pair (min, max) [m], got {value!r}") from exc
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise TerrainError(f"{name} must be a finite interval with max > min, got {(lo, hi)}")
    if max(abs(lo), abs(hi)) > MAX_COORDINATE:
        raise TerrainError(f"{name} {(lo, hi)} m outside [-{MAX_COORDINATE:g}, "
                           f"{MAX_COORDINATE:g}] m")
    return lo, hi


def check_angle(name: str, value: float, allow_zero: bool = True) -> float:
    """``value`` [deg] inside (-`MAX_ANGLE_DEG`, `MAX_ANGLE_DEG`) (> 0 unless allow_zero)."""
    value = check_finite(name, value)
    if not (-MAX_ANGLE_DEG < value < MAX_ANGLE_DEG) or (not allow_zero and value <= 0):
        lo = "0" if not allow_zero else f"-{MAX_ANGLE_DEG:g}"
        raise TerrainError(f"{name} {value:g} deg outside ({lo}, {MAX_ANGLE_DEG:g}) deg")
    return value


def check_scalars(x, y) -> tuple[float, float] | None:
    """``(float(x), float(y))`` for a scalar query point, None for arrays."""
    try:
        if np.ndim(x) == 0 and np.ndim(y) == 0:
            if np.iscomplexobj(x) or np.iscomplexobj(y):
                raise TypeError("complex")
            return float(x), float(y)
    except (TypeError, ValueError) as exc:
        raise TerrainError(f"terrain query point must be real numbers [m], got {x!r}, "
                           f"{y!r}") from exc
    return None


def check_points(x, y) -> tuple[np.ndarray, np.ndarray]:
    """Query points as broadcast float arrays; `TerrainError` for anything else."""
    try:
        if np.iscomplexobj(x) or np.iscomplexobj(y):
            raise TypeError("complex")
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    except (TypeError, ValueError) as exc:
        raise TerrainError(f"terrain query points must be real numbers or arrays of "
                           f"broadcastable shapes [m], got {x!r}, {y!r}") from exc
    return x, y


# ---------------------------------------------------------------------- constructors
