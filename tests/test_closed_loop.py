"""Closed-loop scenario regression: short versions of the three scenarios in MuJoCo.

For each scenario the tracking-only controller and the full-dynamics MPC run on the same
terrain and seed. Asserted: the MPC keeps every wheel's ground-truth normal force above the
threshold (minus `TOLERANCE`) after the settling second, completes the task, and never
falls back; the tracking controller breaks that bound on the same terrain; nothing is NaN.
About 30 s of simulated MPC time in all (~20 s wall on the 2-core dev machine).
"""

import dataclasses
import json

import numpy as np
import pytest

from models import WHEEL_ORDER
from models.log import SETTLE_SECONDS, load_log
from scenarios.closed_loop import run_closed_loop
from scenarios.closed_loop_scenarios import SCENARIOS, TASK_TOLERANCE, threshold
from wbc_hdmm.cli import main

# [N] below the threshold the MPC may go: MuJoCo's contact flickers for one step when a
# lightly loaded wheel's penetration passes zero (measured at ~2.7 kN on a sliding wheel).
TOLERANCE = 200.0

SHORT = {
    "swing-out": dict(duration=7.0, drive_distance=2.0),
    "pick-place-slope": dict(duration=11.0),
    "pick-in-motion": dict(duration=9.0, drive_distance=2.0),
}

REQUIRED = ("min_normal_force_N", "time_below_threshold_s", "tipped", "task_error_final",
            "task_completion_time_s", "control_step_ms", "fallbacks", "sim_seconds",
            "wall_seconds", "real_time_factor", "threshold_N")


def _short(name):
    return dataclasses.replace(SCENARIOS[name], **SHORT[name])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Both controllers on every short scenario (run once for the module)."""
    out = {}
    for name in SHORT:
        for ctrl in ("tracking", "mpc-full"):
            d = tmp_path_factory.mktemp(f"{name}-{ctrl}")
            out[name, ctrl] = (run_closed_loop(_short(name), d, ctrl, seed=0), load_log(d))
    return out


@pytest.mark.parametrize("name", list(SHORT))
def test_mpc_keeps_every_wheel_loaded_and_completes_the_task(runs, name):
    m, log = runs[name, "mpc-full"]
    thr = threshold()
    keep = log["time"] >= SETTLE_SECONDS
    f = log["normal_force"][keep]
    assert np.all(np.isfinite(log["normal_force"])) and np.all(np.isfinite(log["command"]))
    assert f.min() >= thr - TOLERANCE, f"min force {f.min(axis=0)} N, threshold {thr:.0f} N"
    assert not m["tipped"]
    assert m["fallbacks"] == 0
    assert m["task_completed"], m["task_error_final"]
    assert m["task_error_final"] < TASK_TOLERANCE


@pytest.mark.parametrize("name", list(SHORT))
def test_tracking_controller_breaks_the_bound_on_the_same_terrain(runs, name):
    m, log = runs[name, "tracking"]
    m_mpc, log_mpc = runs[name, "mpc-full"]
    assert m["terrain"] == m_mpc["terrain"] and m["seed"] == m_mpc["seed"]
    keep = log["time"] >= SETTLE_SECONDS
    assert np.all(np.isfinite(log["normal_force"]))
    assert log["normal_force"][keep].min() < threshold() - TOLERANCE
    assert m["tipped"] or sum(m["time_below_threshold_s"].values()) > 0.5


def test_metrics_have_the_documented_keys(runs):
    m, log = runs["swing-out", "mpc-full"]
    for key in REQUIRED:
        assert key in m, key
    for key in ("min_normal_force_N", "time_below_threshold_s"):
        assert set(m[key]) == set(WHEEL_ORDER)
    assert set(m["control_step_ms"]) >= {"median", "p99"}
    assert m["threshold_N"] == pytest.approx(threshold())
    # The scenario's clock starts when the machine is ready (scenarios.startup).
    assert m["time_to_ready_s"] >= SETTLE_SECONDS and not m["ready_timed_out"]
    offset = m["time_to_ready_s"] - SETTLE_SECONDS
    assert m["sim_seconds"] == pytest.approx(SHORT["swing-out"]["duration"] + offset,
                                             abs=0.011)
    n = log["time"].size
    assert log["normal_force"].shape == (n, 4) and log["command"].shape == (n, 11)
    # The MPC drove the base (the scripted speeds, scaled by at most its own choice).
    assert m["drive_distance_m"] >= SHORT["swing-out"]["drive_distance"]


def test_payload_event_changes_mujoco_and_the_mpc_model(runs):
    m, log = runs["pick-in-motion", "mpc-full"]
    t_pick, mass = SCENARIOS["pick-in-motion"].payload_event
    t_pick += m["time_to_ready_s"] - SETTLE_SECONDS  # on the scenario's clock
    after = log["time"] >= t_pick - 1e-9
    assert np.all(log["payload_now"][after] == mass)
    assert np.all(log["payload_now"][~after] == SCENARIOS["pick-in-motion"].payload_mass)
    # The ground truth feels the log: the total normal load rises by its weight.
    total = log["normal_force"].sum(axis=1)
    gain = total[log["time"] > t_pick + 3.0].mean() - total[log["time"] < t_pick - 0.5].mean()
    assert gain == pytest.approx((mass - 10.0) * 9.81, rel=0.1)


def test_wbc_run_closed_loop_requires_a_controller_and_defaults_to_mpc_full(tmp_path,
                                                                           capsys):
    out = tmp_path / "run"
    assert main(["run", "swing-out", "--out", str(out), "--duration", "1.1",
                 "--no-progress"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["controller"] == "mpc-full" and m["partial"] is False
    capsys.readouterr()
    assert main(["run", "swing-out", "--controller", "open-loop", "--out",
                 str(tmp_path / "b"), "--duration", "1.1", "--no-progress"]) == 2
    assert "'tracking', 'mpc-quasi-static', 'mpc-full'" in capsys.readouterr().err
    assert main(["run", "flat", "--controller", "tracking", "--out", str(tmp_path / "c"),
                 "--no-progress"]) == 2
    assert "is open loop; it takes no controller" in capsys.readouterr().err


def test_noise_and_delay_are_applied(tmp_path):
    from scenarios.noise import MeasurementNoise

    short = dataclasses.replace(SCENARIOS["swing-out"], duration=1.5)
    noise = MeasurementNoise(q=1e-4, qd=1e-3, suspension_force=100.0, seed=3)
    m = run_closed_loop(short, tmp_path, "mpc-full", noise=noise, delay_periods=2,
                        sensors="oracle")
    assert m["delay_periods"] == 2 and m["noise"]["suspension_force"] == 100.0
    assert m["fallbacks"] == 0
    log = load_log(tmp_path)
    assert np.all(np.isfinite(log["command"]))
    with pytest.raises(ValueError, match="delay_periods"):
        run_closed_loop(short, None, "tracking", delay_periods=-1)
