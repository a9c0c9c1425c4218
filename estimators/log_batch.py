"""A scenario log (`models.log`) as the estimator's `StateBatch`."""

from __future__ import annotations

import numpy as np

from estimators.errors import EstimatorInputError
from models.description import Machine
from models.state_batch import StateBatch

__all__ = ["STROKE_CLIP_TOLERANCE", "log_to_batch"]

STROKE_CLIP_TOLERANCE = 0.005  # [m] stroke excursions beyond the chain range clipped silently

_STATE_FIELDS = ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd")
_CONTACT_FIELDS = ("in_contact", "force_in_fb", "point_in_fb", "normal_in_fb")


def log_to_batch(log: dict, machine: Machine, clip_strokes: bool = True
                 ) -> tuple[StateBatch, dict]:
    """The `StateBatch` of a scenario log, and notes on what had to be adapted.

    Strokes slightly outside their chain's range (MuJoCo's soft joint limits let a cylinder
    overrun by a fraction of a millimetre) are clipped into it, since the estimator refuses
    them; the notes say how many and by how much. Suspension forces are used only if every
    sample has them.

    Args:
        log: Arrays of a log (`models.log.load_log`).
        machine: The machine the log was simulated with.
        clip_strokes: Clip out-of-range strokes (else leave them and let the estimator raise).

    Returns:
        ``(batch, notes)``; ``notes`` has ``clipped_strokes`` (samples, largest excursion [m]
        and chains) and ``suspension_force`` (``logged`` or why not used).

    Raises:
        EstimatorInputError: A field is missing, or a stroke overruns its range by more
            than `STROKE_CLIP_TOLERANCE`.
    """
    missing = [k for k in _STATE_FIELDS + ("time",) if k not in log]
    if missing:
        raise EstimatorInputError(f"log lacks {missing}; a scenario log has "
                                  f"{list(_STATE_FIELDS + _CONTACT_FIELDS)} and 'time'")
    q = np.array(log["q"], float)
    notes: dict = {"clipped_strokes": {"samples": 0, "max_excursion_m": 0.0, "chains": []}}
    if clip_strokes:
        coords = machine.coordinates
        idx = list(coords.chain_indices)
        lo, hi = coords.lower[idx], coords.upper[idx]
        over = np.maximum(lo - q[:, idx], q[:, idx] - hi)  # (N, chains) [m]
        out = over > 0
        worst = float(over.max()) if out.any() else 0.0
        chains = [coords.independent_names[i] for i, o in zip(idx, out.any(axis=0)) if o]
        if worst > STROKE_CLIP_TOLERANCE:
            raise EstimatorInputError(
                f"strokes of {chains} leave their range by up to {worst * 1e3:.2f} mm "
                f"(> {STROKE_CLIP_TOLERANCE * 1e3:.1f} mm tolerated): not a valid log")
        q[:, idx] = np.clip(q[:, idx], lo, hi)
        notes["clipped_strokes"] = {"samples": int(out.any(axis=1).sum()),
                                    "max_excursion_m": worst, "chains": chains}
    kw = {k: log[k] for k in _STATE_FIELDS if k != "q"}
    kw["q"] = q
    for k in _CONTACT_FIELDS:
        if k in log:
            kw[k] = log[k]
    susp = log.get("suspension_force")
    if susp is not None and np.isfinite(susp).all():
        kw["suspension_force"] = susp
        notes["suspension_force"] = "logged"
    else:
        notes["suspension_force"] = "not logged (cylinder-force closure not evaluated)"
    kw["time"] = log["time"]
    return StateBatch(**kw), notes
