"""The readings' servo setpoints as the compiled delivery copies them (`scenarios.listeners_c`).

`DELIVER_C`'s fill copies the simulator's setpoints into the reading's array where they are a
contiguous (9,) float64 array and checks them finite; anything else goes through
`models.state.frozen_array` (its copy, its error), as the Python path does.
"""

import numpy as np
import pytest

from models.errors import StateError
from models.sensor_suites import sensor_suite
from scenarios.listeners_c import compiled_delivery
from scenarios.sensors import SensorSimulator

pytestmark = pytest.mark.skipif(compiled_delivery() is None, reason="no C compiler")


@pytest.fixture()
def sensors(rough):
    s = SensorSimulator(rough, sensor_suite("realistic", 5))
    yield s
    s.close()


def _with_setpoint(sim, monkeypatch, setpoint):
    qpos, qvel, t, _ = sim.measured_arrays()
    monkeypatch.setattr(sim, "measured_arrays", lambda: (qpos, qvel, t, setpoint))


def test_setpoint_is_the_simulators_read_only_and_not_shared(sensors, rough):
    rough.step(5)
    r = sensors.readings(rough.time)
    own = rough.measured_arrays()[3]
    assert r.servo_setpoint.tobytes() == own.tobytes()
    assert not r.servo_setpoint.flags.writeable
    assert not np.shares_memory(r.servo_setpoint, own)


def test_strided_and_short_setpoints_take_frozen_array(sensors, rough, monkeypatch):
    rough.step(5)
    wide = np.arange(18.0)
    _with_setpoint(rough, monkeypatch, wide[::2])  # strided: the C would read it wrongly
    r = sensors.readings(rough.time)
    assert r.servo_setpoint.tolist() == wide[::2].tolist()
    assert not r.servo_setpoint.flags.writeable
    _with_setpoint(rough, monkeypatch, np.zeros(8))
    with pytest.raises(StateError, match="servo_setpoint"):
        sensors.readings(rough.time)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_setpoint_raises_as_frozen_array(sensors, rough, monkeypatch, bad):
    for i in (0, 8):
        setpoint = np.zeros(9)
        setpoint[i] = bad
        _with_setpoint(rough, monkeypatch, setpoint)
        with pytest.raises(StateError, match="servo_setpoint"):
            sensors.readings(rough.time)
