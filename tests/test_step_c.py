"""The simulator's steps in C (`scenarios.step_c`) against its Python steps, to the bit."""

import numpy as np
import pytest

from models import build_reference_machine
from models.sensor_suites import sensor_suite
from scenarios.closed_loop_scenarios import SCENARIOS, scenario_terrain
from scenarios.errors import SimulationError
from scenarios.physics_rate import NormalForceRecorder
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator
from scenarios.step_c import _library

pytestmark = pytest.mark.skipif(_library() is None, reason="no C compiler")

SC = SCENARIOS["swing-out"]
MACHINE = build_reference_machine(payload_mass=SC.payload_mass)


def _sim(compiled: bool) -> Simulator:
    sim = Simulator(MACHINE, scenario_terrain(SC, 0), compiled=compiled)
    sim.reset(SC.start_pose.q(MACHINE), SC.start, settle_time=0.2)
    return sim


def _drive(sim: Simulator, sensors=None) -> list:
    """Rough ground, the crane moving, the wheels driven and braked (held), odd step counts,
    a long gap that grows the listeners' buffers; what each step call leaves behind."""
    out, rng = [], np.random.default_rng(7)
    for i, steps in enumerate([5] * 30 + [700] + [5] * 10 + [3, 7, 1, 12, 2]):
        rates = rng.uniform(-0.05, 0.05, 9)  # every bit of the setpoint path used
        rates[2] = 0.3 * np.sign(rates[2])
        sim.set_command(cylinder_rates=rates[:6], wrist_rates=rates[6:],
                        wheel_speeds=(0.0, 0.0) if i % 9 < 3 else (1.5, 1.0))
        sim.step(steps)
        qpos, qvel, t = sim.measured_instant
        state, contacts = sim.measure()
        out += [np.array(a, copy=True) for a in (
            sim.data.qpos, sim.data.qvel, sim.data.ctrl, sim.data.efc_force[:sim.data.nefc],
            qpos, qvel, [t, sim.time], sim.servo_setpoint, sim._setpoint, state.qdd,
            contacts.force_in_fb)]
        if sensors is not None:
            r = sensors.readings(sim.time)
            out += [s.time for s in (r.specific_force, r.wheel_speeds)] + [
                s.value for s in (r.specific_force, r.angular_rate, r.positions, r.pressures,
                                  r.wheel_speeds, r.drive_torques, r.link_specific_force)]
    return out


def test_compiled_steps_are_the_python_steps_to_the_bit():
    """With the sensors and the force recorder as listeners (their C hooks), and without."""
    runs = []
    for compiled in (True, False):
        sim = _sim(compiled)
        sensors = SensorSimulator(sim, sensor_suite("realistic", 3))
        recorder = NormalForceRecorder(sim)
        assert (sim._c_step is not None) == compiled
        runs.append(_drive(sim, sensors) + [recorder.normal_force, recorder.time])
        bare = _sim(compiled)
        assert (bare._c_step is not None) == compiled
        runs[-1] += _drive(bare)
    fast, slow = runs
    assert len(fast) == len(slow)
    for k, (a, b) in enumerate(zip(fast, slow)):
        assert a.shape == b.shape and a.tobytes() == b.tobytes(), k


def test_a_python_listener_sends_the_steps_back_to_python():
    sim = _sim(True)
    assert sim._c_step is not None
    seen = []

    def listener(s, qpos, qvel, t):
        seen.append(t)

    sim.add_step_listener(listener)
    assert sim._c_step is None
    sim.step(3)
    assert len(seen) == 3
    sim.remove_step_listener(listener)
    assert sim._c_step is not None


@pytest.mark.parametrize("compiled", [True, False])
def test_a_diverged_simulation_raises_in_either_path(compiled, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning to MUJOCO_LOG.TXT here
    sim = _sim(compiled)
    assert (sim._c_step is not None) == compiled
    sim.data.qvel[0] = 1e11  # beyond MuJoCo's bound: its BADQVEL warning
    with pytest.raises(SimulationError, match="BADQVEL"):
        sim.step(5)
