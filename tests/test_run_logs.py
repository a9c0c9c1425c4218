"""Run logs: the schema documents every key a run writes; replay, video and export from them."""

import json
import zipfile

import imageio.v2 as imageio
import numpy as np
import pytest

from models.log import (
    COLUMNS,
    META,
    PHYSICS_COLUMNS,
    SCHEMA_VERSION,
    LogError,
    ScenarioLog,
    load_log,
)
from scenarios import registry
from wbc_hdmm.cli import main
from wbc_hdmm.export import ExportError, export_run
from wbc_hdmm.render import RenderError, render_run


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    registry.run("flat", root / "flat", duration=1.2, progress=False)
    registry.run("swing-out", root / "closed", controller="tracking", duration=1.2,
                 progress=False)
    return root


@pytest.mark.parametrize("name", ["flat", "closed"])
def test_every_written_key_is_documented_with_its_shape(runs, name):
    log = load_log(runs / name)
    n = len(log["time"])
    for key, value in log.items():
        if key.startswith("meta_"):
            assert key[5:] in META, key
            assert value.ndim == 0, key
            continue
        if key in PHYSICS_COLUMNS:
            m = len(log["physics_time"])
            assert m >= n and value.shape[0] == m, key
            continue
        assert key in COLUMNS, f"undocumented log key {key}"
        shape = COLUMNS[key].shape.strip("()").replace(" ", "").split(",")
        shape = [s for s in shape if s]
        assert value.shape[0] == n and len(value.shape) == len(shape), key
        for dim, spec in zip(value.shape[1:], shape[1:]):
            assert spec in ("nq", "nv") or int(spec) == dim, (key, value.shape, spec)
    assert int(log["meta_schema_version"]) == SCHEMA_VERSION
    assert str(log["meta_package_version"]) != "" and str(log["meta_git_commit"]) != ""
    closed = [k for k, c in COLUMNS.items() if c.closed_loop] + list(PHYSICS_COLUMNS)
    assert all((k in log) == (name == "closed") for k in closed)


def test_unknown_keys_and_bad_files_are_typed_errors(tmp_path):
    with pytest.raises(LogError, match="unknown log metadata"):
        ScenarioLog(colour="red")
    bad = tmp_path / "log.npz"
    bad.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(LogError, match="not a readable scenario log"):
        load_log(tmp_path)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(LogError, match="lacks"):
        load_log(tmp_path / "other.npz")
    with pytest.raises(LogError, match="no scenario log"):
        load_log(tmp_path / "missing")
    np.savez(tmp_path / "newer.npz", meta_schema_version=np.asarray(SCHEMA_VERSION + 1),
             time=np.zeros(2))
    with pytest.raises(LogError, match="schema"):
        load_log(tmp_path / "newer.npz")
    assert issubclass(LogError, ValueError) and not zipfile.is_zipfile(bad)


@pytest.mark.parametrize("name", ["flat", "closed"])
def test_render_writes_an_mp4_with_content(runs, tmp_path, name):
    out = render_run(runs / name, tmp_path / "run.mp4", fps=10, width=320, height=180,
                     plot_width=160)
    frames = [f for f in imageio.get_reader(out)]
    t = load_log(runs / name)["time"]
    assert len(frames) == len(np.arange(t[0], t[-1] + 1e-9, 0.1))
    assert frames[0].shape == (176, 480, 3)  # sizes rounded down to multiples of 8
    view = np.asarray(frames[-1][:, :320], float)
    assert view.std() > 10.0  # not blank: terrain, sky and machine
    yellow = (view[..., 0] > 150) & (view[..., 1] > 100) & (view[..., 2] < 80)
    assert yellow.sum() > 50  # the machine's yellow paint is in view
    plot = np.asarray(frames[-1][:, 320:], float)
    assert plot.mean() > 200  # the white force plot beside it


def test_render_refuses_bad_settings(runs, tmp_path):
    with pytest.raises(RenderError, match="fps 0 outside"):
        render_run(runs / "flat", tmp_path / "x.mp4", fps=0)


def test_export_csv_and_parquet(runs, tmp_path):
    files = export_run(runs / "closed", "csv", tmp_path / "csv")
    header = (tmp_path / "csv" / "samples.csv").read_text().splitlines()[0].split(",")
    assert "normal_force[FL]" in header and "q[lift]" in header and "qpos[0]" in header
    units = json.loads((tmp_path / "csv" / "units.json").read_text())
    assert units["normal_force[RR]"] == "N" and units["time"] == "s"
    meta = json.loads((tmp_path / "csv" / "meta.json").read_text())
    assert meta["controller"] == "tracking" and len(files) == 3
    import pyarrow.parquet as pq

    export_run(runs / "closed", "parquet", tmp_path / "pq")
    table = pq.read_table(tmp_path / "pq" / "samples.parquet")
    n = len(load_log(runs / "closed")["time"])
    assert table.num_rows == n and table.num_columns == len(header)
    with pytest.raises(ExportError, match="not one of csv, parquet"):
        export_run(runs / "closed", "xls")


def test_cli_render_export_view(runs, tmp_path, capsys):
    assert main(["export", str(runs / "flat"), "--out", str(tmp_path / "e")]) == 0
    assert (tmp_path / "e" / "samples.csv").exists()
    out = tmp_path / "v.mp4"
    assert main(["render", str(runs / "flat"), "--out", str(out), "--fps", "5",
                 "--width", "160", "--height", "120", "--no-progress"]) == 0
    assert out.stat().st_size > 1000
    assert main(["render", str(runs / "flat"), "--out", str(out), "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["render", str(tmp_path / "nothing"), "--out", str(tmp_path / "n.mp4"),
                 "--no-progress"]) == 2
    capsys.readouterr()
    assert main(["render", str(tmp_path / "nothing"), "--out", str(tmp_path / "m.mp4")]) == 2
    err = capsys.readouterr().err  # refused before its progress bar starts
    assert "no scenario log" in err and "render" not in err.split("wbc: error")[0]
    assert main(["view", str(runs / "flat")]) == 2  # no display here: one line, exit 2
