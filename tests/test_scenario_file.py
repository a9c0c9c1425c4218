"""Scenario files: the documented TOML format, validated field by field; built-ins are files."""

from pathlib import Path

import pytest

from scenarios.closed_loop_scenarios import SCENARIOS
from scenarios.errors import ScenarioFileError
from scenarios.scenario_file import (
    DATA_DIR,
    load_scenario_file,
    scenario_from_dict,
    scenario_to_toml,
)
from wbc_hdmm.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "heavy-swing.toml"


def _valid():
    return {"name": "t", "duration": 5.0, "side_slope_deg": -5.0,
            "goals": [{"slew_deg": 30.0, "lift_deg": 30.0, "tilt_deg": -50.0,
                       "telescope": 0.8}]}


def test_builtin_scenarios_are_the_shipped_files():
    files = sorted(p.stem for p in DATA_DIR.glob("*.toml"))
    assert files == sorted(SCENARIOS)
    for name, scenario in SCENARIOS.items():
        assert load_scenario_file(DATA_DIR / f"{name}.toml") == scenario


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_toml_round_trip(tmp_path, name):
    path = tmp_path / "s.toml"
    path.write_text(scenario_to_toml(SCENARIOS[name]))
    assert load_scenario_file(path) == SCENARIOS[name]


def test_example_file_loads_with_defaults_filled():
    s = load_scenario_file(EXAMPLE)
    assert s.name == "heavy-swing" and len(s.goals) == 2 and s.payload_mass == 250.0
    d = scenario_from_dict(_valid())
    assert d.dwell == 1.0 and d.start_pose.lift_deg == 45.0 and d.payload_event is None


@pytest.mark.parametrize("change,match", [
    ({"duration": 0.5}, r"'duration' = 0.5 outside \(1, 3600\]"),
    ({"duration": "long"}, r"'duration' must be a finite number"),
    ({"side_slope_deg": 45.0}, r"'side_slope_deg' = 45.0 outside \[-20, 20\]"),
    ({"rough_slope_deg": -1.0}, r"'rough_slope_deg' = -1.0 outside \[0, 30\]"),
    ({"payload_mass": 900.0}, r"'payload_mass' = 900.0 outside \[0, 500\]"),
    ({"first_goal_time": 9.0}, r"'first_goal_time' = 9.0 outside \[0, 5\]"),
    ({"name": "has space"}, r"'name' must be 1-64 letters"),
    ({"speed": 1.0}, r"unknown field\(s\) \['speed'\]"),
    ({"goals": []}, r"'goals' must be one or more"),
    ({"goals": [{"slew_deg": 120.0, "lift_deg": 30.0, "tilt_deg": -50.0,
                 "telescope": 0.8}]}, r"'goals\[0\]' is not a pose the crane can take"),
    ({"goals": [{"slew_deg": 0.0, "lift_deg": 30.0, "tilt_deg": -50.0,
                 "telescope": 101.0}]}, r"'goals\[0\].telescope' = 101 m outside"),
    ({"goals": [{"slew_deg": 0.0, "lift_deg": 30.0}]}, r"must have exactly slew_deg"),
    ({"payload_event": {"time": 1.0}}, r"'payload_event' must be a table with exactly"),
    ({"payload_event": {"time": 9.0, "mass": 100.0}},
     r"'payload_event.time' = 9.0 outside \[0, 5\]"),
    ({"start": [0.0, 0.0]}, r"'start' must be \[x, y, heading\]"),
    ({"crane_speed": [0.0, 0.2]}, r"'crane_speed\[0\]' = 0.0 outside \(0, 1\]"),
    ({"side_slope_deg": 0.0}, r"need a slope or rough terrain"),
])
def test_bad_fields_are_named_with_their_range(change, match):
    data = {**_valid(), **change}
    with pytest.raises(ScenarioFileError, match=match):
        scenario_from_dict(data, "my.toml")


def test_missing_duration_and_bad_toml(tmp_path):
    data = _valid()
    del data["duration"]
    with pytest.raises(ScenarioFileError, match="'duration' is required"):
        scenario_from_dict(data)
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(ScenarioFileError, match="not valid TOML"):
        load_scenario_file(bad)
    with pytest.raises(ScenarioFileError, match="cannot read scenario file"):
        load_scenario_file(tmp_path / "missing.toml")


def test_cli_refuses_a_bad_file_in_one_line_with_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nduration = 5000.0\n')
    assert main(["run", "--scenario-file", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'duration' = 5000.0 outside (1, 3600]" in err[0]
    assert not (tmp_path / "o").exists()  # refused before any output
    assert main(["run", "swing-out", "--scenario-file", str(bad)]) == 2
    assert "exactly one" in capsys.readouterr().err


def test_cli_runs_the_example_file(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "--scenario-file", str(EXAMPLE), "--controller", "tracking",
                 "--duration", "1.2", "--out", str(out), "--no-progress"])
    assert code == 0
    assert "heavy-swing (tracking)" in capsys.readouterr().out
    assert (out / "log.npz").exists() and (out / "metrics.json").exists()
