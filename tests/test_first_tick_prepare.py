"""What the MPC's first tick would make of its structure alone is made when it is built.

`wbc.structure.prepare_planner` (run by the controller's construction) also makes the C
force tick's kept buffers and its row plan of every wheel in contact
(`wbc.constraints.force_tick.ForceTick.prepare`): the first tick, all wheels in contact,
finds them and makes neither again. Their bits are the unprepared controller's
(`tests/test_structure_prepare.py` compares every QP and command).
"""

import pytest

from testkit.plant import KinematicPlant, make_state
from wbc import ControllerConfig, JointGoal, MpcController
from wbc.controllers.registry import estimator_models


def test_the_first_tick_finds_the_force_ticks_buffers_and_row_plan(machine):
    model, split = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=split)
    tick = ctrl.force_constraint._tick
    if tick.rows is None:
        pytest.skip("no compiled force map or node kernel (no C compiler)")
    kept, plan = tick._kept, tick._plan
    assert kept is not None and plan is not None
    assert plan[2] == bytes([1, 1, 1, 1])  # the flags of every wheel in contact
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1, suspension=st.q[:2] + 0.03))
    cmd = ctrl.step(KinematicPlant(st, 0.01).state)
    assert not cmd.fallback and ctrl.force_constraint.last_in_contact.all()
    assert tick._kept is kept and tick._plan is plan  # found, not made again
