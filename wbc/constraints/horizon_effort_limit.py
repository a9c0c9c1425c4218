r"""MPC: every crane cylinder's force within its pressure x area range along the horizon.

Each crane axis's effort is affine in the axis accelerations ``u`` (`estimators.efforts`,
the machine's rigid-body dynamics through the chains): ``e_k = E_j u_k + e_{0,j}``, with
``(E_j, e_{0,j})`` evaluated at ``n_linearizations`` nodes ``j`` of the nominal trajectory
(the previous plan shifted, as the force constraint does) and node ``k`` using the last
``j <= k``. The rows keep

.. math:: (1 - m)\, e_{lo} \le E_j u_k + e_{0,j} \le (1 - m)\, e_{hi}

with a margin ``m`` for what the model leaves out (seal friction, the soft chain closures).
So a fast swing at long reach cannot ask the lift cylinder for more than its pressure can
give, where the boom would sag. Each bound is relaxed to admit the brake-and-hold input of
that step (``ctx.brake_inputs``): a pose already over a limit (a heavy pick) is braked, not
infeasible. The suspension axes carry the ground's reaction, which these dynamics lack: they
are not bounded here (the normal-force constraint covers them).
"""

from __future__ import annotations

import numpy as np

from estimators.efforts import ActuatorEfforts, effort_ranges
from wbc.axes import CRANE_AXES, N_AXES, axis_index
from wbc.constraints.constraint import Constraint, DiagonalBlocks, Inequality
from wbc.errors import ConfigurationError
from wbc.mpc.prediction import nominal_state

__all__ = ["HorizonEffortLimit"]


class HorizonEffortLimit(Constraint):
    """The crane axes' efforts within their ranges at every step (module docstring).

    Args:
        efforts: The effort model (its ``payload_mass`` is the controller's).
        margin: Fraction of each range kept free, in [0, 0.5).
        n_linearizations: Effort-model evaluations per tick (>= 1), the first at step 0.
        axes: The axes bounded (default: the four cylinder-driven crane axes, slew, lift,
            tilt and telescope; the wrist drives carry small loads).

    Attributes:
        last_efforts: Efforts at step 0 of the last solution's nominal input, (9,), or None.
    """

    def __init__(self, efforts: ActuatorEfforts, margin: float = 0.05,
                 n_linearizations: int = 1, axes=tuple(CRANE_AXES[:4])):
        if not (0.0 <= margin < 0.5) or n_linearizations < 1:
            raise ConfigurationError(f"need margin in [0, 0.5) and n_linearizations >= 1, got "
                                     f"{margin}, {n_linearizations}")
        self.efforts = efforts
        lo, hi = effort_ranges(efforts.machine)
        self.lower = (1.0 - margin) * lo
        self.upper = (1.0 - margin) * hi
        self.n_linearizations = int(n_linearizations)
        self.axes = np.asarray(axes, int)
        self._scale = np.maximum(hi, -lo)[self.axes]
        self._structure_cache: tuple | None = None
        self.last_efforts: np.ndarray | None = None

    def _structure(self, ctx) -> tuple:
        """What the layout and step lengths fix, built once for them.

        ``(steps j, which j each step uses, flat indices of the upper and the lower rows'
        entries in G, G's `DiagonalBlocks`, the bounded axes as an index: a slice where
        contiguous)``.
        """
        key = (ctx.structure_key, self.n_linearizations, self.axes.tobytes())
        if self._structure_cache is None or self._structure_cache[0] != key:
            lay = ctx.layout
            N, na = lay.n_steps, lay.n_axes
            steps = np.unique(np.round(np.linspace(0, N - 1, self.n_linearizations))
                              .astype(int))
            which = np.minimum(np.searchsorted(steps, np.arange(N), side="right") - 1,
                               len(steps) - 1)
            # G as (N, 2, bounded axes, n): step k's rows hold E_k on step k's columns.
            shape = (N, 2, self.axes.size, lay.n)
            k = np.arange(N)[:, None, None]
            row = np.arange(self.axes.size)[None, :, None]
            col = lay.step(0).start + np.arange(N * na).reshape(N, 1, na)
            # (N, bounded axes x axes): a row of values assigned to them broadcasts over N
            flat = [np.ravel_multi_index(np.broadcast_arrays(k, side, row, col), shape)
                    .reshape(N, -1) for side in (0, 1)]
            diagonal = DiagonalBlocks(2 * self.axes.size, lay.step(0).start, na, N)
            self._structure_cache = (key, steps, which, flat, diagonal,
                                     axis_index(self.axes))
        return self._structure_cache[1:]

    def compute(self, ctx) -> Inequality:
        """Two rows per crane axis and step: ``+-E u_k <= bound - e_0``."""
        lay, pred = ctx.layout, ctx.prediction
        N = lay.n_steps
        steps, which, (upper_idx, lower_idx), diagonal, ax = self._structure(ctx)
        if steps.size > 1:  # the nominal trajectory is needed beyond the measured state
            qn, vn = pred.trajectory(ctx.q, ctx.qd, ctx.nominal_inputs,
                                     (ctx.free_positions, ctx.free_velocities))
            qn = np.vstack([ctx.state.q[:N_AXES], qn])
            vn = np.vstack([ctx.state.qd[:N_AXES], vn])
        maps = []
        for j in steps:
            st = (ctx.state if j == 0 else
                  nominal_state(ctx.state, pred.start_times[j], qn[j], vn[j]))
            maps.append(self.efforts.affine(st))
        na_b = self.axes.size
        # Every step at once: E_k (N, bounded axes, axes) and e_0,k of the node each step uses
        # (one node: its arrays, which the operations broadcast over the steps).
        # Rows scaled to the effort range (the solver's tolerance is absolute): one step's
        # (bounded axes x axes) values, or every step's.
        if len(maps) == 1:
            E1 = maps[0][0][ax]
            E, e0 = E1[None], maps[0][1][ax]
            scaled = (E1 / self._scale[:, None]).ravel()
        else:
            E = np.stack([m[0] for m in maps])[which][:, ax]
            e0 = np.stack([m[1] for m in maps])[which][:, ax]
            scaled = (E / self._scale[:, None]).reshape(N, -1)
        brake = (E @ ctx.brake_inputs[:N, :, None])[:, :, 0] + e0
        hi = np.maximum(self.upper[ax], brake)
        lo = np.minimum(self.lower[ax], brake)
        # Per step k the upper rows, then the lower rows.
        G = np.zeros(2 * N * na_b * lay.n)
        G[upper_idx] = scaled
        G[lower_idx] = -scaled
        h = np.empty((N, 2, na_b))
        np.divide(hi - e0, self._scale, out=h[:, 0])
        np.divide(e0 - lo, self._scale, out=h[:, 1])
        G = G.reshape(2 * N * na_b, lay.n)
        h = h.reshape(2 * N * na_b)
        E0, e00 = maps[0]
        self.last_efforts = E0 @ ctx.nominal_inputs[0] + e00 if N else None
        return Inequality(G, h, diagonal)
