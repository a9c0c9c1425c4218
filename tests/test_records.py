"""`models.records.trusted`: a frozen dataclass's instance as its constructor makes it."""

import dataclasses

import pytest

from models.records import trusted


@dataclasses.dataclass(frozen=True)
class _Pair:
    a: float
    b: tuple = ()


def test_trusted_equals_the_constructor_and_stays_frozen():
    made = trusted(_Pair, a=1.5, b=(2,))
    assert type(made) is _Pair and made == _Pair(1.5, (2,)) and vars(made) == {"a": 1.5, "b": (2,)}
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.a = 2.0
    assert dataclasses.replace(made, a=3.0) == _Pair(3.0, (2,))
