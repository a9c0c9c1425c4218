"""Open-loop scenarios through the command line: logs, metrics, contact loss."""

import json

import numpy as np
import pytest

from models import WHEEL_ORDER
from models.log import load_log, state_at
from wbc_hdmm.cli import main

REQUIRED = ("sim_seconds", "wall_seconds", "real_time_factor", "max_closure_violation_m",
            "min_normal_force_N", "contact_loss_fraction")


def _run(tmp_path, name, *extra):
    out = tmp_path / name
    assert main(["run", name, "--out", str(out), "--no-progress", *extra]) == 0
    return json.loads((out / "metrics.json").read_text()), load_log(out)


def test_flat_run_writes_log_and_metrics(tmp_path):
    metrics, log = _run(tmp_path, "flat", "--duration", "3")
    for key in REQUIRED:
        assert key in metrics
    assert set(metrics["min_normal_force_N"]) == set(WHEEL_ORDER)
    assert set(metrics["contact_loss_fraction"]) == set(WHEEL_ORDER)
    assert metrics["sim_seconds"] == pytest.approx(3.0, abs=0.02)
    n = log["time"].size
    assert n == pytest.approx(300, abs=2)
    assert log["q"].shape == (n, 13) and log["force_in_fb"].shape == (n, 4, 3)
    assert np.all(np.isfinite(log["normal_force"]))
    # The machine drove forward: the paper's wheel profile integrates to b (t - sin t).
    assert log["base_position"][-1, 0] - log["base_position"][0, 0] > 1.0
    st = state_at(log, n // 2)
    assert st.contacts is not None and st.q.shape == (13,)


def test_unknown_scenario_is_a_clear_error(tmp_path, capsys):
    assert main(["run", "moon", "--out", str(tmp_path)]) == 2
    assert "valid: contact-loss, flat, rough" in capsys.readouterr().err


def test_contact_loss_run_loses_every_wheel(tmp_path):
    # The whole 200 s run, without the sensors' observers (the CLI runs are tested above).
    from scenarios.openloop import SCENARIOS as OPEN_LOOP
    from scenarios.openloop import run_open_loop

    metrics = run_open_loop(OPEN_LOOP["contact-loss"], tmp_path, progress=False, observe=False)
    log = load_log(tmp_path)
    assert metrics["sim_seconds"] == pytest.approx(200.0, abs=0.05)
    for wheel in WHEEL_ORDER:
        assert metrics["contact_loss_fraction"][wheel] > 0.0, wheel
    assert np.all(np.isfinite(log["normal_force"]))


def test_machine_doc_is_current(machine):
    # docs/machine.md is generated: it must agree with the code.
    from pathlib import Path

    from models.report import machine_markdown

    doc = Path(__file__).resolve().parents[1] / "docs" / "machine.md"
    assert doc.read_text() == machine_markdown(machine), "run: wbc machine --doc docs/machine.md"
