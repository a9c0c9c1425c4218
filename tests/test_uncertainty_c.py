"""The closed loop's margin in one compiled pass: numpy's bits, and its refusals."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from estimators.errors import EstimatorError
from estimators.payload import PayloadEstimator
from estimators.uncertainty import (
    StateUncertainty,
    _compiled_margin,
    closure_margin,
    force_margin,
    normal_force_std,
    numpy_closure_margin,
)
from models import build_reference_machine
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()




@pytest.mark.skipif(_compiled_margin() is None, reason="no C compiler")
def test_compiled_margin_is_numpys_to_the_bit():
    closure = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    model = PayloadEstimator(MACHINE, fourth="d-beta", strokes="clip")
    rng = np.random.default_rng(11)
    for k in range(16):
        closure.payload_mass = model.payload_mass = float(rng.uniform(0.0, 300.0))
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        unc = StateUncertainty(rng.uniform(0.0, 0.1, 19), rng.uniform(0.0, 0.02, 13),
                               rng.uniform(0.0, 500.0, 2), float(rng.uniform(0.0, 40.0)))
        for m in (model, closure):
            fast = closure_margin(closure, m, s, unc, 0.99)
            assert fast.tobytes() == numpy_closure_margin(closure, m, s, unc, 0.99).tobytes(), k


def test_a_non_finite_load_split_is_refused():
    closure = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    s = replace(random_state(MACHINE, np.random.default_rng(2), max_tilt=0.2, speed=0.3),
                suspension_force=np.array([3e4, 4e4]))
    g = closure.linearize(s).G.copy()
    g[2, 5] = np.nan
    model = SimpleNamespace(linearize=lambda state: SimpleNamespace(G=g))
    unc = StateUncertainty(np.full(19, 0.05), np.full(13, 0.01), np.full(2, 100.0), 5.0)
    with pytest.raises(EstimatorError):
        closure_margin(closure, model, s, unc, 0.99)
    with pytest.raises(EstimatorError, match="confidence"):
        closure_margin(closure, closure, s, unc, 1.5)


@pytest.mark.skipif(_compiled_margin() is None, reason="no C compiler")
def test_margin_pass_on_kept_buffers_is_numpys_to_the_bit():
    """`MarginPass` with and without the model's G and the payload term, wheels lifted."""
    from estimators.uncertainty_c import MarginPass

    fused = MarginPass(_compiled_margin(), 19, 13, 100.0)
    rng = np.random.default_rng(5)
    for k in range(24):
        g_c, g_m = rng.normal(0, 1e3, (4, 19)), rng.normal(0, 1e3, (4, 19))
        d_qd, stepped = rng.normal(0, 1e2, (4, 13)), rng.uniform(0, 2e4, (3, 4))
        d_m, contact = rng.normal(0, 10, 4), rng.uniform(size=4) < 0.8
        unc = StateUncertainty(rng.uniform(0.0, 0.1, 19), rng.uniform(0.0, 0.02, 13),
                               rng.uniform(0.0, 500.0, 2), float(rng.uniform(0.0, 40.0)))
        for model, payload in ((g_m, d_m), (None, d_m), (g_m, None)):
            g = g_c if model is None else g_c - model
            lin = SimpleNamespace(G=g, d_qd=d_qd, in_contact=contact)
            d_s = ((stepped[1:] - stepped[0]) / 100.0).T
            want = force_margin(normal_force_std(lin, unc, d_s, payload), 0.99)
            got = fused(g_c, model, d_qd, stepped, payload, contact, unc, 2.3263478740408408)
            assert got.tobytes() == want.tobytes(), (k, model is None, payload is None)
    g_c[1, 3] = np.inf
    assert fused(g_c, None, d_qd, stepped, d_m, contact, unc, 2.33) is None
