"""The step listeners in C (`scenarios.listeners_c`) against their Python paths, to the bit."""

import dataclasses

import numpy as np
import pytest

from models.sensor_suites import sensor_suite
from scenarios.listeners_c import compiled_delivery, compiled_forces, compiled_sensors
from scenarios.physics_rate import NormalForceRecorder
from scenarios.sensors import SensorSimulator

pytestmark = pytest.mark.skipif(
    compiled_sensors() is None or compiled_delivery() is None or compiled_forces() is None,
    reason="no C compiler")


def _fields(r) -> dict:
    out = {"time": np.array([r.time])}
    for f in dataclasses.fields(r):
        v = getattr(r, f.name)
        if hasattr(v, "value"):
            out[f.name + ".time"], out[f.name + ".value"] = v.time, v.value
        elif isinstance(v, np.ndarray):
            out[f.name] = v
    return out


def test_compiled_sensors_deliver_the_python_readings_to_the_bit(rough):
    """Every stream (IMU, links, strokes, pressures, wheels, drives), with bias walk, noise,
    quantization and latency; a long gap between readings grows the buffers."""
    spec = sensor_suite("realistic", 3)
    fast, slow = SensorSimulator(rough, spec), SensorSimulator(rough, spec, compiled=False)
    assert fast._compiled is not None and fast._delivery is not None
    assert slow._compiled is None and slow._delivery is None
    try:
        rough.set_command(cylinder_rates={"slew": 0.3, "lift": -0.05}, wheel_speeds=(1.5, 1.0))
        for steps in [5] * 30 + [700] + [5] * 10 + [3, 7, 1]:
            rough.step(steps)
            r = fast.readings(rough.time)
            dataclasses.replace(r)  # the trusted constructors' readings pass the checks
            a, b = _fields(r), _fields(slow.readings(rough.time))
            assert a.keys() == b.keys()
            for key in a:
                assert a[key].tobytes() == b[key].tobytes(), key
                assert key == "time" or not a[key].flags.writeable, key
        assert len(fast.readings(rough.time).link_specific_force) == 0  # delivered once
    finally:
        fast.close()
        slow.close()
    assert fast._acc.times.shape[0] > 256  # the long gap grew the compiled path's buffers


def test_compiled_recorder_gives_the_python_sums_to_the_bit(rough):
    fast, slow = NormalForceRecorder(rough), NormalForceRecorder(rough, compiled=False)
    assert fast._record is not None and slow._record is None
    try:
        rough.set_command(cylinder_rates={"slew": -0.3}, wheel_speeds=(1.5, 1.5))
        rough.step(300)
    finally:
        fast.close()
        slow.close()
    assert len(fast) == 300
    assert fast.normal_force.tobytes() == slow.normal_force.tobytes()
    assert fast.time.tobytes() == slow.time.tobytes()
