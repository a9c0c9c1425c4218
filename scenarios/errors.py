"""The simulator's exceptions: one base class, `SimulatorError`."""

from __future__ import annotations

__all__ = ["CommandError", "SimulationError", "SimulatorError"]


class SimulatorError(Exception):
    """Base class of the simulator's errors."""


class CommandError(SimulatorError, ValueError):
    """A command has a wrong shape, an unknown name or a non-finite entry."""


class SimulationError(SimulatorError, RuntimeError):
    """The simulation diverged (MuJoCo flagged a bad position, velocity or acceleration)."""
