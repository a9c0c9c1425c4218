"""Wheel-ground normal-force estimators."""
