"""Batch estimation over logs, and the calibration of D and beta (eq. 30, Fig. 9)."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import NormalForceEstimator, SingularSystemError, StateBatch
from estimators.calibration import (
    calibrate_d_beta,
    calibrate_d_beta_sliding,
    forces_d_beta,
    null_space_form,
)
from models import WheelContacts, build_reference_machine
from testkit.estimator_states import random_state


@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


@pytest.fixture(scope="module")
def states(machine):
    rng = np.random.default_rng(0)
    est = NormalForceEstimator(machine)
    out = []
    flag_sets = [[1, 1, 1, 1]] * 6 + [[1, 0, 1, 1], [1, 1, 0, 0], [0, 0, 0, 0]]
    for i in range(60):
        s = random_state(machine, rng, max_tilt=0.4)
        flags = np.array(flag_sets[i % len(flag_sets)], bool)
        pts = est.estimate(s).contact_points + 0.02 * rng.normal(size=(4, 3))
        s = replace(s, contacts=WheelContacts(flags, 500 * rng.normal(size=(4, 3)), pts,
                                              np.tile([0, 0, 1.0], (4, 1))))
        s = replace(s, suspension_force=1e4 * rng.normal(size=2))
        out.append(s)
    return out


@pytest.mark.parametrize("backend", ["compiled", "casadi", "reference"])
@pytest.mark.parametrize("method,fourth", [("full", "d-beta"), ("full", "cylinder-force"),
                                           ("quasi-static", "d-beta")])
def test_batch_equals_single(machine, states, backend, method, fourth):
    est = NormalForceEstimator(machine, method=method, fourth=fourth, D=1.1, beta=50.0,
                               backend=backend)
    sub = states if backend == "compiled" else states[:12]
    batch = est.estimate_batch(sub, chunk=7)
    assert len(batch) == len(sub) and batch.backend == est.backend
    for i, s in enumerate(sub):
        e = est.estimate(s)
        np.testing.assert_allclose(batch.normal_forces[i], e.normal_forces, rtol=1e-10,
                                   atol=1e-6)
        assert batch.mode[i] == e.mode and batch.tipping[i] == e.tipping
        np.testing.assert_allclose(batch.wrench_xi[i], e.wrench_xi, rtol=1e-10, atol=1e-6)


def test_batch_from_arrays_and_threads(machine, states):
    est = NormalForceEstimator(machine)
    sb = StateBatch.from_states(states)
    as_dict = {k: getattr(sb, k) for k in ("base_rotation", "base_twist", "base_acceleration",
                                           "q", "qd", "qdd", "in_contact", "force_in_fb",
                                           "point_in_fb")}
    a = est.estimate_batch(as_dict, chunk=8, threads=2)
    b = est.estimate_batch(sb, chunk=1000, threads=1)
    np.testing.assert_array_equal(a.normal_forces, b.normal_forces)
    assert np.isfinite(a.normal_forces).all()
    empty = est.estimate_batch([])
    assert empty.normal_forces.shape == (0, 4)


def test_batch_range_check_in_a_later_chunk(machine, states):
    """Strokes out of range in later chunks of a threaded batch: the error names the first
    such row and counts them all, as a serial check does; a stroke on its bound passes."""
    from estimators import EstimatorInputError
    from estimators.checks import coordinate_ranges

    est = NormalForceEstimator(machine)
    sb = StateBatch.from_states(states)
    name, _, i, lo, hi = coordinate_ranges(machine)[-1]
    q = sb.q.copy()
    q[[41, 47, 52], i] = hi + 0.01
    q[44, i] = lo - 0.01
    with pytest.raises(EstimatorInputError, match=rf"row 41 \(4 rows in all\).*'{name}'"):
        est.estimate_batch(StateBatch(**{**sb.fields(), "q": q}), chunk=8, threads=2)
    q = sb.q.copy()
    q[[41, 44], i] = hi, lo
    out = est.estimate_batch(StateBatch(**{**sb.fields(), "q": q}), chunk=8, threads=2)
    assert np.isfinite(out.normal_forces).all()


def test_batch_singular_rows(machine, states):
    est = NormalForceEstimator(machine)
    sb = StateBatch.from_states(states[:6])
    points = sb.point_in_fb.copy()
    points[2, :, 1] = 0.3  # contacts on a line: roll row degenerate
    sb = StateBatch(**{**sb.fields(), "point_in_fb": points})
    with pytest.raises(SingularSystemError, match="row 2"):
        est.estimate_batch(sb)
    out = est.estimate_batch(sb, strict=False)
    assert out.singular.tolist() == [False, False, True, False, False, False]
    assert np.isfinite(out.normal_forces).all()


def test_calibration_recovers_d_and_beta(machine, states):
    est = NormalForceEstimator(machine)
    batch = est.estimate_batch(states)
    use = batch.in_contact.all(axis=1)
    a, b = batch.system_matrix[use], batch.system_rhs[use]
    xp, n = null_space_form(a, b)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", a, xp), b, atol=1e-6)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", a, n), 0.0, atol=1e-9)
    gt = forces_d_beta(xp, n, 1.45, -2500.0)
    for solver in ("scipy", "ipopt"):
        r = calibrate_d_beta(a, b, gt, solver=solver)
        assert abs(r.D - 1.45) < 1e-6 and abs(r.beta + 2500.0) < 1e-3, r
        assert r.rmse < 1e-3 and r.n_samples == use.sum()
    # Through the estimator: an estimator with the fitted pair reproduces the truth.
    gt_all = np.zeros((len(states), 4))
    gt_all[use] = gt
    r = est.calibrate(states, gt_all)
    tuned = NormalForceEstimator(machine, D=r.D, beta=r.beta)
    for i in np.flatnonzero(use)[:5]:
        np.testing.assert_allclose(tuned.estimate(states[i]).normal_forces, gt_all[i],
                                   rtol=1e-6, atol=1e-3)


def test_sliding_calibration_tracks_changing_parameters(machine, states):
    est = NormalForceEstimator(machine)
    batch = est.estimate_batch([s for s in states if s.contacts.in_contact.all()])
    a, b = batch.system_matrix, batch.system_rhs
    xp, n = null_space_form(a, b)
    half = len(a) // 2
    gt = np.vstack([forces_d_beta(xp[:half], n[:half], 0.6, 0.0),
                    forces_d_beta(xp[half:], n[half:], 1.5, -3000.0)])
    sl = calibrate_d_beta_sliding(a, b, gt, window=half, stride=half)
    assert len(sl.D) == 2
    np.testing.assert_allclose(sl.D, [0.6, 1.5], atol=1e-6)
    np.testing.assert_allclose(sl.beta, [0.0, -3000.0], atol=1e-3)


def test_gather_assembles_the_rows_batch_evaluates(machine):
    """The compiled kernel's gather (rows assembled in C from the fields, broadcast rows and
    an indexed table) gives the bits of the batch call on the rows numpy assembles."""
    from estimators._kernel_calls import assemble_rows

    est = NormalForceEstimator(machine, backend="compiled")
    kernel = est._kernels.kernel("nf_estimate")
    rng = np.random.default_rng(4)
    n = 37
    widths = [9, 6, 6, 13, 13, 13, 12, 4, 12]
    parts = [(rng.normal(size=(n, w)) * 0.1, None) for w in widths[:6]]
    parts[0] = (np.tile(np.eye(3).ravel(), (n, 1)), None)
    parts[3] = (np.zeros((n, 13)), None)  # mid-range strokes are not needed: finite rows
    parts += [(np.zeros(12), None), (np.zeros(4), None), (np.zeros(12), None)]
    table = rng.random((16, 16))
    parts += [(table, rng.integers(0, 16, n).astype(np.uint8)), (np.zeros(2), None),
              (rng.uniform(0.0, 300.0, (n, 1)), None)]  # each row's payload mass
    out_c = np.empty((n, kernel.n_out))
    kernel.gather(parts, out_c)
    out_b = np.empty_like(out_c)
    kernel.batch(np.ascontiguousarray(assemble_rows(parts, n)), out_b)
    assert np.isfinite(out_c).mean() > 0.9
    np.testing.assert_array_equal(out_c, out_b)
    with pytest.raises(ValueError, match="takes"):
        kernel.gather(parts[:-1], out_c)
    # Bounds on the rotation's entries: every row in them, then one row out.
    assert kernel.gather(parts, out_c, (0, np.full(9, -1.0), np.full(9, 1.0)))
    parts[0][0][20, 4] = 1.5
    assert not kernel.gather(parts, out_c, (0, np.full(9, -1.0), np.full(9, 1.0)))
    with pytest.raises(ValueError, match="do not fit"):
        kernel.gather(parts, out_c, (100, np.zeros(9), np.ones(9)))
    # What would read past an array is refused before the C code runs.
    short = [(a[:10], i) if a.ndim > 1 and i is None else (a, i) for a, i in parts]
    with pytest.raises(ValueError, match="rows"):
        kernel.gather(short, out_c)
    bad_index = parts[:-3] + [(table, np.full(n, 16, np.uint8)), *parts[-2:]]
    with pytest.raises(ValueError, match="index"):
        kernel.gather(bad_index, out_c)
    with pytest.raises(ValueError, match="C-contiguous"):
        kernel.gather(parts, out_c[:, :5])
