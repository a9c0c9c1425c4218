"""Assemble tasks and constraints into a `qpsolvers.Problem` (building apart from solving)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import qpsolvers

from wbc.constraints.constraint import Box, Constraint, Inequality
from wbc.errors import ConfigurationError, WbcError
from wbc.tasks.task import Task

__all__ = ["build_qp"]


def build_qp(ctx, tasks: Sequence[Task], constraints: Sequence[Constraint],
             regularization: float = 1e-9) -> qpsolvers.Problem:
    r"""The QP of one control step.

    .. math:: \min_x \tfrac12 x^T P x + q^T x \;\; \text{s.t.}\;\; G x \le h,\;
              lb \le x \le ub,

    with ``P = sum_t J_t^T W_t J_t + regularization * I`` and ``q = sum_t J_t^T W_t e_t``
    over the active tasks, ``G, h`` the stacked inequalities and ``lb, ub`` the intersection
    of the boxes of the active constraints (and the layout's default bounds: slacks >= 0).

    Args:
        ctx: A context with a ``layout`` (`QPContext` or `HorizonContext`).
        tasks: Cost terms.
        constraints: Constraints.
        regularization: Tikhonov term added to P's diagonal (> 0 keeps P definite).

    Raises:
        WbcError: A task or constraint returned arrays of the wrong shape, or the boxes
            are empty (lower > upper).
    """
    if not regularization >= 0:
        raise ConfigurationError(f"regularization must be >= 0, got {regularization}")
    n = ctx.layout.n
    P = regularization * np.eye(n)
    q = np.zeros(n)
    for task in tasks:
        if not task.is_active(ctx):
            continue
        H, c = task.compute_qp_objective(ctx)
        if H.shape != (n, n) or c.shape != (n,):
            raise WbcError(f"{type(task).__name__} returned H {H.shape}, c {c.shape}; "
                           f"expected ({n}, {n}), ({n},)")
        P += H
        q += c
    lb, ub = ctx.layout.default_bounds()
    Gs, hs = [], []
    for con in constraints:
        r = con.compute(ctx)
        if r is None:
            continue
        if isinstance(r, Box):
            np.maximum(lb, r.lower, out=lb)
            np.minimum(ub, r.upper, out=ub)
        elif isinstance(r, Inequality):
            if r.G.ndim != 2 or r.G.shape[1] != n or r.h.shape != (r.G.shape[0],):
                raise WbcError(f"{type(con).__name__} returned G {r.G.shape}, h {r.h.shape};"
                               f" expected (m, {n}), (m,)")
            Gs.append(r.G)
            hs.append(r.h)
        else:
            raise WbcError(f"{type(con).__name__}.compute returned {type(r).__name__}, "
                           f"expected Inequality, Box or None")
    if np.any(lb > ub):
        i = int(np.argmax(lb > ub))
        raise WbcError(f"empty bounds on x[{i}]: [{lb[i]}, {ub[i]}]")
    G = np.vstack(Gs) if Gs else None
    h = np.concatenate(hs) if hs else None
    return qpsolvers.Problem(P, q, G, h, None, None, lb, ub)
