"""Abstract task: a weighted least-squares residual that is affine in the decision vector."""

from __future__ import annotations

import abc
import functools

import numpy as np

from wbc.errors import ConfigurationError
from wbc.tasks.linear_c import CONSTANT, LinearTerm

__all__ = ["Objective", "StepWeights", "Task", "step_weights"]

Objective = tuple[np.ndarray, np.ndarray]


@functools.lru_cache(maxsize=32)
def _tiled(weight: bytes, n_axes: int, n_steps: int) -> np.ndarray:
    w = np.tile(np.broadcast_to(np.frombuffer(weight), (n_axes,)), n_steps)
    w.setflags(write=False)
    return w


def step_weights(weight: np.ndarray, layout) -> np.ndarray:
    """A weight (scalar or per axis) repeated over the layout's steps, (n_axes n_steps,).

    Read-only, and built once per weight and layout size (the MPC's tasks ask every tick).
    """
    return _tiled(np.asarray(weight, float).tobytes(), layout.n_axes, layout.n_steps)


class StepWeights:
    """`step_weights` of one task's weight, kept for the last layout and weight array.

    A read-only weight array seen before is the same weight (`Task.weight` is read-only):
    no bytes made and hashed each tick; another array, or a writable one, asks
    `step_weights`.
    """

    def __init__(self):
        self._kept: tuple | None = None  # (weight, layout, the repeated weights)

    def __call__(self, weight: np.ndarray, layout) -> np.ndarray:
        """``step_weights(weight, layout)``."""
        kept = self._kept
        if (kept is None or kept[0] is not weight or kept[1] is not layout
                or weight.flags.writeable):
            self._kept = kept = (weight, layout, step_weights(weight, layout))
        return kept[2]


class Task(abc.ABC):
    r"""A task says its error ``e`` and its Jacobian ``J``; the base class makes the cost.

    The task residual at decision vector ``x`` is ``r(x) = J x + e`` (so ``e`` is the residual
    at ``x = 0``), and its cost, in qpsolvers' form, is

    .. math:: \tfrac12 \|J x + e\|^2_W = \tfrac12 x^T (J^T W J) x + (J^T W e)^T x + const,

    with ``W = diag(weight)``.

    Args:
        weight: Scalar or per-row weight (>= 0) of the residual.
    """

    def __init__(self, weight=1.0):
        w = np.array(weight, dtype=float)  # a copy, read-only
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ConfigurationError(f"{type(self).__name__}: weight must be finite and >= 0, "
                                     f"got {weight}")
        w.setflags(write=False)
        self.weight = w

    def compute_weight(self, ctx) -> np.ndarray:
        """Row weights, scalar or shape (m,); the constructor's ``weight`` by default."""
        return self.weight

    def is_active(self, ctx) -> bool:
        """Whether the task contributes to the cost at this context."""
        return True

    @abc.abstractmethod
    def compute_error(self, ctx) -> np.ndarray:
        """Residual at ``x = 0``, shape (m,)."""

    @abc.abstractmethod
    def compute_jacobian(self, ctx) -> np.ndarray:
        """Derivative of the residual with respect to x, shape (m, layout.n)."""

    def prepare(self, ctx) -> np.ndarray | None:
        """Make what depends on the structure alone before the first tick (`wbc.structure`).

        ``ctx`` is a `wbc.structure.StructureContext` (layout, prediction, period, limits).
        Returns the read-only ``H`` that `compute_qp_objective` returns at every tick of
        that structure, or None where ``H`` depends on more (nothing made: the default).
        """
        return None

    def compute_qp_objective(self, ctx) -> Objective:
        """(H, c): ``J^T W J`` (n, n) and ``J^T W e`` (n,)."""
        jac = self.compute_jacobian(ctx)
        err = self.compute_error(ctx)
        jw = jac.T * self.compute_weight(ctx)
        return jw @ jac, jw @ err

    def linear_term(self, ctx) -> LinearTerm | None:
        """`compute_qp_objective` at ``ctx`` said as a `wbc.tasks.linear_c.LinearTerm`.

        Called only when the task is active. `wbc.qp.QPBuilder` then writes ``c`` and its
        sum in one compiled call (`wbc.tasks.linear_c.LinearProgram`): the same bits.
        None (the default): this task's ``c`` is computed by `compute_qp_objective`.
        """
        return None


class ConstantJacobianTask(Task):
    """A task whose Jacobian depends only on the context's structure: ``J^T W`` is cached.

    The cache is keyed by `structure_key` (``ctx.structure_key``: layout and time steps)
    and the weights. The cached ``H`` is read-only: `wbc.qp.QPBuilder` reuses its Hessian
    sum while the tasks return the same arrays. A subclass whose error depends only on what
    its Jacobian depends on sets `constant_error`: then ``c`` is cached (read-only) too.
    """

    constant_error = False  # True: the error depends on the structure and weights alone

    def structure_key(self, ctx):
        """What the Jacobian depends on (a subclass adds its own constants)."""
        return ctx.structure_key

    def __init__(self, weight=1.0):
        super().__init__(weight)
        self._cache_key = None
        self._weight = None  # the weight array the cache was made with
        self._jw = None
        self._H = None
        self._c = None  # with `constant_error`: ``J^T W e``, read-only
        self._term: LinearTerm | None | bool = None  # `linear_term`'s (False: none)

    def compute_qp_objective(self, ctx) -> Objective:
        """(H, c) with ``H`` and ``J^T W`` cached per structure."""
        self._refresh(ctx)
        if not self.constant_error:
            return self._H, self._linear_term(ctx)
        if self._c is None:
            self._c = self._linear_term(ctx)
            self._c.setflags(write=False)
        return self._H, self._c

    def linear_term(self, ctx) -> LinearTerm | None:
        """`Task.linear_term`: the kept term while the cache stays (made by `_make_term`).

        With `constant_error` a `CONSTANT` term of `compute_qp_objective`'s read-only ``c``
        (a subclass's too: `SlackPenaltyTask` adds its linear penalty), kept while that
        is the same array.
        """
        if self.constant_error:
            H, c = self.compute_qp_objective(ctx)
            term = self._term
            if not term or term.arrays[0] is not c or term.H is not H:
                term = self._term = LinearTerm(CONSTANT, H, (), (c,), self._term_guard())
            return term
        self._refresh(ctx)
        if self._term is None:
            self._term = self._make_term(ctx) or False
        return self._term or None

    def _make_term(self, ctx) -> LinearTerm | None:
        """The `LinearTerm` of the current cache (`_jw`, `_H`); None: no compiled form."""
        return None

    def _term_guard(self) -> tuple | None:
        """`LinearTerm.guard` of this task's terms; None (the default): ask every tick.

        A class that says one says it for its own type only (a subclass may read more).
        """
        return None

    def _refresh(self, ctx) -> None:
        """Make the cache again when the structure or the weights changed."""
        weight = self.compute_weight(ctx)
        structure = self.structure_key(ctx)
        # a read-only weight array seen before is the same weight (no bytes compared)
        same_weight = weight is self._weight and not weight.flags.writeable
        if (self._cache_key is None or self._cache_key[0] != structure
                or (not same_weight and self._cache_key[1] != weight.tobytes())):
            self._fill(ctx, weight, structure)

    def _fill(self, ctx, weight: np.ndarray, structure) -> None:
        """Make the cache of ``structure`` and ``weight``: ``J^T W``, ``H``; ``c`` unset."""
        self._weight = weight
        jac = self.compute_jacobian(ctx)
        self._jw = jac.T * weight
        self._H = self._jw @ jac
        self._H.setflags(write=False)
        self._c = None
        self._term = None
        self._cache_key = (structure, weight.tobytes())

    def prepare(self, ctx) -> np.ndarray | None:
        """Make the cache of ``ctx``'s structure now, as the first tick would; ``H``.

        With `constant_error` the whole objective (its error depends on the structure and
        the weights alone).
        """
        self._fill(ctx, self.compute_weight(ctx), self.structure_key(ctx))
        if self.constant_error:
            return self.compute_qp_objective(ctx)[0]
        return self._H

    def _linear_term(self, ctx) -> np.ndarray:
        """``c = J^T W e``, (n,), from the kept ``J^T W`` (the cache is current)."""
        return self._jw @ self.compute_error(ctx)
