"""Property-based fuzzing of the public API of models, estimators and wbc (issue 11).

The property: every call with a generated input (most of them bad: NaN, inf, wrong shapes
and dtypes, strings, huge finite values, reflections as rotations, out-of-range strokes and
goals, singular contact geometry) either returns a valid, finite result or raises a typed
project error (`models.errors.ModelError`, `estimators.EstimatorError`, `wbc.WbcError`).
Never a generic exception from numpy or the standard library, never a NaN/inf output.

Each test fuzzes one part of the API, prints its figures (inputs generated, calls, outcome
categories) and fails with the first leaks it saw. `test_fuzz_figures` (last) prints the
totals and checks that at least 10,000 inputs were generated when the whole module ran.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import traceback
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import models.terrain as terrain
from estimators import EstimatorError, NormalForceEstimator, StateBatch
from models import MachineState, ModelError, WheelContacts, build_reference_machine
from wbc import (
    AxisLimits,
    ControllerConfig,
    ForceConfig,
    JointGoal,
    MpcConfig,
    QPConfig,
    ReferenceConfig,
    TcpGoal,
    WbcError,
    make_controller,
)

PROJECT_ERRORS = (ModelError, EstimatorError, WbcError)
CATEGORIES = ("typed error", "valid result", "generic exception", "NaN/inf output")
TOTAL: Counter = Counter()  # over the module: inputs, calls and the outcome categories
SECTIONS: set = set()
ALL_SECTIONS = {"state", "batch", "estimator", "estimator_batch", "estimator_options",
                "terrain", "goals", "step", "config"}


def _finite(value, depth: int = 0) -> bool:
    """True when every number reachable in ``value`` is finite.

    A condition number may be +inf (a system with no wheel in contact, documented in
    `estimators.Estimate`); every other number must be finite.
    """
    if depth > 4 or value is None or isinstance(value, (str, bytes, bool)):
        return True
    if dataclasses.is_dataclass(value) and hasattr(value, "condition"):
        cond = np.asarray(value.condition, float)
        if np.isnan(cond).any():
            return False
        return all(_finite(getattr(value, f.name), depth + 1)
                   for f in dataclasses.fields(value) if f.name != "condition")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            return bool(np.all(np.isfinite(value)))
        if value.dtype.kind == "O":
            return all(_finite(v, depth + 1) for v in value.flat)
        return True
    if isinstance(value, (float, np.floating, complex)):
        return math.isfinite(abs(value))
    if isinstance(value, dict):
        return all(_finite(v, depth + 1) for v in value.values())
    if isinstance(value, (tuple, list)):
        return all(_finite(v, depth + 1) for v in value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return all(_finite(getattr(value, f.name), depth + 1)
                   for f in dataclasses.fields(value))
    return True


class Tally:
    """Outcomes of the calls of one fuzz section."""

    def __init__(self, section: str):
        self.section = section
        self.inputs = 0
        self.outcomes: Counter = Counter()
        self.leaks: list[str] = []

    def counted(self, fn):
        """Count an input each time ``fn`` (a fuzz body) runs to its end."""
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            fn(*args, **kwargs)
            self.inputs += 1
        return wrapper

    def call(self, label: str, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` classified; the result if valid, else None."""
        try:
            out = fn(*args, **kwargs)
        except PROJECT_ERRORS:
            self.outcomes["typed error"] += 1
            return None
        except Exception as exc:  # noqa: BLE001 - a leak is what this test looks for
            self.outcomes["generic exception"] += 1
            where = traceback.extract_tb(exc.__traceback__)[-1]
            self.leaks.append(f"{label}: {type(exc).__name__}: {str(exc)[:200]} (at "
                              f"{where.filename}:{where.lineno})")
            return None
        if not _finite(out):
            self.outcomes["NaN/inf output"] += 1
            self.leaks.append(f"{label}: non-finite output {type(out).__name__}: "
                              f"{str(out)[:300]} from {str(args)[:300]}")
            return None
        self.outcomes["valid result"] += 1
        return out

    def finish(self, min_inputs: int) -> None:
        """Print the figures, add them to the module totals and check the property."""
        calls = sum(self.outcomes.values())
        print(f"\nfuzz {self.section}: {self.inputs} inputs, {calls} calls: "
              + ", ".join(f"{c} {self.outcomes[c]}" for c in CATEGORIES))
        TOTAL["inputs"] += self.inputs
        TOTAL["calls"] += calls
        TOTAL.update(self.outcomes)
        SECTIONS.add(self.section)
        kinds = Counter(leak.split(":")[0] + ":" + leak.split(":")[1] for leak in self.leaks)
        assert not self.leaks, (f"{len(self.leaks)} leaks, by kind {dict(kinds)}; first: "
                                + "\n".join(self.leaks[:8]))
        assert self.inputs >= min_inputs


def fuzz(n: int):
    """Hypothesis settings of one section: ``n`` examples, no deadline, no database.

    Derandomized (the same inputs every run, so the suite is reproducible); set
    ``WBC_FUZZ_RANDOM=1`` to draw new inputs, and raise the counts with
    ``WBC_FUZZ_SCALE`` (a factor >= 1) for a longer hunt.
    """
    scale = float(os.environ.get("WBC_FUZZ_SCALE", "1"))
    return settings(max_examples=max(1, int(n * scale)), deadline=None, database=None,
                    derandomize=os.environ.get("WBC_FUZZ_RANDOM") != "1",
                    suppress_health_check=list(HealthCheck))


# ---------------------------------------------------------------------- strategies
HUGE = st.sampled_from([1e300, -1e300, 1e308, -1.7e308, 1e154, 1e20])
SPECIAL = st.sampled_from([np.nan, np.inf, -np.inf])
ANY_FLOAT = st.one_of(st.floats(), HUGE, SPECIAL)
REFLECTION = np.diag([1.0, 1.0, -1.0])


def junk():
    """Values of the wrong kind: strings, None, objects, ragged lists, complex, bools."""
    return st.one_of(
        st.text(max_size=5), st.none(), st.just(object()), st.just([[1.0, 2.0], [3.0]]),
        st.just(["a"] * 3), st.just(1 + 2j), st.booleans(), st.just({"x": 1}),
        st.just(np.array(["x", "y", "z"])), st.just(np.zeros(3, complex) + 1j),
        st.integers(-10**30, 10**30))


def bad_array(shape: tuple[int, ...]):
    """An array that differs from a valid float array of ``shape`` in one way or more."""
    wrong_shape = st.one_of(st.just(()), st.just((0,)), st.just(shape[:-1] or (2,)),
                            st.just(shape + (1,)), st.just(tuple(s + 1 for s in shape)))
    return st.one_of(
        hnp.arrays(float, shape, elements=ANY_FLOAT),
        hnp.arrays(float, wrong_shape, elements=st.floats(-10, 10)),
        hnp.arrays(np.int64, shape, elements=st.integers(-5, 5)),
        hnp.arrays(bool, shape),
        st.just(np.full(shape, "1.0")),
        SPECIAL, HUGE, junk())


def finite_array(shape: tuple[int, ...], scale: float = 1.0):
    """A finite float array of ``shape``, sometimes with huge entries."""
    return st.one_of(hnp.arrays(float, shape, elements=st.floats(-scale, scale)),
                     hnp.arrays(float, shape, elements=st.one_of(st.floats(-scale, scale),
                                                                 HUGE)))


# ---------------------------------------------------------------------- shared objects
@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


@pytest.fixture(scope="module")
def base(machine):
    """Valid constructor arguments of a `MachineState` and a `WheelContacts`."""
    q = machine.coordinates.home()
    state = dict(base_position=np.array([0.0, 0.0, 0.45]), base_rotation=np.eye(3),
                 base_twist=np.zeros(6), base_acceleration=np.zeros(6), q=q,
                 qd=np.zeros(13), qdd=np.zeros(13), time=0.0)
    points = np.array([[1.5, 1.0, -0.5], [-1.5, 1.0, -0.5], [1.5, -1.0, -0.5],
                       [-1.5, -1.0, -0.5]])
    normal = np.tile([0.0, 0.0, 1.0], (4, 1))
    contacts = dict(in_contact=np.ones(4, bool), force_in_fb=np.tile([0, 0, 5e4], (4, 1)),
                    point_in_fb=points, normal_in_fb=normal)
    return state, contacts


@pytest.fixture(scope="module")
def estimators(machine):
    return {"raise": NormalForceEstimator(machine),
            "clip": NormalForceEstimator(machine, strokes="clip"),
            "quasi-static": NormalForceEstimator(machine, method="quasi-static"),
            "cylinder": NormalForceEstimator(machine, fourth="cylinder-force")}


STATE_FIELDS = {"base_position": (3,), "base_rotation": (3, 3), "base_twist": (6,),
                "base_acceleration": (6,), "q": (13,), "qd": (13,), "qdd": (13,)}
CONTACT_FIELDS = {"force_in_fb": (4, 3), "point_in_fb": (4, 3), "normal_in_fb": (4, 3)}


# ---------------------------------------------------------------------- models
def test_fuzz_state_constructors(base):
    """`MachineState` and `WheelContacts` with one or more bad fields."""
    tally = Tally("state")
    state_kw, contact_kw = base

    extra = {"time": st.one_of(ANY_FLOAT, junk()),
             "suspension_force": st.one_of(bad_array((2,)), hnp.arrays(float, (1,))),
             "servo_setpoint": bad_array((9,)),
             "contacts": junk(),
             "base_rotation": st.one_of(st.just(REFLECTION), st.just(-np.eye(3)),
                                        st.just(2 * np.eye(3)), bad_array((3, 3)))}
    state_bad = st.fixed_dictionaries({}, optional={
        **{k: bad_array(s) for k, s in STATE_FIELDS.items() if k != "base_rotation"},
        **extra})
    contact_bad = st.fixed_dictionaries({}, optional={
        "in_contact": st.one_of(bad_array((4,)), st.just(np.array([2, 0, 1, 1])),
                                st.just(np.array([0.5, 1, 1, 1])),
                                st.just(["yes", "no", "yes", "no"])),
        **{k: bad_array(s) for k, s in CONTACT_FIELDS.items()}})

    @fuzz(1800)
    @given(state_bad, contact_bad, st.booleans())
    @tally.counted
    def run(bad_state, bad_contacts, with_contacts):
        contacts = tally.call("WheelContacts", WheelContacts, **{**contact_kw, **bad_contacts})
        kw = {**state_kw, **bad_state}
        if with_contacts and contacts is not None and "contacts" not in bad_state:
            kw["contacts"] = contacts
        tally.call("MachineState", MachineState, **kw)

    run()
    tally.finish(1800)


def test_fuzz_state_batch(base):
    """`StateBatch` with bad fields, wrong row counts and reflections."""
    tally = Tally("batch")
    state_kw, contact_kw = base

    @fuzz(600)
    @given(st.integers(0, 4), st.data())
    @tally.counted
    def run(n, data):
        kw = {k: np.repeat(np.asarray(state_kw[k])[None], n, axis=0)
              for k in ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd")}
        for name in data.draw(st.sets(st.sampled_from(
                [*kw, "in_contact", "force_in_fb", "point_in_fb", "normal_in_fb",
                 "suspension_force", "time"]), min_size=1, max_size=3)):
            shape = {"in_contact": (n, 4), "suspension_force": (n, 2), "time": (n,),
                     "base_rotation": (n, 3, 3)}.get(name)
            shape = shape or ((n, 4, 3) if name.endswith("_fb") else kw[name].shape)
            kw[name] = data.draw(st.one_of(
                bad_array(shape), st.just(np.repeat(REFLECTION[None], n, axis=0)),
                hnp.arrays(float, shape, elements=st.floats(-3, 3)),
                st.just(np.full(shape, 2)), st.just(np.ones((n + 1,) + shape[1:]))))
        tally.call("StateBatch", StateBatch, **kw)

    run()
    tally.finish(600)


def test_fuzz_terrain():
    """Terrain constructors and queries with bad and extreme parameters."""
    tally = Tally("terrain")
    number = st.one_of(ANY_FLOAT, st.floats(-100, 100), junk())
    interval = st.one_of(st.tuples(ANY_FLOAT, ANY_FLOAT), st.tuples(st.floats(-1e6, 1e6),
                                                                    st.floats(-1e6, 1e6)),
                         junk())
    spacing = st.one_of(st.floats(1e-9, 100), ANY_FLOAT, junk())
    heights = st.one_of(bad_array((3, 4)), hnp.arrays(float, (3, 4), elements=st.floats()),
                        hnp.arrays(float, (2, 2), elements=HUGE))
    makers = {
        "Terrain": st.fixed_dictionaries({"name": st.one_of(st.just("t"), junk()),
                                          "heights": heights},
                                         optional={"x_range": interval, "y_range": interval,
                                                   "friction": number}),
        "flat": st.fixed_dictionaries({}, optional={"height": number, "x_range": interval,
                                                    "y_range": interval, "friction": number}),
        "ramp": st.fixed_dictionaries({"angle_deg": number}, optional={
            "start_x": number, "transition_length": number, "spacing": spacing,
            "x_range": interval, "y_range": interval}),
        "side_slope": st.fixed_dictionaries({"angle_deg": number}, optional={
            "spacing": spacing, "x_range": interval, "y_range": interval}),
        "rough": st.fixed_dictionaries({"seed": st.one_of(st.integers(-5, 10**20), junk())},
                                       optional={"max_slope_deg": number,
                                                 "feature_length": number,
                                                 "spacing": spacing, "start_radius": number,
                                                 "blend_length": number}),
    }

    @fuzz(2000)
    @given(st.sampled_from(sorted(makers)), st.data(), st.tuples(number, number))
    @tally.counted
    def run(kind, data, point):
        kw = data.draw(makers[kind])
        if kind == "rough":  # keep generated grids small: the default ranges, coarse
            kw.setdefault("spacing", 1.0)
        maker = terrain.Terrain if kind == "Terrain" else getattr(terrain, kind)
        t = tally.call(kind, maker, **kw)
        if t is not None:
            for method in ("height", "normal", "gradient"):
                tally.call(f"{kind}.{method}", getattr(t, method), *point)
            tally.call(f"{kind}.normal(array)", t.normal, np.array([0.0, 1.0]), point[1])

    run()
    tally.finish(2000)


# ---------------------------------------------------------------------- estimators
def bad_state_values(base, machine):
    """Constructor arguments of states that pass `MachineState` but challenge the estimator.

    Out-of-range strokes and joints (the telescope at 101 m), huge finite rates and
    accelerations that overflow, one-wheel or coincident contact points (singular
    geometry), huge or zero cylinder forces.
    """
    state_kw, contact_kw = base
    lo, hi = machine.coordinates.lower[:9], machine.coordinates.upper[:9]

    @st.composite
    def strategy(draw):
        kw = dict(state_kw)
        q = kw["q"].copy()
        for i in draw(st.sets(st.integers(0, 12), max_size=3)):
            q[i] = draw(st.one_of(st.floats(-2, 2), st.floats(-1e6, 1e6), st.just(101.0),
                                  HUGE, st.just(float(lo[i] if i < 9 else 0) - 1e-3),
                                  st.just(float(hi[i] if i < 9 else 0) + 1e-3)))
        kw["q"] = q
        for name in draw(st.sets(st.sampled_from(["base_twist", "base_acceleration", "qd",
                                                  "qdd"]), max_size=2)):
            kw[name] = draw(finite_array(kw[name].shape, scale=draw(st.sampled_from(
                [1.0, 1e3, 1e8]))))
        kw["time"] = draw(st.floats(-1e300, 1e300))
        if draw(st.booleans()):
            kw["suspension_force"] = draw(finite_array((2,), scale=1e6))
        if draw(st.booleans()):
            ckw = dict(contact_kw)
            ckw["in_contact"] = draw(hnp.arrays(bool, (4,)))
            ckw["point_in_fb"] = draw(st.one_of(
                finite_array((4, 3), scale=3.0), st.just(np.zeros((4, 3))),
                st.just(np.tile([1.0, 0.0, -0.5], (4, 1))),
                st.just(contact_kw["point_in_fb"] * np.array([1.0, 0.0, 1.0]))))
            ckw["force_in_fb"] = draw(finite_array((4, 3), scale=1e5))
            ckw["normal_in_fb"] = draw(st.one_of(st.just(contact_kw["normal_in_fb"]),
                                                 finite_array((4, 3))))
            kw["contacts"] = WheelContacts(**ckw)
        return kw

    return strategy()


def test_fuzz_estimator_methods(machine, base, estimators):
    """`estimate`, `constraint`, `linearize` on states the estimator must refuse or solve."""
    tally = Tally("estimator")

    @fuzz(500)
    @given(bad_state_values(base, machine), st.sampled_from(sorted(estimators)))
    @tally.counted
    def run(kw, which):
        state = tally.call("MachineState", MachineState, **kw)
        est = estimators[which]
        if state is None:
            return
        for method in ("estimate", "constraint", "linearize"):
            tally.call(f"{which}.{method}", getattr(est, method), state)

    run()
    tally.call("estimate(not a state)", estimators["raise"].estimate, {"q": np.zeros(13)})
    tally.finish(500)


def test_fuzz_estimate_batch(machine, base, estimators):
    """`estimate_batch` on mappings, sequences and batches with bad rows."""
    tally = Tally("estimator_batch")
    state_kw, _ = base

    @fuzz(300)
    @given(st.lists(bad_state_values(base, machine), min_size=0, max_size=3),
           st.sampled_from(sorted(estimators)), st.booleans(), st.data())
    @tally.counted
    def run(kws, which, strict, data):
        est = estimators[which]
        states = [s for s in (tally.call("MachineState", MachineState, **kw) for kw in kws)
                  if s is not None]
        if states and len({s.contacts is None for s in states}) > 1:
            states = [dataclasses.replace(s, contacts=None) for s in states]
        tally.call(f"{which}.estimate_batch", est.estimate_batch, states, strict=strict)
        mapping = {k: np.repeat(np.asarray(state_kw[k])[None], 2, axis=0)
                   for k in ("base_rotation", "base_twist", "base_acceleration", "q", "qd",
                             "qdd")}
        name = data.draw(st.sampled_from([*mapping, "bogus"]))
        mapping[name] = data.draw(st.one_of(bad_array((2,) + np.shape(state_kw.get(
            name, 0.0))), st.just(np.repeat(REFLECTION[None], 2, axis=0))))
        tally.call(f"{which}.estimate_batch(mapping)", est.estimate_batch, mapping,
                   strict=strict)
        tally.call(f"{which}.estimate_batch(junk)", est.estimate_batch,
                   data.draw(junk()), strict=strict)

    run()
    tally.finish(300)


def test_fuzz_estimator_options(machine):
    """`NormalForceEstimator(...)` with bad options."""
    tally = Tally("estimator_options")
    option = st.one_of(junk(), ANY_FLOAT)

    @fuzz(1000)
    @given(st.fixed_dictionaries({}, optional={
        "method": st.one_of(st.sampled_from(["full", "quasi-static"]), option),
        "fourth": st.one_of(st.sampled_from(["d-beta", "cylinder-force"]), option),
        "D": st.one_of(ANY_FLOAT, junk()), "beta": st.one_of(ANY_FLOAT, junk()),
        "backend": st.one_of(st.sampled_from(["auto", "reference"]), option),
        "strokes": st.one_of(st.sampled_from(["raise", "clip"]), option)}),
        st.one_of(st.just(machine), junk()))
    @tally.counted
    def run(kw, mach):
        tally.call("NormalForceEstimator", NormalForceEstimator, mach, **kw)

    run()
    tally.finish(1000)


# ---------------------------------------------------------------------- wbc
@pytest.fixture(scope="module")
def controllers(machine):
    return {name: make_controller(name, machine)
            for name in ("tracking", "mpc-quasi-static", "mpc-full")}


def test_fuzz_goals(machine, controllers):
    """`JointGoal`, `TcpGoal` and `set_goal` with NaN, wrong shapes, out-of-range goals."""
    tally = Tally("goals")
    home = machine.coordinates.home()
    crane = st.one_of(bad_array((7,)), hnp.arrays(float, (7,), elements=st.floats(-200, 200)),
                      st.builds(lambda i, v: np.where(np.arange(7) == i, v, home[2:9]),
                                st.integers(0, 6), st.sampled_from([101.0, -1.0, 1e300])))
    suspension = st.one_of(st.none(), bad_array((2,)), hnp.arrays(float, (2,),
                                                                  elements=st.floats(-1, 1)))

    @fuzz(2500)
    @given(crane, suspension, bad_array((3,)), st.sampled_from(sorted(controllers)),
           st.one_of(st.none(), junk()))
    @tally.counted
    def run(crane_goal, suspension_goal, tcp, name, other):
        ctrl = controllers[name]
        goal = tally.call("JointGoal", JointGoal, crane=crane_goal, suspension=suspension_goal)
        if goal is not None:
            tally.call(f"{name}.set_goal", ctrl.set_goal, goal)
        tcp_goal = tally.call("TcpGoal", TcpGoal, tcp, suspension=suspension_goal)
        if tcp_goal is not None:
            tally.call(f"{name}.set_goal(tcp)", ctrl.set_goal, tcp_goal)
        if other is not None:
            tally.call(f"{name}.set_goal(junk)", ctrl.set_goal, other)
        tally.call("make_controller", make_controller, other, machine)
        ctrl.reset()

    run()
    tally.finish(2500)


def test_fuzz_controller_step(machine, base, controllers):
    """`step` of each controller on extreme states and junk, after bad or far goals."""
    tally = Tally("step")
    home = machine.coordinates.home()

    @fuzz(120)
    @given(bad_state_values(base, machine), st.sampled_from(sorted(controllers)),
           st.one_of(st.none(), hnp.arrays(float, (7,), elements=st.floats(-1, 2))),
           st.one_of(st.none(), junk()))
    @tally.counted
    def run(kw, name, crane_goal, other):
        ctrl = controllers[name]
        ctrl.reset()
        if crane_goal is not None:
            goal = tally.call("JointGoal", JointGoal, crane=np.clip(
                crane_goal, ctrl.limits.position_lower[2:], ctrl.limits.position_upper[2:]))
            tally.call(f"{name}.set_goal", ctrl.set_goal, goal)
        state = tally.call("MachineState", MachineState, **kw)
        if state is not None:
            tally.call(f"{name}.step", ctrl.step, state)
        if other is not None:
            tally.call(f"{name}.step(junk)", ctrl.step, other)
        tally.call(f"{name}.step(home)", ctrl.step, MachineState(
            **{**base[0], "q": home, "time": 0.01}))

    run()
    tally.finish(120)


def test_fuzz_config(machine):
    """`AxisLimits` and the controller config objects with bad numbers."""
    tally = Tally("config")
    limits = AxisLimits.from_machine(machine)
    number = st.one_of(ANY_FLOAT, junk(), st.integers(-3, 3), st.floats(-10, 10))
    configs = {ReferenceConfig: ("jerk_time", "velocity_fraction", "acceleration_fraction",
                                 "governor_error"),
               QPConfig: tuple(f.name for f in dataclasses.fields(QPConfig)),
               MpcConfig: tuple(f.name for f in dataclasses.fields(MpcConfig)),
               ForceConfig: tuple(f.name for f in dataclasses.fields(ForceConfig)),
               ControllerConfig: ("dt", "solver", "eps_abs", "eps_rel", "max_iter",
                                  "position_margin", "reference", "qp", "mpc", "force")}

    @fuzz(1900)
    @given(st.sampled_from([AxisLimits, "from_machine", "payload", *configs]), st.data())
    @tally.counted
    def run(kind, data):
        if kind is AxisLimits:
            kw = {f.name: getattr(limits, f.name) for f in dataclasses.fields(AxisLimits)}
            for name in data.draw(st.sets(st.sampled_from(sorted(kw)),
                                          min_size=1, max_size=2)):
                kw[name] = data.draw(st.one_of(bad_array((9,)), st.just(-kw[name])
                                               if name != "names" else junk()))
            tally.call("AxisLimits", AxisLimits, **kw)
        elif kind == "payload":  # bad masses only: a valid one builds a machine (0.6 s)
            mass = data.draw(st.one_of(SPECIAL, HUGE, st.floats(max_value=0.0), junk(),
                                       st.floats(min_value=1.0001e4)).filter(
                lambda m: not isinstance(m, int) or isinstance(m, bool)))
            tally.call("build_reference_machine", build_reference_machine, mass)
        elif kind == "from_machine":
            tally.call("AxisLimits.from_machine", AxisLimits.from_machine, machine,
                       data.draw(number))
        else:
            names = data.draw(st.sets(st.sampled_from(configs[kind]), min_size=1, max_size=2))
            tally.call(kind.__name__, kind, **{n: data.draw(number) for n in names})

    run()
    tally.finish(1900)


def test_fuzz_figures():
    """The totals; the whole module generates at least 10,000 inputs per run."""
    print(f"\nfuzz total: {TOTAL['inputs']} inputs, {TOTAL['calls']} calls: "
          + ", ".join(f"{c} {TOTAL[c]}" for c in CATEGORIES))
    if SECTIONS != ALL_SECTIONS:
        pytest.skip(f"only {sorted(SECTIONS)} ran")
    assert TOTAL["inputs"] >= 10_000
    assert TOTAL["generic exception"] == 0 and TOTAL["NaN/inf output"] == 0
