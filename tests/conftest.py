import numpy as np
import pytest

import models


@pytest.fixture(scope="session")
def machine():
    return models.build_reference_machine()


@pytest.fixture(scope="session")
def coords(machine):
    return machine.coordinates


def random_independent(machine, rng, margin=0.05):
    """Random independent positions inside the valid ranges (a margin of each range kept)."""
    coords = machine.coordinates
    q = np.zeros(models.N_INDEPENDENT)
    for i, name in enumerate(coords.independent_names):
        if name in machine.chains:
            lo, hi = machine.chains[name].chain.stroke_range
        elif name in machine.wheels:
            lo, hi = -np.pi, np.pi
        else:
            lo, hi = machine.body(name).joint.range
        span = hi - lo
        q[i] = rng.uniform(lo + margin * span, hi - margin * span)
    return q


def random_state(machine, rng, dynamic=True):
    """A random consistent machine state: pose, twist, acceleration, coordinates, rates."""
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec(rng.normal(scale=0.3, size=3)).as_matrix()
    scale = 1.0 if dynamic else 0.0
    return models.MachineState(
        base_position=rng.normal(size=3),
        base_rotation=rot,
        base_twist=scale * rng.normal(size=6),
        base_acceleration=scale * rng.normal(size=6),
        q=random_independent(machine, rng),
        qd=scale * rng.normal(scale=0.1, size=models.N_INDEPENDENT),
        qdd=scale * rng.normal(scale=0.3, size=models.N_INDEPENDENT),
    )


@pytest.fixture(scope="module")
def rough():
    """Swing-out's settled machine on its rough ground (several contacts per wheel)."""
    from models import build_reference_machine
    from scenarios.closed_loop_scenarios import SCENARIOS, scenario_terrain
    from scenarios.simulator import Simulator

    sc = SCENARIOS["swing-out"]
    machine = build_reference_machine(payload_mass=sc.payload_mass)
    sim = Simulator(machine, scenario_terrain(sc, 0))
    sim.reset(sc.start_pose.q(machine), sc.start, settle_time=0.2)
    return sim
