"""Stability-aware whole-body control of heavy-duty hydraulic mobile manipulators."""

__version__ = "0.1.0"
