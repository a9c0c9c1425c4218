"""The margin's kernels (`estimators.margin_kernel`): the linearizations' and the stepped
forces' bits on closed-loop ticks and random states, and None where they do not apply."""

from dataclasses import replace

import numpy as np
import pytest

import scenarios.closed_loop as closed_loop
from estimators.estimator import NormalForceEstimator
from estimators.margin_kernel import MARGIN_STEP, margin_terms
from estimators.payload import SPAN, PayloadEstimator, anchor_machines
from estimators.suspension_response import stepped_forces
from estimators.uncertainty import closure_margin, force_margin, normal_force_std
from models import build_reference_machine
from models.state import WheelContacts
from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()


def _compiled(est: PayloadEstimator) -> bool:
    return est._est._kernels is not None and est._est._kernels.compiled


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _check_terms(closure: PayloadEstimator, state, what) -> None:
    """`margin_terms` against `linearize` and the stepped forces, bit for bit."""
    terms = closure.margin_terms(state, MARGIN_STEP)
    assert terms is not None, what
    g, d_qd, in_contact, stepped = (np.array(t) for t in terms)
    lin = closure.linearize(state)
    assert _same(g, lin.G) and _same(d_qd, lin.d_qd), what
    assert _same(in_contact, lin.in_contact), what
    full = stepped_forces(closure._est, state, MARGIN_STEP, payload_step=SPAN)
    assert _same(stepped, full[:3]), what
    assert _same(closure.payload_sensitivity(state), (full[3] - full[0]) / SPAN), what
    assert _same(closure.normal_forces(state), closure._est.estimate(state).normal_forces)


def _check_joint(model: PayloadEstimator, closure: PayloadEstimator, state, what) -> None:
    """`linearize_with_margin` against a fresh `linearize` and `_check_terms`, bit for bit."""
    model._last = closure._stepped = None  # nothing kept: the joint call runs
    got = model.linearize_with_margin(state, closure, MARGIN_STEP)
    assert got is not None, what
    lin, terms = got
    assert model.linearize(state) is lin  # kept for the plan's first node
    fresh = NormalForceEstimator(anchor_machines(MACHINE)[0], strokes="clip")
    fresh.payload_mass = model.payload_mass
    ref = fresh.linearize(state)
    for name in ("normal_forces", "G", "g0", "d_q", "d_qd", "in_contact"):
        assert _same(getattr(lin, name), getattr(ref, name)), (what, name)
    assert (lin.mode, lin.clipped, lin.time) == (ref.mode, ref.clipped, ref.time), what
    if terms is None:
        assert closure.margin_terms(state, MARGIN_STEP) is None, what
        return
    joint = [np.array(t) for t in terms]
    alone = [np.array(t) for t in closure.margin_terms(state, MARGIN_STEP)]
    assert all(_same(a, b) for a, b in zip(joint, alone)), what
    _check_terms(closure, state, what)


@pytest.fixture(scope="module")
def ticks(tmp_path_factory):
    """(closure, model, state, uncertainty, confidence, margin, payloads) of every fifth tick
    of a short run; payloads: the closure's and the model's masses then."""
    seen, run = [], closed_loop.closure_margin

    def spy(closure, model, state, unc, confidence):
        margin = run(closure, model, state, unc, confidence)
        seen.append((closure, model, state, unc, confidence, margin.copy(),
                     (closure.payload_mass, model.payload_mass)))
        return margin

    closed_loop.closure_margin = spy
    try:
        run_closed_loop(DEFAULT_SCENARIO, tmp_path_factory.mktemp("run"), "mpc-full",
                        duration=2.0, progress=False)
    finally:
        closed_loop.closure_margin = run
    return seen[::5]


def test_closed_loop_ticks_are_the_linearizations_bits(ticks):
    assert len(ticks) > 20
    closure = ticks[0][0]
    if not _compiled(closure):
        pytest.skip("no compiled kernels")
    for k, (closure, model, state, unc, confidence, margin, masses) in enumerate(ticks):
        closure.payload_mass, model.payload_mass = masses
        _check_terms(closure, state, k)
        _check_joint(model, closure, state, k)
        # The margin again, through the kernel, and as numpy makes it.
        assert _same(closure_margin(closure, model, state, unc, confidence), margin), k
        lin = closure.linearize(state)
        lin = replace(lin, G=lin.G - model.linearize(state).G)
        full = stepped_forces(closure._est, state, MARGIN_STEP)
        d_s = ((full[1:] - full[0]) / MARGIN_STEP).T
        numpy_margin = force_margin(normal_force_std(
            lin, unc, d_s, closure.payload_sensitivity(state)), confidence)
        assert _same(numpy_margin, margin), k


def test_random_states_and_payloads_are_the_linearizations_bits():
    closure = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    model = PayloadEstimator(MACHINE, strokes="clip")
    if not _compiled(closure):
        pytest.skip("no compiled kernels")
    rng = np.random.default_rng(7)
    for k in range(24):
        closure.payload_mass = float(rng.uniform(0.0, 300.0))
        model.payload_mass = float(rng.uniform(0.0, 300.0))
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        if k % 3 == 1:  # a rear wheel lifted (the three-wheel system), or two (tipping)
            flags = np.array([True, k % 2 == 0, k % 5 != 0, k % 2 == 1])
            points = closure._est.estimate(s).contact_points  # the wheels' lowest points
            s = replace(s, contacts=WheelContacts(flags, np.zeros((4, 3)), points,
                                                  np.tile(s.base_rotation[2], (4, 1))))
        if closure.linearize(s).mode == "tipping":
            assert closure.margin_terms(s, MARGIN_STEP) is None
            model._last = None
            assert model.linearize_with_margin(s, closure, MARGIN_STEP) is None
            continue
        _check_terms(closure, s, k)
        _check_joint(model, closure, s, k)


def test_where_it_does_not_apply_it_says_none():
    s = random_state(MACHINE, np.random.default_rng(3), max_tilt=0.2, speed=0.3)
    closure = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    assert s.suspension_force is None and closure.margin_terms(s, MARGIN_STEP) is None
    s = replace(s, suspension_force=np.array([3e4, 4e4]))
    quasi = PayloadEstimator(MACHINE, method="quasi-static", fourth="cylinder-force")
    assert margin_terms(quasi._est, s, MARGIN_STEP, SPAN) is None
    reference = PayloadEstimator(MACHINE, fourth="cylinder-force", backend="reference")
    assert reference.margin_terms(s, MARGIN_STEP) is None
    model = PayloadEstimator(MACHINE, strokes="clip")
    assert model.linearize_with_margin(s, reference, MARGIN_STEP) is None  # other kernels
    assert model.linearize_with_margin(s, quasi, MARGIN_STEP) is None
    assert model.linearize_with_margin(s, closure, MARGIN_STEP) is not None
    assert model.linearize_with_margin(s, closure, MARGIN_STEP) is None  # kept already
