"""The compiled efforts and link-acceleration kernels against Pinocchio's RNEA and CRBA."""

from types import SimpleNamespace

import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts
from estimators.efforts_kernel import INPUTS, EffortKernels, kernels_for
from estimators.errors import EstimatorError
from models import build_reference_machine
from models.rotations import rpy_rotation
from models.state import N_SERVO_AXES, MachineState

MACHINE = build_reference_machine()
# A point on a moving link, one on the fixed payload body (merged into its host by the
# tree), one on the chassis.
MOUNTS = (("lift", (1.2, 0.0, 0.15)), ("payload", (0.1, -0.2, 0.05)),
          ("chassis", (0.5, 0.3, 0.8)))


def _states(n=12, seed=3):
    """Random states: any attitude, base motion, strokes inside their ranges, rates."""
    rng = np.random.default_rng(seed)
    coords = MACHINE.coordinates
    lo, hi = coords.lower, coords.upper
    out = []
    for _ in range(n):
        q = coords.home().copy()
        finite = np.isfinite(lo) & np.isfinite(hi)
        q[finite] = lo[finite] + rng.uniform(0.05, 0.95, finite.sum()) * (hi - lo)[finite]
        out.append(MachineState(
            rng.normal(size=3), rpy_rotation(*rng.uniform(-0.5, 0.5, 3)),
            rng.normal(scale=0.5, size=6), rng.normal(scale=2.0, size=6), q,
            rng.normal(scale=0.2, size=q.size), rng.normal(scale=0.5, size=q.size)))
    return out


STATES = _states()


@pytest.fixture(scope="module")
def pair():
    kernels = kernels_for(MACHINE)
    if kernels is None:
        pytest.skip("no C compiler: the efforts run on Pinocchio only")
    return ActuatorEfforts(MACHINE), ActuatorEfforts(MACHINE, compiled=False)


@pytest.mark.parametrize("mass", [0.0, 150.0, 420.0])
def test_affine_and_regressor_equal_pinocchios(pair, mass):
    compiled, reference = pair
    for eff in pair:
        eff.payload_mass = mass
    for st in STATES:
        for eff in pair:  # each computes its own (the shared last motion is per machine)
            eff._shared[0] = None
        E, e0 = compiled.affine(st)
        compiled._shared[0] = None
        f0, y = compiled.payload_regressor(st)
        reference._shared[0] = None
        E_ref, e0_ref = reference.affine(st)
        f0_ref, y_ref = reference.payload_regressor(st)
        scale = np.abs(E_ref).max()
        np.testing.assert_allclose(E, E_ref, rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(e0, e0_ref, rtol=0, atol=1e-10 * np.abs(e0_ref).max())
        np.testing.assert_allclose(f0 + mass * y, f0_ref + mass * y_ref, rtol=0,
                                   atol=1e-10 * np.abs(f0_ref).max())
        np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-9 * np.abs(y_ref).max())


def test_point_specific_forces_equal_pinocchios(pair):
    compiled, reference = pair
    for st in STATES:
        a, b = compiled.point_specific_forces(st, MOUNTS)
        a_ref, b_ref = reference.point_specific_forces(st, MOUNTS)
        assert a.shape == (9, N_SERVO_AXES) and b.shape == (9,)
        np.testing.assert_allclose(a, a_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b, b_ref, rtol=0, atol=1e-11)


def test_the_kernels_are_exact_in_u_and_shared_across_payload_masses(pair):
    """The efforts at the state's own accelerations (one RNEA pass of Pinocchio, with u
    inside) equal the compiled E u + e_0; a machine that differs in its payload's mass
    only gets the same compiled kernels (no compile in the loop at a pick)."""
    compiled, reference = pair
    for eff in pair:
        eff.payload_mass = 210.0
    st = STATES[0]
    reference._shared[0] = None
    expected = reference.payload_regressor(st)
    compiled._shared[0] = None
    got = compiled.efforts(st)
    np.testing.assert_allclose(got, expected[0] + 210.0 * expected[1], rtol=1e-10,
                               atol=1e-8)
    assert kernels_for(build_reference_machine(payload_mass=290.0)) is kernels_for(MACHINE)


def test_a_state_the_kernel_cannot_evaluate_falls_back_to_pinocchio(pair, monkeypatch):
    compiled, reference = pair
    st = STATES[1]
    monkeypatch.setattr(EffortKernels, "efforts", lambda self, s: None)
    monkeypatch.setattr(EffortKernels, "points", lambda self, s, m: None)
    for eff in pair:
        eff._shared[0] = None
    E, _ = compiled.affine(st)
    reference._shared[0] = None
    np.testing.assert_array_equal(E, reference.affine(st)[0])
    np.testing.assert_array_equal(compiled.point_specific_forces(st, MOUNTS)[1],
                                  reference.point_specific_forces(st, MOUNTS)[1])


def test_inputs_layout_and_an_unknown_body(pair):
    assert INPUTS["size"] == 9 + 6 + 6 + 13 + 13 + 4
    with pytest.raises(EstimatorError, match="no body 'boom'"):
        pair[0].point_specific_forces(STATES[0], (("boom", (0.0, 0.0, 0.0)),))


def test_without_a_compiler_the_efforts_run_on_pinocchio(monkeypatch, tmp_path):
    """A C compiler that fails (an empty cache, ``CC=false``): no kernels, the same efforts
    from Pinocchio, no error."""
    from estimators import efforts_kernel

    monkeypatch.setenv("WBC_HDMM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "false")
    monkeypatch.setattr(efforts_kernel, "_REGISTRY", {})
    assert kernels_for(MACHINE) is None
    eff = ActuatorEfforts(MACHINE)
    eff._shared[0] = None
    reference = ActuatorEfforts(MACHINE, compiled=False)
    E, e0 = eff.affine(STATES[2])
    reference._shared[0] = None
    np.testing.assert_array_equal(E, reference.affine(STATES[2])[0])
    np.testing.assert_array_equal(eff.point_specific_forces(STATES[2], MOUNTS)[0],
                                  reference.point_specific_forces(STATES[2], MOUNTS)[0])


@pytest.mark.parametrize("mounts", [(("lift", (1.0, 0.0)),), (("lift", (1.0, np.nan, 0.0)),),
                                    (("lift",),)])
def test_a_bad_mount_is_refused(pair, mounts):
    with pytest.raises(EstimatorError, match="mount"):
        pair[0].point_specific_forces(STATES[0], mounts)


def test_prepared_points_build_nothing_at_the_first_call(pair, monkeypatch):
    """`prepare_points` (the link fusion's constructor) builds the kernel; a tick then only
    calls it."""
    from estimators import efforts_kernel

    with pytest.raises(EstimatorError, match="no body 'boom'"):
        pair[0].prepare_points((("boom", (0.0, 0.0, 0.0)),))
    mounts = (("telescope", (0.2, 0.0, 0.05)),)
    pair[0].prepare_points(mounts)
    monkeypatch.setattr(efforts_kernel, "points_function",
                        lambda *a: pytest.fail("built a kernel at the first call"))
    a, _ = pair[0].point_specific_forces(STATES[3], mounts)
    np.testing.assert_allclose(a, pair[1].point_specific_forces(STATES[3], mounts)[0],
                               rtol=0, atol=1e-12)


def test_the_observers_regressor_entries_and_the_joined_fill_are_the_same_bits(pair):
    """`payload_regressor_at` (the observer's lift and tilt) gives `payload_regressor`'s
    entries to the bit, compiled and on Pinocchio; `EffortKernels.fill`'s joined bytes are
    the slices' row, and a state it cannot join (a non-contiguous rotation) still fills."""
    for eff in pair:
        for st in STATES:
            eff._shared[0] = None
            f0, y = eff.payload_regressor(st)
            got = eff.payload_regressor_at(st, (3, 4))
            assert got == (f0[[3, 4]].tolist(), y[[3, 4]].tolist())
            assert all(type(v) is float for v in got[0] + got[1])
    kernels = kernels_for(MACHINE)
    st = STATES[1]
    joined, sliced = np.full(51, np.nan), np.full(51, np.nan)
    kernels.fill(joined, st)
    odd = SimpleNamespace(**{k: getattr(st, k) for k in ("base_twist", "base_acceleration",
                                                          "q", "qd", "qdd")},
                          base_rotation=np.asfortranarray(st.base_rotation))
    kernels.fill(sliced, odd)
    assert joined.tobytes() == sliced.tobytes()
    assert joined.tobytes() == np.concatenate([st.base_rotation.ravel(), st.base_twist,
                                               st.base_acceleration, st.q, st.qd,
                                               st.qdd[9:]]).tobytes()
