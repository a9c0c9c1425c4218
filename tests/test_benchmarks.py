"""The benchmarks stay runnable (their figures are measured by `make bench`, not here)."""

import importlib

import pytest

from benchmarks import BENCHES, EXTRA


@pytest.mark.parametrize("module", ["bench_simulator", "bench_estimator", "bench_wbc",
                                    "bench_qp_solvers", "bench_ticks"])
def test_benchmark_modules_import(module):
    mod = importlib.import_module(f"benchmarks.{module}")
    assert callable(mod.run)


def test_estimator_timing_runs_on_a_few_calls():
    from benchmarks.bench_estimator import timing

    figures = timing(calls=40, batch=200)
    assert figures["pin_rnea_median_us"] > 0
    assert figures["estimate_batch_1_thread_states_per_s"] > 0
    assert "linearize_median_us" in figures


def test_unknown_benchmark_is_refused(tmp_path):
    from benchmarks import _run_one

    with pytest.raises(ValueError, match="valid: " + ", ".join(BENCHES + EXTRA)):
        _run_one("foo", tmp_path)


def test_targets_are_ratios_to_anchors_of_the_same_run():
    from benchmarks.targets import TARGETS, format_table, targets

    results = {
        "estimator": {"pin_rnea_median_us": 4.0, "estimate_d_beta_median_us": 16.0,
                      "constraint_median_us": 6.0, "linearize_median_us": 80.0,
                      "estimate_batch_2_thread_states_per_s": 1.2e6},
        "controller": {"qp_tracking": {"median_ms": 0.3, "solver_median_ms": 0.05},
                       "mpc_full": {"median_ms": 2.5, "solver_median_ms": 0.5,
                                    "solver_call_median_ms": 0.2,
                                    "p99_ms": 4.0, "first_ms": 30.0},
                       "closed_loop": {"real_time_factor": 1.6, "peak_memory_mb": 250.0,
                                       "max_tick_after_first_ms": 9.0,
                                       "control_step_ms": {"median": 2.4, "p99": 1.9}}},
        "simulator": {"bare_stepping_real_time_factor": 40.0},
    }
    rows = targets(results)
    assert set(rows) == set(TARGETS)
    assert rows["estimate_over_rnea"]["value"] == 4.0 and not rows["estimate_over_rnea"]["met"]
    assert rows["constraint_over_rnea"]["value"] == 1.5 and rows["constraint_over_rnea"]["met"]
    assert rows["estimate_batch_states_per_s"]["met"]
    assert rows["qp_step_over_solver"]["value"] == 6.0
    assert "over_solver_call" not in rows["qp_step_over_solver"]  # not measured: not shown
    assert rows["mpc_step_over_solver"]["value"] == 5.0
    assert rows["mpc_step_over_solver"]["over_solver_call"] == 12.5
    assert "12.5x the solver's library call" in "\n".join(format_table(rows))
    assert rows["mpc_first_tick_over_median"]["value"] == 12.0
    assert rows["closed_loop_rtf_over_bare"]["value"] == 0.04
    assert rows["closed_loop_peak_memory_mb"]["met"] and rows["closed_loop_max_tick_ms"]["met"]
    assert rows["closed_loop_tick_median_ms"]["value"] == 2.4
    assert not rows["closed_loop_tick_median_ms"]["met"] and rows["closed_loop_tick_p99_ms"]["met"]
    assert len(format_table(rows)) == len(TARGETS)
    partial = targets({"estimator": results["estimator"]})
    assert partial["mpc_step_median_ms"]["value"] is None
    assert partial["mpc_step_median_ms"]["met"] is None


def test_tick_sample_records_every_run_and_judges_against_the_period():
    from benchmarks.bench_ticks import sample

    r = sample(draws=2, duration=1.5)
    assert [run["index"] for run in r["runs"]] == [0, 1]
    assert r["period_ms"] == 10.0
    worst = max(run["max_after_first"] for run in r["runs"])
    assert r["worst_tick_after_first_ms"] == worst > 0
    assert r["goal_met"] == (not r["runs_over_period"])
    assert all(run["median"] <= run["max"] for run in r["runs"])


def test_the_command_offers_the_benchmarks_the_package_has():
    from wbc_hdmm.cli import BENCHES as CLI_BENCHES
    from wbc_hdmm.cli import EXTRA_BENCHES

    assert CLI_BENCHES == BENCHES and EXTRA_BENCHES == EXTRA


def test_touchdown_tick_windows_end_at_the_ticks_instant():
    """The tick at t reports the step starting at t; its window is that step and the ones
    before it (the pressures' tick mean)."""
    import numpy as np

    from benchmarks.touchdown import tick_windows

    steps = np.arange(20) * 0.002
    forces = np.repeat(np.arange(20.0)[:, None], 4, axis=1)
    win = tick_windows([0.01, 0.02], steps, forces, 5)
    assert win.shape == (2, 5, 4)
    np.testing.assert_array_equal(win[0, :, 0], [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(win[1, :, 0], [6, 7, 8, 9, 10])


def test_touchdown_scores_a_short_contact_loss_run(tmp_path):
    import json

    from benchmarks.touchdown import main

    assert main(["--duration", "3", "--out", str(tmp_path)]) == 0
    fig = json.loads((tmp_path / "touchdown.json").read_text())
    assert fig["steps_per_tick"] == 5
    assert fig["instant_matches_step"] < 126.0  # the recorder and the log agree (1 % of load)
    for suite in ("ideal", "realistic"):
        three = fig["closure_pct"][suite]["tick_mean"]["three_contact"]
        assert three is None or 0.0 <= three < 50.0
