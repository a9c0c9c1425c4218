"""A kinematic plant and a state builder for tests and benchmarks without MuJoCo.

`KinematicPlant` stands in for the velocity-servoed machine: each axis follows its rate
command with a first-order lag (time constant 0 = ideal servo); the base holds its pose
and twist. It is enough to check the controllers' logic in closed loop; the physics are
MuJoCo's job (`scenarios.simulator`).
"""

from __future__ import annotations

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.state import MachineState
from wbc.axes import N_AXES
from wbc.controllers.command import ControlCommand

__all__ = ["KinematicPlant", "make_state", "moving_mpc", "odd_servo_states", "turning_mpc"]


def make_state(machine: Machine, q=None, qd=None, qdd=None, time: float = 0.0,
               base_twist=None, contacts=None) -> MachineState:
    """A state at the origin, level, with the given independent coordinates (home if None)."""
    q = machine.coordinates.home() if q is None else np.asarray(q, float)
    z = np.zeros(N_INDEPENDENT)
    return MachineState(
        base_position=np.array([0.0, 0.0, 0.45]), base_rotation=np.eye(3),
        base_twist=np.zeros(6) if base_twist is None else np.asarray(base_twist, float),
        base_acceleration=np.zeros(6), q=q, qd=z.copy() if qd is None else qd,
        qdd=z.copy() if qdd is None else qdd, time=time, contacts=contacts)


class KinematicPlant:
    """Axes that follow rate commands (first-order servo), integrated at ``dt``.

    Args:
        state: Initial state.
        dt: Integration step [s].
        servo_time_constant: Lag of the rate servos [s] (0: ideal).
    """

    def __init__(self, state: MachineState, dt: float, servo_time_constant: float = 0.0):
        self.state = state
        self.dt = float(dt)
        self.tau = float(servo_time_constant)

    def measure(self) -> MachineState:
        """The current state."""
        return self.state

    def apply(self, command: ControlCommand) -> MachineState:
        """Advance one step with ``command``; returns the new state."""
        st, dt = self.state, self.dt
        qd = st.qd.copy()
        v0 = qd[:N_AXES]
        if self.tau > 0:
            v1 = v0 + (command.rates - v0) * (1.0 - np.exp(-dt / self.tau))
        else:
            v1 = command.rates.copy()
        q = st.q.copy()
        q[:N_AXES] += 0.5 * (v0 + v1) * dt
        q[N_AXES:] += qd[N_AXES:] * dt
        qdd = np.zeros(N_INDEPENDENT)
        qdd[:N_AXES] = (v1 - v0) / dt
        qd[:N_AXES] = v1
        self.state = MachineState(st.base_position, st.base_rotation, st.base_twist,
                                  st.base_acceleration, q, qd, qdd, st.time + dt, st.contacts,
                                  st.suspension_force)
        return self.state


def moving_mpc(machine: Machine, ticks: int = 4, dt: float = 0.01):
    """``(ctrl, plant)``: mpc-full with the estimator's feedback, ``ticks`` into a crane move.

    The goal moves every crane axis by 0.1; after a few ticks the nominal inputs are nonzero,
    so the horizon's rows are those of a moving machine.
    """
    from wbc import ControllerConfig, JointGoal, MpcController
    from wbc.controllers.registry import estimator_models

    model, feedback = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=feedback)
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1))
    plant = KinematicPlant(st, dt)
    for _ in range(ticks):
        plant.apply(ctrl.step(plant.state))
    return ctrl, plant


def turning_mpc(machine: Machine, speed_scale: bool, ticks: int = 5, dt: float = 0.01):
    """``(ctrl, states)``: mpc-full with the estimator, driving and turning, a crane move.

    The base drives at 0.4 m/s, turns at 0.15 rad/s and rolls and pitches slowly, the
    wheels spin at 1.5 rad/s, and the goal moves the crane and the suspension a little:
    every block of the horizon's force rows (drive terms, speed scale) is nonzero.
    ``states``: the plant's state after each of the ``ticks`` ticks. Skips the calling test
    (`pytest.skip`) where the estimator is not compiled.
    """
    import dataclasses

    import pytest

    from wbc import ControllerConfig, ForceConfig, JointGoal, MpcConfig, MpcController
    from wbc.axes import SUSPENSION_AXES
    from wbc.controllers.registry import estimator_models

    model, feedback = estimator_models(machine, "full")
    if not hasattr(model, "linearize_rows") or model._est.backend != "compiled":
        pytest.skip("no compiled estimator")
    cfg = ControllerConfig(force=ForceConfig(speed_scale=speed_scale), mpc=MpcConfig())
    ctrl = MpcController(machine, cfg, force_model=model, feedback=feedback)
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + np.array([0.05, -0.05, 0.05, 0.2, 0, 0, 0]),
                            suspension=st.q[SUSPENSION_AXES] + 0.02))
    plant = KinematicPlant(dataclasses.replace(
        st, qd=np.r_[st.qd[:9], np.full(4, 1.5)],
        base_twist=np.array([0.4, 0.05, 0.0, 0.02, -0.03, 0.15])), dt)
    states = []
    for _ in range(ticks):
        plant.apply(ctrl.step(plant.state))
        states.append(plant.state)
    return ctrl, states


def odd_servo_states(machine: Machine, rng: np.random.Generator, n: int, reset_every: int,
                     dt: float):
    """Yield ``(reset, state)`` ``n`` times: the servo state's odd ticks.

    Time steps of ``dt``, 0, -0.02 and 0.3 s; axis positions scattered by 0.02 around the
    home pose; on three ticks of four a measured setpoint at, near (2 mm) or far (5 cm)
    from the positions, else none. ``reset``: the caller resets its servo states first
    (every ``reset_every``-th tick). The generator draws from ``rng`` between the caller's
    own draws, in the order of the loop it replaces.
    """
    import dataclasses

    base = make_state(machine)
    t = 0.0
    for k in range(n):
        reset = k % reset_every == reset_every - 1
        t += float(rng.choice([dt, dt, 0.0, -0.02, 0.3]))
        q = base.q.copy()
        q[:N_AXES] += rng.normal(0.0, 0.02, N_AXES)
        state = make_state(machine, q=q, time=t)
        if k % 4:
            near = q[:N_AXES] + rng.choice([0.0, 2e-3, -2e-3, 0.05, -0.0], N_AXES)
            state = dataclasses.replace(state, servo_setpoint=near)
        yield reset, state
