"""The log schema: what load_log refuses, and the provenance ScenarioLog writes."""

import pickle
import shutil
import subprocess
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

import models
from models.log import COLUMNS, SCHEMA_VERSION, LogError, ScenarioLog, check_log, load_log
from scenarios import registry


@pytest.fixture(scope="module")
def flat_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("flat")
    registry.run("flat", out, duration=1.2, progress=False)
    return out


def test_saved_provenance_matches_the_package_and_git(flat_log):
    log = load_log(flat_log)
    try:
        version = metadata.version("wbc-hdmm")
    except metadata.PackageNotFoundError:
        version = "unknown"
    assert str(log["meta_package_version"]) == version
    assert int(log["meta_schema_version"]) == SCHEMA_VERSION
    git = shutil.which("git")
    head = subprocess.run([git, "rev-parse", "HEAD"], capture_output=True, text=True,
                          cwd=Path(models.__file__).parent).stdout.strip() if git else ""
    assert str(log["meta_git_commit"]) == (head or "unknown")
    assert log["qpos"].shape[0] == log["qvel"].shape[0] == len(log["time"])


def _documented_shape(key, n, nq=7):
    dims = COLUMNS[key].shape.strip("()").replace(" ", "").split(",")
    return tuple(n if d == "N" else nq if d in ("nq", "nv") else int(d) for d in dims if d)


@pytest.mark.parametrize("key", list(COLUMNS))
def test_every_documented_column_is_checked_for_its_shape(flat_log, key):
    log = dict(load_log(flat_log))
    n = len(log["time"])
    if key not in log:  # a closed-loop column: a correct one first
        log[key] = np.zeros(_documented_shape(key, n))
    assert check_log(log) == n  # the documented shape passes
    where = "key '" if key == "time" else f"key '{key}'"  # a short time shortens N itself
    bad = dict(log, **{key: np.asarray(log[key])[..., None]})  # one axis too many
    with pytest.raises(LogError, match=where):
        check_log(bad)
    bad = dict(log, **{key: np.asarray(log[key])[:-1]})  # one sample short
    with pytest.raises(LogError, match=where):
        check_log(bad)


def test_columns_of_strings_no_samples_and_nan_time_are_refused(flat_log):
    log = dict(load_log(flat_log))
    n = len(log["time"])
    with pytest.raises(LogError, match="key 'normal_force' must be a numeric array"):
        check_log(dict(log, normal_force=np.full((n, 4), "x")))
    with pytest.raises(LogError, match="N >= 1"):
        check_log(dict(log, time=np.zeros(0)))
    t = log["time"].copy()
    t[3] = np.nan
    with pytest.raises(LogError, match="NaN or inf"):
        check_log(dict(log, time=t))
    without = {k: v for k, v in log.items() if k != "normal_force"}
    with pytest.raises(LogError, match="lacks.*normal_force"):
        check_log(without)


def _write(path, content):
    path.write_bytes(content)
    return path


def test_foreign_files_are_one_log_error(flat_log, tmp_path):
    np.save(tmp_path / "bare.npy", np.zeros(3))
    bare = (tmp_path / "bare.npy").rename(tmp_path / "bare.npz")
    cases = {
        bare: "not a scenario log",
        _write(tmp_path / "pickled.npz", pickle.dumps({"time": [0.0]})): "not a readable",
        _write(tmp_path / "text.npz", b"time,q\n0,1\n"): "not a readable",
        _write(tmp_path / "half.npz",
               (flat_log / "log.npz").read_bytes()[:4000]): "not a readable",
    }
    for path, message in cases.items():
        with pytest.raises(LogError, match=message):
            load_log(path)
    for value in (None, 3, ["log.npz"]):
        with pytest.raises(LogError, match="log path must be a str or os.PathLike"):
            load_log(value)


@pytest.mark.parametrize("version, message", [("two", "must be an integer"),
                                              (0, "must be an integer in"),
                                              (1.5, "must be an integer"),
                                              (SCHEMA_VERSION + 1, "reads up to")])
def test_bad_schema_versions(flat_log, tmp_path, version, message):
    log = dict(load_log(flat_log), meta_schema_version=np.asarray(version))
    np.savez(tmp_path / "log.npz", **log)
    with pytest.raises(LogError, match=message):
        load_log(tmp_path)


def test_unknown_column_is_refused_by_append(flat_log):
    from models.log import state_at

    log = load_log(flat_log)
    state = state_at(log, 0)
    rec = ScenarioLog(scenario="flat", seed=0)
    rec.append(state, state.contacts, np.zeros(11), 0.0, qpos=log["qpos"][0],
               qvel=log["qvel"][0])
    assert len(rec) == 1
    with pytest.raises(LogError, match=r"unknown log column\(s\) \['colour'\]"):
        rec.append(state, state.contacts, np.zeros(11), 0.0, colour=1.0)
    arrays = rec.arrays()
    assert check_log(arrays) == 1 and arrays["qpos"].shape == (1, log["qpos"].shape[1])


def test_scalar_columns_stack_as_their_zero_d_arrays(flat_log):
    """Scalars are kept as given and stacked at the end: the dtypes and bits of the 0-d
    arrays they were once copied into; a buffer the caller reuses is copied."""
    from models.log import state_at

    log = load_log(flat_log)
    state = state_at(log, 0)
    scalars = [dict(tcp_error=0.25, goal_index=-1, last_goal_given=False,
                    step_ms=np.float64(1.5), fallback=np.bool_(True)),
               dict(tcp_error=np.float64(0.125), goal_index=2, last_goal_given=True,
                    step_ms=2.0, fallback=False)]
    kept, copied = ScenarioLog(scenario="flat"), ScenarioLog(scenario="flat")
    buffer = np.zeros(4)
    for row in scalars:
        kept.append(state, state.contacts, np.zeros(11), 1e-4, force_margin=buffer, **row)
        copied.append(state, state.contacts, np.zeros(11), 1e-4, force_margin=buffer.copy(),
                      **{k: np.array(v) for k, v in row.items()})
        buffer += 1.0
    a, b = kept.arrays(), copied.arrays()
    for key in ("time", "closure_violation", "force_margin", *scalars[0]):
        assert a[key].dtype == b[key].dtype and a[key].tobytes() == b[key].tobytes(), key
    assert a["force_margin"][:, 0].tolist() == [0.0, 1.0]
