"""The ``wbc`` command: listing, version, comparison, and every error as one line, exit 2."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scenarios import registry
from scenarios.simulator import Simulator
from wbc_hdmm.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _error_line(capsys) -> str:
    """The single stderr line of a failed command."""
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert err.startswith("wbc: error: "), err
    return err


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip().startswith("wbc 0.")


def test_python_dash_m_is_the_same_command():
    r = subprocess.run([sys.executable, "-m", "wbc_hdmm", "--version"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith("wbc ")


def test_list_names_every_scenario_and_controller(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in registry.names():
        line = next(ln for ln in out.splitlines() if ln.split()[:1] == [name])
        assert len(line.split()) > 3, line  # with its description
    for name in ("tracking", "mpc-quasi-static", "mpc-full"):
        assert any(ln.split()[:1] == [name] for ln in out.splitlines()), name
    from models.sensor_suites import SUITES
    from scenarios.families import FAMILIES

    for name in (*FAMILIES, *SUITES):
        line = next(ln for ln in out.splitlines() if ln.split()[:1] == [name])
        assert len(line.split()) > 3, line


def test_help_shows_defaults_and_scenarios(capsys):
    assert main(["run", "--help"]) == 0
    out = capsys.readouterr().out
    assert "[default: 0]" in out and "[default: out/run]" in out and "swing-out" in out
    assert "``" not in out


@pytest.mark.parametrize("scenario", ["flat", "rough", "swing-out"])
def test_negative_seed_refused_for_every_scenario(tmp_path, capsys, scenario):
    assert main(["run", scenario, "--seed", "-1", "--out", str(tmp_path)]) == 2
    assert "seed -1 outside [0, " in _error_line(capsys)


@pytest.mark.parametrize("scenario", ["flat", "swing-out"])
@pytest.mark.parametrize("duration", ["0.5", "1e-9", "nan", "1e6"])
def test_duration_outside_range(tmp_path, capsys, scenario, duration):
    assert main(["run", scenario, "--duration", duration, "--out", str(tmp_path)]) == 2
    assert "outside (1, 3600] s" in _error_line(capsys)


@pytest.mark.parametrize("option", [["--threshold", "-5"], ["--threshold", "1e9"],
                                    ["--delay", "-1"], ["--noise", "loud"]])
def test_closed_loop_options_outside_range(tmp_path, capsys, option):
    assert main(["run", "swing-out", *option, "--out", str(tmp_path)]) == 2
    _error_line(capsys)


@pytest.mark.parametrize("controllers, says", [("foo", "unknown ['foo']"),
                                               ("tracking,bar", "unknown ['bar']"),
                                               (",", "none given"), ("", "none given")])
def test_sweep_controllers_checked_before_anything_runs(tmp_path, capsys, controllers, says):
    out = tmp_path / "sweep"
    assert main(["sweep", "--draws", "1", "--controllers", controllers,
                 "--out", str(out), "--no-progress"]) == 2
    line = _error_line(capsys)
    assert f"--controllers: {says}; valid: tracking, mpc-quasi-static, mpc-full" in line
    assert not out.exists()  # refused before the output folder is made


def test_open_loop_takes_no_noise(tmp_path, capsys):
    assert main(["run", "flat", "--noise", "default", "--out", str(tmp_path)]) == 2
    assert "open loop; it takes no noise" in _error_line(capsys)


def test_out_is_a_file(tmp_path, capsys):
    f = tmp_path / "README.md"
    f.write_text("keep me")
    assert main(["run", "flat", "--out", str(f)]) == 2
    assert "is a file" in _error_line(capsys)
    assert f.read_text() == "keep me"


def test_out_not_empty_needs_force(tmp_path, capsys):
    (tmp_path / "old.txt").write_text("old run")
    assert main(["run", "flat", "--out", str(tmp_path)]) == 2
    assert "is not empty; add --force" in _error_line(capsys)
    # With --force the folder passes; the next check (the duration) is what fails.
    assert main(["run", "flat", "--force", "--duration", "0.5", "--out", str(tmp_path)]) == 2
    assert "duration" in _error_line(capsys)


def test_out_not_writable(tmp_path, capsys):
    if os.geteuid() == 0:  # root writes anywhere chmod allows nothing: use /proc
        target = Path("/proc/wbc-test-out/run")
    else:
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        target = locked / "run"
    assert main(["run", "flat", "--out", str(target)]) == 2
    assert "is not a writable folder" in _error_line(capsys)


def test_compare_refuses_an_open_loop_scenario(tmp_path, capsys):
    assert main(["compare", "flat", "--out", str(tmp_path)]) == 2
    assert "not a closed-loop scenario" in _error_line(capsys)


def test_bench_unknown_benchmark_is_a_wbc_error(tmp_path, capsys):
    assert main(["bench", "--only", "foo", "--out", str(tmp_path)]) == 2
    err = _error_line(capsys)
    assert "'foo' is not one of" in err and "python -m benchmarks" not in err


def test_estimate_truncated_and_foreign_files(tmp_path, capsys):
    good = tmp_path / "good.npz"
    np.savez_compressed(good, time=np.arange(500.0), q=np.zeros((500, 13)))
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:200])
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, a=np.arange(3))
    text = tmp_path / "notes.npz"
    text.write_text("not a log")
    for path in (truncated, foreign, text, tmp_path / "missing.npz"):
        assert main(["estimate", str(path), "--no-plots"]) == 2, path
        _error_line(capsys)


def test_run_a_family_draw_gives_the_sweeps_row_and_a_log(tmp_path, capsys):
    from scenarios.families import FAMILIES
    from scenarios.sweep import run_one
    from wbc_hdmm.cli import FAMILY_NAMES

    assert FAMILY_NAMES == tuple(FAMILIES)
    out = tmp_path / "draw"
    assert main(["run", "--family", "standing-on-rough", "--draw", "0", "--master-seed", "11",
                 "--duration", "3", "--out", str(out), "--no-progress"]) == 0
    assert "standing-on-rough-0000" in capsys.readouterr().out
    ran = json.loads((out / "metrics.json").read_text())
    assert np.load(out / "log.npz")["time"].size > 100
    row = run_one("standing-on-rough", 0, 11, "mpc-full", {"duration": 3.0})
    for key in ("min_normal_force_N", "time_below_threshold_s", "tipped", "time_to_ready_s"):
        assert ran[key] == pytest.approx(row["metrics"][key], rel=1e-6), key  # JSON rounds


@pytest.mark.parametrize("args, says", [
    (["--family", "random"], "--family and --draw go together"),
    (["--draw", "3"], "--family and --draw go together"),
    (["swing-out", "--family", "random", "--draw", "3"], "exactly one"),
    (["--family", "random", "--draw", "3", "--seed", "5"], "has its own terrain seed"),
    (["--family", "nope", "--draw", "3"], "'nope' is not one of 'random'"),
    (["--family", "random", "--draw", "-1"], "-1 is not in the range x>=0"),
])
def test_run_a_family_draw_refuses_bad_arguments(tmp_path, capsys, args, says):
    assert main(["run", *args, "--out", str(tmp_path / "x")]) == 2
    assert says in _error_line(capsys)
    assert not (tmp_path / "x").exists()


def test_estimate_refuses_an_unknown_sensor_suite(tmp_path, capsys):
    assert main(["estimate", str(tmp_path), "--sensors", "exact", "--no-plots"]) == 2
    err = _error_line(capsys)
    assert "'exact' is not one of 'oracle', 'ideal', 'realistic'" in err


def _interrupt_after(monkeypatch, n_calls):
    real_step = Simulator.step
    calls = {"n": 0}

    def step(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > n_calls:
            raise KeyboardInterrupt
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(Simulator, "step", step)


def test_ctrl_c_open_loop_writes_partial_log_and_metrics(tmp_path, capsys, monkeypatch):
    _interrupt_after(monkeypatch, 250)  # the reset's settling steps count too
    out = tmp_path / "run"
    assert main(["run", "flat", "--duration", "3", "--out", str(out), "--no-progress"]) == 130
    assert "partial log and metrics in" in capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    n = np.load(out / "log.npz")["time"].size
    assert metrics["partial"] is True and 0 < n < 300
    assert metrics["sim_seconds"] == pytest.approx(0.01 * n)


def test_ctrl_c_closed_loop_writes_partial_log_and_metrics(tmp_path, capsys, monkeypatch):
    _interrupt_after(monkeypatch, 250)
    out = tmp_path / "run"
    assert main(["run", "swing-out", "--controller", "tracking", "--duration", "3", "--out",
                 str(out), "--no-progress"]) == 130
    metrics = json.loads((out / "metrics.json").read_text())
    n = np.load(out / "log.npz")["time"].size
    assert metrics["partial"] is True and 0 < n < 300
    assert metrics["sim_seconds"] == pytest.approx(0.01 * n)


def _significant_digits(x: float) -> int:
    return len(repr(abs(x)).split("e")[0].replace(".", "").lstrip("0"))


def _floats(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _floats(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _floats(v)
    elif isinstance(obj, float):
        yield obj


def test_compare_prints_a_table_and_writes_rounded_json(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", "swing-out", "--duration", "1.2", "--out", str(out),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    rows = [ln.split()[0] for ln in text.splitlines() if ln.startswith(("tracking", "mpc"))]
    assert rows == ["tracking", "mpc-quasi-static", "mpc-full"]
    assert "[ok]" in text or "[NO]" in text
    assert (out / "forces.png").stat().st_size > 0
    report = json.loads((out / "comparison.json").read_text())
    assert set(report["metrics"]) == {"tracking", "mpc-quasi-static", "mpc-full"}
    floats = list(_floats(report))
    assert floats and max(map(_significant_digits, floats)) <= 10
    for name in report["metrics"]:
        metrics = json.loads((out / name / "metrics.json").read_text())
        assert metrics["partial"] is False
        assert max(map(_significant_digits, _floats(metrics))) <= 10
