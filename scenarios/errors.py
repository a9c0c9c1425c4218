"""The simulator's exceptions: one base class, `SimulatorError`."""

from __future__ import annotations

__all__ = ["CommandError", "RunInputError", "RunInterrupted", "ScenarioFileError",
           "SimulationError", "SimulatorError"]


class SimulatorError(Exception):
    """Base class of the simulator's errors."""


class CommandError(SimulatorError, ValueError):
    """A command has a wrong shape, an unknown name or a non-finite entry."""


class SimulationError(SimulatorError, RuntimeError):
    """The simulation diverged (MuJoCo flagged a bad position, velocity or acceleration)."""


class RunInputError(SimulatorError, ValueError):
    """A run's argument (duration, seed, threshold, ...) is outside its valid range."""


class ScenarioFileError(RunInputError):
    """A scenario file cannot be read, or a field is unknown, missing or out of range."""


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run; the partial log and metrics were written.

    A `KeyboardInterrupt`, so callers that stop on Ctrl-C still stop.

    Attributes:
        out_dir: Folder holding the partial ``log.npz`` and ``metrics.json``, or None.
        metrics: The partial run's metrics (``"partial": True``).
    """

    def __init__(self, out_dir, metrics: dict):
        super().__init__(f"interrupted after {metrics.get('sim_seconds', 0.0):.2f} s "
                         f"simulated")
        self.out_dir = out_dir
        self.metrics = metrics
