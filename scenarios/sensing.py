"""What the controller is told at each tick: the oracle state, or the observer's estimate.

``oracle`` hands the controller `Simulator.measure`'s state (MuJoCo's exact contacts,
accelerations and cylinder forces, with the optional `MeasurementNoise`) and, at a payload
event, the new mass; ``ideal`` and ``realistic`` attach the machine's sensors to the
simulator (`scenarios.sensors`) and hand the controller the observer's state
(`estimators.observer`), with the payload estimated from the crane's pressures and never
told. Both give an `Observation` with the standard deviations of the state's errors
(`estimators.uncertainty.StateUncertainty`; zero for the oracle).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from estimators.observer import Observer
from estimators.payload import PayloadEstimator
from estimators.uncertainty import StateUncertainty
from models.description import Machine
from models.records import trusted
from models.sensor_suites import SUITES, sensor_suite
from models.state import MachineState
from scenarios.errors import RunInputError
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator

__all__ = ["SENSOR_SUITES", "Observation", "Sensing", "check_sensors"]

SENSOR_SUITES = tuple(SUITES)


def check_sensors(name) -> str:
    """``name`` if it is a sensor suite, else a `RunInputError` listing the valid ones."""
    if not isinstance(name, str) or name not in SUITES:
        raise RunInputError(f"sensor suite {name!r} is not one of {', '.join(SUITES)}")
    return name


@dataclass(frozen=True, eq=False)
class Observation:
    """What the controller is told at one tick.

    Attributes:
        state: The state it reads.
        uncertainty: The std of that state's errors.
        payload_mass: The payload it should assume [kg].
        payload_std: Its std [kg].
        payload_event: ``pick``/``release`` detected this tick (observer only), else None.
        observer_seconds: Wall time of the observer's update [s] (0 for the oracle).
    """

    state: MachineState
    uncertainty: StateUncertainty
    payload_mass: float
    payload_std: float
    payload_event: str | None = None
    observer_seconds: float = 0.0


class Sensing:
    """The controller's view of the simulated machine (module docstring).

    Args:
        sim: The simulator.
        machine: The machine description (the payload at the start).
        suite: ``oracle``, ``ideal`` or ``realistic``.
        seed: Seed of the sensors' errors.
        initial_payload: The observer's prior [kg] (not the truth: the payload is not
            told); None: the description's.
    """

    def __init__(self, sim: Simulator, machine: Machine, suite: str = "realistic",
                 seed: int = 0, initial_payload: float | None = None):
        self.suite = check_sensors(suite)
        self.spec = sensor_suite(suite, seed)
        self.sim = sim
        body = next(b for b in machine.bodies if b.name == machine.payload)
        self._told_mass = float(body.inertia.mass)
        self.sensors = None
        self.observer = None
        self.closure = None
        if not self.spec.oracle:
            self.sensors = SensorSimulator(sim, self.spec)
            self.closure = PayloadEstimator(machine, fourth="cylinder-force", strokes="clip")
            self.observer = Observer(machine, self.spec, self.closure,
                                     initial_payload=initial_payload)

    def tell_payload(self, mass: float) -> None:
        """The oracle is told a payload change (the observer finds it by itself)."""
        self._told_mass = float(mass)

    def expect_pick(self, time: float) -> None:
        """The operator's grapple command at ``time`` [s]: the observer expects a pick.

        (`estimators.observer.payload_rls`; the oracle has nothing to expect.)
        """
        if self.observer is not None:
            self.observer.expect_pick(time)

    def observe(self, tick: float) -> Observation:
        """The controller's view at the tick (the simulator's measured instant)."""
        if self.observer is None:
            state, _ = self.sim.measure()
            return Observation(state, StateUncertainty.exact(), self._told_mass, 0.0)
        readings = self.sensors.readings(tick)
        t0 = time.perf_counter()
        est = self.observer.update(readings)
        seconds = time.perf_counter() - t0
        # the observer's fields, valid: without the frozen dataclass's per-field setting
        return trusted(Observation, state=est.state, uncertainty=est.uncertainty,
                       payload_mass=est.payload_mass, payload_std=est.payload_std,
                       payload_event=est.payload_event, observer_seconds=seconds)

    def close(self) -> None:
        """Detach the sensors from the simulator."""
        if self.sensors is not None:
            self.sensors.close()
