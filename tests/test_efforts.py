"""Actuator efforts: the tree's dynamics mapped through the chains, against MuJoCo's servos."""

import dataclasses

import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts, effort_ranges
from estimators.efforts_kernel import EffortKernels
from estimators.errors import EstimatorError
from models import build_reference_machine
from models import terrain as T
from scenarios.simulator import Simulator

MACHINE = build_reference_machine()
CRANE = {"slew": 2, "lift": 3, "tilt": 4, "telescope": 5}


@pytest.fixture(scope="module")
def moving_samples():
    sim = Simulator(MACHINE, T.flat())
    sim.reset()
    sim.set_command(cylinder_rates={"slew": 0.12, "lift": 0.06, "tilt": -0.05,
                                    "telescope": 0.1})
    out = []
    for k in range(60):
        sim.step(5)
        if k >= 20 and k % 5 == 0:
            out.append((sim.measure()[0], sim.actuator_forces()))
    return out


def test_efforts_match_mujoco_servo_forces_while_the_crane_moves(moving_samples):
    eff = ActuatorEfforts(MACHINE)
    lo, hi = effort_ranges(MACHINE)
    for state, mujoco_forces in moving_samples:
        e = eff.efforts(state)
        for name, i in CRANE.items():
            # MuJoCo's servo force also overcomes the seals' friction (the mechanism gets
            # the rest): known while the cylinder slides, any value up to F_c at rest.
            seal = MACHINE.chains[name].cylinder.seal_friction if name in MACHINE.chains \
                else 0.0
            if abs(state.qd[i]) < 2e-3 and seal:
                continue
            mujoco_mechanism = mujoco_forces[i] - np.sign(state.qd[i]) * seal
            # Within 1 % of the cylinder's force range. The slew's four-bar is closed by a
            # soft constraint that lags its stroke's acceleration by a few ms: while it
            # accelerates hard (> 0.1 m/s^2 of stroke) within 10 %.
            tol = 0.1 if name == "slew" and abs(state.qdd[i]) > 0.1 else 0.01
            assert e[i] == pytest.approx(mujoco_mechanism, abs=tol * hi[i]), name


def test_affine_in_the_axis_accelerations_and_in_the_payload(moving_samples):
    state = moving_samples[-1][0]
    eff = ActuatorEfforts(MACHINE)
    E, e0 = eff.affine(state)
    u = np.random.default_rng(0).normal(size=9)
    qdd = state.qdd.copy()
    qdd[:9] = u
    np.testing.assert_allclose(eff.efforts(dataclasses.replace(state, qdd=qdd)), E @ u + e0,
                               rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(E, E.T, atol=1e-6 * np.abs(E).max())
    heavy = ActuatorEfforts(build_reference_machine(payload_mass=300.0))
    eff.payload_mass = 300.0
    np.testing.assert_allclose(eff.efforts(state), heavy.efforts(state), rtol=1e-9, atol=1e-6)


def test_bad_payload_and_state():
    with pytest.raises(EstimatorError, match="payload_mass"):
        ActuatorEfforts(MACHINE, payload_mass=-1.0)
    with pytest.raises(EstimatorError, match="MachineState"):
        ActuatorEfforts(MACHINE).affine("state")


def test_efforts_of_one_machine_share_the_last_motion(moving_samples, monkeypatch):
    """The observer's and the MPC's `ActuatorEfforts` evaluate the same motion once a tick:
    a second instance (another payload mass) reads the first one's pair results, bit for
    bit what it would compute; any other motion (here the wheels' accelerations) is
    computed again."""
    state = moving_samples[-1][0]
    first = ActuatorEfforts(MACHINE)
    fresh = ActuatorEfforts(MACHINE, payload_mass=180.0)
    fresh._shared[:] = [None, None, None]
    expected = fresh.affine(state)  # computed
    first.affine(moving_samples[0][0])  # another motion in between
    first.affine(state)
    second = ActuatorEfforts(MACHINE, payload_mass=180.0)
    for cls, name in ((ActuatorEfforts, "_tree_motion"), (EffortKernels, "efforts")):
        monkeypatch.setattr(cls, name, lambda self, s: pytest.fail("recomputed a shared motion"))
    qdd = state.qdd.copy()
    qdd[:9] += 1.0  # the axes' accelerations are affine's free u: the same motion
    E, e0 = second.affine(dataclasses.replace(state, qdd=qdd))
    assert np.array_equal(E, expected[0]) and np.array_equal(e0, expected[1])
    monkeypatch.undo()
    qdd[9:] += 0.5  # the wheels' accelerations enter e_0: another motion
    assert not np.array_equal(second.affine(dataclasses.replace(state, qdd=qdd))[1], e0)
