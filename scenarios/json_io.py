"""Machine output: JSON files without float noise (``0.9999999999000001`` -> ``1.0``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["SIGNIFICANT_DIGITS", "round_floats", "write_json"]

SIGNIFICANT_DIGITS = 10


def round_floats(obj, digits: int = SIGNIFICANT_DIGITS):
    """``obj`` with every float rounded to ``digits`` significant digits (a copy).

    Dicts, lists and tuples are walked; NumPy scalars and arrays become Python numbers and
    lists; non-finite floats are kept.
    """
    if isinstance(obj, dict):
        return {k: round_floats(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [round_floats(v, digits) for v in obj]
    if isinstance(obj, np.ndarray):
        return round_floats(obj.tolist(), digits)
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return round_floats(obj.item(), digits)
    if isinstance(obj, float) and math.isfinite(obj) and obj != 0.0:
        return float(f"{obj:.{digits}g}")
    return obj


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as indented JSON with floats rounded (`round_floats`); returns the path."""
    path = Path(path)
    path.write_text(json.dumps(round_floats(obj), indent=2) + "\n")
    return path
