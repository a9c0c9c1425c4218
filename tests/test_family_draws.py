"""A short seeded draw of every scenario family, closed loop with mpc-full and real sensing.

Regression draws (master seed `REGRESSION_SEED`, draw 0, the first `DURATION` seconds): the
run completes, stays on four loaded wheels at every physics step after the machine is ready,
does not fall back and emits finite commands. The acceptance sweeps use another master seed
(2026, `docs/sweeps.md`).
"""

import numpy as np
import pytest

from scenarios.closed_loop import run_closed_loop
from scenarios.families import FAMILIES, draw

REGRESSION_SEED = 11
DURATION = 5.0  # [s] after ready: covers the heavy pick (at 2 s) and the first goal


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_a_seeded_draw_of_every_family_runs_safely(family):
    d = draw(family, 0, REGRESSION_SEED)
    m = run_closed_loop(d.scenario, None, "mpc-full", seed=d.terrain_seed,
                        duration=min(DURATION, d.scenario.duration),
                        pick_reserve=family == "heavy-pick-downhill")
    assert not m["partial"] and not m["tipped"] and m["fallbacks"] == 0
    assert not m["ready_timed_out"]
    assert np.isfinite(m["control_step_ms"]["median"])
    assert max(m["longest_below_threshold_s"].values()) <= 0.05
    assert max(m["time_below_threshold_s"].values()) == 0.0, m["min_normal_force_N"]
