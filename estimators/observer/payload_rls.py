r"""The payload mass from the crane cylinders' pressures: recursive least squares, with events.

The lift and tilt cylinders' forces are affine in the payload mass at the measured motion,
``F = F_0(q, qd, qdd, base) + m Y(q, qd, qdd, base)`` (`estimators.efforts`, the same rigid-body
dynamics as the normal-force estimator). With the measured forces ``y`` (from the chamber
pressures) the mass is a recursive least-squares estimate with forgetting factor
``lambda = exp(-dt / T)`` (`FORGETTING_TIME`), the two cylinders weighted by their force noise.

Pick and release: a normalised innovation ``nu^2 / (Y^T P Y + R)`` above `EVENT_CHI2` on
`EVENT_TICKS` ticks in a row is a payload change; the covariance is reset so the estimate
moves to the new mass within a few ticks, and the event is reported (``pick`` when the mass
grew, else ``release``).

After the operator's grapple command (`PayloadRLS.expect_pick`) a growing mass is an event
after `EXPECTED_PICK_TICKS` ticks instead of `EVENT_TICKS`, until the pick is seen or
`EXPECTED_PICK_SECONDS` have passed (an empty grab). A step pick unloads the uphill wheels
within ~0.1 s; the five ticks are what tells a pick from the transient of a lift, which
needs no such care once the operator has said a pick is coming. A release always takes the
five ticks. (Tried and not kept: the raw, unfiltered regression for the expected pick, see
`docs/sweeps.md`: a tick's own forces carry the boom's unmodelled acceleration, and its
mass was 15-35 % high.)

A mass that moved by more than `EVENT_MASS_CHANGE` within `EVENT_WINDOW` is an event as well:
with a short low-pass (the link accelerometers' regression, `docs/sensors.md`) the estimate
can follow a pick within its own update when its covariance is still the prior's (a machine
standing still since the start learns nothing: the seals' dead band), and the innovation
then never stands out against that covariance.

Its standard deviation: the RLS covariance and a floor for what averaging does not remove
(the transducers' zero offsets mapped through ``Y``).
"""

from __future__ import annotations

import math

import numpy as np

from estimators.observer._linalg import solve
from models.cbuild import BufferSlot

__all__ = ["EVENT_CHI2", "EVENT_MASS_CHANGE", "EVENT_TICKS", "EVENT_WINDOW",
           "EXPECTED_PICK_SECONDS", "EXPECTED_PICK_TICKS", "FORGETTING_TIME", "PayloadRLS",
           "RLS_STATE", "forgetting", "without_seal_friction"]

FORGETTING_TIME = 2.0  # [s]
EVENT_CHI2 = 25.0  # normalised innovation (5 sigma)
EVENT_TICKS = 5
EXPECTED_PICK_TICKS = 2  # a growing mass after the grapple command
EXPECTED_PICK_SECONDS = 6.0  # [s] the grapple command's expectation lapses (an empty grab)
EVENT_MASS_CHANGE = 50.0  # [kg] a change of the estimate within `EVENT_WINDOW` is an event
EVENT_WINDOW = 0.5  # [s]
_RESET_STD = 300.0  # [kg] after an event
_MIN_SENSITIVITY = 5.0  # [N/kg] below this the cylinders do not see the payload
_UNUSED_VARIANCE = 1e18  # [N^2] a cylinder inside its dead band this tick

# Two cylinders, once per control tick: the arithmetic is on Python floats in the order of
# the numpy expressions it replaced (the same results, bit for bit, ~1 us less per operation);
# the 2x2 solves stay LAPACK's. The observer's compiled tick runs the same update in C
# (`tail_c`) on the state below, kept in one array (`RLS_STATE`, the places), and the
# window's estimates in a ring of two rows (times, masses) from its ``head``.
RLS_STATE = ("mass", "P", "run", "y0", "y1", "event", "event_time", "expect_until",
             "settle_until", "head", "count", "R0", "R1", "event_variance_scale",
             "expected_pick_ticks")
_EVENTS = (None, "pick", "release")  # `PayloadRLS.event` by its code in the state
_MASS, _P, _Y0, _EVENT, _EVENT_TIME, _HEAD, _COUNT, _R0 = (
    RLS_STATE.index(n) for n in ("mass", "P", "y0", "event", "event_time", "head", "count",
                                 "R0"))
_RING = 64  # the window's first capacity (a 10 ms tick fills 51 of it); it grows when full


def _gain(y0: float, y1: float, p, r0: float, r1: float, rhs) -> np.ndarray:
    """``solve(outer(y, y) p + diag(r), rhs)``."""
    yy = y0 * y1 * p
    s = np.array([[y0 * y0 * p + r0, yy + 0.0], [yy + 0.0, y1 * y1 * p + r1]])
    return solve(s, rhs)  # NaN if singular: not with r0, r1 > 0


def _sign(x: float) -> float:
    """``np.sign`` of a float (NaN stays NaN)."""
    return 1.0 if x > 0 else -1.0 if x < 0 else x * 0.0 if x != x else 0.0


def forgetting(dt: float) -> float:
    """The forgetting factor ``lambda = exp(-dt / T)`` of a tick of ``dt`` [s] (1 if dt <= 0)."""
    return np.exp(-dt / FORGETTING_TIME) if dt > 0 else 1.0


def _slot(name: str, kind: type = float) -> BufferSlot:
    return BufferSlot("_state", RLS_STATE.index(name), kind)


class PayloadRLS:
    """Scalar RLS of the payload mass (module docstring).

    Args:
        initial_mass: Prior [kg].
        initial_std: Its std [kg].
        force_std: Std of each measured cylinder force per tick [N], (2,).
        bias_std: Std of each cylinder force's constant offset [N], (2,).
        event_variance_scale: Factor on the force variance in the event test (below 1 when
            the caller low-passes the regression: the per-tick noise is smaller then, while
            the ticks are correlated, so the estimate's own update keeps ``force_std``).
        expected_pick_ticks: Ticks over the threshold that make a growing mass a pick while
            one is expected (`EXPECTED_PICK_TICKS`).
    """

    mass = _slot("mass")
    P = _slot("P")
    _run = _slot("run", int)
    _expect_until = _slot("expect_until")
    _settle_until = _slot("settle_until")  # an event's estimate converges until then
    event_variance_scale = _slot("event_variance_scale")
    expected_pick_ticks = _slot("expected_pick_ticks", int)

    def __init__(self, initial_mass: float, initial_std: float, force_std, bias_std,
                 event_variance_scale: float = 1.0,
                 expected_pick_ticks: int = EXPECTED_PICK_TICKS):
        self._state = np.zeros(len(RLS_STATE))
        self.event_variance_scale = float(event_variance_scale)
        self.expected_pick_ticks = int(expected_pick_ticks)
        self.mass = float(initial_mass)
        self.P = float(initial_std) ** 2
        self._state[_R0:_R0 + 2] = np.asarray(force_std, float) ** 2
        # fixed at construction (read-only properties): `std` keeps them as floats, the C
        # reads R in the state
        self._r = self._state[_R0:_R0 + 2]
        self._r.flags.writeable = False
        self._bias_std = np.array(bias_std, float)
        self._bias_std.flags.writeable = False
        self._noise = (*self._r.tolist(), *self._bias_std.tolist())
        self._run = 0
        self._y = (0.0, 0.0)
        self.event = None
        self.event_time = None
        self._expect_until = -math.inf
        self._settle_until = -math.inf
        self._ring = np.zeros((2, _RING))  # (time, mass) of the window, from ``head``

    @property
    def R(self) -> np.ndarray:
        """The two cylinders' force variances [N^2], (2,), read-only."""
        return self._r

    @property
    def bias_std(self) -> np.ndarray:
        """Std of each cylinder force's constant offset [N], (2,), read-only."""
        return self._bias_std

    @property
    def _y(self) -> tuple[float, float]:
        """The last tick's ``Y`` of the two cylinders (`std`)."""
        y = self._state[_Y0:_Y0 + 2].tolist()
        return y[0], y[1]

    @_y.setter
    def _y(self, value) -> None:
        self._state[_Y0:_Y0 + 2] = value

    @property
    def event(self) -> str | None:
        """``pick`` or ``release`` when the last update detected one, else None."""
        return _EVENTS[int(self._state[_EVENT])]

    @event.setter
    def event(self, value: str | None) -> None:
        self._state[_EVENT] = _EVENTS.index(value)

    @property
    def event_time(self) -> float | None:
        """When the last event was detected [s], None before any."""
        t = float(self._state[_EVENT_TIME])
        return None if math.isnan(t) else t

    @event_time.setter
    def event_time(self, value: float | None) -> None:
        self._state[_EVENT_TIME] = math.nan if value is None else value

    def expect_pick(self, time: float) -> None:
        """The operator closed the grapple at ``time`` [s]: a pick may come (module docstring)."""
        self._expect_until = float(time) + EXPECTED_PICK_SECONDS

    @property
    def pick_expected(self) -> bool:
        """Whether a grapple command's expectation is on (no pick seen since)."""
        return self._expect_until > -math.inf

    def update(self, time: float, dt: float, measured, f0, y, band=None) -> None:
        """One tick: measured forces (2,), and ``F_0``, ``Y`` of the two cylinders (2,).

        ``band`` (2,) [N]: a dead band about each measured force (a standing cylinder's
        seals hold anything up to their rating, so an innovation inside it says nothing
        and one beyond it counts only by what lies beyond). A tick whose every cylinder
        lies inside its band is skipped, forgetting included: no information, no loss.
        """
        self.event = None
        y0, y1 = self._y = tuple(_floats(y))
        m0, m1 = _floats(measured)
        if _insensitive(y0, y1) or not (math.isfinite(m0) and math.isfinite(m1)):
            return
        f00, f01 = _floats(f0)
        if not (math.isfinite(f00) and math.isfinite(f01)):
            return  # no information (the caller's state was not finite)
        mass = self.mass
        nu = [m0 - f00 - y0 * mass, m1 - f01 - y1 * mass]
        r = self.R.tolist()
        if band is not None:
            inside = [abs(n) <= b for n, b in zip(nu, _floats(band))]
            if all(inside):
                self._run = 0
                return
            nu = [0.0 if i else n - _sign(n) * b for i, n, b in zip(inside, nu, _floats(band))]
            r = [_UNUSED_VARIANCE if i else ri for i, ri in zip(inside, r)]
        lam = forgetting(dt)
        p = self.P / lam
        scale = self.event_variance_scale
        x = _gain(y0, y1, p, r[0] * scale, r[1] * scale, nu).tolist()
        chi2 = float(nu[0] * x[0] + nu[1] * x[1])
        self._run = self._run + 1 if chi2 > EVENT_CHI2 else 0
        ticks = EVENT_TICKS
        if time > self._expect_until:
            self._expect_until = -math.inf
        elif y0 * x[0] + y1 * x[1] > 0:  # the innovation makes the mass grow
            ticks = self.expected_pick_ticks
        moved = self._moved(time, mass)
        event = self._run >= ticks or moved
        if event:
            p = _RESET_STD ** 2
            self._run = 0
        # one step (with the reset covariance after an event: moves the mass to the new load)
        k0, k1 = (p * _gain(y0, y1, p, r[0], r[1], [y0, y1])).tolist()
        new_mass = mass + float(k0 * nu[0] + k1 * nu[1])
        new_p = float(p - p * (k0 * y0 + k1 * y1))
        if not new_p > 0 and p > 0:  # round-off: p k'y ~ p when y'R^-1 y p >> 1
            new_p = 1.0 / (1.0 / p + y0 * y0 / r[0] + y1 * y1 / r[1])  # the same, exactly
        if not (math.isfinite(new_mass) and math.isfinite(new_p)):
            self._run = 0  # a step the arithmetic cannot take (overflow): no update
            return
        self.mass, self.P = new_mass, new_p
        if event:
            self.event = "pick" if self.mass > self._ring[1, self._head] else "release"
            self.event_time = time
            self._settle_until = time + EVENT_WINDOW
            if self.event == "pick":
                self._expect_until = -math.inf

    def _moved(self, time: float, mass: float) -> bool:
        """Whether ``mass`` differs by `EVENT_MASS_CHANGE` from the window's oldest estimate.

        The window restarts after each event's `EVENT_WINDOW` (the estimate converges to the
        new load then: not a second event).
        """
        state, ring = self._state, self._ring
        head, count = int(state[_HEAD]), int(state[_COUNT])
        if time < self._settle_until:
            head, count = 0, 0
        else:
            while count and ring[0, head] < time - EVENT_WINDOW:
                head, count = (head + 1) % ring.shape[1], count - 1
        if count == ring.shape[1]:  # full: the window in order, in a ring twice the size
            ring = self._ring = np.concatenate((np.roll(ring, -head, axis=1),
                                                np.zeros_like(ring)), axis=1)
            head = 0
        at = (head + count) % ring.shape[1]
        ring[0, at], ring[1, at] = time, mass
        state[_HEAD], state[_COUNT] = head, count + 1
        if time < self._settle_until:
            return False
        return abs(mass - ring[1, head]) > EVENT_MASS_CHANGE

    @property
    def _head(self) -> int:
        """Where the window's oldest estimate is in the ring."""
        return int(self._state[_HEAD])

    @property
    def std(self) -> float:
        """Std of the mass [kg]: the covariance and the offsets' floor."""
        _, p, _, y0, y1 = self._state[:_Y0 + 2].tolist()
        floor = 0.0
        if y0 == y0 and y1 == y1 and not _insensitive(y0, y1):
            r0, r1, b0, b1 = self._noise
            w0, w1 = y0 / r0, y1 / r1
            a0, a1 = w0 * b0, w1 * b1
            floor = float(math.sqrt(a0 * a0 + a1 * a1) / (w0 * y0 + w1 * y1))
        return float(math.sqrt(p + floor ** 2))


def without_seal_friction(forces, speeds, seals, sliding_speed: float) -> tuple[list, list]:
    """Two cylinders' forces less their seals' friction, and the dead band left [N].

    A sliding cylinder's (``|speed| > sliding_speed`` [m/s]) pressures also push its seals'
    friction, the rating ``seals`` [N] against the motion: subtracted, no band. A cylinder
    standing still holds anything up to the rating: a band of the rating about the measured
    force.
    """
    corrected, band = [], []
    for f, v, seal in zip(forces, speeds, seals):
        sliding = abs(v) > sliding_speed
        corrected.append(f - (math.copysign(seal, v) if sliding else 0.0))
        band.append(0.0 if sliding else seal)
    return corrected, band


def _insensitive(y0: float, y1: float) -> bool:
    """``max |Y| < _MIN_SENSITIVITY`` (False with a NaN, as numpy's ``max``)."""
    return abs(y0) < _MIN_SENSITIVITY and abs(y1) < _MIN_SENSITIVITY


def _floats(x) -> list:
    """A 2-vector (array or sequence) as Python floats."""
    return x.tolist() if isinstance(x, np.ndarray) else [float(v) for v in x]
