"""Simulation scenarios: open-loop traversals and closed-loop control runs."""
