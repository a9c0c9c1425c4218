"""The benchmarks stay runnable (their figures are measured by `make bench`, not here)."""

import importlib

import pytest

from benchmarks import BENCHES


@pytest.mark.parametrize("module", ["bench_simulator", "bench_estimator", "bench_wbc"])
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

    with pytest.raises(ValueError, match="valid: " + ", ".join(BENCHES)):
        _run_one("foo", tmp_path)
