"""`models.numeric.clip` is `np.clip`, bit for bit (signed zeros and NaN included)."""

import numpy as np

from models.numeric import clip


def test_clip_is_np_clip_bit_for_bit():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(200, 9))
    x[::7, 2] = -0.0
    x[::11, 4] = np.nan
    x[::13, 5] = np.inf
    lo = np.minimum(rng.normal(size=9), 0.0)
    lo[3] = -0.0  # ties against signed zeros
    hi = np.maximum(rng.normal(size=9), 0.0)
    hi[6] = lo[6]  # an empty-width interval
    for a, b in ((x, (lo, hi)), (x[0], (lo, hi)), (x, (-1.0, 1.0)), (0.3, (0.0, 0.25)),
                 (-0.0, (0.0, 1.0))):
        ours, theirs = np.asarray(clip(a, *b)), np.asarray(np.clip(a, *b))
        assert ours.dtype == theirs.dtype and ours.shape == theirs.shape
        assert np.array_equal(ours.view(np.uint64), theirs.view(np.uint64))
    out = x.copy()
    clip(out, -0.5, 0.5, out=out)
    assert np.array_equal(out.view(np.uint64), np.clip(x, -0.5, 0.5).view(np.uint64))
