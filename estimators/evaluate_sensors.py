"""The estimators scored on what the machine's sensors give, per sensor suite.

A log of an open-loop run holds, beside the ground truth, the observer's state for each
sensor suite (`models.log.OBSERVED_COLUMNS`). For each suite present, and for the oracle (the
simulator's measured state: exact accelerations and contacts, the cylinders' pressure forces),
the methods are evaluated on the same samples:

* ``full/d-beta``: the paper's fourth row (eq. 29, D = 0.5, beta = 0);
* ``full/cylinder-force``: the bogie balances with the suspension forces from the pressures;
* ``full/compliance``: the same balances with the forces the servos' deflection predicts
  (`estimators.compliance`: no pressure transducer needed);
* ``quasi-static/d-beta``: ref. [13].

Errors are mean |f - f_true| / (m g / 4) in percent, over the scored samples, over the
samples where all four wheels touch (ground truth) and over those on three wheels, reported
apart: the three-wheel system is exact whatever the fourth row, so a mixed mean hides the
fourth row's error. The observer's own errors: the specific force (RMS, the dynamics' base
input), the attitude (tilt), the contact flags (false positives and negatives) and the
payload (mean and final absolute error).
"""

from __future__ import annotations

import numpy as np

from estimators.errors import EstimatorInputError
from estimators.payload import PayloadEstimator
from models.coordinates import SUSPENSION
from models.description import Machine
from models.log import OBSERVED_SUITES
from models.mujoco import servo_specs
from models.state_batch import StateBatch

__all__ = ["check_suites", "suite_batch", "suite_forces", "suites_present", "suites_report"]

METHODS = (("full", "d-beta"), ("full", "cylinder-force"), ("full", "compliance"),
           ("quasi-static", "d-beta"))


def _specific_force(rot, twist, acc, g) -> np.ndarray:
    """``v_dot + w x v + R^T g e_z`` per row, (N, 3)."""
    return acc[:, :3] + np.cross(twist[:, 3:], twist[:, :3]) + g * rot[:, 2, :]


def suite_batch(log: dict, suite: str) -> tuple[StateBatch, np.ndarray]:
    """The observer's states of ``suite`` as a `StateBatch`, and its payload per row."""
    p = f"obs_{suite}_"
    rot = log[p + "base_rotation"]
    n = rot.shape[0]
    normals = np.repeat(rot[:, 2, None, :], 4, axis=1)  # the chassis' up in fb
    sb = StateBatch(base_rotation=rot, base_twist=log[p + "base_twist"],
                    base_acceleration=log[p + "base_acceleration"], q=log[p + "q"],
                    qd=log[p + "qd"], qdd=log[p + "qdd"], in_contact=log[p + "in_contact"],
                    force_in_fb=log.get(p + "force_in_fb", np.zeros((n, 4, 3))),
                    point_in_fb=log[p + "point_in_fb"],
                    normal_in_fb=normals, suspension_force=log[p + "suspension_force"],
                    time=log["time"])
    return sb, np.asarray(log[p + "payload"], float)


def _compliance_forces(machine: Machine, q, qd, setpoint) -> np.ndarray:
    specs = servo_specs(machine)
    idx = list(range(*SUSPENSION.indices(9)))
    kp = np.array([specs[i].kp for i in idx])
    kv = np.array([specs[i].kv for i in idx])
    lo = np.array([specs[i].force_range[0] for i in idx])
    hi = np.array([specs[i].force_range[1] for i in idx])
    f = kp * (setpoint[:, idx] - q[:, idx]) - kv * qd[:, idx]
    return np.clip(f, lo, hi)


def suite_forces(machine: Machine, sb: StateBatch, payload: np.ndarray, method: str,
                 fourth: str, setpoint: np.ndarray) -> np.ndarray:
    """The method's forces on every row, with each row's payload (affine: exact)."""
    import dataclasses

    if fourth == "compliance":
        sb = dataclasses.replace(sb, suspension_force=_compliance_forces(
            machine, sb.q, sb.qd, setpoint))
        fourth = "cylinder-force"
    est = PayloadEstimator(machine, method=method, fourth=fourth, strokes="clip")
    return est.normal_forces_batch(sb, payload)


def _errors(f: np.ndarray, gt: np.ndarray, rows: np.ndarray, four: np.ndarray,
            static_load: float) -> dict:
    e = np.abs(f - gt) / static_load * 100.0
    out = {}
    for name, sel in (("all", rows), ("four_contact", rows[four[rows]]),
                      ("three_contact", rows[~four[rows]])):
        out[name] = float(np.mean(e[sel])) if sel.size else None
    out["samples"] = {"all": int(rows.size), "four_contact": int(four[rows].sum())}
    return out


def suites_present(log: dict) -> tuple[str, ...]:
    """The suites a log can be scored on: ``oracle`` and each suite it has the observer of."""
    return ("oracle",) + tuple(s for s in OBSERVED_SUITES if f"obs_{s}_q" in log)


def check_suites(log: dict, suites) -> tuple[str, ...]:
    """The suites to score: ``suites`` checked against the log, or all it has if None.

    Raises:
        EstimatorInputError: A name that is not a suite, or a suite the log has no observer
            columns of.
    """
    present = suites_present(log)
    if suites is None:
        return present
    suites = tuple(suites)
    valid = ("oracle",) + OBSERVED_SUITES
    for name in suites:
        if name not in valid:
            raise EstimatorInputError(f"unknown sensor suite {name!r}; valid: "
                                      f"{', '.join(valid)}")
        if name not in present:
            raise EstimatorInputError(
                f"the log has no observer columns of the {name!r} sensor suite (it has: "
                f"{', '.join(present)}); the open-loop logs `wbc run` writes have every suite")
    return suites


def suites_report(log: dict, machine: Machine, oracle: StateBatch, rows: np.ndarray,
                  static_load: float, suites=None) -> dict:
    """Per suite (``oracle`` first) and method, the errors (module docstring).

    ``suites``: the names to score (default: every suite the log has; `check_suites`).
    """
    wanted = check_suites(log, suites)
    gt = np.asarray(log["fz_in_fb"], float)
    true_flags = np.asarray(log["in_contact"], bool)
    four = true_flags.all(axis=1)
    body = next(b for b in machine.bodies if b.name == machine.payload)
    payload_true = np.asarray(log.get("payload_now", np.full(gt.shape[0],
                                                             body.inertia.mass)), float)
    report: dict = {}
    batches = [("oracle", oracle, payload_true, log.get("servo_setpoint"))] \
        if "oracle" in wanted else []
    for suite in OBSERVED_SUITES:
        if suite in wanted:
            sb, payload = suite_batch(log, suite)
            batches.append((suite, sb, payload, log[f"obs_{suite}_servo_setpoint"]))
    for name, sb, payload, setpoint in batches:
        methods = {}
        for method, fourth in METHODS:
            if fourth == "cylinder-force" and sb.suspension_force is None:
                continue
            if fourth == "compliance" and (setpoint is None or np.isnan(setpoint).any()):
                continue
            f = suite_forces(machine, sb, payload, method, fourth, setpoint)
            methods[f"{method}/{fourth}"] = _errors(f, gt, rows, four, static_load)
        entry = {"methods": methods}
        if name != "oracle":
            g = machine.gravity
            sf_true = _specific_force(oracle.base_rotation, oracle.base_twist,
                                      oracle.base_acceleration, g)
            sf = _specific_force(sb.base_rotation, sb.base_twist, sb.base_acceleration, g)
            tilt = np.degrees(np.arccos(np.clip(np.einsum(
                "ni,ni->n", oracle.base_rotation[:, 2], sb.base_rotation[:, 2]), -1, 1)))
            flags = np.asarray(sb.in_contact, bool)
            entry["observer"] = {
                "specific_force_rms": [float(v) for v in np.sqrt(np.mean(
                    (sf - sf_true)[rows] ** 2, axis=0))],
                "tilt_error_deg": {"mean": float(tilt[rows].mean()),
                                   "max": float(tilt[rows].max())},
                "contact_false_positive": int((flags & ~true_flags)[rows].sum()),
                "contact_false_negative": int((~flags & true_flags)[rows].sum()),
                "payload_error_kg": {"mean": float(np.mean(np.abs(payload - payload_true)[rows])),
                                     "final": float(abs(payload[-1] - payload_true[-1]))},
            }
        report[name] = entry
    return report
