"""Frozen dataclasses made from fields already known to be valid, without their checks.

A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` (~0.3 us
a field) and runs its ``__post_init__`` checks; objects made every control tick from fields
the caller has just made or checked (a command, a plan, a reference sample, an observation)
skip both with `trusted`. Only for classes whose ``__init__`` does nothing else: no
``__post_init__``, no ``__slots__``.
"""

from __future__ import annotations

__all__ = ["trusted"]


def trusted(cls, **fields):
    """An instance of ``cls`` with ``fields`` as its instance dict, ``__init__`` not run.

    The caller gives every field (a missing one is an ``AttributeError`` when read) and
    vouches for their values.
    """
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj
