"""wbc export: the table holds the log's numbers under named columns; bad input is typed."""

import csv
import json
import sys

import numpy as np
import pytest

from models.log import COLUMNS, LogError, load_log
from scenarios import registry
from wbc_hdmm.export import ExportError, export_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("flat")
    registry.run("flat", out, duration=1.2, progress=False)
    return out


def test_csv_holds_the_logged_numbers_with_their_units(run, tmp_path):
    files = export_run(run / "log.npz", "csv", tmp_path)
    assert [f.name for f in files] == ["samples.csv", "units.json", "meta.json"]
    log = load_log(run)
    with (tmp_path / "samples.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(log["time"])
    got = np.array([[float(r[f"normal_force[{w}]"]) for w in ("FL", "RL", "FR", "RR")]
                    for r in rows])
    np.testing.assert_array_equal(got, log["normal_force"])  # exact: repr round-trip
    np.testing.assert_array_equal([float(r["force_in_fb[RR].z"]) for r in rows],
                                  log["force_in_fb"][:, 3, 2])
    np.testing.assert_array_equal([float(r["base_rotation[1][0]"]) for r in rows],
                                  log["base_rotation"][:, 1, 0])
    nq = log["qpos"].shape[1]
    assert f"qpos[{nq - 1}]" in rows[0] and f"qpos[{nq}]" not in rows[0]
    units = json.loads((tmp_path / "units.json").read_text())
    assert set(units) == set(rows[0])
    for name, unit in units.items():
        assert unit == COLUMNS[name.split("[")[0]].unit, name
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["scenario"] == "flat" and meta["schema_version"] == int(log[
        "meta_schema_version"])


def test_bad_input_is_one_typed_error(run, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(ExportError, match="is a file; give a folder"):
        export_run(run, "csv", a_file)
    with pytest.raises(ExportError, match="cannot write the export"):
        export_run(run, "csv", a_file / "below")
    with pytest.raises(ExportError, match="out must be a folder path"):
        export_run(run, "csv", 3)
    for fmt in ("xls", None, ["csv"], "CSV"):
        with pytest.raises(ExportError, match="not one of csv, parquet"):
            export_run(run, fmt, tmp_path)
    with pytest.raises(LogError, match="no scenario log"):
        export_run(tmp_path / "nothing", "csv")
    assert not (tmp_path / "samples.csv").exists()  # nothing written on a refusal


def test_parquet_without_pyarrow_says_how_to_get_it(run, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow -> ImportError
    with pytest.raises(ExportError, match=r"pip install 'wbc-hdmm\[parquet\]'"):
        export_run(run, "parquet", tmp_path)
