"""Output folders of the ``wbc`` command, checked before any simulation starts."""

from __future__ import annotations

import tempfile
from pathlib import Path

__all__ = ["OutputError", "prepare_out_dir"]


class OutputError(Exception):
    """An output folder that cannot be used (a file, not writable, or not empty)."""


def prepare_out_dir(path: str | Path, force: bool = False, option: str = "--out") -> Path:
    """Check ``path`` as an output folder and create it; returns it.

    Args:
        path: The folder.
        force: Accept a folder that already holds files (they are overwritten where the new
            run writes the same names; other files stay).
        option: Name of the option, for the message.

    Raises:
        OutputError: ``path`` is a file, cannot be created or written, or is a non-empty
            folder and ``force`` is False.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{option} '{path}' is a file; give a folder")
    if path.is_dir() and not force and any(path.iterdir()):
        raise OutputError(f"{option} '{path}' is not empty; add --force to write into it, "
                          f"or give another folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise OutputError(f"{option} '{path}' is not a writable folder "
                          f"({exc.strerror or exc})") from exc
    return path
