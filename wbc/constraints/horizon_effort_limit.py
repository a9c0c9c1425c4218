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
from wbc.constraints.constraint import Constraint, DiagonalBlocks, Inequality, PreparedForm
from wbc.constraints.limits_c import compiled_effort_rows
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
        compiled: Write the rows in C (`wbc.constraints.limits_c`, the same bits); False,
            or no C compiler: numpy.

    Attributes:
        last_efforts: Efforts at step 0 of the last solution's nominal input, (9,), or None
            (read-only).
    """

    def __init__(self, efforts: ActuatorEfforts, margin: float = 0.05,
                 n_linearizations: int = 1, axes=tuple(CRANE_AXES[:4]), compiled: bool = True):
        if not (0.0 <= margin < 0.5) or n_linearizations < 1:
            raise ConfigurationError(f"need margin in [0, 0.5) and n_linearizations >= 1, got "
                                     f"{margin}, {n_linearizations}")
        self.efforts = efforts
        lo, hi = effort_ranges(efforts.machine)
        self.lower = (1.0 - margin) * lo  # read-only: replace them to change them
        self.upper = (1.0 - margin) * hi
        self.lower.setflags(write=False)
        self.upper.setflags(write=False)
        self.n_linearizations = int(n_linearizations)
        self.compiled = bool(compiled)
        self.axes = np.asarray(axes, int)
        self._scale = np.maximum(hi, -lo)[self.axes]
        self._structure_cache: tuple | None = None
        # `last_efforts`' ((E_0, e_0) or the `affine_pair`, the nominal inputs), or None
        self._last: tuple | None = None

    def _structure(self, ctx) -> tuple:
        """What the layout and step lengths fix, built once for them.

        ``(steps j, which j each step uses, G's shape, where G's nonzero entries are in G's
        buffer: (offset, shape (N, 2, bounded axes, axes), strides) [bytes], G's
        `DiagonalBlocks`, the bounded axes as an index: a slice where contiguous, the
        compiled rows (`wbc.constraints.limits_c.CompiledEffortRows`) or None)``.
        """
        key = (ctx.structure_key, self.n_linearizations, self.axes.tobytes(), self.compiled)
        if self._structure_cache is None or self._structure_cache[0] != key:
            lay = ctx.layout
            N, na, nb, n = lay.n_steps, lay.n_axes, self.axes.size, lay.n
            steps = np.unique(np.round(np.linspace(0, N - 1, self.n_linearizations))
                              .astype(int))
            which = np.minimum(np.searchsorted(steps, np.arange(N), side="right") - 1,
                               len(steps) - 1)
            # G as (N, 2, bounded axes, n): step k's upper then lower rows hold +-E_k on
            # step k's columns, a strided view of G (one step further is a block of rows
            # and na columns on).
            size = np.dtype(float).itemsize
            entries = (lay.step(0).start * size, (N, 2, nb, na),
                       ((2 * nb * n + na) * size, nb * n * size, n * size, size))
            diagonal = DiagonalBlocks(2 * nb, lay.step(0).start, na, N)
            rows = (compiled_effort_rows(1 if steps.size == 1 else N, N, nb, na, n,
                                         lay.step(0).start) if self.compiled else None)
            self._structure_cache = (key, steps, which, (2 * N * nb, n), entries, diagonal,
                                     axis_index(self.axes), rows)
        return self._structure_cache[1:]

    def prepare(self, ctx) -> int:
        """The structure of ``ctx`` and the compiled rows' bounds (`Constraint.prepare`)."""
        _, _, g_shape, _, _, ax, rows = self._structure(ctx)
        if rows is not None:
            rows.set_bounds(self.upper, self.lower, self._scale, ax)
        return g_shape[0]

    def prepared_form(self, ctx) -> PreparedForm:
        """The rows' `DiagonalBlocks` of ``ctx``'s structure (`Constraint.prepared_form`)."""
        return PreparedForm(diagonal=self._structure(ctx)[4])

    def compute(self, ctx) -> Inequality:
        """Two rows per crane axis and step: ``+-E u_k <= bound - e_0``."""
        lay, pred = ctx.layout, ctx.prediction
        N = lay.n_steps
        steps, which, g_shape, entries, diagonal, ax, rows = self._structure(ctx)
        if steps.size > 1:  # the nominal trajectory is needed beyond the measured state
            qn, vn = pred.trajectory(ctx.q, ctx.qd, ctx.nominal_inputs,
                                     (ctx.free_positions, ctx.free_velocities))
            qn = np.vstack([ctx.state.q[:N_AXES], qn])
            vn = np.vstack([ctx.state.qd[:N_AXES], vn])
        if rows is not None and (rows.source is not self.upper
                                 or rows.source_lower is not self.lower):
            rows.set_bounds(self.upper, self.lower, self._scale, ax)
        if rows is not None and steps.size == 1:
            # The numpy path's E, e0, Eu and rows in one call, of the blended rows alone.
            pair = self.efforts.affine_pair(ctx.state)
            made = rows.rows_of_pair(pair, ctx.brake_inputs)
            if made is not None:
                self._last = (pair, ctx.nominal_inputs) if N else None
                return Inequality(*made, diagonal)
        maps = []
        for j in steps:
            st = (ctx.state if j == 0 else
                  nominal_state(ctx.state, pred.start_times[j], qn[j], vn[j]))
            maps.append(self.efforts.affine(st))
        # Every step at once: E_k (N, bounded axes, axes) and e_0,k of the node each step
        # uses (one node: (1, bounded axes, axes) and its e_0, which broadcast over the
        # steps).
        if len(maps) == 1:
            E, e0 = maps[0][0][ax][None], maps[0][1][ax]
        else:
            E = np.stack([m[0] for m in maps])[which][:, ax]
            e0 = np.stack([m[1] for m in maps])[which][:, ax]
        Eu = (E @ ctx.brake_inputs[:N, :, None])[:, :, 0]  # BLAS's, in either path
        if rows is not None:
            G, h = rows.rows(E, e0, Eu)
        else:
            G, h = self._rows(E, e0, Eu, g_shape, entries, ax)
        self._last = (maps[0], ctx.nominal_inputs) if N else None
        return Inequality(G, h, diagonal)

    @property
    def last_efforts(self) -> np.ndarray | None:
        """Efforts at step 0 of the last solution's nominal input, (9,), or None.

        ``E_0 u_0 + e_0`` of the last `compute`, made when asked (nothing in the control
        tick reads it).
        """
        if self._last is None:
            return None
        first, inputs = self._last
        E0, e00 = first if len(first) == 2 else ActuatorEfforts.blend(first)
        return E0 @ inputs[0] + e00

    def _rows(self, E, e0, Eu, g_shape, entries, ax) -> tuple[np.ndarray, np.ndarray]:
        """``(G, h)`` in numpy: what `wbc.constraints.limits_c`'s ``effort_rows`` computes.

        Rows scaled to the effort range (the solver's tolerance is absolute); each bound
        relaxed to admit the brake input ``E u_b + e_0``.
        """
        offset, shape, strides = entries
        scaled = E / self._scale[:, None]
        brake = Eu + e0
        # Per step k the upper rows, then the lower rows.
        G = np.zeros(g_shape)
        blocks = np.ndarray(shape, float, G, offset, strides)
        blocks[:, 0] = scaled
        np.negative(scaled, out=blocks[:, 1])
        h = np.empty((shape[0], 2, shape[2]))
        hi, lo = h[:, 0], h[:, 1]
        np.maximum(self.upper[ax], brake, out=hi)
        np.minimum(self.lower[ax], brake, out=lo)
        np.subtract(hi, e0, out=hi)
        np.subtract(e0, lo, out=lo)
        np.divide(hi, self._scale, out=hi)
        np.divide(lo, self._scale, out=lo)
        return G, h.reshape(-1)
