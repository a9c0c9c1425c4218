"""The per-tick objects' fast constructors (``of``): the dataclasses' own fields, as set."""

import dataclasses

import numpy as np
import pytest

from wbc.controllers.command import ControlCommand
from wbc.force_models.feedback import ForceFeedback
from wbc.mpc.planner import MpcPlan


@pytest.mark.parametrize("cls", [ForceFeedback, MpcPlan, ControlCommand])
def test_of_sets_every_field_as_the_constructor_does(cls):
    names = [f.name for f in dataclasses.fields(cls)]
    values = [np.arange(3.0) + k for k in range(len(names))]
    fast, slow = cls.of(*values), cls(*values)
    assert list(vars(fast)) == list(vars(slow)) == names
    assert all(vars(fast)[n] is vars(slow)[n] for n in names)
    assert type(fast) is cls and not hasattr(cls, "__post_init__")
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.info = {}


class _Forces:
    """A force model that gives fixed forces (and all wheels in contact)."""

    def __init__(self, forces):
        self.forces = np.asarray(forces, float)

    def normal_forces(self, state):
        return self.forces

    def estimate(self, state):
        return type("E", (), {"normal_forces": self.forces, "in_contact": np.ones(4, bool)})


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", [0, 1])
def test_measure_refuses_forces_not_finite(machine, bad, which):
    from testkit.plant import make_state
    from wbc.errors import ForceModelError
    from wbc.force_models.feedback import ClosureFeedback

    state = make_state(machine)
    good, worse = np.full(4, 5e3), np.full(4, 5e3)
    worse[which * 3] = bad
    closure, model = (_Forces(worse), _Forces(good)) if which else (_Forces(good),
                                                                     _Forces(worse))
    with pytest.raises(ForceModelError, match="returned"):
        ClosureFeedback(closure).measure(state, model)
    fb = ClosureFeedback(_Forces(good)).measure(state, _Forces(good + 1e308))
    assert np.isfinite(fb.model_forces).all()
