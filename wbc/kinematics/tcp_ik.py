"""Inverse kinematics of the tool point: a TCP position goal becomes crane joint goals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbc.axes import CRANE_AXES, AxisLimits
from wbc.errors import IKError, WbcInputError
from wbc.kinematics.tcp_kinematics import TcpKinematics

__all__ = ["IKResult", "solve_tcp_ik"]

# Relative cost of moving each crane axis (slew, lift, tilt, telescope, wrist pitch, roll,
# rotator): the boom places the tool, the wrist keeps its orientation.
DEFAULT_AXIS_COST = (1.0, 1.0, 1.0, 1.0, 1e3, 1e3, 1e3)


@dataclass(frozen=True)
class IKResult:
    """Attributes: q (13,) solution; error [m] final distance; iterations."""

    q: np.ndarray
    error: float
    iterations: int


def solve_tcp_ik(kinematics: TcpKinematics, target_in_fb, q_init, limits: AxisLimits, *,
                 tolerance: float = 1e-3, max_iterations: int = 200, damping: float = 1e-4,
                 axis_cost=DEFAULT_AXIS_COST, max_step: float = 0.05) -> IKResult:
    r"""Crane coordinates that put the TCP at ``target_in_fb``, close to ``q_init``.

    Damped least squares with per-axis costs ``W`` and box clipping to the position limits:

    .. math:: \Delta q = (J^T J + \lambda W)^{-1} J^T (p^* - p(q)),

    steps limited to ``max_step`` (per axis, [m or rad]). Only the crane axes move.

    Args:
        kinematics: TCP kinematics.
        target_in_fb: Target position in fb [m], shape (3,).
        q_init: Independent coordinates to start from (13,) (the measured ones).
        limits: Position limits of the axes.
        tolerance: Position tolerance [m].
        max_iterations: Iteration cap.
        damping: lambda.
        axis_cost: W's diagonal for the 7 crane axes [-], shape (7,).
        max_step: Per-iteration step cap.

    Raises:
        WbcInputError: Target or initial configuration of the wrong shape or non-finite.
        IKError: The target is not reached within ``tolerance`` (unreachable or at a limit).
    """
    target = np.asarray(target_in_fb, dtype=float)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise WbcInputError(f"TCP target must be finite with shape (3,), got {target_in_fb}")
    q = np.array(q_init, dtype=float)
    lo = limits.position_lower[CRANE_AXES]
    hi = limits.position_upper[CRANE_AXES]
    q[CRANE_AXES] = np.clip(q[CRANE_AXES], lo, hi)
    w = damping * np.diag(np.asarray(axis_cost, float))
    err = np.inf
    for it in range(max_iterations + 1):
        e = target - kinematics.position(q)
        err = float(np.linalg.norm(e))
        if err <= tolerance:
            return IKResult(q, err, it)
        if it == max_iterations:
            break
        jac = kinematics.jacobian(q)[:, CRANE_AXES]
        dq = np.linalg.solve(jac.T @ jac + w, jac.T @ e)
        dq *= min(1.0, max_step / max(np.max(np.abs(dq)), 1e-12))
        q[CRANE_AXES] = np.clip(q[CRANE_AXES] + dq, lo, hi)
    raise IKError(f"TCP target {np.round(target, 4).tolist()} m (fb) not reached: distance "
                  f"{err:.4g} m > tolerance {tolerance:g} m after {max_iterations} iterations "
                  f"(outside the workspace or blocked by a joint limit)")
