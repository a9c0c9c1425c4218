"""The log's ground-truth rows in C (`scenarios.truth_c`) against the Python path, to the bit."""

import numpy as np
import pytest

import scenarios.truth_c as truth_c
import scenarios.truth_log as truth_log
from models import build_reference_machine
from models.log import COLUMNS, LogError, ScenarioLog
from scenarios.closed_loop import run_closed_loop
from scenarios.closed_loop_scenarios import SCENARIOS, scenario_terrain
from scenarios.simulator import Simulator
from scenarios.truth_c import compiled_truth
from scenarios.truth_log import TRUTH_COLUMNS, TruthColumns

compiled = pytest.mark.skipif(compiled_truth() is None,
                              reason="no C compiler, or numpy's orders differ from TRUTH_C's")


def _drive(name: str, rows: int):
    """Two `TruthColumns` of one simulator, a row each a tick: rough ground, the crane
    moving, driving straight, then turning on the spot (three contacts on a wheel), then
    the bogies moving too (wheels off the ground): the rows the C hands to Python."""
    sc = SCENARIOS[name]
    machine = build_reference_machine(payload_mass=sc.payload_mass)
    sim = Simulator(machine, scenario_terrain(sc, 0))
    sim.reset(sc.start_pose.q(machine), sc.start)
    fast, slow = TruthColumns(sim, rows), TruthColumns(sim, rows, compiled=False)
    rng = np.random.default_rng(3)
    wheel_of_geom = np.full(sim.model.ngeom, -1)
    wheel_of_geom[sim.index.wheel_geoms] = np.arange(4)
    codes, crowded, true_q = [], [], []
    for k in range(rows):
        if k % 20 == 0:
            r = rng.uniform(-0.08, 0.08, 9)
            r[:2] *= k >= rows // 2
            wheels = ((1.5, 1.5) if k < rows // 4 else (-1.5, 1.5) if k < rows // 2
                      else rng.uniform(-2, 2, 2) if k % 60 else (0.0, 0.0))
            sim.set_command(cylinder_rates=r[:6], wrist_rates=r[6:], wheel_speeds=wheels)
        sim.step(5)
        fun, fixed = fast._row
        qpos, qvel, t = sim.measured_instant
        setpoint = sim.servo_setpoint
        codes.append(fun(*fixed, k, qpos.ctypes.data, qvel.ctypes.data, t,
                         setpoint.ctypes.data))
        con = sim.data.contact
        wheel = np.maximum(wheel_of_geom[con.geom[:, 0]], wheel_of_geom[con.geom[:, 1]])
        crowded.append(np.bincount(wheel[(wheel >= 0) & (con.efc_address >= 0)],
                                   minlength=4).max() > 2)
        fast.record(k)
        slow.record(k)
        true_q.append((fast.true_q.copy(), slow.true_q.copy()))
    return fast, slow, np.array(codes), np.array(crowded), true_q


@compiled
@pytest.mark.parametrize("name", ["swing-out", "pick-in-motion"])
def test_compiled_rows_are_the_python_rows_to_the_bit(name):
    fast, slow, codes, crowded, true_q = _drive(name, 500)
    assert 100 < np.sum(codes == 0) < 500  # both paths wrote rows
    crowded &= slow.columns["in_contact"].all(axis=1)  # not also a wheel off the ground
    assert (codes[crowded] == -1).all()  # three contacts on a wheel: Python's sums
    assert crowded.any() or name != "pick-in-motion"  # turning on its bumps makes them
    for column in TRUTH_COLUMNS:
        a, b = fast.columns[column], slow.columns[column]
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), column
    assert all(a.tobytes() == b.tobytes() for a, b in true_q)


@compiled
def test_a_closed_loop_logs_the_same_bits_with_and_without_the_c_rows(tmp_path, monkeypatch):
    runs = []
    for c in (True, False):
        if not c:
            monkeypatch.setattr(truth_log, "compiled_truth", lambda: None)
        run_closed_loop("swing-out", tmp_path / str(c), "tracking", duration=1.5,
                        sensors="oracle")
        with np.load(tmp_path / str(c) / "log.npz") as f:
            runs.append({k: f[k] for k in f.files if k != "step_ms" and k != "observer_ms"})
    assert list(runs[0]) == list(runs[1])
    for key in runs[0]:
        assert runs[0][key].tobytes() == runs[1][key].tobytes(), key


def test_the_c_rows_are_used_only_where_this_hosts_numpy_agrees():
    """The C rows are handed out exactly where the probe finds numpy's three-term products
    summed as `TRUTH_C` sums them; where numpy's BLAS or einsum sums in another order the
    runs take the Python path (the same log), which this skip reports."""
    if truth_c._library() is None:
        pytest.skip("no C compiler")
    agree = truth_c.numpy_orders_agree()
    assert (compiled_truth() is not None) == agree
    if not agree:
        pytest.skip("this host's numpy sums the three-term products in another order than "
                    "TRUTH_C: the runs write their truth rows in Python")


def test_the_truth_columns_are_log_columns():
    assert set(TRUTH_COLUMNS) <= set(COLUMNS)


def test_set_columns_refuses_unknown_names_and_ragged_lengths():
    log = ScenarioLog(scenario="x")
    with pytest.raises(LogError, match="unknown log column"):
        log.set_columns(speed=np.zeros(3))
    log.set_columns(time=np.arange(3.0), tcp_error=np.zeros(3))
    assert len(log) == 3
    with pytest.raises(LogError, match="different lengths"):
        log.set_columns(distance=np.zeros(4))
    arrays = log.arrays()
    assert arrays["time"].tolist() == [0.0, 1.0, 2.0] and "meta_scenario" in arrays
