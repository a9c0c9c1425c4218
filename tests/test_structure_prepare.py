"""The MPC's structure made before its first tick (`wbc.structure`) gives a tick's own bits.

A controller whose planner was prepared (`prepare_planner`) and one whose was not are driven
through the same crane move on the kinematic plant: every QP, command, plan and logged
force map must be the same bytes, and the first tick of the prepared one must find its
caches (no Jacobian made). Prepared for another structure (other step lengths, another
period), the caches are rebuilt at the first tick, not reused.
"""

import numpy as np
import pytest

import wbc.controllers.mpc as mpc_module
import wbc.mpc.planner as planner_module
from estimators._row_views import LINEARIZATION_VIEWS
from estimators.linearize_batch import linearize_first, prepare_rows
from estimators.payload import PayloadEstimator
from testkit.plant import KinematicPlant, make_state
from wbc import ControllerConfig, JointGoal, MpcController
from wbc.axes import N_AXES
from wbc.controllers.registry import estimator_models
from wbc.mpc.prediction import CondensedPrediction
from wbc.structure import StructureContext, prepare_planner
from wbc.tasks import HorizonLevelingTask
from wbc.tasks.task import ConstantJacobianTask

FIELDS = ("P", "q", "G", "h", "lb", "ub")


def _controller(machine, monkeypatch, feedback: bool = True):
    """mpc-full (with the estimator's feedback), its planner not prepared, and its plant."""
    with monkeypatch.context() as m:
        m.setattr(planner_module, "prepare_planner", lambda planner: None)
        m.setattr(mpc_module, "prepare_planner", lambda planner, warp=None: None)
        model, split = estimator_models(machine, "full")
        ctrl = MpcController(machine, ControllerConfig(), force_model=model,
                             feedback=split if feedback else None)
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1, suspension=st.q[:2] + 0.03))
    return ctrl, KinematicPlant(st, 0.01)


def _run(ctrl, plant, ticks: int, Gs: list | None = None) -> list:
    """Per tick: the QP's arrays, the command, the plan and the logged force rows, as bytes.

    ``Gs``: gets each tick's ``G``.
    """
    qps = []
    build = ctrl.planner.builder.build

    def kept(ctx):
        qp = build(ctx)
        qps.append(tuple(getattr(qp, k).tobytes() for k in FIELDS))
        if Gs is not None:
            Gs.append(qp.G)
        return qp

    ctrl.planner.builder.build = kept
    out = []
    for _ in range(ticks):
        cmd = ctrl.step(plant.state)
        plant.apply(cmd)
        fc = ctrl.force_constraint
        plan = ctrl.last_plan
        out.append((qps[-1], cmd.rates.tobytes(), cmd.accelerations.tobytes(),
                     cmd.wheel_speed_scale, cmd.fallback, plan.solution.x.tobytes(),
                     plan.inputs.tobytes(),
                    fc.last_forces_map[0].tobytes(), fc.last_forces_map[1].tobytes(),
                    fc.last_in_contact.tobytes(), ctrl.force_model.n_clipped))
    return out


def _context(planner, prediction=None, dt=None, warp=None) -> StructureContext:
    return StructureContext(planner.layout, prediction or planner.prediction,
                            planner.dt if dt is None else dt, planner.limits, warp)


@pytest.mark.parametrize("feedback", [True, False])
def test_a_prepared_planner_gives_the_bits_of_an_unprepared_one(machine, monkeypatch,
                                                                 feedback):
    """With the feedback the warp is modelled: `HorizonLevelingTask`, prepared with the
    controller's warp matrix, is active at the ticks."""
    plain = _run(*_controller(machine, monkeypatch, feedback), 40)
    ctrl, plant = _controller(machine, monkeypatch, feedback)
    planner = ctrl.planner
    model = ctrl.force_model
    if not hasattr(model, "prepare_nodes"):  # the estimator's hook, as `PayloadEstimator`'s
        monkeypatch.setattr(model, "prepare_nodes", lambda n, m: prepare_rows(model._est, n, m),
                            raising=False)
    caches = (model._last, model._kept, model._stepped, model.n_clipped)
    prepare_planner(planner, ctrl.warp)
    fc, effort = ctrl.force_constraint, ctrl.effort_limit
    # nothing of a state: no logged rows, no efforts, nothing counted or kept by the model
    assert fc.last_forces_map is None and fc.last_in_contact is None
    assert fc.linearization_steps.size == 0 and (effort is None or effort._last is None)
    assert all(a is b for a, b in zip(caches, (model._last, model._kept, model._stepped,
                                               model.n_clipped)))
    fmap = ctrl.force_constraint._compiled_map
    buffers = fmap.iv, fmap.arrays["rows"]
    nodes = model._est._calls.__dict__["linearize_rows"]
    assert ctrl.force_constraint._offsets[0] is LINEARIZATION_VIEWS
    tasks = [t for t in planner.tasks if isinstance(t, ConstantJacobianTask)
             and t.is_active(_context(planner, warp=ctrl.warp))]
    assert len(tasks) == 6 + feedback  # the leveling task with the warp
    hessians = [t._H for t in tasks]
    struct = ctrl.force_constraint._structure_cache[1]
    P = planner.builder._P
    made = []
    for t in tasks:  # a Jacobian made at the first tick would be a cache not found
        monkeypatch.setattr(t, "compute_jacobian",
                            lambda ctx, f=t.compute_jacobian: made.append(1) or f(ctx))
    spare, Gs = planner.builder._spare, []
    first = _run(ctrl, plant, 1, Gs)
    assert made == []
    assert spare is not None and Gs[0] is spare  # the first G's array made beforehand
    assert all(t._H is H for t, H in zip(tasks, hessians))
    assert ctrl.force_constraint._structure_cache[1] is struct
    assert fmap.iv is buffers[0] and fmap.arrays["rows"] is buffers[1]  # not made again
    assert model._est._calls.__dict__["linearize_rows"] is nodes
    assert P is not None and planner.builder._P is P
    assert first + _run(ctrl, plant, 39) == plain


@pytest.mark.parametrize("other", ["steps", "dt", "warp"])
def test_a_structure_prepared_for_another_is_rebuilt(machine, monkeypatch, other):
    plain = _run(*_controller(machine, monkeypatch), 12)
    ctrl, plant = _controller(machine, monkeypatch)
    planner = ctrl.planner
    if other == "steps":
        steps = planner.prediction.step_lengths * 1.5
        ctx = _context(planner, prediction=CondensedPrediction(planner.layout, steps),
                       warp=ctrl.warp)
    elif other == "dt":
        ctx = _context(planner, dt=2 * planner.dt, warp=ctrl.warp)
    else:
        ctx = _context(planner, warp=2 * ctrl.warp)
    planner.builder.prepare(ctx)
    struct = ctrl.force_constraint._structure_cache[1]
    leveling = next(t for t in planner.tasks if isinstance(t, HorizonLevelingTask))
    H = leveling._H
    assert H is not None
    assert _run(ctrl, plant, 12) == plain
    assert leveling._H is not H
    assert (ctrl.force_constraint._structure_cache[1] is struct) == (other == "warp")


def test_planner_construction_prepares(machine):
    model, feedback = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=feedback)
    assert ctrl.force_constraint._structure_cache is not None
    if model._est.backend == "compiled":  # the model's node buffers (`prepare_nodes`)
        assert ctrl.force_constraint._offsets[0] is LINEARIZATION_VIEWS
        assert "linearize_rows" in model._est._calls.__dict__
    assert all(t._cache_key is not None for t in ctrl.planner.tasks
               if isinstance(t, ConstantJacobianTask) and t.is_active(_context(ctrl.planner)))
    # The controller prepares the leveling task with the warp its contexts will carry.
    assert ctrl.warp is not None
    leveling = next(t for t in ctrl.planner.tasks if isinstance(t, HorizonLevelingTask))
    assert leveling._H is not None
    assert leveling._cache_key[0] == leveling.structure_key(_context(ctrl.planner, warp=ctrl.warp))


def test_prepared_rows_are_the_first_calls(machine):
    """`prepare_rows` makes the buffers the first `linearize_first` would, nothing else."""
    prepared, fresh = PayloadEstimator(machine), PayloadEstimator(machine)
    if prepared._est.backend != "compiled":
        pytest.skip("no C compiler")
    views, width = prepare_rows(prepared._est, 2, N_AXES)
    nodes = prepared._est._calls.__dict__["linearize_rows"]
    assert views is LINEARIZATION_VIEWS and width == nodes.out.shape[1]
    assert (nodes.capacity, nodes.m) == (2, N_AXES)
    assert prepared.n_clipped == 0 and prepared._last is None
    state = make_state(machine)
    dt = np.array([0.1, 0.3])
    q = np.tile(state.q[:N_AXES], (2, 1))
    qd = np.tile(state.qd[:N_AXES], (2, 1))
    a = linearize_first(prepared._est, state, dt, q, qd)
    b = linearize_first(fresh._est, state, dt, q, qd)
    assert prepared._est._calls.__dict__["linearize_rows"] is nodes
    assert a[0]._row.size == width and a[0]._row.tobytes() == b[0]._row.tobytes()
    assert a[1].tobytes() == b[1].tobytes()
    quasi = PayloadEstimator(machine, method="quasi-static")
    assert prepare_rows(quasi._est, 2, N_AXES) is None
    assert quasi.prepare_nodes(2, N_AXES) is None
    assert fresh.prepare_nodes(2, N_AXES) == (views, width)
