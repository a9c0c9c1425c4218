"""Test doubles and random-state generators, kept out of the production packages.

Used by `tests/` and `benchmarks/` only; nothing in `models`, `estimators`, `wbc` or
`scenarios` imports this package.
"""
