"""`Inequality`'s own __init__ (its fields written once, cheaply): still a frozen dataclass."""

import dataclasses

import numpy as np
import pytest

from wbc.constraints.constraint import DiagonalBlocks, Inequality


def test_inequality_is_the_frozen_dataclass_it_was():
    G, h = np.ones((2, 3)), np.zeros(2)
    a = Inequality(G, h)
    assert a.G is G and a.h is h and a.diagonal is None
    d = DiagonalBlocks(1, 0, 3, 2)
    b = Inequality(G=G, h=h, diagonal=d)
    assert b.diagonal is d and b == Inequality(G, h, d) and a != b
    assert dataclasses.replace(a, diagonal=d) == b
    assert [f.name for f in dataclasses.fields(a)] == ["G", "h", "diagonal"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.h = h
    assert "diagonal=None" in repr(a)
