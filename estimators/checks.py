"""Checks at the estimator's boundary: options, coordinate ranges, finite results.

Shapes, finiteness and rotations of the states are checked when `models.MachineState` and
`models.state_batch.StateBatch` are built; what depends on the machine or on the estimator's
own arithmetic is checked here.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.errors import EstimatorInputError
from models.description import Machine
from models.reference_machine import MAX_PAYLOAD_MASS

__all__ = ["METHODS", "FOURTH", "BACKENDS", "STROKE_POLICIES", "check_finite_result",
           "check_options", "check_payload_mass", "coordinate_ranges", "real_number"]

METHODS = ("full", "quasi-static")
FOURTH = ("d-beta", "cylinder-force")
BACKENDS = ("auto", "compiled", "casadi", "reference")
STROKE_POLICIES = ("raise", "clip")
_STATE_FIELDS = ("base_twist", "base_acceleration", "q", "qd", "qdd")


def check_payload_mass(value) -> float:
    """``value`` as a payload mass [kg] in [0, `MAX_PAYLOAD_MASS`].

    Raises:
        EstimatorInputError: Not a finite real number in that range.
    """
    ok = isinstance(value, (int, float, np.floating)) and not isinstance(value, bool)
    m = float(value) if ok else math.nan
    if not (math.isfinite(m) and 0.0 <= m <= MAX_PAYLOAD_MASS):
        raise EstimatorInputError(f"payload_mass must be a mass in [0, {MAX_PAYLOAD_MASS:g}] "
                                  f"kg, got {value!r}")
    return m


def check_options(method, fourth, D, beta, backend, strokes) -> tuple[float, float]:  # noqa: N803
    """Validate the estimator's options; returns ``(D, beta)`` as floats.

    Raises:
        EstimatorInputError: A name that is not one of its valid values, or D or beta not a
            finite real number (the message names the option and what is valid).
    """
    for name, value, valid in (("method", method, METHODS), ("fourth", fourth, FOURTH),
                               ("backend", backend, BACKENDS),
                               ("strokes", strokes, STROKE_POLICIES)):
        if not isinstance(value, str) or value not in valid:
            raise EstimatorInputError(f"{name}={value!r} is not one of {valid}")
    return real_number("D", D), real_number("beta", beta)


def real_number(name: str, value) -> float:
    """``value`` as a finite float; `EstimatorInputError` naming ``name`` otherwise.

    Accepts Python and numpy real scalars and 0-d arrays; refuses bools, strings, complex
    numbers, NaN and inf.
    """
    try:
        ok = (not isinstance(value, (bool, np.bool_, str, bytes)) and np.ndim(value) == 0
              and not np.iscomplexobj(value))
        x = float(value) if ok else math.nan
    except (TypeError, ValueError):
        x = math.nan
    if not math.isfinite(x):
        raise EstimatorInputError(f"{name} must be a finite real number, got {value!r}")
    return x


def coordinate_ranges(machine: Machine) -> tuple[tuple[str, str, int, float, float], ...]:
    """``(name, unit, index, lower, upper)`` of every coordinate with a finite range.

    The cylinder chains' strokes (unit ``m stroke``) and the directly driven joints with a
    range (telescope ``m``, wrist ``rad``); the wheels' spin angles are unbounded.
    """
    out = []
    for c in machine.coordinates.table:
        if not (math.isfinite(c.lower) and math.isfinite(c.upper)):
            continue
        if c.kind == "stroke":
            unit = "m stroke"
        else:
            unit = "m" if machine.body(c.name).joint.kind == "prismatic" else "rad"
        out.append((c.name, unit, c.index, c.lower, c.upper))
    return tuple(out)


def check_finite_result(what: str, state, *arrays) -> None:
    """Raise `EstimatorInputError` if an output array holds NaN or inf.

    With a finite, in-range state this happens only when huge finite inputs overflow double
    precision (a twist of 1e200 m/s squared); the message names the largest input.

    Args:
        what: The result's name, for the message.
        state: The `MachineState` (or `StateBatch`) evaluated.
        arrays: The outputs.
    """
    for a in arrays:  # the common case, fast: one ufunc and one reduction per array
        if not np.isfinite(a).all():
            break
    else:
        return
    sizes = {name: float(np.max(np.abs(getattr(state, name)), initial=0.0))
             for name in _STATE_FIELDS}
    f = getattr(state, "suspension_force", None)
    if f is not None:
        sizes["suspension_force"] = float(np.max(np.abs(f), initial=0.0))
    c = getattr(state, "contacts", None)
    for name in ("force_in_fb", "point_in_fb"):
        v = getattr(c, name, None) if c is not None else getattr(state, name, None)
        if v is not None:
            sizes[name] = float(np.max(np.abs(v), initial=0.0))
    field = max(sizes, key=sizes.get)
    raise EstimatorInputError(
        f"{what} is not finite: the inputs overflow double precision (largest: "
        f"|{field}| = {sizes[field]:.3g}); valid: magnitudes that keep the wrenches finite, "
        f"far below 1e150")
