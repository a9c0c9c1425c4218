"""The tracking controller's compiled tick (`wbc.controllers.tracking_c`) = the builder's bits.

Two controllers see the same states, one with the compiled tick and one with
``compiled = False`` (the generic path: `QPContext`, the tasks, the constraints,
`wbc.qp.QPBuilder`); every QP they hand the solver and every command must be the same bits
(``tobytes``: a -0.0 for a +0.0 fails).
"""

import numpy as np
import pytest

from models.coordinates import N_INDEPENDENT
from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    ControllerConfig,
    JointGoal,
    QPConfig,
    ReferenceConfig,
    TcpGoal,
    WbcInputError,
    WholeBodyQPController,
    make_controller,
)
from wbc.controllers import tracking_c

DT = 0.01
# Other gains, weights, time constants, horizon and period than the defaults (none a power
# of two: a product or quotient reassociated shows in the bits).
OTHER = ControllerConfig(dt=0.012, reference=ReferenceConfig(jerk_time=0.3,
                                                             governor_error=0.03),
                         qp=QPConfig(crane_kp=13.3, crane_kd=7.1, crane_weight=1.7,
                                     suspension_kp=3.3, suspension_kd=2.9,
                                     suspension_weight=0.13, damping_weight=3e-3,
                                     damping_time=0.37, position_horizon=0.07,
                                     braking_fraction=0.63))


pytestmark = pytest.mark.skipif(tracking_c.tracking_library() is None,
                                reason="no C compiler")


def _recorded(ctrl) -> list:
    """The problems ``ctrl`` hands its solver, as bytes, one tuple per solve."""
    problems, solve = [], ctrl.solver.solve

    def spy(problem):
        problems.append(tuple(None if a is None else np.asarray(a, float).tobytes()
                              for a in (problem.P, problem.q, problem.G, problem.h,
                                        problem.lb, problem.ub)))
        return solve(problem)

    ctrl.solver.solve = spy
    return problems


def _command_bits(cmd) -> bytes:
    extra = [cmd.info.get(k, ()) for k in ("predicted_forces", "slack")]
    return b"".join(np.asarray(a, float).tobytes() for a in (
        cmd.rates, cmd.accelerations, [cmd.wheel_speed_scale], *extra))


class _Pair:
    """A compiled controller and the generic one, stepped on the same states."""

    def __init__(self, make):
        self.fast, self.slow = make(), make()
        self.slow.compiled = False
        assert self.fast._tick is not None
        self.problems = _recorded(self.fast), _recorded(self.slow)
        self.compiled_ticks = 0
        compiled_qp = self.fast._compiled_qp

        def counted(state):
            qp = compiled_qp(state)
            self.compiled_ticks += qp is not None
            return qp

        self.fast._compiled_qp = counted

    def set_goal(self, goal):
        self.fast.set_goal(goal)
        self.slow.set_goal(goal)

    def step(self, state):
        a, b = self.fast.step(state), self.slow.step(state)
        assert _command_bits(a) == _command_bits(b)
        assert a.fallback == b.fallback
        fast, slow = self.problems[0][-1], self.problems[1][-1]
        assert fast == slow, [i for i, (x, y) in enumerate(zip(fast, slow)) if x != y]
        return a


def _goal(st, crane=(0.12, 0.14, 0.0, 0.45, 0.0, 0.0, 0.0), suspension=0.03):
    return JointGoal(crane=st.q[2:9] + np.asarray(crane),
                     suspension=None if suspension is None else st.q[:2] + suspension)


def _count_numpy_governor(ctrl) -> list:
    """Counts the governor's numpy errors (`RuckigReference.position`) of ``ctrl``."""
    calls = [0]
    for ref in (ctrl.crane_reference, ctrl.suspension_reference):
        position = ref.position

        def counted(t, position=position):
            calls[0] += 1
            return position(t)

        ref.position = counted
    return calls


@pytest.mark.parametrize("config", [None, OTHER])
def test_closed_loop_ticks_are_the_builders_bits(machine, config):
    """Goals, a slowed clock, a held suspension, a reset, and callers between the ticks."""
    pair = _Pair(lambda: make_controller("tracking", machine, config))
    numpy_governor = _count_numpy_governor(pair.fast)
    st = make_state(machine)
    pair.set_goal(_goal(st))
    plant = KinematicPlant(st, pair.fast.dt, servo_time_constant=0.02)
    for k in range(700):
        if k == 150:  # a new crane goal while moving; the suspension keeps its plan
            pair.set_goal(_goal(st, (-0.1, -0.05, 0.1, 0.1, 0.3, -0.4, 0.5), None))
        if k == 220:  # a TCP goal, resolved in the next tick (the state checked again)
            p0 = pair.fast.tcp_kinematics.position(plant.state.q)
            pair.set_goal(TcpGoal(p0 + np.array([0.3, -0.2, 0.2])))
        if k in (260, 262):  # the generic path for two ticks, then C again
            pair.fast.compiled = not pair.fast.compiled
        if k == 300:
            for c in (pair.fast, pair.slow):
                c.reset()
            pair.set_goal(_goal(st, (0.2, 0.0, 0.0, -0.2, 0.0, 0.0, 0.0), None))  # held
        if 400 <= k < 420:
            for c in (pair.fast, pair.slow):
                c._clock["crane"][1] = 0.6  # a slowed reference clock
        if k in (450, 451, 500):  # readers between ticks (they keep other positions)
            for c in (pair.fast, pair.slow):
                c.build_qp(plant.state)
                c.reference_ahead(0.013)
        plant.apply(pair.step(plant.state))
    assert pair.compiled_ticks >= 695
    assert numpy_governor[0] < 20  # the governor's errors came from C


@pytest.mark.parametrize("config", [None, OTHER])
def test_random_states_at_and_past_the_limits_are_the_builders_bits(machine, config):
    """States inside, at and past the ends, faster than the flow limits, one after another."""
    pair = _Pair(lambda: make_controller("tracking", machine, config))
    rng = np.random.default_rng(5)
    lo, hi = machine.coordinates.lower, machine.coordinates.upper
    lim = pair.fast.limits
    st = make_state(machine)
    pair.set_goal(_goal(st, suspension=-0.02))
    for k in range(400):
        span = hi[:9] - lo[:9]
        q, qd = st.q.copy(), np.zeros(N_INDEPENDENT)
        q[:9] = lo[:9] + span * rng.uniform(-0.05, 1.05, 9)
        if k % 5 == 0:  # exactly at an end, at rest or moving
            q[:9] = np.where(rng.random(9) < 0.5, lo[:9], hi[:9])
        qd[:9] = rng.normal(0.0, 1.0, 9) * np.abs(lim.velocity_upper) * (k % 7 != 0)
        if k % 11 == 0:
            qd[:9] = np.where(rng.random(9) < 0.5, lim.velocity_lower, lim.velocity_upper)
        pair.step(make_state(machine, q=q, qd=qd, time=k * DT))
    assert pair.compiled_ticks >= 390


def test_force_model_ticks_are_the_builders_bits(machine):
    """With the force rows, the speed scale and the slacks (their terms from a builder)."""
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    pair = _Pair(lambda: WholeBodyQPController(machine, force_model=model))
    pair.set_goal(_goal(st))
    plant = KinematicPlant(st, DT, servo_time_constant=0.02)
    for _ in range(300):
        plant.apply(pair.step(plant.state))
    assert pair.compiled_ticks >= 290


def test_an_overflowing_state_is_refused_as_before(machine):
    ctrl = make_controller("tracking", machine)
    assert ctrl._tick is not None
    ctrl.step(make_state(machine))
    for value in (2e6, -3e7):
        qd = np.zeros(N_INDEPENDENT)
        qd[4] = value
        with pytest.raises(WbcInputError, match=r"state.qd has an entry of magnitude"):
            ctrl.step(make_state(machine, qd=qd))
    with pytest.raises(WbcInputError, match="state.time"):
        ctrl.step(make_state(machine, time=2e9))
    ctrl.step(make_state(machine, time=0.01))  # and goes on


def test_without_a_compiler_the_builder_runs(machine, monkeypatch):
    """No library: no compiled tick, the same commands."""
    fast = make_controller("tracking", machine)
    monkeypatch.setattr(tracking_c, "tracking_library", lambda: None)
    slow = make_controller("tracking", machine)
    assert slow._tick is None and fast._tick is not None
    st = make_state(machine)
    for c in (fast, slow):
        c.set_goal(_goal(st))
    plant = KinematicPlant(st, DT)
    for _ in range(50):
        a, b = fast.step(plant.state), slow.step(plant.state)
        assert _command_bits(a) == _command_bits(b)
        plant.apply(a)


def test_other_tasks_get_no_compiled_tick(machine):
    """Only the tasks and constraints the C computes (and the force's) are compiled."""
    ctrl = make_controller("tracking", machine)
    refs = [ctrl.crane_reference, ctrl.suspension_reference]
    args = (refs, ctrl.limits, ctrl.dt, ctrl.layout, 1e6)
    assert tracking_c.compiled_tracking_qp(ctrl.tasks, ctrl.constraints, *args) is not None
    swapped = (ctrl.tasks[1], ctrl.tasks[0], ctrl.tasks[2])
    assert tracking_c.compiled_tracking_qp(swapped, ctrl.constraints, *args) is None
    assert tracking_c.compiled_tracking_qp(ctrl.tasks[:2], ctrl.constraints, *args) is None
    assert tracking_c.compiled_tracking_qp(ctrl.tasks, ctrl.constraints[::-1], *args) is None
    assert tracking_c.compiled_tracking_qp(ctrl.tasks, ctrl.constraints, refs[:1],
                                           *args[1:]) is None
