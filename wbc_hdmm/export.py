"""``wbc export``: a run log as tables for analysis tools (CSV or Parquet).

Every column of the log (`models.log.COLUMNS`) becomes one or more named table columns: per
wheel by name (``normal_force[FL]``), per axis (``force_in_fb[FL].x``), per coordinate by its
name (``q[lift]``), MuJoCo's state by index (``qpos[7]``), a rotation by row and column
(``base_rotation[0][1]``). ``units.json`` gives each column's unit and ``meta.json`` the run's
metadata. Parquet needs the optional ``pyarrow`` (``pip install wbc-hdmm[parquet]``).
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np

from models import build_reference_machine
from models.description import WHEEL_ORDER
from models.log import COLUMNS, load_log

__all__ = ["FORMATS", "ExportError", "export_run", "table_of_log"]

FORMATS = ("csv", "parquet")
_AXES = ("x", "y", "z")


class ExportError(ValueError):
    """An unknown format, a format whose library is not installed, or an unusable output."""


def _names(key: str, shape: tuple[int, ...], coordinates: tuple[str, ...]) -> list[str]:
    if len(shape) == 1:
        return [key]
    inner = shape[1:]
    if inner == (4,):
        return [f"{key}[{w}]" for w in WHEEL_ORDER]
    if inner == (4, 3):
        return [f"{key}[{w}].{a}" for w in WHEEL_ORDER for a in _AXES]
    if inner == (13,):
        return [f"{key}[{c}]" for c in coordinates]
    if inner == (3, 3):
        return [f"{key}[{r}][{c}]" for r in range(3) for c in range(3)]
    if inner == (2,) and key == "suspension_force":
        return [f"{key}[L]", f"{key}[R]"]
    flat = int(np.prod(inner))
    return [f"{key}[{i}]" for i in range(flat)]


def table_of_log(log: dict) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(columns name -> (N,) array, units name -> unit) of a loaded log, in schema order."""
    coordinates = build_reference_machine().coordinates.independent_names
    columns, units = {}, {}
    keys = [k for k in COLUMNS if k in log] + sorted(
        k for k in log if not k.startswith("meta_") and k not in COLUMNS)
    n = len(log["time"])
    for key in keys:
        a = np.asarray(log[key])
        if a.shape[:1] != (n,):
            continue
        flat = a.reshape(n, -1)
        for j, name in enumerate(_names(key, a.shape, coordinates)):
            columns[name] = flat[:, j]
            units[name] = COLUMNS[key].unit if key in COLUMNS else "?"
    return columns, units


def _meta(log: dict) -> dict:
    out = {}
    for k, v in log.items():
        if k.startswith("meta_"):
            v = np.asarray(v)
            out[k[5:]] = v.item() if v.ndim == 0 else v.tolist()
    return out


def export_run(run_dir, fmt: str, out=None) -> list[Path]:
    """Write the run's log as ``samples.csv`` or ``samples.parquet`` plus the sidecars.

    Args:
        run_dir: A run folder or its ``log.npz``.
        fmt: ``csv`` or ``parquet``.
        out: Output folder; default: the run folder.

    Returns:
        The files written.

    Raises:
        ExportError: Unknown format, ``parquet`` without ``pyarrow``, ``out`` not a path,
            a file, or not a writable folder.
        LogError: The log cannot be read.
    """
    if not isinstance(fmt, str) or fmt not in FORMATS:
        raise ExportError(f"format {fmt!r} is not one of {', '.join(FORMATS)}")
    if out is not None and not isinstance(out, (str, os.PathLike)):
        raise ExportError(f"out must be a folder path (str or os.PathLike), got "
                          f"{type(out).__name__}")
    log = load_log(run_dir)
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else (run_dir if run_dir.is_dir() else run_dir.parent)
    columns, units = table_of_log(log)
    if out.exists() and not out.is_dir():
        raise ExportError(f"out '{out}' is a file; give a folder")
    try:
        return _write(out, fmt, columns, units, _meta(log))
    except OSError as exc:
        raise ExportError(f"cannot write the export to '{out}' ({exc.strerror or exc})"
                          ) from exc


def _write(out: Path, fmt: str, columns: dict, units: dict, meta: dict) -> list[Path]:
    """Write the table and the sidecars into ``out``; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if fmt == "csv":
        path = out / "samples.csv"
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(columns)
            w.writerows(zip(*(np.asarray(c).tolist() for c in columns.values())))
    else:
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise ExportError("parquet export needs pyarrow: pip install 'wbc-hdmm[parquet]' "
                              "(or use --format csv)") from None
        table = pa.table({k: np.asarray(v) for k, v in columns.items()})
        table = table.replace_schema_metadata({"units": json.dumps(units)})
        path = out / "samples.parquet"
        pq.write_table(table, path)
    written.append(path)
    for name, content in (("units.json", units), ("meta.json", meta)):
        p = out / name
        p.write_text(json.dumps(content, indent=2))
        written.append(p)
    return written
