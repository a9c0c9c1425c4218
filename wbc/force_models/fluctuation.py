r"""How much the wheel loads fluctuate while driving, and the speed that leaves room for it.

The MPC's prediction holds the ground under the wheels fixed (`WarpDrift` extrapolates the
twist's rate a short time ahead, no more). On rough ground at speed the loads move by more
than that: bumps under single wheels, the bogies rocking on their servos, the chassis'
roll. What the prediction misses is not known ahead, but its size is measured, and it grows
with the driving speed (the terrain's excitation comes faster than the servos answer it).
From the measured load of each wheel ``f_i`` (the cylinder-force closure of
`ClosureFeedback`):

.. math:: \bar f_i = \mathrm{LP}_{\tau_h}(f_i), \qquad
          \sigma_i^2 = \mathrm{LP}_{\tau_w}\big((f_i - \bar f_i)^2\big), \qquad
          k_i = \sigma_i / \sqrt{\mathrm{LP}_{\tau_w}(v^2)},

first-order low-pass filters: ``tau_h`` separates the fluctuation from the load the crane
and the slope set, ``tau_w`` is the window of the mean squares; ``v`` is the base's
horizontal speed. ``k_i`` (load fluctuation per unit speed [N s/m]) is updated only while
the machine drives faster than ``min_speed`` with all four wheels on the ground (slower,
the sensors' noise would dominate the ratio) and is kept otherwise.

`SpeedGovernor.cap` turns it into the largest wheel-speed scale ``s`` at which every
wheel's slow load stays ``z`` fluctuations above its threshold:

.. math:: z\, k_i\, v_{nom}\, s \le \bar f_i - f_{min,i}, \qquad v_{nom} = v / s_{lag},

with ``v_nom`` the operator's commanded speed, inferred from the measured one and
``s_lag``, the commanded scale through the drive's first-order lag (`wbc.drive_model`; the
commanded scale itself would overstate ``v_nom`` while the drive slows, and the cap would
run down to zero). The MPC bounds its speed-scale variable by the cap
(`wbc.constraints.SpeedScaleLimit`, still at its rate limit): a derating of the drive, as
machines derate on rough ground, that acts on the speed only.

Tried and left (development draws, master seed 1, 100 `random` draws each): the same
margin inside the force rows, (a) linear in the speed scale, so that the QP could buy it by
slowing down, and (b) as a raised threshold ``z k_i v``. The QP then bought it with the
crane and the suspension as well, the wheels' loads rang at the chassis' 2-3 Hz, and the
measure, which sees that motion too, grew with it: (a) turned two near-misses into wheels
at 0 N, (b) three (draws 1, 11, 17), where the governor alone leaves the draws as they
were. Rows that also hold for the crane inputs' load change doubled (the chassis'
overshoot) did not help either (two failing draws, both worse).
"""

from __future__ import annotations

import math

import numpy as np

from models.cbuild import BufferSlot
from models.numeric import clip
from wbc.force_models.fluctuation_c import GovernorPass

__all__ = ["SideLoadFluctuation", "SpeedGovernor"]

# `np.all`, `np.min` of 1-D arrays without their Python dispatch (the same ufunc
# reductions; this runs every tick)
_all, _min = np.logical_and.reduce, np.minimum.reduce

_MIN_SCALE = 0.05  # below this the commanded speed cannot be inferred from the measured one


class SpeedGovernor:
    """Load fluctuation per unit driving speed and the speed-scale cap it allows.

    Args:
        z: Fluctuations (RMS) kept between a wheel's slow load and its threshold.
        high_pass: tau_h [s].
        window: tau_w [s].
        drive_time_constant: tau of the base drive [s] (`wbc.drive_model`).
        min_speed: Below this horizontal speed [m/s] ``k`` is not updated.
    """

    def __init__(self, z: float, high_pass: float = 0.2, window: float = 1.0,
                 drive_time_constant: float = 0.5, min_speed: float = 0.15):
        self.z = float(z)
        self.high_pass = float(high_pass)
        self.window = float(window)
        self.drive_time_constant = float(drive_time_constant)
        self.min_speed = float(min_speed)
        # The tick in C on kept buffers (`fluctuation_c`), loaded here, not in a tick; None
        # without a compiler. The filters' state lives in its buffers then.
        self._c = GovernorPass.make()
        self._state = np.zeros(2) if self._c is None else self._c.state
        self.reset()

    def reset(self) -> None:
        """Forget the history (no estimate: no cap)."""
        self.mean: np.ndarray | None = None
        self.per_speed = np.zeros(4)  # k [N s/m]
        self.scale_lag = 1.0
        if self._c is None:
            self._square = np.zeros(4)
        else:
            self._square = self._c.square
            self._square[:] = 0.0
        self._speed_square = 0.0
        self._time: float | None = None

    scale_lag = BufferSlot("_state", 0, doc="``s_lag``: the commanded scale through the "
                                            "drive's lag.")
    _speed_square = BufferSlot("_state", 1, doc="The mean square of the speed over the window "
                                                "[m^2/s^2].")

    def update(self, forces, in_contact, time: float, speed: float,
               speed_scale: float) -> None:
        """Take one tick's measurements.

        Args:
            forces: The wheels' measured loads [N], (4,).
            in_contact: Contact flags (4,).
            time: Their time [s].
            speed: The base's horizontal speed [m/s].
            speed_scale: The scale commanded over the last period.
        """
        dt = 0.0 if self._time is None else time - self._time
        self._time = float(time)
        c = self._c
        if (c is not None and self.mean is c.mean and self._square is c.square
                and forces is not c.mean and _quad(forces, float)
                and _quad(in_contact, bool)):
            per_speed = c.update(forces, in_contact, dt, speed, speed_scale,
                                 (self.drive_time_constant, self.high_pass, self.window,
                                  self.min_speed))
            if per_speed is not None:
                self.per_speed = per_speed
            return
        if dt > 0:
            self.scale_lag += dt / (self.drive_time_constant + dt) * (speed_scale
                                                                      - self.scale_lag)
        f = np.asarray(forces, float)
        if c is not None and self.mean is None and self._square is c.square:
            if _usable(f, in_contact, speed):  # the first sample starts the kept mean
                c.mean[:] = f
                self.mean = c.mean
            return
        if _usable(f, in_contact, speed) and _swing_step(self, f, dt, speed >= self.min_speed):
            a = dt / (self.window + dt)
            self._speed_square += a * (speed * speed - self._speed_square)
            self.per_speed = np.sqrt(self._square / self._speed_square)

    def cap(self, thresholds, speed: float, in_contact) -> float:
        """Largest speed scale in [0, 1] that keeps ``z k_i v_nom s`` within the headroom.

        Args:
            thresholds: The wheels' thresholds with the other margins [N], (4,).
            speed: The base's horizontal speed now [m/s].
            in_contact: Contact flags (4,): only wheels on the ground count.
        """
        if self.mean is None:
            return 1.0
        c = self._c
        if (c is not None and self.mean is c.mean and _quad(thresholds, float)
                and _quad(in_contact, bool) and _quad(self.per_speed, float)):
            ratios = c.ratios(self.per_speed, thresholds, in_contact, speed, self.z,
                              _MIN_SCALE)
            return 1.0 if ratios is None else float(clip(_min(ratios), 0.0, 1.0))
        per_speed = self.per_speed.tolist()
        if not any(k > 0 for k in per_speed):
            return 1.0
        v_nom = speed / max(self.scale_lag, _MIN_SCALE)
        if not (math.isfinite(v_nom) and v_nom > 0):
            return 1.0
        # Each wheel's ratio on Python floats (the IEEE operations numpy's arrays did), their
        # smallest by numpy's reduction (its rule for NaN and signed zeros).
        z = self.z
        ratios = []
        for m, t, k, c in zip(self.mean.tolist(), np.asarray(thresholds, float).tolist(),
                              per_speed, np.asarray(in_contact, bool).tolist()):
            need = z * k * v_nom  # the fluctuation at s = 1 [N]
            if c and need > 0:
                ratios.append((m - t) / need)
        return float(clip(_min(np.array(ratios)), 0.0, 1.0)) if ratios else 1.0


class SideLoadFluctuation:
    r"""How much each side pair's load swings while driving: the roll reserve's measure.

    The warp (`wbc.force_models.feedback.DIAGONAL`) moves load within each side pair, and
    the leveling sets that split; the sum of a side pair's loads, ``S_L = f_FL + f_RL`` and
    ``S_R = f_FR + f_RR``, only the crane's pose (and the ground's roll) moves. On rough
    ground the side sums swing while the machine drives, with the crane and the suspension
    still (development draw 17 of `fast-swing-steep`, master seed 1: the uphill pair's sum
    between 0.3 and 5.3 kN at about 2 Hz while creeping at 0.04-0.13 m/s, its RMS 1.8 kN,
    the diagonal's 0.6 kN). From the measured loads:

    .. math:: \bar S_j = \mathrm{LP}_{\tau_h}(S_j), \qquad
              \sigma_j^2 = \mathrm{LP}_{\tau_w}\big((S_j - \bar S_j)^2\big),

    updated only while the machine drives (horizontal speed >= ``min_speed``) on four
    wheels and kept otherwise. Unlike `SpeedGovernor`'s measure it is not per unit speed:
    slowing down did not shrink it (the governor's cap took draw 17 to 0.04 m/s).
    `driving`: the speed low-pass filtered over ``tau_w`` is at least ``min_speed`` (the
    measured speed of a creeping machine dips below it for moments).

    Args:
        high_pass: tau_h [s].
        window: tau_w [s].
        min_speed: Below this horizontal speed [m/s] ``sigma`` is not updated.
    """

    def __init__(self, high_pass: float = 0.2, window: float = 1.0, min_speed: float = 0.02):
        self.high_pass = float(high_pass)
        self.window = float(window)
        self.min_speed = float(min_speed)
        self.reset()

    def reset(self) -> None:
        """Forget the history (no estimate: sigma zero)."""
        self.mean: np.ndarray | None = None  # slow side sums (2,) [N], order left, right
        self.sigma = np.zeros(2)  # RMS swing of the side sums (2,) [N]
        self._square = np.zeros(2)
        self._time: float | None = None
        self.speed = 0.0  # the horizontal speed low-pass filtered over tau_w [m/s]

    @property
    def driving(self) -> bool:
        """Whether the filtered speed is at least ``min_speed``."""
        return self.speed >= self.min_speed

    def update(self, forces, in_contact, time: float, speed: float,
               swing: bool = True) -> None:
        """Take one tick's measurements.

        Args:
            forces: The wheels' measured loads [N], (4,), order FL, RL, FR, RR.
            in_contact: Contact flags (4,).
            time: Their time [s].
            speed: The base's horizontal speed [m/s].
            swing: Update ``mean`` and ``sigma``; False: only the speed (`driving`), for a
                caller that does not read the swing.
        """
        dt = 0.0 if self._time is None else time - self._time
        self._time = float(time)
        if dt > 0 and math.isfinite(speed):
            self.speed += dt / (self.window + dt) * (speed - self.speed)
        if not swing:
            return
        f = np.asarray(forces, float)
        if not _usable(f, in_contact, speed):
            return
        side = f[0::2] + f[1::2]  # (FL + RL, FR + RR)
        if _swing_step(self, side, dt, speed >= self.min_speed):
            self.sigma = np.sqrt(self._square)


def _quad(a, dtype) -> bool:
    """``a`` is a (4,) array of ``dtype`` (what the compiled governor takes)."""
    return type(a) is np.ndarray and a.shape == (4,) and a.dtype == dtype


def _usable(forces: np.ndarray, in_contact, speed: float) -> bool:
    """All four wheels on the ground, the loads and the speed finite."""
    return bool(_all(np.asarray(in_contact, bool).reshape(-1)) and _all(np.isfinite(forces))
                and math.isfinite(speed))


def _swing_step(measure, x: np.ndarray, dt: float, moving: bool) -> bool:
    """One tick of a swing measure (`SpeedGovernor`, `SideLoadFluctuation`).

    ``measure.mean``, the slow part of ``x`` (low-pass over ``measure.high_pass``), and
    ``measure._square``, the mean square of the rest over ``measure.window``, this one only
    while ``moving``. The first sample starts the mean. True when ``_square`` changed.
    """
    if measure.mean is None:
        measure.mean = x.copy()
        return False
    if not dt > 0:
        return False
    measure.mean += dt / (measure.high_pass + dt) * (x - measure.mean)
    if not moving:
        return False
    h = x - measure.mean
    measure._square += dt / (measure.window + dt) * (h * h - measure._square)
    return True
