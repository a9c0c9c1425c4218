"""Jerk-limited references from Ruckig (community version: no intermediate waypoints)."""

from __future__ import annotations

from math import copysign

import numpy as np
import ruckig

from models.numeric import clip
from wbc.axes import N_AXES, AxisLimits, axis_index
from wbc.errors import ConfigurationError, TrajectoryError, WbcInputError
from wbc.references.sample_c import compiled_trajectory

__all__ = ["RuckigReference"]

_OK = (ruckig.Result.Working, ruckig.Result.Finished)
# ruckig 0.19 raises on exact boundary cases between profile types (measured: 0.1 m at
# a = 0.8 m/s^2, j = 3.2 m/s^3, where a just reaches its limit); a slightly lower jerk
# limit moves the input off the boundary.
_JERK_RETRY = (1.0, 1.0 - 1e-6, 1.0 - 1e-4)


class RuckigReference:
    """Time-synchronized, jerk-limited trajectory of some axes from a measured state to a goal.

    Per-axis limits come from `AxisLimits` (the machine description), scaled down so that
    the feedback keeps some authority: velocity ``velocity_fraction * [v_lo, v_hi]``
    (asymmetric for cylinders), acceleration ``acceleration_fraction * a_max``, and jerk
    ``a / jerk_time``. The trajectory is computed once per goal (`plan`) and sampled at any
    time (`sample`, `sample_many`); before a plan, or with `hold`, it is a constant position.

    Args:
        limits: Axis limits.
        axes: Indices of the axes of this reference (crane or suspension).
        jerk_time: Time to build up full acceleration [s].
        velocity_fraction: In (0, 1].
        acceleration_fraction: In (0, 1].

    Attributes:
        axes: The axes' indices, (n,).
        index: The same axes as a slice when they are contiguous (basic indexing: cheaper
            than an index array, the same entries), else ``axes``.
    """

    def __init__(self, limits: AxisLimits, axes, jerk_time: float = 0.25,
                 velocity_fraction: float = 0.8, acceleration_fraction: float = 0.8):
        self.axes = np.asarray(axes, dtype=int).reshape(-1)
        if self.axes.size == 0 or np.any((self.axes < 0) | (self.axes >= N_AXES)):
            raise ConfigurationError(f"axes must be indices in [0, {N_AXES}), got {axes}")
        self.index = axis_index(self.axes)
        if not (jerk_time > 0 and 0 < velocity_fraction <= 1 and 0 < acceleration_fraction <= 1):
            raise ConfigurationError(
                f"need jerk_time > 0 and fractions in (0, 1]; got {jerk_time}, "
                f"{velocity_fraction}, {acceleration_fraction}")
        i = self.axes
        self.limits = limits
        self.names = tuple(limits.names[k] for k in i)
        self.position_lower = limits.position_lower[i].copy()
        self.position_upper = limits.position_upper[i].copy()
        self.max_velocity = velocity_fraction * limits.velocity_upper[i]
        self.min_velocity = velocity_fraction * limits.velocity_lower[i]
        self.max_acceleration = acceleration_fraction * limits.acceleration[i]
        self.max_jerk = self.max_acceleration / jerk_time
        n = i.size
        self._otg = ruckig.Ruckig(n)
        self._traj = ruckig.Trajectory(n)
        self._inp = ruckig.InputParameter(n)
        self._inp.max_velocity = self.max_velocity.tolist()
        self._inp.min_velocity = self.min_velocity.tolist()
        self._inp.max_acceleration = self.max_acceleration.tolist()
        self._inp.min_acceleration = (-self.max_acceleration).tolist()
        self._inp.max_jerk = self.max_jerk.tolist()
        self.start_time = 0.0
        self.goal: np.ndarray | None = None
        self._hold: np.ndarray | None = None
        self._planned = False
        self._kept_position: tuple | None = None  # see `position`
        # `sample_many_into` in C (`wbc.references.sample_c`, Ruckig's bits), the profiles
        # taken at each `plan`; None without a C compiler. `compiled` False: the binding.
        self.compiled = True
        self._compiled = compiled_trajectory(self.position_lower, self.position_upper)
        self._compiled_loaded = False

    @property
    def n(self) -> int:
        """Number of axes."""
        return self.axes.size

    @property
    def duration(self) -> float:
        """Duration of the planned trajectory [s] (0 when holding)."""
        return float(self._traj.duration) if self._planned else 0.0

    def check_goal(self, goal) -> np.ndarray:
        """Goal as an array of shape (n,) inside the position limits.

        Raises:
            WbcInputError: Wrong shape, non-finite, or outside a limit (the message names
                the axis and its range).
        """
        g = np.asarray(goal, dtype=float)
        if g.shape != (self.n,) or not np.all(np.isfinite(g)):
            raise WbcInputError(f"goal must be finite with shape ({self.n},) for axes "
                                f"{self.names}, got {goal}")
        bad = (g < self.position_lower - 1e-12) | (g > self.position_upper + 1e-12)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise WbcInputError(f"goal {g[k]:.6g} outside [{self.position_lower[k]:.6g}, "
                                f"{self.position_upper[k]:.6g}] for axis '{self.names[k]}'")
        return g

    def hold(self, position) -> None:
        """Reference = constant ``position`` (n,) (clipped into the limits)."""
        self._hold = clip(np.asarray(position, float), self.position_lower,
                          self.position_upper)
        self.goal = self._hold.copy()
        self._planned = False
        self._kept_position = None

    def plan(self, t0: float, position, velocity, acceleration, goal) -> float:
        """Plan from the measured state at time ``t0`` [s] to rest at ``goal``.

        The measured acceleration is clipped to the reference's acceleration limits (Ruckig
        brings velocities above the limits back by itself).

        Returns:
            The trajectory duration [s].

        Raises:
            WbcInputError: Bad goal. TrajectoryError: Ruckig failed.
        """
        g = self.check_goal(goal)
        self._kept_position = None  # the trajectory changes from here on
        inp = self._inp
        inp.current_position = np.asarray(position, float).tolist()
        inp.current_velocity = np.asarray(velocity, float).tolist()
        inp.current_acceleration = clip(np.asarray(acceleration, float),
                                        -self.max_acceleration,
                                        self.max_acceleration).tolist()
        inp.target_position = g.tolist()
        inp.target_velocity = [0.0] * self.n
        inp.target_acceleration = [0.0] * self.n
        result = None
        for factor in _JERK_RETRY:
            inp.max_jerk = (factor * self.max_jerk).tolist()
            try:
                result = self._otg.calculate(inp, self._traj)
            except (ruckig.RuckigError, ValueError) as exc:  # ValueError: an unknown code
                result = exc
                continue
            if result in _OK:
                break
        inp.max_jerk = self.max_jerk.tolist()
        if result not in _OK:
            what = result.name if isinstance(result, ruckig.Result) else str(result).strip()
            raise TrajectoryError(f"Ruckig failed ({what}) from {inp.current_position} to "
                                  f"{g.tolist()} for axes {self.names}")
        self.start_time = float(t0)
        self.goal = g
        self._hold = None
        self._planned = True
        self._compiled_loaded = (self._compiled is not None
                                 and self._compiled.load(self._traj))
        return self.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, velocity, acceleration) at time ``t`` [s], shapes (n,).

        Positions are clipped into the limits (a profile that starts fast may overshoot).
        """
        if not self._planned:
            if self._hold is None:
                raise TrajectoryError("reference sampled before plan() or hold()")
            z = np.zeros(self.n)
            return self._hold.copy(), z, z.copy()
        p, v, a = self._traj.at_time(max(t - self.start_time, 0.0))[:3]
        return (clip(p, self.position_lower, self.position_upper), np.asarray(v),
                np.asarray(a))

    def position(self, t: float) -> np.ndarray:
        """``sample(t)[0]``: the position at time ``t`` [s], clipped into the limits, (n,).

        The position `sample_into` wrote last is kept and returned (a copy) when ``t`` is
        at the same trajectory time: the controller's governor asks, each tick, for the
        position at the time the previous tick's reference was sampled. The kept
        position is dropped by `plan` and `hold`, the only changes of the trajectory.
        """
        if not self._planned:
            if self._hold is None:
                self.sample(t)  # raises: neither planned nor held
            return self._hold.copy()  # `sample`'s position, without its zero rates
        kept = self.kept(t)
        if kept is not None:
            return kept.copy()
        return clip(self._traj.at_time(max(t - self.start_time, 0.0))[0],
                    self.position_lower, self.position_upper)

    def kept(self, t: float) -> np.ndarray | None:
        """The position at time ``t`` [s] this reference holds already, or None.

        The held position, or the kept one (`position`) when ``t`` is its time: the array
        itself, not a copy (read it, don't write it). `hold`, `plan` and `keep_position`
        replace it by another array.
        """
        if not self._planned:
            return self._hold
        kept = self._kept_position
        if kept is None:
            return None
        tr = max(t - self.start_time, 0.0)
        return kept[2] if kept[0] == tr and copysign(1.0, tr) == kept[1] else None

    def sample_into(self, t: float, rate: float, position: np.ndarray,
                    velocity: np.ndarray, acceleration: np.ndarray) -> None:
        """Write ``sample(t)``, velocity times ``rate`` and acceleration times ``rate**2``.

        The sample of a reference whose clock runs at ``rate`` (the controller's reference
        governor), written into the given arrays of shape (n,) (views are fine): the same
        operations as scaling `sample`'s arrays, without the temporary arrays (the
        whole-body QP asks every tick).
        """
        if self._planned:
            tr = max(t - self.start_time, 0.0)
            p, v, a = self._traj.at_time(tr)[:3]
            clip(p, self.position_lower, self.position_upper, out=position)
            self.keep_position(tr, position)
        else:
            p, v, a = self.sample(t)
            position[...] = p
        np.multiply(v, rate, out=velocity)
        np.multiply(a, rate**2, out=acceleration)

    def sample_raw(self, t: float) -> tuple[float | None, list]:
        """The sample at time ``t`` [s] before `sample_into` clips and scales it.

        Returns:
            ``(tr, pva)``: the trajectory time ``tr`` [s] (None while holding) and one list
            of 3n floats, the position as Ruckig gives it (not clipped), the velocity and the
            acceleration (not scaled); while holding the held position and zeros. The
            compiled whole-body QP (`wbc.controllers.tracking_c`) clips and scales it.
        """
        if self._planned:
            tr = max(t - self.start_time, 0.0)
            p, v, a = self._traj.at_time(tr)[:3]
            return tr, p + v + a
        return None, self.sample(t)[0].tolist() + [0.0] * (2 * self.n)

    def keep_position(self, tr: float, position: np.ndarray) -> np.ndarray:
        """Keep ``position`` (n,), the clipped position at trajectory time ``tr`` [s].

        `position` returns it while asked at that time again (see there); for whoever
        clipped a `sample_raw` of a planned trajectory. Returns the copy kept (`kept`).
        """
        # (time, its sign: at_time(-0.0) need not be at_time(0.0), position)
        self._kept_position = (tr, copysign(1.0, tr), position.copy())
        return self._kept_position[2]

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Samples at several times [s]: three arrays of shape (len(times), n)."""
        if not self._planned and self._hold is None:
            return self.sample(0.0)  # raises: neither planned nor held
        count = len(times)
        p, v, a = np.empty((count, self.n)), np.empty((count, self.n)), np.empty((count, self.n))
        self.sample_many_into(times, 1.0, p, v, a)  # times 1.0: the same bits
        return p, v, a

    def sample_columns_into(self, times: np.ndarray, rate: float, position: np.ndarray,
                            velocity: np.ndarray, acceleration: np.ndarray) -> None:
        """`sample_many_into` this reference's columns (`index`, a slice) of (m, 9) arrays.

        The controller's node arrays of all nine axes, each reference writing its own
        columns: the same numbers as `sample_many_into` of the columns' views, in C without
        the views where it can (`wbc.references.sample_c`). The position at the first time
        is kept (`position`): the MPC's first node is now, where the controller's governor
        asks at the next tick.
        """
        i = self.index
        if not (self.compiled and self._planned and self._compiled_loaded
                and isinstance(i, slice)
                and self._compiled.sample_columns(times, self.start_time, rate, i.start,
                                                  position, velocity, acceleration)):
            self.sample_many_into(times, rate, position[:, i], velocity[:, i],
                                  acceleration[:, i])
        if self._planned and len(times):
            # `kept`'s trajectory time of times[0]; the row is the clipped sample there
            self.keep_position(max(float(times[0]) - self.start_time, 0.0), position[0, i])

    def sample_nodes_into(self, tau: float, rate: float, offsets: np.ndarray,
                          position: np.ndarray, velocity: np.ndarray,
                          acceleration: np.ndarray) -> None:
        """`sample_columns_into` at the times ``tau + rate * offsets`` [s] (the same bits).

        The controller's node samples (``offsets`` its node times, float64 (m,)): the times
        are made in the compiled call where it can (`sample_c.CompiledTrajectory.
        sample_nodes`); a held reference does not need them.
        """
        i = self.index
        if not self._planned:  # held: `sample_many_into`'s values, no times needed
            if self._hold is None:
                self.sample(0.0)  # raises: neither planned nor held
            position[:, i] = self._hold
            velocity[:, i] = rate * 0.0
            acceleration[:, i] = rate**2 * 0.0
            return
        if self.compiled and self._compiled_loaded and isinstance(i, slice):
            first = self._compiled.sample_nodes(tau, rate, offsets, self.start_time, i.start,
                                                position, velocity, acceleration)
            if first is not None:
                if len(offsets):
                    self.keep_position(max(first - self.start_time, 0.0), position[0, i])
                return
        self.sample_columns_into(tau + rate * offsets, rate, position, velocity,
                                 acceleration)

    def sample_many_into(self, times, rate: float, position: np.ndarray,
                         velocity: np.ndarray, acceleration: np.ndarray) -> None:
        """`sample_many` written into arrays of shape (len(times), n), views are fine.

        Velocities times ``rate``, accelerations times ``rate**2`` (the reference governor's
        clock rate), as `sample_into` scales one sample: no temporary arrays for the MPC's
        node samples each tick. A planned trajectory is sampled in C where it can
        (`wbc.references.sample_c`: every time and axis in one call, the binding's bits).

        Raises:
            TrajectoryError: Neither planned nor held.
        """
        if not self._planned:  # held (or not set: `sample` raises)
            if self._hold is None:
                self.sample(0.0)
            position[...] = self._hold
            velocity[...] = rate * 0.0  # what scaling the held zeros gives (NaN, -0.0)
            acceleration[...] = rate**2 * 0.0
            return
        if (self.compiled and self._compiled_loaded
                and self._compiled.sample_into(np.asarray(times, float), self.start_time, rate,
                                               position, velocity, acceleration)):
            return
        at = self._traj.at_time
        # One flat list of Python floats: numpy converts it at a third of the cost of the
        # nested (times, 3, n) lists. ``max(t - t0, 0)`` as numpy's maximum (its rules on
        # ties and NaN).
        flat: list = []
        extend = flat.extend
        for t in np.maximum(np.asarray(times, float) - self.start_time, 0.0).tolist():
            p, v, a = at(t)[:3]
            extend(p)
            extend(v)
            extend(a)
        pva = np.array(flat, float).reshape(-1, 3, self.n)
        clip(pva[:, 0], self.position_lower, self.position_upper, out=position)
        np.multiply(pva[:, 1], rate, out=velocity)
        np.multiply(pva[:, 2], rate**2, out=acceleration)
